"""Simulated Kinect-like depth sensors and intensity cameras: what a real device makes of an exact rendering.

A depth pixel goes through, in this order:

1. the exact depth d (optical-frame z, metres) of the first surface on the pixel-centre ray, and the cosine of the
   angle between that surface's normal and the ray (both from the renderer; 0 / no surface where nothing is hit);
2. dropouts, decided on the exact image: a *discontinuity* pixel (one of its 4 neighbours differs by more than
   ``edge_threshold`` metres, or shows nothing) is dropped with probability ``edge_dropout``; a *grazing* pixel (the
   surface normal is more than ``grazing_angle`` radians from the ray) with probability ``grazing_dropout``.
   Nothing else is dropped: a fronto-parallel wall has no dropouts;
3. axial noise: d + N(0, sigma(d)^2), sigma(d) = a + b*d + c*d^2 from the camera's
   :class:`~depthguard.cameras.NoiseModel` (the same model whose margin k*sigma the distance monitor uses);
4. quantisation: rounded to the nearest unit of the camera's ``depth_scale`` (millimetres by default), in float32
   (exact to about 1e-7 of the depth);
5. range limits: a quantised depth outside the camera's ``depth_range`` becomes 0 (no measurement); the result is
   ``uint16``, 0 meaning no measurement.

Intensity images are the renderer's Lambertian intensity (albedo per object, light at the camera) in [0, 1], scaled
to 0..255, plus Gaussian noise of ``noise_sigma`` grey levels, rounded and clipped to ``uint8``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from depthguard_lab import config as lab_config


@dataclass(frozen=True)
class SensorModel:
    """How a simulated depth camera degrades the exact depth (see the module docstring).

    Attributes:
        noise: add the Gaussian axial noise of the camera's NoiseModel (False: exact depths, only quantised).
        edge_threshold: metres; a jump larger than this between 4-neighbours is a depth discontinuity.
        edge_dropout: probability in [0, 1] that a discontinuity pixel is dropped.
        grazing_angle: radians in [0, pi/2]; surfaces seen more obliquely than this are grazing.
        grazing_dropout: probability in [0, 1] that a grazing pixel is dropped.
    """

    noise: bool = True
    edge_threshold: float = lab_config.SIM_EDGE_THRESHOLD
    edge_dropout: float = lab_config.SIM_EDGE_DROPOUT
    grazing_angle: float = lab_config.SIM_GRAZING_ANGLE
    grazing_dropout: float = lab_config.SIM_GRAZING_DROPOUT

    def __post_init__(self):
        for name in ("edge_dropout", "grazing_dropout"):
            value = getattr(self, name)
            if not (0.0 <= value <= 1.0):
                raise ValueError(f"{name} must be a probability in [0, 1], got {value!r}")
        if not (self.edge_threshold > 0 and math.isfinite(self.edge_threshold)):
            raise ValueError(f"edge_threshold must be a positive number of metres, got {self.edge_threshold!r}")
        if not (0.0 <= self.grazing_angle <= math.pi / 2):
            raise ValueError(f"grazing_angle must lie in [0, pi/2] radians, got {self.grazing_angle!r}")

    @classmethod
    def ideal(cls) -> "SensorModel":
        """No noise and no dropouts: the exact depth, range-limited and quantised."""
        return cls(noise=False, edge_dropout=0.0, grazing_dropout=0.0)


def discontinuity_mask(depth: np.ndarray, threshold: float) -> np.ndarray:
    """(h, w) bool: pixels with a surface (depth > 0) one of whose 4-neighbours differs by more than ``threshold``
    metres or has no surface. ``depth``: (h, w) float metres, 0 = no surface. Image borders count as continuous."""
    d = np.asarray(depth, dtype=np.float32)
    has = d > 0
    edge = np.zeros(d.shape, dtype=bool)
    for a, b in ((np.s_[:, 1:], np.s_[:, :-1]), (np.s_[1:, :], np.s_[:-1, :])):
        jump = (np.abs(d[a] - d[b]) > threshold) | (has[a] != has[b])
        edge[a] |= jump
        edge[b] |= jump
    return edge & has


def grazing_mask(cosine: np.ndarray, depth: np.ndarray, angle: float) -> np.ndarray:
    """(h, w) bool: pixels with a surface whose normal makes more than ``angle`` radians with the ray.
    ``cosine``: (h, w) float, |cos| of that angle."""
    return (np.asarray(depth) > 0) & (np.asarray(cosine) < math.cos(angle))


def simulate_depth(depth_exact: np.ndarray, cosine: np.ndarray, camera, sensor: SensorModel,
                   rng: np.random.Generator) -> np.ndarray:
    """A simulated ``uint16`` depth image (units of ``camera.depth_scale``; 0 = no measurement).

    Args:
        depth_exact: (h, w) float32 metres, exact optical-frame z of the first surface; 0 where nothing is hit.
        cosine: (h, w) float32, |cos| of the angle between the surface normal and the ray (ignored where
            ``depth_exact`` is 0).
        camera: the :class:`~depthguard.cameras.PinholeCamera` (noise model, depth_range, depth_scale).
        sensor: the :class:`SensorModel`.
        rng: the random generator (seeded by the caller).
    """
    d = np.asarray(depth_exact, dtype=np.float32)
    valid = d > 0
    drop = np.zeros(d.shape, dtype=bool)
    if sensor.edge_dropout > 0:
        edge = discontinuity_mask(d, sensor.edge_threshold)
        drop[edge] = rng.random(int(edge.sum())) < sensor.edge_dropout
    if sensor.grazing_dropout > 0:
        grazing = grazing_mask(cosine, d, sensor.grazing_angle) & ~drop
        drop[grazing] = rng.random(int(grazing.sum())) < sensor.grazing_dropout
    if sensor.noise:
        noise = camera.noise
        sigma = np.float32(noise.a) + d * (np.float32(noise.b) + np.float32(noise.c) * d)
        np.maximum(sigma, 0.0, out=sigma)
        d = d + sigma * rng.standard_normal(d.shape, dtype=np.float32)
    units = np.rint(d * np.float32(1.0 / camera.depth_scale))
    lo, hi = camera.depth_range
    lo_units = max(1.0, math.ceil(lo / camera.depth_scale - 1e-9))
    hi_units = min(float(np.iinfo(np.uint16).max), math.floor(hi / camera.depth_scale + 1e-9))
    keep = valid & ~drop & (units >= lo_units) & (units <= hi_units)
    return np.where(keep, units, np.float32(0.0)).astype(np.uint16)


def simulate_intensity(intensity: np.ndarray, noise_sigma: float, rng: np.random.Generator) -> np.ndarray:
    """(h, w) ``uint8`` from the renderer's (h, w) float intensity in [0, 1] plus Gaussian noise of
    ``noise_sigma`` grey levels."""
    grey = np.asarray(intensity, dtype=np.float32) * np.float32(255.0)
    if noise_sigma > 0:
        grey += np.float32(noise_sigma) * rng.standard_normal(grey.shape, dtype=np.float32)
    return np.clip(np.rint(grey), 0, 255).astype(np.uint8)
