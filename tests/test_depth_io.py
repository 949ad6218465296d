"""Depth image files, frames tied to cameras, and the per-pixel start depths of the possibly-occupied sets.

Real frames: /work/shared/data/real/ (slambook2 room, big-endian 16-bit PGM in millimetres; one TUM RGB-D frame,
16-bit PNG in units of 0.2 mm).
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

import depthguard as dg
from depthguard import config
from depthguard.depth import write_depth_pgm, write_depth_png

REAL = Path("/work/shared/data/real")
SLAMBOOK = REAL / "slambook2-room" / "depth"
TUM = REAL / "tum-rgbd-frame" / "TUM_depth.png"
needs_real = pytest.mark.skipif(not REAL.exists(), reason="real depth data not available")


def make_camera(width=8, height=6, name="cam", **changes) -> dg.PinholeCamera:
    fields = dict(name=name, width=width, height=height, fx=10.0, fy=10.0, cx=(width - 1) / 2, cy=(height - 1) / 2,
                  T_world_camera=np.eye(4), noise=dg.NoiseModel.none())
    fields.update(changes)
    return dg.PinholeCamera(**fields)


# --------------------------------------------------------------------------------------------------------------------
# 16-bit PNG


def test_png16_round_trip_keeps_every_value(tmp_path):
    rng = np.random.default_rng(0)
    data = rng.integers(0, 65536, size=(7, 11), dtype=np.uint16)
    data[0, 0], data[0, 1], data[0, 2] = 0, 65535, 0x0102
    path = tmp_path / "d.png"
    write_depth_png(path, data)
    got = dg.read_depth_file(path)
    assert got.dtype == np.uint16 and got.shape == (7, 11)
    np.testing.assert_array_equal(got, data)


def test_png16_written_by_pillow_directly(tmp_path):
    data = (np.arange(12, dtype=np.uint16).reshape(3, 4) * 1000 + 7)
    path = tmp_path / "d.png"
    Image.fromarray(data).save(path)
    np.testing.assert_array_equal(dg.read_depth_file(path), data)


# --------------------------------------------------------------------------------------------------------------------
# 16-bit binary PGM (big-endian)


def test_pgm_is_big_endian_by_hand(tmp_path):
    # 3x2 image, samples written byte by byte, most significant byte first (the PGM format)
    pixels = bytes([0x01, 0x02, 0x00, 0x00, 0xFF, 0xFF,
                    0x12, 0x34, 0x00, 0x01, 0x80, 0x00])
    path = tmp_path / "d.pgm"
    path.write_bytes(b"P5\n3 2\n65535\n" + pixels)
    got = dg.read_depth_file(path)
    assert got.dtype == np.uint16
    np.testing.assert_array_equal(got, [[0x0102, 0, 0xFFFF], [0x1234, 1, 0x8000]])
    assert got[0, 0] == 258  # not 0x0201 = 513


def test_pgm_header_with_comments_and_odd_whitespace(tmp_path):
    path = tmp_path / "d.pgm"
    path.write_bytes(b"P5 # made by hand\n# another comment\n2\t1\r\n4095 " + bytes([0x0F, 0xFF, 0x00, 0x10]))
    np.testing.assert_array_equal(dg.read_depth_file(path), [[4095, 16]])


def test_pgm_writer_round_trip_is_big_endian(tmp_path):
    data = np.array([[0x0102, 700], [0, 65535]], dtype=np.uint16)
    path = tmp_path / "d.pgm"
    write_depth_pgm(path, data)
    raw = path.read_bytes()
    assert raw.endswith(bytes([0x01, 0x02, 0x02, 0xBC, 0x00, 0x00, 0xFF, 0xFF]))
    np.testing.assert_array_equal(dg.read_depth_file(path), data)


@needs_real
@pytest.mark.parametrize("view", [1, 2, 3, 4, 5])
def test_real_slambook_pgm(view):
    path = SLAMBOOK / f"{view}.pgm"
    depth = dg.read_depth_file(path)
    assert depth.shape == (480, 640) and depth.dtype == np.uint16
    # an independent reading of the same bytes: header is "P5 640 480 65535\n" then big-endian samples
    raw = path.read_bytes()
    header = b"P5 640 480 65535\n"
    assert raw.startswith(header)
    twin = np.frombuffer(raw, dtype=">u2", count=640 * 480, offset=len(header)).reshape(480, 640)
    np.testing.assert_array_equal(depth, twin)
    valid = depth[depth > 0]
    assert 0.68 <= valid.size / depth.size <= 0.735
    assert valid.min() >= 710 and valid.max() <= 9850  # millimetres: 0.71-9.8 m
    assert 2500 <= np.median(valid) <= 3300  # a room, not byte-swapped noise


@needs_real
def test_real_slambook_pgm_as_frame_of_its_camera():
    cam = dg.PinholeCamera("room", 640, 480, 518.0, 519.0, 325.5, 253.5, np.eye(4))
    frame = dg.load_depth(SLAMBOOK / "1.pgm", cam, timestamp=0.0)
    metres = frame.metres()
    ok = np.isfinite(metres)
    assert 0.68 <= ok.mean() <= 0.735
    assert frame.valid_fraction() == pytest.approx(ok.mean())
    assert 0.7 <= np.nanmin(metres) and np.nanmax(metres) <= 9.85


# --------------------------------------------------------------------------------------------------------------------
# TUM frame: 16-bit PNG in units of 0.2 mm


@needs_real
def test_real_tum_png_with_depth_scale():
    cam = dg.PinholeCamera("kinect", 640, 480, 525.0, 525.0, 319.5, 239.5, np.eye(4), depth_scale=0.0002)
    raw = dg.read_depth_file(TUM)
    assert raw.shape == (480, 640) and raw.dtype == np.uint16
    frame = dg.load_depth(TUM, cam)
    assert frame.depth_scale == 0.0002
    metres = frame.metres()
    ok = np.isfinite(metres)
    assert 0.80 <= ok.mean() <= 0.82
    assert np.nanmin(metres) == pytest.approx(1.46, abs=0.01)
    assert np.nanmax(metres) == pytest.approx(9.33, abs=0.01)
    # the same file read with the default millimetre scale would be 5x too near
    frame_mm = dg.load_depth(TUM, cam.replace(depth_scale=0.001))
    np.testing.assert_allclose(frame_mm.metres()[ok], metres[ok] * 5.0, rtol=1e-6)
    # the valid range of the camera cuts it: with depth_range (0.5, 4.0) the far pixels become invalid
    occ = dg.prepare_depth(frame, cam.replace(depth_range=(0.5, 4.0)), invalid="free")
    far = ok & (metres > 4.0)
    assert far.any()
    assert np.all(occ.invalid[far] == 1) and np.all(np.isinf(occ.z_start[far]))


# --------------------------------------------------------------------------------------------------------------------
# .npy and float TIFF


def test_npy_uint16_and_float(tmp_path):
    u16 = np.arange(20, dtype=np.uint16).reshape(4, 5) * 300
    np.save(tmp_path / "u.npy", u16)
    got = dg.read_depth_file(tmp_path / "u.npy")
    assert got.dtype == np.uint16
    np.testing.assert_array_equal(got, u16)

    f64 = np.linspace(0.0, 3.0, 20).reshape(4, 5)
    f64[1, 1], f64[2, 2] = np.nan, np.inf
    np.save(tmp_path / "f.npy", f64)
    got = dg.read_depth_file(tmp_path / "f.npy")
    assert got.dtype == np.float32
    np.testing.assert_array_equal(got, f64.astype(np.float32))


def test_npy_big_endian_uint16_is_read_by_value(tmp_path):
    data = np.array([[0x0102, 1000], [0, 65535]], dtype=">u2")
    np.save(tmp_path / "be.npy", data)
    got = dg.read_depth_file(tmp_path / "be.npy")
    np.testing.assert_array_equal(got, [[258, 1000], [0, 65535]])
    frame = dg.depth_image(got, make_camera(2, 2))
    assert frame.data.dtype == np.dtype("=u2")


class _Payload:
    """Unpickling this would create a marker file: the loader must never get that far."""

    def __init__(self, marker):
        self.marker = str(marker)

    def __reduce__(self):
        return (os.system, (f"echo hacked > {self.marker}",))


def test_npy_pickled_object_array_is_refused_without_running_it(tmp_path):
    marker = tmp_path / "HACKED"
    data = np.empty((2, 2), dtype=object)
    data[:] = 1.0
    data[0, 0] = _Payload(marker)
    path = tmp_path / "evil.npy"
    np.save(path, data, allow_pickle=True)
    with pytest.raises(dg.DepthImageError) as exc_info:
        dg.read_depth_file(path)
    assert "evil.npy" in str(exc_info.value)
    assert not marker.exists()


@pytest.mark.parametrize(
    "array, word",
    [
        (np.zeros((3, 4, 2), np.uint16), "2-D"),
        (np.zeros(5, np.float32), "2-D"),
        (np.zeros((0, 4), np.float32), "non-empty"),
        (np.zeros((3, 4), np.int32), "int32"),
        (np.zeros((3, 4), bool), "bool"),
        (np.zeros((3, 4), np.uint8), "uint8"),
    ],
)
def test_npy_wrong_shape_or_dtype_is_refused(tmp_path, array, word):
    path = tmp_path / "bad.npy"
    np.save(path, array)
    with pytest.raises(dg.DepthImageError) as exc_info:
        dg.read_depth_file(path)
    assert "bad.npy" in str(exc_info.value) and word in str(exc_info.value)


def test_float_tiff(tmp_path):
    data = np.array([[0.5, 1.25, np.nan], [0.0, np.inf, 7.0]], dtype=np.float32)
    path = tmp_path / "d.tif"
    Image.fromarray(data).save(path)
    got = dg.read_depth_file(path)
    assert got.dtype == np.float32
    np.testing.assert_array_equal(got, data)
    frame = dg.load_depth(path, make_camera(3, 2))
    assert frame.depth_scale == 1.0
    np.testing.assert_array_equal(np.isfinite(frame.metres()), [[True, True, False], [False, False, True]])


def test_uppercase_suffix_and_tiff_spelling(tmp_path):
    data = np.full((2, 2), 1234, np.uint16)
    write_depth_png(tmp_path / "D.PNG", data)
    np.testing.assert_array_equal(dg.read_depth_file(tmp_path / "D.PNG"), data)
    Image.fromarray(data.astype(np.float32)).save(tmp_path / "d.tiff")
    np.testing.assert_array_equal(dg.read_depth_file(tmp_path / "d.tiff"), data.astype(np.float32))


# --------------------------------------------------------------------------------------------------------------------
# corrupt, truncated, wrong-kind files: DepthImageError naming the file


def _png_bytes(tmp_path) -> bytes:
    path = tmp_path / "good.png"
    write_depth_png(path, (np.arange(64 * 48, dtype=np.uint16) % 5000).reshape(48, 64))
    return path.read_bytes()


BAD_FILES = {
    "truncated png": lambda tmp: ("d.png", _png_bytes(tmp)[: len(_png_bytes(tmp)) // 2]),
    "png header only": lambda tmp: ("d.png", _png_bytes(tmp)[:20]),
    "garbage png": lambda tmp: ("d.png", b"this is not a png at all"),
    "empty png": lambda tmp: ("d.png", b""),
    "garbage tiff": lambda tmp: ("d.tif", b"II*\x00garbage"),
    "truncated pgm pixels": lambda tmp: ("d.pgm", b"P5\n4 3\n65535\n" + b"\x00" * 23),
    "truncated pgm header": lambda tmp: ("d.pgm", b"P5\n4 3\n"),
    "empty pgm": lambda tmp: ("d.pgm", b""),
    "ascii pgm": lambda tmp: ("d.pgm", b"P2\n2 1\n65535\n1 2\n"),
    "ppm colour": lambda tmp: ("d.pgm", b"P6\n1 1\n255\n\x00\x00\x00"),
    "8-bit pgm": lambda tmp: ("d.pgm", b"P5\n2 2\n255\n\x01\x02\x03\x04"),
    "bad pgm size": lambda tmp: ("d.pgm", b"P5\n0 3\n65535\n"),
    "bad pgm maxval": lambda tmp: ("d.pgm", b"P5\n1 1\n70000\n\x00\x00\x00"),
    "non-numeric pgm header": lambda tmp: ("d.pgm", b"P5\nfour 3\n65535\n"),
    "empty npy": lambda tmp: ("d.npy", b""),
    "random npy": lambda tmp: ("d.npy", bytes(range(256))),
    "wrong suffix jpg": lambda tmp: ("d.jpg", _png_bytes(tmp)),
    "no suffix": lambda tmp: ("depth", _png_bytes(tmp)),
    "txt": lambda tmp: ("d.txt", b"1 2 3"),
}


@pytest.mark.filterwarnings("ignore:Corrupt EXIF data")
@pytest.mark.parametrize("case", BAD_FILES)
def test_bad_file_raises_depth_image_error_naming_the_file(tmp_path, case):
    name, content = BAD_FILES[case](tmp_path)
    path = tmp_path / name
    path.write_bytes(content)
    with pytest.raises(dg.DepthImageError) as exc_info:
        dg.read_depth_file(path)
    assert str(path) in str(exc_info.value)
    assert "\n" not in str(exc_info.value)


def test_png_header_claiming_a_gigantic_image_is_refused(tmp_path):
    import struct
    import zlib

    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    header = struct.pack(">IIBBBBB", 30000, 30000, 16, 0, 0, 0, 0)  # 900 M pixels of 16-bit grey
    path = tmp_path / "bomb.png"
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(b"\x00" * 64))
                     + chunk(b"IEND", b""))
    with pytest.raises(dg.DepthImageError, match="bomb.png"):
        dg.read_depth_file(path)


def test_npz_under_npy_name_is_refused(tmp_path):
    np.savez(tmp_path / "a.npz", depth=np.zeros((2, 2), np.uint16))
    (tmp_path / "a.npz").rename(tmp_path / "a.npy")
    with pytest.raises(dg.DepthImageError, match="a.npy"):
        dg.read_depth_file(tmp_path / "a.npy")


@pytest.mark.parametrize("mode", ["L", "RGB", "RGBA", "1"])
def test_8bit_and_colour_images_hold_no_depth(tmp_path, mode):
    path = tmp_path / f"d_{mode}.png"
    Image.new(mode, (4, 3)).save(path)
    with pytest.raises(dg.DepthImageError) as exc_info:
        dg.read_depth_file(path)
    assert str(path) in str(exc_info.value)
    assert "mode" in str(exc_info.value)


def test_missing_file_and_directory(tmp_path):
    for path in (tmp_path / "absent.png", tmp_path / "absent.pgm", tmp_path / "absent.npy"):
        with pytest.raises(dg.DepthImageError) as exc_info:
            dg.read_depth_file(path)
        assert str(path) in str(exc_info.value)
    folder = tmp_path / "folder.png"
    folder.mkdir()
    with pytest.raises(dg.DepthImageError, match="folder.png"):
        dg.read_depth_file(folder)


def test_load_depth_wrong_size_names_file_camera_and_field(tmp_path):
    path = tmp_path / "d.png"
    write_depth_png(path, np.ones((6, 7), np.uint16))
    with pytest.raises(dg.DepthImageError) as exc_info:
        dg.load_depth(path, make_camera(8, 6, name="wrist"))
    message = str(exc_info.value)
    assert "d.png" in message and "'wrist'" in message and "width/height" in message


# --------------------------------------------------------------------------------------------------------------------
# depth_image: a frame checked against its camera


@pytest.mark.parametrize("shape", [(6, 7), (5, 8), (8, 6), (1, 1)])
def test_depth_image_wrong_size(shape):
    with pytest.raises(dg.DepthImageError) as exc_info:
        dg.depth_image(np.ones(shape, np.float32), make_camera(8, 6, name="wrist"))
    exc = exc_info.value
    assert exc.camera == "wrist" and exc.field == "width/height"
    assert "'wrist'" in str(exc) and "width/height" in str(exc) and "8x6" in str(exc)


@pytest.mark.parametrize("shape", [(6, 8, 1), (6 * 8,), ()])
def test_depth_image_wrong_dimensions(shape):
    with pytest.raises(dg.DepthImageError) as exc_info:
        dg.depth_image(np.ones(shape, np.float32), make_camera(8, 6, name="wrist"))
    assert exc_info.value.camera == "wrist"
    assert "'wrist'" in str(exc_info.value)


@pytest.mark.parametrize("dtype", [np.int32, np.int16, np.uint8, np.uint32, bool, np.complex64, object])
def test_depth_image_wrong_dtype(dtype):
    with pytest.raises(dg.DepthImageError) as exc_info:
        dg.depth_image(np.ones((6, 8), dtype), make_camera(8, 6, name="wrist"))
    assert exc_info.value.field == "dtype"
    assert "'wrist'" in str(exc_info.value) and "dtype" in str(exc_info.value)


@pytest.mark.parametrize("timestamp", [math.nan, math.inf, "now", True])
def test_depth_image_bad_timestamp(timestamp):
    with pytest.raises(dg.DepthImageError) as exc_info:
        dg.depth_image(np.ones((6, 8), np.float32), make_camera(8, 6, name="wrist"), timestamp=timestamp)
    assert exc_info.value.field == "timestamp" and "'wrist'" in str(exc_info.value)


@pytest.mark.parametrize("dtype", [np.uint16, np.float32, np.float64])
def test_depth_image_is_a_read_only_copy(dtype):
    cam = make_camera(8, 6)
    source = np.full((6, 8), 2, dtype=dtype)
    frame = dg.depth_image(source, cam, timestamp=1.5)
    assert frame.timestamp == 1.5 and frame.camera == "cam"
    assert frame.data.dtype == (np.uint16 if dtype == np.uint16 else np.float32)
    assert not frame.data.flags.writeable
    with pytest.raises(ValueError):
        frame.data[0, 0] = 9
    source[:] = 0  # the caller reuses its buffer for the next frame
    assert np.all(frame.data == 2)
    assert not np.shares_memory(frame.data, source)


def test_depth_image_uint16_uses_camera_scale_float_is_metres():
    cam = make_camera(2, 1, depth_scale=0.0002)
    assert dg.depth_image(np.array([[5000, 0]], np.uint16), cam).metres()[0, 0] == pytest.approx(1.0)
    assert dg.depth_image(np.array([[5000, 0]], np.float64), cam).metres()[0, 0] == pytest.approx(5000.0)
    assert np.isnan(dg.depth_image(np.array([[5000, 0]], np.uint16), cam).metres()[0, 1])


# --------------------------------------------------------------------------------------------------------------------
# prepare_depth: invalid-pixel policies and the noise margin


def _frame(values, cam):
    return dg.depth_image(np.asarray(values), cam)


INVALID_VALUES = [np.nan, np.inf, -np.inf, 0.0, -1.0, 0.1, 9.0]  # 0.1 < min range 0.3, 9.0 > max range 5.0


@pytest.mark.parametrize("policy, expected", [("occupied", 0.3), ("free", np.inf)])
def test_invalid_pixels_occupied_from_min_range_or_free(policy, expected):
    cam = make_camera(len(INVALID_VALUES) + 1, 1, depth_range=(0.3, 5.0))
    row = np.array([INVALID_VALUES + [2.0]], dtype=np.float32)
    occ = dg.prepare_depth(_frame(row, cam), cam, invalid=policy)
    np.testing.assert_array_equal(occ.invalid[0], [1] * len(INVALID_VALUES) + [0])
    assert occ.invalid_pixels == len(INVALID_VALUES)
    np.testing.assert_array_equal(occ.z_start[0, :-1], np.float32(expected))
    assert occ.z_start[0, -1] == np.float32(2.0)
    assert occ.invalid_policy == policy
    assert occ.z_start.dtype == np.float32 and not occ.z_start.flags.writeable


def test_invalid_uint16_zero_and_out_of_range():
    cam = make_camera(4, 1, depth_range=(0.4, 4.0), depth_scale=0.001)
    occ = dg.prepare_depth(_frame(np.array([[0, 300, 2500, 4001]], np.uint16), cam), cam)
    np.testing.assert_array_equal(occ.invalid[0], [1, 1, 0, 1])
    np.testing.assert_array_equal(occ.z_start[0], np.float32([0.4, 0.4, 2.5, 0.4]))


def test_depth_range_limits_are_valid():
    cam = make_camera(2, 1, depth_range=(0.5, 3.0))
    occ = dg.prepare_depth(_frame(np.array([[0.5, 3.0]], np.float32), cam), cam, invalid="free")
    np.testing.assert_array_equal(occ.invalid[0], [0, 0])


def test_noise_margin_is_subtracted():
    noise = dg.NoiseModel(a=0.002, b=0.001, c=0.0025, k=3.0)
    cam = make_camera(5, 1, noise=noise, depth_range=(0.2, 10.0))
    d = np.array([0.5, 1.0, 2.0, 4.0, 8.0])
    occ = dg.prepare_depth(_frame(d[None].astype(np.float32), cam), cam)
    d32 = d.astype(np.float32).astype(np.float64)
    expected = d32 - 3.0 * (0.002 + 0.001 * d32 + 0.0025 * d32 ** 2)
    np.testing.assert_allclose(occ.z_start[0], expected, rtol=0, atol=1e-6)
    assert np.all(occ.z_start[0] < d)  # the margin moves every start towards the camera


def test_noise_margin_with_uint16_and_default_model():
    cam = make_camera(3, 1, noise=dg.NoiseModel(), depth_scale=0.0005)
    units = np.array([[1000, 4000, 12000]], np.uint16)  # 0.5, 2.0, 6.0 m
    occ = dg.prepare_depth(_frame(units, cam), cam)
    d = units[0] * 0.0005
    sigma = 0.0012 + 0.0019 * (d - 0.4) ** 2  # Nguyen et al., the default before its expansion
    np.testing.assert_allclose(occ.z_start[0], d - 3.0 * sigma, atol=1e-6)


def test_margin_never_makes_a_negative_start():
    cam = make_camera(1, 1, noise=dg.NoiseModel(a=1.0, b=0.0, c=0.0, k=1.0))
    occ = dg.prepare_depth(_frame(np.array([[0.5]], np.float32), cam), cam)
    assert occ.z_start[0, 0] == 0.0


def test_neighbors_fills_small_holes_from_their_own_surroundings():
    noise = dg.NoiseModel(a=0.01, b=0.0, c=0.0, k=1.0)  # a constant 1 cm margin
    cam = make_camera(12, 7, noise=noise, depth_range=(0.25, 9.0))
    depth = np.full((7, 12), 3.0, np.float32)
    # hole A: one NaN pixel at (row 2, col 2); its nearest surroundings include a 2.5 m pixel
    depth[2, 2] = np.nan
    depth[2, 3] = 2.5
    # hole B: two pixels (0 and inf) at (row 4, cols 8-9); around it 3.0 m and one 2.8 m pixel, diagonal
    depth[4, 8], depth[4, 9] = 0.0, np.inf
    depth[5, 10] = 2.8
    # a far-away nearer pixel must not leak into either hole
    depth[6, 0] = 1.0
    occ = dg.prepare_depth(_frame(depth, cam), cam, invalid="neighbors", hole_pixels=2)
    assert occ.invalid[2, 2] == 1 and occ.invalid[4, 8] == 1 and occ.invalid[4, 9] == 1
    assert occ.invalid_pixels == 3
    assert occ.z_start[2, 2] == pytest.approx(2.5 - 0.01, abs=1e-6)
    assert occ.z_start[4, 8] == pytest.approx(2.8 - 0.01, abs=1e-6)
    assert occ.z_start[4, 9] == pytest.approx(2.8 - 0.01, abs=1e-6)
    assert occ.z_start[6, 0] == pytest.approx(1.0 - 0.01, abs=1e-6)


def test_neighbors_large_hole_stays_at_min_range():
    cam = make_camera(10, 8, depth_range=(0.3, 9.0))
    depth = np.full((8, 10), 2.0, np.float32)
    depth[2:5, 3:6] = np.nan  # a 3x3 hole: 9 pixels
    depth[0, 0] = np.nan      # a 1-pixel hole
    for k, big_filled in ((8, False), (9, True)):
        occ = dg.prepare_depth(_frame(depth, cam), cam, invalid="neighbors", hole_pixels=k)
        assert occ.z_start[0, 0] == pytest.approx(2.0)
        expected = 2.0 if big_filled else 0.3
        np.testing.assert_allclose(occ.z_start[2:5, 3:6], expected, atol=1e-6)


def test_neighbors_all_invalid_stays_at_min_range():
    cam = make_camera(4, 3, depth_range=(0.3, 9.0))
    occ = dg.prepare_depth(_frame(np.full((3, 4), np.nan, np.float32), cam), cam, invalid="neighbors",
                           hole_pixels=100)
    np.testing.assert_array_equal(occ.z_start, np.float32(0.3))
    assert occ.invalid_pixels == 12


def test_neighbors_with_uint16_uses_depth_scale():
    cam = make_camera(3, 3, depth_scale=0.0002, depth_range=(0.1, 9.0))
    units = np.full((3, 3), 10000, np.uint16)  # 2.0 m
    units[1, 1] = 0
    units[0, 1] = 7500  # 1.5 m
    occ = dg.prepare_depth(_frame(units, cam), cam, invalid="neighbors", hole_pixels=1)
    assert occ.z_start[1, 1] == pytest.approx(1.5, abs=1e-6)


def test_block_minimum_bounds_every_pixel():
    rng = np.random.default_rng(11)
    cam = make_camera(37, 21, depth_range=(0.2, 8.0))
    depth = rng.uniform(0.5, 7.0, size=(21, 37)).astype(np.float32)
    depth[rng.random((21, 37)) < 0.1] = np.nan
    occ = dg.prepare_depth(_frame(depth, cam), cam, invalid="free")
    B = config.BLOCK_SIZE
    for i in range(occ.block_min.shape[0]):
        for j in range(occ.block_min.shape[1]):
            assert occ.block_min[i, j] == occ.z_start[i * B:(i + 1) * B, j * B:(j + 1) * B].min()


def test_prepare_depth_rejects_bad_policy_and_mismatched_camera():
    cam = make_camera(4, 3)
    frame = _frame(np.ones((3, 4), np.float32), cam)
    with pytest.raises(dg.InputError, match="invalid"):
        dg.prepare_depth(frame, cam, invalid="ignore")
    with pytest.raises(dg.InputError, match="'other'"):
        dg.prepare_depth(frame, make_camera(4, 3, name="other"))


def test_prepare_depth_does_not_change_the_frame():
    cam = make_camera(4, 3, depth_range=(0.3, 9.0))
    values = np.array([[np.nan, 1, 2, 3], [0, 1, 2, 3], [1, 1, 1, 1]], np.float32)
    frame = _frame(values, cam)
    dg.prepare_depth(frame, cam, invalid="neighbors")
    np.testing.assert_array_equal(frame.data, values)


# --------------------------------------------------------------------------------------------------------------------
# hostile depth files (issue 12): decoded only as the suffix says, bounded, checked before allocating


import io  # noqa: E402
import stat  # noqa: E402
import tracemalloc  # noqa: E402

from hypothesis import HealthCheck, given, settings, strategies as st  # noqa: E402
from PIL import EpsImagePlugin, ImageFile  # noqa: E402

import hostile  # noqa: E402
from depthguard.io import images as depth_io  # noqa: E402


@pytest.mark.parametrize("name", ["ps.png", "ps.PNG", "ps.tif", "ps.tiff"])
def test_postscript_under_an_image_name_starts_no_process(tmp_path, monkeypatch, name):
    # Pillow decodes by content: this file would reach its EPS plugin, whose loader looks for Ghostscript (running
    # ``gs --version``) and then runs it. Forget any earlier search so that a regression shows here.
    monkeypatch.setattr(EpsImagePlugin, "gs_binary", None)
    opened = []
    original = EpsImagePlugin.EpsImageFile._open
    monkeypatch.setattr(EpsImagePlugin.EpsImageFile, "_open", lambda self: (opened.append(1), original(self))[1])
    path = tmp_path / name
    path.write_bytes(hostile.EPS)
    with hostile.no_process_started(), pytest.raises(dg.DepthImageError) as exc_info:
        dg.read_depth_file(path)
    assert str(path) in str(exc_info.value)
    assert not opened, "the EPS plugin saw the file"


@pytest.mark.parametrize("suffix, other", [(".png", "tif"), (".tif", "png"), (".tiff", "png")])
def test_the_suffix_decides_the_format(tmp_path, suffix, other):
    data = np.full((3, 4), 1234, np.uint16)
    source = tmp_path / f"real.{other}"
    Image.fromarray(data).save(source)  # a valid image of the other format
    path = tmp_path / f"d{suffix}"
    path.write_bytes(source.read_bytes())
    with pytest.raises(dg.DepthImageError, match=f"d{suffix}"):
        dg.read_depth_file(path)


@pytest.mark.parametrize("name", ["fifo.png", "fifo.tif", "fifo.pgm", "fifo.npy"])
def test_fifo_is_refused_promptly(tmp_path, name):
    path = tmp_path / name
    os.mkfifo(path)  # nobody writes: opening it for reading would wait forever
    with hostile.deadline(5), pytest.raises(dg.DepthImageError) as exc_info:
        dg.read_depth_file(path)
    assert str(path) in str(exc_info.value) and "regular file" in str(exc_info.value)


@pytest.mark.parametrize("device", ["/dev/zero", "/dev/urandom"])
def test_device_behind_a_symlink_is_refused(tmp_path, device):
    if not os.path.exists(device) or not stat.S_ISCHR(os.stat(device).st_mode):
        pytest.skip(f"{device} is not available")
    path = tmp_path / "frame.npy"
    path.symlink_to(device)
    with hostile.deadline(5), pytest.raises(dg.DepthImageError, match="regular file"):
        dg.read_depth_file(path)


def test_file_over_the_size_cap_is_refused(tmp_path, monkeypatch):
    path = tmp_path / "d.png"
    write_depth_png(path, np.ones((6, 8), np.uint16))
    monkeypatch.setattr(config, "MAX_DEPTH_FILE_BYTES", path.stat().st_size - 1)
    with pytest.raises(dg.DepthImageError, match="more than"):
        dg.read_depth_file(path)
    monkeypatch.setattr(config, "MAX_DEPTH_FILE_BYTES", path.stat().st_size)
    np.testing.assert_array_equal(dg.read_depth_file(path), np.ones((6, 8), np.uint16))


HUGE_SHAPES = [(10**12, 10**12), (2**62, 2), (-1, 5), (5, -1), (-(10**12), -(10**12)), (0, 5), (5, 0), (16385, 1),
               (1, 16385)]


@pytest.mark.parametrize("shape", HUGE_SHAPES)
@pytest.mark.parametrize("descr", ["<u2", "<f4"])
def test_npy_header_claiming_a_huge_or_negative_shape_allocates_nothing(tmp_path, shape, descr):
    path = tmp_path / "claim.npy"
    path.write_bytes(hostile.npy_bytes(descr, shape, payload=b"\x00" * 64))
    tracemalloc.start()
    try:
        with pytest.raises(dg.DepthImageError) as exc_info:
            dg.read_depth_file(path)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert "claim.npy" in str(exc_info.value)
    assert peak < 4 << 20, f"{peak} bytes allocated for a refused header"  # read_bytes reads in 1 MiB chunks


@pytest.mark.parametrize("claimed", [(480, 640), (16384, 16384)])
def test_size_other_than_the_camera_is_refused_before_reading_pixels(tmp_path, monkeypatch, claimed):
    """The header's size is compared with the camera before any pixel is decoded: nothing as large as the claimed
    image is allocated (npy, pgm), and Pillow's decoder never runs (png)."""
    camera = make_camera(8, 6, name="wrist")
    h, w = claimed
    files = {"claim.npy": hostile.npy_bytes("<u2", claimed, payload=b"\x00" * 64),
             "claim.pgm": f"P5\n{w} {h}\n65535\n".encode() + b"\x00" * 64,
             "claim.png": hostile.png_bytes(w, h)}
    loads = []
    monkeypatch.setattr(ImageFile.ImageFile, "load", lambda self: loads.append(1))
    for name, content in files.items():
        path = tmp_path / name
        path.write_bytes(content)
        tracemalloc.start()
        try:
            with pytest.raises(dg.DepthImageError) as exc_info:
                dg.read_depth_file(path, camera)
            _, peak = tracemalloc.get_traced_memory()
        finally:
            tracemalloc.stop()
        exc = exc_info.value
        assert exc.camera == "wrist" and exc.field == "width/height", str(exc)
        assert name in str(exc) and f"{w}x{h}" in str(exc) and "8x6" in str(exc)
        assert peak < 4 << 20  # 16384 x 16384 x 2 bytes would be 512 MiB
    assert not loads, "the PNG decoder ran for an image of the wrong size"


def test_read_depth_file_with_the_right_camera(tmp_path):
    data = (np.arange(48, dtype=np.uint16) * 100).reshape(6, 8)
    camera = make_camera(8, 6)
    for name, write in (("d.png", write_depth_png), ("d.pgm", write_depth_pgm), ("d.npy", np.save)):
        write(tmp_path / name, data)
        np.testing.assert_array_equal(dg.read_depth_file(tmp_path / name, camera), data)


@pytest.mark.filterwarnings("ignore::PIL.Image.DecompressionBombWarning")
def test_image_within_the_side_limit_but_over_pillows_pixel_limit_is_refused(tmp_path, monkeypatch):
    loads = []
    monkeypatch.setattr(ImageFile.ImageFile, "load", lambda self: loads.append(1))
    side = int((Image.MAX_IMAGE_PIXELS * 1.5) ** 0.5)  # above the limit, below twice it (where Pillow refuses)
    assert side <= config.MAX_IMAGE_SIDE
    path = tmp_path / "big.png"
    path.write_bytes(hostile.png_bytes(side, side))
    with pytest.raises(dg.DepthImageError, match="decompression-bomb"):
        dg.read_depth_file(path)
    assert not loads


@pytest.mark.parametrize(
    "descr, word",
    [("|O", "object"), ([("a", "<u2")], "dtype"), ("<i4", "int32"), ("|b1", "bool"), ("<c8", "complex"),
     ("<M8[s]", "datetime"), ("|V4", "V4"), ("|u1", "uint8"), ("<u4", "uint32"), ("<i2", "int16")],
)
def test_npy_dtypes_other_than_uint16_and_float_are_refused_from_the_header(tmp_path, descr, word):
    path = tmp_path / "dtype.npy"
    path.write_bytes(hostile.npy_bytes(descr, (2, 2), payload=b"\x00" * 64))
    with pytest.raises(dg.DepthImageError) as exc_info:
        dg.read_depth_file(path)
    assert "dtype.npy" in str(exc_info.value) and word in str(exc_info.value)


def test_npy_subarray_dtype_is_refused(tmp_path):
    path = tmp_path / "sub.npy"
    path.write_bytes(hostile.npy_bytes("<u2", (2, 2), header="{'descr': ('<u2', (2,)), 'fortran_order': False, "
                                                            "'shape': (2, 2), }", payload=b"\x00" * 16))
    with pytest.raises(dg.DepthImageError, match="sub.npy"):
        dg.read_depth_file(path)


@pytest.mark.parametrize(
    "descr, values, expected",
    [("<u2", b"\x01\x02\x03\x04", [[0x0201, 0x0403]]),
     (">u2", b"\x01\x02\x03\x04", [[0x0102, 0x0304]]),
     ("<f2", b"\x00\x3c\x00\x40", [[1.0, 2.0]]),  # IEEE half precision: 0x3c00 = 1.0, 0x4000 = 2.0
     (">f4", b"\x3f\xc0\x00\x00\x7f\xc0\x00\x00", [[1.5, np.nan]]),
     ("<f8", b"\x00" * 7 + b"\x40" + b"\x00" * 6 + b"\xf0\x7f", [[2.0, np.inf]])],
)
def test_npy_by_hand_is_read_by_value(tmp_path, descr, values, expected):
    path = tmp_path / "hand.npy"
    path.write_bytes(hostile.npy_bytes(descr, (1, 2), payload=values))
    got = dg.read_depth_file(path)
    assert got.dtype == (np.uint16 if descr[1] == "u" else np.float32)
    np.testing.assert_array_equal(got, np.array(expected, dtype=got.dtype))


def test_npy_fortran_order_is_read_by_index(tmp_path):
    # shape (2, 3) in Fortran order: the data runs down the columns
    payload = np.array([1, 4, 2, 5, 3, 6], dtype="<u2").tobytes()
    path = tmp_path / "f.npy"
    path.write_bytes(hostile.npy_bytes("<u2", (2, 3), fortran_order=True, payload=payload))
    got = dg.read_depth_file(path)
    np.testing.assert_array_equal(got, [[1, 2, 3], [4, 5, 6]])
    assert got.flags.c_contiguous


@pytest.mark.parametrize(
    "content, word",
    [(hostile.npy_bytes("<u2", (2, 3), payload=b"\x00" * 11), "truncated"),
     (hostile.npy_bytes("<u2", (2, 3), payload=b"\x00" * 13), "trailing"),
     (hostile.npy_bytes("<u2", (2, 3)), "truncated"),
     (hostile.npy_bytes("<u2", (2, 3), payload=b"\x00" * 12, version=(2, 0))[:-1], "truncated"),
     (hostile.npy_bytes("<u2", (2, 3), payload=b"\x00" * 12, version=(3, 0)), "version"),
     (hostile.npy_bytes("<u2", (2, 3), payload=b"\x00" * 12, version=(9, 9)), "npy"),
     (hostile.npy_bytes("", (), header="[1, 2, 3]", payload=b"\x00" * 12), "npy"),
     (hostile.npy_bytes("", (), header="{'descr': '<u2', 'shape': (2, 3)}", payload=b"\x00" * 12), "npy"),
     (hostile.npy_bytes("", (), header="{'descr': '<u2', 'fortran_order': False, 'shape': (2.0, 3), }",
                        payload=b"\x00" * 12), "npy"),
     (hostile.npy_bytes("", (), header="{'descr': 'not a dtype', 'fortran_order': False, 'shape': (2, 3), }",
                        payload=b"\x00" * 12), "npy"),
     (hostile.npy_bytes("", (), header="__import__('os').system('echo hacked')", payload=b"\x00" * 12), "npy"),
     (hostile.npy_bytes("", (), header="{" * 5000, payload=b"\x00" * 12), "npy"),
     (hostile.npy_bytes("", (), header="{'descr': '<u2', 'fortran_order': False, 'shape': (2, 3), }" + " " * 20000,
                        version=(2, 0), payload=b"\x00" * 12), "npy"),
     (b"\x93NUMPY\x01", "npy"),
     (b"\x93NUMPY\x01\x00\xff\xff{", "npy"),
     (b"\x93NUMPY\x02\x00\xff\xff\xff\xff{", "npy")],
)
def test_npy_malformed_or_truncated_is_refused(tmp_path, content, word):
    path = tmp_path / "bad.npy"
    path.write_bytes(content)
    with hostile.no_process_started(), pytest.raises(dg.DepthImageError) as exc_info:
        dg.read_depth_file(path)
    assert "bad.npy" in str(exc_info.value) and word in str(exc_info.value)
    assert "\n" not in str(exc_info.value)


def _npz_bytes(tmp_path) -> bytes:
    np.savez(tmp_path / "a.npz", depth=np.zeros((2, 2), np.uint16))
    return (tmp_path / "a.npz").read_bytes()


@pytest.mark.parametrize("cut", [None, 40, 4, 0])
def test_npz_whole_or_truncated_under_an_npy_name_is_refused(tmp_path, cut):
    content = _npz_bytes(tmp_path)
    path = tmp_path / "z.npy"
    path.write_bytes(content if cut is None else content[:cut])
    with pytest.raises(dg.DepthImageError, match="z.npy"):
        dg.read_depth_file(path)


def _valid_files(tmp_path) -> dict[str, tuple[bytes, np.ndarray]]:
    """name -> (bytes of a valid small depth file, the array it holds)."""
    u16 = (np.arange(35, dtype=np.uint16) * 1234).reshape(5, 7)
    f32 = np.linspace(0.25, 4.0, 35, dtype=np.float32).reshape(5, 7)
    files = {}
    for name, write, data in (("d.png", write_depth_png, u16), ("d.pgm", write_depth_pgm, u16),
                              ("d.npy", np.save, u16), ("f.npy", np.save, f32),
                              ("d.tif", lambda p, a: Image.fromarray(a).save(p), u16),
                              ("f.tif", lambda p, a: Image.fromarray(a).save(p), f32)):
        write(tmp_path / name, data)
        files[name] = ((tmp_path / name).read_bytes(), data)
    return files


@pytest.mark.filterwarnings("ignore:Corrupt EXIF data", "ignore:Possibly corrupt EXIF", "ignore:Truncated File")
def test_every_truncation_is_refused_or_reads_the_same_image(tmp_path):
    """A file cut anywhere gives DepthImageError, or (a PNG missing only its end marker, a TIFF missing only unread
    trailing bytes) the complete image: never another exception, never other values."""
    for name, (content, data) in _valid_files(tmp_path).items():
        path = tmp_path / f"cut_{name}"
        for length in range(len(content)):
            path.write_bytes(content[:length])
            try:
                got = dg.read_depth_file(path)
            except dg.DepthImageError as exc:
                assert str(path) in str(exc)
                continue
            np.testing.assert_array_equal(got, data, err_msg=f"{name} cut to {length} bytes")


@pytest.mark.filterwarnings("ignore::UserWarning")
@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_corrupted_files_give_depth_image_error_or_an_image(tmp_path, data):
    """Bytes flipped or overwritten anywhere: DepthImageError or a 2-D uint16/float32 array of the image's size
    (raw formats hold no checksum, so changed pixel values are possible), never another exception."""
    files = _valid_files(tmp_path)
    name = data.draw(st.sampled_from(sorted(files)))
    content = bytearray(files[name][0])
    for _ in range(data.draw(st.integers(1, 4))):
        where = data.draw(st.integers(0, len(content) - 1))
        content[where] = data.draw(st.integers(0, 255))
    path = tmp_path / f"fuzz_{name}"
    path.write_bytes(bytes(content))
    with hostile.no_process_started():
        try:
            got = dg.read_depth_file(path)
        except dg.DepthImageError as exc:
            assert str(path) in str(exc) and "\n" not in str(exc)
            return
    assert got.ndim == 2 and got.dtype in (np.uint16, np.float32)
    assert got.size <= config.MAX_IMAGE_SIDE ** 2


def test_npy_header_parser_reads_numpys_own_files():
    for array in (np.zeros((3, 4), "<u2"), np.zeros((1, 1), ">f8"), np.zeros((2, 5), "<f4", order="F")):
        buffer = io.BytesIO()
        np.save(buffer, array)
        raw = buffer.getvalue()
        shape, fortran_order, dtype, offset = depth_io.npy_header(raw)
        assert shape == array.shape and dtype == array.dtype
        assert fortran_order == (array.flags.f_contiguous and not array.flags.c_contiguous)
        assert len(raw) - offset == array.nbytes


@pytest.mark.parametrize("compression", ["tiff_deflate", "tiff_lzw", "tiff_adobe_deflate"])
def test_compressed_tiff_is_read_by_value(tmp_path, compression):
    data = np.linspace(0.5, 3.0, 12, dtype=np.float32).reshape(3, 4)
    data[1, 2] = np.nan
    Image.fromarray(data).save(tmp_path / "c.tif", compression=compression)
    np.testing.assert_array_equal(dg.read_depth_file(tmp_path / "c.tif"), data)


def test_load_depth_refuses_a_wrong_size_before_decoding(tmp_path, monkeypatch):
    loads = []
    monkeypatch.setattr(ImageFile.ImageFile, "load", lambda self: loads.append(1))
    path = tmp_path / "wide.png"
    path.write_bytes(hostile.png_bytes(16000, 12000))
    with pytest.raises(dg.DepthImageError) as exc_info:
        dg.load_depth(path, make_camera(8, 6, name="wrist"))
    assert exc_info.value.camera == "wrist" and exc_info.value.field == "width/height"
    assert "wide.png" in str(exc_info.value)
    assert not loads
