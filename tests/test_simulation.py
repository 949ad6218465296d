"""depthguard_lab.simulation: the scene loader, the people, the hexagon, the sensor model, ground truth and episode files.

Judges and tolerances:

- noise-free rendering vs exact ray casting (``depthguard.scenes.render_depth``) of the same primitives: the
  renderer draws spheres and capsules as circumscribed meshes that lie outside the true surface by at most
  ``primitive_mesh_excess`` (r (1/h - 1); 3.8e-5 m for the 0.14 m torso at the 192 segments used here), so along a
  ray it may be nearer by that over the cosine of the incidence angle. Off silhouettes (pixels whose 8 neighbours
  show the same thing) and where |cos| >= 0.5: agreement within 1e-4 m, and never behind the true surface by more
  than float32 rounding (2e-5 m);
- noise statistics: the measured standard deviation on a flat fronto-parallel wall within 20 % of sigma(d) at two
  depths;
- ground truth: control point distances against coal (an independent exact-distance library) to 1e-9 m; the
  robot-person clearance (coal, link meshes) against pybullet's getClosestPoints between the same triangle meshes
  and the body's capsules, which reports distances short by its collision margin (PYBULLET_MESH_MARGIN = 1 mm,
  measured), to 1e-4 m; the robot-box clearance against the distance from dense samples of the link meshes'
  surfaces to the box (an upper bound), within 0.5 mm.
"""

from __future__ import annotations

import copy
import csv
import math

import coal
import numpy as np
import pybullet
import pytest
import trimesh
import yaml
from PIL import Image

import depthguard as dg
from depthguard.errors import SceneError
from depthguard.rendering import primitive_mesh_excess
from depthguard.scenes import Capsule, render_depth
from depthguard_lab.simulation import (
    PART_NAMES,
    SceneRenderer,
    SensorModel,
    TruthComputer,
    cosine_from_intensity,
    default_workcell,
    discontinuity_mask,
    load_workcell,
    save_workcell,
    simulate,
    simulate_depth,
    workcell_from_dict,
    write_episode,
)
from depthguard_lab.simulation._truth import coal_shape

#: Off-silhouette agreement of the rendered depth with exact ray casting, metres (see the module docstring).
DEPTH_TOL = 1e-4
#: pybullet's getClosestPoints on a GEOM_FORCE_CONCAVE_TRIMESH reports distances this much short (its margin), m.
PYBULLET_MESH_MARGIN = 1e-3


@pytest.fixture(scope="module")
def wc():
    return default_workcell()


def span(workcell, kind):
    return next(s for s in workcell.timeline() if s.kind == kind)


def hold_frames(workcell, kind, ramp=0.0, step=1):
    """Frame indices of an action's hold (after its walk), without ``ramp`` seconds at either end."""
    s = span(workcell, kind)
    times = workcell.times()
    keep = (times >= s.hold_start + ramp) & (times <= s.end - ramp)
    return np.flatnonzero(keep)[::step]


def tiny_scene(**changes) -> dict:
    """A small scene: one 64x48 camera at (0, 3, 1) facing a wall 1.95 m away (fronto-parallel), the robot behind
    the camera, out of view."""
    scene = {
        "duration": 0.1,
        "rate": 30,
        "cameras": [{"name": "cam", "width": 64, "height": 48, "fx": 52.5, "fy": 52.5, "cx": 31.5, "cy": 23.5,
                     "look_at": {"eye": [0.0, 3.0, 1.0], "target": [0.0, 6.0, 1.0]}, "depth_range": [0.5, 4.5]}],
        "robot": {"model": "iiwa", "trajectory": {"type": "joints", "waypoints": [{"time": 0.0, "joints": [0.0] * 7}]}},
        "static_objects": [{"name": "wall", "box": {"center": [0.0, 5.0, 1.0], "size": [8.0, 0.1, 8.0]}}],
    }
    scene.update(changes)
    return scene


# ------------------------------------------------------------------------------------------------- loader

def test_default_scene_round_trip(wc, tmp_path):
    path = tmp_path / "scene.yaml"
    save_workcell(wc, path)
    again = load_workcell(path)
    assert again.rig.fingerprint() == wc.rig.fingerprint()
    assert again.rig.principal == "principal" and list(again.rig.cameras) == ["principal", "second"]
    np.testing.assert_array_equal(again.times(), wc.times())
    assert again.duration == wc.duration and again.rate == wc.rate == 30
    for t in (0.0, 2.5, 5.0, 10.7, wc.times()[-1]):
        np.testing.assert_array_equal(again.joints_at(t), wc.joints_at(t))
        a, b = again.obstacles_at(t), wc.obstacles_at(t)
        assert list(a) == list(b)
        for name in a:
            assert [primitive_numbers(p) for p in a[name]] == [primitive_numbers(p) for p in b[name]]
    assert [(s.kind, s.start, s.end) for s in again.timeline()] == [(s.kind, s.start, s.end) for s in wc.timeline()]


def primitive_numbers(primitive) -> list[float]:
    """A primitive's parameters as one list of floats, for comparisons."""
    values = [np.ravel(np.asarray(v, dtype=float)) for v in vars(primitive).values()]
    return np.concatenate(values).tolist()


BAD_SCENES = [
    # (what to change in the default scene, field the error must name)
    (lambda s: s.pop("duration"), "duration"),
    (lambda s: s.update(rate=-30), "rate"),
    (lambda s: s.update(extra_key=1), "extra_key"),
    (lambda s: s["cameras"][0].update(fx=-5.0), "cameras[principal].fx"),
    (lambda s: s["cameras"][1].update(T_world_camera=np.eye(4).tolist()), "cameras[1].T_world_camera"),
    (lambda s: s["cameras"][0]["sensor"].update(edge_dropout=1.5), "cameras[0].sensor.edge_dropout"),
    (lambda s: s.update(principal="nobody"), "cameras.principal"),
    (lambda s: s["robot"].update(model="ur5"), "robot.model"),
    (lambda s: s["robot"]["trajectory"]["posture"].pop("lbr_iiwa_joint_3"), "robot.trajectory.posture"),
    (lambda s: s["robot"]["trajectory"].update(radius=2.0), "robot.trajectory"),
    (lambda s: s["static_objects"][0]["box"].update(max=[-4.0, 3.5, -0.5]), "static_objects[0].box.max"),
    (lambda s: s["static_objects"][1].update(name="floor"), "static_objects[1].name"),
    (lambda s: s["people"][0]["actions"][1]["reach"].update(target="elbw"), "people[0].actions[1].reach.target"),
    (lambda s: s["people"][0]["actions"].append({"dance": {}}), "people[0].actions[6]"),
    (lambda s: s["people"][0]["actions"][3]["carry"].update(object="crate"), "people[0].actions[3].carry.object"),
    (lambda s: s["people"][0]["actions"][0]["walk"].update(to=[1.0]), "people[0].actions[0].walk.to"),
    (lambda s: s["people"][0]["actions"][0]["walk"].update(backwards="yes"), "people[0].actions[0].walk.backwards"),
    (lambda s: s["people"][0]["actions"][3]["carry"].update(backwards=1), "people[0].actions[3].carry.backwards"),
    (lambda s: s.update(duration=8.0), "people[0].actions"),
]


@pytest.mark.parametrize("change, field", BAD_SCENES, ids=[f for _, f in BAD_SCENES])
def test_malformed_scenes_name_the_field(wc, change, field):
    scene = copy.deepcopy(wc.scene)
    change(scene)
    with pytest.raises(SceneError) as info:
        workcell_from_dict(scene)
    assert info.value.field == field, str(info.value)
    assert f"field {field!r}" in str(info.value)


def test_scene_file_errors(tmp_path):
    evil = tmp_path / "evil.yaml"
    evil.write_text("duration: !!python/object/apply:os.system ['echo pwned']\n")
    with pytest.raises(SceneError, match="not allowed"):
        load_workcell(evil)
    broken = tmp_path / "broken.yaml"
    broken.write_text("duration: [1, 2\n")
    with pytest.raises(SceneError, match="broken.yaml"):
        load_workcell(broken)
    with pytest.raises(SceneError, match="cannot read"):
        load_workcell(tmp_path / "missing.yaml")
    listed = tmp_path / "list.yaml"
    listed.write_text("- 1\n- 2\n")
    with pytest.raises(SceneError, match="must be a mapping"):
        load_workcell(listed)


# --------------------------------------------------------------------------------------- noise-free depth

def test_noise_free_depth_matches_exact_ray_casting(wc):
    scene = copy.deepcopy(wc.scene)
    scene["render_segments"] = 192
    for camera in scene["cameras"]:
        camera["noise_sigma"] = 0.0  # noise-free intensity, from which the incidence angles are recovered
    fine = workcell_from_dict(scene).scaled(0.5)
    excess = max(primitive_mesh_excess(p, 192) for p in fine.primitives_at(0.0))
    assert excess < 4e-5
    names = [name for name, _ in fine.labels()]
    albedo = np.array([a for _, a in fine.labels()])
    robot_labels = [i for i, name in enumerate(names) if name.startswith("robot/")]
    frames = [int(2.6 * fine.rate), int(10.6 * fine.rate)]
    checked = 0
    for frame in simulate(fine, frames=frames):
        primitives = fine.primitives_at(frame.time)
        for name, camera in fine.rig.cameras.items():
            rendered = frame.depth_exact[name].astype(np.float64)
            exact = render_depth(camera, primitives).astype(np.float64)
            label = frame.label[name]
            same = np.ones(label.shape, dtype=bool)  # the pixel and its 8 neighbours show the same thing
            padded = np.pad(label, 1, mode="edge")
            for dv in (0, 1, 2):
                for du in (0, 1, 2):
                    same &= padded[dv : dv + label.shape[0], du : du + label.shape[1]] == label
            # |cos| from the uint8 intensity: off by at most 0.5/255/(albedo (1 - ambient)) < 0.01 here.
            cosine = cosine_from_intensity(frame.intensity[name] / 255.0, label, albedo)
            ok = same & ~np.isin(label, robot_labels) & (label >= 0) & (exact > 0)
            assert ok.mean() > 0.5
            diff = exact - rendered
            assert diff[ok].min() > -2e-5, "rendered surface behind the true one"
            strict = ok & (cosine >= 0.5)
            assert np.abs(diff[strict]).max() <= DEPTH_TOL, np.abs(diff[strict]).max()
            people = np.isin(label, [i for i, n in enumerate(names) if n.startswith("worker/")])
            assert (strict & people).sum() > 500, "the person is checked too"
            checked += int(strict.sum())
    assert checked > 50_000


def test_cosine_from_renderer_matches_geometry():
    """The normals the grazing-angle dropouts use: a floor seen obliquely, |cos| against the analytic value."""
    scene = tiny_scene(static_objects=[{"name": "floor", "box": {"min": [-10, -10, -0.1], "max": [10, 20, 0.0]}}])
    scene["cameras"][0]["look_at"] = {"eye": [0.0, 3.0, 1.0], "target": [0.0, 6.0, 0.3]}
    small = workcell_from_dict(scene)
    renderer = SceneRenderer(small)
    camera = small.rig.cameras["cam"]
    q = small.joints_at(0.0)
    result = renderer.render(camera, renderer.instances(small.robot.link_poses(q), small.obstacles_at(0.0)))
    cosine = renderer.cosine(result)
    renderer.release()
    u, v = camera.pixel_grid()
    rays = camera.back_project(u, v, np.ones_like(u)) @ camera.T_world_camera[:3, :3].T
    expected = np.abs(rays[..., 2]) / np.linalg.norm(rays, axis=-1)  # floor normal (0, 0, 1)
    hit = result.depth > 0
    assert hit.mean() > 0.3
    np.testing.assert_allclose(cosine[hit], expected[hit], atol=2e-3)


# ------------------------------------------------------------------------------------------- sensor model

def flat_camera(noise=None, depth_range=(0.5, 4.5)):
    return dg.PinholeCamera("c", 200, 200, 200.0, 200.0, 99.5, 99.5, np.eye(4), depth_range=depth_range,
                            noise=noise or dg.NoiseModel())


@pytest.mark.parametrize("d", [1.0, 3.0])
def test_noise_matches_sigma_on_a_flat_wall(d):
    camera = flat_camera()
    rng = np.random.default_rng(1)
    exact = np.full(camera.shape, d, dtype=np.float32)
    data = simulate_depth(exact, np.ones(camera.shape, np.float32), camera, SensorModel(), rng)
    assert data.dtype == np.uint16
    assert np.all(data > 0), "a fronto-parallel wall in range has no dropouts"
    measured = data.astype(np.float64) * camera.depth_scale
    sigma = camera.noise.a + camera.noise.b * d + camera.noise.c * d * d
    assert abs(measured.std() / sigma - 1.0) < 0.2, (measured.std(), sigma)
    assert abs(measured.mean() - d) < 3 * sigma / math.sqrt(measured.size) + 0.0005


def test_quantisation_and_range_limits():
    camera = flat_camera()
    exact = np.array([[1.2344, 1.2346, 0.45, 4.6], [0.0, 2.0, 4.4996, 0.5]], dtype=np.float32)
    exact = np.pad(exact, ((0, 198), (0, 196)), constant_values=2.0)
    data = simulate_depth(exact, np.ones(exact.shape, np.float32), camera, SensorModel.ideal(),
                          np.random.default_rng(0))
    np.testing.assert_array_equal(data[:2, :4], [[1234, 1235, 0, 0], [0, 2000, 4500, 500]])
    noisy = simulate_depth(np.full(camera.shape, 4.49, np.float32), np.ones(camera.shape, np.float32), camera,
                           SensorModel(edge_dropout=0, grazing_dropout=0), np.random.default_rng(0))
    assert 0.05 < (noisy == 0).mean() < 0.95 and noisy.max() <= 4500, "noise crossing the range limit reads 0"


def test_dropouts_only_at_edges_and_grazing_angles():
    camera = flat_camera()
    exact = np.full(camera.shape, 2.0, dtype=np.float32)
    exact[:, 100:] = 2.5                       # a step: columns 99 and 100 are discontinuity pixels
    exact[150:, :50] = 0.0                     # nothing there: its border is a discontinuity too
    cosine = np.ones(camera.shape, dtype=np.float32)
    cosine[:40, 20:60] = 0.1                   # a grazing patch (84 degrees)
    cosine[:40, 60:80] = 0.3                   # 72.5 degrees: below the grazing angle
    sensor = SensorModel(noise=False, edge_dropout=0.5, grazing_dropout=0.9)
    data = simulate_depth(exact, cosine, camera, sensor, np.random.default_rng(3))
    dropped = (data == 0) & (exact > 0)
    edge = discontinuity_mask(exact, sensor.edge_threshold)
    grazing = cosine < math.cos(sensor.grazing_angle)
    assert not np.any(dropped & ~edge & ~grazing), "dropouts only at edges and grazing angles"
    assert set(np.flatnonzero(edge.any(axis=0))) >= {99, 100}
    assert 0.4 < dropped[edge & ~grazing].mean() < 0.6
    assert 0.85 < dropped[grazing & ~edge].mean() < 0.95
    assert not dropped[:40, 61:79].any()


def test_rendered_wall_has_no_dropouts_and_the_right_noise():
    small = workcell_from_dict(tiny_scene())
    frame = next(simulate(small, seed=4))
    image = frame.depth["cam"]
    assert image.timestamp == frame.time == 0.0 and image.depth_scale == 0.001
    assert np.all(image.data > 0)
    np.testing.assert_allclose(frame.depth_exact["cam"], 1.95, atol=1e-5)
    noise = small.rig.cameras["cam"].noise
    sigma = noise.a + noise.b * 1.95 + noise.c * 1.95**2
    assert abs((image.data * 0.001).std() / sigma - 1) < 0.2


def test_frames_are_reproducible_and_excerpts_equal_full_runs():
    small = workcell_from_dict(tiny_scene(duration=0.2))
    full = list(simulate(small, seed=7))
    excerpt = list(simulate(small, seed=7, frames=[3]))
    other = list(simulate(small, seed=8, frames=[3]))
    assert len(full) == 6
    np.testing.assert_array_equal(excerpt[0].depth["cam"].data, full[3].depth["cam"].data)
    assert not np.array_equal(other[0].depth["cam"].data, full[3].depth["cam"].data)
    with pytest.raises(dg.InputError):
        list(simulate(small, frames=[6]))


# -------------------------------------------------------------------------------------------------- people

JOINT_PAIRS = [  # (part, end, part, end): the two ends coincide
    ("upper_arm_left", "p1", "forearm_left", "p0"), ("forearm_left", "p1", "hand_left", "p0"),
    ("upper_arm_right", "p1", "forearm_right", "p0"), ("forearm_right", "p1", "hand_right", "p0"),
    ("thigh_left", "p1", "shin_left", "p0"), ("shin_left", "p1", "foot_left", "p0"),
    ("thigh_right", "p1", "shin_right", "p0"), ("shin_right", "p1", "foot_right", "p0"),
    ("shoulders", "p0", "upper_arm_left", "p0"), ("shoulders", "p1", "upper_arm_right", "p0"),
    ("pelvis", "p0", "thigh_left", "p0"), ("pelvis", "p1", "thigh_right", "p0"),
    ("torso", "p1", "head", "p0"),
]


def test_body_parts_are_connected_and_rigid(wc):
    person = wc.person("worker")
    lengths = None
    for t in np.linspace(0.0, wc.duration, 97):
        parts = dict(zip(PART_NAMES, person.parts_at(t)))
        for a, end_a, b, end_b in JOINT_PAIRS:
            np.testing.assert_allclose(getattr(parts[a], end_a), getattr(parts[b], end_b), atol=1e-12)
        middle = lambda c: (np.asarray(c.p0) + np.asarray(c.p1)) / 2  # noqa: E731
        np.testing.assert_allclose(middle(parts["pelvis"]), parts["torso"].p0, atol=1e-12)
        np.testing.assert_allclose(middle(parts["shoulders"]), parts["torso"].p1, atol=1e-12)
        now = np.array([np.linalg.norm(np.subtract(c.p1, c.p0)) for c in parts.values()])
        if lengths is None:
            lengths = now
        np.testing.assert_allclose(now, lengths, atol=1e-9)
        feet = min(parts["foot_left"].p1[2], parts["foot_right"].p1[2])
        assert wc.floor - 0.01 < feet - 0.04 < wc.floor + 0.2, "feet near the floor"


def test_walk_follows_its_path_at_its_speed(wc):
    person = wc.person("worker")
    walk = span(wc, "walk")
    target = np.array(walk.params["to"], dtype=float)
    start = person.base_at(0.0).position
    speed = walk.params["speed"]
    times = np.linspace(walk.start, walk.end, 50)
    positions = np.array([person.base_at(t).position for t in times])
    direction = (target - start) / np.linalg.norm(target - start)
    offsets = positions - start
    np.testing.assert_allclose(offsets - np.outer(offsets @ direction, direction), 0.0, atol=1e-9)  # on the line
    np.testing.assert_allclose(offsets @ direction, speed * (times - walk.start), atol=1e-9)  # at its speed
    np.testing.assert_allclose(person.base_at(walk.end).position, target, atol=1e-9)
    assert abs(walk.end - walk.start - np.linalg.norm(target - start) / speed) < 1e-9
    heading = person.base_at(walk.start + 0.5).heading
    assert abs(math.remainder(heading - math.atan2(direction[1], direction[0]), 2 * math.pi)) < 1e-6


def test_reach_brings_the_hand_to_its_target(wc):
    reach = span(wc, "reach")
    person = wc.person("worker")
    ee = wc.robot.end_effector_index
    standoff = reach.params["standoff"]
    frames = hold_frames(wc, "reach", ramp=reach.params["ramp"], step=3)
    assert len(frames) * 3 / wc.rate >= 1.4
    truth = TruthComputer(wc.robot)
    names = {n: wc.part_names(n) for n in wc.obstacle_names}
    closest = []
    for t in wc.times()[frames]:
        joints = person.joints_at(t)
        p = wc.control_points_at(t)[ee]
        shoulder = joints["shoulder_right"]
        target = p - standoff * (p - shoulder) / np.linalg.norm(p - shoulder)
        hand = dict(zip(PART_NAMES, person.parts_at(t)))["hand_right"]
        assert hand.distance(target[None])[0] < 0.03
        assert np.linalg.norm(joints["hand_right"] - target) < 0.03
        g = truth(wc.joints_at(t), wc.obstacles_at(t), names)
        closest.append(g.distances[:, list(g.obstacles).index("worker")].min())
    assert 0.1 <= min(closest) and max(closest) <= 0.3, (min(closest), max(closest))


def test_shadow_case(wc):
    frames = hold_frames(wc, "shadow", step=5)
    assert len(frames) * 5 / wc.rate >= 1.5
    eye = wc.rig.cameras[wc.rig.principal].T_world_camera[:3, 3]
    for t in wc.times()[frames]:
        person = wc.obstacles_at(t)["worker"]
        points = wc.control_points_at(t)
        gap = min(part.distance(points).min() for part in person)
        assert gap >= 1.0, f"t = {t}: the person is {gap:.2f} m from the robot"
        rays = points - eye
        length = np.linalg.norm(rays, axis=1)
        origins = np.broadcast_to(eye, rays.shape)
        hit = np.full(len(points), np.inf)
        for part in person:
            hit = np.minimum(hit, part.intersect(origins, rays / length[:, None]))
        assert np.all(hit < length - 1.0), f"t = {t}: rays to {np.flatnonzero(hit >= length - 1.0)} miss the person"


def test_hidden_hand_case(wc):
    case = span(wc, "hidden_hand")
    small = wc.scaled(0.5)
    hand = [name for name, _ in small.labels()].index("worker/hand_right")
    frames = hold_frames(wc, "hidden_hand", ramp=case.params["ramp"], step=8)
    assert len(frames) * 8 / wc.rate >= 1.4
    for frame in simulate(small, frames=frames):
        parts = dict(zip(PART_NAMES, small.obstacles_at(frame.time)["worker"]))
        d = parts["hand_right"].distance(small.control_points_at(frame.time)).min()
        assert 0.1 <= d <= 0.3, f"t = {frame.time}: hand {d:.3f} m from the robot"
        assert 0.0 < frame.truth.clearance < d
        assert (frame.label["principal"] == hand).sum() == 0, "the principal camera sees the hand"
        assert (frame.label["second"] == hand).sum() >= 50, "the second camera does not see the hand"


# ------------------------------------------------------------------------------------------------- hexagon

def test_end_effector_traces_the_hexagon(wc):
    hexagon = wc.trajectory.hexagon
    vertices = hexagon.vertices()
    times = wc.times()
    ee = np.array([wc.control_points_at(t)[wc.robot.end_effector_index] for t in times])
    a, b = vertices, np.roll(vertices, -1, axis=0)
    ab = b - a
    s = np.clip(np.einsum("kij,ij->ki", ee[:, None] - a[None], ab) / np.einsum("ij,ij->i", ab, ab), 0, 1)
    to_edges = np.linalg.norm(ee[:, None] - (a[None] + s[..., None] * ab[None]), axis=2).min(axis=1)
    assert to_edges.max() < 0.003
    assert wc.trajectory.tracking_error < 1e-4
    assert np.linalg.norm(ee[:, None] - vertices[None], axis=2).min(axis=0).max() < 0.015, "every vertex visited"
    speed = np.linalg.norm(np.diff(ee, axis=0), axis=1) * wc.rate
    arc = hexagon.speed * times / hexagon.radius
    straight = np.floor(arc[:-1]) == np.floor(arc[1:])  # both ends of the step on one side
    assert straight.sum() > 0.8 * len(straight)
    assert np.all(np.abs(speed[straight] / 0.4 - 1.0) < 0.05), speed[straight].min()
    assert hexagon.speed == 0.4 and abs(np.linalg.norm(ab, axis=1) - hexagon.radius).max() < 1e-12
    assert abs(hexagon.plane_normal @ [0, 0, 1]) < 1e-12, "a vertical plane"


# -------------------------------------------------------------------------------------------- ground truth

def test_ground_truth_against_coal_and_pybullet(wc):
    from scipy.spatial.transform import Rotation

    client = pybullet.connect(pybullet.DIRECT)
    truth = TruthComputer(wc.robot)
    names = {n: wc.part_names(n) for n in wc.obstacle_names}
    request = coal.DistanceRequest()
    try:
        for t in (2.6, 4.6, 10.6):
            q = wc.joints_at(t)
            obstacles = wc.obstacles_at(t)
            g = truth(q, obstacles, names)
            points = wc.control_points_at(t)
            # Control point distances: coal, a point (sphere of radius 0) against each primitive.
            for j, name in enumerate(g.obstacles):
                for i, p in enumerate(points):
                    best = math.inf
                    for primitive in obstacles[name]:
                        shape, pose = coal_shape(primitive)
                        d = coal.distance(coal.Sphere(0.0), coal.Transform3s(np.eye(3), p), shape, pose, request,
                                          coal.DistanceResult())
                        best = min(best, max(d, 0.0))
                    assert abs(best - g.distances[i, j]) < 1e-9 or best == g.distances[i, j] == math.inf
            assert [g.obstacles[j] for j in g.distances.argmin(axis=1)] == list(g.nearest)
            # Clearance to the person: pybullet's closest points between the link triangle meshes and the body's
            # capsules. (Against boxes its mesh-box distances are off by up to 0.6 mm, more than its margin.)
            person = {"worker": obstacles["worker"]}
            g = truth(q, person, names)
            bodies = []
            poses = wc.robot.link_poses(q)
            links = {}
            for link, mesh in wc.robot.collision_meshes.items():
                shape = pybullet.createCollisionShape(pybullet.GEOM_MESH, vertices=mesh.vertices.tolist(),
                                                      indices=mesh.faces.ravel().tolist(),
                                                      flags=pybullet.GEOM_FORCE_CONCAVE_TRIMESH,
                                                      physicsClientId=client)
                T = poses[link]
                links[link] = pybullet.createMultiBody(0, shape, basePosition=T[:3, 3].tolist(),
                                                       baseOrientation=Rotation.from_matrix(T[:3, :3]).as_quat(),
                                                       physicsClientId=client)
            best = math.inf
            for name, primitives in person.items():
                for primitive in primitives:
                    body = _pybullet_body(pybullet, client, primitive, Rotation)
                    bodies.append(body)
                    for link_body in links.values():
                        for contact in pybullet.getClosestPoints(link_body, body, 3.0, physicsClientId=client):
                            best = min(best, contact[8] + PYBULLET_MESH_MARGIN)
            assert abs(best - g.clearance) < 1e-4, (t, best, g.clearance)
            for body in bodies + list(links.values()):
                pybullet.removeBody(body, physicsClientId=client)
            # Clearance to the carried box: the distance from points spread over the link meshes (and their
            # vertices) to the box is an upper bound that dense sampling brings within a fraction of a millimetre.
            if obstacles["box"]:
                g = truth(q, {"box": obstacles["box"]}, names)
                sampled = math.inf
                for link, mesh in wc.robot.collision_meshes.items():
                    moved = mesh.copy()
                    moved.apply_transform(poses[link])
                    samples, _ = trimesh.sample.sample_surface(moved, 100_000, seed=0)
                    points = np.concatenate([samples, moved.vertices])
                    sampled = min(sampled, obstacles["box"][0].distance(points).min())
                assert g.clearance <= sampled + 1e-9 and sampled - g.clearance < 5e-4, (t, sampled, g.clearance)
    finally:
        pybullet.disconnect(client)


def _pybullet_body(pybullet, client, primitive, Rotation):
    from depthguard.scenes import Box
    from depthguard.transforms import rotation_with_z

    if isinstance(primitive, Capsule):
        p0, p1 = np.asarray(primitive.p0), np.asarray(primitive.p1)
        length = np.linalg.norm(p1 - p0)
        shape = pybullet.createCollisionShape(pybullet.GEOM_CAPSULE, radius=primitive.radius, height=length,
                                              physicsClientId=client)
        position, R = (p0 + p1) / 2, rotation_with_z((p1 - p0) / length)
    elif isinstance(primitive, Box):
        shape = pybullet.createCollisionShape(pybullet.GEOM_BOX, halfExtents=list(primitive.half_extents),
                                              physicsClientId=client)
        position, R = np.asarray(primitive.center), np.asarray(primitive.R_world_box)
    else:
        shape = pybullet.createCollisionShape(pybullet.GEOM_SPHERE, radius=primitive.radius, physicsClientId=client)
        position, R = np.asarray(primitive.center), np.eye(3)
    return pybullet.createMultiBody(0, shape, basePosition=position.tolist(),
                                    baseOrientation=Rotation.from_matrix(R).as_quat(), physicsClientId=client)


def test_default_scenario_keeps_its_promises(wc):
    """Scenario B as the brief describes it: 10-12 s at 30 Hz, every case at least 1.5 s, the person near the robot
    during the reach but never touching it."""
    assert 10.0 <= wc.duration <= 12.0 and wc.rate == 30
    assert [s.kind for s in wc.timeline()] == ["walk", "reach", "walk", "carry", "shadow", "hidden_hand"]
    for s in wc.timeline():
        if s.kind != "walk" or s.index == 0:
            assert s.end - s.hold_start >= 1.5, s
    cameras = wc.rig.cameras
    assert 3.5 <= np.linalg.norm(cameras["principal"].T_world_camera[:3, 3] - cameras["second"].T_world_camera[:3, 3])
    assert all(c.shape == (480, 640) for c in cameras.values())
    truth = TruthComputer(wc.robot)
    names = {n: wc.part_names(n) for n in wc.obstacle_names}
    worker = list(wc.obstacle_names).index("worker")
    clearance, nearest = [], []
    for t in wc.times()[::2]:
        g = truth(wc.joints_at(t), wc.obstacles_at(t), names)
        clearance.append(g.clearance)
        nearest.append(g.distances[:, worker].min())
    assert min(clearance) > 0.0
    assert min(nearest) > 0.0
    reach = span(wc, "reach")
    during = [d for t, d in zip(wc.times()[::2], nearest) if reach.hold_start <= t <= reach.end]
    assert 0.1 <= min(during) <= 0.3


# ------------------------------------------------------------------------------------------------ episode

def test_write_episode(wc, tmp_path):
    small = wc.scaled(0.25)
    frames = [0, 75, 300]
    out = write_episode(small, tmp_path / "episode", seed=3, progress=False, frames=frames)
    assert out == tmp_path / "episode"
    rig = dg.load_rig(out / "rig.yaml")
    assert rig.fingerprint() == small.rig.fingerprint() and rig.principal == "principal"
    expected = list(simulate(small, seed=3, frames=frames))
    for frame in expected:
        for name in small.rig.cameras:
            path = out / "depth" / name / f"{frame.index:06d}.png"
            with Image.open(path) as image:
                assert image.mode.startswith("I;16") or image.mode == "I"
            loaded = dg.load_depth(path, rig.cameras[name])
            assert loaded.data.dtype == np.uint16 and loaded.shape == (120, 160)
            np.testing.assert_array_equal(loaded.data, frame.depth[name].data)
            grey = np.array(Image.open(out / "intensity" / name / f"{frame.index:06d}.png"))
            np.testing.assert_array_equal(grey, frame.intensity[name])
    with open(out / "joint_states.csv") as f:
        rows = list(csv.reader(f))
    assert rows[0] == ["time", *small.robot.joint_names]
    assert len(rows) == 1 + len(frames)
    np.testing.assert_allclose([float(x) for x in rows[2][1:]], small.joints_at(75 / 30), atol=1e-12)
    with open(out / "ground_truth.csv") as f:
        truth = list(csv.DictReader(f))
    assert len(truth) == len(frames) * 9
    assert set(truth[0]) == {"time", "frame", "control_point", "distance", "nearest_obstacle", "nearest_part",
                             "touching", "clearance"}
    row = next(r for r in truth if r["frame"] == "75" and r["control_point"] == "end_effector")
    assert abs(float(row["distance"]) - expected[1].truth.distance[-1]) < 1e-6
    assert row["nearest_obstacle"] == expected[1].truth.nearest[-1] and row["touching"] == "0"
    again = load_workcell(out / "scene.yaml")
    assert again.rig.fingerprint() == wc.rig.fingerprint()
    assert yaml.safe_load((out / "scene.yaml").read_text())["duration"] == wc.duration
    with open(out / "timeline.csv") as f:
        assert [r["action"] for r in csv.DictReader(f)] == [s.kind for s in wc.timeline()]


def test_scene_options_urdf_waypoints_intensity_cameras_and_simple_actions(tmp_path):
    """The keys scenario B does not use: a URDF path, joint waypoints, an intensity camera posed by T_world_camera,
    sphere and capsule objects, and a person who stands and reaches for a fixed point."""
    from depthguard.robots import default_robot_path

    names = dg.robots.RobotModel.default().joint_names
    up = {name: 0.0 for name in names}
    bent = {**up, names[1]: 0.5, names[3]: -1.0}
    T_world_eye = dg.transforms.look_at([3.0, 0.0, 1.2], [0.0, 0.0, 0.6])
    scene = tiny_scene(
        duration=2.5,
        robot={"urdf": str(default_robot_path()), "base": {"position": [0.0, 0.0, 0.0], "yaw": 0.5},
               "trajectory": {"type": "joints", "waypoints": [{"time": 0.2, "joints": up},
                                                              {"time": 1.0, "joints": bent}]}},
        intensity_cameras=[{"name": "grey", "width": 80, "height": 60, "fx": 60.0, "fy": 60.0, "cx": 39.5,
                            "cy": 29.5, "T_world_camera": T_world_eye.tolist(), "noise_sigma": 0.0}],
        static_objects=[{"name": "ball", "sphere": {"center": [1.0, 1.0, 0.3], "radius": 0.2}},
                        {"name": "post", "capsule": {"p0": [1.0, -1.0, 0.0], "p1": [1.0, -1.0, 1.0], "radius": 0.1},
                         "obstacle": False}],
        people=[{"name": "visitor", "start": {"position": [2.0, 1.0], "facing": "robot"},
                 "actions": [{"stand": {"duration": 0.3, "position": [1.8, 0.0], "facing": [0.0, 0.0]}},
                             {"reach": {"hand": "left", "target": [1.45, 0.15, 1.1], "duration": 1.0, "ramp": 0.2}}]}],
    )
    wc = workcell_from_dict(scene)
    assert wc.robot.joint_names == names and wc.intensity_rig is not None
    np.testing.assert_allclose(wc.robot.T_world_base[:2, :2], [[math.cos(0.5), -math.sin(0.5)],
                                                               [math.sin(0.5), math.cos(0.5)]])
    np.testing.assert_allclose(wc.joints_at(0.0), wc.robot.joint_vector(up))
    np.testing.assert_allclose(wc.joints_at(1.0), wc.robot.joint_vector(bent), atol=1e-12)
    np.testing.assert_allclose(wc.joints_at(2.4), wc.robot.joint_vector(bent), atol=1e-12)
    assert np.all(np.diff(wc.trajectory.joints[:, 1]) >= -1e-12), "monotone between waypoints"
    assert wc.obstacle_names == ("visitor", "ball")
    person = wc.person("visitor")
    stand, reach = person.spans
    np.testing.assert_allclose(person.base_at(stand.end).position, [1.8, 0.0], atol=1e-12)
    assert stand.hold_start > stand.start and abs(stand.end - stand.hold_start - 0.3) < 1e-12
    hand = person.joints_at(reach.start + 0.5)["hand_left"]
    assert np.linalg.norm(hand - [1.45, 0.15, 1.1]) < 1e-6
    frame = next(simulate(wc, frames=[15]))
    grey = frame.intensity["grey"]
    assert grey.dtype == np.uint8 and grey.shape == (60, 80) and "grey" not in frame.depth
    labels = [name for name, _ in wc.labels()]
    seen = {labels[i] for i in np.unique(frame.label["grey"]) if i >= 0}
    assert {"ball", "post", "visitor/torso"} <= seen and any(n.startswith("robot/") for n in seen)
    assert frame.truth.obstacles == ("visitor", "ball")
    assert frame.truth.distances.shape == (len(wc.robot.control_points), 2)  # the URDF default control points
    out = write_episode(wc, tmp_path / "ep", progress=False, frames=[0])
    assert dg.load_rig(out / "intensity_rig.yaml").fingerprint() == wc.intensity_rig.fingerprint()
    assert (out / "intensity" / "grey" / "000000.png").is_file()


def test_a_scene_loads_with_another_scenes_camera_layout(tmp_path):
    """load_workcell(scene, layout=other): the scene's robot, task and people, the other file's cameras, principal
    and workspace (issue 9's four-camera runs of the avoidance scenarios)."""
    from importlib import resources
    from pathlib import Path

    folder = Path(str(resources.files("depthguard_lab.simulation")))
    scene = load_workcell(folder / "scenario_b_reach.yaml")
    four = load_workcell(folder / "scenario_b_four.yaml")
    both = load_workcell(folder / "scenario_b_reach.yaml", layout=folder / "scenario_b_four.yaml")
    assert tuple(both.rig.cameras) == tuple(four.rig.cameras) != tuple(scene.rig.cameras)
    assert both.rig.principal == four.rig.principal
    for name, camera in four.rig.cameras.items():
        assert np.array_equal(both.rig.cameras[name].T_world_camera, camera.T_world_camera)
    assert [p.name for p in both.people] == [p.name for p in scene.people]
    for t in (0.5, 2.5):
        assert np.array_equal(both.joints_at(t), scene.joints_at(t))
        assert np.allclose(both.control_points_at(t), scene.control_points_at(t))
    (tmp_path / "empty.yaml").write_text("duration: 4.0\n")
    with pytest.raises(SceneError, match="with the cameras of"):
        load_workcell(folder / "scenario_b_reach.yaml", layout=tmp_path / "empty.yaml")
    (tmp_path / "bad.yaml").write_text("cameras: 3\n")
    with pytest.raises(SceneError, match="with the cameras of"):
        load_workcell(folder / "scenario_b_reach.yaml", layout=tmp_path / "bad.yaml")


def test_rotation_with_z_is_a_rotation_whose_third_column_is_the_axis():
    from depthguard.transforms import rotation_with_z

    rng = np.random.default_rng(7)
    axes = [np.array(a, dtype=float) for a in ([1, 0, 0], [0, 1, 0], [0, 0, 1], [-1, 0, 0], [0.9, 0.1, 0.0])]
    axes += list(rng.normal(size=(200, 3)))
    for axis in axes:
        axis = axis / np.linalg.norm(axis)
        R = rotation_with_z(axis)
        np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
        assert np.linalg.det(R) > 0.0
        np.testing.assert_allclose(R[:, 2], axis, atol=1e-15)


def test_a_person_stepping_back_keeps_facing_the_way_it_came(wc):
    """walk/carry ``backwards: true`` (scenario_b_board.yaml: the board is carried back out of the robot's reach
    without swinging through it): the person moves the other way and its heading stays."""
    scene = copy.deepcopy(wc.scene)
    person = scene["people"][0]
    person["actions"] = [{"walk": {"to": [2.0, 0.0], "speed": 1.0}},
                         {"walk": {"to": [3.0, 0.0], "speed": 0.5, "backwards": True}}]
    walker = workcell_from_dict(scene).people[0]
    forward, back = walker.base_at(1.0), walker.base_at(walker.time - 0.1)
    assert back.position[0] > forward.position[0]  # it went on along +x ...
    facing = np.array([np.cos(back.heading), np.sin(back.heading)])
    np.testing.assert_allclose(facing, [-1.0, 0.0], atol=1e-6)  # ... facing -x, the way it came
