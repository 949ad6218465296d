"""The frame-set loop of live input and replay (depthguard.live): grouping by stamp, carried frames, waits, idle
answers, joints near each stamp, cameras that restart."""

import math

import numpy as np
import pytest

import depthguard as dg
from depthguard.errors import InputError
from depthguard.live import FrameSetLoop, JointHistory


def camera(name):
    return dg.PinholeCamera(name, 4, 3, 2.0, 2.0, 2.0, 1.5, np.eye(4))


def frame(name, t):
    return dg.depth_image(np.full((3, 4), 1000, dtype=np.uint16), camera(name), timestamp=t)


def test_joints_are_interpolated_between_near_states_held_briefly_and_never_guessed():
    history = JointHistory(gap=0.05, hold=0.005)
    assert history.at(1.0) is None  # nothing yet
    assert history.add(1.0, [0.0, 1.0]) and history.add(1.01, [1.0, 3.0])
    np.testing.assert_allclose(history.at(1.0025), [0.25, 1.5])
    np.testing.assert_array_equal(history.at(1.01), [1.0, 3.0])
    np.testing.assert_array_equal(history.at(1.014), [1.0, 3.0])  # held: 4 ms after the last state
    assert history.at(1.016) is None  # 6 ms after it: no joints
    assert history.at(0.999) is None  # before the first state: never extrapolated
    assert history.add(1.2, [2.0, 2.0])
    assert history.at(1.1) is None  # between two states 0.19 s apart: a hole, not an interpolation
    assert not history.add(1.2, [9.0, 9.0]) and not history.add(1.1, [9.0, 9.0]) and history.refused == 2
    assert not history.add(1.3, [math.nan, 0.0]) and history.refused == 3


def test_the_history_keeps_its_last_states_only():
    history = JointHistory(capacity=4)
    for k in range(10):
        history.add(k * 0.001, [float(k)])
    assert len(history) == 4
    assert history.at(0.0055) is None  # forgotten
    np.testing.assert_allclose(history.at(0.0075), [7.5])


def loop_with_joints(**options):
    loop = FrameSetLoop(("a", "b"), wait=0.02, idle=0.1, **options)
    for k in range(2001):
        loop.add_joints(k * 0.002, [k * 0.002])
    return loop


def test_a_set_is_formed_when_every_camera_has_a_new_frame():
    loop = loop_with_joints()
    assert loop.add_frame(frame("a", 1.000)) == []
    (s,) = loop.add_frame(frame("b", 1.004))
    assert (s.why, s.time, s.new, s.no_joints) == ("complete", 1.004, ("a", "b"), ())
    assert list(s.images) == ["a", "b"]
    np.testing.assert_allclose(s.joints["a"], [1.0])
    np.testing.assert_allclose(s.joints["b"], [1.004])
    assert loop.add_frame(frame("b", 1.037)) == []  # b again before a: still waiting for a
    (s,) = loop.add_frame(frame("a", 1.033))
    assert s.why == "complete" and s.time == 1.037


def test_a_late_camera_is_waited_for_a_bounded_time_and_its_last_frame_carried_forward():
    loop = loop_with_joints()
    loop.add_frame(frame("a", 1.000))
    loop.add_frame(frame("b", 1.001))
    old_b = loop.camera("b").frame
    assert loop.add_frame(frame("a", 1.033)) == []
    assert loop.tick(1.052) == []
    (s,) = loop.tick(1.053)  # 20 ms after a's new frame: formed without b's
    assert (s.why, s.time, s.new) == ("waited", 1.053, ("a",))
    assert s.images["b"] is old_b  # carried forward: its age (52 ms) is the monitor's to judge
    # In replay the next message does the same: a frame past the deadline forms the waited set first.
    replay = loop_with_joints()
    replay.add_frame(frame("a", 1.000))
    replay.add_frame(frame("b", 1.001))
    replay.add_frame(frame("a", 1.033))
    (r,) = replay.add_frame(frame("a", 1.066))
    assert (r.why, r.time, r.new) == ("waited", 1.053, ("a",))


def test_answers_keep_coming_when_no_frame_does():
    loop = loop_with_joints()
    loop.add_frame(frame("a", 1.0))
    loop.add_frame(frame("b", 1.0))
    assert loop.tick(1.05) == []
    (s,) = loop.tick(1.1)
    assert (s.why, s.time, s.new) == ("idle", 1.1, ())
    (s,) = loop.tick(1.45)  # a late tick: one set at the latest idle deadline passed, not a burst
    assert (s.why, s.time) == ("idle", pytest.approx(1.4))


def test_a_frame_without_joints_near_its_stamp_is_left_out_and_named():
    loop = FrameSetLoop(("a", "b"), wait=0.02, idle=0.1, joints=JointHistory(hold=0.005))
    loop.add_joints(1.0, [0.0])
    loop.add_frame(frame("a", 1.001))  # held: 1 ms after the last joint state
    assert loop.add_frame(frame("b", 1.015)) == []  # 15 ms after it: the next joint state may still bracket it
    (s,) = loop.tick(1.021)  # it did not come within the wait
    assert s.why == "waited" and list(s.images) == ["a"] and s.no_joints == ("b",)
    loop.add_joints(1.01, [1.0])
    loop.add_joints(1.02, [2.0])
    (s,) = loop.tick(1.2)  # the joints came later: b's frame is in the next set
    assert s.why == "idle" and list(s.images) == ["a", "b"] and s.no_joints == ()
    np.testing.assert_allclose(s.joints["b"], [1.5])
    # A frame 0.2 s after the last joint state: no state can come near enough, so the set does not wait for one.
    loop.add_frame(frame("a", 1.4))
    (s,) = loop.add_frame(frame("b", 1.4))
    assert s.why == "complete" and s.no_joints == ("a", "b")


def test_by_default_no_joint_state_is_held_past_its_time():
    loop = FrameSetLoop(("a",), wait=0.02, idle=0.1)
    loop.add_joints(1.0, [0.0])
    assert loop.add_frame(frame("a", 1.0000003)) == []  # 0.3 us after the last state: waits for the next
    (s,) = loop.tick(1.03)
    assert s.why == "waited" and s.no_joints == ("a",) and s.images == {}  # none came: blind, named
    (s,) = loop.add_frame(frame("a", 1.0))  # exactly at a state's stamp: its joints (a stamp that went back)
    assert s.why == "complete" and s.reset == ("a",) and list(s.images) == ["a"]


def test_a_complete_set_waits_for_the_joint_state_after_its_stamps():
    loop = FrameSetLoop(("a", "b"), wait=0.02, idle=0.1)
    loop.add_joints(1.000, [0.0])
    loop.add_frame(frame("a", 1.003))
    assert loop.add_frame(frame("b", 1.008)) == []  # b's joints: after the last state by more than JOINT_HOLD
    (s,) = loop.add_joints(1.010, [1.0])
    assert (s.why, s.time, s.no_joints) == ("complete", 1.008, ())
    np.testing.assert_allclose(s.joints["a"], [0.3])
    np.testing.assert_allclose(s.joints["b"], [0.8])


def test_a_stamp_that_goes_back_resets_the_camera():
    loop = loop_with_joints()
    loop.add_frame(frame("a", 2.0))
    loop.add_frame(frame("b", 2.0))
    loop.add_frame(frame("a", 1.5))
    assert loop.camera("a").resets == 1 and loop.camera("a").frame.timestamp == 1.5
    (s,) = loop.add_frame(frame("b", 2.01))
    assert s.reset == ("a",)
    loop.add_frame(frame("a", 2.03))
    (s,) = loop.add_frame(frame("b", 2.04))
    assert s.reset == ()  # named once, in the set after the reset


def test_a_stamp_that_jumps_ahead_resets_the_camera():
    loop = loop_with_joints()
    loop.add_frame(frame("a", 2.0))
    loop.add_frame(frame("b", 2.0))
    loop.add_frame(frame("a", 2.0 + 0.9 * dg.config.STAMP_JUMP))  # within the jump: no reset
    assert loop.camera("a").resets == 0
    jumped = 2.0 + 0.9 * dg.config.STAMP_JUMP + 1.01 * dg.config.STAMP_JUMP
    loop.add_frame(frame("a", jumped))
    assert loop.camera("a").resets == 1 and loop.camera("a").frame.timestamp == jumped


def test_frames_of_unknown_cameras_or_without_stamps_are_refused_by_name():
    loop = loop_with_joints()
    with pytest.raises(InputError, match="'c'"):
        loop.add_frame(frame("c", 1.0))
    with pytest.raises(InputError, match="stamp"):
        loop.add_frame(dg.depth_image(np.zeros((3, 4), dtype=np.uint16), camera("a")))
    with pytest.raises(InputError):
        FrameSetLoop(("a", "a"))
