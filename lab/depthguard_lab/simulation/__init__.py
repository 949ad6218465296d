"""Simulated robot workcells: depth and intensity cameras watching a robot and scripted people, with exact ground
truth (design §12, scenario B).

Typical use::

    from depthguard_lab.simulation import default_workcell, simulate, write_episode
    wc = default_workcell()                 # reference scenario B, from scenario_b.yaml
    for frame in simulate(wc, seed=0):      # one SimFrame per time step, at wc.rate Hz
        frame.depth["principal"]            # DepthImage, uint16 millimetres, timestamp = frame.time
        frame.truth.distance                # (9,) metres: each control point to the nearest obstacle
    write_episode(wc, "out/episode")        # PNGs, CSVs, rig.yaml, scene.yaml

The scene file format is described in :mod:`depthguard_lab.simulation._scene`; the people's actions in
:mod:`depthguard_lab.simulation._people`; the sensor model in :mod:`depthguard_lab.simulation._sensors`; ground truth in
:mod:`depthguard_lab.simulation._truth`.
"""

from depthguard_lab.simulation._episode import SceneRenderer, SimFrame, cosine_from_intensity, simulate, write_episode
from depthguard_lab.simulation._people import JOINTS, PART_NAMES, PARTS, ActionSpan, BasePose, BodyPart, Person, arm_ik
from depthguard_lab.simulation._scene import (
    CarriedObject,
    StaticObject,
    Workcell,
    default_workcell,
    load_workcell,
    save_workcell,
    workcell_from_dict,
)
from depthguard_lab.simulation._standing import standing_person
from depthguard_lab.simulation._sensors import (
    SensorModel,
    discontinuity_mask,
    grazing_mask,
    simulate_depth,
    simulate_intensity,
)
from depthguard_lab.simulation._trajectory import Hexagon, HexagonTrajectory, JointTrajectory, RobotTrajectory
from depthguard_lab.simulation._truth import GroundTruth, TruthComputer

__all__ = [
    "JOINTS",
    "PARTS",
    "PART_NAMES",
    "ActionSpan",
    "BasePose",
    "BodyPart",
    "CarriedObject",
    "GroundTruth",
    "Hexagon",
    "HexagonTrajectory",
    "JointTrajectory",
    "Person",
    "RobotTrajectory",
    "SceneRenderer",
    "SensorModel",
    "SimFrame",
    "StaticObject",
    "TruthComputer",
    "Workcell",
    "arm_ik",
    "cosine_from_intensity",
    "default_workcell",
    "discontinuity_mask",
    "grazing_mask",
    "load_workcell",
    "save_workcell",
    "simulate",
    "simulate_depth",
    "simulate_intensity",
    "standing_person",
    "workcell_from_dict",
    "write_episode",
]
