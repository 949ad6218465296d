"""The collision test against thin limbs beside the robot (issue 27: "0 missed collisions, including a hand next to the
robot and swept motions"), judged by code the project did not write: pybullet's iiwa renders the depth images
(TinyRenderer), coal measures whether a future configuration's collision meshes touch a limb
(``thin_limbs.IiwaWorld.primitive_to_link``).

The scenes are design §11a's (``thin_limbs.make_cases``): a hand on top of a link and a forearm beside another, each
1 cm from the link's mesh; a finger in the crook of the bent elbow; a hand across the flange. Three noise-free
640 x 480 cameras each (p, s, t). The futures are the current configuration moved by up to 0.25 rad per joint
(seeded); those whose meshes touch a limb must be judged colliding:

- the image test, on depth images and on grey ones (pybullet's, no shadows), its defaults (theta = C - 1, class B
  collides, ``robot_pixels``), the reference the robot in three configurations without the limbs: every one, and
  every straight motion that passes through one while both its ends are clear (its swept volume); without
  ``robot_pixels`` (the paper's Table I) it misses most of them in the first scene. Except, stated: on grey images
  the first scene's hand and forearm lie within the robot's padded silhouette in every camera, and every
  configuration touching them is missed (each verdict flagged ``shell``);
- the depth grid's verdict (``DepthGridCollisionTest``, the three cameras fused): every one, or it names the
  self-filter's shell (``conceded``: ``robot_shell``) and every sample of the limbs inside the future robot's
  padded capsules lies within the shell that design §7 states (``thin_limbs.in_shell``): the concession hides
  nothing beyond its bound.
"""

from __future__ import annotations

import numpy as np
import pybullet as p
import pytest

import depthguard as dg
import pybullet_scenes as ps
import thin_limbs as tl
from depthguard.collision import ConfigurationTable, DepthGridCollisionTest, ImageCollisionTest
from depthguard.robots import RobotModel

TIME = 10.0
CASES = ("along a link", "between two links", "past the end-effector")
FUTURES = 60
SPREAD = 0.25  # rad per joint
MOTIONS = 6  # touching configurations tried as the middle of a motion
#: (scene, images) the image test misses, measured and stated (README, design §10): grey images of a hand and a
#: forearm lying along their links.
GREY_MISSES = {("along a link", "intensity")}
SEED = 27
LIGHT = (0.6, -0.4, 1.0)  # pybullet's light direction for the grey images


@pytest.fixture(scope="module")
def robot():
    return RobotModel.default()


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    world = tl.IiwaWorld(str(tmp_path_factory.mktemp("iiwa")))
    yield world
    world.close()


@pytest.fixture(scope="module")
def judged(world, robot):
    """label -> (case, futures (k, 7), touching (k,) bool by coal, references {"depth" | "intensity": {camera:
    [images]}} and their joints, the grey images now {camera: image})."""
    rng = np.random.default_rng(SEED)
    return {case.label: judge(world, robot, case, rng) for case in tl.make_cases(world, robot) if case.label in CASES}


#: The reference images' configurations, as offsets from each scene's (the robot elsewhere, no limb).
REFERENCE_OFFSETS = (0.6, -0.6, np.array([0.9, -0.3, 0.5, 0.4, -0.6, 0.3, 0.0]))


def judge(world, robot, case, rng, offsets=REFERENCE_OFFSETS, spread=SPREAD, count=FUTURES) -> tuple:
    """One judged scene (the tuple :func:`judged` holds): the references rendered without the limbs (the robot at
    ``case.q`` + each of ``offsets``; None: one image of the room without the robot, joints None), the case built,
    its grey images, seeded futures round its configuration and whether each touches a limb."""
    references = {kind: {n: [] for n in case.rig.cameras} for kind in ("depth", "intensity")}
    joints = []
    for q in ([None] if offsets is None else [case.q + offset for offset in offsets]):
        if q is None:  # the robot out of the room (60 m up) while the room is drawn
            base = p.getBasePositionAndOrientation(world.body, physicsClientId=world.client)
            p.resetBasePositionAndOrientation(world.body, [base[0][0], base[0][1], base[0][2] + 60.0], base[1],
                                              physicsClientId=world.client)
        else:
            q = np.clip(q, robot.lower, robot.upper)
            world.set_joints(q)
        scene = ps.PybulletScene(world.client, ps.room())
        try:
            for name, cam in case.rig.cameras.items():
                depth = ps.render_depth(world.client, cam)[0]
                references["depth"][name].append(np.where(np.isfinite(depth), depth, 0.0).astype(np.float32))
                references["intensity"][name].append(grey(world, cam))
        finally:
            scene.remove()
            if q is None:
                p.resetBasePositionAndOrientation(world.body, *base, physicsClientId=world.client)
        joints.append(q)
    joints = None if offsets is None else joints
    case = tl.build(world, case, 0.4)
    world.set_joints(case.q)
    scene = ps.PybulletScene(world.client, ps.room() + list(case.limbs.values()))
    try:
        now = {name: grey(world, cam) for name, cam in case.rig.cameras.items()}
    finally:
        scene.remove()
    futures = np.clip(case.q + rng.uniform(-spread, spread, (count, robot.n_joints)), robot.lower, robot.upper)
    return case, futures, touches(world, case, futures), references, joints, now


def grey(world, camera) -> np.ndarray:
    """pybullet's grey image of ``camera`` (uint8, BT.601 luma of TinyRenderer's colour image, no shadows)."""
    rgba = p.getCameraImage(camera.width, camera.height, viewMatrix=ps.view_matrix(camera),
                            projectionMatrix=ps.projection_matrix(camera), renderer=p.ER_TINY_RENDERER,
                            lightDirection=list(LIGHT), shadow=0, physicsClientId=world.client)[2]
    rgb = np.asarray(rgba, dtype=np.float64).reshape(camera.height, camera.width, 4)[..., :3]
    return np.rint(rgb @ np.array([0.299, 0.587, 0.114])).clip(0, 255).astype(np.uint8)


def touches(world, case, configurations) -> np.ndarray:
    """(k,) bool: whether each configuration's collision meshes touch a limb of ``case`` (coal)."""
    out = []
    for q in configurations:
        world.set_joints(q)
        out.append(any(world.primitive_to_link(limb, link) == 0.0 for limb in case.limbs.values()
                       for link in range(8)))
    world.set_joints(case.q)
    return np.array(out)


def image_test(case, references, joints, now, robot, images="depth", robot_pixels=True):
    test = ImageCollisionTest(case.rig, robot, tl.WORKSPACE, tiles=(64, 64), images=images, robot_pixels=robot_pixels)
    test.set_reference(references[images], joints=joints)
    if images == "depth":
        frames = case.frames(TIME)
        test.observe({n: frames[n].data for n in case.rig.cameras}, case.q)
    else:
        test.observe(now, case.q)
    return test


@pytest.mark.parametrize("images", ["depth", "intensity"])
@pytest.mark.parametrize("label", CASES)
def test_the_image_test_misses_no_configuration_or_motion_that_touches_a_limb(judged, world, robot, label, images):
    case, futures, touching, references, joints, now = judged[label]
    assert touching.sum() >= 5 and (~touching).sum() >= 5, "the futures must hold touching and clear ones"
    test = image_test(case, references, joints, now, robot, images)
    verdicts = [test.test(q) for q in futures]
    missed = [k for k in np.flatnonzero(touching) if not verdicts[k].collision]
    print(f"\n{label}: image test ({images}), {touching.sum()} touching, missed {len(missed)}; clear ones judged "
          f"colliding {sum(v.collision for v, t in zip(verdicts, touching) if not t)} of {(~touching).sum()}")
    if (label, images) in GREY_MISSES:
        # Grey images cannot tell these limbs from the robot: every pixel of them lies within the robot's padded
        # silhouette (+ a pixel) in all three cameras (and the hand is as bright as what lies behind it). Each miss
        # rests on the shell and says so.
        assert missed and all(verdicts[k].shell for k in missed), [verdicts[k] for k in missed if not
                                                                   verdicts[k].shell][:1]
        return
    assert not missed, f"missed: {futures[missed[0]].round(3).tolist()}, {verdicts[missed[0]]}"
    # Motions through a touching configuration whose ends are clear: the swept volume must collide.
    rng = np.random.default_rng(SEED + 1)
    motions = 0
    for k in np.flatnonzero(touching)[:MOTIONS]:
        for _ in range(6):  # a random direction whose ends, 0.8 rad away on either side, are clear of the limbs
            step = rng.normal(size=robot.n_joints)
            step *= 0.8 / np.linalg.norm(step)
            ends = np.clip(np.array([futures[k] - step, futures[k] + step]), robot.lower, robot.upper)
            if not touches(world, case, ends).any():
                motions += 1
                assert test.test_motion([ends[0], futures[k], ends[1]]).collision, ends.round(3).tolist()
                break
    assert motions >= 3, "too few motions with clear ends to judge"


@pytest.mark.parametrize("images", ["depth", "intensity"])
def test_without_robot_pixels_the_papers_table_i_misses_a_hand_along_a_link(judged, robot, images):
    """Table I alone calls every foreground tile under the robot's tile image unknown; the hand and the forearm 1 cm
    from their links lie under it in all three cameras, so no band confirms them and every touching configuration is
    judged free (class A): what robot_pixels is for."""
    case, futures, touching, references, joints, now = judged["along a link"]
    test = image_test(case, references, joints, now, robot, images, robot_pixels=False)
    missed = sum(not test.test(q).collision for q in futures[touching])
    assert missed > touching.sum() // 2, missed


@pytest.mark.parametrize("label", CASES)
def test_the_depth_grid_verdict_misses_a_limb_only_within_the_self_filters_shell_and_says_so(judged, robot, label):
    case, futures, touching, _, _, _ = judged[label]
    monitor = dg.DistanceMonitor(case.rig, robot=robot, rho=0.3)
    prepared = monitor.prepare_set(case.frames(TIME), joints=case.q, now=TIME)
    verdicts = DepthGridCollisionTest(robot).verdicts(prepared, futures)
    shell = tl.in_shell(case, case.rig.cameras.values())
    limbs = case.owner != "floor"
    missed = np.flatnonzero(touching & ~verdicts.collision)
    print(f"\n{label}: depth grid, {touching.sum()} touching, missed {len(missed)} (each within the self-filter's "
          f"shell); clear ones judged colliding {np.sum(verdicts.collision & ~touching)} of {(~touching).sum()}")
    for k in missed:
        assert dg.Flag.ROBOT_SHELL in verdicts.conceded[k], f"an unflagged miss: {futures[k].round(3).tolist()}"
        inside = limbs & (tl.zone_gap(robot, futures[k], case.samples, 0.0) <= 0.0)
        assert inside.any() and shell[inside].all(), \
            f"a limb outside the stated shell missed: {futures[k].round(3).tolist()}"


def test_a_finger_the_robot_hides_from_two_cameras_is_missed_by_theta_1_and_kept_by_the_default(world, robot):
    """Why theta stays C - 1 (design §10): theta 1 assumes the robot hides an obstacle from at most one camera. A
    finger 5 cm under the horizontal arm's link 2, along it, two cameras straight above the link (it hides the finger
    from both: no pixel of it drawn) and one low beside it: theta 1 needs C - theta = 2 cameras to confirm what the
    robot hides and has one, so configurations touching the finger are judged free; the default keeps them."""
    world.set_joints(tl.Q_HORIZONTAL)
    # 5 cm under the mesh: beyond the padded hull and the self-filter's tolerance (noise-free cameras), so the camera
    # that sees it can tell it from the link
    hand = world.place(tl.capsule(tl.FINGER, [0.2, 0.0, 0.36], [1, 0, 0]), [0, 0, -1], [2, 3, 4], gap=0.05)
    above = [[hand.centre[0] - 0.04, hand.centre[1], 1.3], [hand.centre[0] + 0.04, hand.centre[1], 1.3]]
    rig = dg.Rig({"a": tl.camera("a", above[0], np.asarray(above[0]) - [0.0, 0.0, 1.0], up=(1.0, 0.0, 0.0)),
                  "b": tl.camera("b", above[1], np.asarray(above[1]) - [0.0, 0.0, 1.0], up=(1.0, 0.0, 0.0)),
                  "s": tl.camera("s", [0.34, -1.3, 0.12], hand.centre)}, workspace=tl.WORKSPACE)
    case = tl.Case("hidden from two cameras", tl.Q_HORIZONTAL, {"finger": hand}, [], rig,
                   robot.control_point_positions(tl.Q_HORIZONTAL), len(robot.control_points))
    # the reference: the room without the robot (no median to leave it in where it stood in every image)
    case, futures, touching, references, joints, now = judge(world, robot, case, np.random.default_rng(SEED + 2),
                                                             None, spread=0.5, count=120)
    assert case.pixels["a", "finger"] == case.pixels["b", "finger"] == 0 and case.pixels["s", "finger"] > 100, \
        case.pixels
    assert touching.sum() >= 5
    for images in ("depth", "intensity"):
        missed = {}
        for theta in (1, None):
            test = ImageCollisionTest(rig, robot, tl.WORKSPACE, tiles=(64, 64), images=images, theta=theta)
            test.set_reference(references[images], joints=joints)
            frames = case.frames(TIME)
            test.observe({n: frames[n].data for n in rig.cameras} if images == "depth" else now, case.q)
            missed[theta] = sum(not test.test(q).collision for q in futures[touching])
        print(f"\nhidden from two cameras ({images}): {touching.sum()} touching; theta 1 missed {missed[1]}, the "
              f"default {missed[None]}")
        assert missed[None] == 0 and missed[1] > 0, missed


def test_a_finger_within_the_shell_the_robot_hides_from_the_other_cameras_is_missed_and_lies_within_the_shell(
        world, robot):
    """The stated limit (design §10, README): the image test, like the distances, takes what lies within the
    self-filter's shell (the padded hull + the tolerance + the noise margins) for the robot in a camera that sees it;
    when the robot hides it from every other camera, no rule sees it. The finger 1 cm under link 2, the two cameras
    above: the default misses the configurations touching it, and every sample of the finger lies within the shell
    of the camera that sees it (thin_limbs.in_shell)."""
    world.set_joints(tl.Q_HORIZONTAL)
    finger = world.place(tl.capsule(tl.FINGER, [0.2, 0.0, 0.36], [1, 0, 0]), [0, 0, -1], [2, 3, 4])
    above = [[finger.centre[0] - 0.04, finger.centre[1], 1.3], [finger.centre[0] + 0.04, finger.centre[1], 1.3]]
    side = tl.camera("s", [0.34, -1.3, 0.12], finger.centre)
    rig = dg.Rig({"a": tl.camera("a", above[0], np.asarray(above[0]) - [0.0, 0.0, 1.0], up=(1.0, 0.0, 0.0)),
                  "b": tl.camera("b", above[1], np.asarray(above[1]) - [0.0, 0.0, 1.0], up=(1.0, 0.0, 0.0)),
                  "s": side}, workspace=tl.WORKSPACE)
    case = tl.Case("within the shell", tl.Q_HORIZONTAL, {"finger": finger}, [], rig,
                   robot.control_point_positions(tl.Q_HORIZONTAL), len(robot.control_points))
    case, futures, touching, references, joints, _ = judge(world, robot, case, np.random.default_rng(SEED + 3),
                                                           None, spread=0.5, count=80)
    assert case.pixels["a", "finger"] == case.pixels["b", "finger"] == 0 and case.pixels["s", "finger"] > 100
    test = ImageCollisionTest(rig, robot, tl.WORKSPACE, tiles=(64, 64), images="depth")
    test.set_reference(references["depth"], joints=joints)
    frames = case.frames(TIME)
    test.observe({n: frames[n].data for n in rig.cameras}, case.q)
    verdicts = [test.test(q) for q in futures]
    missed = [v for v, t in zip(verdicts, touching) if t and not v.collision]
    print(f"\nwithin the shell: {touching.sum()} touching, the default missed {len(missed)}")
    assert touching.sum() >= 5 and missed
    assert tl.in_shell(case, [side])[case.owner == "finger"].all()
    # each miss says what it rests on: its robot image meets the current one in every camera (Verdict.shell), and
    # the table gives the same verdicts
    assert all(v.shell for v in missed)
    table = ConfigurationTable(test, futures)
    collision, _ = table.verdicts()
    assert [table.verdict(k) for k in range(len(futures))] == verdicts
    assert not np.any(table.shell & collision)
