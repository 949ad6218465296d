"""Values read from the command line that more than one command parses."""

from __future__ import annotations

import math


def parse_joints(text: str, option: str = "--joints"):
    """``"a=0.1,b=0.2"`` -> {"a": 0.1, "b": 0.2}; ``"0.1,0.2"`` -> [0.1, 0.2]. InputError naming ``option`` if
    malformed."""
    from depthguard.errors import InputError

    items = [item.strip() for item in text.split(",") if item.strip()]
    if not items:
        raise InputError(f"{option}: no values in {text!r}")
    named = ["=" in item for item in items]
    if any(named) and not all(named):
        raise InputError(f"{option} mixes name=value and plain values: {text!r}")
    pairs = [item.split("=", 1) if "=" in item else (None, item) for item in items]
    try:
        values = [float(value) for _, value in pairs]
    except ValueError:
        raise InputError(f"{option}: not numbers: {text!r}") from None
    if not all(math.isfinite(value) for value in values):
        raise InputError(f"{option}: values must be finite numbers (radians, or metres for prismatic joints): "
                         f"{text!r}")
    if not all(named):
        return values
    names = [name.strip() for name, _ in pairs]
    if len(set(names)) != len(names):
        raise InputError(f"{option} names a joint twice: {text!r}")
    return dict(zip(names, values))
