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
  ``robot_pixels`` (the paper's Table I) it misses most of them in the first scene;
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
from depthguard.collision import DepthGridCollisionTest, ImageCollisionTest
from depthguard.robots import RobotModel

TIME = 10.0
CASES = ("along a link", "between two links", "past the end-effector")
FUTURES = 60
SPREAD = 0.25  # rad per joint
MOTIONS = 6  # touching configurations tried as the middle of a motion
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
    out = {}
    rng = np.random.default_rng(SEED)
    for case in tl.make_cases(world, robot):
        if case.label not in CASES:
            continue
        references = {kind: {n: [] for n in case.rig.cameras} for kind in ("depth", "intensity")}
        joints = []
        for q in (case.q + 0.6, case.q - 0.6, case.q + np.array([0.9, -0.3, 0.5, 0.4, -0.6, 0.3, 0.0])):
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
            joints.append(q)
        case = tl.build(world, case, 0.4)
        world.set_joints(case.q)
        scene = ps.PybulletScene(world.client, ps.room() + list(case.limbs.values()))
        try:
            now = {name: grey(world, cam) for name, cam in case.rig.cameras.items()}
        finally:
            scene.remove()
        futures = np.clip(case.q + rng.uniform(-SPREAD, SPREAD, (FUTURES, robot.n_joints)), robot.lower, robot.upper)
        out[case.label] = (case, futures, touches(world, case, futures), references, joints, now)
    return out


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
