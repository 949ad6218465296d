"""Reading and writing depth image files: 16-bit PNG, 16-bit binary PGM, .npy, float TIFF.

Raw values are kept as they are: ``uint16`` in units of the camera's ``depth_scale`` (0 = no measurement), or
``float32`` metres (0, NaN or inf = no measurement).

A depth image file is input from outside, and reading it is bounded (docs/bad-input.md):

- The file is read through :mod:`depthguard.io.files`: a regular file of at most ``config.MAX_DEPTH_FILE_BYTES`` bytes
  (a FIFO, a device or a folder is refused before it is opened).
- The suffix decides the format, never the content: a ``.png`` is decoded only as PNG, a ``.tif``/``.tiff`` only as
  TIFF (Pillow restricted to that one format, so a PostScript file under such a name never reaches Pillow's
  Ghostscript plugin, and no process is started). PGM and ``.npy`` are parsed here.
- The image size is read from the header and checked before any pixel is decoded or allocated: each side between 1
  and ``config.MAX_IMAGE_SIDE`` pixels, at most Pillow's ``Image.MAX_IMAGE_PIXELS`` pixels in all, and, when the
  camera is known, exactly the camera's size.
- ``.npy`` headers are parsed without running code (no pickle) and checked (dtype ``uint16`` or floating point, no
  object or structured dtype, 2-D, the data exactly as long as the header says) before the array is made.

Every problem is a :class:`DepthImageError` naming the file (and the camera when it is known).
"""

from __future__ import annotations

import io
import warnings
from pathlib import Path

import numpy as np
import numpy.lib.format as npy_format
from PIL import Image, PngImagePlugin, TiffImagePlugin

from depthguard import config
from depthguard.io.files import atomic_write, read_bytes
from depthguard.errors import DepthguardError, DepthImageError

#: Suffix -> format. Nothing else is read.
SUFFIXES = {".png": "PNG", ".tif": "TIFF", ".tiff": "TIFF", ".pgm": "PGM", ".npy": "NPY"}

#: Pillow image modes that hold depth: 16-bit grayscale (as units), 32-bit integer (PNG's 16-bit grey in some Pillow
#: versions; values must fit 16 bits) and 32-bit float (metres).
_UINT16_MODES = ("I;16", "I;16B", "I;16L", "I;16N")
_PILLOW_MODES = _UINT16_MODES + ("I", "F")

#: The Pillow plugin that decodes each format; a file is never given to another.
_PILLOW_PLUGINS = {"PNG": PngImagePlugin.PngImageFile, "TIFF": TiffImagePlugin.TiffImageFile}

#: Bytes at the start of a file that may hold a .npy header (numpy's own header size limit is 10000 characters).
_NPY_HEADER_BYTES = 1 << 16

#: Bytes at the start of a PGM file that may hold its header (comments included).
_PGM_HEADER_BYTES = 1 << 16


def read_depth_file(path, camera=None) -> np.ndarray:
    """Read a depth image file into a 2-D ``uint16`` or ``float32`` array, values as stored.

    Formats by suffix (case-insensitive), and only the one the suffix names:

    - ``.png``: 16-bit grayscale PNG (ROS ``16UC1``);
    - ``.pgm``: binary ``P5`` with 16-bit samples, big-endian as the PGM format says;
    - ``.npy``: a plain ``uint16`` or floating-point array (the latter read as ``float32`` metres); not an ``.npz``;
    - ``.tif``/``.tiff``: 32-bit float metres or 16-bit grayscale.

    ``camera``: optional :class:`~depthguard.cameras.PinholeCamera`. When given, an image whose size (read from the
    file's header, before decoding) differs from the camera's is refused unread, with an error naming the camera and
    the field ``width/height``.

    Raises :class:`DepthImageError` naming the file on any problem (missing, not a regular file, larger than
    ``config.MAX_DEPTH_FILE_BYTES``, another format than the suffix says, corrupt, truncated, wrong size or dtype).
    """
    path = Path(path)
    context = {} if camera is None else {"camera": camera.name}
    kind = SUFFIXES.get(path.suffix.lower())
    if kind is None:
        raise DepthImageError(f"unknown depth image format {path.suffix!r} (use .png, .pgm, .npy or .tif)",
                              source=str(path), **context)
    data = read_bytes(path, what="depth image", max_bytes=config.MAX_DEPTH_FILE_BYTES, error=DepthImageError,
                      **context)
    try:
        if kind == "PGM":
            return _read_pgm(data, camera)
        if kind == "NPY":
            return _read_npy(data, camera)
        return _read_pillow(data, kind, camera)
    except DepthImageError as exc:
        raise exc.with_source(str(path)) from None


def read_intensity_png(path, camera=None) -> np.ndarray:
    """Read an 8-bit grayscale PNG (ROS ``mono8``) into a (height, width) ``uint8`` array, through the same checks
    as :func:`read_depth_file` (a regular file of at most ``config.MAX_DEPTH_FILE_BYTES``, only Pillow's PNG plugin
    sees the bytes, the size from the header checked against ``camera`` before decoding). Another mode than ``L``
    (colour, 16-bit, palette) is refused: a grey level must not depend on a conversion the caller did not choose.

    Raises :class:`DepthImageError` naming the file (and the camera, when given)."""
    path = Path(path)
    context = {} if camera is None else {"camera": camera.name}
    if path.suffix.lower() != ".png":
        raise DepthImageError(f"intensity images are 8-bit grayscale .png files, got {path.suffix!r}",
                              source=str(path), **context)
    data = read_bytes(path, what="intensity image", max_bytes=config.MAX_DEPTH_FILE_BYTES, error=DepthImageError,
                      **context)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            array, _ = _open_pillow(data, "PNG", camera, ("L",), "is not 8-bit grayscale ('L')")
    except DepthImageError as exc:
        raise DepthImageError(exc.message, source=str(path), field=exc.field, **context) from None
    return array.astype(np.uint8)


def write_depth_png(path, depth_u16: np.ndarray) -> None:
    """Write a (height, width) ``uint16`` depth image as a 16-bit grayscale PNG (ROS ``16UC1``), whole or not at
    all."""
    depth_u16 = np.asarray(depth_u16)
    if depth_u16.dtype != np.uint16 or depth_u16.ndim != 2:
        raise DepthImageError(f"write_depth_png needs a 2-D uint16 array, got {depth_u16.dtype} {depth_u16.shape}",
                              source=str(path))
    with atomic_write(path, "wb") as f:
        Image.fromarray(depth_u16).save(f, format="PNG")


def write_depth_pgm(path, depth_u16: np.ndarray) -> None:
    """Write a (height, width) ``uint16`` depth image as a binary 16-bit PGM (big-endian), whole or not at all."""
    depth_u16 = np.asarray(depth_u16, dtype=np.uint16)
    h, w = depth_u16.shape
    with atomic_write(path, "wb") as f:
        f.write(f"P5\n{w} {h}\n65535\n".encode("ascii"))
        f.write(depth_u16.astype(">u2").tobytes())


# ------------------------------------------------------------------------------------------------------ checks


def _check_size(width: int, height: int, camera) -> None:
    """Refuse an image size outside 1..MAX_IMAGE_SIDE per side, or other than the camera's, before decoding."""
    if not (1 <= width <= config.MAX_IMAGE_SIDE and 1 <= height <= config.MAX_IMAGE_SIDE):
        raise DepthImageError(f"image is {width}x{height} (width x height); each side must be 1 to "
                              f"{config.MAX_IMAGE_SIDE} pixels", field="width/height")
    if camera is not None and (height, width) != tuple(camera.shape):
        raise DepthImageError(f"image is {width}x{height} (width x height) but the camera is "
                              f"{camera.width}x{camera.height}", camera=camera.name, field="width/height")


# ------------------------------------------------------------------------------------------------------------- PGM


def _read_pgm(data: bytes, camera) -> np.ndarray:
    head = data[:_PGM_HEADER_BYTES]
    tokens: list[bytes] = []
    pos = 0
    while len(tokens) < 4:
        while pos < len(head) and head[pos : pos + 1].isspace():
            pos += 1
        if pos < len(head) and head[pos : pos + 1] == b"#":
            while pos < len(head) and head[pos : pos + 1] not in (b"\n", b"\r"):
                pos += 1
            continue
        if pos >= len(head):
            raise DepthImageError("truncated PGM header" if len(head) == len(data) else
                                  f"PGM header longer than {_PGM_HEADER_BYTES} bytes")
        start = pos
        while pos < len(head) and not head[pos : pos + 1].isspace() and head[pos : pos + 1] != b"#":
            pos += 1
        token = head[start:pos]
        if not tokens and token != b"P5":
            raise DepthImageError(f"not a binary PGM (magic {token[:8]!r}, expected b'P5')")
        if tokens and not (token.isdigit() and len(token) <= 9 and (pos < len(head) or len(head) == len(data))):
            raise DepthImageError(f"malformed PGM header (expected width, height and maxval, got {token[:16]!r})")
        tokens.append(token)
    width, height, maxval = (int(t) for t in tokens[1:4])
    if not 0 < maxval < 65536:
        raise DepthImageError(f"bad PGM header: maxval {maxval} (must be 1 to 65535)")
    if maxval <= 255:
        raise DepthImageError("8-bit PGM cannot hold depth; expected 16-bit samples (maxval > 255)")
    _check_size(width, height, camera)
    pos += 1  # exactly one whitespace byte ends the header
    expected = width * height * 2
    if len(data) - pos < expected:
        raise DepthImageError(f"truncated PGM: {max(len(data) - pos, 0)} bytes of pixels, expected {expected}")
    return np.frombuffer(data, dtype=">u2", count=width * height, offset=pos).reshape(height, width).astype(np.uint16)


# ------------------------------------------------------------------------------------------------------------- NPY


def npy_header(data, error: type[DepthguardError] = DepthImageError) -> tuple[tuple, bool, np.dtype, int]:
    """Parse the header of the ``.npy`` bytes ``data`` (versions 1.0 and 2.0) without reading its array.

    Returns (shape, fortran_order, dtype, offset of the array's first byte). The header is a Python literal that
    numpy parses with ``ast.literal_eval`` (no code runs) and caps at 10000 characters; nothing here allocates
    beyond it. Raises ``error`` (without a source: the caller names the file) for anything malformed.
    """
    head = bytes(data[:_NPY_HEADER_BYTES])
    if head[:2] == b"PK":
        raise error("a .npz (zip) archive, not a plain .npy array")
    stream = io.BytesIO(head)
    try:
        version = npy_format.read_magic(stream)
        if version == (1, 0):
            shape, fortran_order, dtype = npy_format.read_array_header_1_0(stream)
        elif version == (2, 0):
            shape, fortran_order, dtype = npy_format.read_array_header_2_0(stream)
        else:
            raise error(f"unsupported .npy format version {version[0]}.{version[1]} (1.0 and 2.0 are read)")
    except DepthguardError:
        raise
    except Exception as exc:  # noqa: BLE001 - numpy reports malformed headers as ValueError, EOFError, TypeError...
        reason = " ".join(str(exc).split())[:200] or type(exc).__name__
        raise error(f"not a plain .npy array ({reason})") from None
    return tuple(shape), bool(fortran_order), dtype, stream.tell()


def _read_npy(data: bytes, camera) -> np.ndarray:
    if len(data) == 0:
        raise DepthImageError("not a plain .npy array (empty file)")
    shape, fortran_order, dtype, offset = npy_header(data)
    if dtype.hasobject or dtype.fields is not None or dtype.subdtype is not None:
        raise DepthImageError(f"unsupported dtype {dtype} (expected uint16 units or float metres; object and "
                              "structured arrays are never read)", field="dtype")
    if dtype.kind == "u" and dtype.itemsize == 2:  # uint16 of either byte order
        target = np.uint16
    elif dtype.kind == "f":
        target = np.float32
    else:
        raise DepthImageError(f"unsupported dtype {dtype} (expected uint16 units or float metres)", field="dtype")
    if len(shape) != 2:
        raise DepthImageError(f"a depth image must be a non-empty 2-D array, got shape {shape}", field="shape")
    height, width = shape
    if height == 0 or width == 0:
        raise DepthImageError(f"a depth image must be a non-empty 2-D array, got shape {shape}", field="shape")
    _check_size(width, height, camera)
    expected = width * height * dtype.itemsize
    if len(data) - offset != expected:
        state = "truncated" if len(data) - offset < expected else "trailing bytes after the array"
        raise DepthImageError(f"{state}: {len(data) - offset} bytes of data for shape {shape} of {dtype}, expected "
                              f"{expected}")
    array = np.frombuffer(data, dtype=dtype, count=width * height, offset=offset)
    array = array.reshape((height, width), order="F" if fortran_order else "C")
    return np.ascontiguousarray(array, dtype=target)


# ----------------------------------------------------------------------------------------------- PNG and TIFF


def _read_pillow(data: bytes, kind: str, camera) -> np.ndarray:
    # Pillow warns about corrupt metadata (EXIF) and about images near its decompression-bomb limit: in a depth
    # image either means the file is not what it claims, so it is refused like any other corrupt file (and nothing
    # is printed beside the one-line error).
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        return _decode_pillow(data, kind, camera)


def _open_pillow(data: bytes, kind: str, camera, modes, refusal: str) -> tuple[np.ndarray, str]:
    """(array, mode) of an image that only the ``kind`` plugin decodes; its size checked against ``camera`` (and
    Pillow's decompression-bomb limit) before decoding; a mode not in ``modes`` refused with "image mode M
    ``refusal``"."""
    try:
        # The plugin of the format the suffix names, constructed directly: no other Pillow plugin (EPS, whose loader
        # runs Ghostscript, among them) ever sees the bytes, and the size checks below come before Pillow's own.
        image = _PILLOW_PLUGINS[kind](io.BytesIO(data))
    except Exception as exc:  # noqa: BLE001 - Pillow reports corrupt files in many exception types
        raise DepthImageError(f"not a readable {kind} file ({_reason(exc)})") from None
    with image:
        width, height = image.size
        _check_size(width, height, camera)
        limit = Image.MAX_IMAGE_PIXELS
        if limit is not None and width * height > limit:
            raise DepthImageError(f"image of {width}x{height} pixels is larger than Pillow's decompression-bomb "
                                  f"limit of {limit} pixels", field="width/height")
        mode = image.mode
        if mode not in modes:
            raise DepthImageError(f"image mode {mode!r} {refusal}", field="dtype")
        try:
            image.load()
            array = np.array(image)
        except Exception as exc:  # noqa: BLE001 - truncated or corrupt pixel data
            raise DepthImageError(f"corrupt {kind} file ({_reason(exc)})") from None
    if array.shape != (height, width):
        raise DepthImageError(f"corrupt {kind} file (decoded {array.shape}, header says {height}x{width})")
    return array, mode


def _decode_pillow(data: bytes, kind: str, camera) -> np.ndarray:
    array, mode = _open_pillow(data, kind, camera, _PILLOW_MODES,
                               "holds no depth (expected 16-bit grayscale or 32-bit float)")
    if mode in _UINT16_MODES:
        return array.astype(np.uint16)
    if mode == "I":  # 32-bit integer container
        if array.min(initial=0) < 0 or array.max(initial=0) > 65535:
            raise DepthImageError("32-bit integer image with values outside 0..65535", field="dtype")
        return array.astype(np.uint16)
    return array.astype(np.float32)


def _reason(exc: Exception) -> str:
    text = " ".join(str(exc).split())[:200]
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__
