"""Campaign (issue 12, item 8), kind "time": frame timestamps, ``now`` and ``max_age``, one camera and fused.

Values: NaN, +-inf, huge (1e300, 1e308), negative, subnormal, -0.0, ordinary ages around ``max_age``, and frames
stamped in the future (100 s ahead, and just beyond the clock skew tolerance). Frames are built with
``dg.depth_image`` (which checks the timestamp), directly as ``dg.DepthImage(...)`` (a frozen dataclass: this skips
every check, so the monitor itself must not trust the stamp), or given as plain arrays (no timestamp).

The rule (docs/design.md §8 and §11): a frame older than ``max_age`` at ``now`` is stale; so is a frame stamped
later than ``now`` by more than ``SKEW`` (0.01 s, stated in campaign_support; the library's
``config.CLOCK_SKEW_TOLERANCE`` may not be looser): its time is wrong. A stale frame never counts as fresh: the
monitor raises a DepthguardError, or answers distance 0 with the flag STALE_CAMERA for every point (for a stale
secondary camera: it clears nothing, and every point whose distance is positive carries STALE_CAMERA).

Safe readings where the rule is silent (stated here, applied below):

- A frame whose timestamp is NaN or infinite, or absent, is stale whenever time matters (``max_age`` set, or ``now``
  given): its age cannot be known.
- ``now`` that is NaN or infinite makes every frame stale (or is refused); ``now=None`` with ``max_age`` set too.
- With ``max_age=None`` and ``now`` given, a frame from the future is still stale (its time is wrong).
- With ``max_age=None`` and ``now=None`` nothing can be judged: every frame is fresh.
- Within a relative 1e-9 of a threshold either answer is accepted (float rounding of ``now - t``).

A stale frame's content is an old view (the wall at OLD_WALL = 3.9 m, before it came nearer): if it is used as fresh,
points behind today's wall get positive distances, which the oracle for today's wall refuses. A fresh frame shows
today's wall, and the oracle holds. A frame the monitor treats as stale though it is fresh gets 0 (conservative):
counted, not failed.
"""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

import depthguard as dg
from campaign_support import (
    OLD_WALL,
    SKEW,
    Refused,
    call,
    campaign,
    check_result,
    finite,
    fused_rig,
    point_sets,
    record,
    rigid_transforms,
    secondary_image,
    secondary_layouts,
    single_rig,
    surveyed,
    to_world,
    violation,
    wall_image,
)
from depthguard import Flag, config

AGGREGATES = ["min", "mean", "hybrid"]
FRESH, STALE, EITHER = "fresh", "stale", "either"

TIME_SPECIALS = [math.nan, math.inf, -math.inf, 1e308, -1e308, 1e300, -1e300, 1e160, 5e-324, -5e-324, -0.0, 0.0]
#: How far ``now`` is after the frame (negative: the frame is from the future).
AGE_SPECIALS = [0.0, 0.05, 0.1, 0.0999999, 0.1000001, 1.0, 1e6, -100.0, -1.0, -0.02, -0.0100001, -0.0099, -1e6]


def _real(x) -> bool:
    return isinstance(x, (int, float, np.integer, np.floating)) and not isinstance(x, (bool, np.bool_))


def frame_state(t, now, max_age) -> str:
    """FRESH, STALE or EITHER for a frame stamped ``t`` (None: no stamp) at ``now`` with ``max_age`` (module
    docstring)."""
    if now is None:
        return FRESH if max_age is None else STALE
    if not (_real(now) and math.isfinite(now)):
        return STALE
    if t is None:
        return STALE if max_age is not None else FRESH
    if not math.isfinite(t):
        return STALE
    band = 1e-9 * max(1.0, abs(t), abs(now))
    with np.errstate(all="ignore"):
        age = float(now) - float(t)
    future = -age
    stale = future > SKEW + band or (max_age is not None and age > max_age + band)
    if stale:
        return STALE
    if future > SKEW - band or (max_age is not None and age > max_age - band):
        return EITHER
    return FRESH


def test_the_library_s_clock_skew_is_no_looser_than_the_campaign_s():
    assert 0 <= config.CLOCK_SKEW_TOLERANCE <= SKEW


@st.composite
def clocks(draw):
    """(now, max_age)."""
    max_age = draw(st.one_of(st.none(), st.sampled_from([0.1, 1.0, 1e-300, 5e-324, 1e6, 1e300]), finite(1e-6, 1e3)))
    if draw(st.integers(0, 4)) == 0:
        now = draw(st.one_of(st.none(), st.sampled_from(TIME_SPECIALS), finite(-1e9, 1e9), st.integers(-10, 10)))
    else:
        now = draw(st.one_of(finite(-1e6, 2e9), st.sampled_from([0.0, 1.7e9, 1e300, -1e300])))
    return now, max_age


@st.composite
def stamps(draw, now, max_age):
    """A frame's timestamp relative to ``now`` (ages around max_age, from the future) or wild."""
    choice = draw(st.integers(0, 9))
    if choice == 0:
        return None
    if choice <= 2 or not (_real(now) and math.isfinite(now)):
        return draw(st.one_of(st.sampled_from(TIME_SPECIALS), finite(-1e9, 1e9)))
    if choice <= 6:
        age = draw(st.sampled_from(AGE_SPECIALS))
    elif max_age is not None and math.isfinite(max_age):
        age = draw(st.one_of(finite(0.0, 2.0 * max_age), st.just(max_age * 1.5)))
    else:
        age = draw(finite(-200.0, 200.0))
    return float(now) - age


def _frame(how, name, data, scale, t, camera):
    if how == "array":
        return data
    if how == "depth_image":
        return dg.depth_image(data, camera, t)
    data = data.copy()
    data.setflags(write=False)
    return dg.DepthImage(camera=name, data=data, depth_scale=scale, timestamp=t)


def _effective(how, t):
    return None if how == "array" else t


def _targets(wall):
    """Points behind today's wall and in front of the old one (exact distance 0)."""
    z = 0.5 * (wall + min(OLD_WALL, 3.6))
    return [(0.0, 0.0, z), (0.3 * z, -0.2 * z, z), (-0.5 * z, 0.4 * z, z)]


HOW = st.sampled_from(["depth_image", "DepthImage", "DepthImage", "array"])


@campaign(80)
@given(G=rigid_transforms(), mm=st.integers(600, 3300), f32=st.booleans(), clock=clocks(), data=st.data(), how=HOW,
       aggregate=st.sampled_from(AGGREGATES), rho=st.floats(0.05, 1.0))
@surveyed
def test_time_single_camera(G, mm, f32, clock, data, how, aggregate, rho):
    kind = "time: single"
    now, max_age = clock
    t = data.draw(stamps(now, max_age))
    wall = mm * 0.001
    state = frame_state(_effective(how, t), now, max_age)
    shown = OLD_WALL if state == STALE else wall
    image = wall_image(shown, "f32") if f32 else wall_image(round(shown * 1000), "u16")
    wall_true = float(np.float32(wall)) if f32 else wall
    points = np.array(data.draw(point_sets(wall_true)) + _targets(wall_true))
    rig = single_rig(G)
    tag = f"{state} frame via {how}"

    def query():
        frame = _frame(how, "p", image, 1.0 if f32 else 0.001, t, rig.cameras["p"])
        monitor = dg.DistanceMonitor(rig, rho=rho, aggregate=aggregate, max_age=max_age)
        return monitor.query({"p": frame}, to_world(G, points), now=now)

    result = call(kind, query, tag=tag)
    context = f"t={t!r}, now={now!r}, max_age={max_age!r}, {how}"
    if isinstance(result, Refused):
        record(kind, result.label)
        return
    if state == STALE:
        if not (np.all(result.distance == 0.0) and all(Flag.STALE_CAMERA in f for f in result.flags)):
            violation(kind, f"{tag}: stale frame counted as fresh",
                      f"{context}: distances {result.distance.tolist()}, flags {[f.names for f in result.flags]}")
        record(kind, "stale: 0 + stale_camera")
        return
    outcome = check_result(kind, result, points, wall_true, rho, aggregate, context=context, tag=tag)
    if all(Flag.STALE_CAMERA in f for f in result.flags) and state == FRESH:
        outcome = "fresh frame answered as stale (conservative)"
    record(kind, outcome)


@campaign(50)
@given(G=rigid_transforms(), mm=st.integers(600, 3300), layout=secondary_layouts(), clock=clocks(), data=st.data(),
       how_p=HOW, how_s=HOW, aggregate=st.sampled_from(AGGREGATES), rho=st.floats(0.05, 1.0))
@surveyed
def test_time_fused(G, mm, layout, clock, data, how_p, how_s, aggregate, rho):
    kind = "time: fused"
    now, max_age = clock
    t_p = data.draw(stamps(now, max_age))
    t_s = data.draw(stamps(now, max_age))
    wall = mm * 0.001
    state_p = frame_state(_effective(how_p, t_p), now, max_age)
    state_s = frame_state(_effective(how_s, t_s), now, max_age)
    principal = wall_image(round((OLD_WALL if state_p == STALE else wall) * 1000), "u16")
    secondary = secondary_image(layout, OLD_WALL if state_s == STALE else wall, "f32")
    points = np.array(data.draw(point_sets(wall)) + _targets(wall))
    rig = fused_rig(G, layout)
    tag = f"principal {state_p} via {how_p}, secondary {state_s} via {how_s}"

    def query():
        frames = {"p": _frame(how_p, "p", principal, 0.001, t_p, rig.cameras["p"]),
                  "s": _frame(how_s, "s", secondary, 1.0, t_s, rig.cameras["s"])}
        monitor = dg.DistanceMonitor(rig, rho=rho, aggregate=aggregate, max_age=max_age)
        return monitor.query(frames, to_world(G, points), now=now)

    result = call(kind, query, tag=tag)
    context = f"t_p={t_p!r}, t_s={t_s!r}, now={now!r}, max_age={max_age!r}"
    if isinstance(result, Refused):
        record(kind, result.label)
        return
    blind = len(result.principal) > 0 and set(result.principal) == {""}
    if state_p == STALE and (state_s == STALE or (state_s == EITHER and blind)):
        if not (blind and np.all(result.distance == 0.0) and all(Flag.STALE_CAMERA in f for f in result.flags)):
            violation(kind, f"{tag}: stale frames counted as fresh",
                      f"{context}: distances {result.distance.tolist()}, flags {[f.names for f in result.flags]}")
        record(kind, "both stale: 0 + stale_camera")
        return
    if state_p == STALE:
        # The monitor's plan: the fresh secondary answers alone, by the single-camera method (whose own campaigns
        # judge it against the geometry), every answer flagged.
        if not (all(Flag.STALE_CAMERA in f for f in result.flags) and set(result.principal) == {"s"}):
            violation(kind, f"{tag}: stale principal counted as fresh",
                      f"{context}: principal {set(result.principal)}, flags {[f.names for f in result.flags]}")
        camera_s = rig.cameras["s"]
        alone = dg.single_camera_distances(dg.prepare_depth(dg.depth_image(secondary, camera_s), camera_s),
                                           to_world(G, points), rho, aggregate)
        if not np.array_equal(result.distance, alone.distance):
            violation(kind, f"{tag}: the secondary alone answered otherwise than the single-camera method",
                      f"{context}: {result.distance.tolist()} != {alone.distance.tolist()}")
        record(kind, "stale principal: secondary alone, flagged")
        return
    outcome = check_result(kind, result, points, wall, rho, aggregate, context=context, tag=tag)
    if state_s == STALE:
        unflagged = [i for i, f in enumerate(result.flags) if result.distance[i] > 0 and Flag.STALE_CAMERA not in f]
        if unflagged:
            violation(kind, f"{tag}: positive distance without stale_camera",
                      f"{context}: point #{unflagged[0]} distance {result.distance[unflagged[0]]!r}")
        outcome = "stale secondary: oracle holds, flagged"
    record(kind, outcome)


@campaign(30)
@given(mm=st.integers(600, 3300), max_age=st.one_of(st.none(), finite(1e-3, 10.0)), t=finite(-1e6, 1e6),
       later=st.sampled_from([1.0, 100.0, 1e6, math.inf, math.nan]), future=st.booleans(), data=st.data())
@surveyed
def test_time_same_frame_goes_stale(mm, max_age, t, later, future, data):
    """One monitor, one DepthImage object queried twice: fresh, then at a later ``now`` (or an earlier one, which
    puts the frame in the future). The cached preparation must not carry the first query's freshness over."""
    kind = "time: same frame later"
    rig = single_rig(np.eye(4))
    wall = mm * 0.001
    points = np.array(data.draw(point_sets(wall)) + _targets(wall))
    second = t - later if future else t + (later if max_age is None else later * max_age + max_age)
    state = frame_state(t, second, max_age)
    if state != STALE:
        return  # nothing to check: max_age None and a frame in the past never goes stale

    def query():
        frame = dg.depth_image(wall_image(mm, "u16"), rig.cameras["p"], t)
        monitor = dg.DistanceMonitor(rig, rho=0.5, aggregate="min", max_age=max_age)
        first = monitor.query({"p": frame}, points, now=t)
        return first, monitor.query({"p": frame}, points, now=second)

    out = call(kind, query)
    if isinstance(out, Refused):
        record(kind, out.label)
        return
    first, result = out
    check_result(kind, first, points, wall, 0.5, "min")
    if not (np.all(result.distance == 0.0) and all(Flag.STALE_CAMERA in f for f in result.flags)):
        violation(kind, "the same frame later: stale frame counted as fresh",
                  f"t={t!r}, now={second!r}, max_age={max_age!r}: distances {result.distance.tolist()}")
    record(kind, "stale: 0 + stale_camera")
