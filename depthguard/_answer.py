"""The answer stage (docs/design.md, "Layers and the pipeline"): one set of frames as the monitor's stages left it
(:class:`PreparedSet`), how it answers (:class:`QueryPlan`), and where its concessions counted space free that no
camera saw free (:class:`Concessions`, design §11a)."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from depthguard import config
from depthguard.depthspace import single_camera_distances
from depthguard.errors import InputError
from depthguard.results import DetectableResult, DistanceResult, Flag
from depthguard.validation import check_points, check_real, short_repr


@dataclass(frozen=True)
class QueryPlan:
    """How a query answers (:meth:`DistanceMonitor.plan`): ``kind`` "blind", "single" or "fused"; ``principals``:
    the cameras that answer (the single camera, or the depth grids' principals); ``absent``: the flags every answer
    carries for the rig's stale and missing cameras; ``stale``: the stale frames' timestamps by camera."""

    kind: str
    principals: tuple[str, ...]
    absent: Flag
    stale: dict


@dataclass(frozen=True, eq=False)
class PreparedSet:
    """One set of frames as :meth:`DistanceMonitor.prepare_set` prepared it, ready for queries: the plan, the usable
    frames, the depth grid's fusion of each principal (fused plans), the free-space memory's remembered voxels (for
    the flag), where the concessions counted space free (:class:`Concessions`), and its times:

    - ``time``: the OLDEST capture time among the usable frames (seconds, or None): the set is as old as that, since
      each camera's free space is what it saw when it captured its frame (design §9, T_r);
    - ``newest``: the newest capture time among them;
    - ``now``: the clock the set was prepared at (the ``now`` given, else ``newest``);
    - ``prepare_seconds``: wall-clock seconds :meth:`DistanceMonitor.prepare_set` took (SSM's reaction time counts
      it: :meth:`reaction_time`).

    Queries change only the fusion's cache of classified cells: query it from one thread at a time."""

    plan: QueryPlan
    usable: dict
    fused: tuple
    free_now: tuple | None
    rho: float
    aggregate: str
    unseen: str
    method: str
    time: float | None
    detectable: object = None
    now: float | None = None
    newest: float | None = None
    max_age: float | None = None
    untimed_stale: bool = False
    concessions: "Concessions | None" = None
    prepare_seconds: float = 0.0
    capability: tuple | None = None  # (d, hidden band) of the monitor's detectable space

    def ages(self, now: float | None = None) -> dict[str, float | None]:
        """Camera name -> the age of its usable frame at ``now`` (seconds; default: the set's own clock), None for
        a frame without a timestamp."""
        clock = self.now if now is None else now
        return {name: (None if state.occupancy.timestamp is None or clock is None
                       else clock - state.occupancy.timestamp) for name, state in self.usable.items()}

    def reaction_time(self, now: float, control_period: float) -> float:
        """SSM's reaction time T_r at ``now`` (seconds, the frames' clock), design §9: the age of the oldest
        usable frame at ``now`` + the measured preparation of this set (``prepare_seconds``) + one control period
        (seconds, > 0). inf when no usable frame carries a timestamp (nothing says how old the answer is)."""
        now = check_real(now, "now", unit="seconds", field="now")
        control_period = check_real(control_period, "control_period", minimum=0.0, unit="seconds",
                                    field="control_period")
        if self.time is None:
            return math.inf
        return max(now - self.time, 0.0) + self.prepare_seconds + control_period

    def _stale_at(self, now: float | None) -> dict | None:
        """The usable frames' timestamps by camera when one of them is stale at ``now`` (None if none is)."""
        if now is None:
            return None
        times = {name: state.occupancy.timestamp for name, state in self.usable.items()}
        if any(is_stale(t, now, self.max_age, self.untimed_stale) for t in times.values()):
            return times
        return None

    def detectable_distances(self, points_world, limit: float = math.inf, check: bool = True,
                             now: float | None = None) -> DetectableResult:
        """For speed and separation monitoring only: for each control point ((n, 3) float64, metres, world frame), a
        lower bound of its distance to every ball of diameter d (the monitor's ``detection_capability``) lying in the
        space these frames leave possibly occupied, or ``limit`` where it is at least that
        (:class:`depthguard.freespace.DetectableSpace`), with flags (:class:`DetectableResult`). Regions thinner than
        d do not count, and the concessions of the monitor may hide a band next to a surface: use them only with
        ISO 13855's intrusion distance C for the result's ``effective_capability`` counted (SSM's S_p does, and
        refuses another). Every distance is 0 when no camera had a usable frame, or when a frame is stale at
        ``now``. Raises :class:`InputError` (field ``detection_capability``) if the monitor has none."""
        if self.detectable is None:
            raise InputError("this monitor has no detection_capability: pass DistanceMonitor(detection_capability="
                             "...) for detectable distances", field="detection_capability")
        from depthguard.validation import check_limit

        points = check_points(points_world) if check else points_world
        limit = check_limit(limit)
        if now is not None:
            now = check_real(now, "now", unit="seconds", field="now")
        d, band = self.capability
        n = len(points)
        stale = self._stale_at(now)
        if not self.usable or stale is not None:
            flag = self.plan.absent | (Flag.STALE_CAMERA if stale is not None else Flag(0))
            return DetectableResult(np.zeros(n), tuple(flag or Flag.MISSING_CAMERA for _ in range(n)), d, band,
                                    {}, self.prepare_seconds)
        distance = self.detectable.distances(points, limit)
        flags = [self.plan.absent | (Flag.DETECTION_OPENING if x > 0.0 else Flag(0)) for x in distance]
        if self.concessions is not None:
            flags, _ = self.concessions.flag(points, distance, min(limit, _FAR), flags, query=False)
        flags = self._flag_remembered(points, distance, min(limit, _FAR), flags)
        return DetectableResult(distance, tuple(flags), d, band, self.ages(now), self.prepare_seconds)

    def _flag_remembered(self, points, distance, rho, flags):
        """``flags`` with ``REMEMBERED`` added where space nearer than min(distance, rho) counts free only because
        the memory remembers it (no frame of the last update saw it free)."""
        from depthguard.freespace import voxels_within

        if self.free_now is None:
            return flags
        rests = voxels_within(self.free_now[2], self.free_now[1], points, np.minimum(distance, rho))
        return [f | Flag.REMEMBERED if r else f for f, r in zip(flags, rests)]

    def query(self, points_world, check: bool = True, now: float | None = None,
              aggregate: str | None = None) -> DistanceResult:
        """Distances of control points ((n, 3) float64, metres, world frame) on these frames, as
        :meth:`DistanceMonitor.query` gives them. ``now`` (seconds, the frames' clock): when a usable frame is stale
        at ``now`` (older than the monitor's ``max_age``), every point gets distance 0 and ``stale_camera``; the
        result's ages are taken at ``now`` (default: the set's own clock). ``aggregate``: "min", "mean" or "hybrid"
        for this query (default: the monitor's): a controller asks "hybrid" for the end-effector's direction and
        "min" for the other control points (design §9), whose distances are the same."""
        points = check_points(points_world) if check else points_world
        if now is not None:
            now = check_real(now, "now", unit="seconds", field="now")
        if aggregate is None:
            aggregate = self.aggregate
        elif not isinstance(aggregate, str) or aggregate not in config.AGGREGATES:
            raise InputError(f"aggregate must be one of {config.AGGREGATES}, got {short_repr(aggregate)}",
                             field="aggregate")
        plan = self.plan
        if plan.kind == "blind":
            return DistanceResult.blind(len(points), plan.absent, plan.stale)
        stale = self._stale_at(now)
        if stale is not None:
            return DistanceResult.blind(len(points), plan.absent | Flag.STALE_CAMERA, stale)
        ages = self.ages(now)
        if plan.kind == "single":
            (name,) = plan.principals
            result = single_camera_distances(self.usable[name].occupancy, points, self.rho, aggregate,
                                             self.unseen, self.method, check=False)
            flags = [f | plan.absent for f in result.flags]
            flags, near = self.concessions.flag(points, result.distance, self.rho, flags, query=True)
            return replace(result, flags=tuple(flags), ages=ages, concession_distance=near)
        results = [frames.distances(points, self.rho, aggregate, self.unseen, check=False)
                   for frames in self.fused]
        timestamps = {name: state.occupancy.timestamp for name, state in self.usable.items()}
        invalid_pixels = {n: s.occupancy.invalid_pixels for n, s in self.usable.items()}
        if len(results) == 1:
            chosen = np.zeros(len(points), dtype=np.int64)
        else:
            holds = np.array([[Flag.REGION_OUTSIDE_VIEW not in f for f in r.flags] for r in results])
            candidates = np.where(holds, np.array([r.distance for r in results]), -np.inf)
            chosen = np.where(holds.any(axis=0), np.argmax(candidates, axis=0), 0)
        rows = np.arange(len(points))

        def pick(attr):  # each point's value from the principal chosen for it: (principals, n, ...) -> (n, ...)
            return np.stack([getattr(r, attr) for r in results])[chosen, rows]

        # FusedFrames flags a blind secondary camera STALE_CAMERA; the plan knows whether it was stale or missing.
        bits = np.array([[int(f) for f in r.flags] for r in results], dtype=np.int64).reshape(len(results), -1)
        bits = (bits[chosen, rows] & ~int(Flag.STALE_CAMERA)) | int(plan.absent)
        flags = [Flag(int(b)) for b in bits]
        distance = pick("distance")
        # An answer rests on memory when space nearer than it counts free only because it is remembered.
        flags = self._flag_remembered(points, distance, self.rho, flags)
        flags, near = self.concessions.flag(points, distance, self.rho, flags, query=True)
        return DistanceResult(distance=distance, direction=pick("direction"),
                              count=pick("count"), invalid_count=pick("invalid_count"), flags=tuple(flags),
                              blind_distance=pick("blind_distance"), timestamps=timestamps,
                              cameras=tuple(self.usable), invalid_pixels=invalid_pixels,
                              principal=tuple(plan.principals[c] for c in chosen), ages=ages,
                              concession_distance=near)


#: A concession farther than this (metres) is not looked for when the query has no finite limit.
_FAR = 1e3


@dataclass(frozen=True)
class Concessions:
    """Where one set of frames' concessions (design §11a) counted space free that no camera saw free:

    - ``zone``: None, or (capsules (n, 7) float64: p0, p1, radius with the padding, metres, world frame, at every
      usable frame's joints; thickness, metres): the robot zone takes space within thickness of a capsule for the
      robot. It applies to fused answers (``zone_in_query``) and to the detectable space.
    - ``solids``: None, or (boxes, band metres): every replaced measurement lies within band of a known solid
      (``StaticSolids.substitute_band``). Queries only: the detectable space takes the frames as measured.
    - ``fills``: occupancy images of the space filled holes counted free (``depthguard.depth.filled_space``), in
      queries and in the detectable space alike.
    - ``shell``: None, or (capsules as ``zone``'s, thickness): self-filtering takes a measurement within the
      rendered geometry plus the tolerance and the noise margin for the robot, and the depth grid as much behind it;
      that space lies within thickness of the capsules (queries only: the detectable space takes the frames' free
      space as measured, up to the robot's surface less the margin).
    """

    zone: tuple | None
    solids: tuple | None
    fills: tuple
    zone_in_query: bool = False
    shell: tuple | None = None

    def distances(self, points: np.ndarray, rho: float, query: bool = True) -> dict:
        """Flag -> (n,) float64 metres: each concession's distance from the points ((n, 3) world frame), a lower
        bound (the zone: to the capsules grown by the thickness; a solid: to the box grown by the band; fills:
        exact, to the filled frusta), inf where there is none within ``rho``."""
        n = len(points)
        out = {}
        if self.zone is not None and (self.zone_in_query or not query) and n:
            out[Flag.ROBOT_ZONE] = _to_grown_capsules(points, *self.zone)
        if self.shell is not None and query and n:
            out[Flag.ROBOT_SHELL] = _to_grown_capsules(points, *self.shell)
        if self.solids is not None and query and n:
            boxes, band = self.solids
            near = np.full(n, np.inf)
            for box in boxes:
                local = (points - np.asarray(box.center, dtype=np.float64)) @ np.asarray(box.R_world_box,
                                                                                       dtype=np.float64)
                outside = np.maximum(np.abs(local) - np.asarray(box.half_extents, dtype=np.float64), 0.0)
                near = np.minimum(near, np.linalg.norm(outside, axis=1))
            out[Flag.KNOWN_SOLID] = np.maximum(near - band, 0.0)
        if self.fills and n:
            near = np.full(n, np.inf)
            for occupancy in self.fills:
                result = single_camera_distances(occupancy, points, rho, "min", "free", "exact", check=False)
                near = np.minimum(near, result.distance)
            out[Flag.HOLE_FILLED] = near
        return {flag: np.where(d < rho, d, np.inf) for flag, d in out.items()}

    def flag(self, points, distance, rho, flags, query=True):
        """(flags with each concession nearer than min(distance, rho) added, (n,) the nearest concession's distance
        (inf: none within rho))."""
        near = np.full(len(points), np.inf)
        bound = np.minimum(distance, rho)
        flags = list(flags)
        for flag, d in self.distances(points, rho, query).items():
            near = np.minimum(near, d)
            flags = [f | flag if x < b else f for f, x, b in zip(flags, d, bound)]
        return flags, near


def _to_grown_capsules(points: np.ndarray, capsules: np.ndarray, thickness: float) -> np.ndarray:
    """(n,) metres from each point ((n, 3) world frame) to the union of the capsules ((k, 7): p0, p1, radius) grown
    by ``thickness`` metres (0 inside)."""
    p0, p1, radius = capsules[:, 0:3], capsules[:, 3:6], capsules[:, 6]
    axis = p1 - p0
    length2 = np.maximum((axis * axis).sum(1), 1e-300)
    rel = points[:, None, :] - p0[None]
    t = np.clip((rel * axis[None]).sum(2) / length2, 0.0, 1.0)
    gap = np.linalg.norm(rel - t[..., None] * axis[None], axis=2) - (radius + thickness)[None]
    return np.maximum(gap.min(axis=1), 0.0)


def is_stale(timestamp, now, max_age, untimed_stale) -> bool:
    """Whether a frame stamped ``timestamp`` (seconds, or None) counts as blind at ``now`` (seconds, or None) under
    ``max_age`` (seconds, or None: no age limit); ``untimed_stale``: a frame without a timestamp is stale."""
    if timestamp is None:
        return max_age is not None and untimed_stale
    if not math.isfinite(timestamp):
        return True
    if now is not None and timestamp > now + config.CLOCK_SKEW_TOLERANCE:
        return True
    return max_age is not None and now is not None and now - timestamp > max_age
