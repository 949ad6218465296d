"""A simulated person with thin limbs (design §11a): forearms 45 mm across, hands 25 mm thick, a finger 15 mm
across. The simulated people were never thinner than 9 cm before, so nothing checked what the cameras make of a
finger. Judged by the exact ground truth (coal between the robot's control points and the person's capsules)."""

import copy
from importlib import resources
from pathlib import Path

import numpy as np
import pytest
import yaml

import depthguard as dg
from depthguard.errors import SceneError
from depthguard.results import CONCESSION_FLAGS, Flag
from depthguard_lab.simulation import workcell_from_dict
from depthguard_lab.simulation._episode import sense_at

PACKAGE = resources.files("depthguard_lab.simulation")


def _thin_reach(layout="scenario_b_four.yaml"):
    """scenario_b_reach.yaml in ``layout``'s cameras, its worker with thin limbs."""
    scene = yaml.safe_load((PACKAGE / "scenario_b_reach.yaml").read_text())
    cameras = yaml.safe_load((PACKAGE / layout).read_text())
    scene = copy.deepcopy(scene)
    for key in ("cameras", "principal", "workspace"):
        if key in cameras:
            scene[key] = cameras[key]
    scene["people"][0]["limbs"] = "thin"
    return workcell_from_dict(scene, base_dir=Path(str(PACKAGE)))


def test_thin_limbs_have_the_stated_thickness():
    workcell = _thin_reach()
    person = workcell.people[0]
    names = workcell.part_names(person.name)
    assert names[-2:] == ("finger_left", "finger_right") and len(names) == 18  # 16 parts and two fingers
    parts = dict(zip(names, person.parts_at(2.5)))
    assert parts["forearm_right"].radius * 2 == pytest.approx(0.045)
    assert parts["hand_right"].radius * 2 == pytest.approx(0.025)
    assert parts["finger_right"].radius * 2 == pytest.approx(0.015)
    # the finger ends where the hand ended: a reach still ends at its target
    default = workcell_from_dict(yaml.safe_load((PACKAGE / "scenario_b_reach.yaml").read_text()),
                                 base_dir=Path(str(PACKAGE))).people[0]
    np.testing.assert_allclose(parts["finger_right"].p1, default.joints_at(2.5)["hand_right"], atol=1e-12)
    with pytest.raises(SceneError):
        scene = yaml.safe_load((PACKAGE / "scenario_b_reach.yaml").read_text())
        scene["people"][0]["limbs"] = "skinny"
        workcell_from_dict(scene, base_dir=Path(str(PACKAGE)))


@pytest.mark.slow
def test_the_fused_defaults_see_a_thin_hand_reaching_for_the_arm():
    """Four cameras, the monitor's defaults (no concession but the flagged memory): while the thin hand and finger
    come towards the end-effector, no control point reads farther than its exact distance to the person plus the
    fused tolerance (2.5 footprints of the farthest camera + 1 mm), wherever the person is farther from the robot's
    meshes than what self-filtering may take for the robot (DistanceMonitor.query_hidden_band: the padded capsules'
    gap to the meshes, the tolerance and twice the noise margin); every answer says it rests on self-filtering
    (robot_shell, concession_distance 0 on the robot) and on no other concession but the memory."""
    workcell = _thin_reach()
    robot = workcell.robot
    monitor = dg.DistanceMonitor(workcell.rig, robot=robot, rho=0.6)
    shell, _ = monitor.query_hidden_band()
    focal = min(camera.fx for camera in workcell.rig.cameras.values())
    judged, finger_nearest = 0, 0
    for frame in sense_at(workcell, list(np.arange(1.2, 3.0, 0.1))):
        points = robot.control_point_positions(frame.joints)
        result = monitor.query(frame.depth, points, joints=frame.joints, now=frame.time)
        # on the robot every answer rests on self-filtering (robot_shell), and on nothing else but the memory
        assert not any(f & (CONCESSION_FLAGS & ~Flag.REMEMBERED & ~Flag.ROBOT_SHELL) for f in result.flags)
        assert all(Flag.ROBOT_SHELL in f for f, d in zip(result.flags, result.distance) if d > 0.0)
        assert np.all(result.concession_distance == 0.0)  # the control points lie inside the capsules
        if not frame.truth.clearance > shell:
            continue
        far = max(np.linalg.norm(points - camera.T_world_camera[:3, 3], axis=1).max()
                  for camera in workcell.rig.cameras.values())
        tolerance = 2.5 * far / focal + 1e-3
        truth = frame.truth.distance
        assert np.all(np.minimum(result.distance, 0.6) <= truth + tolerance), (frame.time, result.distance - truth)
        judged += 1
        finger_nearest += sum("finger" in part or "hand" in part for part in frame.truth.nearest_part)
    print(f"shell {shell:.3f} m, {judged} frames judged, thin parts nearest {finger_nearest} times")
    assert judged >= 5 and finger_nearest >= 3, (judged, finger_nearest)  # the thin parts were what came near
