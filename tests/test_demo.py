"""``depthguard demo``, the Quick start's main job (issue 9): the closed loop run per mode, its figures and files.

The figures are checked against hand-made logs whose answers are written out here (contacts, reversals, the first
usable set), and the command end to end on a short run: one JSON object per mode with the fields the issue names,
a plot per mode, and figures that agree with the run's own log (the exact clearance it measured)."""

import json

import numpy as np
import pytest

from depthguard_lab.experiments import avoidance_demo
from depthguard_lab.simulation._closed_loop import LoopLog

FIELDS = {"collisions": int, "true_min_distance_m": float, "clearance_m": float, "task_error_after_m": float,
          "oscillation_per_s": float, "loop_hz": float}


def make_log(mode="avoid", steps=10, clearance=None, repulsive=None, scale=None, reported=None, age=None):
    """A LoopLog of ``steps`` control steps of 2 ms, 2 control points; the truth every step."""
    t = np.arange(steps) * 0.002
    ee = np.zeros((steps, 3))
    ee_ref = np.zeros((steps, 3))
    ee_ref[-1] = [0.03, 0.0, 0.04]  # 5 cm off at the end
    return LoopLog(
        mode=mode, times=t, q=np.zeros((steps, 7)), dq=np.zeros((steps, 7)), dq_requested=np.zeros((steps, 7)),
        ee=ee, ee_ref=ee_ref,
        reported=np.full((steps, 2), 0.3) if reported is None else reported,
        flags=np.zeros((steps, 2), dtype=np.int64),
        repulsive=np.zeros((steps, 3)) if repulsive is None else repulsive,
        scale=np.ones(steps) if scale is None else scale,
        data_age=np.full(steps, 0.04) if age is None else age, step_seconds=np.full(steps, 0.001),
        truth_steps=np.arange(steps), truth=np.tile([0.5, 0.2], (steps, 1)),
        clearance=np.full(steps, 0.1) if clearance is None else clearance, frames=1, wall_seconds=0.5)


def test_collisions_count_each_contact_once():
    clearance = np.array([0.1, 0.0, -0.01, 0.02, 0.05, -0.02, -0.03, 0.01, 0.0, 0.3])
    summary = avoidance_demo.summarize(make_log(clearance=clearance), 0.002)
    assert summary["collisions"] == 3  # steps 1-2, 5-6 and 8
    assert summary["clearance_m"] == pytest.approx(-0.03)
    assert avoidance_demo.summarize(make_log(clearance=-clearance[::-1] - 1), 0.002)["collisions"] == 1
    assert avoidance_demo.summarize(make_log(), 0.002)["collisions"] == 0


def test_oscillation_counts_reversals_of_the_reaction():
    r = np.zeros((10, 3))
    r[1:5, 0] = [0.2, -0.2, 0.2, 0.1]  # two reversals
    r[6:9, 1] = [0.1, 0.1, 0.1]  # steady: none
    avoid = avoidance_demo.summarize(make_log(repulsive=r), 0.002)
    assert avoid["oscillation_per_s"] == pytest.approx(2 / 0.02)
    tiny = r * 1e-4  # below REPULSIVE_EPSILON: not a reaction
    assert avoidance_demo.summarize(make_log(repulsive=tiny), 0.002)["oscillation_per_s"] == 0.0
    scale = np.array([1.0, 1.0, 0.4, 0.6, 0.3, 0.3, 0.9, 1.0, 1.0, 1.0])  # crosses 0.5 four times
    ssm = avoidance_demo.summarize(make_log("ssm", scale=scale), 0.002)
    assert ssm["oscillation_per_s"] == pytest.approx(4 / 0.02)
    assert ssm["time_reacting_s"] == pytest.approx(5 * 0.002)
    assert avoidance_demo.summarize(make_log("none", repulsive=r), 0.002)["oscillation_per_s"] == 0.0


def test_figures_of_a_run():
    reported = np.full((10, 2), np.inf)
    reported[:3] = 0.0  # before the first usable set: blind, not counted
    reported[5, 1] = 0.15
    age = np.full(10, 0.04)
    age[:3] = np.inf
    from dataclasses import replace
    from types import SimpleNamespace

    robot = SimpleNamespace(control_point_names=("link_a/0", "end_effector"), control_point_radii=np.array([0.1, 0.05]))
    summary = avoidance_demo.summarize(replace(make_log(reported=reported, age=age), robot=robot), 0.002)
    assert summary["per_link"] == {"link_a": None, "end_effector": pytest.approx(0.10)}  # from the surface
    assert summary["per_control_point"]["true_min_m"] == [0.5, 0.2]
    assert summary["true_min_distance_m"] == 0.2
    assert summary["task_error_after_m"] == pytest.approx(0.05)
    assert summary["loop_hz"] == pytest.approx(20.0) and summary["step_hz"] == pytest.approx(1000.0)
    assert summary["simulated_s"] == pytest.approx(0.02)


def test_demo_writes_one_summary_per_mode_and_plots(tmp_path, capsys):
    from depthguard_lab import cli

    assert cli.main(["demo", "--out", str(tmp_path), "--duration", "0.1", "--mode", "avoid", "--mode",
                     "none"]) == 0
    out = capsys.readouterr().out
    assert "collisions" in out and "task error end m" in out and "end_effector" in out
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert list(summary["modes"]) == ["avoid", "none"]
    assert summary["scene"] == avoidance_demo.SCENE and summary["control_hz"] == 500.0
    for mode, figures in summary["modes"].items():
        for field, kind in FIELDS.items():
            assert isinstance(figures[field], kind), (mode, field)
        assert figures["simulated_s"] == pytest.approx(0.1)
        assert figures["frames"] == 3  # 30 Hz over 0.1 s
        assert figures["collisions"] == 0 and figures["clearance_m"] > 0.5  # the person is still far at the start
        assert np.isfinite(figures["loop_hz"]) and figures["loop_hz"] > 0
        assert len(figures["per_control_point"]["true_min_m"]) == len(summary["control_points"]) == 9
        assert (tmp_path / f"demo_{mode}.png").stat().st_size > 5000
    assert not (tmp_path / "demo_ssm.png").exists()
    assert (tmp_path / "bag_avoid" / "metadata.yaml").is_file() and list((tmp_path / "bag_avoid").glob("*.mcap"))
    assert "bag_avoid" in out
    # Run again: the command replaces its own recording; --no-bag writes none.
    assert cli.main(["demo", "--out", str(tmp_path), "--duration", "0.05", "--mode", "avoid"]) == 0
    assert cli.main(["demo", "--out", str(tmp_path / "quiet"), "--duration", "0.05", "--mode", "avoid",
                     "--no-bag", "--cameras", "2"]) == 0
    assert not (tmp_path / "quiet" / "bag_avoid").exists()
    # four cameras round the robot by default (issue 8's reference layout), the scene's front two on request
    assert summary["cameras"] == ["principal", "second", "third", "fourth"]
    assert json.loads((tmp_path / "quiet" / "summary.json").read_text())["cameras"] == ["principal", "second"]


def test_the_demos_ssm_is_refused_where_it_cannot_be_sound_and_says_why(tmp_path, capsys):
    """Mode ssm cannot be sound in the demo's cells (its distances may leave out an object thicker than ISO 13855's
    70 mm lying on the robot: tests/test_closed_loop.py): the demo says so, with the band, and runs the others."""
    from depthguard_lab import cli

    assert cli.main(["demo", "--out", str(tmp_path), "--duration", "0.1", "--mode", "ssm", "--mode", "none",
                     "--no-bag"]) == 0
    out = capsys.readouterr().out
    assert avoidance_demo.SSM_LAYOUT in out and "ssm    refused" in out and "70 mm" in out
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert list(summary["modes"]) == ["none"] and "70 mm" in summary["refused"]["ssm"]
    assert not (tmp_path / "demo_ssm.png").exists()


def test_resumption_needs_the_obstacles_gone_and_the_task_back_for_a_while():
    """The demo's "resumed after" figure (issue 9): from when every control point is truly beyond 0.4 m for good,
    until the task error is below 1 cm and stays there for 0.1 s; a reference passing by a stopped robot does not
    count."""
    from types import SimpleNamespace

    from depthguard_lab.experiments.avoidance_demo import resumption

    t = np.arange(0.0, 3.0, 0.002)
    steps = np.arange(0, len(t), 5)
    far = np.where(t[steps] < 0.5, 0.1, 1.0)[:, None] * np.ones((1, 3))

    def log(error, truth=far):
        return SimpleNamespace(truth=truth, truth_steps=steps, times=t, task_error=error)

    back = np.where(t < 1.5, 0.2, 0.004)
    passing = back.copy()
    passing[(t > 0.9) & (t < 0.95)] = 0.005  # the path passes by for 0.05 s
    left, resumed, median = resumption(log(passing))
    assert abs(left - 0.5) < 0.011 and abs(resumed - 1.0) < 0.011 and median == pytest.approx(0.004)
    assert resumption(log(np.where((t > 0.9) & (t < 0.95), 0.005, 0.2)))[1:] == (None, None)  # never back
    assert resumption(log(back, np.full((len(steps), 3), 0.1))) == (None, None, None)  # never left
    came_late = np.where(t[steps] < 2.0, 1.0, 0.1)[:, None] * np.ones((1, 3))
    assert resumption(log(back, came_late)) == (None, None, None)  # still there at the end
