"""Depth noise: the margin m(d) by which a measured surface may lie in front of its reported depth."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from depthguard import config


@dataclass(frozen=True)
class NoiseModel:
    """Axial depth noise sigma(d) = a + b*d + c*d**2 (metres, d in metres); the margin is m(d) = k * sigma(d).

    The margin moves the start of each pixel's possibly-occupied set towards the camera (SPEC section 3), so a
    surface measured a little too far away is still counted. ``m(d)`` is clamped at 0 from below.
    """

    a: float = config.DEFAULT_NOISE_SIGMA[0]
    b: float = config.DEFAULT_NOISE_SIGMA[1]
    c: float = config.DEFAULT_NOISE_SIGMA[2]
    k: float = config.DEFAULT_NOISE_K

    def __post_init__(self):
        for name in ("a", "b", "c", "k"):
            value = getattr(self, name)
            if not isinstance(value, (int, float)) or not np.isfinite(value):
                raise ValueError(f"noise model field {name!r} must be a finite number, got {value!r}")
        if self.k < 0:
            raise ValueError(f"noise model field 'k' must be >= 0, got {self.k}")

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
