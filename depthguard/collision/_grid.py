"""The depth grid's collision verdict (design §10, "A second opinion from the distances"): a future configuration
collides unless every sphere covering its moving links lies farther than its radius from what the frames leave
possibly occupied, the space hidden behind and between the robot's links included.

Sound by construction, up to the concessions the monitor was built with (each flagged per configuration): the spheres
(:meth:`RobotModel.with_surface_points`) cover every moving link's padded capsule; each sphere's distance is the
monitor's fully conservative distance, ``min(distance, blind_distance)`` (with one camera, the space behind the
robot counts; the depth grid checks it, between two links included); and the pixel grid's discretisation, up to 2.5
pixel footprints at the sphere's depth in the coarsest camera plus 1 mm (the judges' tolerance,
``tests/thin_limbs.py``), is added to every radius. A configuration judged free therefore has nothing possibly occupied inside its padded capsules, except space a
concession counted free, and that concession's flag is on it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from depthguard import config
from depthguard.errors import InputError
from depthguard.results import CONCESSION_FLAGS, Flag
from depthguard.validation import NOT_A_NUMBER, check_real_positive, short_repr

#: Pixel footprints by which a depth grid distance may exceed the truth (the judges' tolerance), and metres for the
#: float32 depth buffer: added to every sphere's radius.
FOOTPRINTS = 2.5
BUFFER = 1e-3


@dataclass(frozen=True, eq=False)
class GridVerdicts:
    """The depth grid's verdicts on n configurations.

    - ``collision``: (n,) bool, True where something possibly occupied (or unseen) comes within a sphere of the
      configuration's moving links.
    - ``clearance``: (n,) float64 metres, the least over its spheres of the conservative distance less the radius
      and the discretisation slack (<= 0 exactly where ``collision``; inf where nothing lies within the monitor's rho).
    - ``conceded``: n :class:`Flag` values: on a configuration judged free, the concessions (design §11a) whose space
      comes within one of its spheres: something they can hide (stated where each is configured) could be hit.
    - ``flags``: n :class:`Flag` values: every flag of the spheres that decided (the nearest one of a free
      configuration, every colliding one of a collision), stale and missing cameras included.
    """

    collision: np.ndarray
    clearance: np.ndarray
    conceded: tuple
    flags: tuple

    def __len__(self) -> int:
        return len(self.collision)


class DepthGridCollisionTest:
    """Collision verdicts of future configurations on a :class:`depthguard.PreparedSet` (any plan: the single camera's
    distances with its blind spot counted, the fused depth grid, or none: every configuration collides).

    Args:
        robot: the :class:`depthguard.robots.RobotModel` the monitor filters (its padded capsules are judged).
        tolerance: metres (> 0) by which a sphere may reach beyond its capsule (:meth:`RobotModel.with_surface_points`):
            smaller means more spheres, more work, fewer false alarms.
    """

    def __init__(self, robot, tolerance: float = config.SSM_ROBOT_UNCERTAINTY):
        from depthguard.robots import RobotModel

        if not isinstance(robot, RobotModel):
            raise InputError(f"robot must be a depthguard.robots.RobotModel, got {short_repr(robot)}", field="robot")
        self.robot = robot
        self.tolerance = float(check_real_positive(tolerance, "tolerance"))
        self.surface = robot.with_surface_points(self.tolerance)
        self.radii = np.asarray(self.surface.control_point_radii, dtype=np.float64)

    def verdicts(self, prepared, configurations) -> GridVerdicts:
        """The verdicts of ``configurations`` ((n, joints) float64, rad or m, each within the joint limits) on the
        frames of ``prepared``, in one query of n x spheres points. Raises :class:`InputError` when the monitor's rho
        is smaller than a sphere's radius plus its slack (distances beyond rho are not looked for)."""
        from depthguard import PreparedSet

        if not isinstance(prepared, PreparedSet):
            raise InputError(f"prepared must be a depthguard.PreparedSet (DistanceMonitor.prepare_set), got "
                             f"{short_repr(prepared)}", field="prepared")
        try:
            qs = np.asarray(configurations, dtype=np.float64) if not isinstance(configurations, str) else None
        except NOT_A_NUMBER:  # words, ragged rows
            qs = None
        if qs is None or qs.ndim != 2 or qs.shape[1] != self.robot.n_joints:
            raise InputError(f"configurations must be (n, {self.robot.n_joints}) joint vectors, got "
                             f"{short_repr(configurations)}", field="configurations")
        n, k = len(qs), len(self.radii)
        if n == 0:
            return GridVerdicts(np.zeros(0, bool), np.zeros(0), (), ())
        points = np.concatenate([self.surface.control_point_positions(q) for q in qs])  # checks each q
        slack = self._slack(prepared, points)
        reach = self.radii.max() + float(slack.max())
        if prepared.rho < reach:
            raise InputError(f"the monitor's rho {prepared.rho:g} m is smaller than the spheres' radius plus the "
                             f"discretisation slack, {reach:.3f} m: a collision within a sphere would not be looked "
                             "for (DistanceMonitor(rho=...))", field="rho")
        result = prepared.query(points, check=False)
        distance = result.distance if result.blind_distance is None else np.minimum(result.distance,
                                                                                   result.blind_distance)
        extent = np.tile(self.radii, n) + slack  # each point's sphere and its slack
        gap = (distance - extent).reshape(n, k)
        near = np.full(n * k, np.inf) if result.concession_distance is None else result.concession_distance
        inside = (near - extent <= 0.0).reshape(n, k)
        bits = np.array([int(f) for f in result.flags], dtype=np.int64).reshape(n, k)
        clearance = gap.min(axis=1)
        collision = clearance <= 0.0
        nearest = np.argmin(gap, axis=1)
        rows = np.arange(n)
        deciding = np.where(collision, np.bitwise_or.reduce(np.where(gap <= 0.0, bits, 0), axis=1),
                            bits[rows, nearest])
        conceded = np.where(collision, 0, np.bitwise_or.reduce(np.where(inside, bits, 0), axis=1)
                            & int(CONCESSION_FLAGS))
        return GridVerdicts(collision, clearance, tuple(Flag(int(b)) for b in conceded),
                            tuple(Flag(int(b)) for b in deciding))

    @staticmethod
    def _slack(prepared, points) -> np.ndarray:
        """(m,) metres: FOOTPRINTS pixel footprints at each point's depth in the coarsest usable camera, plus
        BUFFER (BUFFER alone without a usable camera: every distance is 0 then)."""
        slack = np.full(len(points), BUFFER)
        for state in prepared.usable.values():
            camera = state.camera
            depth = np.maximum(camera.world_to_camera(points)[:, 2], 0.0)
            slack = np.maximum(slack, FOOTPRINTS * depth / min(camera.fx, camera.fy) + BUFFER)
        return slack
