"""SSM's speed factor for a controller that scales a trajectory of its own (design §9, §12b): ros2_control's speed
scaling (``control_msgs/msg/SpeedScalingFactor``), which runs the trajectory at ``factor`` times its speed. The
trajectory itself is not told, only a bound on its joint speeds, so the factor holds for any motion within that bound
(:meth:`SpeedSeparationMonitor.speed_factor_within`).

Where the distances come from: the robot's surface (design §9): spheres that cover every moving link's padded
capsule, none more than Z_r beyond it (``RobotModel.with_surface_points``), asked of the monitor's detectable space
(``PreparedSet.detectable_distances``: what a ball of the monitor's ``detection_capability`` d fits in; C for d plus
the band its concessions hide), each distance less its sphere's radius; asked only as far as a point can slow the
robot (``full_speed_distance``), so the monitor's rho, which its distances keep, does not bound SSM's reach. The
query's own distances are not used: their band (the self-filter's shell: 0.12-0.29 m with the shipped robots) is
coarser than the 70 mm for which ISO 13855 gives a C.

What the reaction time counts (design §9, T_r), from the OLDEST frame of the set to the last instant the factor may
be applied:

    T_r = (clock - oldest stamp) + the set's preparation + one control cycle   (PreparedSet.reaction_time)
          + transport      the factor's way to the controller (computing the factor included)
          + hold           how long the controller applies a factor with no newer one (its watchdog)
          + clock skew     config.CLOCK_SKEW_TOLERANCE: the cameras' clocks may lag the host's by that much

A host clock behind the set's newest stamp by more than the skew tolerance says the clocks disagree: the factor is 0.
So is it where no frame was usable (distance 0 everywhere), and where the joints are not known.

Frames and units: world frame, metres, seconds, radians.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace

import numpy as np

from depthguard import config
from depthguard.avoidance._limits import JointLimits
from depthguard.avoidance._ssm import SpeedSeparationMonitor, SSMParams, protective_separation_distance
from depthguard.errors import InputError
from depthguard.freespace import voxels_within
from depthguard.validation import check_real


#: Seconds the query of the detectable distances is expected to take at most, in the reaction time its reach is
#: chosen for (a longer one only makes a factor below 1 where 1 was possible: never unsound).
QUERY_SLACK = 0.05


@dataclass(frozen=True)
class ScalingAnswer:
    """One speed factor and what it rests on.

    Attributes:
        factor: in [0, 1], the fraction of the trajectory's speed allowed.
        reaction_time: T_r, seconds, as counted (inf when nothing says how old the frames are).
        why: "" when the factor comes from the distances; else why it is 0 ("blind", "clock", "no joints").
        limiting: the name of the surface point that set the factor ("" when 1 or 0 for a reason).
        distance: metres, that point's distance from its sphere's surface (inf: none).
        starting: the factor is below 1 and may rest on space that the monitor's free-space memory has not seen
            free since it was made (``FreeSpaceMemory.never_seen`` within that point's distance): at start-up, until
            the cameras have seen round the robot as it moves through its poses; where it lasts, space no camera
            sees (``depthguard coverage`` shows which). False without a memory.
    """

    factor: float
    reaction_time: float
    why: str = ""
    limiting: str = ""
    distance: float = math.inf
    starting: bool = False


class SpeedScaling:
    """SSM's factor for a scaled trajectory, from a :class:`~depthguard.DistanceMonitor`'s prepared sets (see the
    module's docstring).

    Args:
        monitor: the :class:`~depthguard.DistanceMonitor` whose sets are asked (its robot; its detectable space,
            of its ``detection_capability``; its concessions).
        params: :class:`SSMParams` (default: its defaults). Its ``detection_capability`` is replaced by the
            monitor's plus the band its concessions may hide, refused above ISO 13855's 70 mm; its
            ``sensing_uncertainty`` grows by the monitor's robot zone; its ``robot_uncertainty`` is the covering
            spheres' tolerance.
        joint_speed: (n,) or a number, rad/s: the most each joint moves at factor 1 (default: the robot's velocity
            limits from its URDF).
        braking: (n,) or a number, rad/s^2: the deceleration each joint is sure of (default
            ``config.JOINT_ACCELERATION``).
        hold: seconds the controller applies a factor before it must have a newer one, else stop (its watchdog).
        transport: seconds from the factor's computation to the controller.
        control_period: seconds, the controller's cycle.
    """

    def __init__(self, monitor, params: SSMParams | None = None, *, joint_speed=None, braking=None,
                 hold: float = config.SSM_HOLD, transport: float = config.LIVE_TRANSPORT,
                 control_period: float = config.SSM_CONTROL_PERIOD):
        robot = monitor.robot
        if robot is None:
            raise InputError("speed scaling needs the monitor's robot (DistanceMonitor(robot=...))", field="robot")
        params = SSMParams() if params is None else params
        if not isinstance(params, SSMParams):
            raise InputError(f"params must be SSMParams, got {type(params).__name__}", field="params")
        self.hold = check_real(hold, "hold", minimum=0.0, maximum=10.0, unit="seconds", field="hold")
        self.transport = check_real(transport, "transport", minimum=0.0, maximum=10.0, unit="seconds",
                                    field="transport")
        self.control_period = check_real(control_period, "control_period", minimum=0.0, maximum=1.0,
                                         unit="seconds", field="control_period")
        if monitor.detectable is None:
            raise InputError("speed scaling needs the monitor's detectable space: DistanceMonitor("
                             "detection_capability=d) (and the rig's workspace)", field="detection_capability")
        # The monitor refused at its making a capability that, with the band its concessions hide, exceeds ISO
        # 13855's 70 mm (DistanceMonitor: field detection_capability); C is taken for that sum.
        band = monitor.detectable.capability + monitor.hidden_band
        why = f"detection capability {monitor.detectable.capability:g} m + {monitor.hidden_band:.3f} m hidden"
        tolerance = params.robot_uncertainty if params.robot_uncertainty > 0.0 else config.SSM_ROBOT_UNCERTAINTY
        self.params = replace(params, detection_capability=band, robot_uncertainty=tolerance,
                              sensing_uncertainty=params.sensing_uncertainty + monitor.robot_zone)
        self.hidden = why
        self.memory = monitor.memory  # for ScalingAnswer.starting
        try:
            limits = JointLimits.from_robot(robot, velocity=joint_speed, acceleration=braking)
        except InputError as error:  # named for this class's arguments
            name = {"velocity": "joint_speed", "acceleration": "braking"}.get(error.field, error.field)
            raise InputError(f"{name}: {error.message}", field=name) from None
        for name, values, most, unit in (("joint_speed", limits.velocity, config.SSM_JOINT_SPEED_MAX, "rad/s"),
                                         ("braking", limits.acceleration, config.SSM_BRAKING_MAX, "rad/s^2")):
            if not np.all((values > 0.0) & (values <= most)):
                given = "the URDF's velocity limits" if name == "joint_speed" and joint_speed is None else "given"
                shown = ", ".join(f"{v:g}" for v in values)
                raise InputError(f"{name} must be > 0 and at most {most:g} {unit} for every joint, got {shown} "
                                 f"({given})", field=name)
        self.joint_speed = limits.velocity
        self.surface = robot.with_surface_points(tolerance)
        self.radii = self.surface.control_point_radii
        self.names = self.surface.control_point_names
        # No rho: each distance is asked up to where it stops mattering (full_speed_distance), none is "beyond".
        self.ssm = SpeedSeparationMonitor(self.params, rho=math.inf, braking=limits.acceleration,
                                          reaches=robot.joint_reaches())

    @property
    def extra_time(self) -> float:
        """Seconds T_r counts beyond the set's own age and preparation: transport + hold + clock skew."""
        return self.transport + self.hold + config.CLOCK_SKEW_TOLERANCE

    def at_rest(self, reaction_time: float) -> float:
        """Metres, the protective separation S_p of a robot at rest here, with this reaction time and the stopping
        time of the joint speeds (v_h near): a distance below it stops the robot."""
        stopping = replace(self.params, stopping_time=self.ssm.stopping_time(self.joint_speed))
        return protective_separation_distance(stopping, 0.0, reaction_time)

    def factor(self, prepared, joints, clock=time.time) -> ScalingAnswer:
        """The factor on ``prepared`` (a :class:`~depthguard.PreparedSet` of the monitor) for the robot at
        ``joints`` ((n,) radians, None: unknown), with ``clock()`` the host's clock in the frames' time base
        (seconds), read after the distances are known."""
        if joints is None:
            return ScalingAnswer(0.0, math.inf, "no joints")
        if prepared.time is None:  # no usable frame: nothing is known
            return ScalingAnswer(0.0, math.inf, "blind")
        points, jacobians = self.surface.control_point_kinematics(np.asarray(joints, dtype=np.float64))
        # Asked only as far as a point can slow the robot (full_speed_distance at the reaction time expected after
        # the query): "at least that far" is a true lower bound that lets it go at full speed, and the detectable
        # space beyond is not looked at (its cost grows with the reach).
        expected = prepared.reaction_time(clock(), self.control_period) + self.extra_time + QUERY_SLACK
        full = self.ssm.full_speed_distance(jacobians, self.joint_speed, expected, self.radii)
        limit = float(np.max(full + self.radii))
        distance = prepared.detectable_distances(points, limit=limit, check=False).distance
        surface = np.maximum(np.minimum(distance, limit) - self.radii, 0.0)
        now = clock()
        if prepared.newest is not None and now < prepared.newest - config.CLOCK_SKEW_TOLERANCE:
            return ScalingAnswer(0.0, math.inf, "clock")
        reaction = prepared.reaction_time(now, self.control_period) + self.extra_time
        verdict = self.ssm.speed_factor_within(surface, jacobians, self.joint_speed, reaction, radii=self.radii,
                                               check=False)
        k = verdict.limiting
        return ScalingAnswer(verdict.factor, reaction, "", self.names[k] if k >= 0 else "",
                             float(surface[k]) if k >= 0 else float(np.min(surface, initial=math.inf)),
                             starting=k >= 0 and verdict.factor < 1.0 and self._near_never_seen(points[k], distance[k]))

    def _near_never_seen(self, point: np.ndarray, distance: float) -> bool:
        """Whether space the memory has never seen free lies within ``distance`` (metres, the detectable distance
        of the limiting point, world frame) of ``point``, give or take the diagonal of a memory voxel."""
        if self.memory is None:
            return False
        if not math.isfinite(distance):  # nothing within reach: only a memory that has seen nothing is starting
            return self.memory.time is None
        reach = distance + self.memory.box.voxel * math.sqrt(3.0)
        return bool(voxels_within(self.memory.never_seen, self.memory.box, point[None], np.array([reach]))[0])
