import os
import sys

import pytest

sys.path.insert(0, os.path.dirname(__file__))

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SHARED = os.path.join(os.path.dirname(REPO), "shared")
REAL_DATA = os.path.join(SHARED, "data", "real")


def pytest_configure(config):
    """Under pytest-xdist (``./dev.sh test`` runs one worker per core), each worker runs numba's parallel kernels on
    one thread: two workers of two threads each on two cores wait for each other's threads far longer than they
    work. The answers do not depend on the thread count; ``test_depth_grid`` and the kernels' thread tests set it
    themselves where it is what they check."""
    if os.environ.get("PYTEST_XDIST_WORKER"):
        import numba

        numba.set_num_threads(1)


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
