"""Depth noise: the margin m(d) by which a measured surface may lie in front of its reported depth."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from depthguard import config
from depthguard.errors import RigError
from depthguard.validation import short_repr as _short


@dataclass(frozen=True)
class NoiseModel:
    """Axial depth noise sigma(d) = a + b*d + c*d**2 (metres, d in metres); the margin is m(d) = k * sigma(d).

    The margin moves the start of each pixel's possibly-occupied set towards the camera (design §3), so a
    surface measured a little too far away is still counted. ``m(d)`` is clamped at 0 from below.

    Ranges: |a| (m), |b| (m/m) and |c| (1/m) at most ``config.NOISE_COEFFICIENT_LIMIT``; k in
    [0, ``config.NOISE_K_MAX``]. Anything else raises :class:`~depthguard.errors.RigError` (field ``noise``).
    """

    a: float = config.DEFAULT_NOISE_SIGMA[0]
    b: float = config.DEFAULT_NOISE_SIGMA[1]
    c: float = config.DEFAULT_NOISE_SIGMA[2]
    k: float = config.DEFAULT_NOISE_K

    def __post_init__(self):
        for name in ("a", "b", "c", "k"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
                raise RigError(f"{name!r} must be a number, got {_short(value)}", field="noise")
            try:
                number = float(value)
            except OverflowError:
                number = math.inf
            if not math.isfinite(number):
                raise RigError(f"{name!r} must be a finite number, got {_short(value)}", field="noise")
            if name == "k":
                if not 0.0 <= number <= config.NOISE_K_MAX:
                    raise RigError(f"'k' must be in [0, {config.NOISE_K_MAX:g}], got {number!r}", field="noise")
            elif abs(number) > config.NOISE_COEFFICIENT_LIMIT:
                raise RigError(f"{name!r} must be within +-{config.NOISE_COEFFICIENT_LIMIT:g} (metres-based "
                               f"coefficient), got {number!r}", field="noise")
            object.__setattr__(self, name, number)

    @classmethod
    def none(cls) -> "NoiseModel":
        """No margin: for exact synthetic images."""
        return cls(0.0, 0.0, 0.0, 0.0)

    def margin(self, depth):
        """m(d) in metres for depths ``depth`` (scalar or array, metres)."""
        d = np.asarray(depth, dtype=np.float64)
        return np.maximum(self.k * (self.a + self.b * d + self.c * d * d), 0.0)

    def coefficients(self) -> tuple[float, float, float]:
        """(k*a, k*b, k*c): the margin as one polynomial, for kernels."""
        return (self.k * self.a, self.k * self.b, self.k * self.c)

