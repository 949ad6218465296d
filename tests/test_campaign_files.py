"""Campaign (issue 12, item 8), kind "files": bad files and options through the command line.

``depthguard.cli.main([...])`` runs in-process (fast), bounded in time and memory, with the audit hook armed; a few
cases also run the real ``.venv/bin/depthguard`` in a subprocess (exit status, single-line stderr, an address-space
limit, a fake ``gs`` on PATH that leaves a mark if anything runs it).

Rule, for every case: exit status 2 and exactly one line on standard error, starting with ``depthguard: error:`` and
naming the input (the file's name, or the option); never exit 3 ("internal error"), never a traceback, no hang, no
runaway memory, no child process (PostScript content named .png/.tif must never reach Ghostscript: Pillow's EPS
plugin first runs ``gs --version``, which the armed audit hook refuses and records whether or not Ghostscript is
installed, since the worker resets ``PIL.EpsImagePlugin.gs_binary`` before each case).

The in-process runs happen in a persistent worker process (``campaign_support.CliWorker``): a crash (the first
campaign run found a segfault) or a hang the alarm cannot interrupt then fails its case, not the whole session.

Safe readings: unknown or misspelled keys in a rig are refused (a typo of ``depth_range`` must not silently give the
default range; the brief asks for it, although design §2 lets the contract grow); a rig that uses YAML anchors
or aliases is refused even when harmless; a rig or points file above the size caps in ``depthguard.config`` is
refused; ``--rho 1e-200`` is refused (below ``config.RHO_MIN``); ``demo --duration 1e-9`` (less than one frame) is
refused. Generated variants (truncations, flipped bits, junk) may by chance still be valid files: then exit 0 is
accepted, and where the scene is the known wall its answer must pass the oracle.
"""

from __future__ import annotations

import io
import itertools
import json
import math
import os
import shutil

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from campaign_support import (
    FILE_POINTS,
    FILE_WALL_MM,
    Files,
    SurveyedViolation,
    campaign,
    check_cli_json,
    cli_call,
    cli_outcome,
    record,
    rig_text,
    run_cli_subprocess,
    surveyed,
    violation,
)

WALL = FILE_WALL_MM * 0.001
BIG = "1" + "0" * 400  # a 400-digit integer
_COUNTER = itertools.count()


@pytest.fixture(scope="module")
def files():
    f = Files()
    yield f
    f.close()


def unique(name: str) -> str:
    stem, dot, suffix = name.rpartition(".")
    return f"{stem}-{next(_COUNTER)}.{suffix}" if dot else f"{name}-{next(_COUNTER)}"


# ------------------------------------------------------------------------------------------- building bad files


def rig_with(f: Files, text: str, name="rig.yaml"):
    path = f.write(unique(name), text)
    return f.distance_argv(rig=path), [path.name]


def rig_edit(old: str, new: str, two: bool = False):
    def build(f):
        text = rig_text(two)
        assert old in text, old
        path = f.write(unique("rig.yaml"), text.replace(old, new, 1))
        return f.distance_argv(rig=path, two=two), [path.name]

    return build


def anchored() -> str:
    """The two-camera rig with the secondary's depth_range an alias of the principal's (harmless, but an alias)."""
    text = rig_text(two=True).replace("depth_range: [0.3, 4.0]", "depth_range: &r [0.3, 4.0]", 1)
    return text.replace("depth_range: [0.3, 4.0]", "depth_range: *r", 1)


def billion_laughs() -> str:
    lines = ["lol0: &a0 [1, 1, 1, 1, 1, 1, 1, 1, 1, 1]"]
    for i in range(1, 9):
        lines.append(f"lol{i}: &a{i} [" + ", ".join([f"*a{i - 1}"] * 10) + "]")
    return "\n".join(lines) + "\n" + rig_text().replace(
        "T_world_camera: [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]", "T_world_camera: *a8")


def camera_info_case(kind: str):
    def build(f):
        info = {"fifo": lambda: f.fifo(unique("info.yaml")), "dev/zero": lambda: f.dev_zero(unique("info.yaml")),
                "folder": lambda: f.folder(unique("info.yaml")),
                "distortion": lambda: f.write(unique("info.yaml"), "image_width: 64\nimage_height: 48\n"
                                              "camera_matrix: {rows: 3, cols: 3, data: [50, 0, 31.5, 0, 50, 23.5, 0, "
                                              "0, 1]}\ndistortion_coefficients: {rows: 1, cols: 5, data: [0.1, 0, 0, "
                                              "0, 0]}\n"),
                "alias": lambda: f.write(unique("info.yaml"), "image_width: &w 64\nimage_height: 48\n"
                                         "camera_matrix: {rows: 3, cols: 3, data: [50, 0, 31.5, 0, 50, 23.5, 0, 0, "
                                         "1]}\nwidth2: *w\n")}[kind]()
        text = rig_text()
        for key in ("width", "height", "fx", "fy", "cx", "cy"):
            text = "\n".join(line for line in text.splitlines() if not line.strip().startswith(f"{key}:")) + "\n"
        text = text.replace("  - name: p\n", f"  - name: p\n    camera_info: {info}\n")
        path = f.write(unique("rig.yaml"), text)
        return f.distance_argv(rig=path), [info.name, path.name]

    return build


def points_with(name: str, content):
    def build(f):
        path = f.write(unique(name), content)
        return f.distance_argv(points=path), [path.name]

    return build


def points_special(kind: str, suffix: str):
    def build(f):
        path = {"fifo": f.fifo, "dev/zero": f.dev_zero, "folder": f.folder}[kind](unique(f"points.{suffix}"))
        return f.distance_argv(points=path), [path.name]

    return build


def depth_with(name: str, content):
    def build(f):
        data = content(f) if callable(content) else content
        path = f.write(unique(name), data)
        return f.distance_argv(depth=path), [path.name]

    return build


def depth_special(kind: str, suffix: str):
    def build(f):
        path = {"fifo": f.fifo, "dev/zero": f.dev_zero, "folder": f.folder}[kind](unique(f"depth.{suffix}"))
        return f.distance_argv(depth=path), [path.name]

    return build


POSTSCRIPT = b"%!PS-Adobe-3.0 EPSF-3.0\n%%BoundingBox: 0 0 64 48\n%%EndComments\nnewpath 0 0 moveto 64 48 lineto " \
             b"stroke showpage\n%%EOF\n"


def eps_binary(ps: bytes = POSTSCRIPT) -> bytes:
    """A DOS EPS binary header (magic C5 D0 D3 C6) followed by the PostScript section."""
    header_len = 30
    return (b"\xc5\xd0\xd3\xc6" + header_len.to_bytes(4, "little") + len(ps).to_bytes(4, "little") + bytes(16)
            + b"\xff\xff" + ps)


def npy_bytes(header: str, data: bytes = b"", version=(1, 0)) -> bytes:
    raw = header.encode("latin1")
    pad = 16 - (10 + len(raw) + 1) % 16
    raw = raw + b" " * pad + b"\n"
    return b"\x93NUMPY" + bytes(version) + len(raw).to_bytes(2, "little") + raw + data


def png_bomb() -> bytes:
    """A 16-bit grayscale PNG whose header claims 100000 x 100000 pixels (one tiny IDAT)."""
    import struct
    import zlib

    def chunk(tag, payload):
        return struct.pack(">I", len(payload)) + tag + payload + struct.pack(">I", zlib.crc32(tag + payload))

    ihdr = struct.pack(">IIBBBBB", 100000, 100000, 16, 0, 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"\x00" * 1000))
            + chunk(b"IEND", b""))


def image_bytes(array, fmt: str, mode=None) -> bytes:
    from PIL import Image

    buffer = io.BytesIO()
    Image.fromarray(array, mode=mode).save(buffer, format=fmt)
    return buffer.getvalue()


def map_case(kind: str):
    def build(f):
        base = f.map
        if kind in ("fifo", "dev/zero", "folder"):
            path = {"fifo": f.fifo, "dev/zero": f.dev_zero, "folder": f.folder}[kind](unique("map.npz"))
        elif kind == "empty":
            path = f.write(unique("map.npz"), b"")
        elif kind == "truncated":
            data = base.read_bytes()
            path = f.write(unique("map.npz"), data[: len(data) // 2])
        elif kind == "not a zip":
            path = f.write(unique("map.npz"), b"PK\x03\x04" + os.urandom(200))
        elif kind == "flipped bit":
            data = bytearray(base.read_bytes())
            data[len(data) // 2] ^= 0x10
            path = f.write(unique("map.npz"), bytes(data))
        else:
            with np.load(base, allow_pickle=False) as z:
                arrays = {k: z[k] for k in z.files}
            raw = arrays["header"]  # a JSON string: as a 0-d str array, or as its UTF-8 bytes (uint8)
            as_bytes = raw.dtype == np.uint8
            header = json.loads(raw.tobytes().decode() if as_bytes else str(raw))
            if kind == "NaN corners":
                arrays["corners"] = arrays["corners"].copy()
                arrays["corners"][0, 10:20, 10:20, :] = np.nan
            elif kind == "NaN offsets":
                arrays["offsets"] = np.full_like(arrays["offsets"], np.nan)
            elif kind == "inf corners":
                arrays["corners"] = np.full_like(arrays["corners"], np.inf)
            elif kind == "n_cells 10**12":
                header["n_cells"] = 10 ** 12
            elif kind == "n_cells 400 digits":
                header["n_cells"] = int(BIG)
            elif kind == "d_min NaN":
                header["d_min"] = math.nan
            elif kind == "delta_d 0":
                header["delta_d"] = 0.0
            elif kind == "delta_d -0.01":
                header["delta_d"] = -0.01
            elif kind == "corners wrong shape":
                arrays["corners"] = arrays["corners"][:, :10]
            elif kind == "another rig":
                from depthguard import load_rig
                from depthguard.depthgrid import build_map, save_map

                other = f.write(unique("rig2.yaml"), rig_text(two=True).replace("[0, 0, 1, -0.1]", "[0, 0, 1, -0.2]"))
                path = f.dir / unique("map.npz")
                save_map(build_map(load_rig(other), "p"), path)
                return f.distance_argv(two=True, extra=["--map", path]), [path.name]
            else:
                raise AssertionError(kind)
            text = json.dumps(header)
            arrays["header"] = np.frombuffer(text.encode(), np.uint8) if as_bytes else np.array(text)
            path = f.dir / unique("map.npz")
            with open(path, "wb") as out:
                np.savez(out, **arrays)
        return f.distance_argv(two=True, extra=["--map", path]), [path.name]

    return build


def options(*extra, names=(), command=None, seconds=10.0):
    def build(f):
        argv = list(command) if command is not None else f.distance_argv(extra=extra)
        if command is not None:
            argv = [a.replace("{dir}", str(f.dir)) for a in argv]
            if "{rig}" in " ".join(argv):
                argv = [a.replace("{rig}", str(f.rig2)) for a in argv]
        return argv, list(names), seconds

    return build


def fifo_out(f):
    path = f.fifo(unique("map.npz"))
    return ["build-map", "--rig", f.rig2, "--out", path], [path.name]


IIWA_NAN = ",".join(["nan"] * 7)

CASES = {
    # ---- rig files
    "rig: misspelled top-level key": rig_edit("depth_scale:", "depth_scael:"),
    "rig: misspelled camera key": rig_edit("depth_range:", "depth_rnage:"),
    "rig: misspelled noise key": rig_edit("noise: none", "noize: none"),
    "rig: unknown key": rig_edit("principal: p", "principal: p\nexposure: 0.01"),
    "rig: D: distortion": rig_edit("    depth_range:", "    D: [0.1, 0.0, 0.0, 0.0, 0.0]\n    depth_range:"),
    "rig: d: distortion": rig_edit("    depth_range:", "    d: [0.1, 0.0, 0.0, 0.0, 0.0]\n    depth_range:"),
    "rig: distortion_coefficients": rig_edit("    depth_range:", "    distortion_coefficients: [0.1, 0, 0, 0, 0]\n"
                                             "    depth_range:"),
    "rig: anchor and alias": lambda f: rig_with(f, anchored()),
    "rig: billion laughs": lambda f: rig_with(f, billion_laughs()),
    "rig: deep nesting (sequences)": lambda f: rig_with(f, "cameras: " + "[" * 50000 + "]" * 50000 + "\n"),
    "rig: deep nesting (mappings)": lambda f: rig_with(f, "cameras: " + "{a: " * 20000 + "1" + "}" * 20000 + "\n"),
    "rig: 400-digit fx": rig_edit("fx: 50.0", f"fx: {BIG}"),
    "rig: 400-digit width": rig_edit("width: 64", f"width: {BIG}"),
    "rig: 400-digit depth_scale": rig_edit("depth_scale: 0.001", f"depth_scale: {BIG}"),
    "rig: 400-digit T entry": rig_edit("[1, 0, 0, 0], [0, 1", f"[1, 0, 0, {BIG}], [0, 1"),
    "rig: 400-digit depth_range": rig_edit("depth_range: [0.3, 4.0]", f"depth_range: [0.3, {BIG}]"),
    "rig: 5000-digit integer": rig_edit("cx: 31.5", "cx: " + "7" * 5000),
    "rig: NaN fx": rig_edit("fx: 50.0", "fx: .nan"),
    "rig: inf fy": rig_edit("fy: 50.0", "fy: .inf"),
    "rig: NaN depth_range": rig_edit("depth_range: [0.3, 4.0]", "depth_range: [.nan, 4.0]"),
    "rig: NaN T entry": rig_edit("[1, 0, 0, 0], [0, 1", "[1, 0, 0, .nan], [0, 1"),
    "rig: NaN depth_scale": rig_edit("depth_scale: 0.001", "depth_scale: .nan"),
    "rig: NaN noise": rig_edit("noise: none", "noise: {a: .nan, b: 0, c: 0, k: 3}"),
    "rig: duplicate key": rig_edit("fx: 50.0", "fx: 50.0\n    fx: 5000.0"),
    "rig: python tag": rig_edit("fx: 50.0", "fx: !!python/object/apply:os.system ['echo hi']"),
    "rig: bool width": rig_edit("width: 64", "width: true"),
    "rig: empty file": lambda f: rig_with(f, ""),
    "rig: binary junk": lambda f: rig_with(f, bytes(range(256)) * 4),
    "rig: not UTF-8": lambda f: rig_with(f, rig_text().replace("name: p", "name: p\u00e9").encode("latin-1")),
    "rig: over the size cap": lambda f: rig_with(f, rig_text() + ("# padding\n" * 220000)),
    "rig: FIFO": lambda f: (lambda p: (f.distance_argv(rig=p), [p.name]))(f.fifo(unique("rig.yaml"))),
    "rig: /dev/zero": lambda f: (lambda p: (f.distance_argv(rig=p), [p.name]))(f.dev_zero(unique("rig.yaml"))),
    "rig: /dev/zero itself": lambda f: (f.distance_argv(rig="/dev/zero"), ["/dev/zero"]),
    "rig: folder": lambda f: (lambda p: (f.distance_argv(rig=p), [p.name]))(f.folder(unique("rig.yaml"))),
    "rig: missing": lambda f: (f.distance_argv(rig=f.dir / "nope.yaml"), ["nope.yaml"]),
    # ---- camera_info files named by a rig
    "camera_info: FIFO": camera_info_case("fifo"),
    "camera_info: /dev/zero": camera_info_case("dev/zero"),
    "camera_info: folder": camera_info_case("folder"),
    "camera_info: distortion": camera_info_case("distortion"),
    "camera_info: alias": camera_info_case("alias"),
    # ---- points files
    "points JSON: 400-digit integer": points_with("points.json", f"[[0, 0, {BIG}]]"),
    "points JSON: 400-digit negative integer": points_with("points.json", f"[[-{BIG}, 0, 1]]"),
    "points JSON: 5000-digit integer": points_with("points.json", "[[0, 0, " + "9" * 5000 + "]]"),
    "points JSON: 1e400": points_with("points.json", "[[0, 0, 1e400]]"),
    "points JSON: deep nesting": points_with("points.json", "[" * 100000 + "]" * 100000),
    "points JSON: deep nesting in an entry": points_with("points.json", "[[0, 0, " + "[" * 100000 + "]" * 100000
                                                         + "]]"),
    "points JSON: NaN literal": points_with("points.json", "[[0, 0, NaN]]"),
    "points JSON: Infinity literal": points_with("points.json", "[[0, Infinity, 1]]"),
    "points JSON: -Infinity literal": points_with("points.json", "[[-Infinity, 0, 1]]"),
    "points JSON: bools": points_with("points.json", "[[true, false, true]]"),
    "points JSON: strings": points_with("points.json", '[["0", "0", "1"]]'),
    "points JSON: object": points_with("points.json", '{"x": 0, "y": 0, "z": 1}'),
    "points JSON: truncated": points_with("points.json", "[[0, 0, 1], [0.1, 0"),
    "points JSON: empty file": points_with("points.json", ""),
    "points CSV: field longer than 131072": points_with("points.csv", "x,y,z\n" + "1" * 140000 + ",0,1\n"),
    "points CSV: quoted field longer than 131072": points_with("points.csv", 'x,y,z\n"' + "0" * 140000 + '",0,1\n'),
    "points CSV: NaN": points_with("points.csv", "x,y,z\n0,nan,1\n"),
    "points CSV: inf": points_with("points.csv", "x,y,z\ninf,0,1\n"),
    "points CSV: 400-digit integer": points_with("points.csv", f"x,y,z\n0,0,{BIG}\n"),
    "points CSV: 1e400": points_with("points.csv", "x,y,z\n0,0,1e400\n"),
    "points CSV: no header": points_with("points.csv", "0,0,1\n"),
    "points CSV: empty file": points_with("points.csv", ""),
    "points CSV: NUL bytes": points_with("points.csv", b"x,y,z\n0,0\x00,1\n"),
    "points CSV: not UTF-8": points_with("points.csv", b"x,y,z\n0,0,1\xff\n"),
    "points: over the size cap": points_with("points.csv", "x,y,z\n" + "0,0,1\n" * 3_000_000),
    "points: FIFO (.json)": points_special("fifo", "json"),
    "points: FIFO (.csv)": points_special("fifo", "csv"),
    "points: /dev/zero (.json)": points_special("dev/zero", "json"),
    "points: /dev/zero (.csv)": points_special("dev/zero", "csv"),
    "points: folder": points_special("folder", "csv"),
    "points: missing": lambda f: (f.distance_argv(points=f.dir / "nope.csv"), ["nope.csv"]),
    # ---- depth images
    "depth: PostScript named .png": depth_with("depth.png", POSTSCRIPT),
    "depth: PostScript named .tif": depth_with("depth.tif", POSTSCRIPT),
    "depth: PostScript named .tiff": depth_with("depth.tiff", POSTSCRIPT),
    "depth: PostScript named .pgm": depth_with("depth.pgm", POSTSCRIPT),
    "depth: PostScript named .npy": depth_with("depth.npy", POSTSCRIPT),
    "depth: binary EPS named .png": depth_with("depth.png", eps_binary()),
    "depth: binary EPS named .tif": depth_with("depth.tif", eps_binary()),
    "depth: npy huge shape": depth_with("depth.npy", npy_bytes(
        "{'descr': '<u2', 'fortran_order': False, 'shape': (1000000, 1000000), }", b"\x00" * 64)),
    "depth: npy huge 1-D shape": depth_with("depth.npy", npy_bytes(
        "{'descr': '<f4', 'fortran_order': False, 'shape': (4000000000000,), }", b"\x00" * 64)),
    "depth: npy negative shape": depth_with("depth.npy", npy_bytes(
        "{'descr': '<u2', 'fortran_order': False, 'shape': (-1, 64), }", b"\x00" * 64)),
    "depth: npy negative product": depth_with("depth.npy", npy_bytes(
        "{'descr': '<u2', 'fortran_order': False, 'shape': (-48, -64), }", b"\x00" * 6144)),
    "depth: npy 400-digit shape": depth_with("depth.npy", npy_bytes(
        f"{{'descr': '<u2', 'fortran_order': False, 'shape': ({BIG}, 64), }}", b"\x00" * 64)),
    "depth: npy object dtype": depth_with("depth.npy", npy_bytes(
        "{'descr': '|O', 'fortran_order': False, 'shape': (48, 64), }", b"\x80\x04N." * 10)),
    "depth: npy complex": lambda f: depth_with("depth.npy", (lambda: (lambda b: (np.save(b, np.full((48, 64), 2 + 1j,
                                               np.complex64)), b.getvalue())[1])(io.BytesIO()))())(f),
    "depth: npy 3-D": lambda f: depth_with("depth.npy", (lambda b: (np.save(b, np.full((48, 64, 1), 2.0, np.float32)),
                                                                      b.getvalue())[1])(io.BytesIO()))(f),
    "depth: npy header length beyond the file": depth_with("depth.npy", b"\x93NUMPY\x01\x00\xff\xff{'descr'"),
    "depth: npy version 3 junk header": depth_with("depth.npy", npy_bytes("{'descr': '<u2', 'shape': (48, 64)}",
                                                                          version=(3, 0))),
    "depth: npy truncated data": lambda f: depth_with("depth.npy", f.npy.read_bytes()[:-100])(f),
    "depth: npz under .npy name": lambda f: depth_with("depth.npy", f.map.read_bytes())(f),
    "depth: empty .npy": depth_with("depth.npy", b""),
    "depth: empty .png": depth_with("depth.png", b""),
    "depth: empty .tif": depth_with("depth.tif", b""),
    "depth: empty .pgm": depth_with("depth.pgm", b""),
    "depth: truncated .png": lambda f: depth_with("depth.png", f.png.read_bytes()[:60])(f),
    "depth: truncated .tif": lambda f: depth_with("depth.tif", f.tif.read_bytes()[:200])(f),
    "depth: truncated .pgm": lambda f: depth_with("depth.pgm", f.pgm.read_bytes()[:-10])(f),
    "depth: PNG bomb header": depth_with("depth.png", png_bomb()),
    "depth: PGM huge header": depth_with("depth.pgm", b"P5\n100000 100000\n65535\n" + b"\x00" * 100),
    "depth: PGM 400-digit header": depth_with("depth.pgm", f"P5\n{BIG} 48\n65535\n".encode() + b"\x00" * 100),
    "depth: 8-bit PNG": depth_with("depth.png", lambda f: image_bytes(np.full((48, 64), 200, np.uint8), "PNG")),
    "depth: RGB PNG": depth_with("depth.png", lambda f: image_bytes(np.full((48, 64, 3), 200, np.uint8), "PNG")),
    "depth: wrong size PNG": depth_with("depth.png", lambda f: image_bytes(np.full((64, 48), 2000, np.uint16),
                                                                           "PNG")),
    "depth: unknown suffix": depth_with("depth.jpg", lambda f: f.png.read_bytes()),
    "depth: FIFO (.png)": depth_special("fifo", "png"),
    "depth: FIFO (.npy)": depth_special("fifo", "npy"),
    "depth: FIFO (.pgm)": depth_special("fifo", "pgm"),
    "depth: /dev/zero (.png)": depth_special("dev/zero", "png"),
    "depth: /dev/zero (.npy)": depth_special("dev/zero", "npy"),
    "depth: /dev/zero (.pgm)": depth_special("dev/zero", "pgm"),
    "depth: /dev/zero (.tif)": depth_special("dev/zero", "tif"),
    "depth: folder": depth_special("folder", "png"),
    "depth: missing": lambda f: (f.distance_argv(depth=f.dir / "nope.png"), ["nope.png"]),
    # ---- depth grid maps
    "map: FIFO": map_case("fifo"),
    "map: /dev/zero": map_case("dev/zero"),
    "map: folder": map_case("folder"),
    "map: empty": map_case("empty"),
    "map: truncated": map_case("truncated"),
    "map: not a zip": map_case("not a zip"),
    "map: flipped bit": map_case("flipped bit"),
    "map: NaN in corners": map_case("NaN corners"),
    "map: NaN offsets": map_case("NaN offsets"),
    "map: inf corners": map_case("inf corners"),
    "map: n_cells 10**12": map_case("n_cells 10**12"),
    "map: n_cells 400 digits": map_case("n_cells 400 digits"),
    "map: d_min NaN": map_case("d_min NaN"),
    "map: delta_d 0": map_case("delta_d 0"),
    "map: delta_d negative": map_case("delta_d -0.01"),
    "map: corners of the wrong shape": map_case("corners wrong shape"),
    "map: built for another rig": map_case("another rig"),
    # ---- options
    "option: --rho nan": options("--rho", "nan", names=["rho"]),
    "option: --rho 1e-200": options("--rho", "1e-200", names=["rho"]),
    "option: --rho -1": options("--rho", "-1", names=["rho"]),
    "option: --rho 0": options("--rho", "0", names=["rho"]),
    "option: --rho inf": options("--rho", "inf", names=["rho"]),
    "option: --rho 1e308": options("--rho", "1e308", names=["rho"]),
    "option: --rho abc": options("--rho", "abc", names=["rho"]),
    "option: --aggregate max": options("--aggregate", "max", names=["aggregate"]),
    "option: --depth unknown camera": lambda f: (f.distance_argv() + ["--depth", f"zz={f.png}"], ["zz"]),
    "option: --joints NaN (values)": options("--robot", "iiwa", "--joints", IIWA_NAN, names=["joint"], seconds=120),
    "option: --joints NaN (named)": options("--robot", "iiwa", "--joints", ",".join(
        f"lbr_iiwa_joint_{i}=nan" for i in range(1, 8)), names=["joint"], seconds=120),
    "option: --joints inf": options("--robot", "iiwa", "--joints", ",".join(["inf"] * 7), names=["joint"],
                                    seconds=120),
    "option: --joints 400 digits": options("--robot", "iiwa", "--joints", ",".join([BIG] * 7), names=["joint"],
                                           seconds=120),
    "option: simulate --duration inf": options(names=["duration"], command=["simulate", "--out", "{dir}/sim-inf",
                                                                             "--duration", "inf"], seconds=120),
    "option: simulate --duration nan": options(names=["duration"], command=["simulate", "--out", "{dir}/sim-nan",
                                                                             "--duration", "nan"], seconds=120),
    "option: demo --duration 1e-9": options(names=["duration"], command=["demo", "--out", "{dir}/demo-tiny",
                                                                          "--duration", "1e-9"], seconds=120),
    "option: demo --duration nan": options(names=["duration"], command=["demo", "--out", "{dir}/demo-nan",
                                                                         "--duration", "nan"], seconds=120),
    "option: build-map --d-min nan": options(names=["d-min", "d_min"], command=["build-map", "--rig", "{rig}",
                                                                                 "--d-min", "nan", "--out",
                                                                                 "{dir}/m1.npz"]),
    "option: build-map --delta-d 0": options(names=["delta"], command=["build-map", "--rig", "{rig}", "--delta-d",
                                                                        "0", "--out", "{dir}/m2.npz"]),
    "option: build-map --delta-d 1e-300": options(names=["delta"], command=["build-map", "--rig", "{rig}",
                                                                             "--delta-d", "1e-300", "--out",
                                                                             "{dir}/m3.npz"]),
    "option: build-map --out FIFO": fifo_out,
}


def _group(name: str) -> str:
    head = name.split(":")[0]
    return "files: " + {"points JSON": "points", "points CSV": "points", "option": "options (CLI)"}.get(head, head)


def _run_case(f: Files, name: str):
    built = CASES[name](f)
    argv, names = built[0], built[1]
    seconds = built[2] if len(built) > 2 else 10.0
    kind = _group(name)
    outcome, _, _ = cli_call(kind, argv, names, seconds=seconds, context=name, tag=name, trace=seconds <= 10.0)
    record(kind, outcome)


@pytest.mark.parametrize("name", list(CASES))
def test_cli_bad_file_or_option(files, name):
    try:
        _run_case(files, name)
    except SurveyedViolation:
        pass


# ------------------------------------------------------------------------------------ generated variants


BINARY = {"png": "png", "npy": "npy", "tif": "tif", "pgm": "pgm", "map": "map"}


def _target(f: Files, which: str):
    """(path of the valid file, how to put a variant in the argv, names, whether exit 0 can be checked)."""
    if which == "rig":
        return f.rig, lambda p: f.distance_argv(rig=p)
    if which == "points.json":
        return f.json, lambda p: f.distance_argv(points=p)
    if which == "points.csv":
        return f.csv, lambda p: f.distance_argv(points=p)
    if which == "map":
        return f.map, lambda p: f.distance_argv(two=True, extra=["--map", p])
    source = {"png": f.png, "npy": f.npy, "tif": f.tif, "pgm": f.pgm}[which]
    return source, lambda p: f.distance_argv(depth=p)


def _variant(kind, f, which, data: bytes, *, allow_success: bool, check_oracle: bool, context: str):
    source, argv_for = _target(f, which)
    path = f.write(unique(source.name), data)
    outcome, out, code = cli_call(kind, argv_for(path), [path.name], allow_success=allow_success, context=context)
    if code == 0 and check_oracle:
        check_cli_json(kind, out, FILE_POINTS, WALL, 0.4, "hybrid", context=context)
        outcome = "exit 0 (still valid), oracle holds"
    record(kind, outcome)
    path.unlink()


WHICH = ["rig", "points.json", "points.csv", "png", "npy", "tif", "pgm", "map"]


@campaign(60)
@given(which=st.sampled_from(WHICH), fraction=st.floats(0.0, 1.0, exclude_max=True))
@surveyed
def test_cli_truncated_files(files, which, fraction):
    """A valid file cut short. Text may still parse (a rig cut inside "23.5" reads "23."), so exit 0 is allowed for
    text; for the binary formats exit 0 is allowed only when nothing the pixels need was cut (a PNG cut inside its
    final IEND chunk; a TIFF, whose directory may precede the cut) and then the wall's oracle must hold."""
    kind = "files: truncated"
    data = _target(files, which)[0].read_bytes()
    cut = int(fraction * len(data))
    text = which in ("rig", "points.json", "points.csv")
    tolerant = text or which == "tif" or (which == "png" and cut >= data.rfind(b"IEND") - 4)
    _variant(kind, files, which, data[:cut], allow_success=tolerant, check_oracle=not text,
             context=f"{which} cut at {cut} of {len(data)} bytes")


@campaign(40)
@given(position=st.floats(0.0, 1.0, exclude_max=True), bit=st.integers(0, 7))
@surveyed
def test_cli_map_with_a_flipped_bit(files, position, bit):
    """One flipped bit anywhere in a depth grid map. The zip's CRC catches most; a flip in a field nothing reads
    (a timestamp) leaves a valid map, and then the two-camera wall's oracle must hold."""
    kind = "files: map bit flip"
    data = bytearray(files.map.read_bytes())
    i = int(position * len(data))
    data[i] ^= 1 << bit
    _variant(kind, files, "map", bytes(data), allow_success=True, check_oracle=True,
             context=f"bit {bit} of byte {i} of {len(data)}")


@campaign(60)
@given(which=st.sampled_from(WHICH), junk=st.binary(max_size=3000), keep_magic=st.booleans())
@surveyed
def test_cli_junk_files(files, which, junk, keep_magic):
    """Random bytes (optionally behind the format's own first bytes) in place of a file."""
    kind = "files: junk"
    if keep_magic:
        junk = _target(files, which)[0].read_bytes()[:16] + junk
    text = which in ("rig", "points.json", "points.csv")
    _variant(kind, files, which, junk, allow_success=text, check_oracle=not text,
             context=f"{len(junk)} junk bytes as {which}")


@campaign(30)
@given(suffix=st.sampled_from(["png", "tif", "tiff", "pgm", "npy", "PNG"]), payload=st.binary(max_size=200),
       binary=st.booleans(), box=st.tuples(st.integers(-10, 10 ** 6), st.integers(-10, 10 ** 6)))
@surveyed
def test_cli_postscript_never_reaches_ghostscript(files, suffix, payload, binary, box):
    """PostScript (plain or in a DOS EPS binary wrapper) under an image name. ``shutil.which("gs")`` is recorded in
    the outcome; the audit hook makes the test meaningful either way."""
    kind = "files: PostScript"
    ps = (f"%!PS-Adobe-3.0 EPSF-3.0\n%%BoundingBox: 0 0 {box[0]} {box[1]}\n").encode() + payload + b"\nshowpage\n"
    data = eps_binary(ps) if binary else ps
    path = files.write(unique(f"depth.{suffix}"), data)
    outcome, _, _ = cli_call(kind, files.distance_argv(depth=path), [path.name], context=f"{len(data)} bytes")
    record(kind, f"{outcome} (gs {'installed' if shutil.which('gs') else 'absent'})")
    path.unlink()


@campaign(30)
@given(digits=st.integers(300, 6000), where=st.sampled_from(["fx", "width", "cx", "depth_scale", "T", "noise",
                                                            "points.json", "points.csv"]), negative=st.booleans())
@surveyed
def test_cli_long_integers(files, digits, where, negative):
    """Integers of 300-6000 digits (beyond Python's 4300-digit str->int limit at the top) in a rig or points."""
    kind = "files: long integers"
    number = ("-" if negative else "") + "9" * digits
    if where.startswith("points"):
        suffix = where.split(".")[1]
        content = f"[[0, 0, {number}]]" if suffix == "json" else f"x,y,z\n0,0,{number}\n"
        path = files.write(unique(where), content)
        argv = files.distance_argv(points=path)
    else:
        text = rig_text()
        text = {"fx": lambda: text.replace("fx: 50.0", f"fx: {number}"),
                "width": lambda: text.replace("width: 64", f"width: {number}"),
                "cx": lambda: text.replace("cx: 31.5", f"cx: {number}"),
                "depth_scale": lambda: text.replace("depth_scale: 0.001", f"depth_scale: {number}"),
                "T": lambda: text.replace("[0, 0, 1, 0], [0", f"[0, 0, 1, {number}], [0"),
                "noise": lambda: text.replace("noise: none", f"noise: {{a: {number}, b: 0, c: 0, k: 3}}")}[where]()
        path = files.write(unique("rig.yaml"), text)
        argv = files.distance_argv(rig=path)
    outcome, _, _ = cli_call(kind, argv, [path.name], context=f"{digits} digits in {where}")
    record(kind, outcome)
    path.unlink()


@campaign(20)
@given(length=st.integers(100_000, 400_000), quoted=st.booleans(), column=st.integers(0, 2))
@surveyed
def test_cli_long_csv_fields(files, length, quoted, column):
    """A CSV field of 100k-400k characters (Python's csv module refuses fields above 131072 by default)."""
    kind = "files: long CSV field"
    field = "1" * length
    cells = ["0", "0", "1"]
    cells[column] = f'"{field}"' if quoted else field
    path = files.write(unique("points.csv"), "x,y,z\n" + ",".join(cells) + "\n")
    outcome, _, _ = cli_call(kind, files.distance_argv(points=path), [path.name], context=f"{length} characters")
    record(kind, outcome)
    path.unlink()


@campaign(30)
@given(shape=st.lists(st.one_of(st.integers(-10, 10 ** 13), st.just(10 ** 400)), min_size=0, max_size=4),
       descr=st.sampled_from(["<u2", ">u2", "<f4", "<f8", "|O", "<c8", "|b1", "<i8", "|V16", "<U4", "bogus"]),
       fortran=st.booleans(), data=st.binary(max_size=256), version=st.sampled_from([(1, 0), (2, 0), (3, 0), (9, 9)]))
@surveyed
def test_cli_npy_headers(files, shape, descr, fortran, data, version):
    """.npy files whose header claims any shape (huge, negative, 400 digits, 0-4 dimensions) and dtype, with a few
    bytes of data."""
    kind = "files: npy headers"
    dims = ", ".join(map(str, shape)) + ("," if len(shape) == 1 else "")
    text = f"{{'descr': '{descr}', 'fortran_order': {fortran}, 'shape': ({dims}), }}"
    if version == (1, 0) and len(text) > 60000:
        version = (2, 0)
    raw = text.encode("latin1")
    if version[0] >= 2:
        pad = 16 - (12 + len(raw) + 1) % 16
        raw = raw + b" " * pad + b"\n"
        blob = b"\x93NUMPY" + bytes(version) + len(raw).to_bytes(4, "little") + raw + data
    else:
        blob = npy_bytes(text, data, version)
    path = files.write(unique("depth.npy"), blob)
    outcome, out, code = cli_call(kind, files.distance_argv(depth=path), [path.name], allow_success=False,
                                  context=f"header {text[:200]}")
    record(kind, outcome)
    path.unlink()


# ------------------------------------------------------------------------------------------ real subprocesses


@pytest.fixture(scope="module")
def address_space(files):
    """A normal ``distance`` run's peak address space (VmPeak), measured in a subprocess, plus 2 GiB."""
    import subprocess
    import sys

    script = ("import sys; from depthguard.cli import main; code = main(sys.argv[1:]); "
              "status = open('/proc/self/status').read(); "
              "peak = [l for l in status.splitlines() if l.startswith('VmPeak:')][0].split()[1]; "
              "print(peak, file=sys.stderr); sys.exit(code)")
    argv = [str(a) for a in files.distance_argv(two=True)]
    run = subprocess.run([sys.executable, "-c", script, *argv], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    peak = int(run.stderr.strip().splitlines()[-1]) * 1024
    return peak + (2 << 30)


SUBPROCESS_CASES = ["rig: FIFO", "points: /dev/zero (.csv)", "depth: PostScript named .png", "rig: billion laughs",
                    "points JSON: deep nesting", "option: --rho nan", "map: flipped bit"]


@pytest.mark.parametrize("name", SUBPROCESS_CASES)
def test_cli_subprocess(files, address_space, tmp_path, name):
    """The real executable: exit 2, one line on stderr naming the input, within 60 s and the address-space limit, and
    no Ghostscript (a fake ``gs`` first on PATH leaves a mark if anything runs it)."""
    kind = "files: subprocess"
    built = CASES[name](files)
    argv, names = built[0], built[1]
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    mark = tmp_path / "gs-was-run"
    fake = bin_dir / "gs"
    fake.write_text(f"#!/bin/sh\ntouch '{mark}'\nexit 0\n")
    fake.chmod(0o755)
    env = dict(os.environ, PATH=f"{bin_dir}{os.pathsep}{os.environ.get('PATH', '')}")
    env.pop("DEPTHGUARD_DEBUG", None)
    try:
        code, out, err, seconds, rss = run_cli_subprocess(argv, timeout=60, address_space=address_space, env=env)
        if code is None:
            violation(kind, f"{name}: hang (killed after 60 s)", str(argv))
        if mark.exists():
            violation(kind, f"{name}: Ghostscript was run", err[:300])
        if rss > address_space:
            violation(kind, f"{name}: child memory above bound", f"{rss / 1e6:.0f} MB")
        if code is not None and code < 0:
            violation(kind, f"{name}: crashed (signal {-code})", err[-600:])
        record(kind, cli_outcome(kind, code, err, names, context=name, tag=name))
    except SurveyedViolation:
        pass
