"""The monitor decides once, by one rule, which method answers (issue 8, "Decide once, with one rule").

:meth:`DistanceMonitor.plan`: no usable frame -> no camera answers (distance 0); one usable frame -> the single-camera
method on it, the same answer whatever else the rig holds; several -> the depth grid of each principal with a usable
frame, or of the first usable camera when no principal has one. A stale or missing camera of the rig flags every
answer, and ``principal`` names the camera that answered. Every branch is tested here against answers computed
another way: the single-camera function on the same frame, or a monitor over a smaller rig.
"""

from __future__ import annotations

import numpy as np
import pytest

import depthguard as dg
from depthguard.scenes import Box, render_depth
from depthguard.transforms import look_at

Flag = dg.Flag
SCENE = [Box.from_bounds([-4, -4, -0.1], [4, 4, 0]), Box.from_bounds([-0.2, -0.2, 0], [0.2, 0.2, 1.0])]
EYES = {"p": [2.5, 0.0, 1.4], "s": [0.0, 2.5, 1.4], "t": [-2.0, -1.5, 1.6]}
POINTS = np.array([[0.5, 0.0, 0.6], [0.0, 0.5, 0.9], [-0.6, -0.3, 0.4], [0.3, 0.3, 1.3]])
NOW = 10.0


def camera(name: str) -> dg.PinholeCamera:
    return dg.PinholeCamera(name, 80, 60, 65.6, 65.6, 39.5, 29.5, look_at(EYES[name], [0, 0, 0.5]),
                            depth_range=(0.3, 6.0), noise=dg.NoiseModel.none())


def rig(*names: str, principal: str = "p") -> dg.Rig:
    return dg.Rig({n: camera(n) for n in names}, principal=principal if principal in names else None)


def frame(name: str, t: float = NOW) -> dg.DepthImage:
    cam = camera(name)
    return dg.depth_image(render_depth(cam, SCENE), cam, timestamp=t)


def monitor(r: dg.Rig, **kwargs) -> dg.DistanceMonitor:
    return dg.DistanceMonitor(r, rho=0.6, aggregate="min", max_age=0.5, **kwargs)


def single(name: str) -> dg.DistanceResult:
    """The single-camera answer on camera ``name``'s frame, from the library's function, not the monitor."""
    cam = camera(name)
    return dg.single_camera_distances(dg.prepare_depth(frame(name), cam), POINTS, 0.6, "min")


STALE = NOW - 1.0  # older than max_age


def test_no_usable_frame_answers_zero_flagged_and_names_no_camera():
    m = monitor(rig("p", "s"))
    missing = m.query({}, POINTS, now=NOW)
    stale = m.query({"p": frame("p", STALE)}, POINTS, now=NOW)
    assert m.plan({}, {}).kind == "blind"
    for result, flag in ((missing, Flag.MISSING_CAMERA), (stale, Flag.STALE_CAMERA | Flag.MISSING_CAMERA)):
        assert np.all(result.distance == 0) and np.all(result.blind_distance == 0)
        assert all(f == flag for f in result.flags) and result.principal == ("",) * len(POINTS)


def test_one_usable_frame_is_the_single_camera_method_whatever_the_rig_holds():
    alone = monitor(rig("p")).query({"p": frame("p")}, POINTS, now=NOW)
    expected = single("p")
    assert np.array_equal(alone.distance, expected.distance) and alone.flags == expected.flags
    assert alone.principal == ("p",) * len(POINTS)
    # the same frame in a rig of three cameras, the others missing: the same numbers, flagged missing
    in_three = monitor(rig("p", "s", "t")).query({"p": frame("p")}, POINTS, now=NOW)
    assert np.array_equal(in_three.distance, expected.distance)
    assert np.array_equal(in_three.direction, expected.direction)
    assert all(f == e | Flag.MISSING_CAMERA for f, e in zip(in_three.flags, expected.flags))


def test_a_missing_principal_lets_the_secondary_answer_alone_flagged():
    result = monitor(rig("p", "s")).query({"s": frame("s")}, POINTS, now=NOW)
    expected = single("s")
    assert np.array_equal(result.distance, expected.distance)
    assert result.principal == ("s",) * len(POINTS)
    assert all(Flag.MISSING_CAMERA in f for f in result.flags)


def test_a_stale_principal_lets_the_fresh_camera_answer_instead_of_zero():
    m = monitor(rig("p", "s"))
    result = m.query({"p": frame("p", STALE), "s": frame("s")}, POINTS, now=NOW)
    expected = single("s")
    assert np.array_equal(result.distance, expected.distance) and np.any(result.distance > 0)
    assert all(Flag.STALE_CAMERA in f and Flag.MISSING_CAMERA not in f for f in result.flags)
    plan = m.plan({"s": None}, {"p": STALE})
    assert (plan.kind, plan.principals, plan.absent) == ("single", ("s",), Flag.STALE_CAMERA)


def test_with_the_principal_stale_the_first_fresh_camera_of_the_rig_fuses_in_its_place():
    three = rig("p", "s", "t")
    result = monitor(three).query({"p": frame("p", STALE), "s": frame("s"), "t": frame("t")}, POINTS, now=NOW)
    assert result.principal == ("s",) * len(POINTS)
    assert all(Flag.STALE_CAMERA in f for f in result.flags)
    # the same as a monitor whose principal is "s" with "p" blind: the same grid, the same frames
    reference = monitor(three, principals=["s"]).query({"s": frame("s"), "t": frame("t")}, POINTS, now=NOW)
    assert np.array_equal(result.distance, reference.distance)
    assert all(f == (r & ~Flag.MISSING_CAMERA) | Flag.STALE_CAMERA for f, r in zip(result.flags, reference.flags))


def test_fused_answers_name_their_principal_and_flag_a_missing_secondary_as_missing():
    three = rig("p", "s", "t")
    both = monitor(three).query({"p": frame("p"), "s": frame("s")}, POINTS, now=NOW)
    assert both.principal == ("p",) * len(POINTS)
    assert all(Flag.MISSING_CAMERA in f and Flag.STALE_CAMERA not in f for f in both.flags)
    full = monitor(three).query({n: frame(n) for n in ("p", "s", "t")}, POINTS, now=NOW)
    assert not any(f & (Flag.MISSING_CAMERA | Flag.STALE_CAMERA) for f in full.flags)
    assert np.all(full.distance >= both.distance - 1e-12)  # a third camera only clears more


def test_several_principals_give_each_point_the_largest_answer_whose_view_holds_its_region():
    r = rig("p", "s")
    frames = {n: frame(n) for n in ("p", "s")}
    by_p = monitor(r, principals=["p"]).query(frames, POINTS, now=NOW)
    by_s = monitor(r, principals=["s"]).query(frames, POINTS, now=NOW)
    both = monitor(r, principals=["p", "s"]).query(frames, POINTS, now=NOW)
    for i in range(len(POINTS)):
        answers = {"p": by_p, "s": by_s}
        holds = [n for n in ("p", "s") if Flag.REGION_OUTSIDE_VIEW not in answers[n].flags[i]]
        expected = max(holds, key=lambda n: answers[n].distance[i]) if holds else "p"
        assert both.distance[i] == answers[expected].distance[i]
        assert both.distance[i] == answers[both.principal[i]].distance[i]


@pytest.mark.parametrize("stale_names, given, kind", [((), ("p", "s"), "fused"), (("p",), ("p", "s"), "single"),
                                                      (("p", "s"), ("p", "s"), "blind"), ((), ("s",), "single"),
                                                      ((), (), "blind")])
def test_the_plan_is_one_rule(stale_names, given, kind):
    m = monitor(rig("p", "s"))
    usable = {n: None for n in given if n not in stale_names}
    stale = {n: STALE for n in stale_names}
    plan = m.plan(usable, stale)
    assert plan.kind == kind
    expected = Flag(0)
    if stale_names:
        expected |= Flag.STALE_CAMERA
    if len(given) < 2:
        expected |= Flag.MISSING_CAMERA
    assert plan.absent == expected


@pytest.mark.parametrize("option", [dict(v_max=float("nan")), dict(v_max=0.0), dict(v_max=-2.0), dict(v_max="2"),
                                    dict(memory_voxel=float("inf")), dict(memory_voxel=0.0), dict(memory="yes")])
def test_memory_options_are_checked_whether_or_not_the_rig_has_a_workspace(option):
    for r in (rig("p", "s"), dg.Rig(rig("p", "s").cameras, principal="p", workspace=[[-1, -1, 0], [1, 1, 1.5]])):
        with pytest.raises(dg.InputError, match=next(iter(option))):
            dg.DistanceMonitor(r, **option)
