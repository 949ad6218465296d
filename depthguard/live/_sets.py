"""One frame-set loop for live input and replay (design §12b): frames of several cameras and the robot's joint
states come in one by one, in the order they arrive; sets of frames, each with the joints at every frame's stamp,
come out.

Times are seconds on the cameras' clock (header stamps). The loop holds no wall clock: the caller advances its clock
with :meth:`FrameSetLoop.tick` (live: the host's clock; replay: each message's stamp), so the same messages give the
same sets whichever drives it, as long as every frame arrives within the wait.

- **Grouping by stamp.** Each camera's newest frame is kept and carried forward into later sets, where it ages (the
  monitor counts it stale past ``max_age``). A set is formed as soon as every camera has a frame newer than the last
  set and each new frame's joints are settled (``complete``; with the robot's joint states at their usual rate the
  next one after a stamp settles it), or ``wait`` seconds after the first such frame's stamp (``waited``: a camera is late or quiet),
  or ``idle`` seconds after the last set when no new frame came at all (``idle``: answers keep coming, and the
  cameras' frames age in them). A set's ``time``, its clock for ages, is its newest stamp (complete), the wait's end
  (waited) or the idle deadline (idle): a function of the stamps alone.
- **Joints.** One :class:`JointHistory`. A frame without joint states around its stamp (``config.JOINT_GAP``;
  ``config.JOINT_HOLD``, 0 by default: no state is held past its time) is left out of the set and named in
  ``no_joints``: its camera counts as blind.
- **A stamp that goes backwards, or jumps ahead** by more than ``config.STAMP_JUMP`` (a camera or its driver
  restarted, a clock stepped, a camera silent that long) resets that camera: its carried frame is dropped
  (``resets`` counts it), its new frame starts again, and the next set names it (``reset_camera:<name>``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from depthguard import config
from depthguard.depth import DepthImage
from depthguard.errors import InputError
from depthguard.validation import check_points, check_real

__all__ = ["JointHistory", "FrameSet", "FrameSetLoop", "SetAnswer", "answer_set", "RESULT_COLUMNS"]


class JointHistory:
    """The robot's joint states over time, the last ``capacity`` of them, looked up at a frame's stamp.

    :meth:`at` interpolates linearly between the two states around a time when they are at most ``gap`` seconds
    apart, or holds the last state for a time at most ``hold`` seconds after it; otherwise it answers None. A state
    stamped at or before the last one is refused (``refused`` counts them): joint states come in stamp order."""

    def __init__(self, gap: float = config.JOINT_GAP, hold: float = config.JOINT_HOLD,
                 capacity: int = config.JOINT_HISTORY):
        self.gap = check_real(gap, "gap", minimum=0.0, unit="seconds", field="joint_gap")
        self.hold = check_real(hold, "hold", minimum=0.0, unit="seconds", field="joint_hold")
        self.capacity = int(capacity)
        self._times = np.full(self.capacity, np.nan)
        self._rows: np.ndarray | None = None
        self._count = 0  # states added (the ring holds the last min(count, capacity))
        self.refused = 0

    def __len__(self) -> int:
        return min(self._count, self.capacity)

    @property
    def last_time(self) -> float | None:
        return None if self._count == 0 else float(self._times[(self._count - 1) % self.capacity])

    def add(self, time: float, positions) -> bool:
        """Record the joints ``positions`` ((n,) float64, the robot's order) at ``time``; False when refused."""
        positions = np.asarray(positions, dtype=np.float64)
        if not math.isfinite(time) or not np.isfinite(positions).all():
            self.refused += 1
            return False
        last = self.last_time
        if last is not None and time <= last:
            self.refused += 1
            return False
        if self._rows is None or self._rows.shape[1] != positions.shape[0]:
            self._rows = np.zeros((self.capacity, positions.shape[0]))
            self._count = 0
        slot = self._count % self.capacity
        self._times[slot] = time
        self._rows[slot] = positions
        self._count += 1
        return True

    def at(self, time: float) -> np.ndarray | None:
        """(n,) float64 joints at ``time``, or None when no state lies near enough (see the class)."""
        n = len(self)
        if n == 0 or not math.isfinite(time):
            return None
        first = self._count - n
        slots = [(first + i) % self.capacity for i in range(n)]
        times = self._times[slots]
        i = int(np.searchsorted(times, time, side="right")) - 1  # the last state at or before time
        if i < 0:
            return None
        if times[i] == time:
            return self._rows[slots[i]].copy()
        if i + 1 < n:
            t0, t1 = times[i], times[i + 1]
            if t1 - t0 > self.gap:
                return None
            w = (time - t0) / (t1 - t0)
            return (1.0 - w) * self._rows[slots[i]] + w * self._rows[slots[i + 1]]
        if time - times[i] <= self.hold:
            return self._rows[slots[i]].copy()
        return None


@dataclass(frozen=True, eq=False)
class FrameSet:
    """One set of frames from :class:`FrameSetLoop`.

    Attributes:
        index: the set's number, 0, 1, ... in the order the loop formed them.
        time: the set's clock, seconds (stamp clock): its newest stamp, or the deadline that formed it.
        why: ``"complete"``, ``"waited"`` or ``"idle"`` (see the module docstring).
        images: camera -> :class:`DepthImage` (its newest frame, new or carried forward), rig order; cameras
            without a frame yet, or without joints at its stamp, are absent.
        joints: camera -> (n,) float64 joints at that frame's stamp, the robot's order (empty without a robot).
        new: the cameras whose frame is new in this set.
        no_joints: cameras with a frame but no joint state near its stamp (left out: they count as blind).
        reset: cameras whose stamps went back, or jumped ahead, since the last set (started again).
    """

    index: int
    time: float
    why: str
    images: dict[str, DepthImage]
    joints: dict[str, np.ndarray]
    new: tuple[str, ...]
    no_joints: tuple[str, ...] = ()
    reset: tuple[str, ...] = ()


@dataclass
class _Camera:
    frame: DepthImage | None = None
    joints: np.ndarray | None = None  # fixed once the frame first went out with joints
    new: bool = False
    received: int = 0
    resets: int = 0
    reset_since_set: bool = False


@dataclass
class FrameSetLoop:
    """Frames and joint states in, sets of frames out (see the module docstring).

    Args:
        cameras: the rig's camera names, in order.
        wait: seconds a set waits for the other cameras after its first new frame (``config.FRAME_SET_WAIT``).
        idle: seconds after the last set when a set is formed without a new frame (the monitor's max_age).
        robot: whether joints are needed (with a robot, a frame without joints near its stamp is left out).
        joints: the :class:`JointHistory` (one is made with the defaults).
    """

    cameras: tuple
    wait: float = config.FRAME_SET_WAIT
    idle: float = config.DEFAULT_MAX_AGE
    robot: bool = True
    joints: JointHistory = field(default_factory=JointHistory)

    def __post_init__(self):
        self.cameras = tuple(self.cameras)
        if not self.cameras or len(set(self.cameras)) != len(self.cameras):
            raise InputError(f"a frame-set loop needs distinct camera names, got {list(self.cameras)}",
                             field="cameras")
        self.wait = check_real(self.wait, "wait", minimum=0.0, unit="seconds", field="wait")
        self.idle = check_real(self.idle, "idle", minimum=0.0, above_minimum=True, unit="seconds", field="idle")
        self._state = {name: _Camera() for name in self.cameras}
        self._first_new: float | None = None  # stamp of the first frame newer than the last set
        self._last_set: float | None = None  # the last set's time
        self.clock = -math.inf
        self.sets = 0

    def camera(self, name: str) -> _Camera:
        return self._state[name]

    def add_joints(self, time: float, positions) -> list[FrameSet]:
        """A joint state (the robot's order) stamped ``time``: the set it completes (none or one: every camera had
        a new frame, and this state was the one a frame's joints waited for)."""
        self.joints.add(time, positions)
        return self._complete()

    def _joints_ready(self, state: _Camera) -> bool:
        """Whether a new frame's joints are settled: a state at or after its stamp came (they are interpolated),
        or none can come near enough. While the last state is before the stamp and within JOINT_GAP of it, the next
        one will bracket it: the set waits for it (within ``wait``; after the wait the last state is held, up to
        JOINT_HOLD)."""
        if not self.robot or state.frame is None:
            return True
        stamp = state.frame.timestamp
        last = self.joints.last_time
        return last is None or last >= stamp or stamp - last > self.joints.gap

    def _complete(self) -> list[FrameSet]:
        states = [self._state[name] for name in self.cameras]
        if self._first_new is None or not all(s.new for s in states) or \
                not all(self._joints_ready(s) for s in states if s.new):
            return []
        return [self._form(max(s.frame.timestamp for s in states), "complete")]

    def add_frame(self, image: DepthImage) -> list[FrameSet]:
        """A camera's new frame (a :class:`DepthImage` named for a camera of the loop, with its stamp): the sets it
        completes (none or one)."""
        state = self._state.get(image.camera)
        if state is None:
            raise InputError(f"a frame of camera {image.camera!r}, which the rig lacks", camera=image.camera,
                             field="camera")
        stamp = image.timestamp
        if stamp is None or not math.isfinite(stamp):
            raise InputError("a live frame needs a finite stamp", camera=image.camera, field="header.stamp")
        out = self.tick(stamp)
        previous = state.frame
        if previous is not None and not previous.timestamp < stamp <= previous.timestamp + config.STAMP_JUMP:
            state.resets += 1  # a stamp that went back, or jumped ahead: the camera starts again
            state.reset_since_set = True
        state.frame, state.joints, state.new = image, None, True
        state.received += 1
        if self._first_new is None:
            self._first_new = stamp
        return out + self._complete()

    def tick(self, now: float) -> list[FrameSet]:
        """Advance the loop's clock to ``now`` (seconds, stamp clock; it never goes back): the set a wait or the idle
        deadline forms by then (none or one; an idle set repeats every ``idle`` seconds)."""
        out = []
        if now <= self.clock:
            return out
        self.clock = now
        if self._first_new is not None and now >= self._first_new + self.wait:
            out.append(self._form(self._first_new + self.wait, "waited"))
        elif self._first_new is None and self._last_set is not None and now >= self._last_set + self.idle:
            deadline = self._last_set + self.idle
            deadline += self.idle * math.floor((now - deadline) / self.idle)  # the latest idle deadline passed
            out.append(self._form(deadline, "idle"))
        return out

    def _form(self, time: float, why: str) -> FrameSet:
        images, joints, new, no_joints = {}, {}, [], []
        reset = tuple(name for name in self.cameras if self._state[name].reset_since_set)
        for name in self.cameras:
            state = self._state[name]
            state.reset_since_set = False
            if state.frame is None:
                continue
            if state.new:
                new.append(name)
                state.new = False
            if self.robot and state.joints is None:
                state.joints = self.joints.at(state.frame.timestamp)
            if self.robot and state.joints is None:
                no_joints.append(name)
                continue
            images[name] = state.frame
            if state.joints is not None:
                joints[name] = state.joints
        self._first_new = None
        self._last_set = time
        self.sets += 1
        return FrameSet(index=self.sets - 1, time=time, why=why, images=images, joints=joints, new=tuple(new), no_joints=tuple(no_joints), reset=reset)


#: The columns of ``replay``'s RESULTS.csv (``live --out`` adds ``cameras`` and ``latency_ms``).
RESULT_COLUMNS = ["time", "frame", "control_point", "x", "y", "z", "distance", "blind_distance", "flags"]


@dataclass(frozen=True, eq=False)
class SetAnswer:
    """One set of frames answered (:func:`answer_set`).

    Attributes:
        frame_set: the set.
        index: the set's number (0, 1, ... in the loop's order).
        points: (n, 3) float64, metres, world frame: the control points asked about.
        result: the monitor's :class:`~depthguard.DistanceResult` for them.
        seen: the cameras counted as seen (in the set and not stale at its time), rig order.
        named: one flag per other camera of the rig: ``missing_camera:<name>`` (no frame yet, or left out) or
            ``stale_camera:<name>`` (a frame too old at the set's time, or without joints near its stamp); and
            ``reset_camera:<name>`` for a camera whose stamps went back since the last set.
        prepared: the monitor's :class:`~depthguard.PreparedSet` of the set (more queries: speed scaling).
        joints: (n,) radians, the robot's joints the points were placed at (None when ``points`` were given).
    """

    frame_set: FrameSet
    index: int
    points: np.ndarray
    result: object
    seen: tuple
    named: tuple
    prepared: object = None
    joints: object = None

    def flags(self, k: int) -> list[str]:
        """Point k's flags: the result's, then the cameras'."""
        return list(self.result.flags[k].names) + list(self.named)

    def rows(self, point_names) -> list[list[str]]:
        """RESULT_COLUMNS rows, one per point (numbers as repr: they read back as the same floats)."""
        t = repr(float(self.frame_set.time))
        return [[t, str(self.index), name, *(repr(float(c)) for c in self.points[k]),
                 repr(float(self.result.distance[k])), repr(float(self.result.blind_distance[k])),
                 ";".join(self.flags(k))] for k, name in enumerate(point_names)]


def answer_set(monitor, loop: FrameSetLoop, frame_set: FrameSet, robot=None, points=None,
               now: float | None = None) -> SetAnswer | None:
    """Ask ``monitor`` (a :class:`~depthguard.DistanceMonitor`) about ``points`` ((n, 3) world, metres), or the
    ``robot``'s control points at its joints at the set's time (the joint history's, else those of the set's newest
    frame), on ``frame_set`` at ``now`` (default: the set's time; live passes its host clock less the transport
    allowance when that is later): the one answering step of ``live`` and ``replay``. None when the robot's joints
    are not known at all (no answer can name its points)."""
    now = frame_set.time if now is None else max(now, frame_set.time)
    q = None
    if points is None:
        q = loop.joints.at(frame_set.time)
        if q is None and frame_set.joints:
            newest = max(frame_set.joints, key=lambda name: frame_set.images[name].timestamp)
            q = frame_set.joints[newest]
        if q is None:
            return None
        points = robot.control_point_positions(q)
    camera_joints = frame_set.joints if robot is not None else None
    prepared = monitor.prepare_set(frame_set.images, camera_joints=camera_joints or None, now=now)
    result = prepared.query(check_points(points), check=False)
    seen, named = [], []
    for name in loop.cameras:
        image = frame_set.images.get(name)
        if image is not None and not monitor.is_stale(image.timestamp, now):
            seen.append(name)
        elif image is None and loop.camera(name).frame is None:
            named.append(f"missing_camera:{name}")
        else:
            named.append(f"stale_camera:{name}")
    named += [f"reset_camera:{name}" for name in frame_set.reset]
    return SetAnswer(frame_set, frame_set.index, np.asarray(points), result, tuple(seen), tuple(named), prepared, q)
