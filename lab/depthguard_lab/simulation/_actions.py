"""The people of a scene file: their ``actions`` lists compiled into :class:`Person` timelines (the keys are listed
in :mod:`depthguard_lab.simulation._scene`, what each action does in :mod:`depthguard_lab.simulation._people`)."""

from __future__ import annotations

import math

import numpy as np

from depthguard_lab import config as lab_config
from depthguard.cameras import Rig
from depthguard.errors import SceneError
from depthguard.robots import RobotModel
from depthguard_lab.simulation._fields import Section, as_number, as_vector, new_name, pose_of
from depthguard_lab.simulation._people import LIMBS, Person
from depthguard_lab.simulation._trajectory import RobotTrajectory


class ActionContext:
    """What actions that follow the robot or a camera need: control points over time and camera positions."""

    def __init__(self, robot: RobotModel, trajectory: RobotTrajectory, rig: Rig, intensity_rig: Rig | None):
        self.robot = robot
        self.trajectory = trajectory
        self.rig = rig
        self.cameras = dict(rig.cameras)
        if intensity_rig is not None:
            self.cameras.update(intensity_rig.cameras)
        self._cache_t = None
        self._cache = None

    def control_point(self, index: int, t: float) -> np.ndarray:
        """(3,) world position of control point ``index`` at time ``t`` (clamped to the trajectory's span)."""
        t = min(max(float(t), self.trajectory.times[0]), self.trajectory.times[-1])
        if t != self._cache_t:
            self._cache = self.robot.control_point_positions(self.trajectory.joints_at(t), check=False)
            self._cache_t = t
        return self._cache[index]

    def control_point_index(self, name, field: str) -> int:
        names = self.robot.control_point_names
        if name not in names:
            raise SceneError(f"{name!r} is not a control point of the robot ({', '.join(names)})", field=field)
        return names.index(name)

    def camera_eye(self, name, field: str) -> np.ndarray:
        if name is None:
            name = self.rig.principal
            if name is None:
                raise SceneError("no camera given and the rig names no principal camera", field=field)
        if name not in self.cameras:
            raise SceneError(f"{name!r} is not a camera of the scene ({', '.join(self.cameras)})", field=field)
        return self.cameras[name].T_world_camera[:3, 3].copy()


def _facing(section: Section, key: str, position: np.ndarray, robot_xy: np.ndarray):
    """Heading (radians) from a ``facing`` value: an angle, a point [x, y] to face, or ``robot``; None if absent."""
    if not section.has(key):
        return None
    value = section.get(key)
    if value == "robot":
        target = robot_xy
    elif isinstance(value, (int, float)) and not isinstance(value, bool):
        return as_number(value, section.field(key))
    else:
        target = as_vector(value, 2, section.field(key))
    d = target - position
    if np.linalg.norm(d) < 1e-9:
        raise SceneError("the person stands on the point it should face", field=section.field(key))
    return math.atan2(d[1], d[0])


def _limbs(section: Section) -> str:
    limbs = section.get("limbs", default="default")
    if limbs not in LIMBS:
        raise SceneError(f"limbs must be one of {', '.join(LIMBS)}, got {limbs!r}", field=section.field("limbs"))
    return limbs


def build_person(section: Section, names: set, floor: float, context: ActionContext, carried: dict,
            duration: float) -> Person:
    name = new_name(section, names)
    robot_xy = context.robot.T_world_base[:2, 3].copy()
    start = section.section("start")
    position = start.vector("position", 2)
    heading = _facing(start, "facing", position, robot_xy)
    start.done()
    person = Person(name, section.number("height", default=1.75, minimum=1.0, maximum=2.3), floor, position,
                    0.0 if heading is None else heading,
                    section.number("walk_speed", default=lab_config.SIM_WALK_SPEED, positive=True),
                    section.number("clothes_albedo", default=lab_config.SIM_CLOTHES_ALBEDO, minimum=0.01, maximum=1.0),
                    section.number("skin_albedo", default=lab_config.SIM_SKIN_ALBEDO, minimum=0.01, maximum=1.0),
                    _limbs(section))
    for index, item in enumerate(section.get("actions", default=[]) or []):
        field = f"{section.field('actions')}[{index}]"
        if not isinstance(item, dict) or len(item) != 1:
            raise SceneError("each action must be a mapping with one key (walk, stand, reach, carry, shadow, "
                             f"hidden_hand), got {item!r}", field=field)
        (kind, params), = item.items()
        if kind not in _ACTIONS:
            raise SceneError(f"unknown action {kind!r} (walk, stand, reach, carry, shadow, hidden_hand)", field=field)
        action = Section(params if params is not None else {}, f"{field}.{kind}")
        start_time = person.time
        hold_start = _ACTIONS[kind](person, action, context, carried, robot_xy)
        action.done()
        person.add_span(index, kind, start_time, hold_start, dict(params or {}))
    section.done()
    if person.time > duration + 1e-9:
        raise SceneError(f"the actions of {name!r} last until t = {person.time:.2f} s, beyond the scene's duration "
                         f"{duration} s", field=section.field("actions"))
    person.finish()
    return person


def _go(person: Person, action: Section, robot_xy, default_facing=None) -> tuple[float, float | None]:
    """Walk to the action's ``position`` (through ``via``) if given; return (hold start, heading to face)."""
    via = action.points("via", 2, default=[])
    if action.has("position"):
        person.go_to(action.vector("position", 2), via)
    elif len(via):
        raise SceneError("via needs a position to walk to", field=action.field("via"))
    heading = _facing(action, "facing", person.position, robot_xy)
    return person.time, heading if heading is not None else default_facing


def _walk(person, action, context, carried, robot_xy):
    start = person.time
    points = np.concatenate([action.points("via", 2, default=[]), action.vector("to", 2)[None]])
    person.walk(points, action.number("speed", default=person.walk_speed, positive=True),
                action.number("leg_swing", default=lab_config.SIM_LEG_SWING, minimum=0.0, maximum=1.0),
                action.boolean("backwards", default=False))
    return start


def _stand(person, action, context, carried, robot_xy):
    hold_start, heading = _go(person, action, robot_xy)
    person.hold(action.number("duration", positive=True), heading)
    return hold_start


def _target_function(action: Section, key: str, context: ActionContext, standoff: float):
    """target(t, base, shoulder) -> (goal, None) for a reach: a fixed point or a control point followed in time,
    ``standoff`` metres short of it on the line from the shoulder. Also returns the target at a given time."""
    value = action.get(key)
    if isinstance(value, str):
        index = context.control_point_index(value, action.field(key))
        point_at = lambda t: context.control_point(index, t)  # noqa: E731
    else:
        point = as_vector(value, 3, action.field(key))
        point_at = lambda t: point  # noqa: E731

    def target(t, base, shoulder):
        p = point_at(t)
        d = p - shoulder
        n = np.linalg.norm(d)
        return (p - standoff * d / n if n > standoff else shoulder + 1e-3 * d / max(n, 1e-12)), None

    return target, point_at


def _reach(person, action, context, carried, robot_xy):
    standoff = action.number("standoff", default=0.0, minimum=0.0)
    target, point_at = _target_function(action, "target", context, standoff)
    side = action.string("hand", default="right", choices=("left", "right"))
    duration = action.number("duration", positive=True)
    ramp = action.number("ramp", default=lab_config.SIM_REACH_RAMP, minimum=0.0, maximum=duration / 2)
    hold_start, heading = _go(person, action, robot_xy)
    if heading is None:
        d = point_at(person.time)[:2] - person.position
        heading = math.atan2(d[1], d[0])
    person.hold(0.0, heading)
    person.reach(side, target, duration, ramp)
    return hold_start


def _carry(person, action, context, carried, robot_xy):
    name = action.string("object")
    if name not in carried:
        raise SceneError(f"{name!r} is not a carried object ({', '.join(carried) or 'none declared'})",
                         field=action.field("object"))
    points = np.concatenate([action.points("via", 2, default=[]), action.vector("to", 2)[None]])
    place = pose_of(action.section("place_at")) if action.has("place_at") else None
    start = person.time
    person.carry(name, carried[name].size, points, action.number("speed", default=1.0, positive=True),
                 action.number("leg_swing", default=0.3, minimum=0.0, maximum=1.0), place,
                 hold=action.number("hold", default=0.0, minimum=0.0),
                 backwards=action.boolean("backwards", default=False))
    return start


def _shadow(person, action, context, carried, robot_xy):
    eye = context.camera_eye(action.get("camera", default=None), action.field("camera"))
    index = context.control_point_index(action.string("target", default="elbow"), action.field("target"))
    distance = action.number("distance", default=1.5, positive=True)
    duration = action.number("duration", positive=True)
    target = context.control_point(index, person.time)
    towards_camera = eye[:2] - target[:2]
    span = float(np.linalg.norm(towards_camera))
    if distance >= span - 0.3:
        raise SceneError(f"the camera is only {span:.2f} m from the target (horizontally): a person {distance} m from "
                         "the target would not stand between them", field=action.field("distance"))
    position = target[:2] + distance * towards_camera / span
    via = action.points("via", 2, default=[])
    person.go_to(position, via)
    hold_start = person.time
    person.hold(duration, math.atan2(-towards_camera[1], -towards_camera[0]))
    return hold_start


def _hidden_hand(person, action, context, carried, robot_xy):
    eye = context.camera_eye(action.get("camera", default=None), action.field("camera"))
    index = context.control_point_index(action.string("target", default="elbow"), action.field("target"))
    behind = action.number("behind", default=0.2, positive=True)
    stand_off = action.number("stand_off", default=0.6, positive=True)
    side = action.string("hand", default="right", choices=("left", "right"))
    duration = action.number("duration", positive=True)
    ramp = action.number("ramp", default=lab_config.SIM_REACH_RAMP, minimum=0.0, maximum=duration / 2)
    p0 = context.control_point(index, person.time)
    ray = p0 - eye
    horizontal = ray[:2] / np.linalg.norm(ray[:2])
    via = action.points("via", 2, default=[])
    position = action.vector("position", 2) if action.has("position") else p0[:2] + stand_off * horizontal
    person.go_to(position, via)
    hold_start = person.time
    facing = p0[:2] - person.position
    person.hold(0.0, math.atan2(facing[1], facing[0]))

    def target(t, base, shoulder):
        p = context.control_point(index, t)
        r = p - eye
        r /= np.linalg.norm(r)
        return p + behind * r, -r

    person.reach(side, target, duration, ramp)
    return hold_start


_ACTIONS = dict(walk=_walk, stand=_stand, reach=_reach, carry=_carry, shadow=_shadow, hidden_hand=_hidden_hand)
