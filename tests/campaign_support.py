"""The bad-input campaign's shared machinery (issue 12, item 8): the exact oracle, bounds, and the outcome counts.

The campaign (``tests/test_campaign_*.py``) feeds depthguard inputs built by ``hypothesis`` strategies, one strategy
per kind of input, and checks four things for every one of them:

1. no answer above the exact distance unflagged (the oracle below);
2. no exception other than :class:`depthguard.errors.DepthguardError` (the CLI: exit status 2 and exactly one line on
   standard error that starts with ``depthguard: error:`` and names the input; never exit 3, never a traceback);
3. time and memory bounded (:func:`bounded`: a per-call alarm, an address-space limit, tracemalloc for file cases);
4. no child process started (an audit hook, armed around every library call, that refuses process creation).

**The oracle.** One camera, 64x48 pixels, fx = fy = 50, cx = 31.5, cy = 23.5, no noise margin, depth range
[0.3, 4.0] m, looks straight at a flat wall: every pixel's depth is D (the plane z = D of its optical frame). What is
possibly occupied, with the default policies (``invalid="occupied"``, ``unseen="occupied"``), is the wall and
everything behind it (z >= D), everything outside the view (outside the union of the pixel footprints,
[-0.5, W - 0.5] x [-0.5, H - 0.5] in image coordinates), and everything nearer than 0.3 m or farther than 4.0 m.
The free space is therefore the convex polytope

    P = { 0.3 <= z <= D,  a0 z <= x <= a1 z,  b0 z <= y <= b1 z }    (optical frame)
    a0 = (-0.5 - cx) / fx,  a1 = (W - 0.5 - cx) / fx,  b0 = (-0.5 - cy) / fy,  b1 = (H - 0.5 - cy) / fy

and the exact distance of a point to the possibly-occupied set is its distance to the complement of P: for a point
inside P the smallest of its distances to P's six facet planes, 0 for a point outside P (behind the wall, outside
the view, nearer than 0.3 m; every point with a non-finite or huge coordinate, since P is bounded).

Expected values come from this geometry, never from depthguard's own output. A reported distance passes when

- it is at most exact + TOL (TOL = 1e-6 m: the float32 depth images and the float64 transforms), or it is ``inf``
  while exact >= rho (nothing within rho), for ``min`` and ``hybrid``;
- it is exactly 0, flagged ``inside_obstacle`` / ``region_outside_view`` (or ``stale_camera`` /
  ``missing_camera``), for a point clearly outside P (by more than TOL), whatever the aggregation and rho;
- for ``mean`` (the mean over the contributors, which may exceed the nearest distance, design §6): 0 as above,
  and, when exact < rho, a finite value below rho (there is a contributor closer than rho, and every contributor is).

Anything that only removes information (a pixel without a measurement, a stale camera, a masked value) can only make
the occupied set larger, so the same oracle still bounds the answer from above.

**Counts.** :func:`record` counts every input tried, by kind and outcome; ``tests/conftest.py`` prints the table at
the end of a session that ran campaign tests, and writes it as JSON to the file named by the environment variable
``DEPTHGUARD_CAMPAIGN_REPORT`` when it is set. ``python tests/campaign_support.py REPORT.json`` prints a saved table.

**Profiles.** ``DEPTHGUARD_CAMPAIGN=ci`` (default): fixed example counts, ``derandomize=True`` (reproducible).
``DEPTHGUARD_CAMPAIGN=long``: ``DEPTHGUARD_CAMPAIGN_FACTOR`` (default 25) times as many examples, random seeds.
``DEPTHGUARD_CAMPAIGN_SURVEY=1`` (for reports only, never CI): a violation is counted but does not fail its test,
so one run gives the outcome table of every example instead of stopping each test at its first failure.
"""

from __future__ import annotations

import atexit
import contextlib
import functools
import io
import json
import math
import os
import resource
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import traceback
import tracemalloc
from collections import Counter, defaultdict
from decimal import Decimal
from fractions import Fraction
from pathlib import Path

import numpy as np
from hypothesis import HealthCheck, settings
from hypothesis import strategies as st

import depthguard as dg
from depthguard import Flag
from depthguard.errors import DepthguardError

REPO = Path(__file__).resolve().parent.parent
DEPTHGUARD_EXE = REPO / ".venv" / "bin" / "depthguard"

# ------------------------------------------------------------------------------------------------------- profiles

PROFILE = os.environ.get("DEPTHGUARD_CAMPAIGN", "ci")
if PROFILE not in ("ci", "long"):
    raise RuntimeError(f"DEPTHGUARD_CAMPAIGN must be 'ci' or 'long', got {PROFILE!r}")
LONG_FACTOR = int(os.environ.get("DEPTHGUARD_CAMPAIGN_FACTOR", "25"))
SURVEY = os.environ.get("DEPTHGUARD_CAMPAIGN_SURVEY") == "1"

_QUIET_CHECKS = [HealthCheck.too_slow, HealthCheck.filter_too_much, HealthCheck.data_too_large,
                 HealthCheck.large_base_example]
settings.register_profile("depthguard-campaign-ci", derandomize=True, deadline=None, database=None,
                          print_blob=False, suppress_health_check=_QUIET_CHECKS)
settings.register_profile("depthguard-campaign-long", derandomize=False, deadline=None, database=None,
                          print_blob=True, suppress_health_check=_QUIET_CHECKS)


def campaign(ci_examples: int) -> settings:
    """Hypothesis settings for one campaign test: ``ci_examples`` examples in CI, LONG_FACTOR times more in the long
    run. ``deadline=None``: numba may compile on a first call."""
    n = ci_examples if PROFILE == "ci" else ci_examples * LONG_FACTOR
    return settings(settings.get_profile(f"depthguard-campaign-{PROFILE}"), max_examples=n)


# ------------------------------------------------------------------------------------------------ the geometry

W, H = 64, 48
FX = FY = 50.0
CX, CY = 31.5, 23.5
Z_MIN, Z_MAX = 0.3, 4.0
A0, A1 = (-0.5 - CX) / FX, (W - 0.5 - CX) / FX  # -0.64, 0.64
B0, B1 = (-0.5 - CY) / FY, (H - 0.5 - CY) / FY  # -0.48, 0.48
TOL = 1e-6  # metres
#: Farther than this from the optical centre (optical-frame max-norm), a point is outside P whatever D.
FAR = 10.0
#: Where a stale frame's content puts the wall: it shows the room before the wall came nearer (an old frame).
OLD_WALL = 3.9
#: Seconds a frame may be stamped later than ``now`` and still be fresh; beyond it the frame's time is wrong (stale).
#: Stated here: 10 ms, a third of a 30 Hz frame period, is as far as the clocks of a camera and the host may
#: disagree. The library's config.CLOCK_SKEW_TOLERANCE may be tighter (a fresh frame answered as stale is
#: conservative: counted, not failed), never looser (tests/test_campaign_time.py checks).
SKEW = 0.01

_NORMS = np.array([1.0, 1.0, math.hypot(1.0, A0), math.hypot(1.0, A1), math.hypot(1.0, B0), math.hypot(1.0, B1)])


def facet_margins(points_camera, wall: float) -> np.ndarray:
    """(n,) the smallest signed distance of each optical-frame point to P's facet planes: positive inside P (then it
    is the exact distance), negative outside; -inf for a non-finite or far point."""
    p = np.asarray(points_camera, dtype=np.float64).reshape(-1, 3)
    with np.errstate(all="ignore"):
        x, y, z = p[:, 0], p[:, 1], p[:, 2]
        s = np.stack([z - Z_MIN, wall - z, x - A0 * z, A1 * z - x, y - B0 * z, B1 * z - y], axis=1) / _NORMS
        margin = s.min(axis=1)
        bad = ~np.all(np.isfinite(p), axis=1) | (np.abs(p).max(axis=1, initial=0.0) > FAR) | np.isnan(margin)
    margin[bad] = -np.inf
    return margin


def exact_distance(points_camera, wall: float) -> np.ndarray:
    """(n,) exact distance of optical-frame points to the complement of P (0 outside P)."""
    return np.maximum(facet_margins(points_camera, wall), 0.0)


def rotation_from_quaternion(q) -> np.ndarray:
    w, x, y, z = np.asarray(q, dtype=np.float64) / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def rigid(R, t) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t
    return T


def to_world(G: np.ndarray, points_camera) -> np.ndarray:
    p = np.asarray(points_camera, dtype=np.float64).reshape(-1, 3)
    return p @ G[:3, :3].T + G[:3, 3]


def to_camera(G: np.ndarray, points_world) -> np.ndarray:
    """World points in the principal's optical frame (G = its T_world_camera); far or non-finite points stay far or
    non-finite (their exact distance is 0 either way)."""
    p = np.asarray(points_world, dtype=np.float64).reshape(-1, 3)
    with np.errstate(all="ignore"):
        return (p - G[:3, 3]) @ G[:3, :3]


def camera(name: str, T_world_camera, depth_scale: float = 0.001) -> dg.PinholeCamera:
    return dg.PinholeCamera(name, W, H, FX, FY, CX, CY, T_world_camera, depth_range=(Z_MIN, Z_MAX),
                            depth_scale=depth_scale, noise=dg.NoiseModel.none())


def single_rig(G) -> dg.Rig:
    return dg.Rig({"p": camera("p", G)}, principal="p")


def fused_rig(G, T_principal_secondary) -> dg.Rig:
    """The principal ``p`` at G and the secondary ``s`` at G @ T_principal_secondary (both look at the wall)."""
    return dg.Rig({"p": camera("p", G), "s": camera("s", G @ T_principal_secondary)}, principal="p")


def wall_image(wall_mm_or_m, kind: str) -> np.ndarray:
    """The principal's view of the wall: every pixel at depth D. ``kind`` "f32": float32 metres (D given in metres,
    float32-representable); "u16": uint16 millimetres (D given in millimetres)."""
    if kind == "u16":
        return np.full((H, W), int(wall_mm_or_m), dtype=np.uint16)
    return np.full((H, W), np.float32(wall_mm_or_m), dtype=np.float32)


def secondary_wall_depths(T_principal_secondary, wall: float) -> np.ndarray:
    """(H, W) float64 metres: for each pixel of the secondary camera, the nearest depth (its optical z) of the wall
    plane z_p = ``wall`` over the pixel's footprint (the minimum over its four corner rays: depth along a ray through
    the footprint is 1 / (an affine function of the image coordinates), so the extremes lie at corners). NaN where a
    corner ray does not reach the wall. A camera that reports this never claims to see beyond the wall."""
    R = T_principal_secondary[:3, :3]
    t = T_principal_secondary[:3, 3]
    u = np.arange(W + 1) - 0.5
    v = np.arange(H + 1) - 0.5
    cu, cv = np.meshgrid((u - CX) / FX, (v - CY) / FY)  # (H+1, W+1)
    # the principal-frame z of the ray direction (cu, cv, 1) of the secondary camera
    dz = R[2, 0] * cu + R[2, 1] * cv + R[2, 2]
    with np.errstate(all="ignore"):
        s = np.where(dz > 1e-9, (wall - t[2]) / dz, np.nan)
        s[s <= 0] = np.nan
    corners = np.stack([s[:-1, :-1], s[:-1, 1:], s[1:, :-1], s[1:, 1:]])
    return corners.min(axis=0)  # NaN if any corner is NaN


def secondary_image(T_principal_secondary, wall: float, kind: str) -> np.ndarray:
    """The secondary camera's view of the wall, rounded towards the camera (never beyond the wall)."""
    depth = secondary_wall_depths(T_principal_secondary, wall)
    if kind == "u16":
        mm = np.floor(np.nan_to_num(depth, nan=0.0) * 1000.0 - 1e-6)
        return np.clip(mm, 0, 65535).astype(np.uint16)
    d32 = depth.astype(np.float32)
    over = d32.astype(np.float64) > depth
    d32[over] = np.nextafter(d32[over], np.float32(0))
    return d32


# ------------------------------------------------------------------------------------------------ strategies

def finite(lo, hi):
    return st.floats(min_value=lo, max_value=hi, allow_nan=False, allow_infinity=False)


@st.composite
def rigid_transforms(draw, max_translation: float = 1000.0):
    """A random rigid transform of the whole setup (world frame): identity, or a random rotation and translation."""
    if draw(st.booleans()):
        return np.eye(4)
    q = [draw(finite(-1.0, 1.0)) for _ in range(4)]
    if np.linalg.norm(q) < 0.1:
        q = [1.0, 0.0, 0.0, 0.0]
    t = [draw(finite(-max_translation, max_translation)) for _ in range(3)]
    return rigid(rotation_from_quaternion(q), t)


@st.composite
def walls(draw, lo_mm: int = 600, hi_mm: int = 3800):
    """(kind, value for wall_image, D in metres): float32 metres or uint16 millimetres."""
    kind = draw(st.sampled_from(["f32", "u16"]))
    mm = draw(st.integers(lo_mm, hi_mm))
    if kind == "u16":
        return kind, mm, mm * 0.001
    d = float(np.float32(draw(finite(lo_mm / 1000.0, hi_mm / 1000.0))))
    return kind, d, d


@st.composite
def secondary_layouts(draw):
    """T_principal_secondary: a secondary camera beside the principal, on the same side of the wall, looking at it
    from a slightly different position and direction (translation up to 0.3 m, rotations up to ~8 degrees)."""
    angles = [draw(finite(-0.14, 0.14)) for _ in range(3)]
    t = [draw(finite(-0.3, 0.3)), draw(finite(-0.3, 0.3)), draw(finite(-0.3, 0.1))]
    cx_, sx = math.cos(angles[0]), math.sin(angles[0])
    cy_, sy = math.cos(angles[1]), math.sin(angles[1])
    cz, sz = math.cos(angles[2]), math.sin(angles[2])
    Rx = np.array([[1, 0, 0], [0, cx_, -sx], [0, sx, cx_]])
    Ry = np.array([[cy_, 0, sy], [0, 1, 0], [-sy, 0, cy_]])
    Rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return rigid(Rz @ Ry @ Rx, t)


@st.composite
def camera_points(draw, wall: float):
    """One optical-frame point: inside P, near one of its facets (either side), behind the wall, outside the view,
    nearer than the minimum range, or near the optical centre."""
    where = draw(st.sampled_from(["inside", "inside", "facet", "facet", "behind", "outside", "near", "centre"]))
    fx_, fy_ = draw(finite(0.0, 1.0)), draw(finite(0.0, 1.0))
    if where == "inside":
        z = draw(finite(Z_MIN, wall))
    elif where == "behind":
        z = draw(finite(wall, wall + 3.0))
    elif where == "near":
        z = draw(finite(0.01, Z_MIN))
    elif where == "centre":
        return (draw(finite(-0.05, 0.05)), draw(finite(-0.05, 0.05)), draw(finite(-0.2, 0.2)))
    else:
        z = draw(finite(Z_MIN, wall))
    if where == "outside":
        fx_ = draw(st.one_of(finite(-3.0, -0.001), finite(1.001, 4.0)))
    x = (A0 + fx_ * (A1 - A0)) * z
    y = (B0 + fy_ * (B1 - B0)) * z
    point = np.array([x, y, z])
    if where == "facet":
        facet = draw(st.integers(0, 5))
        offset = draw(st.sampled_from([0.0, 1e-9, -1e-9, 1e-7, -1e-7, 1e-4, -1e-4, 0.01, -0.01]))
        normals = np.array([[0, 0, 1], [0, 0, -1], [1, 0, -A0], [-1, 0, A1], [0, 1, -B0], [0, -1, B1]], float)
        offsets = np.array([Z_MIN, -wall, 0, 0, 0, 0])
        n = normals[facet] / np.linalg.norm(normals[facet])
        signed = (normals[facet] @ point - offsets[facet]) / np.linalg.norm(normals[facet])
        point = point - (signed - offset) * n  # on the plane, then offset along its inner normal
    return tuple(float(c) for c in point)


def point_sets(wall: float, min_size: int = 1, max_size: int = 6):
    return st.lists(camera_points(wall), min_size=min_size, max_size=max_size)


NASTY_FLOATS = [math.nan, math.inf, -math.inf, 1e160, -1e160, 1e308, -1e308, 1.7976931348623157e308, 5e-324,
                -5e-324, 2.2250738585072014e-308, 1e-310, -0.0, 0.0]


def nasty_floats():
    return st.one_of(st.sampled_from(NASTY_FLOATS), st.floats(allow_nan=True, allow_infinity=True))


# ----------------------------------------------------------------------------------------------- the counts

COUNTS: dict[str, Counter] = defaultdict(Counter)
DETAILS: dict[str, list] = defaultdict(list)  # kind -> first violation messages (a few per label)


def record(kind: str, outcome: str) -> None:
    COUNTS[kind][outcome] += 1


class SurveyedViolation(Exception):
    """Raised in survey mode instead of an AssertionError: the test stops this example and passes."""


def violation(kind: str, label: str, detail: str = ""):
    """Count a violation of the rule and fail (or, in survey mode, stop this example)."""
    record(kind, f"VIOLATION: {label}")
    seen = [d for d in DETAILS[kind] if d[0] == label]
    if len(seen) < 3:
        DETAILS[kind].append((label, detail[:2000]))
    message = f"[{kind}] {label}" + (f"\n{detail}" if detail else "")
    if SURVEY:
        raise SurveyedViolation(message)
    raise AssertionError(message)


_violation = violation


def surveyed(fn):
    """Decorator (below ``@given``): in survey mode, a violation ends the example without failing the test."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        try:
            return fn(*args, **kwargs)
        except SurveyedViolation:
            return None

    return wrapper


def table() -> list[str]:
    """The counts as text lines: per kind, its total and each outcome."""
    lines = [f"{'kind':<22s} {'inputs':>7s}  outcomes"]
    total = 0
    for kind in sorted(COUNTS):
        counts = COUNTS[kind]
        n = sum(counts.values())
        total += n
        outcomes = "; ".join(f"{label}: {c}" for label, c in sorted(counts.items(), key=lambda kv: (-kv[1], kv[0])))
        lines.append(f"{kind:<22s} {n:7d}  {outcomes}")
    lines.append(f"{'all':<22s} {total:7d}")
    return lines


def report(write_line) -> None:
    """Print the table (pytest's terminal summary) and write the JSON file named by DEPTHGUARD_CAMPAIGN_REPORT."""
    write_line(f"depthguard bad-input campaign (profile {PROFILE}{', survey' if SURVEY else ''}; library "
               f"{Path(dg.__file__).parent}): inputs tried by kind and outcome")
    for line in table():
        write_line(line)
    path = os.environ.get("DEPTHGUARD_CAMPAIGN_REPORT")
    if path:
        data = {"profile": PROFILE, "survey": SURVEY, "counts": {k: dict(v) for k, v in sorted(COUNTS.items())},
                "violations": {k: [{"label": a, "detail": b} for a, b in v] for k, v in sorted(DETAILS.items())}}
        Path(path).write_text(json.dumps(data, indent=2))
        write_line(f"campaign report written to {path}")


# ------------------------------------------------------------------------------------------------- the bounds


class CampaignTimeout(BaseException):
    """A library call took longer than its bound. A BaseException, so that no ``except Exception`` inside the
    library (the CLI's "internal error" handler) can turn a hang into an ordinary answer."""


class ChildProcessAttempt(BaseException):
    """The library tried to start a process while the audit hook was armed; the attempt was refused."""


_CHILD_EVENTS = frozenset({"subprocess.Popen", "os.system", "os.posix_spawn", "os.exec", "os.fork", "os.spawn",
                           "os.forkpty", "pty.spawn"})
_ARMED = False
CHILD_EVENTS: list = []  # (event, args) of every refused attempt


def _audit(event, args):
    if _ARMED and event in _CHILD_EVENTS:
        CHILD_EVENTS.append((event, repr(args)[:300]))
        raise ChildProcessAttempt(f"{event}{args!r:.300}")


sys.addaudithook(_audit)  # cannot be removed; costs one global lookup per audit event while disarmed

#: Default bound of one library call, seconds. Generous: a first call may load numba's cached kernels, and the
#: machine is shared. A hang inside a numba kernel cannot be interrupted by a signal: faulthandler then ends the
#: whole run at HARD_KILL_FACTOR times the bound, so CI fails instead of freezing.
TIME_LIMIT = 60.0
HARD_KILL_FACTOR = 4.0
#: Address space a call may add to the process, bytes (numba/LLVM need address space; a normal query adds little).
MEMORY_HEADROOM = 2 << 30
#: Largest Python/numpy allocation peak (tracemalloc) of one file case, bytes.
FILE_PEAK_LIMIT = 256 << 20


def _vm_size() -> int:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmSize:"):
                return int(line.split()[1]) * 1024
    return 0


def _on_alarm(signum, frame):
    raise CampaignTimeout("the call exceeded its time bound")


class Bound:
    seconds = 0.0
    peak = 0


@contextlib.contextmanager
def bounded(seconds: float = TIME_LIMIT, headroom: int = MEMORY_HEADROOM, trace: bool = False):
    """Run a library call with a time bound (SIGALRM raising CampaignTimeout), an address-space bound (RLIMIT_AS soft
    limit: the current size plus ``headroom``; an allocation beyond it raises MemoryError), optionally tracemalloc
    (``Bound.peak``), and the audit hook armed (a child process attempt raises ChildProcessAttempt)."""
    global _ARMED
    import faulthandler

    stats = Bound()
    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    limit = _vm_size() + headroom
    if hard != resource.RLIM_INFINITY:
        limit = min(limit, hard)
    old = signal.signal(signal.SIGALRM, _on_alarm)
    faulthandler.dump_traceback_later(seconds * HARD_KILL_FACTOR + 30, exit=True)
    if trace:
        tracemalloc.start()
    start = time.perf_counter()
    resource.setrlimit(resource.RLIMIT_AS, (limit, hard))
    signal.setitimer(signal.ITIMER_REAL, seconds)
    _ARMED = True
    try:
        yield stats
    finally:
        _ARMED = False
        signal.setitimer(signal.ITIMER_REAL, 0)
        resource.setrlimit(resource.RLIMIT_AS, (soft, hard))
        stats.seconds = time.perf_counter() - start
        if trace:
            stats.peak = tracemalloc.get_traced_memory()[1]
            tracemalloc.stop()
        faulthandler.cancel_dump_traceback_later()
        signal.signal(signal.SIGALRM, old)


class Refused:
    """What a library call raised on purpose (a DepthguardError)."""

    def __init__(self, exc: DepthguardError):
        self.exc = exc
        self.label = f"refused: {type(exc).__name__}"


def call(kind: str, fn, *, seconds: float = TIME_LIMIT, trace: bool = False, tag: str = ""):
    """``fn()`` bounded. Returns its value, or a :class:`Refused` for a DepthguardError; any other exception, a
    timeout, a child process attempt or a memory bound is a violation (its label prefixed by ``tag``)."""
    prefix = f"{tag}: " if tag else ""

    def violation(kind, label, detail=""):  # noqa: F811 - the module's, with the tag
        _violation(kind, prefix + label, detail)

    try:
        with bounded(seconds, trace=trace) as stats:
            value = fn()
    except DepthguardError as exc:
        return Refused(exc)
    except CampaignTimeout:
        violation(kind, "hang (time bound exceeded)", f"{seconds} s")
    except ChildProcessAttempt as exc:
        violation(kind, "child process started", str(exc))
    except MemoryError as exc:
        violation(kind, "memory bound exceeded (MemoryError)", repr(exc))
    except SurveyedViolation:
        raise
    except AssertionError:
        raise
    except Exception as exc:  # noqa: BLE001 - every other exception is the finding
        violation(kind, f"{type(exc).__name__} (not a DepthguardError)",
                  f"{exc!r}\n{''.join(traceback.format_exception(exc)[-6:])}")
    if trace and stats.peak > FILE_PEAK_LIMIT:
        violation(kind, "memory peak above bound", f"{stats.peak / 1e6:.0f} MB")
    return value


# ------------------------------------------------------------------------------------------------- the checks


FLAGS_ZERO_OK = Flag.INSIDE_OBSTACLE | Flag.REGION_OUTSIDE_VIEW | Flag.STALE_CAMERA | Flag.MISSING_CAMERA


def _fmt(i, points_camera, exact, reported, flags):
    return (f"point #{i} (optical frame {np.asarray(points_camera)[i].tolist()}): exact {exact[i]!r}, reported "
            f"{reported[i]!r}, flags {flags[i].names}")


def check_result(kind: str, result, points_camera, wall: float, rho, aggregate: str, *, unknown=None,
                 context: str = "", tag: str = "") -> str:
    """Apply the oracle to a DistanceResult for optical-frame points (principal camera), wall depth ``wall`` and
    surveillance radius ``rho`` (a float, possibly NaN or <= 0 when depthguard accepted such a value). ``unknown``:
    (n,) bool, points whose coordinates are not known (masked): only 0 is safe for them. ``tag`` prefixes violation
    labels (what kind of bad input it was). Returns the outcome label."""
    kind_ = kind

    def violation(kind, label, detail=""):  # noqa: F811 - the module's, with the tag
        _violation(kind_, f"{tag}: {label}" if tag else label, detail)

    points_camera = np.asarray(points_camera, dtype=np.float64).reshape(-1, 3)
    n = len(points_camera)
    margin = facet_margins(points_camera, wall)
    exact = np.maximum(margin, 0.0)
    unknown = np.zeros(n, bool) if unknown is None else np.asarray(unknown, bool)
    d = np.asarray(result.distance)
    where = f" ({context})" if context else ""
    if d.shape != (n,) or len(result.flags) != n or np.asarray(result.direction).shape != (n, 3):
        violation(kind, "result of the wrong length", f"{n} points, distance shape {d.shape}{where}")
    if np.isnan(d).any() or (d < 0).any():
        i = int(np.argmax(np.isnan(d) | (d < 0)))
        violation(kind, "NaN or negative distance", _fmt(i, points_camera, exact, d, result.flags) + where)
    if not np.all(np.isfinite(np.asarray(result.direction))):
        violation(kind, "non-finite direction", where)
    rho_ok = isinstance(rho, float)
    for i in range(n):
        flags = result.flags[i]
        if unknown[i] or margin[i] < -TOL:
            if d[i] != 0.0:
                label = "unknown (masked) point answered" if unknown[i] else "point in occupied/unseen space not 0"
                violation(kind, label, _fmt(i, points_camera, exact, d, result.flags) + where)
            if not (flags & FLAGS_ZERO_OK):
                violation(kind, "0 without inside/outside-view flag", _fmt(i, points_camera, exact, d, result.flags)
                          + where)
            continue
        nothing_near = rho_ok and exact[i] >= rho - TOL
        if aggregate == "mean":
            if rho_ok and exact[i] < rho - TOL and not (d[i] < rho + TOL):
                violation(kind, "mean: nothing reported within rho though an obstacle is",
                          _fmt(i, points_camera, exact, d, result.flags) + f", rho {rho!r}" + where)
            continue
        if d[i] <= exact[i] + TOL:
            continue
        if math.isinf(d[i]) and nothing_near:
            continue
        label = "inf though an obstacle is within rho" if math.isinf(d[i]) else "distance above exact (optimistic)"
        violation(kind, label, _fmt(i, points_camera, exact, d, result.flags) + f", rho {rho!r}, aggregate "
                  f"{aggregate}" + where)
    return "answered: oracle holds"


# ------------------------------------------------------------------------------------------------- the CLI


def run_cli(argv, *, seconds: float = 10.0, trace: bool = True):
    """``depthguard.cli.main(argv)`` in-process, bounded, with stdout and stderr captured. Returns (exit status,
    stdout, stderr, Bound) or raises the bound's exception."""
    from cli_support import lab_main, main, program

    out, err = io.StringIO(), io.StringIO()
    with bounded(seconds, trace=trace) as stats, contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = (lab_main if program(argv) == "depthguard-lab" else main)([str(a) for a in argv])
        except SystemExit as exc:  # argparse's usage errors
            code = exc.code
    return code, out.getvalue(), err.getvalue(), stats


def cli_outcome(kind: str, code, stderr: str, names, *, allow_success: bool = False, context: str = "",
                tag: str = "") -> str:
    """Check a CLI run against the rule: exit 2 with exactly one line on stderr that starts with
    ``depthguard: error:`` and names the input (one of ``names``, case-insensitive), never exit 3 nor a traceback.
    ``allow_success``: exit 0 is also acceptable (the input may be valid by chance)."""
    prefix = f"{tag}: " if tag else ""

    def violation(kind, label, detail=""):  # noqa: F811 - the module's, with the tag
        _violation(kind, prefix + label, detail)

    lines = stderr.splitlines()
    where = f"{context}: exit {code}, stderr {stderr[:600]!r}"
    if "Traceback" in stderr:
        violation(kind, "traceback on stderr", where)
    if code == 0 and allow_success:
        return "exit 0 (valid by chance)"
    if code == 3 or "internal error" in stderr:
        violation(kind, "exit 3 (internal error)", where)
    if code == 0:
        violation(kind, "exit 0 (bad input accepted)", where)
    if code != 2:
        violation(kind, f"exit {code}", where)
    if len(lines) != 1:
        violation(kind, f"{len(lines)} lines on stderr", where)
    if not (lines[0].startswith("depthguard: error:") or lines[0].startswith("depthguard-lab: error:")):
        violation(kind, "stderr line does not start with 'depthguard: error:' (or 'depthguard-lab: error:')",
                  where)
    if names and not any(str(name).lower() in lines[0].lower() for name in names):
        violation(kind, "error line does not name the input", f"expected one of {list(names)}; {where}")
    return "exit 2, one line"


class CliWorker:
    """A persistent Python process that runs ``depthguard.cli.main(argv)`` in-process (fast: depthguard is imported
    once), bounded by :func:`bounded` there, one request at a time. A crash (a segfault in a kernel), a hang that the
    alarm cannot interrupt, or a blown memory bound kills only the worker: it is counted and the worker restarted.
    It imports the same depthguard as the tests (its folder is put first on PYTHONPATH)."""

    def __init__(self):
        self.process = None
        self.log = None

    def _start(self):
        self.log = tempfile.TemporaryFile()
        env = dict(os.environ)
        library = str(Path(dg.__file__).resolve().parent.parent)
        env["PYTHONPATH"] = os.pathsep.join([library, str(Path(__file__).resolve().parent)] + (
            [env["PYTHONPATH"]] if env.get("PYTHONPATH") else []))
        env.pop("DEPTHGUARD_DEBUG", None)
        self.process = subprocess.Popen([sys.executable, str(Path(__file__).resolve()), "--worker"],
                                        stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=self.log, env=env,
                                        cwd=tempfile.gettempdir(), start_new_session=True)

    def run(self, argv, seconds: float, trace: bool) -> dict:
        import select

        if self.process is None or self.process.poll() is not None:
            self._start()
        request = json.dumps({"argv": [str(a) for a in argv], "seconds": seconds, "trace": trace}) + "\n"
        try:
            self.process.stdin.write(request.encode())
            self.process.stdin.flush()
        except BrokenPipeError:
            return self._died()
        fd = self.process.stdout.fileno()
        buffer = b""
        deadline = time.monotonic() + seconds * 2 + 60  # startup and the alarm's own margin
        while not buffer.endswith(b"\n"):
            left = deadline - time.monotonic()
            ready = select.select([fd], [], [], max(left, 0))[0] if left > 0 else []
            if not ready:
                self.kill()
                return {"timeout": True, "how": "killed by the watchdog"}
            chunk = os.read(fd, 1 << 20)
            if not chunk:
                return self._died()
            buffer += chunk
        return json.loads(buffer)

    def _died(self) -> dict:
        code = self.process.wait()
        self.log.seek(0)
        tail = self.log.read()[-1500:].decode(errors="replace")
        self.process = None
        how = f"killed by signal {-code}" if code < 0 else f"exit status {code}"
        return {"crash": how, "log": tail}

    def kill(self):
        if self.process is not None and self.process.poll() is None:
            os.killpg(self.process.pid, signal.SIGKILL)
            self.process.wait()
        self.process = None


WORKER = CliWorker()
atexit.register(WORKER.kill)


def _worker_main():
    """The worker's loop: requests on stdin, replies on a private copy of stdout (fd 1 itself goes to /dev/null, so
    that whatever C code prints cannot garble a reply)."""
    replies = os.fdopen(os.dup(1), "w")
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, 1)
    for line in sys.stdin:
        request = json.loads(line)
        from PIL import EpsImagePlugin  # pillow is a dependency: a missing one must fail, never pass silently

        EpsImagePlugin.gs_binary = None  # look for Ghostscript again: an attempt would show in the audit hook
        try:
            code, out, err, stats = run_cli(request["argv"], seconds=request["seconds"], trace=request["trace"])
            reply = {"code": code if isinstance(code, int) or code is None else str(code), "stdout": out,
                     "stderr": err, "peak": stats.peak, "seconds": stats.seconds}
        except CampaignTimeout:
            reply = {"timeout": True, "how": "alarm"}
        except ChildProcessAttempt as exc:
            reply = {"child": str(exc)}
        except MemoryError as exc:
            reply = {"memory": repr(exc)}
        except BaseException as exc:  # noqa: BLE001 - reported, the worker goes on
            reply = {"crash": f"{type(exc).__name__}: {exc}", "log": traceback.format_exc()[-1500:]}
        replies.write(json.dumps(reply) + "\n")
        replies.flush()


def cli_call(kind: str, argv, names, *, seconds: float = 10.0, allow_success: bool = False, context: str = "",
             tag: str = "", trace: bool = True):
    """Run the CLI in the worker and check it against the rule; returns (outcome label, stdout, exit status)."""
    prefix = f"{tag}: " if tag else ""
    reply = WORKER.run(argv, seconds, trace)
    if reply.get("timeout"):
        _violation(kind, prefix + "hang (time bound exceeded)", f"{context}: {seconds} s ({reply['how']}); {argv}")
    if "child" in reply:
        _violation(kind, prefix + "child process started", f"{context}: {reply['child']}")
    if "memory" in reply:
        _violation(kind, prefix + "memory bound exceeded (MemoryError)", f"{context}: {reply['memory']}")
    if "crash" in reply:
        _violation(kind, prefix + f"process crashed ({reply['crash'].split(':')[0]})",
                   f"{context}: {reply['crash']}\n{reply.get('log', '')}")
    if reply["peak"] > FILE_PEAK_LIMIT:
        _violation(kind, prefix + "memory peak above bound", f"{context}: {reply['peak'] / 1e6:.0f} MB")
    code = reply["code"]
    return cli_outcome(kind, code, reply["stderr"], names, allow_success=allow_success, context=context,
                       tag=tag), reply["stdout"], code


def run_cli_subprocess(argv, *, timeout: float = 60.0, address_space: int | None = None, env=None):
    """The real ``.venv/bin/depthguard`` in a new session, its address space limited (``ulimit -v``), killed with its
    process group after ``timeout``. Returns (exit status or None on timeout, stdout, stderr, seconds, its own peak
    resident memory in bytes, from wait4)."""
    import threading

    limit_kb = (address_space or (4 << 30)) // 1024
    command = ["/bin/sh", "-c", f'ulimit -v {limit_kb} && exec "$0" "$@"', str(DEPTHGUARD_EXE), *map(str, argv)]
    start = time.perf_counter()
    with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err:
        process = subprocess.Popen(command, stdout=out, stderr=err, start_new_session=True, env=env)
        killed = []

        def kill():
            killed.append(True)
            with contextlib.suppress(ProcessLookupError):
                os.killpg(process.pid, signal.SIGKILL)

        timer = threading.Timer(timeout, kill)
        timer.start()
        try:
            _, status, usage = os.wait4(process.pid, 0)
        finally:
            timer.cancel()
        process.returncode = os.waitstatus_to_exitcode(status)
        out.seek(0)
        err.seek(0)
        stdout, stderr = out.read().decode(errors="replace"), err.read().decode(errors="replace")
    code = None if killed else process.returncode
    return code, stdout, stderr, time.perf_counter() - start, usage.ru_maxrss * 1024


# ------------------------------------------------------------------------------------------------- files


RIG_TEMPLATE = """\
depth_scale: 0.001
noise: none
principal: p
cameras:
  - name: p
    width: {W}
    height: {H}
    fx: {FX}
    fy: {FY}
    cx: {CX}
    cy: {CY}
    T_world_camera: [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]
    depth_range: [{Z_MIN}, {Z_MAX}]
"""

SECONDARY_TEMPLATE = """\
  - name: s
    width: {W}
    height: {H}
    fx: {FX}
    fy: {FY}
    cx: {CX}
    cy: {CY}
    T_world_camera: [[1, 0, 0, 0.2], [0, 1, 0, 0.05], [0, 0, 1, -0.1], [0, 0, 0, 1]]
    depth_range: [{Z_MIN}, {Z_MAX}]
"""
#: The secondary camera of the file rig, as T_principal_secondary (the principal is the world frame).
FILE_SECONDARY = rigid(np.eye(3), [0.2, 0.05, -0.1])
FILE_WALL_MM = 2000

_FORMAT = dict(W=W, H=H, FX=FX, FY=FY, CX=CX, CY=CY, Z_MIN=Z_MIN, Z_MAX=Z_MAX)


def rig_text(two: bool = False) -> str:
    text = RIG_TEMPLATE.format(**_FORMAT)
    return text + SECONDARY_TEMPLATE.format(**_FORMAT) if two else text


FILE_POINTS = np.array([[0.0, 0.0, 1.0], [0.3, -0.2, 1.9], [0.0, 0.0, 2.5], [0.5, 0.1, 0.9], [0.0, 0.0, 0.2]])


class Files:
    """A folder of valid input files for the CLI (the wall at 2 m, principal ``p``, secondary ``s``), and helpers to
    add bad ones. The folder is removed by :meth:`close`."""

    def __init__(self):
        self.dir = Path(tempfile.mkdtemp(prefix="dg-campaign-"))
        self.rig = self.write("rig.yaml", rig_text())
        self.rig2 = self.write("rig2.yaml", rig_text(two=True))
        from PIL import Image

        wall = wall_image(FILE_WALL_MM, "u16")
        self.png = self.dir / "depth.png"
        Image.fromarray(wall).save(self.png)
        self.png_s = self.dir / "depth_s.png"
        Image.fromarray(secondary_image(FILE_SECONDARY, FILE_WALL_MM * 0.001, "u16")).save(self.png_s)
        self.npy = self.dir / "depth.npy"
        np.save(self.npy, wall_image(FILE_WALL_MM * 0.001, "f32"))
        self.tif = self.dir / "depth.tif"
        Image.fromarray(wall_image(FILE_WALL_MM * 0.001, "f32"), mode="F").save(self.tif)
        self.pgm = self.dir / "depth.pgm"
        self.pgm.write_bytes(f"P5\n{W} {H}\n65535\n".encode() + wall.astype(">u2").tobytes())
        self.csv = self.write("points.csv", "x,y,z\n" + "".join(f"{x},{y},{z}\n" for x, y, z in FILE_POINTS))
        self.json = self.write("points.json", json.dumps(FILE_POINTS.tolist()))
        self._map = None

    @property
    def map(self) -> Path:
        """A valid depth grid map of rig2 (principal p), written by depthguard's own save_map (a fixture, not an
        expected value)."""
        if self._map is None:
            from depthguard.depthgrid import build_map, save_map

            self._map = self.dir / "map.npz"
            save_map(build_map(dg.load_rig(self.rig2), "p"), self._map)
        return self._map

    def write(self, name: str, content) -> Path:
        path = self.dir / name
        path.parent.mkdir(parents=True, exist_ok=True)
        if isinstance(content, bytes):
            path.write_bytes(content)
        else:
            path.write_text(content)
        return path

    def fifo(self, name: str) -> Path:
        path = self.dir / name
        os.mkfifo(path)
        return path

    def dev_zero(self, name: str) -> Path:
        """A symbolic link named ``name`` (so that its suffix picks a reader) to /dev/zero."""
        path = self.dir / name
        path.symlink_to("/dev/zero")
        return path

    def folder(self, name: str) -> Path:
        path = self.dir / name
        path.mkdir()
        return path

    def distance_argv(self, *, rig=None, depth=None, points=None, extra=(), two: bool = False, depth_s=None):
        argv = ["distance", "--rig", rig or (self.rig2 if two else self.rig), "--depth", f"p={depth or self.png}",
                "--points", points or self.json, "--json"]
        if two:
            argv += ["--depth", f"s={depth_s or self.png_s}"]
        return argv + list(extra)

    def close(self):
        shutil.rmtree(self.dir, ignore_errors=True)


def check_cli_json(kind: str, stdout: str, points_world, wall: float, rho: float, aggregate: str = "hybrid",
                   context: str = "") -> str:
    """Apply the oracle to ``distance --json`` output (the file rig: the principal is the world frame)."""
    try:
        records = json.loads(stdout)
    except json.JSONDecodeError:
        violation(kind, "exit 0 without a JSON result", f"{context}: {stdout[:300]!r}")
    d = np.array([math.inf if r["distance"] is None else r["distance"] for r in records], dtype=np.float64)
    flags = tuple(Flag(sum(getattr(Flag, name.upper()) for name in r["flags"])) for r in records)

    class _Result:  # the fields check_result reads
        distance = d
        direction = np.array([r["direction"] for r in records], dtype=np.float64).reshape(-1, 3)

    _Result.flags = flags
    return check_result(kind, _Result, points_world, wall, rho, aggregate, context=context)


# --------------------------------------------------------------------------------------------- numbers


def real_value(x):
    """The real number a scalar argument denotes (bool as 0/1, numeric strings, Decimal, Fraction, complex with a
    zero imaginary part), or None when it denotes none."""
    if isinstance(x, (bool, np.bool_)):
        return float(x)
    if isinstance(x, (int, float, np.integer, np.floating, Decimal, Fraction)):
        try:
            return float(x)
        except (OverflowError, ValueError):
            return None
    if isinstance(x, (complex, np.complexfloating)):
        return float(x.real) if x.imag == 0 else None
    if isinstance(x, (str, bytes)):
        try:
            return float(x)
        except ValueError:
            return None
    return None


if __name__ == "__main__" and sys.argv[1:] == ["--worker"]:
    _worker_main()
elif __name__ == "__main__":  # print a saved report: python tests/campaign_support.py REPORT.json
    data = json.loads(Path(sys.argv[1]).read_text())
    for kind, counts in data["counts"].items():
        COUNTS[kind].update(counts)
    for line in table():
        print(line)
    for kind, items in data.get("violations", {}).items():
        for item in items:
            print(f"\n[{kind}] {item['label']}\n{item['detail']}")
