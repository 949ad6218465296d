"""A hand in the gap between two links, hidden from the principal camera by the nearer one and seen by the second
camera, judged by code the project did not write (design §11a, "The space between two links is checked"; the scene
from ``thin_limbs``: pybullet's iiwa with its collision meshes drawn, TinyRenderer's depth images, coal's and
pybullet's getClosestPoints' exact distances).

The scene. The KUKA iiwa (``RobotModel.default()``; pybullet's ``kuka_iiwa`` drawn) arches forward: the shoulder
tilted 0.89 rad, the elbow bent 1.50 rad, the wrist (link 6's origin) at (0.6, 0, 0.33) with the flange pointing
straight down. Under the arch, between the hanging wrist (x = 0.6) and the base column (x = 0), floats a hand
(``thin_limbs.hand``: a flat box 25 x 80 x 100 mm, centre (0.32, 0, 0.2), 25 mm along y, 100 mm along x, 80 mm
along z), 13.6 cm or more from every link's padded capsule (``robot.capsules_world``; 17.6 cm or more from the
meshes, by coal): well outside the self-filter's shell (the padded capsule grown by the rendered geometry's reach
beyond it, the 2 cm tolerance and the noise margin, 0 here), so no concession may hide it. Two noise-free 640 x 480
cameras (``thin_limbs.camera``): p, the principal, at (2.0, 0, 0.7) looking at the hand, whose rays to the hand go
through the wrist first and, past the hand, meet the base again; s at (0.37, -1.4, 0.7), which sees the hand's broad
face (about 1,080 pixels). Rig workspace ``thin_limbs.WORKSPACE``; the monitor ``DistanceMonitor(rig, robot=robot)``
with its defaults (rho 0.4 m, hybrid, memory on), queried at the frames' time.

What it checks.

1. The scene is what it claims: p's depth image is the same, pixel for pixel, with and without the hand (it is
   hidden behind the wrist, every pixel within 10 of its projection showing the robot 10 cm or more in front of it),
   and pybullet's ray test along p's ray through the hand meets the wrist (link 6) before it and the base (link 0)
   past it; s's image changes where the hand is (1,078 pixels). The hand lies more than 12 cm from every padded
   capsule and from the judge's padded hulls (``IiwaWorld.padded_distance``).
2. The judge: for every query point (the robot's 9 control points; 11 points 3-10 cm off the hand's faces)
   ``distance <= truth + tolerance``, truth the exact distance to the hand and the room (the robot is no obstacle),
   tolerance ``thin_limbs``' 2.5 pixel footprints at the farthest camera + 1 mm: with no flag taken as an excuse.
   ``thin_limbs.violations`` (its rules 1-3 against the shell) finds nothing either.
3. No answer carries ``robot_blind_spot``.
4. The judge can fail: the same prepared frames fused the old way (``depthgrid.fused_distances`` without
   ``robot_exit``: the whole span along a principal ray from where it first enters the robot to where it last
   leaves it taken for the robot) miss the hand: points beside it read far above truth + tolerance. The same call
   with ``robot_exit`` (and the monitor's robot shell) finds it: the difference is the fix alone.

Measured (pytest -s prints it): with the fix the worst distance - truth is -11.2 mm over the points beside the hand
(they read 11-14 mm below the truth; the one in s's shadow of the hand reads 0, flagged inside_obstacle) and -1.4 mm
over all points: no answer lies above the truth. Fused the old way the points beside the hand read the floor's distance
(or rho) instead: up to 238.4 mm above the truth, all 11 beyond the tolerance, with no flag that says so. The
monitor of the commit before the fix (e6c4611) fails this judge the same way (238.4 mm, flagged robot_blind_spot,
which the judge takes as no excuse). The module runs in about 5 s with the numba kernels' cache warm, about 50 s cold.
"""

from __future__ import annotations

import numpy as np
import pybullet as p
import pytest
from scipy.ndimage import binary_dilation

import depthguard as dg
import pybullet_scenes as ps
import thin_limbs as tl
from depthguard import config
from depthguard.depthgrid import fused_distances
from depthguard.robots import RobotModel

RHO = config.DEFAULT_RHO
TIME = 10.0  # the frames' capture time and the queries' now, seconds

#: The arch: shoulder 0.8945 rad forward, elbow bent 1.4978 rad, wrist 0.7493 rad so that the flange points straight
#: down; the wrist (link 6's origin) at (0.6, 0, 0.33).
Q_ARCH = np.array([0.0, 0.8945, 0.0, -1.4978, 0.0, 0.7493, 0.0])
#: The hand's centre under the arch (world, metres): 25 mm thick along y, 100 mm long along x, 80 mm wide along z.
HAND_CENTRE = np.array([0.32, 0.0, 0.2])
#: The hand's clearance from every padded capsule the scene promises (metres): beyond any shell.
CLEARANCE = 0.12
#: Pixels round the hand's projection in p that show the robot in front of it (the hand is not hidden by a hair).
MARGIN_PIXELS = 10


@pytest.fixture(scope="module")
def robot():
    return RobotModel.default()


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    """pybullet's iiwa (thin_limbs.IiwaWorld)."""
    world = tl.IiwaWorld(str(tmp_path_factory.mktemp("iiwa")))
    yield world
    world.close()


@pytest.fixture(scope="module")
def case(world, robot):
    """The scene rendered and measured (thin_limbs.build), plus p's and s's depth images without the hand
    (``case.bare``)."""
    palm = tl.hand(HAND_CENTRE, [0, 1, 0], [1, 0, 0])
    centre = palm.centre
    faces = {"y": tl.HAND[2], "x": tl.HAND[1], "z": tl.HAND[0]}
    points = np.concatenate([
        robot.control_point_positions(Q_ARCH),
        # towards s (the face s sees) and away from it, above, below, towards the wrist and towards the base
        tl.offsets(centre, [0, -1, 0], faces["y"], steps=(0.03, 0.06, 0.1), lateral=[[0.03, 0.0, 0.02]]),
        tl.offsets(centre, [0, 1, 0], faces["y"], steps=(0.05,)),
        tl.offsets(centre, [0, 0, 1], faces["z"], steps=(0.04,)),
        tl.offsets(centre, [0, 0, -1], faces["z"], steps=(0.05,)),
        tl.offsets(centre, [1, 0, 0], faces["x"], steps=(0.04,)),
        tl.offsets(centre, [-1, 0, 0], faces["x"], steps=(0.04,)),
    ])
    rig = dg.Rig({"p": tl.camera("p", [2.0, 0.0, 0.7], centre),
                  "s": tl.camera("s", [centre[0] + 0.05, -1.4, centre[2] + 0.5], centre)},
                 principal="p", workspace=tl.WORKSPACE)
    case = tl.build(world, tl.Case("between two links", Q_ARCH, {"hand": palm}, [], rig, points,
                                   len(robot.control_points)), RHO)
    world.set_joints(Q_ARCH)
    bare = ps.PybulletScene(world.client, ps.room())
    try:
        case.bare = {name: ps.render_depth(world.client, cam)[0] for name, cam in rig.cameras.items()}
    finally:
        bare.remove()
    return case


def near_hand(case) -> np.ndarray:
    """Indices of the query points beside the hand (after the control points)."""
    return np.arange(case.n_control, len(case.points))


@pytest.fixture(scope="module")
def answers(case, robot):
    """(the monitor's result, the old fusion's result, the same call with robot_exit, the expectation)."""
    rig = case.rig
    monitor = dg.DistanceMonitor(rig, robot=robot)
    prepared = monitor.prepare_set(case.frames(TIME), joints=case.q, now=TIME)
    assert prepared.plan.kind == "fused"
    result = prepared.query(case.points)
    # The old way: the same prepared frames, fused without robot_exit (depthgrid.FusedFrames then takes the whole
    # span from where a principal ray first enters the robot to where it last leaves it for the robot).
    principal, second = prepared.usable["p"], prepared.usable["s"]

    def fused(**robot_exit):
        return fused_distances(monitor.maps["p"], rig, principal.occupancy, {"s": second.free}, case.points, RHO,
                               monitor.aggregate, monitor.unseen, robot_far=principal.robot_far,
                               margin=monitor.fusion_margin, pad=monitor.fusion_pixels,
                               robot_tolerance=monitor.self_filter_tolerance, robot_near=principal.robot_near,
                               **robot_exit)

    old = fused()
    checked = fused(robot_exit=principal.robot_exit, robot_shell=monitor._robot_zone_and_shell(principal)[1])
    return result, old, checked, tl.expect(case, robot, rig, RHO)


def excess(case, distance, idx) -> float:
    """The worst (distance - truth) over the points ``idx``, metres (distances capped at rho)."""
    return float(np.max(np.minimum(distance[idx], RHO) - case.truth.distance[idx]))


def test_the_scene_is_what_it_claims(case, world, robot):
    """The hand is hidden from p by the wrist (p's image is the same without it), p's ray meets the robot again
    past it (the base), s sees it, and it lies outside every link's shell with room to spare."""
    hand = case.limbs["hand"]
    shown = {name: int(np.count_nonzero(case.depths[name] != case.bare[name])) for name in case.rig.cameras}
    print(f"\npixels that change with the hand: {shown}; pixels showing it {dict(case.pixels)}")
    assert np.array_equal(case.depths["p"], case.bare["p"])
    assert case.pixels["p", "hand"] == 0
    # ... and not by a hair: every pixel within MARGIN_PIXELS of the hand's projection shows the robot in front of it.
    cam = case.rig.cameras["p"]
    X = cam.world_to_camera(tl.volume_samples(hand))
    footprint = np.zeros(cam.shape, dtype=bool)
    footprint[np.round(cam.fy * X[:, 1] / X[:, 2] + cam.cy).astype(int),
              np.round(cam.fx * X[:, 0] / X[:, 2] + cam.cx).astype(int)] = True
    around = binary_dilation(footprint, iterations=MARGIN_PIXELS)
    assert np.all(case.bare["p"][around] < X[:, 2].min() - 0.1)
    assert shown["s"] >= 500 and case.pixels["s", "hand"] >= 500
    # Past the hand, p's ray through its centre meets the robot again (pybullet's ray test, the hand not loaded).
    eye = case.rig.cameras["p"].T_world_camera[:3, 3]
    ray = (hand.centre - eye) / np.linalg.norm(hand.centre - eye)
    before = p.rayTest(eye.tolist(), hand.centre.tolist(), physicsClientId=world.client)[0]
    after = p.rayTest(hand.centre.tolist(), (hand.centre + 1.0 * ray).tolist(), physicsClientId=world.client)[0]
    print(f"p's ray through the hand: first the robot's link {before[1]} at {before[3]}, past the hand its link "
          f"{after[1]} at {after[3]}")
    assert before[0] == world.body and after[0] == world.body
    # Clear of every shell: the padded capsules (the library's) and the padded hulls (the judge's).
    samples = tl.volume_samples(hand)
    to_capsule = np.inf
    for c in robot.capsules_world(case.q):
        a, b = np.asarray(c.p0), np.asarray(c.p1)
        t = np.clip(((samples - a) @ (b - a)) / max(float((b - a) @ (b - a)), 1e-300), 0.0, 1.0)
        to_capsule = min(to_capsule, float(np.min(np.linalg.norm(samples - (a + t[:, None] * (b - a)), axis=1)))
                         - c.radius)
    world.set_joints(case.q)
    to_mesh = min(world.primitive_to_link(hand, k) for k in range(len(robot.link_names)))
    print(f"hand to the padded capsules {to_capsule:.4f} m, to the padded hulls "
          f"{world.padded_distance(samples).min():.4f} m, to the meshes {to_mesh:.4f} m")
    assert to_capsule > CLEARANCE and world.padded_distance(samples).min() > CLEARANCE
    assert case.truth.judges_gap <= 1e-3
    # every point beside the hand is 3-10 cm from it, and the hand is the nearest obstacle
    beside = near_hand(case)
    assert np.all((case.truth.distance[beside] >= 0.03 - 1e-6) & (case.truth.distance[beside] <= 0.1 + 1e-6))
    assert np.all(case.truth.primitive[beside] == len(ps.room()))


def test_the_hand_between_the_links_is_found(case, answers):
    """Every point reads at most the truth + tolerance, flags or not; no answer carries robot_blind_spot; and
    thin_limbs' rules hold."""
    result, _, _, e = answers
    truth = case.truth.distance
    bound = np.minimum(truth + e.tolerance, RHO)
    beside, everywhere = near_hand(case), np.arange(len(case.points))
    print(f"\nfused (the monitor): worst distance - truth {excess(case, result.distance, beside) * 1e3:.1f} mm beside "
          f"the hand, {excess(case, result.distance, everywhere) * 1e3:.1f} mm over all points; flags "
          f"{sorted({n for f in result.flags for n in f.names})}")
    over = np.nonzero(np.minimum(result.distance, RHO) > bound + tl.EPS)[0]
    assert len(over) == 0, [(int(i), np.round(case.points[i], 3).tolist(), float(result.distance[i]),
                             float(truth[i]), result.flags[i].names) for i in over]
    assert all(dg.Flag.ROBOT_BLIND_SPOT not in f for f in result.flags)
    assert not tl.violations(result, e, RHO)


def test_the_judge_catches_the_old_fusion(case, answers):
    """The same frames fused without robot_exit (the old way) miss the hand: points beside it read above truth +
    tolerance. With robot_exit (and the robot shell) the same call finds it."""
    _, old, checked, e = answers
    truth = case.truth.distance
    bound = np.minimum(truth + e.tolerance, RHO)
    beside = near_hand(case)
    missed = beside[np.minimum(old.distance[beside], RHO) > bound[beside] + tl.EPS]
    print(f"\nfused the old way (no robot_exit): worst distance - truth {excess(case, old.distance, beside) * 1e3:.1f} "
          f"mm beside the hand, {len(missed)} of {len(beside)} points beyond the tolerance; flags "
          f"{sorted({n for f in old.flags for n in f.names})}"
          f"\nthe same call with robot_exit: worst distance - truth {excess(case, checked.distance, beside) * 1e3:.1f} "
          f"mm beside the hand")
    assert len(missed) >= 1
    assert np.all(np.minimum(checked.distance, RHO) <= bound + tl.EPS)
