"""Fused distances (the depth grid, design §8) judged by code the project did not write (issue 4).

pybullet renders every camera (TinyRenderer through ``getCameraImage``, the conventions of ``pybullet_scenes``, which
``test_judge_pybullet`` checks) and pybullet's ``getClosestPoints`` and coal say how far each control point truly is
from the obstacles. The scenes: random boxes, spheres and capsules in the closed room of ``pybullet_scenes``, seen by
two cameras 3.5 m apart and by four; a capsule "person" between the principal camera and the control points, far from
them (the shadow case); a small capsule hidden from the principal camera behind a link of the KUKA iiwa and seen by
the second camera (the hidden-hand case). All 160x120 (f = 131.25 px), noise-free float32 images, rho = 0.4 m,
``aggregate="min"``, fusion margin 1 cm and footprints grown by 1 pixel (the monitor's defaults, passed explicitly).

The claims under test, for every control point:

1. never optimistic: fused <= true + tolerance;
2. fusion only removes false occupancy: fused >= the principal camera's own single-camera distance on the same frame
   (with a robot: its conservative ``min(distance, blind_distance)``), to 1e-9 m.

Tolerance (``fusion_scenes.fused_bound``, derived there): the distance from the true nearest obstacle point Q to the
nearest point the fused query must count as occupied whatever it does with the gray area: the measured surfaces' own
grid cells in the 3 x 3 principal pixels around Q (the principal camera's pixel discretisation at Q, as
``pybullet_scenes.discretisation_bound`` but without the gray area behind a surface), the view's boundary, and the gray
cells that every secondary camera's image shows it cannot see through by the corrected confirmation rule (for Q's own
cell, tolerance 0). Measured below with ``pytest -s``.

Can the assertions fail? Yes, and the tests show it on these scenes: with the hidden capsule taken out of the second
camera's image only, 48 points near it come out above truth + tolerance; with each secondary image pushed deeper by
the fusion margin plus the smallest depth extent of a grid cell in that camera (the library's rule then clears a cell
once every pixel of its footprint sees beyond the cell's near depth: less than the papers' rule clears), the judge
flags optimistic points; and the papers' rule itself clears 26 of the 34 cells that hold the hidden capsule's nearest
points, which the corrected rule (``naive.camera_clears_reference``) all keeps.
"""

from __future__ import annotations

import os
import shutil
from dataclasses import dataclass

import numpy as np
import pybullet as p
import pybullet_data
import pytest
from scipy import ndimage

import coal  # noqa: F401  (a judge: a missing one must fail, never skip)
import depthguard as dg
import fusion_scenes as fs
import naive
import pybullet_scenes as ps
from depthguard.depthgrid import build_map
from depthguard.robots import RobotModel
from test_judge_pybullet import EPS, JUDGES_AGREE

RHO = 0.4
MARGIN = 0.01
PAD = 1

SEEDS_TWO = tuple(range(8))
SEEDS_FOUR = (100, 101, 102, 103)


@pytest.fixture(scope="module")
def client():
    cid = p.connect(p.DIRECT)
    yield cid
    p.disconnect(cid)


@dataclass
class Judged:
    """One scene, its control points and everything measured about them."""

    label: str
    rig: dg.Rig
    depths: dict  # camera name -> (h, w) rendered optical z, metres (inf: nothing)
    segmentation: dict  # camera name -> (h, w) pybullet body ids
    points: np.ndarray  # (n, 3) world
    truth: ps.Truth
    bound: np.ndarray  # (n,) tolerance, metres
    how: np.ndarray  # (n,) which candidate gave the tolerance
    fused: dg.DistanceResult
    single: np.ndarray  # (n,) the principal's single-camera (conservative) distance
    robot: object = None
    joints: np.ndarray | None = None

    def frames(self, shift: float = 0.0) -> dict:
        """Fresh depthguard frames of every camera; ``shift`` metres added to the secondary cameras' depths."""
        return {n: fs.depth_frame(d + (0.0 if n == "p" else shift), self.rig.cameras[n])
                for n, d in self.depths.items()}

    def monitor(self, rig: dg.Rig | None = None) -> dg.DistanceMonitor:
        rig = self.rig if rig is None else rig
        return dg.DistanceMonitor(rig, rho=RHO, aggregate="min", robot=self.robot, fusion_margin=MARGIN,
                                  fusion_pixels=PAD)


def judge(client, label: str, scene: ps.PybulletScene, rig: dg.Rig, points, robot=None, joints=None,
          maybe_robot=None, behind_robot=None) -> Judged:
    """Render ``rig``'s cameras (every body of ``client``), measure the truth at ``points`` against ``scene``'s
    primitives (points inside one are left out), query the fused and the single-camera monitors, work out the
    tolerance."""
    depths, segmentation = {}, {}
    for name, cam in rig.cameras.items():
        depths[name], segmentation[name] = ps.render_depth(client, cam)
        lo, hi = cam.depth_range
        assert np.all((depths[name] > lo) & (depths[name] < hi)), f"{label}: camera {name} sees beyond its range"
    truth = scene.measure(points, RHO + 0.2)
    assert truth.judges_gap <= JUDGES_AGREE, f"{label}: pybullet and coal differ by {truth.judges_gap:.3g} m"
    outside = truth.distance > 0.0
    truth = ps.Truth(truth.distance[outside], truth.nearest_world[outside], truth.primitive[outside],
                     truth.judges_gap)
    points = np.asarray(points)[outside]
    j = Judged(label, rig, depths, segmentation, points, truth, np.empty(0), np.empty(0), None, np.empty(0), robot,
               joints)
    grid = build_map(rig, "p")
    frames = j.frames()
    j.fused = j.monitor().query(frames, points, joints=joints)
    single = j.monitor(dg.Rig({"p": rig.cameras["p"]})).query({"p": frames["p"]}, points, joints=joints)
    j.single = np.minimum(single.distance, single.blind_distance)
    secondaries = [(rig.cameras[n], depths[n]) for n in rig.cameras if n != "p"]
    j.bound, j.how = fs.fused_bound(rig.cameras["p"], depths["p"], truth.nearest_world, grid, secondaries, MARGIN,
                                    PAD, maybe_robot=maybe_robot, behind_robot=behind_robot)
    return j


def excess(j: Judged, reported=None) -> np.ndarray:
    """(n,) reported - true, metres; a point reported free (inf) gets +inf if truth + tolerance lies within rho (the
    library should have kept something) and -inf otherwise."""
    reported = j.fused.distance if reported is None else reported
    within = j.truth.distance + j.bound + EPS < RHO
    with np.errstate(invalid="ignore"):
        return np.where(np.isfinite(reported), reported - j.truth.distance, np.where(within, np.inf, -np.inf))


def optimistic(j: Judged, reported=None) -> np.ndarray:
    """Indices of the points whose reported distance exceeds the truth plus the tolerance."""
    return np.flatnonzero(excess(j, reported) - j.bound > EPS)


def assert_never_optimistic(j: Judged) -> None:
    bad = optimistic(j)
    if len(bad):
        i = bad[np.argmax((excess(j) - j.bound)[bad])]
        P, Q = j.points[i], j.truth.nearest_world[i]
        seen = {n: _sees(j.rig.cameras[n], j.depths[n], Q) for n in j.rig.cameras}
        pytest.fail(f"{j.label}: {len(bad)} optimistic points; worst P = {P.tolist()} (world): fused "
                    f"{j.fused.distance[i]:.6f} m, single {j.single[i]:.6f} m, true {j.truth.distance[i]:.6f} m "
                    f"(nearest point {Q.tolist()}, primitive {j.truth.primitive[i]}), tolerance {j.bound[i]:.6f} m "
                    f"({j.how[i]}); camera sees Q: {seen}; flags {j.fused.flags[i].names}")


def assert_not_below_single(j: Judged) -> None:
    below = np.flatnonzero(j.fused.distance < j.single - 1e-9)
    assert len(below) == 0, (f"{j.label}: fused below the principal's single-camera distance at "
                             f"{j.points[below[0]].tolist()}: {j.fused.distance[below[0]]} < {j.single[below[0]]}")


def _sees(cam, depth, point_world) -> bool:
    """Whether ``cam`` sees the world point: in its image and not more than 1 cm behind what its pixel shows."""
    u, v, z = cam.project(cam.world_to_camera(np.asarray(point_world)[None]))
    if not (z[0] > 0 and -0.5 < u[0] < cam.width - 0.5 and -0.5 < v[0] < cam.height - 0.5):
        return False
    return bool(depth[int(np.rint(v[0])), int(np.rint(u[0]))] >= z[0] - 0.01)


# ----------------------------------------------------------------------------------------------------- random scenes

def random_scene(client, seed: int, names) -> Judged:
    """The room and 5-8 random obstacles in its middle; control points near the obstacles (24 tries each, 1 mm to
    rho off their surfaces) and 30 anywhere among them."""
    rng = np.random.default_rng(seed)
    room = ps.room()
    primitives = room + fs.random_obstacles(rng, int(rng.integers(5, 9)))
    scene = ps.PybulletScene(client, primitives)
    try:
        points = np.concatenate([fs.points_near(scene, rng, range(len(room), len(primitives)), 24, RHO),
                                 rng.uniform(fs.OBSTACLE_LOW, fs.OBSTACLE_HIGH, (30, 3))])
        return judge(client, f"{len(names)} cameras, seed {seed}", scene, fs.rig(names), points)
    finally:
        scene.remove()


@pytest.fixture(scope="module")
def two_camera_scenes(client):
    return [random_scene(client, seed, ("p", "s")) for seed in SEEDS_TWO]


@pytest.fixture(scope="module")
def four_camera_scenes(client):
    return [random_scene(client, seed, ("p", "s", "t", "w")) for seed in SEEDS_FOUR]


def _summary(scenes) -> dict:
    e = np.concatenate([excess(j) for j in scenes])
    bound = np.concatenate([j.bound for j in scenes])
    how = np.concatenate([j.how for j in scenes])
    truth = np.concatenate([j.truth.distance for j in scenes])
    fused = np.concatenate([j.fused.distance for j in scenes])
    single = np.concatenate([j.single for j in scenes])
    finite = np.isfinite(e)
    ratio = np.where(bound > 0, e / np.where(bound > 0, bound, 1.0), -np.inf)
    return dict(points=len(e), max_excess=float(e[finite].max()), max_ratio=float(ratio[finite].max()),
                max_bound=float(bound[how != "unseen"].max()),
                exact=int(np.count_nonzero((how == "confirmed") & (bound == 0))),
                how={h: int(np.count_nonzero(how == h)) for h in np.unique(how)},
                raised=int(np.count_nonzero(np.minimum(fused, RHO) > np.minimum(single, RHO) + 0.01)),
                near=int(np.count_nonzero(truth < RHO)))


def test_random_scenes_two_cameras(two_camera_scenes):
    """Eight random scenes, two cameras: never above truth + tolerance, never below the principal alone.

    Measured: 1504 points (1416 within rho of an obstacle); largest fused - true 14.2 mm, largest (fused - true) /
    tolerance 0.995 (the tolerance is tight); tolerance at most 14.6 mm (about half a pixel footprint at 3.5 m);
    1064 points judged through a gray cell the second camera confirms (631 of them with tolerance 0: the cell holding
    Q), 430 through a surface cell, 10 with Q out of view; fusion raised 275 distances by more than 1 cm over the
    principal camera's own.
    """
    for j in two_camera_scenes:
        assert_never_optimistic(j)
        assert_not_below_single(j)
    s = _summary(two_camera_scenes)
    print(f"\ntwo cameras: {s}")
    # the judge is not vacuous: many points rest on tolerance 0 through a confirmed cell, and fusion did something
    assert s["exact"] >= 300 and s["raised"] >= 100 and s["max_bound"] < 0.03


def test_random_scenes_four_cameras(four_camera_scenes):
    """Four random scenes, four cameras around the room (a cell is occupied only if all three secondaries confirm
    it). Measured: 736 points (684 within rho); largest fused - true 11.3 mm, largest (fused - true) / tolerance
    0.975; tolerance at most 11.7 mm; 551 points judged through gray cells all three secondaries confirm (322 with
    tolerance 0); fusion raised 167 distances by more than 1 cm."""
    for j in four_camera_scenes:
        assert_never_optimistic(j)
        assert_not_below_single(j)
    s = _summary(four_camera_scenes)
    print(f"\nfour cameras: {s}")
    assert s["exact"] >= 150 and s["raised"] >= 50 and s["max_bound"] < 0.03


# ------------------------------------------------------------------------------------------------------ the shadow

#: The control points' region (world, metres): a cube of half-size SHADOW_HALF around SHADOW_CENTRE.
SHADOW_CENTRE = np.array([0.7, 0.3, 0.8])
SHADOW_HALF = 0.35

#: A false alarm: the single camera reports an obstacle more than this nearer than min(truth, rho) (4 pixel
#: footprints at the region's range). Within a few centimetres of a surface the second camera sees, its pixels cannot
#: clear the cells (margin + grown footprint), so a smaller threshold would count that as unremoved.
FALSE_ALARM = 0.1


def test_shadow_of_a_person_is_removed(client):
    """A capsule "person" (radius 0.2 m, 1.6 m tall) stands between the principal camera and the control points, more
    than 0.6 m from every one of them, and a table top lies among them. The principal camera alone reports the
    person's gray area (distance 0 for most points); fused with the second camera, most of those false alarms go
    away, and no point comes out above truth + tolerance.

    Measured: 150 points, 124 false alarms of the single camera, 120 removed (96.8 %); median fused / min(truth, rho)
    over the false alarms 0.91 (single: 0).
    """
    eye = np.array(fs.EYES["p"])
    xy = eye[:2] + 0.42 * (SHADOW_CENTRE[:2] - eye[:2])
    person = ps.Primitive("capsule", (0.2, 1.2), ps.pose(np.eye(3), [xy[0], xy[1], 0.8]))
    table = ps.Primitive("box", (0.3, 0.3, 0.02), ps.pose(np.eye(3), [0.7, 0.3, 0.43]))
    room = ps.room()
    scene = ps.PybulletScene(client, room + [person, table])
    rng = np.random.default_rng(0)
    points = SHADOW_CENTRE + rng.uniform(-SHADOW_HALF, SHADOW_HALF, (150, 3))
    try:
        to_person = scene.closest_coal(points)[0][:, len(room)]
        assert to_person.min() > 0.6, "the person must stand far from the control points"
        j = judge(client, "shadow", scene, fs.rig(("p", "s")), points)
    finally:
        scene.remove()
    assert_never_optimistic(j)
    assert_not_below_single(j)
    reference = np.minimum(j.truth.distance, RHO)
    alarm = j.single < reference - FALSE_ALARM
    removed = alarm & (j.fused.distance >= reference - FALSE_ALARM)
    fraction = removed.sum() / alarm.sum()
    median = float(np.median(np.minimum(j.fused.distance[alarm], RHO) / reference[alarm]))
    print(f"\nshadow: {len(j.points)} points, person >= {to_person.min():.2f} m away; single-camera false alarms "
          f"{alarm.sum()} (distance 0: {np.count_nonzero(j.single == 0)}), removed by fusion {removed.sum()} "
          f"({100 * fraction:.1f} %); median fused / min(truth, rho) over them {median:.3f}; largest fused - true "
          f"{np.max(excess(j)[np.isfinite(excess(j))]) * 1e3:.1f} mm")
    assert alarm.sum() >= 100, "the person must cast its shadow over the control points"
    assert fraction >= 0.9


# ------------------------------------------------------------------------------------- hidden behind the robot

#: The iiwa's configuration (radians) and the hidden object: a capsule (radius 3 cm, axis 12 cm) parallel to link 3,
#: HIDDEN_BEHIND metres behind its axis along the principal camera's line of sight.
HIDDEN_Q = np.array([0.0, 0.3, 0.0, -0.6, 0.0, 0.5, 0.0])
HIDDEN_BEHIND = 0.25

#: The self-filter counts as the robot everything up to where its padded hull ends along a pixel (padding 2 cm, plus
#: the hull's excess over the mesh) plus its 2 cm tolerance. The judge counts on a gray cell behind the robot only
#: for points whose line of sight to the principal camera meets the robot's mesh at least BEHIND_ALONG_RAY metres in
#: front of them and that are at least BEHIND_CLEARANCE metres from the mesh in every direction.
BEHIND_ALONG_RAY = 0.10
BEHIND_CLEARANCE = 0.06

#: Principal pixels that may show the robot's padded hull: pybullet's robot silhouette grown by this many pixels
#: (2 cm of padding is about one pixel at 2.5 m; the self-filter also looks one pixel around).
ROBOT_SILHOUETTE_GROWTH = 4


@pytest.fixture(scope="module")
def iiwa_urdf(tmp_path_factory):
    """pybullet_data's iiwa with its collision meshes as visuals (as in test_judge_self_filter), so that pybullet
    draws the geometry depthguard's robot model describes."""
    folder = tmp_path_factory.mktemp("iiwa")
    source = os.path.join(pybullet_data.getDataPath(), "kuka_iiwa")
    shutil.copytree(os.path.join(source, "meshes"), folder / "meshes")
    with open(os.path.join(source, "model.urdf")) as f:
        (folder / "model.urdf").write_text(f.read().replace(".obj", ".stl"))
    return str(folder / "model.urdf")


@pytest.fixture(scope="module")
def hidden_object(iiwa_urdf):
    """The iiwa at HIDDEN_Q, the room, and the hidden capsule; control points: the robot's 9 and 80 tries around
    the capsule. Returns (Judged, info dict)."""
    client = p.connect(p.DIRECT)
    robot_only = p.connect(p.DIRECT)  # for ray casts against the robot alone
    try:
        bodies = [p.loadURDF(iiwa_urdf, useFixedBase=True, physicsClientId=c) for c in (client, robot_only)]
        for joint in range(7):
            for c, body in zip((client, robot_only), bodies):
                p.resetJointState(body, joint, HIDDEN_Q[joint], physicsClientId=c)
        robot = RobotModel.default()
        control = robot.control_point_positions(HIDDEN_Q)
        rig = fs.rig(("p", "s"))
        eye = np.array(fs.EYES["p"])
        anchor = 0.5 * (control[1] + control[2])  # on link 3's axis
        axis = (control[2] - control[1]) / np.linalg.norm(control[2] - control[1])
        sight = (anchor - eye) / np.linalg.norm(anchor - eye)
        side = np.cross(axis, [1.0, 0.0, 0.0])
        side /= np.linalg.norm(side)
        hidden = ps.Primitive("capsule", (0.03, 0.12), ps.pose(np.stack([side, np.cross(axis, side), axis], 1),
                                                                 anchor + HIDDEN_BEHIND * sight))
        room = ps.room()
        scene = ps.PybulletScene(client, room + [hidden])
        probe = p.createCollisionShape(p.GEOM_SPHERE, radius=1e-5, physicsClientId=robot_only)

        def behind_robot(points_world):
            hits = p.rayTestBatch(points_world.tolist(), [eye.tolist()] * len(points_world),
                                  physicsClientId=robot_only)
            out = np.zeros(len(points_world), bool)
            for k, (B, hit) in enumerate(zip(points_world, hits)):
                along = hit[0] == bodies[1] and np.linalg.norm(np.asarray(hit[3]) - B) >= BEHIND_ALONG_RAY
                near = p.getClosestPoints(bodyA=-1, bodyB=bodies[1], distance=BEHIND_CLEARANCE,
                                          collisionShapeA=probe, collisionShapePositionA=B.tolist(),
                                          physicsClientId=robot_only)
                out[k] = along and not near
            return out

        _, segmentation = ps.render_depth(client, rig.cameras["p"])
        maybe_robot = ndimage.binary_dilation(segmentation == bodies[0], structure=np.ones((3, 3), bool),
                                              iterations=ROBOT_SILHOUETTE_GROWTH)
        rng = np.random.default_rng(4)
        points = np.concatenate([control, fs.points_near(scene, rng, [len(room)], 80, RHO)])
        j = judge(client, "hidden behind the robot", scene, rig, points, robot=robot, joints=HIDDEN_Q,
                  maybe_robot=maybe_robot, behind_robot=behind_robot)
        # the second camera's view without the capsule: what it would show if it could see through it
        p.resetBasePositionAndOrientation(scene.bodies[-1], [0.0, 0.0, -5.0], [0, 0, 0, 1], physicsClientId=client)
        without, _ = ps.render_depth(client, rig.cameras["s"])
        info = dict(robot_body=bodies[0], hidden_body=scene.bodies[-1], hidden_index=len(room),
                    maybe_robot=maybe_robot, n_control=len(control), s_without_hidden=without)
        yield j, info
    finally:
        p.disconnect(robot_only)
        p.disconnect(client)


def test_object_hidden_behind_the_robot(hidden_object):
    """A small capsule behind link 3 of the iiwa as the principal camera sees it, in full view of the second camera.
    The single camera cannot see it: its distance is above the truth for the points near the capsule, and only its
    blind distance (the space behind the robot) covers them. Fused, the second camera confirms the cells behind the
    link that hold the capsule: fused <= truth + tolerance, and fused >= the single camera's conservative
    min(distance, blind_distance). Points on the robot get small fused distances where space next to the robot is
    hidden from both cameras: conservative and correct, so only these bounds are asserted.

    The check has teeth: with the capsule taken out of the second camera's image only (as if that camera saw through
    it), the same judge finds points above truth + tolerance.

    Measured: the capsule covers 0 principal pixels and 21 of the second camera's; 79 points within rho of it (7 of
    the robot's 9 control points); the single camera's distance exceeded truth + tolerance at 78 of them (the other
    is as near the floor, which it sees, as the capsule), its blind distance covers all 79; 44 judged with
    tolerance 0 through the cell holding Q, which the second camera confirms; largest fused - true -1.2 mm (fused /
    true median 0.16: the space around the arm that neither camera sees); without the capsule in the second image,
    48 of the 79 come out above truth + tolerance.
    """
    j, info = hidden_object
    p_pixels = int(np.count_nonzero(j.segmentation["p"] == info["hidden_body"]))
    s_pixels = int(np.count_nonzero(j.segmentation["s"] == info["hidden_body"]))
    assert p_pixels == 0, "the principal camera must not see the hidden object"
    assert s_pixels >= 10, "the second camera must see the hidden object"
    # The judge's robot mask covers every pixel the library's self-filter gave to the robot.
    occupancy = j.monitor(dg.Rig({"p": j.rig.cameras["p"]})).prepare("p", j.frames()["p"], joints=j.joints)
    assert occupancy.robot_pixels > 100
    assert not np.any(np.isfinite(occupancy.blind) & ~info["maybe_robot"])

    assert_never_optimistic(j)
    assert_not_below_single(j)
    near = (j.truth.primitive == info["hidden_index"]) & (j.truth.distance < RHO)
    single = j.monitor(dg.Rig({"p": j.rig.cameras["p"]})).query({"p": j.frames()["p"]}, j.points,
                                                                  joints=j.joints)
    hidden_from_single = near & (single.distance > j.truth.distance + j.bound)
    covered = np.minimum(single.distance, single.blind_distance) <= j.truth.distance + j.bound + EPS
    exact = near & (j.how == "confirmed") & (j.bound == 0)
    e = excess(j)
    print(f"\nhidden object: {p_pixels} principal pixels, {s_pixels} second-camera pixels; {near.sum()} points within "
          f"rho of it ({near[: info['n_control']].sum()} control points); single camera above truth + tolerance at "
          f"{hidden_from_single.sum()}, blind distance covering {np.count_nonzero(covered & near)}; tolerance 0 "
          f"through confirmed cells at {exact.sum()}; largest fused - true {np.max(e[near]) * 1e3:.1f} mm; fused / "
          f"true median {np.median(j.fused.distance[near] / j.truth.distance[near]):.3f}")
    # Had the second camera seen through the capsule, the fused distances would have missed it.
    frames = j.frames()
    frames["s"] = fs.depth_frame(info["s_without_hidden"], j.rig.cameras["s"])
    blind_s = j.monitor().query(frames, j.points, joints=j.joints)
    missed = near & np.isin(np.arange(len(j.points)), optimistic(j, blind_s.distance))
    print(f"  without the capsule in the second camera's image: {missed.sum()} of them above truth + tolerance")
    assert near.sum() >= 40 and near[: info["n_control"]].sum() >= 3
    assert missed.sum() >= 5
    assert hidden_from_single.sum() >= 0.95 * near.sum()
    assert np.all(covered[near])
    assert exact.sum() >= 0.5 * near.sum()


# --------------------------------------------------------------------------------------- the judge can catch

def smallest_cell_extent(rig: dg.Rig, name: str, z_from: float) -> float:
    """The smallest depth extent, in camera ``name``, of the principal's grid cells that reach beyond depth
    ``z_from``: over each cell's 8 corners, the largest minus the smallest depth in ``name`` (a lower bound of far -
    near for each of those cells)."""
    grid = build_map(rig, "p")
    a = grid.corners[grid.secondaries.index(name), ..., 2]  # depth in ``name`` per metre of principal depth
    per_pixel = np.stack([a[:-1, :-1], a[:-1, 1:], a[1:, :-1], a[1:, 1:]], axis=-1)
    c_lo, c_hi = per_pixel.min(axis=-1)[..., None], per_pixel.max(axis=-1)[..., None]
    z0 = grid.d_min + np.arange(grid.n_cells) * grid.delta_d
    z0 = z0[z0 + grid.delta_d >= z_from]
    z1 = z0 + grid.delta_d
    # corner depth = c * z + offset: over z in {z0, z1} and the 4 corner rays, from min(c z) to max(c z)
    extent = np.maximum(c_hi * z0, c_hi * z1) - np.minimum(c_lo * z0, c_lo * z1)
    return float(extent.min())


def papers_rule_clears(grid, j: int, depth_j: np.ndarray, u: int, v: int, z0: float, z1: float) -> bool:
    """The 2016 paper's confirmation rule for secondary camera j (index in ``grid.secondaries``): j confirms the
    cell [z0, z1] of principal pixel (u, v) only if its depth at the pixel holding the cell's centre is nearer than
    the cell's near depth; otherwise it declares the cell free."""
    corners = np.array([grid.corners[j, v + dv, u + du] * z + grid.offsets[j]
                        for dv in (0, 1) for du in (0, 1) for z in (z0, z1)])
    near = corners[:, 2].min()
    centre = corners.mean(axis=0)
    q, r = int(np.rint(centre[0] / centre[2])), int(np.rint(centre[1] / centre[2]))
    return bool(depth_j[r, q] >= near)


def test_the_judge_catches_the_papers_confirmation_rule(two_camera_scenes, hidden_object):
    """The same judge flags a library that clears too much.

    1. Each secondary image pushed deeper by MARGIN + the smallest depth extent of any grid cell in that camera: the
       library's own rule then clears a cell once every pixel of its grown footprint sees beyond the cell's near
       depth, which the papers' rule (one pixel beyond the near depth) always clears too; clearing more can only
       raise fused distances, so whatever the judge flags here it flags for the papers' rule as well.
    2. The cells that hold the hidden object's nearest points (tolerance 0 above): the papers' rule clears some of
       them, while the corrected rule (``naive.camera_clears_reference``, the slow twin) clears none.

    Measured: depths pushed 19.1-31.8 mm deeper; optimistic points: 1 in two-camera seed 4 (0.5 mm beyond its
    tolerance) and 4 in the hidden-object scene (up to 6.8 mm beyond); the papers' rule clears 26 of the 34 cells,
    the corrected rule none.
    """
    flagged, shifts = [], []
    for j in two_camera_scenes + [hidden_object[0]]:
        # cells nearer than every control point's depth minus rho are farther than rho from all of them
        z_from = float(j.rig.cameras["p"].world_to_camera(j.points)[:, 2].min()) - RHO
        shift = MARGIN + smallest_cell_extent(j.rig, "s", z_from)
        shifts.append(shift)
        wrong = j.monitor().query(j.frames(shift), j.points, joints=j.joints)
        bad = optimistic(j, wrong.distance)
        if len(bad):
            flagged.append((j.label, len(bad), float(np.max((excess(j, wrong.distance) - j.bound)[bad]))))
    j, info = hidden_object
    grid = build_map(j.rig, "p")
    cam = j.rig.cameras["p"]
    free_s = np.where(np.isfinite(j.depths["s"]), j.depths["s"], 0.0).astype(np.float32)
    cells = set()
    on_hidden = j.truth.primitive == info["hidden_index"]
    for i in np.flatnonzero(on_hidden & (j.how == "confirmed") & (j.bound == 0)):
        u, v, z = cam.project(cam.world_to_camera(j.truth.nearest_world[i][None]))
        k = int((z[0] - grid.d_min) // grid.delta_d)
        cells.add((int(np.rint(u[0])), int(np.rint(v[0])), k))
    papers = ours = 0
    for u, v, k in sorted(cells):
        z0, z1 = grid.d_min + k * grid.delta_d, grid.d_min + (k + 1) * grid.delta_d
        papers += papers_rule_clears(grid, 0, free_s, u, v, z0, z1)
        ours += naive.camera_clears_reference(grid.corners[0], grid.offsets[0], free_s, 0.3, z0, z1, u, v, MARGIN,
                                              PAD)
    print(f"\nwrong rule: secondary depths pushed {min(shifts) * 1e3:.1f}-{max(shifts) * 1e3:.1f} mm deeper; "
          f"optimistic points (scene, count, worst excess over tolerance) {flagged}; hidden object: the papers' rule "
          f"clears {papers} of the {len(cells)} cells holding nearest points, the corrected rule {ours}")
    assert flagged, "a library clearing by the near depth went unnoticed"
    assert papers >= 1 and ours == 0
