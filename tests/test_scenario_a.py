"""Reference scenario A (2015 paper, section 4): the scene reproduces the paper's geometry, and depthguard shows
what the paper claims (the depth space sees the hidden face, never overestimates, switches near x = 0.157)."""

import json
import math

import numpy as np
import pytest

from depthguard_lab.experiments import scenario_a as sa

MM = 1e-3


@pytest.fixture(scope="module")
def scenario():
    scene = sa.make_scene()
    camera = sa.make_camera()
    depth = sa.render(scene, camera)
    points = sa.control_points()
    frame = sa.make_frame(camera, depth)
    run = sa.run_methods("noise-free", frame, points)
    truth, truth_direction = sa.true_nearest(scene, points)
    return dict(scene=scene, camera=camera, depth=depth, points=points, x=points[:, 0], frame=frame, run=run,
                truth=truth, truth_direction=truth_direction)


def test_truth_is_the_papers_geometry(scenario):
    x, truth = scenario["x"], scenario["truth"]
    expected = np.where(x <= 0, 0.03, np.where(x < sa.TRUE_SWITCH_X, np.hypot(x, 0.03), 0.16))
    np.testing.assert_allclose(truth, expected, atol=1e-12)
    assert sa.TRUE_SWITCH_X == pytest.approx(0.1572, abs=1e-4)
    # Nearest obstacle: the hidden face (pointing +y) behind the wall, the table (pointing +z) past the switch.
    np.testing.assert_allclose(scenario["truth_direction"][x < 0], [[0, 1, 0]] * int(np.sum(x < 0)), atol=1e-12)
    np.testing.assert_allclose(scenario["truth_direction"][x > 0.16], [[0, 0, 1]] * int(np.sum(x > 0.16)), atol=1e-12)


def test_every_pixel_hits_something_and_only_the_front_face_of_the_wall_is_seen(scenario):
    depth = scenario["depth"]
    assert depth.dtype == np.float32 and np.all(depth > 0)
    faces = sa.wall_faces_seen(scenario["scene"], scenario["camera"], depth)
    assert faces["X=0"] > 500  # the paper's Y-Z face, towards the camera
    assert faces["Y=0.37"] == 0  # the paper's X-Z face: hidden
    assert faces["Y=0.33"] == 0 and faces["X=-0.5"] == 0


def test_depth_space_min_never_exceeds_the_true_distance(scenario):
    run, truth = scenario["run"], scenario["truth"]
    for aggregate in ("min", "hybrid"):
        d = run.distance[aggregate]
        assert np.all(np.isfinite(d))
        assert np.max(d - truth) <= 1 * MM, aggregate
    # ... and it is a tight bound where the nearest obstacle is seen: the table, within pixel discretisation.
    table = scenario["x"] > 0.2
    assert np.max(truth[table] - run.distance["min"][table]) < 5 * MM


def test_point_cloud_misses_the_hidden_face_and_depth_space_does_not(scenario):
    run, x = scenario["run"], scenario["x"]
    behind = x < -0.2
    assert behind.sum() > 50
    assert np.all(run.distance["point cloud"][behind] > 0.1)  # it sees only the table, 0.16 below
    assert np.all(run.distance["min"][behind] <= 0.03)  # hidden face (0.03) or its gray area
    # The depth-space direction points away from the hidden face (+y); the point cloud's points up or sideways.
    assert np.all(run.direction["min"][behind, 1] > 0.9)
    assert np.all(run.direction["point cloud"][behind, 1] < 0.5)


def test_min_direction_switches_from_the_wall_to_the_table_near_the_true_switch(scenario):
    run, x = scenario["run"], scenario["x"]
    switch = sa.direction_switch(scenario["frame"], "min", x, run.direction["min"])
    assert switch is not None and 0.12 < switch < 0.19
    vertical = sa.is_vertical(run.direction["min"])
    assert not vertical[x < 0.12].any()
    assert vertical[x > 0.19].all()


def test_hybrid_distance_is_the_min_distance(scenario):
    run = scenario["run"]
    np.testing.assert_array_equal(run.distance["hybrid"], run.distance["min"])
    assert np.all(run.distance["mean"] >= run.distance["min"])


def test_timing_protocol_returns_one_median_per_position(scenario):
    medians = sa.time_methods(scenario["frame"], sa.METHODS, scenario["points"][:3], repeats=2)
    assert set(medians) == set(sa.METHODS)
    assert all(t.shape == (3,) and np.all(t > 0) for t in medians.values())
    table = sa.timing_table(medians)
    assert all(row["best"] <= row["median"] <= row["worst"] for row in table.values())
    with pytest.raises(sa.dg.InputError):
        sa.time_methods(scenario["frame"], ("min",), scenario["points"][:1], repeats=0)


def test_main_writes_the_figures_and_summary(tmp_path, capsys):
    out = tmp_path / "scenario-a"
    from depthguard_lab.experiments import _scenario_a_plots as report

    assert report.main(out=str(out), repeats=1) == 0
    expected = {"scenario_a_overview.png", "scenario_a_fig7_point_cloud.png", "scenario_a_fig8_min.png",
                "scenario_a_fig9_mean.png", "scenario_a_fig10_hybrid.png", "scenario_a_fig11_timing.png",
                "scenario_a_noisy.png"}
    for name in expected:
        data = (out / name).read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 10_000, name
    summary = json.loads((out / "summary.json").read_text())
    assert set(summary["files"]) == expected
    exact = summary["noise_free"]
    assert 0.12 < exact["min_direction_switch_x"] < 0.19
    assert exact["max_excess_over_truth"]["min"] <= 1 * MM
    assert exact["hidden_face_point_cloud_distance"][0] > 0.1
    assert exact["hidden_face_min_distance"][1] <= 0.03
    assert exact["hybrid_equals_min"] is True
    assert summary["noisy"]["max_excess_over_truth"]["min"] <= 1 * MM
    assert summary["wall_face_pixels"]["Y=0.37"] == 0
    assert set(summary["timing_seconds"]) == set(sa.METHODS)
    assert all(math.isfinite(v) and v > 0 for row in summary["timing_seconds"].values() for v in row.values())
    printed = capsys.readouterr().out
    assert "0.1572" in printed and "point cloud" in printed and str(out) in printed
