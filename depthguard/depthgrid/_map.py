"""The depth grid map (SPEC section 8): from the principal camera's grid cells to the secondary cameras' pixels.

The principal camera's grid cell (u, v, k) is the frustum segment of pixel (u, v) between d_k = d_min + k*delta_d
and d_{k+1}. All cells of one pixel lie on its frustum, whose four edges are the rays through the pixel's footprint
corners. A point z*c on corner ray c (principal optical frame, c = ((u -+ 1/2 - cx)/fx, (v -+ 1/2 - cy)/fy, 1))
lands in secondary camera j at homogeneous image coordinates

    h(z) = K_j (R_jp c z + t_jp) = A_c z + B_j,   pixel = (h_x / h_z, h_y / h_z),   depth in j = h_z,

linear in z. The map stores A_c for every footprint corner of the principal image ((H+1) x (W+1) corners, shared by
neighbouring pixels) and B_j per secondary camera: memory proportional to pixels (about 7 MB per secondary camera at
640x480), from which any cell's footprint in j costs a few operations online. It is built from the rig alone, saved
to one ``.npz`` file (no pickle) with the rig's fingerprint, and refused for any other rig.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from depthguard import config
from depthguard.cameras import Rig
from depthguard.errors import DepthguardError, InputError

MAP_FORMAT = "depthguard-depth-grid-map/1"


class MapError(DepthguardError, ValueError):
    """A depth grid map file is malformed, or was built for another rig."""


@dataclass(frozen=True, eq=False)
class DepthGridMap:
    """What the online fusion needs, for one principal camera.

    Attributes:
        rig_fingerprint: :meth:`Rig.fingerprint` of the rig it was built for.
        principal: the principal camera's name.
        secondaries: the other cameras' names, in the order of the arrays below.
        d_min, delta_d: metres: cell k spans [d_min + k*delta_d, d_min + (k+1)*delta_d] along the principal's z.
        n_cells: number of cells along each pixel; the grid ends at d_max = d_min + n_cells*delta_d.
        corners: (n_secondaries, H+1, W+1, 3) float64: A of the footprint corner at image coordinates
            (u - 1/2, v - 1/2) for u in 0..W, v in 0..H, for each secondary camera (pixels per metre of principal z).
        offsets: (n_secondaries, 3) float64: B of each secondary camera (pixels; metres for the third component).
    """

    rig_fingerprint: str
    principal: str
    secondaries: tuple[str, ...]
    d_min: float
    delta_d: float
    n_cells: int
    corners: np.ndarray
    offsets: np.ndarray

    @property
    def d_max(self) -> float:
        return self.d_min + self.n_cells * self.delta_d

    @property
    def nbytes(self) -> int:
        return int(self.corners.nbytes + self.offsets.nbytes)

    def check_rig(self, rig: Rig) -> None:
        """Raise :class:`MapError` unless this map was built for ``rig``."""
        if rig.fingerprint() != self.rig_fingerprint:
            raise MapError(f"this depth grid map was built for another rig (principal {self.principal!r}, "
                           f"secondaries {', '.join(self.secondaries)}): rebuild it with depthguard build-map")


def build_map(rig: Rig, principal: str | None = None, d_min: float = config.DEPTH_GRID_D_MIN,
              d_max: float | None = None, delta_d: float = config.DEPTH_GRID_DELTA_D,
              n_cells: int | None = None) -> DepthGridMap:
    """Build the depth grid map of ``rig`` for ``principal`` (default: the rig's principal, else its first camera).

    The grid spans [d_min, d_max] in cells of ``delta_d`` metres (or ``n_cells`` cells; defaults: SPEC section 12's
    d_min = 0.2882 m, delta_d = 0.01 m, 343 cells). Every other camera of the rig is a secondary camera.
    """
    principal = principal or rig.principal or next(iter(rig.cameras))
    camera = rig.camera(principal)
    secondaries = tuple(name for name in rig.cameras if name != principal)
    if not secondaries:
        raise InputError(f"a depth grid needs a secondary camera; the rig has only {principal!r}")
    for name, value in (("d_min", d_min), ("delta_d", delta_d)):
        if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
            raise InputError(f"{name} must be a positive number of metres, got {value!r}")
    if n_cells is None:
        d_max = config.DEPTH_GRID_D_MIN + config.DEPTH_GRID_CELLS * config.DEPTH_GRID_DELTA_D if d_max is None \
            else d_max
        if not (math.isfinite(d_max) and d_max > d_min):
            raise InputError(f"d_max must be larger than d_min ({d_min}), got {d_max!r}")
        n_cells = int(math.ceil((d_max - d_min) / delta_d - 1e-9))
    if not (isinstance(n_cells, int) and n_cells > 0):
        raise InputError(f"n_cells must be a positive integer, got {n_cells!r}")
    u = (np.arange(camera.width + 1) - 0.5 - camera.cx) / camera.fx
    v = (np.arange(camera.height + 1) - 0.5 - camera.cy) / camera.fy
    rays = np.stack(np.broadcast_arrays(u[None, :], v[:, None], np.ones((1, 1))), axis=-1)  # (H+1, W+1, 3)
    corners = np.empty((len(secondaries), camera.height + 1, camera.width + 1, 3))
    offsets = np.empty((len(secondaries), 3))
    for i, name in enumerate(secondaries):
        other = rig.cameras[name]
        T_other_principal = other.T_camera_world @ camera.T_world_camera
        KR = other.K @ T_other_principal[:3, :3]
        corners[i] = rays @ KR.T
        offsets[i] = other.K @ T_other_principal[:3, 3]
    return DepthGridMap(rig_fingerprint=rig.fingerprint(), principal=principal, secondaries=secondaries,
                        d_min=float(d_min), delta_d=float(delta_d), n_cells=int(n_cells), corners=corners,
                        offsets=offsets)


def save_map(grid: DepthGridMap, path) -> None:
    """Write ``grid`` to one ``.npz`` file (arrays and a JSON header; nothing pickled)."""
    header = dict(format=MAP_FORMAT, rig_fingerprint=grid.rig_fingerprint, principal=grid.principal,
                  secondaries=list(grid.secondaries), d_min=grid.d_min, delta_d=grid.delta_d, n_cells=grid.n_cells)
    with open(path, "wb") as f:
        np.savez(f, header=np.array(json.dumps(header)), corners=grid.corners, offsets=grid.offsets)


def load_map(path, rig: Rig | None = None) -> DepthGridMap:
    """Read a map written by :func:`save_map` (``allow_pickle=False``: no code runs). With ``rig``, refuse a map built
    for another rig (:class:`MapError`)."""
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as data:
            header = json.loads(str(data["header"]))
            corners = np.ascontiguousarray(data["corners"], dtype=np.float64)
            offsets = np.ascontiguousarray(data["offsets"], dtype=np.float64)
    except OSError as exc:
        raise MapError(f"{path}: cannot read depth grid map ({exc.strerror or exc})") from None
    except (ValueError, KeyError, json.JSONDecodeError) as exc:
        raise MapError(f"{path}: not a depth grid map ({exc})") from None
    if not isinstance(header, dict) or header.get("format") != MAP_FORMAT:
        raise MapError(f"{path}: not a depth grid map of format {MAP_FORMAT!r}")
    try:
        grid = DepthGridMap(rig_fingerprint=str(header["rig_fingerprint"]), principal=str(header["principal"]),
                            secondaries=tuple(str(s) for s in header["secondaries"]), d_min=float(header["d_min"]),
                            delta_d=float(header["delta_d"]), n_cells=int(header["n_cells"]), corners=corners,
                            offsets=offsets)
    except (KeyError, TypeError, ValueError) as exc:
        raise MapError(f"{path}: malformed depth grid map header ({exc})") from None
    if corners.ndim != 4 or corners.shape[0] != len(grid.secondaries) or corners.shape[3] != 3 or \
            offsets.shape != (len(grid.secondaries), 3):
        raise MapError(f"{path}: depth grid map arrays have the wrong shapes {corners.shape}, {offsets.shape}")
    if rig is not None:
        try:
            grid.check_rig(rig)
        except MapError as exc:
            raise MapError(f"{path}: {exc}") from None
    return grid
