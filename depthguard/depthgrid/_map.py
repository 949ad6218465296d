"""The depth grid map (design §8): from the principal camera's grid cells to the secondary cameras' pixels.

The principal camera's grid cell (u, v, k) is the frustum segment of pixel (u, v) between d_k = d_min + k*delta_d
and d_{k+1}. All cells of one pixel lie on its frustum, whose four edges are the rays through the pixel's footprint
corners. A point z*c on corner ray c (principal optical frame, c = ((u -+ 1/2 - cx)/fx, (v -+ 1/2 - cy)/fy, 1))
lands in secondary camera j at homogeneous image coordinates

    h(z) = K_j (R_jp c z + t_jp) = A_c z + B_j,   pixel = (h_x / h_z, h_y / h_z),   depth in j = h_z,

linear in z. The map stores A_c for every footprint corner of the principal image ((H+1) x (W+1) corners, shared by
neighbouring pixels) and B_j per secondary camera: memory proportional to pixels (about 7 MB per secondary camera at
640x480), from which any cell's footprint in j costs a few operations online. It is built from the rig alone.

The map is derived data, and never trusted silently (docs/bad-input.md):

- The file (format ``depthguard-depth-grid-map/2``) is one ``.npz`` archive of exactly three plain arrays, nothing
  pickled: ``header`` (uint8, UTF-8 JSON), ``corners`` and ``offsets`` (little-endian float64). The header records
  the format, the rig's fingerprint, the principal and secondary cameras, d_min, delta_d, n_cells, the principal's
  image size, each secondary's image size, and ``sha256``: the SHA-256 of the header's other fields (as canonical
  JSON: ``json.dumps(fields, sort_keys=True, separators=(",", ":"))`` of their typed values) followed by the bytes of
  ``corners`` and ``offsets`` (C order). A flipped bit anywhere in what the map says changes it.
- :func:`load_map` reads the file through ``depthguard.io.files`` (a regular file of at most
  ``config.MAX_MAP_FILE_BYTES`` bytes), checks the archive's members and their ``.npy`` headers (names, dtype,
  shapes as the header says) before reading any array, then the checksum, the parameters' ranges (d_min > 0,
  delta_d >= MIN_DELTA_D, 1 <= n_cells <= ``config.DEPTH_GRID_MAX_CELLS``, d_max <= ``config.COORDINATE_LIMIT``,
  image sides 1..``config.MAX_IMAGE_SIDE``), that every value is finite, and that the corners form the affine grid
  that a pinhole camera gives (A_c is affine in the corner's (u, v)).
- With a rig (``load_map(path, rig)``, :meth:`DepthGridMap.check_rig`, which the monitor and FusedFrames call),
  the fingerprint must match, and the geometry is rebuilt from the rig (milliseconds) and compared, within
  GEOMETRY_TOLERANCE relative: an edit that recomputed the checksum is caught too.

A map given explicitly (:func:`load_map`, the command line's ``--map``, ``DistanceMonitor(maps=...)``) that is
corrupt, of an older format, or built for another rig raises :class:`MapError` naming the file: the user asked for
that file, and it is never silently replaced by a rebuilt one. Without a map, the monitor builds one from the rig.
"""

from __future__ import annotations

import hashlib
import io
import json
import math
import numbers
import re
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from depthguard import config
from depthguard.io.files import atomic_write, read_bytes
from depthguard.cameras import Rig
from depthguard.depth import npy_header
from depthguard.errors import DepthguardError, InputError
from depthguard.validation import check_real, short_repr

MAP_FORMAT = "depthguard-depth-grid-map/2"
_OLD_FORMATS = ("depthguard-depth-grid-map/1",)

MIN_DELTA_D = config.DEPTH_GRID_MIN_DELTA_D
GEOMETRY_TOLERANCE = config.DEPTH_GRID_GEOMETRY_TOLERANCE

#: Largest header member, bytes.
_MAX_HEADER_BYTES = 1 << 16

_MEMBERS = ("header.npy", "corners.npy", "offsets.npy")
_HEADER_KEYS = ("format", "rig_fingerprint", "principal", "secondaries", "d_min", "delta_d", "n_cells", "width",
                "height", "secondary_sizes", "sha256")
_HEX64 = re.compile(r"[0-9a-f]{64}")


class MapError(DepthguardError, ValueError):
    """A depth grid map is malformed, corrupt, of an older format, or was built for another rig."""


@dataclass(frozen=True, eq=False)
class DepthGridMap:
    """What the online fusion needs, for one principal camera. Checked when made (:class:`MapError`); its arrays are
    read-only.

    Attributes:
        rig_fingerprint: :meth:`Rig.fingerprint` of the rig it was built for.
        principal: the principal camera's name.
        secondaries: the other cameras' names, in the order of the arrays below.
        d_min, delta_d: metres: cell k spans [d_min + k*delta_d, d_min + (k+1)*delta_d] along the principal's z.
        n_cells: number of cells along each pixel; the grid ends at d_max = d_min + n_cells*delta_d.
        corners: (n_secondaries, H+1, W+1, 3) float64: A of the footprint corner at image coordinates
            (u - 1/2, v - 1/2) for u in 0..W, v in 0..H, for each secondary camera (pixels per metre of principal z).
        offsets: (n_secondaries, 3) float64: B of each secondary camera (pixels; metres for the third component).
        secondary_sizes: (width, height) in pixels of each secondary camera, in the order of ``secondaries``.
    """

    rig_fingerprint: str
    principal: str
    secondaries: tuple[str, ...]
    d_min: float
    delta_d: float
    n_cells: int
    corners: np.ndarray
    offsets: np.ndarray
    secondary_sizes: tuple[tuple[int, int], ...]

    def __post_init__(self):
        _check_parameters(self.rig_fingerprint, self.principal, self.secondaries, self.d_min, self.delta_d,
                          self.n_cells, self.secondary_sizes, MapError)
        object.__setattr__(self, "secondaries", tuple(self.secondaries))
        object.__setattr__(self, "secondary_sizes", tuple((int(w), int(h)) for w, h in self.secondary_sizes))
        object.__setattr__(self, "d_min", float(self.d_min))
        object.__setattr__(self, "delta_d", float(self.delta_d))
        object.__setattr__(self, "n_cells", int(self.n_cells))
        n = len(self.secondaries)
        corners, offsets = _read_only(self.corners, "corners"), _read_only(self.offsets, "offsets")
        if corners.ndim != 4 or corners.shape[0] != n or corners.shape[3] != 3 or \
                not (2 <= corners.shape[1] <= config.MAX_IMAGE_SIDE + 1 and
                     2 <= corners.shape[2] <= config.MAX_IMAGE_SIDE + 1) or offsets.shape != (n, 3):
            raise MapError(f"depth grid map arrays have the wrong shapes {corners.shape}, {offsets.shape} for "
                           f"{n} secondary cameras (expected ({n}, H+1, W+1, 3) and ({n}, 3))")
        for name, array in (("corners", corners), ("offsets", offsets)):
            if not np.isfinite(array).all():
                raise MapError(f"depth grid map {name} hold values that are not finite", field=name)
        object.__setattr__(self, "corners", corners)
        object.__setattr__(self, "offsets", offsets)
        object.__setattr__(self, "_rig_checked", None)

    def kernel_arrays(self, used: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
        """(corners, offsets) of the secondary cameras ``used`` (indices into ``secondaries``), as the fused kernels
        take them: C-contiguous and writable (numba compiles read-only arrays as another type). Never written. The
        copy for the cameras of the latest call is kept, so that a new set of frames from the same cameras does not
        copy several MB a camera again."""
        kept = self.__dict__.get("_kernel_arrays")
        if kept is None or kept[0] != used:
            index = list(used)
            kept = (used, np.ascontiguousarray(self.corners[index]), np.ascontiguousarray(self.offsets[index]))
            object.__setattr__(self, "_kernel_arrays", kept)
        return kept[1], kept[2]

    @property
    def d_max(self) -> float:
        return self.d_min + self.n_cells * self.delta_d

    @property
    def shape(self) -> tuple[int, int]:
        """(height, width) of the principal camera's image."""
        return self.corners.shape[1] - 1, self.corners.shape[2] - 1

    @property
    def nbytes(self) -> int:
        return int(self.corners.nbytes + self.offsets.nbytes)

    def check_rig(self, rig: Rig) -> None:
        """Raise :class:`MapError` unless this map was built for ``rig``: the rig's fingerprint, and the geometry
        rebuilt from the rig (cameras, image sizes, every corner and offset within GEOMETRY_TOLERANCE relative).
        The rebuild takes milliseconds; a map object remembers the last rig it passed with."""
        if not isinstance(rig, Rig):
            raise InputError(f"check_rig needs a Rig, got {type(rig).__name__}")
        fingerprint = rig.fingerprint()
        if fingerprint != self.rig_fingerprint:
            raise MapError(f"this depth grid map was built for another rig (principal {self.principal!r}, "
                           f"secondaries {', '.join(self.secondaries)}): rebuild it with depthguard build-map")
        if self._rig_checked == fingerprint:  # the arrays are read-only, and the fingerprint fixes the geometry
            return
        try:
            built = build_map(rig, self.principal, d_min=self.d_min, delta_d=self.delta_d, n_cells=self.n_cells)
        except DepthguardError as exc:
            raise MapError(f"this depth grid map does not fit the rig ({exc})") from None
        if built.secondaries != self.secondaries or built.secondary_sizes != self.secondary_sizes or \
                built.corners.shape != self.corners.shape:
            raise MapError(f"this depth grid map's cameras ({self.principal!r} {self.shape[1]}x{self.shape[0]}, "
                           f"secondaries {_sizes_text(self.secondaries, self.secondary_sizes)}) are not the rig's "
                           f"({built.principal!r} {built.shape[1]}x{built.shape[0]}, secondaries "
                           f"{_sizes_text(built.secondaries, built.secondary_sizes)}): rebuild it")
        for name in ("corners", "offsets"):
            mine, rigs = getattr(self, name), getattr(built, name)
            for j, camera in enumerate(self.secondaries):
                scale = float(np.max(np.abs(rigs[j])))
                error = float(np.max(np.abs(mine[j] - rigs[j])))
                if not error <= GEOMETRY_TOLERANCE * max(scale, 1e-300):
                    raise MapError(f"this depth grid map's {name} for camera {camera!r} differ from the rig's "
                                   f"geometry by up to {error:.3g} (tolerance {GEOMETRY_TOLERANCE:g} of "
                                   f"{scale:.3g}): the map was altered; rebuild it with depthguard build-map",
                                   field=name)
        object.__setattr__(self, "_rig_checked", fingerprint)


def grid_range(rig: Rig, principal: str | None = None) -> tuple[float, float]:
    """(d_min, d_max), metres along ``principal``'s optical z: the depths its depth grid spans by default (design
    section 8, "Grid range").

    The depths at which the camera sees the rig's workspace box (the smallest and largest z of its corners), within
    the camera's depth_range, whichever is tighter; never nearer than ``config.DEPTH_GRID_NEAREST``. Without a
    workspace, the camera's depth_range; a camera with no finite maximum range then reaches
    ``config.DEPTH_GRID_UNBOUNDED_END`` metres beyond the grid's start. A surveillance region that leaves the grid is
    counted occupied there and flagged ``outside_grid``. A workspace the camera cannot see in front of it within its
    range is an error.
    """
    if not isinstance(rig, Rig):
        raise InputError(f"grid_range needs a Rig, got {type(rig).__name__}")
    principal = _principal_name(rig, principal)
    camera = rig.camera(principal)
    z_lo, z_hi = camera.depth_range
    d_min = max(float(z_lo), config.DEPTH_GRID_NEAREST)
    d_max = float(z_hi)
    if rig.workspace is not None:
        lo, hi = rig.workspace
        corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
        z = camera.world_to_camera(corners)[:, 2]
        d_min, d_max = max(d_min, float(z.min())), min(d_max, float(z.max()))
        if not d_min < d_max:
            raise InputError(f"camera {principal!r} sees no part of the rig's workspace within its depth range "
                             f"{list(camera.depth_range)} (the box spans z from {z.min():.3g} to {z.max():.3g} m in "
                             "its optical frame)", camera=principal, field="workspace")
    if not math.isfinite(d_max):
        d_max = d_min + config.DEPTH_GRID_UNBOUNDED_END
    d_max = min(d_max, config.COORDINATE_LIMIT)
    if not d_min < d_max:
        raise InputError(f"camera {principal!r} has no depths for a grid: depth_range {list(camera.depth_range)}, "
                         f"and the grid starts at {config.DEPTH_GRID_NEAREST:g} m at the nearest", camera=principal,
                         field="depth_range")
    return d_min, d_max


def _principal_name(rig: Rig, principal) -> str:
    if principal is not None and not isinstance(principal, str):
        raise InputError(f"principal must be a camera name, got {short_repr(principal)}", field="principal")
    return principal or rig.principal or next(iter(rig.cameras))


def build_map(rig: Rig, principal: str | None = None, d_min: float | None = None, d_max: float | None = None,
              delta_d: float | None = None, n_cells: int | None = None) -> DepthGridMap:
    """Build the depth grid map of ``rig`` for ``principal`` (default: the rig's principal, else its first camera).

    The grid spans [d_min, d_max] in cells of ``delta_d`` metres, or ``n_cells`` cells (give d_max or n_cells, not
    both). Defaults: the range :func:`grid_range` gives for the rig (its workspace and the camera's depth_range), in
    cells of ``config.DEPTH_GRID_DELTA_D`` (1 cm), coarser when the range needs more than
    ``config.DEPTH_GRID_MAX_CELLS``. Every other camera of the rig is a secondary camera. Ranges: d_min > 0, delta_d
    >= MIN_DELTA_D metres, n_cells (given or resulting) 1 to ``config.DEPTH_GRID_MAX_CELLS``, d_max <=
    ``config.COORDINATE_LIMIT``; else :class:`InputError`.
    """
    if not isinstance(rig, Rig):
        raise InputError(f"build_map needs a Rig, got {type(rig).__name__}")
    principal = _principal_name(rig, principal)
    camera = rig.camera(principal)
    secondaries = tuple(name for name in rig.cameras if name != principal)
    if not secondaries:
        raise InputError(f"a depth grid needs a secondary camera; the rig has only {principal!r}")
    if n_cells is not None and d_max is not None:
        raise InputError("give d_max or n_cells, not both", field="n_cells")
    default_min, default_max = grid_range(rig, principal) if d_min is None or (d_max is None and n_cells is None) \
        else (None, None)
    d_min = _real(default_min if d_min is None else d_min, "d_min", InputError)
    if not d_min > 0:
        raise InputError(f"d_min must be a positive number of metres, got {d_min!r}", field="d_min")
    if d_max is None and n_cells is None:
        if not default_max > d_min:
            raise InputError(f"d_min ({d_min:g} m) lies beyond the grid's default end {default_max:g} m: give d_max",
                             field="d_min")
        d_max = default_max
        if delta_d is None:  # the default cell depth, coarser if the range needs more cells than the grid holds
            delta_d = max(config.DEPTH_GRID_DELTA_D, (d_max - d_min) / config.DEPTH_GRID_MAX_CELLS)
    delta_d = _real(config.DEPTH_GRID_DELTA_D if delta_d is None else delta_d, "delta_d", InputError)
    if not delta_d >= MIN_DELTA_D:
        raise InputError(f"delta_d must be at least {MIN_DELTA_D:g} metres, got {delta_d!r}", field="delta_d")
    if n_cells is None:
        d_max = _real(d_max, "d_max", InputError)
        if not d_min < d_max <= config.COORDINATE_LIMIT:
            raise InputError(f"d_max must be larger than d_min ({d_min:g}) and at most {config.COORDINATE_LIMIT:g} "
                             f"metres, got {d_max!r}", field="d_max")
        cells = (d_max - d_min) / delta_d
        if not cells <= config.DEPTH_GRID_MAX_CELLS * (1 + 1e-12):
            raise InputError(f"[{d_min:g}, {d_max:g}] m in cells of {delta_d:g} m is {math.ceil(cells)} cells; at "
                             f"most {config.DEPTH_GRID_MAX_CELLS} are supported (config.DEPTH_GRID_MAX_CELLS)",
                             field="delta_d")
        n_cells = min(config.DEPTH_GRID_MAX_CELLS, max(1, int(math.ceil(cells - 1e-9))))
    if isinstance(n_cells, bool) or not isinstance(n_cells, numbers.Integral) or \
            not 1 <= n_cells <= config.DEPTH_GRID_MAX_CELLS:
        raise InputError(f"n_cells must be a whole number from 1 to {config.DEPTH_GRID_MAX_CELLS}, got "
                         f"{short_repr(n_cells)}", field="n_cells")
    n_cells = int(n_cells)
    if not d_min + n_cells * delta_d <= config.COORDINATE_LIMIT:
        raise InputError(f"the grid would end at {d_min + n_cells * delta_d:g} m, beyond "
                         f"{config.COORDINATE_LIMIT:g} m", field="n_cells")
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
    corners.setflags(write=False)
    offsets.setflags(write=False)
    sizes = tuple((rig.cameras[name].width, rig.cameras[name].height) for name in secondaries)
    try:
        return DepthGridMap(rig_fingerprint=rig.fingerprint(), principal=principal, secondaries=secondaries,
                            d_min=d_min, delta_d=delta_d, n_cells=n_cells, corners=corners, offsets=offsets,
                            secondary_sizes=sizes)
    except MapError as exc:  # geometry that overflowed float64: the rig is out of range
        raise InputError(f"the rig gives no usable depth grid: {exc.message}", field=exc.field) from None


def save_map(grid: DepthGridMap, path) -> None:
    """Write ``grid`` to one ``.npz`` file (format MAP_FORMAT: three plain arrays, a JSON header with a SHA-256 of
    the map, nothing pickled). The file is written beside ``path`` and then renamed, so a reader never sees half a
    map."""
    if not isinstance(grid, DepthGridMap):
        raise InputError(f"save_map needs a DepthGridMap, got {type(grid).__name__}")
    fields = _header_fields(grid)
    corners = np.ascontiguousarray(grid.corners, dtype="<f8")
    offsets = np.ascontiguousarray(grid.offsets, dtype="<f8")
    fields["sha256"] = _digest(fields, corners, offsets)
    header = np.frombuffer(json.dumps(fields).encode("utf-8"), dtype=np.uint8)
    with atomic_write(path, "wb") as f:
        np.savez(f, header=header, corners=corners, offsets=offsets)


def load_map(path, rig: Rig | None = None) -> DepthGridMap:
    """Read a map written by :func:`save_map`, checking it whole (see the module docstring): nothing is pickled, no
    code runs, no array is read before its header was checked. With ``rig``, also refuse a map built for another rig
    or whose geometry differs from the rig's (:meth:`DepthGridMap.check_rig`).

    Raises :class:`MapError` naming the file for anything missing, malformed, corrupt or mismatched.
    """
    path = Path(path)
    data = read_bytes(path, what="depth grid map", max_bytes=config.MAX_MAP_FILE_BYTES, error=MapError)
    try:
        grid = _parse(data)
        del data
        _check_affine(grid)
        if rig is not None:
            grid.check_rig(rig)
    except MapError as exc:
        raise exc.with_source(str(path)) from None
    return grid


# ------------------------------------------------------------------------------------------------ file contents


def _parse(data: bytes) -> DepthGridMap:
    try:
        archive = zipfile.ZipFile(io.BytesIO(data))
    except Exception as exc:  # noqa: BLE001 - zipfile reports corrupt archives in several exception types
        raise MapError(f"not a depth grid map (not a readable .npz archive: {_reason(exc)})") from None
    with archive:
        infos = archive.infolist()
        names = [info.filename for info in infos]
        if sorted(names) != sorted(_MEMBERS):
            raise MapError(f"not a depth grid map (archive members {short_repr(names, 120)}, expected "
                           f"{', '.join(_MEMBERS)})")
        for info in infos:
            if info.flag_bits & 0x1 or info.compress_type not in (zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED):
                raise MapError(f"archive member {info.filename} is encrypted or compressed in an unsupported way")
        raw = _read_member(archive, "header.npy", None, np.dtype(np.uint8))
        fields = _parse_header(raw.tobytes())
        n = len(fields["secondaries"])
        shapes = {"corners.npy": (n, fields["height"] + 1, fields["width"] + 1, 3), "offsets.npy": (n, 3)}
        total = sum(8 * math.prod(shape) for shape in shapes.values())
        if total > config.MAX_MAP_FILE_BYTES:
            raise MapError(f"the header describes {total} bytes of arrays, more than the "
                           f"{config.MAX_MAP_FILE_BYTES} a map may hold")
        corners = _read_member(archive, "corners.npy", shapes["corners.npy"], np.dtype("<f8"))
        offsets = _read_member(archive, "offsets.npy", shapes["offsets.npy"], np.dtype("<f8"))
    expected = fields.pop("sha256")
    if _digest(fields, corners, offsets) != expected:
        raise MapError("checksum mismatch: the map's header or arrays were changed or corrupted since it was "
                       "written; rebuild it with depthguard build-map")
    return DepthGridMap(rig_fingerprint=fields["rig_fingerprint"], principal=fields["principal"],
                        secondaries=tuple(fields["secondaries"]), d_min=fields["d_min"], delta_d=fields["delta_d"],
                        n_cells=fields["n_cells"], corners=corners, offsets=offsets,
                        secondary_sizes=tuple(tuple(size) for size in fields["secondary_sizes"]))


def _read_member(archive: zipfile.ZipFile, name: str, shape, dtype: np.dtype) -> np.ndarray:
    """The array of archive member ``name``, after checking from its .npy header that it holds ``dtype`` in C order
    and ``shape`` (``None``: 1-D of at most _MAX_HEADER_BYTES elements) and exactly that many bytes."""
    info = archive.getinfo(name)
    try:
        with archive.open(info) as stream:
            head = stream.read(min(info.file_size, 1 << 16))
            got_shape, fortran_order, got_dtype, offset = npy_header(head, error=MapError)
            wanted = shape if shape is not None else got_shape
            if got_dtype != dtype or fortran_order or got_shape != wanted or \
                    (shape is None and not (len(got_shape) == 1 and got_shape[0] <= _MAX_HEADER_BYTES)):
                raise MapError(f"archive member {name} holds {got_dtype} of shape {got_shape}"
                               f"{' (Fortran order)' if fortran_order else ''}, expected {dtype} of shape "
                               f"{'(n,)' if shape is None else shape}")
            nbytes = math.prod(wanted) * dtype.itemsize
            if info.file_size - offset != nbytes:
                raise MapError(f"archive member {name} holds {info.file_size - offset} bytes of data, expected "
                               f"{nbytes}")
            body = bytearray(nbytes)
            filled = len(head) - offset
            body[:filled] = head[offset:]
            view = memoryview(body)
            while filled < nbytes:
                chunk = stream.read(min(nbytes - filled, 1 << 24))
                if not chunk:
                    raise MapError(f"archive member {name} is truncated")
                view[filled : filled + len(chunk)] = chunk
                filled += len(chunk)
            if stream.read(1):  # reading to its end also checks the member's CRC-32
                raise MapError(f"archive member {name} holds more data than its size says")
    except MapError:
        raise
    except Exception as exc:  # noqa: BLE001 - zipfile and zlib report corrupt members in several exception types
        raise MapError(f"archive member {name} is corrupt ({_reason(exc)})") from None
    array = np.frombuffer(body, dtype=dtype).reshape(wanted)
    array.setflags(write=False)
    return array


def _parse_header(raw: bytes) -> dict:
    def pairs(items):
        keys = [key for key, _ in items]
        if len(set(keys)) != len(keys):
            raise ValueError("a key repeats")
        return dict(items)

    def constant(name):
        raise ValueError(f"{name} is not a number")

    try:
        fields = json.loads(raw.decode("utf-8"), object_pairs_hook=pairs, parse_constant=constant)
    except (UnicodeDecodeError, ValueError, RecursionError) as exc:
        raise MapError(f"malformed depth grid map header ({_reason(exc)})") from None
    if not isinstance(fields, dict) or not isinstance(fields.get("format"), str):
        raise MapError("not a depth grid map (its header names no format)")
    if fields["format"] in _OLD_FORMATS:
        raise MapError(f"a depth grid map of the older format {fields['format']!r}, which has no checksum: rebuild "
                       "it with depthguard build-map")
    if fields["format"] != MAP_FORMAT:
        raise MapError(f"not a depth grid map of format {MAP_FORMAT!r} (got {short_repr(fields['format'])})")
    if sorted(fields) != sorted(_HEADER_KEYS):
        raise MapError(f"depth grid map header has the keys {short_repr(sorted(fields), 200)}, expected "
                       f"{', '.join(_HEADER_KEYS)}")
    if not (isinstance(fields["sha256"], str) and _HEX64.fullmatch(fields["sha256"])):
        raise MapError("depth grid map header: sha256 must be 64 hexadecimal digits", field="sha256")
    for key in ("width", "height"):
        value = fields[key]
        if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= config.MAX_IMAGE_SIDE:
            raise MapError(f"depth grid map header: {key} must be a whole number of pixels from 1 to "
                           f"{config.MAX_IMAGE_SIDE}, got {short_repr(value)}", field=key)
    if not isinstance(fields["secondaries"], list) or not isinstance(fields["secondary_sizes"], list) or \
            not all(isinstance(size, list) for size in fields["secondary_sizes"]):
        raise MapError("depth grid map header: secondaries and secondary_sizes must be lists", field="secondaries")
    _check_parameters(fields["rig_fingerprint"], fields["principal"], fields["secondaries"], fields["d_min"],
                      fields["delta_d"], fields["n_cells"], fields["secondary_sizes"], MapError)
    fields["d_min"], fields["delta_d"] = float(fields["d_min"]), float(fields["delta_d"])
    return fields


def _header_fields(grid: DepthGridMap) -> dict:
    """The header's fields but the checksum, as typed values (their canonical JSON is hashed)."""
    height, width = grid.shape
    return dict(format=MAP_FORMAT, rig_fingerprint=grid.rig_fingerprint, principal=grid.principal,
                secondaries=list(grid.secondaries), d_min=float(grid.d_min), delta_d=float(grid.delta_d),
                n_cells=int(grid.n_cells), width=int(width), height=int(height),
                secondary_sizes=[[int(w), int(h)] for w, h in grid.secondary_sizes])


def _digest(fields: dict, corners: np.ndarray, offsets: np.ndarray) -> str:
    """SHA-256 (hex) of the header's fields but ``sha256`` (canonical JSON) and the arrays' little-endian bytes."""
    canonical = {key: value for key, value in fields.items() if key != "sha256"}
    digest = hashlib.sha256(json.dumps(canonical, sort_keys=True, separators=(",", ":")).encode("utf-8"))
    for array in (corners, offsets):
        digest.update(np.ascontiguousarray(array, dtype="<f8").data)
    return digest.hexdigest()


# ------------------------------------------------------------------------------------------------------- checks


def _check_parameters(fingerprint, principal, secondaries, d_min, delta_d, n_cells, sizes, error) -> None:
    """The map's parameters and names: types and ranges (see the module docstring)."""
    if not (isinstance(fingerprint, str) and _HEX64.fullmatch(fingerprint)):
        raise error(f"rig_fingerprint must be 64 hexadecimal digits, got {short_repr(fingerprint)}",
                    field="rig_fingerprint")
    if not (isinstance(principal, str) and principal):
        raise error(f"principal must be a camera name, got {short_repr(principal)}", field="principal")
    if not isinstance(secondaries, (list, tuple)) or not secondaries or \
            not all(isinstance(name, str) and name for name in secondaries) or \
            len(set(secondaries)) != len(secondaries) or principal in secondaries:
        raise error(f"secondaries must be distinct camera names other than the principal {principal!r}, got "
                    f"{short_repr(secondaries, 120)}", field="secondaries")
    if not isinstance(sizes, (list, tuple)) or len(sizes) != len(secondaries) or \
            not all(isinstance(size, (list, tuple)) and len(size) == 2 and
                    all(not isinstance(side, bool) and isinstance(side, numbers.Integral) and
                        1 <= side <= config.MAX_IMAGE_SIDE for side in size) for size in sizes):
        raise error(f"secondary_sizes must give (width, height) of each secondary camera, 1 to "
                    f"{config.MAX_IMAGE_SIDE} pixels, got {short_repr(sizes, 120)}", field="secondary_sizes")
    d_min, delta_d = _real(d_min, "d_min", error), _real(delta_d, "delta_d", error)
    if not d_min > 0:
        raise error(f"d_min must be a positive number of metres, got {d_min!r}", field="d_min")
    if not delta_d >= MIN_DELTA_D:
        raise error(f"delta_d must be at least {MIN_DELTA_D:g} metres, got {delta_d!r}", field="delta_d")
    if isinstance(n_cells, bool) or not isinstance(n_cells, numbers.Integral) or \
            not 1 <= n_cells <= config.DEPTH_GRID_MAX_CELLS:
        raise error(f"n_cells must be a whole number from 1 to {config.DEPTH_GRID_MAX_CELLS}, got "
                    f"{short_repr(n_cells)}", field="n_cells")
    if not d_min + int(n_cells) * delta_d <= config.COORDINATE_LIMIT:
        raise error(f"the grid ends at {d_min + int(n_cells) * delta_d:g} m, beyond {config.COORDINATE_LIMIT:g} m",
                    field="n_cells")


def _check_affine(grid: DepthGridMap) -> None:
    """Refuse corners that are not the affine function of (u, v) that any pinhole camera pair gives:
    A(u, v) = K_j R_jp ((u - 1/2 - cx)/fx, (v - 1/2 - cy)/fy, 1), within GEOMETRY_TOLERANCE relative."""
    height, width = grid.shape
    u = np.arange(width + 1, dtype=np.float64)[None, :, None]
    v = np.arange(height + 1, dtype=np.float64)[:, None, None]
    for j, camera in enumerate(grid.secondaries):
        c = grid.corners[j]
        du = (c[0, width] - c[0, 0]) / width
        dv = (c[height, 0] - c[0, 0]) / height
        scale = float(np.max(np.abs(c)))
        error = float(np.max(np.abs(c - (c[0, 0] + u * du + v * dv))))
        if not error <= GEOMETRY_TOLERANCE * max(scale, 1e-300):
            raise MapError(f"the corners for camera {camera!r} are not a pinhole camera's (off by up to {error:.3g} "
                           f"of {scale:.3g}): the map was altered or corrupted; rebuild it", field="corners")


def _real(value, name: str, error) -> float:
    return check_real(value, name, unit="metres", error=error, field=name)


def _read_only(array, name: str) -> np.ndarray:
    """``array`` as a read-only C-contiguous float64 array (a copy unless it already is one that cannot change)."""
    if not isinstance(array, np.ndarray) or array.dtype.kind not in "fiu":
        raise MapError(f"depth grid map {name} must be a float64 array, got "
                       f"{getattr(array, 'dtype', type(array).__name__)}", field=name)
    if array.dtype != np.float64 or not array.flags.c_contiguous or array.flags.writeable:
        array = np.array(array, dtype=np.float64, order="C", copy=True)
        array.setflags(write=False)
    return array


def _sizes_text(names, sizes) -> str:
    return ", ".join(f"{name!r} {w}x{h}" for name, (w, h) in zip(names, sizes))


def _reason(exc: Exception) -> str:
    text = " ".join(str(exc).split())[:200]
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__
