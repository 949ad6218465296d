"""Simulated people: articulated bodies of rigid capsules driven by a scripted timeline of actions.

Body
----
A person is 17 rigid capsules (:data:`PARTS`) hung on a skeleton of named joints (:data:`JOINTS`). Each part joins
two joints, so neighbouring parts share a joint point exactly (the shoulders' capsule and the pelvis's have the neck
and the pelvis centre at their middles, where the torso ends). Lengths and radii are those of a 1.75 m adult
(:data:`BONES`), scaled by ``height / 1.75``; a part keeps its length in every pose (rigid).

The person's frame: origin on the floor between the feet, x forward, y to the person's left, z up; ``heading`` is
the angle of x about the world's z axis from the world's x axis.

Actions (a person's ``actions`` list in the scene file; each starts when the previous one ends)
-------------------------------------------------------------------------------------------------
- ``walk``: to a point (optionally ``via`` points) at ``speed``; legs and arms swing (``leg_swing`` radians of hip
  flexion), the heading follows the path.
- ``stand``: stay for ``duration`` seconds, optionally at ``position`` (walked to first) and ``facing``.
- ``reach``: one hand (``left`` / ``right``) moves to a ``target`` (a world point, or a robot control point's name,
  such as ``end_effector``, followed as the robot moves), stopping ``standoff`` metres short of it on the line from
  the shoulder. The arm's pose is a two-link IK (upper arm, forearm + hand) with the elbow turned down and out.
  ``ramp`` seconds to reach out, the same to come back, within ``duration``.
- ``carry``: both hands hold a box (a ``carried_objects`` entry) in front of the body while walking to ``to``;
  afterwards the box rests at ``place_at`` (or leaves the scene if none is given). The box jumps from its resting
  place into the hands at the start of the carry (no pick-up motion).
- ``shadow`` (2016 paper, Fig. 8): stand on the line from a camera (default: the rig's principal camera) to a
  robot control point ``target``, ``distance`` metres (horizontally) from it, facing the robot: far from the robot,
  but hiding it from that camera.
- ``hidden_hand`` (2016 paper, Fig. 9): stand behind the robot as a camera sees it and hold a hand right behind a
  robot control point ``target`` (``behind`` metres beyond it along that camera's ray, pointing back along the ray),
  so that the link hides the hand from that camera. Followed as the robot moves.

An action with a ``position`` the person is not at walks there first (straight, at the person's ``walk_speed``)
and then lasts its ``duration``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from depthguard_lab import config as lab_config
from depthguard.scenes import Box, Capsule

#: The skeleton's joints.
JOINTS = ("pelvis", "neck", "head_top", "hip_left", "hip_right", "knee_left", "knee_right", "ankle_left",
          "ankle_right", "toe_left", "toe_right", "shoulder_left", "shoulder_right", "elbow_left", "elbow_right",
          "wrist_left", "wrist_right", "hand_left", "hand_right")

#: Bone lengths and radii of a 1.75 m adult, metres (scaled with height).
BONES = dict(
    hip_height=0.92,        # pelvis centre and hip joints above the floor
    hip_half_width=0.09,
    pelvis_radius=0.12,
    torso=0.48,             # pelvis centre to neck
    torso_radius=0.14,
    shoulder_half_width=0.18,
    shoulders_radius=0.06,
    head=0.22,              # neck to the head capsule's upper end
    head_radius=0.10,
    upper_arm=0.29,
    upper_arm_radius=0.05,
    forearm=0.26,
    forearm_radius=0.04,
    hand=0.10,              # wrist to the hand capsule's end
    hand_radius=0.045,
    thigh=0.43,
    thigh_radius=0.07,
    shin=0.41,
    shin_radius=0.05,
    foot=0.14,
    foot_radius=0.04,
)


@dataclass(frozen=True)
class BodyPart:
    """A rigid capsule from joint ``a`` to joint ``b`` of the skeleton, of radius ``radius`` key in :data:`BONES`;
    ``skin`` parts (head, hands) take the person's skin albedo, the others the clothes'."""

    name: str
    a: str
    b: str
    radius: str
    skin: bool = False


PARTS = (
    BodyPart("pelvis", "hip_left", "hip_right", "pelvis_radius"),
    BodyPart("torso", "pelvis", "neck", "torso_radius"),
    BodyPart("shoulders", "shoulder_left", "shoulder_right", "shoulders_radius"),
    BodyPart("head", "neck", "head_top", "head_radius", skin=True),
    BodyPart("upper_arm_left", "shoulder_left", "elbow_left", "upper_arm_radius"),
    BodyPart("upper_arm_right", "shoulder_right", "elbow_right", "upper_arm_radius"),
    BodyPart("forearm_left", "elbow_left", "wrist_left", "forearm_radius"),
    BodyPart("forearm_right", "elbow_right", "wrist_right", "forearm_radius"),
    BodyPart("hand_left", "wrist_left", "hand_left", "hand_radius", skin=True),
    BodyPart("hand_right", "wrist_right", "hand_right", "hand_radius", skin=True),
    BodyPart("thigh_left", "hip_left", "knee_left", "thigh_radius"),
    BodyPart("thigh_right", "hip_right", "knee_right", "thigh_radius"),
    BodyPart("shin_left", "knee_left", "ankle_left", "shin_radius"),
    BodyPart("shin_right", "knee_right", "ankle_right", "shin_radius"),
    BodyPart("foot_left", "ankle_left", "toe_left", "foot_radius"),
    BodyPart("foot_right", "ankle_right", "toe_right", "foot_radius"),
)

#: Names of the parts, in the order of :meth:`Person.parts_at` (of a person with the default limbs).
PART_NAMES = tuple(part.name for part in PARTS)

#: A person with ``limbs: thin`` (design §11a's thin-limb judges), whatever their height: forearms 45 mm across,
#: hands 25 mm thick (from the wrist to the knuckles, half the hand's length) and a finger 15 mm across (from the
#: knuckles to the hand's end, where a reach ends). Radii in metres.
THIN_LIMBS = dict(forearm_radius=0.0225, hand_radius=0.0125, finger_radius=0.0075)
THIN_PARTS = tuple(BodyPart(part.name, part.a, f"knuckles_{part.a.split('_')[1]}", part.radius, part.skin)
                   if part.name.startswith("hand_") else part for part in PARTS) + (
    BodyPart("finger_left", "knuckles_left", "hand_left", "finger_radius", skin=True),
    BodyPart("finger_right", "knuckles_right", "hand_right", "finger_radius", skin=True))
LIMBS = ("default", "thin")

_FINE_RATE = 240.0  # Hz: the grid on which heading and gait amplitude are sampled and smoothed


def smoothstep(x):
    """0 below 0, 1 above 1, 3x^2 - 2x^3 between: a blend with zero slope at both ends."""
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


@dataclass(frozen=True)
class ActionSpan:
    """When one scripted action happens: ``start`` to ``end`` seconds; ``hold_start`` is when the person arrived at
    the action's position (after the walk there, if any) and the action proper began. ``index`` is its position in
    the person's ``actions`` list, ``kind`` its key (walk, stand, reach, carry, shadow, hidden_hand)."""

    person: str
    index: int
    kind: str
    start: float
    hold_start: float
    end: float
    params: dict = field(default_factory=dict, compare=False, repr=False)


@dataclass
class _ArmTask:
    """One arm held towards a target from t0 to t1, blending in over ``ramp_in`` and out over ``ramp_out``.
    ``target(t, base) -> (reach point (3,) world, hand direction (3,) world unit or None)``."""

    side: str
    t0: float
    t1: float
    ramp_in: float
    ramp_out: float
    target: object

    def weight(self, t: float) -> float:
        if t < self.t0 or t > self.t1:
            return 0.0
        w_in = 1.0 if self.ramp_in <= 0 else float(smoothstep((t - self.t0) / self.ramp_in))
        w_out = 1.0 if self.ramp_out <= 0 else float(smoothstep((self.t1 - t) / self.ramp_out))
        return min(w_in, w_out)


@dataclass
class _Carry:
    """A carried box between t0 and t1; afterwards it rests at ``place`` ((center (3,), yaw) or None: gone)."""

    name: str
    t0: float
    t1: float
    place: tuple | None


@dataclass(frozen=True)
class BasePose:
    """Where a person is at one time: ``position`` (2,) metres on the floor, world frame; ``heading`` radians
    about z from the world x axis; ``gait_phase`` radians; ``gait_amplitude`` radians of hip flexion."""

    position: np.ndarray
    heading: float
    gait_phase: float
    gait_amplitude: float


class Person:
    """A scripted person. Built by the scene loader (see the module docstring); query with :meth:`joints_at`,
    :meth:`parts_at` and :meth:`base_at`.

    Attributes:
        name: unique in the scene.
        height: metres.
        floor: world z of the floor the person stands on, metres.
        clothes_albedo, skin_albedo: reflectance in [0, 1] for intensity images.
        spans: the :class:`ActionSpan` of each action, in order.
    """

    def __init__(self, name: str, height: float, floor: float, start_position, start_heading: float,
                 walk_speed: float, clothes_albedo: float, skin_albedo: float, limbs: str = "default"):
        self.name = name
        self.limbs = limbs
        self.parts = THIN_PARTS if limbs == "thin" else PARTS  # BodyParts in parts_at's order
        self.height = float(height)
        self.floor = float(floor)
        self.walk_speed = float(walk_speed)
        self.clothes_albedo = float(clothes_albedo)
        self.skin_albedo = float(skin_albedo)
        s = self.height / 1.75
        self.bones = {key: value * s for key, value in BONES.items()}
        if limbs == "thin":
            self.bones.update(THIN_LIMBS)
        self.spans: list[ActionSpan] = []
        self.arm_tasks: list[_ArmTask] = []
        self.carries: list[_Carry] = []
        # Base keyframes: times (k,), positions (k, 2); heading and gait targets as step functions.
        self._key_t = [0.0]
        self._key_xy = [np.asarray(start_position, dtype=np.float64)]
        self._heading_steps = [(0.0, float(start_heading))]  # (from time, heading)
        self._gait_steps = [(0.0, 0.0)]  # (from time, amplitude)
        self._stride = lab_config.SIM_STRIDE_PER_HEIGHT * self.height

    # ---------------------------------------------------------------------------------------- timeline building

    @property
    def time(self) -> float:
        """End of the timeline so far, seconds."""
        return self._key_t[-1]

    @property
    def position(self) -> np.ndarray:
        """Where the timeline so far leaves the person: (2,) metres, world frame."""
        return self._key_xy[-1]

    @property
    def heading(self) -> float:
        return self._heading_steps[-1][1]

    def walk(self, points, speed: float, leg_swing: float, backwards: bool = False) -> None:
        """Walk through ``points`` ((k, 2) metres) at ``speed`` m/s from the current position, facing the way it goes
        (``backwards``: facing the other way, as a person stepping back from something keeps facing it)."""
        for p in np.asarray(points, dtype=np.float64).reshape(-1, 2):
            step = p - self.position
            length = float(np.linalg.norm(step))
            if length < 1e-9:
                continue
            t0 = self.time
            heading = math.atan2(step[1], step[0])
            self._heading_steps.append((t0, heading + math.pi if backwards else heading))
            self._gait_steps.append((t0, float(leg_swing)))
            self._key_t.append(t0 + length / speed)
            self._key_xy.append(p.copy())
        self._gait_steps.append((self.time, 0.0))

    def hold(self, duration: float, heading: float | None = None) -> None:
        """Stand still for ``duration`` seconds, turned to ``heading`` (radians) if given."""
        if heading is not None:
            self._heading_steps.append((self.time, float(heading)))
        if duration > 0:
            self._key_t.append(self.time + float(duration))
            self._key_xy.append(self.position.copy())

    def add_span(self, index: int, kind: str, start: float, hold_start: float, params: dict) -> None:
        self.spans.append(ActionSpan(self.name, index, kind, start, hold_start, self.time, params))

    def go_to(self, position, via=()) -> None:
        """Walk (at :attr:`walk_speed`) to ``position`` (2,) through ``via`` points, if not there already."""
        points = [np.asarray(p, dtype=np.float64) for p in via] + [np.asarray(position, dtype=np.float64)]
        if np.linalg.norm(points[-1] - self.position) > 1e-9 or len(points) > 1:
            self.walk(points, self.walk_speed, lab_config.SIM_LEG_SWING)

    def reach(self, side: str, target, duration: float, ramp: float) -> None:
        """Hold the ``side`` hand towards ``target(t, base, shoulder) -> (goal (3,), direction (3,) or None)`` for
        ``duration`` seconds from now, blending in and out over ``ramp`` seconds; the person stands still."""
        t0 = self.time
        self.arm_tasks.append(_ArmTask(side, t0, t0 + duration, ramp, ramp, target))
        self.hold(duration)

    def carry(self, name: str, size, points, speed: float, leg_swing: float, place, hold: float = 0.0,
              backwards: bool = False) -> None:
        """Carry the box ``name`` of full ``size`` (3,) in both hands while walking through ``points`` at ``speed``
        (``backwards``: stepping back, facing the other way), then stand ``hold`` seconds; afterwards the box rests
        at ``place`` ((center, yaw) or None: gone)."""
        t0 = self.time
        self.walk(points, speed, leg_swing, backwards)
        if hold > 0:
            self.hold(hold)
        t1 = self.time
        size = np.asarray(size, dtype=np.float64)
        half_width = size[1] / 2.0 + self.bones["hand_radius"]
        for side, sign in (("left", 1.0), ("right", -1.0)):
            def target(t, base, shoulder, sign=sign):
                center, yaw = self.carry_box_pose(base, size)
                forward = np.array([math.cos(yaw), math.sin(yaw), 0.0])
                left = np.array([-math.sin(yaw), math.cos(yaw), 0.0])
                return center + sign * half_width * left + 0.25 * size[0] * forward, forward
            self.arm_tasks.append(_ArmTask(side, t0, t1, min(0.3, (t1 - t0) / 2), 0.0, target))
        self.carries.append(_Carry(name, t0, t1, place))

    def carried_box_at(self, name: str, t: float, size, rest) -> tuple[np.ndarray, float] | None:
        """(center (3,), yaw) of the box ``name`` at time ``t`` as this person's carries leave it, or ``rest``
        before its first carry (None: not in the scene)."""
        state = rest
        for carry in self.carries:
            if carry.name != name:
                continue
            if t < carry.t0:
                return state
            if t <= carry.t1:
                return self.carry_box_pose(self.base_at(t), np.asarray(size, dtype=np.float64))
            state = carry.place
        return state

    def carries_object(self, name: str) -> bool:
        return any(carry.name == name for carry in self.carries)

    def finish(self) -> None:
        """Freeze the timeline: sample and smooth the heading and gait amplitude."""
        end = self.time + 1.0
        n = int(math.ceil(end * _FINE_RATE)) + 1
        self._fine_t = np.arange(n) / _FINE_RATE
        heading = _steps(self._heading_steps, self._fine_t, unwrap=True)
        amplitude = _steps(self._gait_steps, self._fine_t, unwrap=False)
        width = max(1, int(round(lab_config.SIM_PERSON_BLEND * _FINE_RATE)))
        self._fine_heading = _box_filter(heading, width)
        self._fine_amplitude = _box_filter(amplitude, width)
        self._key_t_array = np.asarray(self._key_t)
        self._key_xy_array = np.asarray(self._key_xy)
        travelled = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(self._key_xy_array, axis=0), axis=1))])
        self._key_s = travelled

    # -------------------------------------------------------------------------------------------------- queries

    def base_at(self, t: float) -> BasePose:
        """The person's :class:`BasePose` at time ``t`` (seconds; before 0 and after the last action the person
        stands still)."""
        t = float(t)
        x = np.interp(t, self._key_t_array, self._key_xy_array[:, 0])
        y = np.interp(t, self._key_t_array, self._key_xy_array[:, 1])
        heading = float(np.interp(t, self._fine_t, self._fine_heading))
        amplitude = float(np.interp(t, self._fine_t, self._fine_amplitude))
        travelled = float(np.interp(t, self._key_t_array, self._key_s))
        return BasePose(np.array([x, y]), heading, 2.0 * math.pi * travelled / self._stride, amplitude)

    def joints_at(self, t: float) -> dict[str, np.ndarray]:
        """Skeleton joint positions at time ``t`` (seconds): joint name -> (3,) float64, metres, world frame."""
        base = self.base_at(t)
        b = self.bones
        c, s = math.cos(base.heading), math.sin(base.heading)
        forward = np.array([c, s, 0.0])
        left = np.array([-s, c, 0.0])
        up = np.array([0.0, 0.0, 1.0])
        origin = np.array([base.position[0], base.position[1], self.floor])
        amplitude, phase = base.gait_amplitude, base.gait_phase
        legs = b["thigh"] + b["shin"]
        swing = {"left": amplitude * math.sin(phase), "right": -amplitude * math.sin(phase)}
        # Lower the body so that the straighter (stance) leg keeps its foot on the floor.
        drop = legs * (1.0 - math.cos(abs(swing["left"])))
        origin = origin - drop * up
        joints = {}
        pelvis = origin + b["hip_height"] * up
        joints["pelvis"] = pelvis
        joints["neck"] = pelvis + b["torso"] * up
        joints["head_top"] = joints["neck"] + b["head"] * up
        for side, sign, leg_phase in (("left", 1.0, phase), ("right", -1.0, phase + math.pi)):
            hip = pelvis + sign * b["hip_half_width"] * left
            theta = swing[side]
            knee_bend = 1.6 * amplitude * max(0.0, math.cos(leg_phase))
            thigh_dir = math.sin(theta) * forward - math.cos(theta) * up
            shin_dir = math.sin(theta - knee_bend) * forward - math.cos(theta - knee_bend) * up
            foot_dir = (forward - 0.2 * up) / math.sqrt(1.04)  # the foot stays level, toes a little down
            joints[f"hip_{side}"] = hip
            joints[f"knee_{side}"] = hip + b["thigh"] * thigh_dir
            joints[f"ankle_{side}"] = joints[f"knee_{side}"] + b["shin"] * shin_dir
            joints[f"toe_{side}"] = joints[f"ankle_{side}"] + b["foot"] * foot_dir
        for side, sign in (("left", 1.0), ("right", -1.0)):
            shoulder = joints["neck"] + sign * b["shoulder_half_width"] * left
            joints[f"shoulder_{side}"] = shoulder
            # The arm at rest: hanging, swinging against the leg of its side, the elbow a little bent.
            arm_swing = -0.6 * swing[side]
            elbow_bend = 0.1 + 0.5 * amplitude
            upper_dir = math.sin(arm_swing) * forward - math.cos(arm_swing) * up
            fore_dir = math.sin(arm_swing + elbow_bend) * forward - math.cos(arm_swing + elbow_bend) * up
            rest_elbow = shoulder + b["upper_arm"] * upper_dir
            rest_hand = rest_elbow + (b["forearm"] + b["hand"]) * fore_dir
            weight, goal, direction = 0.0, None, None
            for task in self.arm_tasks:
                if task.side == side:
                    w = task.weight(t)
                    if w > 0.0:
                        weight = w
                        goal, direction = task.target(t, base, shoulder)
                        break
            if weight <= 0.0:
                elbow, wrist, hand = rest_elbow, rest_elbow + b["forearm"] * fore_dir, rest_hand
            else:
                goal = (1.0 - weight) * rest_hand + weight * np.asarray(goal, dtype=np.float64)
                if direction is not None:
                    direction = (1.0 - weight) * fore_dir + weight * np.asarray(direction, dtype=np.float64)
                    direction /= np.linalg.norm(direction)
                hint = -up - 0.6 * sign * left - 0.3 * forward
                elbow, wrist, hand = arm_ik(shoulder, goal, direction, b["upper_arm"], b["forearm"], b["hand"], hint)
            joints[f"elbow_{side}"] = elbow
            joints[f"wrist_{side}"] = wrist
            joints[f"hand_{side}"] = hand
            if self.limbs == "thin":
                joints[f"knuckles_{side}"] = 0.5 * (wrist + hand)
        return joints

    @property
    def part_names(self) -> tuple[str, ...]:
        """Names of the parts, in :meth:`parts_at`'s order (:data:`PART_NAMES`, then the fingers of thin limbs)."""
        return tuple(part.name for part in self.parts)

    def parts_at(self, t: float) -> list[Capsule]:
        """The body's capsules at time ``t`` (world frame, metres), in :attr:`part_names` order."""
        joints = self.joints_at(t)
        b = self.bones
        return [Capsule(tuple(joints[part.a]), tuple(joints[part.b]), b[part.radius]) for part in self.parts]

    def carry_box_pose(self, base: BasePose, size) -> tuple[np.ndarray, float]:
        """(center (3,) world metres, yaw radians) of a box of ``size`` (3,) held in front of the body."""
        b = self.bones
        c, s = math.cos(base.heading), math.sin(base.heading)
        forward = np.array([c, s, 0.0])
        reach = b["torso_radius"] + 0.06 + size[0] / 2.0
        height = self.floor + b["hip_height"] + 0.17 * self.height / 1.75  # about the elbows
        center = np.array([base.position[0], base.position[1], height])
        return center + reach * forward, base.heading


def arm_ik(shoulder, goal, direction, upper: float, forearm: float, hand: float, hint):
    """Two-link arm IK: (elbow, wrist, hand end), each (3,) world metres.

    The hand's end goes to ``goal``. With ``direction`` (unit, wrist towards hand end) the wrist sits ``hand``
    metres behind the goal along it and the upper arm and forearm reach the wrist; without it, the hand continues
    the forearm and the two links are upper arm and forearm + hand. The elbow lies on the side of ``hint``. A goal
    out of reach gets the arm stretched towards it.
    """
    shoulder = np.asarray(shoulder, dtype=np.float64)
    goal = np.asarray(goal, dtype=np.float64)
    if direction is not None:
        wrist_goal = goal - hand * np.asarray(direction, dtype=np.float64)
        l1, l2 = upper, forearm
    else:
        wrist_goal = goal
        l1, l2 = upper, forearm + hand
    d = wrist_goal - shoulder
    dist = float(np.linalg.norm(d))
    u = d / dist if dist > 1e-12 else np.array([0.0, 0.0, -1.0])
    dist = min(max(dist, abs(l1 - l2) + 1e-6), l1 + l2 - 1e-9)
    a = (l1 * l1 - l2 * l2 + dist * dist) / (2.0 * dist)
    h = math.sqrt(max(l1 * l1 - a * a, 0.0))
    hint = np.asarray(hint, dtype=np.float64)
    v = hint - (hint @ u) * u
    if np.linalg.norm(v) < 1e-9:
        v = np.cross(u, [0.0, 0.0, 1.0]) if abs(u[2]) < 0.9 else np.cross(u, [1.0, 0.0, 0.0])
    v /= np.linalg.norm(v)
    elbow = shoulder + a * u + h * v
    reached = shoulder + dist * u
    link = (reached - elbow) / l2
    if direction is not None:
        wrist = reached
        hand_end = wrist + hand * np.asarray(direction, dtype=np.float64)
    else:
        wrist = elbow + forearm * link
        hand_end = reached
    return elbow, wrist, hand_end


def _steps(steps, times: np.ndarray, unwrap: bool) -> np.ndarray:
    """A step function (list of (from time, value), later entries win) sampled at ``times``; angles unwrapped so
    that each step turns the short way."""
    values = []
    previous = None
    for _, value in steps:
        if unwrap and previous is not None:
            value = previous + (value - previous + math.pi) % (2.0 * math.pi) - math.pi
        values.append(value)
        previous = value
    starts = np.array([start for start, _ in steps])
    index = np.searchsorted(starts, times, side="right") - 1
    return np.asarray(values)[np.clip(index, 0, len(values) - 1)]


def _box_filter(signal: np.ndarray, width: int) -> np.ndarray:
    """Moving average over ``width`` samples, centred, edges padded with the end values."""
    pad = width // 2
    padded = np.concatenate([np.full(pad, signal[0]), signal, np.full(width - 1 - pad, signal[-1])])
    kernel = np.ones(width) / width
    return np.convolve(padded, kernel, mode="valid")


def box_primitive(center, yaw: float, size) -> Box:
    """A :class:`~depthguard.scenes.Box` of full ``size`` (3,) metres at ``center`` (3,), turned ``yaw`` about z."""
    c, s = math.cos(yaw), math.sin(yaw)
    R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return Box(tuple(np.asarray(center, dtype=np.float64)), tuple(np.asarray(size, dtype=np.float64) / 2.0), R)
