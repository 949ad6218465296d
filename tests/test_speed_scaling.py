"""SSM's factor for a trajectory the controller scales (depthguard.avoidance.SpeedScaling, ``live --ssm``).

The judge of ``speed_factor_within`` is ``speed_factor`` itself, the per-command rule with its proof: for random
configurations, distances and commands anywhere in the joint-speed box, the bound's factor never exceeds the
command's own factor with no direction trusted, and the scaled command keeps S_p <= D at every approaching point.
``SpeedScaling`` is checked on what it composes: the surface spheres' distances less their radii, the reaction time
(the set's age + preparation + control period + transport + hold + clock skew), and the reasons for 0."""

from __future__ import annotations

import math

import numpy as np
import pytest

import depthguard as dg
from depthguard import config
from depthguard.avoidance import SpeedScaling, SpeedSeparationMonitor, SSMParams
from depthguard.avoidance._ssm import _protective  # the formula, to check the scaled command against S_p
from depthguard.errors import InputError
from depthguard.robots import RobotModel


@pytest.fixture(scope="module")
def robot():
    return RobotModel.default()


def test_the_bound_never_exceeds_any_command_s_own_factor(robot):
    rng = np.random.default_rng(7)
    surface = robot.with_surface_points(0.01)
    radii = surface.control_point_radii
    braking = np.full(robot.n_joints, 10.0)
    ssm = SpeedSeparationMonitor(SSMParams(), rho=2.5, braking=braking, reaches=robot.joint_reaches())
    positive = 0
    for trial in range(60):
        q = rng.uniform(robot.lower, robot.upper)
        _, jacobians = surface.control_point_kinematics(q)
        m = len(radii)
        distances = rng.uniform(0.6, 2.5, m)
        distances[rng.random(m) < 0.2] = np.inf
        speed = rng.uniform(0.05, 1.0, robot.n_joints)
        reaction = rng.uniform(0.05, 0.4)
        bound = ssm.speed_factor_within(distances, jacobians, speed, reaction, radii=radii)
        assert 0.0 <= bound.factor <= 1.0
        positive += bound.factor > 0.0
        for _ in range(20):  # commands in the box, corners included
            dq = speed * rng.choice([-1.0, 1.0, rng.uniform(-1, 1)], robot.n_joints)
            own = ssm.speed_factor(distances, np.zeros((m, 3)), jacobians, dq, reaction)
            assert bound.factor <= own.factor + 1e-12, (trial, bound.factor, own.factor)
            # the scaled command keeps S_p at its speed within every approaching point's distance
            v = np.linalg.norm(np.einsum("mkn,n->mk", jacobians, bound.factor * dq), axis=1)
            t_s = ssm.stopping_time(dq)
            d = np.where(np.isfinite(distances), distances, 2.5)
            s_p = _protective(ssm.params, v, reaction, d, t_s)
            assert np.all((v == 0.0) | (s_p <= d + 1e-9))
    assert positive > 10  # the bound lets the robot move where there is room


def test_the_bound_refuses_what_it_cannot_use(robot):
    ssm = SpeedSeparationMonitor(SSMParams(), rho=1.0, braking=np.full(robot.n_joints, 10.0))
    jac = np.zeros((2, 3, robot.n_joints))
    with pytest.raises(InputError) as error:
        ssm.speed_factor_within([1.0, 1.0], jac, np.zeros(robot.n_joints), 0.1)
    assert error.value.field == "joint_speed"
    with pytest.raises(InputError) as error:
        ssm.speed_factor_within([1.0, 1.0], jac, np.ones(3), 0.1)
    assert error.value.field == "joint_speed"
    with pytest.raises(InputError) as error:
        ssm.speed_factor_within([1.0, -1.0], jac, np.ones(robot.n_joints), 0.1)
    assert error.value.field == "distances"


class _Prepared:
    """A prepared set of given detectable distances (metres, at the surface points' centres) and times."""

    def __init__(self, distance, time=10.0, newest=10.0, prepare_seconds=0.004):
        self.distance, self.time, self.newest, self.prepare_seconds = distance, time, newest, prepare_seconds

    def detectable_distances(self, points, limit=math.inf, check=True):
        return type("R", (), {"distance": np.minimum(np.broadcast_to(self.distance, (len(points),)), limit)})()

    reaction_time = dg.PreparedSet.reaction_time


@pytest.fixture(scope="module")
def scaling(robot):
    from depthguard_lab.simulation import default_workcell

    rig = default_workcell().scaled(0.25).rig
    monitor = dg.DistanceMonitor(rig, robot=robot, rho=1.5, detection_capability=0.04)
    return SpeedScaling(monitor, joint_speed=0.3, hold=0.1)


def test_speed_scaling_counts_every_delay_and_the_spheres(scaling, robot):
    q = np.zeros(robot.n_joints)
    answer = scaling.factor(_Prepared(0.8), q, clock=lambda: 10.03)
    extra = config.LIVE_TRANSPORT + 0.1 + config.CLOCK_SKEW_TOLERANCE
    assert answer.reaction_time == pytest.approx(0.03 + 0.004 + config.SSM_CONTROL_PERIOD + extra)
    assert scaling.extra_time == pytest.approx(extra)
    _, jacobians = scaling.surface.control_point_kinematics(q)
    surface = np.maximum(0.8 - scaling.radii, 0.0)
    want = scaling.ssm.speed_factor_within(surface, jacobians, scaling.joint_speed, answer.reaction_time,
                                           radii=scaling.radii)
    assert answer.factor == want.factor and 0.0 < answer.factor < 1.0
    assert answer.limiting in scaling.names and answer.why == ""
    # older frames, a longer hold: less speed; nothing within rho: the most
    older = scaling.factor(_Prepared(0.8, time=9.9), q, clock=lambda: 10.03)
    assert older.factor < answer.factor
    nothing = scaling.factor(_Prepared(np.inf), q, clock=lambda: 10.03)  # asked as far as it matters: nothing
    assert nothing.factor == 1.0
    near = scaling.factor(_Prepared(0.5), q, clock=lambda: 10.03)
    assert near.factor == 0.0 and near.why == ""


def test_speed_scaling_is_zero_without_joints_frames_or_an_agreeing_clock(scaling, robot):
    q = np.zeros(robot.n_joints)
    assert scaling.factor(_Prepared(np.inf), None).why == "no joints"
    blind = scaling.factor(_Prepared(np.inf, time=None, newest=None), q, clock=lambda: 10.0)
    assert (blind.factor, blind.why) == (0.0, "blind")
    behind = scaling.factor(_Prepared(np.inf), q, clock=lambda: 10.0 - 2 * config.CLOCK_SKEW_TOLERANCE)
    assert (behind.factor, behind.why) == (0.0, "clock")


def test_a_factor_that_may_rest_on_space_never_seen_says_starting(scaling, robot):
    """``ScalingAnswer.starting`` (issue 35, start-up stated): a factor below 1 is "starting" exactly when space the
    memory has never seen free (``FreeSpaceMemory.never_seen``) lies within the limiting point's detectable distance
    (give or take a voxel's diagonal); judged against the distance from that point to the nearest cube of never-seen
    voxels, found by brute force. A factor of 1 never is."""
    from depthguard.freespace import FreeSpaceMemory

    q = np.zeros(robot.n_joints)
    monitor_memory = scaling.memory
    assert monitor_memory is not None and monitor_memory.time is None
    box = monitor_memory.box
    near = scaling.factor(_Prepared(0.5), q, clock=lambda: 10.03)
    assert near.factor == 0.0 and near.starting  # nothing seen yet
    assert not scaling.factor(_Prepared(np.inf), q, clock=lambda: 10.03).starting  # factor 1
    points, _ = scaling.surface.control_point_kinematics(q)
    rng = np.random.default_rng(11)
    outcomes = []
    try:
        for trial in range(24):
            # one voxel never seen, its cube about as far from the limiting point as the rule's reach (+- 12 cm)
            distance = rng.uniform(0.3, 0.6)
            memory = FreeSpaceMemory(box)
            memory.update(1.0, np.ones(box.shape, dtype=bool))
            scaling.memory = memory
            k = scaling.names.index(scaling.factor(_Prepared(distance), q, clock=lambda: 10.03).limiting)
            direction = rng.normal(size=3)
            target = distance + box.voxel * math.sqrt(3.0) + rng.uniform(-0.12, 0.12)
            at = points[k] + direction / np.linalg.norm(direction) * (target + box.voxel / 2)
            index = np.floor((at - box.lo) / box.voxel).astype(int)
            if np.any(index < 0) or np.any(index >= box.shape):
                continue
            seen = np.ones(box.shape, dtype=bool)
            seen[tuple(index)] = False
            memory = FreeSpaceMemory(box)
            memory.update(1.0, seen)
            scaling.memory = memory
            answer = scaling.factor(_Prepared(distance), q, clock=lambda: 10.03)
            assert answer.factor < 1.0 and answer.limiting == scaling.names[k]
            lo = box.lo + index * box.voxel
            gap = np.linalg.norm(np.maximum(np.maximum(lo - points[k], points[k] - (lo + box.voxel)), 0.0))
            want = gap < distance + box.voxel * math.sqrt(3.0)
            assert answer.starting == want, (trial, answer, gap, distance)
            outcomes.append(want)
        memory = FreeSpaceMemory(box)
        memory.update(1.0, np.ones(box.shape, dtype=bool))
        scaling.memory = memory
        seen_all = scaling.factor(_Prepared(0.5), q, clock=lambda: 10.03)
        assert seen_all.factor == 0.0 and not seen_all.starting  # 0 from the distances, everything seen once
        assert True in outcomes and False in outcomes, outcomes
    finally:
        scaling.memory = monitor_memory


def test_speed_scaling_needs_a_detectable_space_of_at_most_70_mm(robot):
    from depthguard_lab.simulation import default_workcell

    rig = default_workcell().scaled(0.25).rig
    # the query's own distances: their band (the self-filter's shell here) is coarser than ISO 13855's 70 mm
    with pytest.raises(InputError) as error:
        SpeedScaling(dg.DistanceMonitor(rig, robot=robot, rho=0.4), joint_speed=0.3)
    assert error.value.field == "detection_capability"
    with pytest.raises(InputError) as error:  # hole fills hide more than 70 mm - 40 mm here
        SpeedScaling(dg.DistanceMonitor(rig, robot=robot, detection_capability=0.04, invalid="neighbors"))
    assert error.value.field == "detection_capability"


def test_beyond_the_full_speed_distance_a_point_does_not_slow_the_robot(robot):
    surface = robot.with_surface_points(0.01)
    radii = surface.control_point_radii
    # one human speed at every separation: the full-speed distance is then the least (the default's near speed
    # makes it larger, which only asks a little farther)
    ssm = SpeedSeparationMonitor(SSMParams(human_speed_near=1.6), rho=5.0, braking=np.full(robot.n_joints, 10.0),
                                 reaches=robot.joint_reaches())
    rng = np.random.default_rng(3)
    for _ in range(20):
        _, jacobians = surface.control_point_kinematics(rng.uniform(robot.lower, robot.upper))
        speed, reaction = rng.uniform(0.1, 1.0, robot.n_joints), rng.uniform(0.05, 0.4)
        full = ssm.full_speed_distance(jacobians, speed, reaction, radii)
        assert ssm.speed_factor_within(full, jacobians, speed, reaction, radii=radii).factor == 1.0
        k = rng.integers(len(full))
        nearer = full.copy()
        nearer[k] *= 0.98
        assert ssm.speed_factor_within(nearer, jacobians, speed, reaction, radii=radii).factor < 1.0


@pytest.mark.parametrize("options, field", [
    (dict(joint_speed=1e300), "joint_speed"), (dict(joint_speed=0.0), "joint_speed"),
    (dict(joint_speed=float("nan")), "joint_speed"), (dict(joint_speed=float("inf")), "joint_speed"),
    (dict(joint_speed=0.5, braking=1e300), "braking"), (dict(joint_speed=0.5, braking=1e-300 * 0), "braking"),
    (dict(joint_speed=0.5, braking=float("nan")), "braking"), (dict(joint_speed=0.5, hold=float("inf")), "hold"),
    (dict(joint_speed=[0.5, 0.5]), "joint_speed"), (dict(joint_speed="fast"), "joint_speed")])
def test_joint_speeds_brakings_and_holds_that_are_not_real_are_refused_by_name(robot, options, field):
    from depthguard_lab.simulation import default_workcell

    monitor = dg.DistanceMonitor(default_workcell().scaled(0.25).rig, robot=robot, detection_capability=0.04)
    with pytest.raises(InputError) as error:
        SpeedScaling(monitor, **options)
    assert error.value.field == field


def test_the_joint_speeds_default_to_the_urdf_s_velocity_limits(robot):
    from depthguard_lab.simulation import default_workcell

    monitor = dg.DistanceMonitor(default_workcell().scaled(0.25).rig, robot=robot, detection_capability=0.04)
    assert SpeedScaling(monitor).joint_speed.tolist() == robot.velocity_limits.tolist()  # the iiwa's: 10 rad/s
