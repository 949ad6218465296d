"""LiveMonitor: queries never wait for frames (issue 8, "Ready in time").

Frames are prepared on a worker thread; a query answers from the latest fully prepared set. Checked here: the
answers equal DistanceMonitor's on the same frames (with the free-space memory and with a robot self-filtered on the
worker's OpenGL context); a query made while a set is being prepared answers from the previous set at once (the
preparation held on an event, so no timing decides the test); the newest set wins; a bad set is skipped and kept in
``errors``; a set gone stale at the query's time answers 0; before the first set, 0 and ``missing_camera``.
"""

from __future__ import annotations

import threading

import numpy as np
import pytest

import depthguard as dg
from depthguard._monitor import DistanceMonitor
from depthguard.robots import RobotModel
from depthguard.scenes import Box, render_depth
from depthguard.transforms import look_at

Flag = dg.Flag
EYES = {"p": [2.5, 0.0, 1.4], "s": [0.0, 2.5, 1.4]}
WORKSPACE = [[-1.2, -1.2, -0.1], [1.3, 1.3, 1.6]]
POINTS = np.array([[0.5, 0.0, 0.6], [0.0, 0.5, 0.9], [-0.6, -0.3, 0.4], [0.3, 0.3, 1.3]])
FPS = 30.0


def camera(name: str) -> dg.PinholeCamera:
    return dg.PinholeCamera(name, 80, 60, 65.6, 65.6, 39.5, 29.5, look_at(EYES[name], [0, 0, 0.5]),
                            depth_range=(0.3, 6.0), noise=dg.NoiseModel.none())


RIG = dg.Rig({n: camera(n) for n in EYES}, principal="p", workspace=WORKSPACE)


def frames_at(k: int) -> dict:
    """The frames of set k: a room and a box sliding along x, stamped k / FPS."""
    scene = [Box.from_bounds([-4, -4, -0.1], [4, 4, 0]), Box.from_bounds([-3, -4, 0], [-2.9, 4, 3]),
             Box.from_bounds([-0.2 + 0.02 * k, -0.2, 0], [0.2 + 0.02 * k, 0.2, 1.0])]
    return {n: dg.depth_image(render_depth(c, scene), c, timestamp=k / FPS) for n, c in RIG.cameras.items()}


def same(a: dg.DistanceResult, b: dg.DistanceResult) -> None:
    assert np.array_equal(a.distance, b.distance) and np.array_equal(a.direction, b.direction)
    assert a.flags == b.flags and a.principal == b.principal and a.timestamps == b.timestamps


def test_before_the_first_set_every_point_is_zero_and_missing():
    with dg.LiveMonitor(RIG, rho=0.5) as live:
        result = live.query(POINTS)
    assert np.all(result.distance == 0) and all(f == Flag.MISSING_CAMERA for f in result.flags)


def test_answers_equal_the_monitor_s_on_the_same_frames_with_memory():
    reference = DistanceMonitor(RIG, rho=0.5, aggregate="hybrid")
    with dg.LiveMonitor(RIG, rho=0.5, aggregate="hybrid") as live:
        for k in range(6):
            frames = frames_at(k)
            live.submit(frames, now=k / FPS)
            assert live.wait(60)
            expected = reference.query(frames, POINTS, now=k / FPS)
            for _ in range(2):  # the same prepared set, queried again
                same(live.query(POINTS, now=k / FPS), expected)
            assert live.latest_time == k / FPS
        assert live.prepared == 6 and live.errors == []


def test_a_robot_is_filtered_out_on_the_worker_thread():
    robot = RobotModel.default()
    q = np.array([0.0, 0.4, 0.0, -1.2, 0.0, 0.6, 0.0])
    frames = frames_at(0)
    reference = DistanceMonitor(RIG, rho=0.5, robot=robot).query(frames, POINTS, joints=q, now=0.0)
    with dg.LiveMonitor(RIG, rho=0.5, robot=robot) as live:
        live.submit(frames, joints=q, now=0.0)
        assert live.wait(120)
        same(live.query(POINTS, now=0.0), reference)
    # The robot was filtered: its self-filter's shell comes within rho of some points.
    assert any(dg.Flag.ROBOT_SHELL in f for f in reference.flags) and np.any(np.isfinite(reference.concession_distance))


def test_a_query_never_waits_for_the_set_being_prepared(monkeypatch):
    release, started = threading.Event(), threading.Event()
    original = DistanceMonitor.prepare_set

    def held(self, frames, **kwargs):
        if kwargs.get("now", 0.0) > 0.0:  # every set after the first: held until released
            started.set()
            assert release.wait(60)
        return original(self, frames, **kwargs)

    monkeypatch.setattr(DistanceMonitor, "prepare_set", held)
    first, second, third = frames_at(0), frames_at(5), frames_at(10)
    # No age limit here: the first set is asked for after 5 frame periods (0.17 s), older than the default 0.1 s.
    with dg.LiveMonitor(RIG, rho=0.5, max_age=None) as live:
        live.submit(first, now=0.0)
        assert live.wait(60)
        answer_first = live.query(POINTS, now=0.0)
        live.submit(second, now=5 / FPS)
        assert started.wait(60)
        # The second set is being prepared (held): the query answers from the first, at once.
        during = live.query(POINTS, now=5 / FPS)
        same(during, answer_first)
        assert not live.wait(0.01)
        live.submit(third, now=10 / FPS)  # waits behind the held one
        live.submit(third, now=10 / FPS)  # replaces it: the newest set wins
        assert live.dropped == 1
        release.set()
        assert live.wait(60)
        assert live.latest_time == 10 / FPS
        expected = DistanceMonitor(RIG, rho=0.5, max_age=None).query(third, POINTS, now=10 / FPS)
        assert np.array_equal(live.query(POINTS, now=10 / FPS).distance, expected.distance)


def test_a_bad_set_is_skipped_and_kept_and_the_worker_goes_on():
    with dg.LiveMonitor(RIG, rho=0.5) as live:
        live.submit(frames_at(0), now=0.0)
        assert live.wait(60)
        good = live.query(POINTS, now=0.0)
        live.submit({"p": np.zeros((3, 3), dtype=np.uint16)}, now=1 / FPS)  # the wrong size
        assert live.wait(60)
        assert len(live.errors) == 1 and "p" in str(live.errors[0])
        same(live.query(POINTS, now=1 / FPS), good)
        live.submit(frames_at(2), now=2 / FPS)
        assert live.wait(60) and live.latest_time == 2 / FPS


def test_a_set_gone_stale_at_the_query_s_time_answers_zero():
    with dg.LiveMonitor(RIG, rho=0.5, max_age=0.1) as live:
        live.submit(frames_at(0), now=0.0)
        assert live.wait(60)
        fresh = live.query(POINTS, now=0.05)
        assert np.any(fresh.distance > 0) and not any(Flag.STALE_CAMERA in f for f in fresh.flags)
        stale = live.query(POINTS, now=1.0)
        assert np.all(stale.distance == 0) and all(Flag.STALE_CAMERA in f for f in stale.flags)
        with pytest.raises(dg.InputError, match="now"):
            live.query(POINTS)
    with dg.LiveMonitor(RIG, rho=0.5) as live:  # the default max_age (0.1 s) for stamped frames
        live.submit(frames_at(0), now=0.0)
        assert live.wait(60)
        assert not live.query(POINTS, now=0.05).is_blind and live.query(POINTS, now=0.05).age == 0.05
        stale = live.query(POINTS, now=0.2)
        assert stale.is_blind and all(Flag.STALE_CAMERA in f for f in stale.flags)


def test_a_closed_monitor_takes_no_frames_and_bad_options_fail_at_once():
    live = dg.LiveMonitor(RIG, rho=0.5)
    live.close()
    with pytest.raises(dg.InputError, match="closed"):
        live.submit(frames_at(0), now=0.0)
    with pytest.raises(dg.InputError, match="rho"):
        dg.LiveMonitor(RIG, rho=-1.0)
