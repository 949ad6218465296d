"""Speed and separation monitoring (depthguard.avoidance._ssm; design §9, ISO/TS 15066).

The expected values are written out from the formula S_p = v_h (T_r + T_s) + v_r T_r + S_s + C + Z_d + Z_r with
S_s = v_r T_s / 2 (uniform deceleration) and ISO 13855's C and v_h, independently of the module's code.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from depthguard.avoidance._ssm import (
    SSMParams,
    SpeedSeparationMonitor,
    allowed_approach_speed,
    intrusion_distance,
    protective_separation_distance,
)
from depthguard.errors import InputError
from depthguard.results import DistanceResult, Flag

#: Tolerance of float comparisons, metres or m/s (the module lowers distances by 1e-12 m against rounding).
TOL = 1e-9


def sp_by_hand(p: SSMParams, v_r: float, T_r: float, separation: float) -> float:
    """S_p written out term by term, with C from ISO 13855 and v_h from the separation."""
    d = p.detection_capability
    C = 0.0 if d <= 0.014 else (8.0 * (d - 0.014) if d <= 0.040 else 0.85)
    v_h = p.human_speed_near if separation <= p.near_separation else p.human_speed
    v_r = max(v_r, 0.0)
    S_s = v_r * p.stopping_time / 2.0 + p.stopping_distance_extra
    return v_h * (T_r + p.stopping_time) + v_r * T_r + S_s + C + p.sensing_uncertainty + p.robot_uncertainty


def one_point(direction, velocity):
    """directions (1, 3) and a (1, 3, 3) Jacobian with dq = (1, 1, 1) giving the point the velocity ``velocity``."""
    J = np.zeros((1, 3, 3))
    J[0] = np.diag(velocity)
    return np.array([direction], dtype=float), J, np.ones(3)


def distance_for_speed(p, v, T_r):
    """The distance D (> near_separation for these numbers) at which the allowed speed is exactly v."""
    D = sp_by_hand(p, v, T_r, separation=math.inf)
    assert D > p.near_separation
    return D


# ------------------------------------------------------------------------------------------------ C and S_p


@pytest.mark.parametrize("d, C", [(0.0, 0.0), (0.014, 0.0), (0.03, 0.128), (0.04, 0.208), (0.0401, 0.85),
                                  (0.05, 0.85), (0.07, 0.85)])
def test_intrusion_distance(d, C):
    assert intrusion_distance(d) == pytest.approx(C, abs=1e-12)
    assert SSMParams(detection_capability=d).intrusion == pytest.approx(C, abs=1e-12)


def test_default_intrusion_is_a_hand():
    assert SSMParams().intrusion == pytest.approx(0.208, abs=1e-12)


def test_protective_distance_by_hand():
    p = SSMParams()
    # v_h 1.6 (separation 0.9 > 0.5), T_r 0.1, T_s 0.25, v_r 0.8:
    # 1.6 * 0.35 + 0.8 * 0.1 + 0.8 * 0.25 / 2 + 0.208 + 0.05 + 0.01
    expected = 0.56 + 0.08 + 0.1 + 0.208 + 0.05 + 0.01
    assert protective_separation_distance(p, 0.8, 0.1, separation=0.9) == pytest.approx(expected, abs=1e-12)
    assert expected == pytest.approx(1.008, abs=1e-12)

    q = SSMParams(human_speed=1.0, human_speed_near=1.5, near_separation=0.3, stopping_time=0.4,
                  stopping_distance_extra=0.02, detection_capability=0.03, sensing_uncertainty=0.1,
                  robot_uncertainty=0.0)
    # near (0.2 <= 0.3): 1.5 * 0.45 + 0.5 * 0.05 + (0.5 * 0.4 / 2 + 0.02) + 0.128 + 0.1 + 0
    expected = 0.675 + 0.025 + 0.12 + 0.128 + 0.1
    assert protective_separation_distance(q, 0.5, 0.05, separation=0.2) == pytest.approx(expected, abs=1e-12)


def test_human_speed_is_chosen_by_separation():
    p = SSMParams()
    T_r = 0.1
    near = protective_separation_distance(p, 0.3, T_r, separation=0.5)  # at 0.5 m: still "within 0.5 m"
    far = protective_separation_distance(p, 0.3, T_r, separation=0.5 + 1e-9)
    assert near - far == pytest.approx((2.0 - 1.6) * (T_r + 0.25), abs=1e-12)
    assert protective_separation_distance(p, 0.3, T_r) == near  # None: the conservative near speed
    assert protective_separation_distance(p, 0.3, T_r, separation=math.inf) == far


def test_moving_away_counts_as_standing_still():
    p = SSMParams()
    assert protective_separation_distance(p, -1.0, 0.1, 1.0) == protective_separation_distance(p, 0.0, 0.1, 1.0)
    assert protective_separation_distance(p, 0.1, 0.1, 1.0) > protective_separation_distance(p, 0.0, 0.1, 1.0)


def test_protective_distance_is_vectorised():
    p = SSMParams()
    speed = np.array([-0.5, 0.0, 0.3, 1.2])
    sep = np.array([0.1, 0.6, np.inf, 0.5])
    got = protective_separation_distance(p, speed, 0.07, separation=sep)
    assert isinstance(got, np.ndarray) and got.shape == (4,)
    for i in range(4):
        assert got[i] == pytest.approx(sp_by_hand(p, speed[i], 0.07, sep[i]), abs=1e-12)
    assert isinstance(protective_separation_distance(p, 0.3, 0.07, separation=0.2), float)


# ------------------------------------------------------------------------------------------------ allowed speed


@pytest.mark.parametrize("T_r", [0.0, 0.033, 0.1, 0.5])
def test_allowed_speed_inverts_protective_distance(T_r):
    p = SSMParams()
    distances = np.linspace(0.0, 3.0, 3001)
    allowed = allowed_approach_speed(p, distances, T_r)
    assert allowed.shape == distances.shape
    checked = 0
    for D, v in zip(distances, allowed):
        sp0 = sp_by_hand(p, 0.0, T_r, D)
        if v > 0:
            assert sp_by_hand(p, v, T_r, D) == pytest.approx(D, abs=TOL)
            assert protective_separation_distance(p, v, T_r, separation=D) <= D  # never above, even by rounding
            checked += 1
        else:
            assert D <= sp0 + TOL
        if D < sp0:
            assert v == 0.0
    assert checked > 1000  # most of the range fits


def test_allowed_speed_inf_and_scalar():
    p = SSMParams()
    assert allowed_approach_speed(p, math.inf, 0.1) == math.inf
    assert allowed_approach_speed(p, 0.0, 0.1) == 0.0
    D = 1.5
    expected = (D - (1.6 * 0.35 + 0.208 + 0.05 + 0.01)) / (0.1 + 0.25 / 2)
    got = allowed_approach_speed(p, D, 0.1)
    assert isinstance(got, float) and got == pytest.approx(expected, abs=TOL)


# ------------------------------------------------------------------------------------------------ speed factor


def test_moving_away_is_never_slowed():
    monitor = SpeedSeparationMonitor(rho=np.inf)
    directions, J, dq = one_point([1.0, 0.0, 0.0], [2.0, 0.0, 0.0])  # away from the obstacle at 2 m/s
    for D in (0.0, 0.01, 0.3, 2.0):
        verdict = monitor.speed_factor(np.array([D]), directions, J, dq, 0.1)
        assert verdict.factor == 1.0 and verdict.limiting == -1
        assert verdict.approach_speed[0] == pytest.approx(-2.0, abs=1e-12)


def test_tangential_motion_is_not_slowed():
    monitor = SpeedSeparationMonitor(rho=np.inf)
    directions, J, dq = one_point([1.0, 0.0, 0.0], [0.0, 1.0, 0.5])
    verdict = monitor.speed_factor(np.array([0.01]), directions, J, dq, 0.1)
    assert verdict.factor == 1.0 and verdict.approach_speed[0] == 0.0


def test_approaching_inside_the_protective_distance_stops():
    p = SSMParams()
    monitor = SpeedSeparationMonitor(p, rho=np.inf)
    directions, J, dq = one_point([1.0, 0.0, 0.0], [-0.05, 0.0, 0.0])
    D = sp_by_hand(p, 0.0, 0.1, 0.9) - 1e-6
    verdict = monitor.speed_factor(np.array([D]), directions, J, dq, 0.1)
    assert verdict.factor == 0.0 and verdict.limiting == 0
    assert verdict.allowed_speed[0] == 0.0


def test_factor_one_half():
    p = SSMParams()
    monitor = SpeedSeparationMonitor(p, rho=np.inf)
    v, T_r = 1.0, 0.1
    D = distance_for_speed(p, v / 2, T_r)  # 0.9405 m
    directions, J, dq = one_point([1.0, 0.0, 0.0], [-v, 0.0, 0.0])
    verdict = monitor.speed_factor(np.array([D]), directions, J, dq, T_r)
    assert verdict.factor == pytest.approx(0.5, abs=TOL) and verdict.factor <= 0.5
    assert verdict.limiting == 0
    assert verdict.approach_speed[0] == pytest.approx(v, abs=1e-12)
    assert verdict.allowed_speed[0] == pytest.approx(v / 2, abs=TOL)
    assert verdict.protective_distance[0] == pytest.approx(D, abs=TOL) and verdict.protective_distance[0] <= D


def test_two_points_take_the_minimum():
    p = SSMParams()
    monitor = SpeedSeparationMonitor(p, rho=np.inf)
    T_r = 0.05
    D = np.array([distance_for_speed(p, 0.5, T_r), distance_for_speed(p, 0.25, T_r)])  # each allows factor 0.5, 0.25
    directions = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, -1.0]])
    J = np.zeros((2, 3, 2))
    J[0, 1, 0] = -1.0  # joint 0 moves point 0 towards its obstacle at 1 m/s
    J[1, 2, 1] = 1.0  # joint 1 moves point 1 towards its obstacle at 1 m/s
    dq = np.array([1.0, 1.0])
    verdict = monitor.speed_factor(D, directions, J, dq, T_r)
    assert verdict.factor == pytest.approx(0.25, abs=TOL) and verdict.limiting == 1
    assert np.allclose(verdict.approach_speed, [1.0, 1.0], atol=1e-12)
    alone = [monitor.speed_factor(D[i:i + 1], directions[i:i + 1], J[i:i + 1], dq, T_r).factor for i in range(2)]
    assert alone == pytest.approx([0.5, 0.25], abs=TOL)


def test_inf_distance_imposes_nothing():
    monitor = SpeedSeparationMonitor(rho=np.inf)
    directions, J, dq = one_point([1.0, 0.0, 0.0], [-3.0, 0.0, 0.0])
    verdict = monitor.speed_factor(np.array([np.inf]), directions, J, dq, 0.1)
    assert verdict.factor == 1.0 and verdict.limiting == -1 and verdict.allowed_speed[0] == np.inf
    verdict = monitor.speed_factor(np.array([np.inf]), np.zeros((1, 3)), J, dq, 0.1)  # unknown direction too
    assert verdict.factor == 1.0


def test_unknown_direction_counts_the_whole_speed():
    p = SSMParams()
    monitor = SpeedSeparationMonitor(p, rho=np.inf)
    T_r = 0.1
    D = distance_for_speed(p, 0.5, T_r)
    _, J, dq = one_point([0.0, 0.0, 0.0], [0.0, 0.6, 0.8])  # |velocity| = 1 m/s
    verdict = monitor.speed_factor(np.array([D]), np.zeros((1, 3)), J, dq, T_r)
    assert verdict.approach_speed[0] == pytest.approx(1.0, abs=1e-12)
    assert verdict.factor == pytest.approx(0.5, abs=TOL)
    # the same motion with a known direction perpendicular to it is not slowed
    verdict = monitor.speed_factor(np.array([D]), np.array([[1.0, 0.0, 0.0]]), J, dq, T_r)
    assert verdict.factor == 1.0
    # distance 0 with the zero direction (inside an obstacle or unseen): any motion stops
    verdict = monitor.speed_factor(np.array([0.0]), np.zeros((1, 3)), J, 1e-6 * dq, T_r)
    assert verdict.factor == 0.0


def test_distance_result_is_accepted():
    p = SSMParams()
    monitor = SpeedSeparationMonitor(p, rho=np.inf)
    D = np.array([distance_for_speed(p, 0.5, 0.1), 0.2, np.inf])
    directions = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    rng = np.random.default_rng(1)
    J = rng.normal(size=(3, 3, 7))
    dq = rng.normal(size=7)
    result = DistanceResult(distance=D, direction=directions, count=np.ones(3, dtype=np.int64),
                            invalid_count=np.zeros(3, dtype=np.int64), flags=(Flag(0),) * 3)
    a = monitor.speed_factor(result, None, J, dq, 0.1)
    b = monitor.speed_factor(D, directions, J, dq, 0.1)
    assert a.factor == b.factor and a.limiting == b.limiting
    assert np.array_equal(a.approach_speed, b.approach_speed)
    with pytest.raises(InputError) as info:
        monitor.speed_factor(result, directions, J, dq, 0.1)
    assert info.value.field == "directions"


def test_no_points():
    verdict = SpeedSeparationMonitor(rho=np.inf).speed_factor(np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3, 7)),
                                                    np.ones(7), 0.1)
    assert verdict.factor == 1.0 and verdict.limiting == -1 and verdict.approach_speed.shape == (0,)


# ------------------------------------------------------------------------------------------------ properties


def random_params(rng) -> SSMParams:
    if rng.random() < 0.5:
        return SSMParams()
    human = rng.uniform(0.0, 2.0)
    return SSMParams(human_speed=human, human_speed_near=human + rng.uniform(0.0, 1.0),
                     near_separation=rng.uniform(0.0, 1.0), stopping_time=rng.uniform(0.01, 1.0),
                     stopping_distance_extra=rng.uniform(0.0, 0.1), detection_capability=rng.uniform(0.0, 0.07),
                     sensing_uncertainty=rng.uniform(0.0, 0.1), robot_uncertainty=rng.uniform(0.0, 0.05))


def random_case(rng):
    p = random_params(rng)
    T_r = 0.0 if rng.random() < 0.1 else rng.uniform(0.0, 0.3)
    m, n = int(rng.integers(1, 10)), 7
    J = rng.normal(0.0, 0.5, size=(m, 3, n))
    dq = np.zeros(n) if rng.random() < 0.03 else rng.normal(0.0, 1.0, size=n)
    directions = rng.normal(size=(m, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    directions[rng.random(m) < 0.1] = 0.0
    truth = rng.uniform(0.0, 2.5, size=m)
    truth[rng.random(m) < 0.1] = np.inf
    truth[rng.random(m) < 0.03] = 0.0
    error = np.where(rng.random(m) < 0.3, 0.0, rng.uniform(0.0, 0.3, size=m))  # often exact: the boundary case
    reported = np.maximum(truth - error, 0.0)
    at_boundary = rng.random(m) < 0.05  # reported exactly S_p(0)
    reported[at_boundary] = [sp_by_hand(p, 0.0, T_r, 0.0) for _ in range(int(at_boundary.sum()))]
    truth = np.maximum(truth, reported)
    return p, T_r, J, dq, directions, truth, reported


def approach_by_hand(J, dq, directions, distances):
    velocity = np.array([Ji @ dq for Ji in J]).reshape(-1, 3)
    v = np.array([-(d @ w) for d, w in zip(directions, velocity)])
    for i in range(len(v)):
        if not directions[i].any() and np.isfinite(distances[i]):
            v[i] = np.linalg.norm(velocity[i])
    return v


def test_random_cases_keep_the_separation():
    rng = np.random.default_rng(20240611)
    stats = {"stopped": 0, "slowed": 0, "free": 0}
    for _ in range(1000):
        p, T_r, J, dq, directions, truth, reported = random_case(rng)
        monitor = SpeedSeparationMonitor(p, rho=np.inf)
        verdict = monitor.speed_factor(reported, directions, J, dq, T_r)
        k = verdict.factor
        v = approach_by_hand(J, dq, directions, reported)
        assert np.allclose(verdict.approach_speed, v, atol=1e-12, rtol=0)
        assert 0.0 <= k <= 1.0
        approaching = (v > 0) & np.isfinite(reported)
        allowed = verdict.allowed_speed

        # the scaled command respects every point's allowed speed
        assert np.all(k * v <= allowed + TOL)
        # S_p at the scaled speed never exceeds the reported distance of a point that still approaches (no tolerance)
        moving = approaching & (k * v > 0)
        assert np.all(verdict.protective_distance[moving] <= reported[moving])

        # a twin: the factor from the formula written out
        k_twin = 1.0
        for i in np.flatnonzero(approaching):
            fits = reported[i] - sp_by_hand(p, 0.0, T_r, reported[i])
            k_twin = min(k_twin, max(fits, 0.0) / (T_r + p.stopping_time / 2) / v[i])
        assert k == pytest.approx(k_twin, abs=TOL)

        sp0 = np.array([sp_by_hand(p, 0.0, T_r, D) for D in reported])
        if np.any(approaching & (reported < sp0)):
            assert k == 0.0
        if not approaching.any():
            assert k == 1.0 and verdict.limiting == -1
        if k < 1.0:
            assert approaching[verdict.limiting]

        # the judge: where the TRUE distance is below S_p at the commanded approach speed, the point does not approach
        for i in np.flatnonzero(approaching):
            if truth[i] < sp_by_hand(p, k * v[i], T_r, truth[i]):
                assert k * v[i] == 0.0

        # the fast path answers the same
        fast = monitor.speed_factor(reported, directions, J, dq, T_r, check=False)
        assert fast.factor == k and fast.limiting == verdict.limiting

        stats["stopped" if k == 0 else "slowed" if k < 1 else "free"] += 1
    # the cases cover all three outcomes (otherwise the properties above were tested on nothing)
    assert min(stats.values()) > 50, stats


# ------------------------------------------------------------------------------------------------ looking ahead
#
# The judge: a cloud of possibly occupied points, known exactly. SSM sees only distances from the cloud (at the point
# and at the point looked ahead to, each possibly reported smaller than the truth, as a conservative monitor does) and
# no direction; every point of the cloud that the scaled command approaches must keep S_p's condition with its own
# exact direction and distance.


def cloud_distance(x, cloud, radius=0.0):
    """Exact distance from x (3,) to the nearest point of the (N, 3) cloud, minus a sphere's radius (>= 0)."""
    return max(float(np.min(np.linalg.norm(cloud - x, axis=1))) - radius, 0.0)


def lookahead_verdict(monitor, P, velocity, cloud, T_r, radius=0.0, under=(0.0, 0.0)):
    """SSM's verdict for one point P (3,) moving at ``velocity`` (3,) m/s, told only distances to the cloud (reported
    ``under`` = (metres, metres) below the truth at P and ahead), with an unknown direction."""
    J = np.diag(velocity)[None]
    T = monitor.lookahead_time(T_r)
    D = max(cloud_distance(P, cloud, radius) - under[0], 0.0)
    ahead = max(cloud_distance(P + T * velocity, cloud, radius) - under[1], 0.0)
    return monitor.speed_factor(np.array([D]), np.zeros((1, 3)), J, np.ones(3), T_r, ahead=np.array([ahead]))


def test_looking_ahead_keeps_every_occupied_point_s_separation():
    rng = np.random.default_rng(20261125)
    stats = {"certified": 0, "stopped": 0, "slowed": 0}
    for _ in range(1500):
        p = random_params(rng)
        T_r = rng.uniform(0.0, 0.3)
        radius = 0.0 if rng.random() < 0.3 else rng.uniform(0.0, 0.12)
        P = np.zeros(3)
        centre = rng.normal(size=3)
        centre *= rng.uniform(0.3, 2.5) / np.linalg.norm(centre)
        cloud = centre + rng.normal(scale=rng.uniform(0.01, 0.8), size=(int(rng.integers(1, 60)), 3))
        velocity = rng.normal(size=3) * rng.uniform(0.0, 2.0)
        if rng.random() < 0.3:  # straight away from the cloud's centre
            velocity = -centre / np.linalg.norm(centre) * rng.uniform(0.0, 2.0)
        under = (0.0, 0.0) if rng.random() < 0.5 else tuple(rng.uniform(0.0, 0.2, size=2))
        monitor = SpeedSeparationMonitor(p, rho=np.inf)
        verdict = lookahead_verdict(monitor, P, velocity, cloud, T_r, radius, under)
        k = verdict.factor
        for q in cloud:  # the judge: each occupied point with its exact direction and distance
            d = max(np.linalg.norm(q - P) - radius, 0.0)
            u = (q - P) / max(np.linalg.norm(q - P), 1e-300)
            approach = k * float(velocity @ u)
            if approach > 1e-12:
                assert d >= sp_by_hand(p, approach, T_r, d) - TOL, (d, approach, k, bool(verdict.certified[0]))
        stats["certified" if verdict.certified[0] else "stopped" if k == 0.0 else "slowed"] += 1
    assert min(stats.values()) > 100, stats


def test_moving_straight_away_from_everything_is_not_slowed():
    """A point moving straight away from a person (a ball of points) is not slowed while it is beyond S_p at rest,
    however fast; sideways at that distance it is, as if it approached at its whole speed."""
    p = SSMParams()
    T_r = 0.1
    monitor = SpeedSeparationMonitor(p, rho=np.inf)
    rng = np.random.default_rng(3)
    ball = rng.normal(size=(400, 3))
    ball = 0.25 * ball / np.linalg.norm(ball, axis=1, keepdims=True) + [0.0, 0.0, 0.0]  # a 0.25 m sphere's surface
    at_rest = sp_by_hand(p, 0.0, T_r, 1.0)
    for gap in (at_rest + 1e-3, at_rest + 0.1, 2.0):
        P = np.array([0.25 + gap, 0.0, 0.0])  # the sphere's nearest point is at x = 0.25
        for speed in (0.1, 0.5, 2.0):
            verdict = lookahead_verdict(monitor, P, np.array([speed, 0.0, 0.0]), ball, T_r)
            assert verdict.factor == 1.0 and verdict.certified[0], (gap, speed)
    P = np.array([0.25 + at_rest + 0.05, 0.0, 0.0])
    sideways = lookahead_verdict(monitor, P, np.array([0.0, 1.0, 0.0]), ball, T_r)
    assert not sideways.certified[0] and sideways.factor < 1.0
    towards = lookahead_verdict(monitor, P, np.array([-1.0, 0.0, 0.0]), ball, T_r)
    assert not towards.certified[0] and towards.factor == pytest.approx(sideways.factor)
    # nearer than S_p at rest, the distances cannot tell away from towards: it stops
    P = np.array([0.25 + at_rest - 0.01, 0.0, 0.0])
    assert lookahead_verdict(monitor, P, np.array([1.0, 0.0, 0.0]), ball, T_r).factor == 0.0


def test_looking_ahead_to_nothing_within_rho():
    """ahead = inf says only that nothing is within rho of the point looked ahead to: it counts as rho."""
    p = SSMParams()
    directions, J, dq = one_point([0.0, 0.0, 0.0], [1.0, 0.0, 0.0])
    D = np.array([2.0])
    at_rest = sp_by_hand(p, 0.0, 0.1, 2.0)
    T = SpeedSeparationMonitor(p, rho=1.0).lookahead_time(0.1)
    assert T == pytest.approx(0.1 + p.stopping_time / 2)
    for rho, certified in ((at_rest + T * 1.0 + 1e-6, True), (at_rest + T * 1.0 - 1e-6, False)):
        verdict = SpeedSeparationMonitor(p, rho=rho).speed_factor(np.array([np.inf]), directions, J, dq, 0.1,
                                                                  ahead=np.array([np.inf]))
        assert bool(verdict.certified[0]) is certified
        assert (verdict.factor == 1.0) is certified or verdict.factor == 1.0
    assert SpeedSeparationMonitor(p, rho=np.inf).speed_factor(D, directions, J, dq, 0.1,
                                                              ahead=np.array([np.inf])).certified[0]
    # without ahead, nothing is certified
    assert not SpeedSeparationMonitor(p, rho=np.inf).speed_factor(D, directions, J, dq, 0.1).certified.any()


def test_a_depth_camera_lets_a_point_move_away_from_a_person_unslowed():
    """The look-ahead on a depth camera's distances (what it counts occupied: the person, the space they hide, the
    edge of the view): a point 0.85 m beside a person (a 0.25 m ball), just beyond S_p at rest, moving away at 1 m/s
    is not slowed (factor 1; without looking ahead 0.075); moving towards them or sideways it is, to what its distance
    allows at its whole speed."""
    import depthguard as dg
    from depthguard.scenes import Box, Sphere, render_depth, scene_distance

    camera = dg.PinholeCamera("cam", 320, 240, 262.5, 262.5, 159.5, 119.5, np.eye(4), depth_range=(0.2, 10.0),
                              noise=dg.NoiseModel.none())
    person = Sphere((-0.8, 0.0, 4.0), 0.25)
    occupancy = dg.prepare_depth(dg.depth_image(render_depth(
        camera, [person, Box.from_bounds([-9, -9, 8.0], [9, 9, 8.1])]), camera), camera)
    T_r, rho = 0.1, 2.0
    monitor = SpeedSeparationMonitor(SSMParams(), rho=rho)
    T = monitor.lookahead_time(T_r)
    P = np.array([0.3, 0.0, 4.0])
    factors = {}
    for name, velocity in (("away", [1.0, 0.0, 0.0]), ("towards", [-1.0, 0.0, 0.0]), ("sideways", [0.0, 1.0, 0.0])):
        velocity = np.array(velocity)
        D, ahead = dg.single_camera_distances(occupancy, np.array([P, P + T * velocity]), rho, "min").distance
        assert D <= scene_distance([person], P[None])[0] + 1e-9
        J = np.diag(velocity)[None]
        verdict = monitor.speed_factor(np.array([D]), np.zeros((1, 3)), J, np.ones(3), T_r, ahead=np.array([ahead]))
        blind = monitor.speed_factor(np.array([D]), np.zeros((1, 3)), J, np.ones(3), T_r)
        factors[name] = (verdict.factor, blind.factor, bool(verdict.certified[0]))
    assert factors["away"] == (1.0, pytest.approx(factors["towards"][1]), True), factors
    assert 0.0 < factors["away"][1] < 0.2  # without looking ahead, moving away was slowed as much as approaching (0.075)
    for name in ("towards", "sideways"):
        assert factors[name][0] == factors[name][1] < 0.5 and not factors[name][2], factors


@pytest.mark.parametrize("ahead", [np.array([0.5]), np.array([0.5, math.nan]), np.array([0.5, -0.1]),
                                   np.array([0.5, -math.inf]), np.zeros((2, 1)), "far"])
def test_bad_ahead(ahead):
    args = good_args()
    with pytest.raises(InputError) as info:
        SpeedSeparationMonitor(rho=np.inf).speed_factor(*args, ahead=ahead)
    assert info.value.field == "ahead"


# ------------------------------------------------------------------------------------------------ bad inputs


def good_args(m=2, n=7):
    rng = np.random.default_rng(0)
    directions = np.array([[1.0, 0.0, 0.0]] * m)
    return [np.full(m, 0.5), directions, rng.normal(size=(m, 3, n)), rng.normal(size=n), 0.1]


@pytest.mark.parametrize("reaction_time", [math.nan, math.inf, -0.01, "0.1", True, None, np.array([0.1])])
def test_bad_reaction_time(reaction_time):
    p = SSMParams()
    args = good_args()
    args[4] = reaction_time
    calls = [lambda: SpeedSeparationMonitor(p, rho=np.inf).speed_factor(*args),
             lambda: protective_separation_distance(p, 0.1, reaction_time),
             lambda: allowed_approach_speed(p, 1.0, reaction_time)]
    for call in calls:
        with pytest.raises(InputError) as info:
            call()
        assert info.value.field == "reaction_time"


@pytest.mark.parametrize("name", ["human_speed", "human_speed_near", "near_separation", "stopping_time",
                                  "stopping_distance_extra", "detection_capability", "sensing_uncertainty",
                                  "robot_uncertainty"])
@pytest.mark.parametrize("value", [-0.1, math.nan, math.inf, 1e6, "1", None])
def test_bad_params(name, value):
    with pytest.raises(InputError) as info:
        SSMParams(**{name: value})
    assert info.value.field == name and name in str(info.value)


def test_bad_params_relations():
    with pytest.raises(InputError) as info:
        SSMParams(stopping_time=0.0)  # a robot does not stop in no time
    assert info.value.field == "stopping_time"
    with pytest.raises(InputError) as info:
        SSMParams(human_speed=2.5)  # faster far than near
    assert info.value.field == "human_speed_near"
    with pytest.raises(InputError) as info:
        SpeedSeparationMonitor({"human_speed": 1.6}, rho=0.4)
    assert info.value.field == "params"
    with pytest.raises(InputError) as info:
        protective_separation_distance(None, 0.1, 0.1)
    assert info.value.field == "params"


@pytest.mark.parametrize("d", [math.nan, -0.01, 2.0, "0.04", 0.0701, 0.3, math.inf])
def test_bad_detection_capability(d):
    """ISO 13855 defines C up to d = 70 mm only: a coarser detection capability is refused, never given C = 0.85 m."""
    with pytest.raises(InputError) as info:
        intrusion_distance(d)
    assert info.value.field == "detection_capability"
    with pytest.raises(InputError) as info:
        SSMParams(detection_capability=d)
    assert info.value.field == "detection_capability"


@pytest.mark.parametrize("index, value, field", [
    (0, np.full((2, 1), 0.5), "distances"),
    (0, np.array([0.5, math.nan]), "distances"),
    (0, np.array([0.5, -0.1]), "distances"),
    (0, np.array([0.5, -math.inf]), "distances"),
    (0, np.array(["a", "b"]), "distances"),
    (1, np.zeros((2, 2)), "directions"),
    (1, np.zeros((3, 3)), "directions"),
    (1, np.array([[2.0, 0.0, 0.0], [1.0, 0.0, 0.0]]), "directions"),
    (1, np.array([[math.nan, 0.0, 0.0], [1.0, 0.0, 0.0]]), "directions"),
    (2, np.zeros((2, 3)), "jacobians"),
    (2, np.zeros((3, 3, 7)), "jacobians"),
    (2, np.zeros((2, 2, 7)), "jacobians"),
    (2, np.full((2, 3, 7), math.inf), "jacobians"),
    (3, np.zeros(6), "dq"),
    (3, np.zeros((7, 1)), "dq"),
    (3, np.full(7, math.nan), "dq"),
])
def test_bad_speed_factor_arrays(index, value, field):
    args = good_args()
    args[index] = value
    with pytest.raises(InputError) as info:
        SpeedSeparationMonitor(rho=np.inf).speed_factor(*args)
    assert info.value.field == field


def test_bad_formula_arrays():
    p = SSMParams()
    for call, field in [(lambda: protective_separation_distance(p, math.nan, 0.1), "approach_speed"),
                        (lambda: protective_separation_distance(p, 0.1, 0.1, separation=-1.0), "separation"),
                        (lambda: protective_separation_distance(p, 0.1, 0.1, separation=math.nan), "separation"),
                        (lambda: protective_separation_distance(p, np.zeros(3), 0.1, np.zeros(2)), "separation"),
                        (lambda: allowed_approach_speed(p, -0.1, 0.1), "distance"),
                        (lambda: allowed_approach_speed(p, [1.0, math.nan], 0.1), "distance")]:
        with pytest.raises(InputError) as info:
            call()
        assert info.value.field == field


def test_nothing_within_rho_counts_as_rho_from_anywhere():
    """The monitor says only that nothing is within rho: SSM must take the obstacle at rho, direction unknown."""
    p = SSMParams()
    rho = 0.9
    J = np.zeros((1, 3, 2))
    J[0, 0, 0] = 1.0  # joint 0 moves the point along +x at 1 m/s per rad/s
    dq = np.array([1.0, 0.0])
    allowed = allowed_approach_speed(p, rho, 0.05)
    for direction in ([1.0, 0.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 0.0]):  # ignored: unknown beyond rho
        verdict = SpeedSeparationMonitor(p, rho=rho).speed_factor(np.array([np.inf]), np.array([direction]), J, dq,
                                                                  0.05)
        assert verdict.factor == pytest.approx(min(1.0, allowed / 1.0))
    # below the protective distance at standstill, a rho that small stops every motion
    assert SpeedSeparationMonitor(p, rho=0.4).speed_factor(np.array([np.inf]), np.zeros((1, 3)), J, dq,
                                                           0.05).factor == 0.0
    with pytest.raises(InputError):
        SpeedSeparationMonitor(p, rho=0.0)
