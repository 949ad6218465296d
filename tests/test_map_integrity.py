"""The depth grid map is derived data, never trusted silently (issue 12).

Maps here are written by hand from the documented format (three plain arrays in an .npz, a JSON header whose sha256
covers the other fields' canonical JSON and the arrays' bytes), so that a test can forge a map whose checksum is
right and whose content is wrong. Expected outcomes follow from the rule: a corrupt, altered or mismatched map is a
MapError naming the file, whatever the change; a map that loads is the map that was written.
"""

from __future__ import annotations

import hashlib
import json
import os
import stat
import tracemalloc
import zipfile

import numpy as np
import pytest

import depthguard as dg
import hostile
from depthguard import config
from depthguard.cli import main
from depthguard.depth import write_depth_png
from depthguard.depthgrid import DepthGridMap, MapError, build_map, load_map, save_map
from depthguard.errors import InputError
from depthguard.transforms import look_at

FORMAT = "depthguard-depth-grid-map/2"


def small_rig(width=8, height=6, side_eye=(0.0, 2.5, 1.4)) -> dg.Rig:
    f = 7.0 * width / 8
    cams = {name: dg.PinholeCamera(name, width, height, f, f, (width - 1) / 2, (height - 1) / 2,
                                   look_at(eye, [0, 0, 0.6]), depth_range=(0.3, 6.0))
            for name, eye in (("p", [2.5, 0.0, 1.4]), ("s", side_eye))}
    return dg.Rig(cams, principal="p")


def fields_of(grid: DepthGridMap) -> dict:
    height, width = grid.corners.shape[1] - 1, grid.corners.shape[2] - 1
    return dict(format=FORMAT, rig_fingerprint=grid.rig_fingerprint, principal=grid.principal,
                secondaries=list(grid.secondaries), d_min=grid.d_min, delta_d=grid.delta_d, n_cells=grid.n_cells,
                width=width, height=height, secondary_sizes=[list(size) for size in grid.secondary_sizes])


def checksum(fields: dict, corners, offsets) -> str:
    """The documented checksum, computed here independently of the loader."""
    canonical = json.dumps({k: v for k, v in fields.items() if k != "sha256"}, sort_keys=True, separators=(",", ":"))
    digest = hashlib.sha256(canonical.encode("utf-8"))
    digest.update(np.asarray(corners, dtype="<f8").tobytes(order="C"))
    digest.update(np.asarray(offsets, dtype="<f8").tobytes(order="C"))
    return digest.hexdigest()


def write_map(path, fields: dict, corners, offsets, *, sign=True, header_text=None, save=np.savez, **extra):
    """A map file by hand: ``sign`` recomputes the checksum over what is written (a forger's map)."""
    fields = dict(fields)
    if sign:
        fields["sha256"] = checksum(fields, corners, offsets)
    text = json.dumps(fields) if header_text is None else header_text
    with open(path, "wb") as f:
        save(f, header=np.frombuffer(text.encode("utf-8"), np.uint8), corners=corners, offsets=offsets, **extra)
    return path


def refused(path, rig=None, *words):
    with hostile.deadline(10), hostile.no_process_started(), pytest.raises(MapError) as exc_info:
        load_map(path, rig)
    message = str(exc_info.value)
    assert str(path) in message and "\n" not in message, message
    for word in words:
        assert word in message, message
    return message


@pytest.fixture(scope="module")
def rig():
    return small_rig()


@pytest.fixture(scope="module")
def grid(rig):
    return build_map(rig)


# --------------------------------------------------------------------------------------------------------------------
# what a good map holds


def test_saved_map_follows_the_documented_format(tmp_path, rig, grid):
    path = tmp_path / "map.npz"
    save_map(grid, path)
    with zipfile.ZipFile(path) as archive:
        assert sorted(archive.namelist()) == ["corners.npy", "header.npy", "offsets.npy"]
        with archive.open("header.npy") as f:
            header = json.loads(np.load(f, allow_pickle=False).tobytes().decode("utf-8"))
        with archive.open("corners.npy") as f:
            corners = np.load(f, allow_pickle=False)
        with archive.open("offsets.npy") as f:
            offsets = np.load(f, allow_pickle=False)
    assert corners.dtype == np.dtype("<f8") and offsets.dtype == np.dtype("<f8")
    assert header["format"] == FORMAT and header["rig_fingerprint"] == rig.fingerprint()
    assert header["principal"] == "p" and header["secondaries"] == ["s"]
    assert (header["width"], header["height"]) == (8, 6) and header["secondary_sizes"] == [[8, 6]]
    assert header["d_min"] == grid.d_min and header["n_cells"] == grid.n_cells and header["delta_d"] == grid.delta_d
    assert header["sha256"] == checksum(header, corners, offsets)
    again = load_map(path, rig)
    assert np.array_equal(again.corners, grid.corners) and np.array_equal(again.offsets, grid.offsets)
    assert (again.d_min, again.delta_d, again.n_cells) == (grid.d_min, grid.delta_d, grid.n_cells)
    assert again.secondary_sizes == ((8, 6),)


def test_map_arrays_are_read_only(grid, tmp_path, rig):
    save_map(grid, tmp_path / "map.npz")
    for g in (grid, load_map(tmp_path / "map.npz", rig)):
        for array in (g.corners, g.offsets):
            with pytest.raises(ValueError):
                array[0] = 1.0


def test_a_compressed_map_is_read_too(tmp_path, rig, grid):
    path = write_map(tmp_path / "deflated.npz", fields_of(grid), grid.corners, grid.offsets, save=np.savez_compressed)
    assert np.array_equal(load_map(path, rig).corners, grid.corners)


# --------------------------------------------------------------------------------------------------------------------
# corruption


def test_every_flipped_bit_is_refused_or_changes_nothing(tmp_path, rig, grid):
    """One bit flipped anywhere in the file (a bit of each byte, cycling through the 8 positions): a MapError, or
    (a bit in zip bookkeeping that no reader uses) exactly the same map. Never another map."""
    good = tmp_path / "map.npz"
    save_map(grid, good)
    content = good.read_bytes()
    path = tmp_path / "flipped.npz"
    refusals = 0
    for i in range(len(content)):
        flipped = bytearray(content)
        flipped[i] ^= 1 << (i % 8)
        path.write_bytes(bytes(flipped))
        try:
            got = load_map(path, rig)
        except MapError as exc:
            assert str(path) in str(exc) and "\n" not in str(exc)
            refusals += 1
            continue
        assert np.array_equal(got.corners, grid.corners) and np.array_equal(got.offsets, grid.offsets), i
        assert (got.principal, got.secondaries, got.d_min, got.delta_d, got.n_cells, got.secondary_sizes) == \
            (grid.principal, grid.secondaries, grid.d_min, grid.delta_d, grid.n_cells, grid.secondary_sizes), i
    assert refusals > 0.8 * len(content)


def test_every_flipped_bit_of_the_arrays_or_header_is_refused(tmp_path, rig, grid):
    """Flips inside what the map says (header text, array bytes) are always refused, whatever the bit."""
    good = tmp_path / "map.npz"
    save_map(grid, good)
    content = good.read_bytes()
    markers = [content.index(b'"d_min"'), content.index(grid.corners.tobytes()[:64])]
    path = tmp_path / "flipped.npz"
    for start in markers:
        for i in range(start, start + 64):
            for bit in range(8):
                flipped = bytearray(content)
                flipped[i] ^= 1 << bit
                path.write_bytes(bytes(flipped))
                refused(path)


def test_wrong_checksum_is_refused(tmp_path, grid):
    corners = grid.corners.copy()
    corners[0, 2, 3, 1] += 1e-3
    fields = fields_of(grid)
    fields["sha256"] = checksum(fields, grid.corners, grid.offsets)  # the original map's checksum
    path = write_map(tmp_path / "edited.npz", fields, corners, grid.offsets, sign=False)
    refused(path, None, "checksum")
    fields["d_min"] = grid.d_min + 0.01  # a header value changed, arrays kept
    path = write_map(tmp_path / "edited2.npz", fields, grid.corners, grid.offsets, sign=False)
    refused(path, None, "checksum")


@pytest.mark.parametrize("value", [np.nan, np.inf, -np.inf])
@pytest.mark.parametrize("where", ["corners", "offsets"])
def test_values_that_are_not_finite_are_refused_even_when_signed(tmp_path, grid, rig, value, where):
    arrays = {"corners": grid.corners.copy(), "offsets": grid.offsets.copy()}
    arrays[where].reshape(-1)[2] = value
    path = write_map(tmp_path / "nan.npz", fields_of(grid), arrays["corners"], arrays["offsets"])
    refused(path, None, "finite")
    refused(path, rig, "finite")


def test_one_edited_corner_with_a_recomputed_checksum_is_refused(tmp_path, grid, rig):
    corners = grid.corners.copy()
    corners[0, 3, 4, 0] *= 1 + 1e-6  # a tiny nudge of one footprint corner
    path = write_map(tmp_path / "edited.npz", fields_of(grid), corners, grid.offsets)
    refused(path, None, "pinhole")  # not an affine grid: caught without the rig
    refused(path, rig)


@pytest.mark.parametrize("edit", ["scale corners", "shift offsets", "other rig's geometry"])
def test_a_consistent_forgery_is_caught_with_the_rig(tmp_path, grid, rig, edit):
    """A forged map whose corners still form a pinhole grid, with a recomputed checksum and the right fingerprint,
    is caught when the rig is given: its geometry is rebuilt and compared."""
    corners, offsets = grid.corners.copy(), grid.offsets.copy()
    if edit == "scale corners":
        corners *= 1.001
    elif edit == "shift offsets":
        offsets[0, 0] += 0.5  # half a pixel
    else:
        other = build_map(small_rig(side_eye=(0.05, 2.5, 1.4)))  # the side camera 5 cm away
        corners, offsets = other.corners.copy(), other.offsets.copy()
    path = write_map(tmp_path / "forged.npz", fields_of(grid), corners, offsets)
    refused(path, rig, "rig's geometry")
    forged = DepthGridMap(**{**_grid_fields(grid), "corners": corners, "offsets": offsets})
    with pytest.raises(MapError, match="rig's geometry"):
        forged.check_rig(rig)
    with pytest.raises(MapError, match="rig's geometry"):
        dg.DistanceMonitor(rig, maps={"p": forged})


def test_swapped_principal_is_caught_with_the_rig(tmp_path, grid, rig):
    fields = fields_of(grid)
    fields["principal"], fields["secondaries"] = "s", ["p"]
    path = write_map(tmp_path / "swapped.npz", fields, grid.corners, grid.offsets)
    refused(path, rig)


def test_a_map_of_another_rig_is_refused(tmp_path, grid):
    save_map(grid, tmp_path / "map.npz")
    refused(tmp_path / "map.npz", small_rig(side_eye=(0.05, 2.5, 1.4)), "another rig")


def _grid_fields(grid):
    return dict(rig_fingerprint=grid.rig_fingerprint, principal=grid.principal, secondaries=grid.secondaries,
                d_min=grid.d_min, delta_d=grid.delta_d, n_cells=grid.n_cells, corners=grid.corners,
                offsets=grid.offsets, secondary_sizes=grid.secondary_sizes)


def test_check_rig_accepts_the_true_map_and_a_rebuild(grid, rig):
    grid.check_rig(rig)
    grid.check_rig(rig)  # remembered
    DepthGridMap(**_grid_fields(grid)).check_rig(small_rig())  # an equal rig, another object


# --------------------------------------------------------------------------------------------------------------------
# header fields: checked with a correct checksum, so that only the range check can refuse them


@pytest.mark.parametrize(
    "change, word",
    [(dict(d_min=0.0), "d_min"), (dict(d_min=-0.3), "d_min"), (dict(d_min="0.3"), "d_min"),
     (dict(d_min=True), "d_min"), (dict(delta_d=0.0), "delta_d"), (dict(delta_d=1e-9), "delta_d"),
     (dict(delta_d=-0.01), "delta_d"), (dict(n_cells=0), "n_cells"), (dict(n_cells=4097), "n_cells"),
     (dict(n_cells=343.0), "n_cells"), (dict(n_cells=True), "n_cells"), (dict(n_cells=10**400), "n_cells"),
     (dict(d_min=9999.0, n_cells=343), "n_cells"), (dict(width=9), "shape"), (dict(height=0), "height"),
     (dict(width=10**6), "width"), (dict(secondaries=[]), "secondaries"), (dict(secondaries=["p"]), "secondaries"),
     (dict(secondaries=["s", "s"]), "secondaries"), (dict(secondaries=[7]), "secondaries"),
     (dict(secondary_sizes=[[8]]), "secondary_sizes"), (dict(secondary_sizes=[[0, 6]]), "secondary_sizes"),
     (dict(principal=""), "principal"), (dict(rig_fingerprint="abc"), "rig_fingerprint"),
     (dict(format="depthguard-depth-grid-map/1"), "older format"), (dict(format="something else"), "format"),
     (dict(extra=1), "keys")],
)
def test_header_values_out_of_range_are_refused(tmp_path, grid, change, word):
    fields = {**fields_of(grid), **change}
    path = write_map(tmp_path / "header.npz", fields, grid.corners, grid.offsets)
    refused(path, None, word)


@pytest.mark.parametrize(
    "text",
    ['{"format": "depthguard-depth-grid-map/2", "format": "depthguard-depth-grid-map/2"}',
     '{"format": "depthguard-depth-grid-map/2", "d_min": NaN}',
     "[" * 100_000 + "]" * 100_000,
     '"just a string"',
     "{not json",
     "\udcff"],
)
def test_malformed_header_text_is_refused(tmp_path, grid, text):
    path = tmp_path / "header.npz"
    with open(path, "wb") as f:
        np.savez(f, header=np.frombuffer(text.encode("utf-8", "surrogateescape"), np.uint8), corners=grid.corners,
                 offsets=grid.offsets)
    refused(path)


def test_missing_header_key_is_refused(tmp_path, grid):
    fields = fields_of(grid)
    del fields["secondary_sizes"]
    refused(write_map(tmp_path / "header.npz", fields, grid.corners, grid.offsets), None, "keys")


# --------------------------------------------------------------------------------------------------------------------
# archive members: names, dtypes and shapes from their headers, before any array is read


def test_pickled_header_runs_no_code(tmp_path, grid):
    marker = tmp_path / "HACKED"

    class Payload:
        def __reduce__(self):
            return (os.system, (f"echo hacked > {marker}",))

    path = tmp_path / "evil.npz"
    np.savez(path, header=np.array([Payload()], dtype=object), corners=grid.corners, offsets=grid.offsets)
    refused(path)
    assert not marker.exists()


@pytest.mark.parametrize(
    "members, word",
    [(lambda g: dict(corners=g.corners, offsets=g.offsets), "members"),
     (lambda g: dict(corners=g.corners, offsets=g.offsets, extra=np.zeros(1)), "members"),
     (lambda g: dict(corners=g.corners.astype(np.float32), offsets=g.offsets), "corners"),
     (lambda g: dict(corners=g.corners.astype(">f8"), offsets=g.offsets), "corners"),
     (lambda g: dict(corners=np.asfortranarray(g.corners), offsets=g.offsets), "Fortran"),
     (lambda g: dict(corners=g.corners[:, :-1], offsets=g.offsets), "corners"),
     (lambda g: dict(corners=g.corners, offsets=g.offsets[:, :2]), "offsets")],
)
def test_wrong_members_are_refused(tmp_path, grid, members, word):
    arrays = members(grid)
    header = json.dumps({**fields_of(grid), "sha256": "0" * 64})
    path = tmp_path / "members.npz"
    np.savez(path, header=np.frombuffer(header.encode(), np.uint8), **arrays)
    refused(path, None, word)


@pytest.mark.parametrize("shape", [(1, 10**6 + 1, 10**6 + 1, 3), (1, -7, 9, 3), (10**9, 7, 9, 3)])
def test_member_header_claiming_a_huge_array_allocates_nothing(tmp_path, grid, shape):
    fake = hostile.npy_bytes("<f8", shape, payload=b"\x00" * 64)
    fields = fields_of(grid)
    fields["sha256"] = "0" * 64
    path = tmp_path / "huge.npz"
    with zipfile.ZipFile(path, "w") as archive:
        archive.writestr("header.npy", hostile.npy_bytes("|u1", (len(json.dumps(fields)),),
                                                          payload=json.dumps(fields).encode()))
        archive.writestr("corners.npy", fake)
        archive.writestr("offsets.npy", hostile.npy_bytes("<f8", (1, 3), payload=b"\x00" * 24))
    tracemalloc.start()
    try:
        refused(path, None, "corners")
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 4 << 20


def test_header_claiming_a_huge_image_is_refused_before_reading(tmp_path, grid):
    fields = {**fields_of(grid), "width": config.MAX_IMAGE_SIDE, "height": config.MAX_IMAGE_SIDE,
              "secondaries": [f"s{i}" for i in range(20)], "secondary_sizes": [[8, 6]] * 20}
    path = write_map(tmp_path / "huge.npz", fields, grid.corners, grid.offsets)
    tracemalloc.start()
    try:
        refused(path)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 4 << 20


def test_unsupported_compression_is_refused(tmp_path, grid):
    path = tmp_path / "bz2.npz"
    fields = {**fields_of(grid)}
    fields["sha256"] = checksum(fields, grid.corners, grid.offsets)
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_BZIP2) as archive:
        for name, array in (("header", np.frombuffer(json.dumps(fields).encode(), np.uint8)),
                            ("corners", grid.corners), ("offsets", grid.offsets)):
            with archive.open(f"{name}.npy", "w") as f:
                np.lib.format.write_array(f, np.ascontiguousarray(array))
    refused(path, None, "compressed")


# --------------------------------------------------------------------------------------------------------------------
# the file itself


def test_fifo_device_folder_empty_truncated_and_size_cap(tmp_path, grid, monkeypatch):
    os.mkfifo(tmp_path / "fifo.npz")
    refused(tmp_path / "fifo.npz", None, "regular file")
    if os.path.exists("/dev/zero") and stat.S_ISCHR(os.stat("/dev/zero").st_mode):
        (tmp_path / "zero.npz").symlink_to("/dev/zero")
        refused(tmp_path / "zero.npz", None, "regular file")
    (tmp_path / "folder.npz").mkdir()
    refused(tmp_path / "folder.npz", None, "folder")
    refused(tmp_path / "absent.npz", None, "cannot read")
    save_map(grid, tmp_path / "map.npz")
    content = (tmp_path / "map.npz").read_bytes()
    for length in sorted({0, 1, 4, 22, 100, len(content) // 2, len(content) - 22, len(content) - 1}):
        (tmp_path / "cut.npz").write_bytes(content[:length])
        refused(tmp_path / "cut.npz")
    (tmp_path / "text.npz").write_text("not a map")
    refused(tmp_path / "text.npz", None, "not a depth grid map")
    monkeypatch.setattr(config, "MAX_MAP_FILE_BYTES", len(content) - 1)
    refused(tmp_path / "map.npz", None, "more than")


def test_save_map_replaces_the_file_whole(tmp_path, grid, rig):
    path = tmp_path / "map.npz"
    path.write_text("an older file")
    save_map(grid, path)
    assert np.array_equal(load_map(path, rig).corners, grid.corners)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["map.npz"]


# --------------------------------------------------------------------------------------------------------------------
# build_map's parameters


@pytest.mark.parametrize(
    "kwargs, field",
    [(dict(d_min=np.nan), "d_min"), (dict(d_min=np.inf), "d_min"), (dict(d_min=0.0), "d_min"),
     (dict(d_min=-1.0), "d_min"), (dict(d_min="0.3"), "d_min"), (dict(d_min=True), "d_min"),
     (dict(delta_d=0.0), "delta_d"), (dict(delta_d=1e-9), "delta_d"), (dict(delta_d=np.nan), "delta_d"),
     (dict(delta_d=-0.01), "delta_d"), (dict(d_max=0.2), "d_max"), (dict(d_max=np.inf), "d_max"),
     (dict(d_max=2e4), "d_max"), (dict(d_max=np.nan), "d_max"), (dict(delta_d=1e-4), "delta_d"),
     (dict(n_cells=0), "n_cells"), (dict(n_cells=4097), "n_cells"), (dict(n_cells=2.5), "n_cells"),
     (dict(n_cells=True), "n_cells"), (dict(n_cells=10, d_max=3.0), "n_cells"),
     (dict(d_min=9999.0, n_cells=343), "n_cells")],
)
def test_build_map_refuses_bad_parameters(rig, kwargs, field):
    with pytest.raises(InputError) as exc_info:
        build_map(rig, **kwargs)
    assert type(exc_info.value) is InputError and exc_info.value.field == field, str(exc_info.value)


def test_build_map_accepts_numpy_numbers_and_the_cell_cap(rig):
    grid = build_map(rig, d_min=np.float32(0.5), delta_d=np.float64(0.02),
                     n_cells=np.int64(config.DEPTH_GRID_MAX_CELLS))
    assert grid.n_cells == config.DEPTH_GRID_MAX_CELLS and isinstance(grid.n_cells, int)
    assert grid.d_min == float(np.float32(0.5))
    grid = build_map(rig, d_min=0.5, d_max=2.5, delta_d=0.01)
    assert grid.n_cells == 200  # (2.5 - 0.5) / 0.01, exactly


# --------------------------------------------------------------------------------------------------------------------
# the command line: a corrupt --map is one line naming the file, exit status 2


def test_cli_corrupt_map_exits_2_naming_the_file(tmp_path, capsys):
    rig = small_rig(64, 48)
    dg.save_rig(rig, tmp_path / "rig.yaml")
    for name in rig.cameras:
        write_depth_png(tmp_path / f"{name}.png", np.full((48, 64), 2000, np.uint16))
    (tmp_path / "points.csv").write_text("x,y,z\n0,0,0.6\n")
    assert main(["build-map", "--rig", str(tmp_path / "rig.yaml"), "--out", str(tmp_path / "map.npz")]) == 0
    capsys.readouterr()
    base = ["distance", "--rig", str(tmp_path / "rig.yaml"), "--depth", f"p={tmp_path / 'p.png'}", "--depth",
            f"s={tmp_path / 's.png'}", "--points", str(tmp_path / "points.csv"), "--json"]
    assert main(base + ["--map", str(tmp_path / "map.npz")]) == 0
    capsys.readouterr()
    content = bytearray((tmp_path / "map.npz").read_bytes())
    content[len(content) // 2] ^= 0x10
    (tmp_path / "bad.npz").write_bytes(bytes(content))
    assert main(base + ["--map", str(tmp_path / "bad.npz")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and str(tmp_path / "bad.npz") in err and "internal" not in err
