"""Reading and writing depth image files: 16-bit PNG, 16-bit binary PGM, .npy, float TIFF.

Raw values are kept as they are: ``uint16`` in units of the camera's ``depth_scale`` (0 = no measurement), or
``float32`` metres (0, NaN or inf = no measurement). Nothing here executes code from a file (``.npy`` is read with
``allow_pickle=False``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image, UnidentifiedImageError

from depthguard.errors import DepthImageError


def read_depth_file(path) -> np.ndarray:
    """Read a depth image file into a 2-D ``uint16`` or ``float32`` array, values as stored.

    Formats by suffix: ``.png`` (16-bit grayscale), ``.pgm`` (binary ``P5``; 16-bit samples are big-endian, as the
    PGM format says), ``.npy`` (``uint16`` or floating point, the latter as ``float32`` metres), ``.tif``/``.tiff``
    (32-bit float metres or 16-bit). Raises :class:`DepthImageError` naming the file on any problem.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    try:
        if suffix == ".pgm":
            array = _read_pgm(path)
        elif suffix == ".npy":
            array = _read_npy(path)
        elif suffix in (".png", ".tif", ".tiff"):
            array = _read_pillow(path)
        else:
            raise DepthImageError(f"unknown depth image format {suffix!r} (use .png, .pgm, .npy or .tif)",
                                  source=str(path))
    except OSError as exc:
        raise DepthImageError(f"cannot read file ({exc.strerror or exc})", source=str(path)) from None
    if array.ndim != 2 or array.size == 0:
        raise DepthImageError(f"a depth image must be a non-empty 2-D array, got shape {array.shape}",
                              source=str(path))
    return array


def write_depth_png(path, depth_u16: np.ndarray) -> None:
    """Write a (height, width) ``uint16`` depth image as a 16-bit grayscale PNG (ROS ``16UC1``)."""
    depth_u16 = np.asarray(depth_u16)
    if depth_u16.dtype != np.uint16 or depth_u16.ndim != 2:
        raise DepthImageError(f"write_depth_png needs a 2-D uint16 array, got {depth_u16.dtype} {depth_u16.shape}",
                              source=str(path))
    Image.fromarray(depth_u16).save(path)


def write_depth_pgm(path, depth_u16: np.ndarray) -> None:
    """Write a (height, width) ``uint16`` depth image as a binary 16-bit PGM (big-endian)."""
    depth_u16 = np.asarray(depth_u16, dtype=np.uint16)
    h, w = depth_u16.shape
    with open(path, "wb") as f:
        f.write(f"P5\n{w} {h}\n65535\n".encode("ascii"))
        f.write(depth_u16.astype(">u2").tobytes())


def _read_pgm(path: Path) -> np.ndarray:
    data = path.read_bytes()
    tokens: list[bytes] = []
    pos = 0
    while len(tokens) < 4:
        while pos < len(data) and data[pos : pos + 1].isspace():
            pos += 1
        if pos < len(data) and data[pos : pos + 1] == b"#":
            while pos < len(data) and data[pos : pos + 1] not in (b"\n", b"\r"):
                pos += 1
            continue
        start = pos
        while pos < len(data) and not data[pos : pos + 1].isspace() and data[pos : pos + 1] != b"#":
            pos += 1
        if start == pos:
            raise DepthImageError("truncated PGM header", source=str(path))
        tokens.append(data[start:pos])
    if tokens[0] != b"P5":
        raise DepthImageError(f"not a binary PGM (magic {tokens[0][:8]!r}, expected b'P5')", source=str(path))
    try:
        width, height, maxval = (int(t) for t in tokens[1:4])
    except ValueError:
        raise DepthImageError("malformed PGM header", source=str(path)) from None
    if width <= 0 or height <= 0 or not 0 < maxval < 65536:
        raise DepthImageError(f"bad PGM header: width {width}, height {height}, maxval {maxval}", source=str(path))
    pos += 1  # exactly one whitespace byte ends the header
    dtype = np.dtype(">u2") if maxval > 255 else np.dtype("u1")
    expected = width * height * dtype.itemsize
    if len(data) - pos < expected:
        raise DepthImageError(f"truncated PGM: {len(data) - pos} bytes of pixels, expected {expected}",
                              source=str(path))
    array = np.frombuffer(data, dtype=dtype, count=width * height, offset=pos).reshape(height, width)
    if dtype.itemsize != 2:
        raise DepthImageError("8-bit PGM cannot hold depth; expected 16-bit samples (maxval > 255)",
                              source=str(path))
    return array.astype(np.uint16)


def _read_npy(path: Path) -> np.ndarray:
    try:
        array = np.load(path, allow_pickle=False)
    except (ValueError, EOFError) as exc:
        raise DepthImageError(f"not a plain .npy array ({exc or 'empty file'})", source=str(path)) from None
    if not isinstance(array, np.ndarray):  # a .npz archive under a .npy name
        getattr(array, "close", lambda: None)()
        raise DepthImageError(f"not a plain .npy array (got {type(array).__name__})", source=str(path))
    if array.dtype.kind == "u" and array.dtype.itemsize == 2:  # uint16 of either byte order
        return np.ascontiguousarray(array, dtype=np.uint16)
    if np.issubdtype(array.dtype, np.floating):
        return np.ascontiguousarray(array, dtype=np.float32)
    raise DepthImageError(f"unsupported dtype {array.dtype} (expected uint16 units or float metres)",
                          source=str(path))


def _read_pillow(path: Path) -> np.ndarray:
    try:
        with Image.open(path) as image:
            mode = image.mode
            array = np.array(image)
    except UnidentifiedImageError:
        raise DepthImageError("not a readable image file", source=str(path)) from None
    except (SyntaxError, ValueError) as exc:  # Pillow reports some corrupt files this way
        raise DepthImageError(f"corrupt image file ({exc})", source=str(path)) from None
    except Image.DecompressionBombError as exc:  # a corrupt or hostile header claiming a gigantic image
        raise DepthImageError(f"refused: {exc}", source=str(path)) from None
    if mode in ("I;16", "I;16B", "I;16L"):
        return array.astype(np.uint16)
    if mode == "I":  # 32-bit integer container; PNG loads 16-bit grayscale this way in some Pillow versions
        if array.min(initial=0) < 0 or array.max(initial=0) > 65535:
            raise DepthImageError("32-bit integer image with values outside 0..65535", source=str(path))
        return array.astype(np.uint16)
    if mode == "F":
        return array.astype(np.float32)
    raise DepthImageError(f"image mode {mode!r} holds no depth (expected 16-bit grayscale or 32-bit float)",
                          source=str(path))
