"""``depthguard coverage`` (issue 8, item 6): the space near the robot that no camera of a rig clears.

The rigs are scenario B's layouts made small (160x120 cameras): two cameras on the robot's front side, the same two
plus two at the back corners, and the principal camera alone. The frames and the monitors' answers are recomputed
here from the library's primitives, not taken from the code under test.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

import depthguard as dg
from cli_support import assert_refused, run_cli
from depthguard import coverage as cov
from depthguard.robots import RobotModel, segment_distances
from depthguard.scenes import Box, render_depth
from depthguard.self_filter import RobotSilhouette
from depthguard.transforms import look_at

EYES = {"principal": [1.5, -2.0, 1.3], "second": [1.5, 2.0, 1.3], "third": [-1.9, 2.6, 1.3],
        "fourth": [-1.9, -2.6, 1.3]}
TARGET = [0.2, 0.0, 0.45]
WORKSPACE = [[-1.5, -1.5, -0.5], [1.5, 1.5, 1.5]]
FLOOR = -0.5
FAR = 7.0
KINECT = dg.NoiseModel(0.001504, -0.00152, 0.0019, 3.0)
POSES = [("posture", np.array([0.0, 0.5, 0.0, -1.5, 0.0, 0.8, 0.0])),
         ("reaching", np.array([0.3, 0.6, 0.0, -1.2, 0.0, 0.8, 0.0]))]
SPACING = 0.06  # coarser than the command's 3 cm: fewer samples, a faster test
RHO = 0.4


def camera(name):
    return dg.PinholeCamera(name, 160, 120, 131.25, 131.25, 79.5, 59.5, look_at(EYES[name], TARGET),
                            depth_range=(0.5, FAR), noise=KINECT)


def rig_of(names):
    return dg.Rig({name: camera(name) for name in names}, principal="principal", workspace=WORKSPACE)


@pytest.fixture(scope="module")
def robot():
    return RobotModel.default()


@pytest.fixture(scope="module")
def results(robot):
    layouts = {"two": ["principal", "second"], "four": list(EYES), "one": ["principal"]}
    return {name: (rig_of(names), cov.coverage(rig_of(names), robot, POSES, rho=RHO, spacing=SPACING))
            for name, names in layouts.items()}


def frames_here(rig, robot, q):
    """The empty room as this test builds it: the robot's meshes (no padding) and a floor, the nearer per pixel;
    nothing hit within range reads the range's end."""
    silhouette = RobotSilhouette(robot, geometry="meshes", padding=0.0)
    floor = Box.from_bounds([-20.0, -20.0, FLOOR - 0.05], [20.0, 20.0, FLOOR])
    frames = {}
    for name, cam in rig.cameras.items():
        ground = render_depth(cam, [floor])
        arm = silhouette.render(cam, q)
        depth = np.where(arm > 0, np.minimum(arm, np.where(ground > 0, ground, np.inf)), ground)
        depth = np.where((depth <= 0) | (depth > FAR), FAR, depth)
        frames[name] = dg.depth_image(depth.astype(np.float32), cam, timestamp=0.0)
    return frames, silhouette


def keyed(samples, spacing=SPACING):
    """Sample points as integer lattice indices, to match samples between rigs."""
    return {tuple(k): i for i, k in enumerate(np.round(samples / spacing).astype(int))}


# --------------------------------------------------------------------------------------------------------------------
# camera placement shows


def test_cameras_round_the_robot_clear_more_than_two_on_one_side(results):
    (_, two), (_, four) = results["two"], results["four"]
    for p2, p4 in zip(two.poses, four.poses):
        assert len(p2.samples) > 1000 and len(p4.samples) > 1000
        # Same principal camera, two more secondaries: a cell the two cameras clear stays cleared, so no sample
        # becomes not clearable, and the ones behind the links that only the back cameras see are cleared.
        k2, k4 = keyed(p2.samples), keyed(p4.samples)
        common = sorted(set(k2) & set(k4))
        assert len(common) > 0.95 * min(len(k2), len(k4))
        i2, i4 = [k2[k] for k in common], [k4[k] for k in common]
        assert not np.any(p4.not_clearable[i4] & ~p2.not_clearable[i2])
        assert not np.any(p4.occupied[i4] & ~p2.occupied[i2])
        assert p4.occupied[i4].sum() < p2.occupied[i2].sum()
    f2, f4 = cov.figures(two.poses), cov.figures(four.poses)
    assert f4["not_clearable_fraction"] < f2["not_clearable_fraction"]
    assert f4["occupied_fraction"] < f2["occupied_fraction"]
    assert f4["control_alarm_fraction"] <= f2["control_alarm_fraction"]


def test_one_camera_leaves_everything_behind_the_robot_not_clearable(results, robot):
    """With one camera (the single-camera method), every sample the camera sees behind the robot's meshes is not
    clearable (unchecked: its blind spot); it is not refused."""
    rig, one = results["one"]
    cam = rig.cameras["principal"]
    for (_, q), pose in zip(POSES, one.poses):
        frames, silhouette = frames_here(rig, robot, q)
        arm = silhouette.render(cam, q)
        x, y, z = cam.world_to_camera(pose.samples).T
        u = np.round(cam.fx * x / z + cam.cx).astype(int)
        v = np.round(cam.fy * y / z + cam.cy).astype(int)
        inside = (z > 0) & (u >= 0) & (u < cam.width) & (v >= 0) & (v < cam.height)
        behind = np.zeros(len(z), dtype=bool)
        behind[inside] = (arm[v[inside], u[inside]] > 0) & (arm[v[inside], u[inside]] < z[inside])
        assert behind.sum() > 300
        assert pose.not_clearable[behind].all()
        assert pose.unchecked[behind].any()
    assert cov.figures(one.poses)["not_clearable_fraction"] > 2 * cov.figures(results["two"][1].poses)[
        "not_clearable_fraction"]


# --------------------------------------------------------------------------------------------------------------------
# the fractions are the monitor's


@pytest.mark.parametrize("layout", ["two", "four", "one"])
def test_samples_answer_as_the_monitor_does(results, robot, layout):
    """Every sample's class against a direct query of a fresh monitor on frames built here (samples within 1 mm
    of the threshold, where a rounding of the floor's depth could tip them, are left out)."""
    rig, result = results[layout]
    for (_, q), pose in zip(POSES, result.poses):
        frames, _ = frames_here(rig, robot, q)
        monitor = dg.DistanceMonitor(rig, rho=SPACING, aggregate="min", robot=robot, memory=False)
        answer = monitor.query(frames, pose.samples, joints=q)
        nearest = np.minimum(answer.distance, answer.blind_distance)
        clear = np.abs(nearest - SPACING) > 1e-3
        assert clear.mean() > 0.99
        np.testing.assert_array_equal(pose.not_clearable[clear], nearest[clear] < SPACING)
        np.testing.assert_array_equal(pose.occupied[clear], answer.distance[clear] < SPACING)
        # a handful, one by one, in a monitor of its own
        rng = np.random.default_rng(8)
        blocked, free = np.flatnonzero(pose.not_clearable & clear), np.flatnonzero(~pose.not_clearable & clear)
        picks = np.concatenate([rng.choice(blocked, min(5, len(blocked)), replace=False),
                                rng.choice(free, 5, replace=False)])
        alone = dg.DistanceMonitor(rig, rho=SPACING, aggregate="min", robot=robot, memory=False)
        for i in picks:
            one = alone.query(frames, pose.samples[i:i + 1], joints=q)
            assert (min(one.distance[0], one.blind_distance[0]) < SPACING) == pose.not_clearable[i]


@pytest.mark.parametrize("layout", ["two", "four"])
def test_control_point_alarms_are_the_monitors(results, robot, layout):
    """The control points' false alarms: far from the floor by more than rho + 5 cm, fused distance (hybrid, rho
    0.4, no memory) below rho; on the noise-free frames and on the same with the rig's noise."""
    rig, result = results[layout]
    for i, ((_, q), pose) in enumerate(zip(POSES, result.poses)):
        frames, _ = frames_here(rig, robot, q)
        noisy = cov.with_noise(frames, rig, np.random.default_rng([cov.NOISE_SEED, i]))
        points = robot.control_point_positions(q)
        far = points[:, 2] - FLOOR > RHO + 0.05
        assert far.sum() >= 6
        np.testing.assert_array_equal(pose.control_far, far)
        for images, alarms in ((frames, pose.control_alarms), (noisy, pose.control_alarms_noisy)):
            monitor = dg.DistanceMonitor(rig, rho=RHO, aggregate="hybrid", robot=robot, memory=False)
            distance = monitor.query(images, points, joints=q).distance
            np.testing.assert_array_equal(alarms, far & (distance < RHO))
    numbers = cov.figures(result.poses)
    for suffix in ("", "_noisy"):
        alarms = sum(int(getattr(p, "control_alarms" + suffix).sum()) for p in result.poses)
        assert numbers["control_points_below_rho" + suffix] == alarms
        assert numbers["control_alarm_fraction" + suffix] == alarms / sum(int(p.control_far.sum())
                                                                          for p in result.poses)


def test_noise_is_the_rigs(robot):
    """with_noise: on surfaces within range, (measured - exact) / sigma(exact) is standard normal up to the
    millimetre rounding; elsewhere nothing changes; the same generator state gives the same frames."""
    rig = rig_of(["principal", "second"])
    frames, _ = frames_here(rig, robot, POSES[0][1])
    noisy = cov.with_noise(frames, rig, np.random.default_rng(3))
    again = cov.with_noise(frames, rig, np.random.default_rng(3))
    for name, cam in rig.cameras.items():
        exact = frames[name].data.astype(np.float64)
        measured = noisy[name].data.astype(np.float64)
        np.testing.assert_array_equal(measured, again[name].data)
        surface = exact < FAR
        assert surface.sum() > 0.5 * exact.size
        np.testing.assert_array_equal(measured[~surface], exact[~surface])
        sigma = KINECT.a + exact * (KINECT.b + KINECT.c * exact)
        z = (measured[surface] - exact[surface]) / sigma[surface]
        assert abs(z.mean()) < 0.05 and 0.95 < z.std() < 1.1
        np.testing.assert_allclose(measured[surface] * 1000, np.round(measured[surface] * 1000), atol=1e-3)
        assert ((measured >= cam.depth_range[0]) & (measured <= FAR)).all()


def test_samples_lie_where_they_should(results, robot):
    """Between 2 cm and rho from the padded capsules (distances computed here), above the floor by more than a
    spacing, on a lattice of the spacing; and every lattice point well above the floor within that shell is one."""
    rig, result = results["two"]
    for (_, q), pose in zip(POSES, result.poses):
        capsules = robot.capsules_world(q)
        gap = np.min([segment_distances(pose.samples, c.p0, c.p1) - c.radius for c in capsules], axis=0)
        assert gap.min() >= cov.CLEARANCE - 1e-9 and gap.max() <= RHO + 1e-9
        assert (pose.samples[:, 2] > FLOOR + SPACING).all()
        np.testing.assert_allclose(pose.samples / SPACING, np.round(pose.samples / SPACING), atol=1e-9)
        lo, hi = np.floor(pose.samples.min(axis=0) / SPACING), np.ceil(pose.samples.max(axis=0) / SPACING)
        lattice = np.stack(np.meshgrid(*[np.arange(a, b + 1) * SPACING for a, b in zip(lo, hi)], indexing="ij"),
                           axis=-1).reshape(-1, 3)
        gap = np.min([segment_distances(lattice, c.p0, c.p1) - c.radius for c in capsules], axis=0)
        wanted = lattice[(gap >= cov.CLEARANCE + 1e-9) & (gap <= RHO - 1e-9) & (lattice[:, 2] > FLOOR + 0.5)]
        assert len(wanted) > 1000
        assert set(keyed(wanted)) <= set(keyed(pose.samples))


# --------------------------------------------------------------------------------------------------------------------
# one more camera


def test_sees_past_is_the_stated_rule_on_a_wall_with_a_post():
    """``sees_past``: a camera facing a wall 4 m away, a post 2 m away covering a band of columns; a sample sees past
    exactly when it is in view and the nearest surface within a pixel of its own (the post or the wall) lies beyond
    it by more than twice the noise margin there, the fusion margin and the spacing."""
    cam = camera("principal").replace(T_world_camera=np.eye(4))
    depth = np.full(cam.shape, 4.0, dtype=np.float32)
    depth[:, 70:80] = 2.0
    spacing = 0.06

    def need(surface):
        return surface - (2.0 * float(cam.noise.margin(surface)) + dg.config.DEFAULT_FUSION_MARGIN + spacing)

    rng = np.random.default_rng(2)
    u = rng.uniform(-5, 165, 400)
    v = rng.uniform(-5, 125, 400)
    z = rng.uniform(0.2, 4.5, 400)
    samples = np.column_stack([(u - cam.cx) * z / cam.fx, (v - cam.cy) * z / cam.fy, z])
    got = cov.sees_past(cam, depth, samples, spacing)
    q, r = np.round(u), np.round(v)
    inside = (q >= 1) & (q <= cam.width - 2) & (r >= 1) & (r <= cam.height - 2) & (z > cam.depth_range[0])
    post = (q >= 69) & (q <= 80)
    want = inside & (z < np.where(post, need(2.0), need(4.0)))
    np.testing.assert_array_equal(got, want)
    assert want.sum() > 50 and (inside & post & want).sum() > 3 and (inside & post & ~want & (z < need(4.0))).sum() > 3


def test_the_suggested_camera_clears_most_of_what_the_rig_cannot(results, robot):
    """``suggest_camera`` on the two front cameras: the suggested camera, added to the rig, leaves far fewer samples
    not clearable when the coverage is computed again (measured: 147 -> 15 of 13983), and the share it claimed to see
    past is most of them (the far control points below rho: 18 -> 10 of 18)."""
    rig, before = results["two"]
    suggestion = cov.suggest_camera(rig, robot, POSES, before)
    assert suggestion is not None and suggestion.tried == len(cov.SUGGEST_HEIGHTS) * cov.SUGGEST_AZIMUTHS
    bigger = dg.Rig({**rig.cameras, "suggested": suggestion.camera}, principal="principal", workspace=WORKSPACE)
    after = cov.coverage(bigger, robot, POSES, rho=RHO, spacing=SPACING)
    n_before = cov.figures(before.poses)["not_clearable"]
    n_after = cov.figures(after.poses)["not_clearable"]
    alarms = [cov.figures(c.poses)["control_points_below_rho"] for c in (before, after)]
    print(f"\nsuggested {suggestion.eye.round(2)}: sees past {suggestion.sees_past:.3f}; not clearable {n_before} -> "
          f"{n_after}; far control points below rho {alarms[0]} -> {alarms[1]}")
    assert suggestion.sees_past > 0.5 and n_after <= 0.5 * n_before and alarms[1] <= alarms[0]


# --------------------------------------------------------------------------------------------------------------------
# the command


@pytest.fixture(scope="module")
def files(tmp_path_factory, robot):
    folder = tmp_path_factory.mktemp("coverage")
    dg.save_rig(rig_of(["principal", "second"]), folder / "rig.yaml")
    q = POSES[0][1]
    # the joints' columns in reverse order: read by name
    lines = [",".join(["time", *reversed(robot.joint_names)])] + [
        ",".join([repr(t)] + [repr(float(x)) for x in (q + t * 0.1)[::-1]]) for t in (0.0, 0.5)]
    (folder / "joint_states.csv").write_text("\n".join(lines) + "\n")
    (folder / "bad_joints.csv").write_text("time,a,b\n0.0,1,2\n")
    return folder




def test_command_writes_the_picture_and_the_numbers(files, capsys, tmp_path, robot):
    out = tmp_path / "cov"
    status, text, err = run_cli(["coverage", "--rig", files / "rig.yaml", "--trajectory", files / "joint_states.csv",
                             "--out", out], capsys)
    assert status == 0, err
    assert (out / "coverage.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    numbers = json.loads((out / "coverage.json").read_text())
    assert [p["label"] for p in numbers["poses"]] == ["row 1, t=0 s", "row 2, t=0.5 s"]
    q = POSES[0][1]
    np.testing.assert_allclose(numbers["poses"][1]["joints"], q + 0.05)
    assert numbers["rho"] == RHO and numbers["spacing"] == cov.SPACING and set(numbers["cameras"]) == {
        "principal", "second"}
    assert numbers["samples"] == sum(p["samples"] for p in numbers["poses"]) > 10000
    assert numbers["not_clearable"] == numbers["occupied"] + numbers["unchecked"]
    assert numbers["not_clearable_fraction"] == pytest.approx(numbers["not_clearable"] / numbers["samples"])
    assert numbers["control_points_far"] == 18
    assert 0 <= numbers["control_points_below_rho"] <= 18 and 0 <= numbers["control_points_below_rho_noisy"] <= 18
    assert "all poses" in text and "row 2, t=0.5 s" in text


def test_suggest_writes_the_rig_with_one_more_camera_and_its_coverage(files, capsys, tmp_path):
    out = tmp_path / "cov"
    status, text, err = run_cli(["coverage", "--rig", files / "rig.yaml", "--trajectory", files / "joint_states.csv",
                                 "--out", out, "--suggest"], capsys)
    assert status == 0, err
    numbers = json.loads((out / "coverage.json").read_text())
    suggestion = numbers["suggestion"]
    bigger = dg.load_rig(out / "rig_suggested.yaml")
    assert list(bigger.cameras) == ["principal", "second", "suggested"] and bigger.principal == "principal"
    np.testing.assert_allclose(bigger.cameras["suggested"].T_world_camera[:3, 3], suggestion["eye"], atol=1e-9)
    assert suggestion["with_it"]["not_clearable"] < numbers["not_clearable"]
    assert "--suggest" in text and "sees past" in text


def _bad_cases(files, tmp):
    base = ["coverage", "--rig", files / "rig.yaml", "--trajectory", files / "joint_states.csv", "--out", tmp / "o"]
    a_file = tmp / "a_file"
    a_file.write_text("x")
    return {
        "rho too small": (base + ["--rho", "0.01"], "--rho"),
        "rho too large": (base + ["--rho", "5"], "--rho"),
        "rho nan": (base + ["--rho", "nan"], "--rho"),
        "no rig": (["coverage", "--out", tmp / "o"], "--rig"),
        "missing rig file": (["coverage", "--rig", tmp / "none.yaml", "--out", tmp / "o"], "none.yaml"),
        "trajectory of another robot": (base[:4] + [files / "bad_joints.csv", "--out", tmp / "o"], "joints"),
        "missing trajectory": (base[:4] + [tmp / "none.csv", "--out", tmp / "o"], "none.csv"),
        "missing urdf": (base + ["--robot", tmp / "none.urdf"], "none.urdf"),
        "out is a file": (base[:-1] + [a_file], "--out"),
    }


BAD = ["rho too small", "rho too large", "rho nan", "no rig", "missing rig file", "trajectory of another robot",
       "missing trajectory", "missing urdf", "out is a file"]


@pytest.mark.parametrize("case", BAD)
def test_bad_arguments_exit_2_with_one_line(files, capsys, tmp_path, case):
    argv, needle = _bad_cases(files, tmp_path)[case]
    assert_refused(argv, capsys, needle)
    assert not (tmp_path / "o").exists()


def test_all_bad_cases_are_tested(files, tmp_path):
    assert sorted(_bad_cases(files, tmp_path)) == sorted(BAD)


def test_the_iiwas_default_poses_are_scenario_bs():
    """The library keeps scenario B's poses of the iiwa as numbers (it does not import the lab): they are the lab's
    scenario B posture and its trajectory's joints at a quarter lap apart."""
    from depthguard.robots import RobotModel
    from depthguard_lab.simulation import default_workcell

    workcell = default_workcell()
    poses = dict(cov.default_poses(RobotModel.default()))
    np.testing.assert_array_equal(poses.pop("posture"), workcell.trajectory.posture)
    assert len(poses) == 4
    for label, q in poses.items():
        np.testing.assert_allclose(q, workcell.joints_at(float(label[2:-2])), rtol=0, atol=1e-15)
