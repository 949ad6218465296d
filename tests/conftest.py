import os
import sys

import pytest

sys.path.insert(0, os.path.dirname(__file__))

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SHARED = os.path.join(os.path.dirname(REPO), "shared")
REAL_DATA = os.path.join(SHARED, "data", "real")


@pytest.fixture
def real_data():
    if not os.path.isdir(REAL_DATA):
        pytest.skip(f"real data not found at {REAL_DATA} (the shared folder sits beside the checkout)")
    return REAL_DATA


def pytest_terminal_summary(terminalreporter):
    """The bad-input campaign's counts (tests/campaign_support.py), only in sessions that ran campaign tests."""
    support = sys.modules.get("campaign_support")
    if support is not None and support.COUNTS:
        terminalreporter.section("depthguard campaign")
        support.report(terminalreporter.write_line)
