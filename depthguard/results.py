"""What every distance query returns (design §11)."""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field

import numpy as np


class Flag(enum.IntFlag):
    """Why a result may be conservative or incomplete. Combine with ``|``; test with ``in``.

    - ``INSIDE_OBSTACLE``: the point lies inside a possibly-occupied set (distance 0, zero direction).
    - ``REGION_OUTSIDE_VIEW``: the surveillance region (the ball of radius rho) leaves the volume the cameras
      observe; under ``unseen="occupied"`` the boundary of that volume counted as an obstacle (distance 0 when the
      point itself is unseen).
    - ``INVALID_PIXELS_USED``: pixels without a valid measurement contributed (see ``DistanceResult.invalid_count``).
    - ``STALE_CAMERA``: a camera's latest frame was older than the allowed age, so it counted as blind.
    - ``MISSING_CAMERA``: a camera the query needed had no frame, so it counted as blind.
    - ``ROBOT_BLIND_SPOT``: space hidden behind the robot, which one camera cannot see (design §7), comes
      closer to the point than the reported distance (see ``DistanceResult.blind_distance``): an obstacle there
      could be nearer than the answer.
    - ``OUTSIDE_GRID``: fused cameras only: the surveillance region reaches depths the principal camera's depth grid
      does not span (design §8, "Grid range"); what the principal cannot see there counted occupied, whatever
      the other cameras saw. Give the rig a ``workspace`` or ``depth_range`` that holds the region.
    - ``REMEMBERED``: fused cameras with the free-space memory (design §8a): space nearer than the reported
      distance counted free only because it was seen free a moment ago and no person moving at ``v_max`` can have
      reached it since; no camera sees it free now.

    Concessions (design §11a): space counted free on purpose, to make answers useful, although no camera saw it
    free. Each flag says that such space lies nearer to the point than the reported distance, so that an object
    hidden there could be nearer than the answer; ``DistanceResult.concession_distance`` says how near. What each
    can hide is stated where it is configured (``DistanceMonitor``) and in docs/design.md (§11a, "Concessions").

    - ``ROBOT_ZONE``: the robot zone (``DistanceMonitor(robot_zone=...)``): space within that much of the robot's
      padded capsules counted as the robot.
    - ``KNOWN_SOLID``: a known static solid (``DistanceMonitor(static=...)``): a measurement within the
      self-filter's tolerance plus the noise margin of its surface counted as the solid.
    - ``HOLE_FILLED``: a hole in a frame filled from its neighbours (``invalid="neighbors"``): a pixel with no
      measurement counted free up to the nearest surface round it.
    - ``ROBOT_SHELL``: self-filtering (design §7): space within the self-filter's shell of the robot (its
      padded geometry, plus the tolerance and twice the noise margin) counted as the robot. A thin object lying on
      the robot is not told from it.
    - ``DETECTION_OPENING``: SSM's detectable distances only (:meth:`PreparedSet.detectable_distances`): possibly
      occupied regions in which no ball of the detection capability fits were left out (ISO 13855's intrusion
      distance C covers them).
    """

    INSIDE_OBSTACLE = 1
    REGION_OUTSIDE_VIEW = 2
    INVALID_PIXELS_USED = 4
    STALE_CAMERA = 8
    MISSING_CAMERA = 16
    ROBOT_BLIND_SPOT = 32
    OUTSIDE_GRID = 64
    REMEMBERED = 128
    ROBOT_ZONE = 256
    KNOWN_SOLID = 512
    HOLE_FILLED = 1024
    DETECTION_OPENING = 2048
    ROBOT_SHELL = 4096

    @property
    def names(self) -> list[str]:
        """The set flags as lower-case names, in bit order, e.g. ``["region_outside_view"]``."""
        return [member.name.lower() for member in Flag if member in self]


CONCESSION_FLAGS = (Flag.REMEMBERED | Flag.ROBOT_ZONE | Flag.KNOWN_SOLID | Flag.HOLE_FILLED | Flag.DETECTION_OPENING
                    | Flag.ROBOT_SHELL)


@dataclass(frozen=True, eq=False)
class DistanceResult:
    """Distances of n control points to what the cameras say is possibly occupied.

    Attributes:
        distance: (n,) float64, metres. The aggregated distance (``min``/``hybrid``: the smallest; ``mean``: the
            mean over contributors). ``inf`` when nothing is within rho; 0 inside an obstacle or in unseen space
            (under ``unseen="occupied"``).
        direction: (n, 3) float64, world frame, unit vectors pointing **from the obstacle towards the point** (the
            way to move away); ``min``: of the nearest obstacle point; ``mean``/``hybrid``: the normalised mean of
            the contributors' unit directions. The zero vector when there is no contributor, inside an obstacle, or
            when the contributors' directions cancel out.
        count: (n,) int64, contributors used: ``mean``/``hybrid``: every pixel frustum closer than rho, plus the
            boundary of the observed volume when it counts; ``min``: 1 when there is a nearest one, else 0.
        invalid_count: (n,) int64, how many of those contributors were pixels without a valid measurement.
        flags: n :class:`Flag` values, one per point.
        timestamps: camera name -> capture time (seconds) of the frame used, or None when unknown.
        cameras: names of the cameras whose frames were used.
        invalid_pixels: camera name -> pixels of its frame without a valid measurement (whatever the policy did
            with them): a frame that is mostly invalid shows here even under the permissive ``invalid="free"``.
        blind_distance: (n,) float64 metres, the distance to the space hidden behind the robot (single camera:
            from the robot's rendered surface on), inf when it is farther than rho or there is no robot. The fully
            conservative distance is ``min(distance, blind_distance)``. With several cameras the depth grid checks
            that space, between two links included, with the other cameras and the memory: inf.
        principal: per point, the camera whose image the answer was computed in: the single camera, or the
            principal camera of the depth grid whose fused answer is reported; ``""`` when no camera could answer
            (:meth:`blind`).
        ages: camera name -> the age of the frame used, seconds, at the query's ``now`` (at the set's newest capture
            time when no ``now`` was given), or None when the frame has no timestamp. The answer is as old as its
            oldest frame (:attr:`age`): a camera's free space is what it saw then.
        concession_distance: (n,) float64 metres, the distance to the nearest space that a concession (the
            self-filter's shell round the robot, the robot zone, a known solid, a filled hole; the flags
            ``robot_shell``, ``robot_zone``, ``known_solid``, ``hole_filled``) counted free although no camera saw it
            free now, inf when none lies within rho (remembered space has its own bound, ``v_max``). Each such flag is set where it is nearer than ``distance``. The answer without any
            concession is at least ``min(distance, blind_distance, concession_distance)``.
    """

    distance: np.ndarray
    direction: np.ndarray
    count: np.ndarray
    invalid_count: np.ndarray
    flags: tuple[Flag, ...]
    timestamps: dict[str, float | None] = field(default_factory=dict)
    cameras: tuple[str, ...] = ()
    invalid_pixels: dict[str, int] = field(default_factory=dict)
    blind_distance: np.ndarray | None = None
    principal: tuple[str, ...] = ()
    ages: dict[str, float | None] = field(default_factory=dict)
    concession_distance: np.ndarray | None = None

    def __post_init__(self):
        if self.blind_distance is None:
            object.__setattr__(self, "blind_distance", np.full(len(self.distance), np.inf))
        if self.concession_distance is None:
            object.__setattr__(self, "concession_distance", np.full(len(self.distance), np.inf))

    @property
    def age(self) -> float | None:
        """Seconds: the age of the oldest frame the answer used (None when no frame had a timestamp, inf when no
        camera answered). Speed and separation monitoring's reaction time starts here (design §9)."""
        if not self.cameras:
            return math.inf
        known = [a for a in self.ages.values() if a is not None]
        return max(known) if known else None

    @classmethod
    def blind(cls, n: int, flag: "Flag", timestamps: dict | None = None) -> "DistanceResult":
        """The conservative answer for n points when no camera can see (no usable frame): distance 0 and
        blind_distance 0, zero direction, no contributors, every point flagged ``flag`` (``STALE_CAMERA`` and/or
        ``MISSING_CAMERA``), principal ``""``, no camera (:attr:`age` inf)."""
        return cls(distance=np.zeros(n), direction=np.zeros((n, 3)), count=np.zeros(n, dtype=np.int64),
                   invalid_count=np.zeros(n, dtype=np.int64), flags=tuple(flag for _ in range(n)),
                   timestamps=dict(timestamps or {}), cameras=(), blind_distance=np.zeros(n), principal=("",) * n)

    @property
    def is_blind(self) -> bool:
        """True when no camera answered and every distance is 0 (:meth:`blind`): nothing could be seen. A controller
        stops the robot on such an answer."""
        return not self.cameras and bool(np.all(self.distance == 0.0))

    def __len__(self) -> int:
        return len(self.distance)

    def records(self, points_world) -> list[dict]:
        """One JSON-ready dict per point, in input order (``distance`` is None when nothing is within rho)."""
        out = []
        for i, point in enumerate(np.asarray(points_world, dtype=np.float64)):
            d = float(self.distance[i])
            out.append(
                {
                    "point": [float(x) for x in point],
                    "distance": None if math.isinf(d) else d,
                    "direction": [float(x) for x in self.direction[i]],
                    "count": int(self.count[i]),
                    "flags": self.flags[i].names,
                }
            )
        return out


@dataclass(frozen=True, eq=False)
class DetectableResult:
    """SSM's detectable distances of n control points (:meth:`depthguard.PreparedSet.detectable_distances`): to the
    nearest ball of diameter ``capability`` in possibly occupied space, for speed and separation monitoring only.

    Attributes:
        distance: (n,) float64 metres, a lower bound of the distance to every such ball (the search's ``limit``
            where it is at least that; 0 when no camera could see).
        flags: n :class:`Flag` values: ``DETECTION_OPENING`` wherever the distance is above 0 (regions thinner than
            the capability were left out), the concessions whose space lies nearer than the distance
            (``ROBOT_ZONE``, ``KNOWN_SOLID``, ``HOLE_FILLED``, ``REMEMBERED``), and ``STALE_CAMERA`` /
            ``MISSING_CAMERA`` as the query's.
        capability: d, metres: the ball's diameter (the monitor's ``detection_capability``).
        hidden_band: metres: the thickest layer next to a surface (the robot's, a known solid's) that the monitor's
            concessions count free in this space; an object thinner than that lying on the surface is not seen.
        ages: camera name -> the age of its frame, seconds, as :attr:`DistanceResult.ages`.
        prepare_seconds: wall-clock seconds the set took to prepare (part of SSM's reaction time).
    """

    distance: np.ndarray
    flags: tuple[Flag, ...]
    capability: float
    hidden_band: float
    ages: dict[str, float | None] = field(default_factory=dict)
    prepare_seconds: float = 0.0

    @property
    def effective_capability(self) -> float:
        """d + hidden band, metres: the smallest object these distances are sure to count, wherever it lies. A body
        part thinner than it may reach unseen beyond the detected body; ISO 13855's intrusion distance C must be
        taken for it (SSM refuses another)."""
        return self.capability + self.hidden_band

    @property
    def age(self) -> float | None:
        """Seconds: the age of the oldest frame (None when no frame had a timestamp, inf when no camera could see)."""
        if not self.ages:
            return math.inf
        known = [a for a in self.ages.values() if a is not None]
        return max(known) if known else None

    def __len__(self) -> int:
        return len(self.distance)
