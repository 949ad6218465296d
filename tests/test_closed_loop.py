"""The avoidance loop in simulated time (issue 9): cameras at 30 Hz, control at 500 Hz, judged by the exact ground
truth (coal between the robot's collision meshes and the person)."""

from importlib import resources
from pathlib import Path

import numpy as np
import pytest

from depthguard.avoidance import JointLimits
from depthguard_lab.simulation import load_workcell
from depthguard_lab.simulation._closed_loop import LoopSettings, run_closed_loop

#: The person reaches into the end-effector (no standoff): without avoidance the hand meets the robot at about 3.0 s.
CONTACT_WINDOW = (1.9, 1.3)  # start, duration (s)
CLEARANCE = 0.05  # metres the avoidance must keep between the robot's meshes and the person in that window
#: Reversals of the reaction per second (the demo's oscillation_per_s: the repulsive velocity turning by more than
#: 90 degrees between control steps, or SSM's speed factor crossing 0.5) that a run may have: at most one every 0.5 s.
OSCILLATION_BOUND = 2.0


@pytest.fixture(scope="module")
def reach_workcell():
    return load_workcell(_packaged("scenario_b_reach.yaml"))


#: The person has left (every control point truly farther than 0.4 m for good); the task must be back within 1 cm of
#: its path this soon after (measured: reach 0.76 s with two cameras, 0.70 s with four; board 0.91 s, 0.78 s).
RESUME_WITHIN = 1.2
#: metres: the median task error from then on may be at most this.
RESUMED_MEDIAN = 0.015


@pytest.fixture(scope="module")
def runs(reach_workcell):
    """Modes none and avoid over the contact window; the avoidance on to the scene's end (the person walks away).
    SSM cannot run soundly in these cells (test_ssm_is_refused_where_its_distances_can_hide_more_than_iso_covers)."""
    start, duration = CONTACT_WINDOW
    logs = {"none": run_closed_loop(reach_workcell, "none", start=start, duration=duration, measure=False)}
    logs["avoid"] = run_closed_loop(reach_workcell, "avoid", start=start)
    return logs


@pytest.mark.slow
def test_without_avoidance_the_hand_meets_the_robot_and_with_it_the_robot_keeps_clear(runs):
    assert runs["none"].clearance.min() <= 0.0
    assert runs["avoid"].clearance.min() >= CLEARANCE


@pytest.mark.slow
@pytest.mark.parametrize("scene", ["reach", "board", "elbow"])
def test_the_task_resumes_after_the_person_has_left(runs, board_runs, elbow_runs, scene):
    """Issue 9: after the avoidance the end-effector's task resumes, its error back below 1 cm within RESUME_WITHIN
    of the obstacle leaving (the reaching hand at about 3.4 s; the board, carried back, at about 3.9 s; the box,
    taken off its stand, at 4.8 s), and near it from then on. This needs the loop's robot zone
    (config.LOOP_ROBOT_ZONE): without it the uncleared shell round the links kept the arm pushed 0.1-0.44 m off its
    path after the person had gone. What is left pushes it 1-3 cm off now and then (median RESUMED_MEDIAN at most;
    measured 0.8-1.1 cm): in about one frame in six, sensor dropouts at the robot's own silhouette in three of four
    cameras leave cells 5 cm beyond the zone uncleared, 0.12-0.15 m from the elbow's control points. The elbow
    scenario has bounds of its own (ELBOW_RESUME): the arm comes back from 0.39 m off its path, not 0.1-0.2 m, and in
    its posture the same phantoms keep more of the arm's points within reach (measured: back 1.19 s after the box
    left, median error after 1.75 cm, two cameras)."""
    from depthguard_lab.experiments.avoidance_demo import resumption

    log = {"reach": runs, "board": board_runs, "elbow": elbow_runs}[scene]["avoid"]
    within, median_bound = ELBOW_RESUME if scene == "elbow" else (RESUME_WITHIN, RESUMED_MEDIAN)
    assert log.times[-1] > 5.4  # the run lasts until the person is gone
    assert log.task_error.max() > 0.1  # the avoidance did take the end-effector off its path
    left, resumed, median = resumption(log)
    assert left is not None and left < log.times[-1] - 1.0, left
    assert resumed is not None and resumed <= within, resumed
    assert median < median_bound, median


#: The board is carried face first into the end-effector's path, edge-on to the principal camera
#: (scenario_b_board.yaml): without avoidance the end-effector meets it at about 2.7 s.
BOARD_WINDOW = (1.6, 1.6)


def _packaged(name: str) -> Path:
    return Path(str(resources.files("depthguard_lab.simulation").joinpath(name)))


def _every_mode(name: str, window, to_the_end=(), windows=None) -> dict:
    """The packaged scene ``name`` run in closed loop over ``window`` (start, duration) in each mode; the modes in
    ``to_the_end`` run from the window's start to the scene's end; ``windows``: mode -> a window of its own."""
    workcell = load_workcell(_packaged(name))
    windows = {**{mode: window for mode in ("none", "avoid")}, **(windows or {})}
    return {mode: run_closed_loop(workcell, mode, start=start, duration=None if mode in to_the_end else duration,
                                  measure=mode != "none")  # the task alone reads no distance
            for mode, (start, duration) in windows.items()}


@pytest.fixture(scope="module")
def board_runs():
    """Modes none and avoid over BOARD_WINDOW; the avoidance on to the scene's end (the person steps back with the
    board at 3.6 s)."""
    return _every_mode("scenario_b_board.yaml", BOARD_WINDOW, to_the_end=("avoid",))


@pytest.mark.slow
def test_a_board_the_principal_camera_sees_edge_on_is_avoided(board_runs):
    """The second avoidance scenario: a flat object approaching the end-effector, mostly hidden from the principal
    camera (it sees the board's 2 cm edge; the second camera its face). The fused cameras find it."""
    from depthguard_lab.experiments.avoidance_demo import summarize

    assert board_runs["none"].clearance.min() <= 0.0
    for mode in ("avoid",):
        log = board_runs[mode]
        assert log.clearance.min() >= CLEARANCE, (mode, log.clearance.min())
        assert summarize(log, 1.0 / LoopSettings().control_rate)["oscillation_per_s"] <= OSCILLATION_BOUND


#: The box is put on the arm's path (scenario_b_elbow.yaml) at about 2.6 s, 0.09 m above the forearm; without avoidance
#: the rising forearm meets it at about 4.1 s. Clearance stated for this scenario: the papers' avoidance bounds the
#: joints by the distances of control points on the links' axes, which does not keep a link's surface 5 cm from a box
#: it passes under (measured with the papers' parameterisation: 0.021 m; with the loop's defaults, distances from the
#: links' surfaces: 0.087 m with avoid, 0.090 m with ssm; benchmarks/bench_avoidance_scenarios.py).
ELBOW_WINDOW = (2.4, 2.6)
#: The window of modes none and ssm: from 0.9 s before the unguarded meeting (4.1 s) to 0.2 s after (SSM holds the
#: same clearance as over ELBOW_WINDOW, 0.090 m, and its control step is the slowest here).
ELBOW_MEETING = (3.2, 1.1)
ELBOW_CLEARANCE = 0.01
#: The elbow scenario's task comes back within this many seconds of the box leaving, with the median error after it at
#: most this many metres (see test_the_task_resumes_after_the_person_has_left).
ELBOW_RESUME = (1.5, 0.025)


@pytest.fixture(scope="module")
def elbow_runs():
    """Modes none and avoid over ELBOW_WINDOW; the avoidance on to the scene's end (the box is taken away at
    4.8 s)."""
    return _every_mode("scenario_b_elbow.yaml", ELBOW_WINDOW, to_the_end=("avoid",), windows={"none": ELBOW_MEETING})


@pytest.mark.slow
def test_a_box_on_the_elbows_path_is_avoided_by_the_arm(elbow_runs):
    """The third avoidance scenario (the 2015 paper's scenario 3): without avoidance the forearm meets the box while
    the end-effector stays clear of it, so only the other control points can keep the arm away; with either mode it
    stays ELBOW_CLEARANCE clear, without oscillating."""
    from depthguard_lab.experiments.avoidance_demo import summarize

    none = elbow_runs["none"]
    assert none.clearance.min() <= 0.0
    contact = none.truth_steps[none.clearance <= 0.0]
    assert np.all(none.truth[np.isin(none.truth_steps, contact), -1] > 0.1)  # the end-effector is not what meets it
    for mode in ("avoid",):
        log = elbow_runs[mode]
        assert log.clearance.min() >= ELBOW_CLEARANCE, (mode, log.clearance.min())
        assert summarize(log, 1.0 / LoopSettings().control_rate)["oscillation_per_s"] <= OSCILLATION_BOUND


@pytest.mark.slow
def test_four_cameras_keep_the_reaching_hand_clear_too(reach_workcell):
    """Issue 9 asks for each scenario with the four-camera layout of issue 8 as well (scenario_b_four.yaml's room
    corners; the three scenarios in both layouts: benchmarks/bench_avoidance_scenarios.py)."""
    four = load_workcell(_packaged("scenario_b_reach.yaml"), layout=_packaged("scenario_b_four.yaml"))
    assert len(four.rig.cameras) == 4
    start, duration = CONTACT_WINDOW
    log = run_closed_loop(four, "avoid", start=start, duration=duration)
    assert log.clearance.min() >= CLEARANCE, log.clearance.min()


@pytest.mark.slow
def test_distances_from_the_links_surface_keep_the_arm_clear_of_the_box_with_four_cameras():
    """With four cameras the papers' avoidance lets the forearm pass 1 mm under the elbow scenario's box
    (benchmarks/bench_avoidance_scenarios.py --papers); measuring each control point's distance from its link's
    surface (AvoidanceParams(from_surface=True), the loop's default) keeps it CLEARANCE away (measured: 0.086 m)."""
    from depthguard.avoidance import AvoidanceParams

    four = load_workcell(_packaged("scenario_b_elbow.yaml"), layout=_packaged("scenario_b_four.yaml"))
    start, duration = ELBOW_WINDOW
    log = run_closed_loop(four, "avoid", start=start, duration=duration,
                          settings=LoopSettings(avoidance=AvoidanceParams(from_surface=True)))
    assert log.clearance.min() >= CLEARANCE, log.clearance.min()


def test_the_task_alone_runs_the_same_without_measuring(reach_workcell):
    """Mode none's commands read no distance: run with measure=False (no monitor), its joints, commands and truth
    are those of the measured run, and it reports what a loop reports before its first set."""
    start = CONTACT_WINDOW[0]
    measured = run_closed_loop(reach_workcell, "none", start=start, duration=0.2)
    alone = run_closed_loop(reach_workcell, "none", start=start, duration=0.2, measure=False)
    np.testing.assert_array_equal(alone.q, measured.q)
    np.testing.assert_array_equal(alone.dq, measured.dq)
    np.testing.assert_array_equal(alone.clearance, measured.clearance)
    assert np.isfinite(measured.data_age).any() and not np.isfinite(alone.data_age).any()
    assert np.all(alone.reported == 0.0)


def test_the_board_is_mostly_hidden_from_the_principal_camera():
    from depthguard_lab.simulation import simulate

    workcell = load_workcell(_packaged("scenario_b_board.yaml"))
    board = [name for name, _ in workcell.labels()].index("board")
    (frame,) = simulate(workcell, frames=[84])  # 2.8 s: the board stands in the end-effector's path
    seen = {camera: int(np.count_nonzero(label == board)) for camera, label in frame.label.items()}
    assert seen["second"] > 2000 and seen["principal"] < seen["second"] / 4, seen


@pytest.mark.parametrize("layout, capability", [("scenario_b.yaml", False), ("scenario_b_ssm.yaml", True),
                                                 ("scenario_b_ssm.yaml", False)])
def test_ssm_is_refused_where_its_distances_can_hide_more_than_iso_covers(layout, capability):
    """design §9: C from the detection capability of the distances SSM uses, up to 70 mm. The loop's distances
    (the depth grid's, or SSM's detectable ones) can leave out an object lying on the robot: within its robot zone
    (6 cm) beyond its capsules (2 cm padding, up to 6.7 cm from the iiwa's meshes), or the self-filter's shell (2 cm
    + twice the noise margin), or in a hole the loop's invalid="neighbors" fills (9 pixels wide at the workspace's
    far side). That is far above 70 mm in every layout, so the loop refuses to run SSM, naming the band, rather
    than count C for a hand. (Before: SSM ran with C = 0.208 m.)"""
    from depthguard.errors import InputError

    workcell = load_workcell(_packaged("scenario_b_reach.yaml"), layout=_packaged(layout))
    with pytest.raises(InputError) as caught:
        run_closed_loop(workcell, "ssm", duration=0.1, settings=LoopSettings(ssm_capability=capability,
                                                                             known_solids=capability))
    assert caught.value.field == "detection_capability"
    message = str(caught.value)
    assert "70 mm" in message and any(cause in message for cause in ("robot zone", "shell", "filled holes")), message


def test_the_loops_ssm_brakes_along_its_path_within_the_stopping_time_and_distance():
    """design §9: T_s and S_s from the robot's braking. From full speed on every joint (the URDF's velocity
    limits, 10 rad/s on the iiwa) the loop's SSM command (_ssm_command) with factor 0 stops the arm within
    T_s = max |dq_i| / a_i of SpeedSeparationMonitor(braking=a), every joint within its acceleration limit, and each
    point covering the robot travels at most S_s = |v| T_s / 2 (the robot keeps its path while it brakes) plus what
    the Jacobians' change along the path adds, (V - |v|) T_s / 2 with V = sum reaches_i |dq_i| (from full speed the
    points travel up to 1.5 times |v| T_s / 2: the arm turns by radians while it brakes)."""
    from depthguard.avoidance import SpeedSeparationMonitor
    from depthguard.robots import RobotModel
    from depthguard_lab.simulation._closed_loop import _ssm_command

    robot = RobotModel.default().with_surface_points()
    limits = JointLimits.from_robot(robot, acceleration=LoopSettings().acceleration)
    ssm = SpeedSeparationMonitor(rho=1.2, braking=limits.acceleration, reaches=robot.joint_reaches())
    dt = 1.0 / LoopSettings().control_rate
    rng = np.random.default_rng(4)
    exceeded = False
    for _ in range(5):
        q = rng.uniform(np.maximum(limits.lower, -2.0), np.minimum(limits.upper, 2.0)) * 0.5
        dq = limits.velocity * rng.choice([-1.0, 1.0], robot.n_joints) * rng.uniform(0.2, 1.0, robot.n_joints)
        t_s = ssm.stopping_time(dq)
        points, jacobians = robot.control_point_kinematics(q)
        speed = np.linalg.norm(jacobians @ dq, axis=1)
        bound = speed + np.maximum(ssm.reaches @ np.abs(dq) - speed, 0.0)  # S_s = bound T_s / 2
        start, travelled, t = points, np.zeros(len(points)), 0.0
        while np.any(dq != 0.0):
            new = _ssm_command(np.zeros_like(dq), dq, 0.0, limits, dt)
            assert np.all(np.abs(new - dq) <= limits.acceleration * dt + 1e-9)
            q = q + new * dt
            dq, t = new, t + dt
            now = robot.control_point_positions(q, check=False)  # joint limits aside: braking alone
            travelled += np.linalg.norm(now - start, axis=1)
            start = now
            assert t <= t_s + dt + 1e-9
        assert np.all(travelled <= bound * t_s / 2 + bound * dt + 1e-6), np.max(travelled / (bound * t_s / 2))
        exceeded = exceeded or bool(np.any(travelled > speed * t_s / 2))
    assert exceeded, "the Jacobians' change mattered somewhere (else the test says less)"


@pytest.mark.slow
@pytest.mark.parametrize("mode", ["avoid"])
def test_the_reaction_does_not_oscillate(runs, mode):
    from depthguard_lab.experiments.avoidance_demo import summarize

    log = runs[mode]
    figures = summarize(log, 1.0 / LoopSettings().control_rate)
    assert figures["time_reacting_s"] > 0.5  # it does react in this window (else the bound would say nothing)
    assert figures["oscillation_per_s"] <= OSCILLATION_BOUND, figures["oscillation_per_s"]


@pytest.mark.slow
@pytest.mark.parametrize("mode", ["none", "avoid"])
def test_every_step_respects_the_joint_limits(runs, reach_workcell, mode):
    log = runs[mode]
    limits = JointLimits.from_robot(reach_workcell.robot, acceleration=LoopSettings().acceleration)
    dt = 1.0 / LoopSettings().control_rate
    assert np.all(log.q >= limits.lower - 1e-9) and np.all(log.q <= limits.upper + 1e-9)
    assert np.all(np.abs(log.dq) <= limits.velocity + 1e-9)
    previous = np.vstack([np.zeros((1, log.dq.shape[1])), log.dq[:-1]])
    assert np.all(np.abs(log.dq - previous) <= limits.acceleration * dt + 1e-9)
    # the joints move by the command: q[k+1] = q[k] + dq[k] dt
    np.testing.assert_allclose(log.q[1:], log.q[:-1] + log.dq[:-1] * dt, atol=1e-12)


@pytest.mark.slow
def test_the_loop_runs_cameras_at_their_rate_and_answers_from_frames_no_younger_than_the_latency(runs,
                                                                                                 reach_workcell):
    log = runs["avoid"]
    settings = LoopSettings()
    duration = reach_workcell.duration - CONTACT_WINDOW[0]
    assert log.frames == int(np.ceil(duration * reach_workcell.rate - 1e-9))
    seen = np.isfinite(log.data_age)
    assert not seen[0] and seen[-1]  # nothing to answer from before the first set is usable
    assert np.all(log.data_age[seen] >= settings.latency - 1e-9)
    assert np.all(log.data_age[seen] <= settings.latency + 1.0 / reach_workcell.rate + 1e-9)
    assert np.all(log.reported[~seen] == 0.0)  # and meanwhile every distance is 0


@pytest.mark.parametrize("field, kwargs", [
    ("mode", dict(mode="fast")),
    ("start", dict(start=float("nan"))),
    ("start", dict(start=-1.0)),
    ("duration", dict(duration=float("inf"))),
    ("duration", dict(duration=1e300)),  # beyond the episode: refused, not run for ever
    ("duration", dict(duration="1")),
    ("seed", dict(seed=-1)),
    ("seed", dict(seed="0")),
    ("measure", dict(measure=False)),  # in mode avoid
    ("measure", dict(mode="none", measure=0)),
])
def test_bad_loop_arguments_are_refused_before_any_work(reach_workcell, field, kwargs):
    from depthguard.errors import InputError

    with pytest.raises(InputError) as error:
        run_closed_loop(reach_workcell, **{"mode": "avoid", **kwargs})
    assert error.value.field == field


@pytest.mark.parametrize("field, kwargs", [
    ("truth_every", dict(truth_every=0)),
    ("truth_every", dict(truth_every=True)),
    ("ssm_lookahead", dict(ssm_lookahead="yes")),
    ("ssm_lookahead", dict(ssm_lookahead=1)),
    ("ssm_capability", dict(ssm_capability="True")),
    ("ssm_ramp", dict(ssm_ramp=-0.1)),
    ("ssm_ramp", dict(ssm_ramp=float("nan"))),
    ("known_solids", dict(known_solids=None)),
    ("ssm_rho", dict(ssm_rho=0.0)),
    ("ssm_rho", dict(ssm_rho=float("inf"))),
    ("ssm_rho", dict(ssm_rho="1.2")),
    ("control_rate", dict(control_rate=float("nan"))),
    ("monitor", dict(monitor="robot_zone=0.06")),
    ("robot_zone", dict(monitor=dict(robot_zone="0.06"))),
    ("robot_zone", dict(monitor=dict(robot_zone=-0.01))),
    ("robot_zone", dict(monitor=dict(robot_zone=float("nan")))),
    ("robot_zone", dict(monitor=dict(robot_zone=1.0))),
])
def test_bad_loop_settings_are_refused(field, kwargs):
    from depthguard.errors import InputError

    with pytest.raises(InputError) as info:
        LoopSettings(**kwargs)
    assert info.value.field == field


def test_the_loops_ssm_looks_ahead_from_the_links_surfaces():
    """The loop's SSM step (_ssm_factor) on exact distances to a person (a 0.25 m ball): the points are spheres of
    their links' radii, no direction is trusted, and a point moving straight away from the person is not slowed
    while its surface is beyond S_p at rest; without looking ahead it is slowed like one approaching."""
    from depthguard.avoidance import SpeedSeparationMonitor, SSMParams, protective_separation_distance
    from depthguard.results import DistanceResult, Flag
    from depthguard.scenes import Sphere, scene_distance
    from depthguard_lab.simulation._closed_loop import _ssm_factor

    person = Sphere((0.0, 0.0, 0.0), 0.25)
    asked = []

    class ExactSet:  # stands in for a PreparedSet: exact distances to the person, inf beyond rho
        def query(self, points, check=True):
            asked.append(len(points))
            d = scene_distance([person], points)
            d = np.where(d < rho, d, np.inf)
            return DistanceResult(distance=d, direction=np.zeros((len(d), 3)), count=np.ones(len(d), dtype=np.int64),
                                  invalid_count=np.zeros(len(d), dtype=np.int64), flags=tuple(Flag(0) for _ in d))

    rho, reaction = 1.2, 0.07
    params = SSMParams(sensing_uncertainty=0.05 + 0.06)  # Z_d with the loop's robot zone
    ssm = SpeedSeparationMonitor(params, rho=rho)
    radii = np.array([0.1, 0.05])
    at_rest = protective_separation_distance(params, 0.0, reaction, separation=1.0)  # 0.84 m
    points = np.array([[0.25 + at_rest + 0.1 + 0.01, 0.0, 0.0], [0.0, 3.0, 0.0]])  # surface 1 cm beyond it; far
    jacobians = np.zeros((2, 3, 3))
    jacobians[0] = np.eye(3)
    dq_away, dq_side = np.array([0.5, 0.0, 0.0]), np.array([0.0, 0.5, 0.0])
    distance = ExactSet().query(points).distance
    assert distance[1] == np.inf
    asked.clear()
    away = _ssm_factor(ssm, ExactSet(), distance, points, jacobians, dq_away, reaction, radii, True)
    assert away == 1.0 and asked == [1]  # only the point that would slow the robot was asked again
    blind = _ssm_factor(ssm, ExactSet(), distance, points, jacobians, dq_away, reaction, radii, False)
    side = _ssm_factor(ssm, ExactSet(), distance, points, jacobians, dq_side, reaction, radii, True)
    assert 0.0 < blind < 0.5 and side == pytest.approx(blind)
    # the same point 2 cm nearer is inside S_p at rest from its surface: it stops whichever way it moves
    nearer = points - [[0.02, 0.0, 0.0], [0.0, 0.0, 0.0]]
    assert _ssm_factor(ssm, ExactSet(), ExactSet().query(nearer).distance, nearer, jacobians, dq_away, reaction,
                       radii, True) == 0.0


def test_ssms_distances_between_asks_are_lower_bounds_and_only_moved_points_are_asked_again():
    """The loop's SSM asks the monitor again on the same frames only for points that moved more than the tolerance;
    meanwhile a point's distance is the one asked minus how far it moved: judged against exact distances to a fixed
    cloud (inf beyond rho, as the monitor says "nothing within rho")."""
    from depthguard_lab.simulation._closed_loop import _MovedSince

    rng = np.random.default_rng(11)
    cloud = rng.uniform(-1.0, 1.0, (200, 3))
    rho = 0.5
    asked = []

    def exact(points):
        d = np.linalg.norm(points[:, None] - cloud[None], axis=2).min(1)
        return np.where(d >= rho, np.inf, d)

    def ask(prepared, points):
        asked.append(len(points))
        return exact(points)

    cache = _MovedSince(ask, rho, tolerance=0.005)
    frames = object()
    points = rng.uniform(-1.2, 1.2, (9, 3))
    for step in range(400):
        if step == 200:
            frames = object()  # a new set of frames asks every point
        points = points + rng.normal(0.0, 0.0015, points.shape) * (rng.random((9, 1)) < 0.5)
        got = cache(frames, points)
        truth = exact(points)
        assert np.all(np.minimum(got, rho) <= np.minimum(truth, rho) + 1e-12)
        assert np.all(got >= np.minimum(truth, rho) - 2 * 0.005 - 1e-12)  # at most twice the tolerance below
    assert asked[0] == 9 and 9 in asked[1:]  # the first and the new set asked all nine
    assert sum(asked) < 400 * 9 / 2  # most steps asked no point or only a few


def test_the_avoidance_bounds_the_other_points_towards_the_nearest_obstacle_and_repels_the_end_effector_along_the_mean():
    """design §9: the loop's query gives each control point the distance and direction of "min" (the direction to
    the nearest obstacle, along which the other points' joints are bounded) and the end-effector the direction of
    "hybrid" (its repulsion); "min" and "hybrid" report the same distances. Here the hand reaches for the
    end-effector, so both are within rho and their directions differ somewhere."""
    from depthguard_lab.simulation import simulate
    from depthguard_lab.simulation._closed_loop import _avoidance_query
    from depthguard import DistanceMonitor
    from depthguard.errors import InputError

    workcell = load_workcell(_packaged("scenario_b_reach.yaml"))
    (frame,) = simulate(workcell, frames=[88])  # about 2.9 s: the hand next to the end-effector
    robot = workcell.robot
    points_robot = robot.with_surface_points(LoopSettings().surface_tolerance)
    points = points_robot.control_point_positions(frame.joints)
    ee = points_robot.end_effector_index
    options = dict(LoopSettings().monitor, rho=LoopSettings().avoidance.rho, robot=robot)
    answers = {}
    for aggregate in ("min", "hybrid"):
        monitor = DistanceMonitor(workcell.rig, **{**options, "aggregate": aggregate})
        prepared = monitor.prepare_set(frame.depth, joints=frame.joints, now=frame.time)
        answers[aggregate] = prepared.query(points)
        if aggregate == "min":
            loop = _avoidance_query(prepared, points, ee)
            per_call = prepared.query(points, aggregate="hybrid")  # as a monitor that aggregates so answers
            with pytest.raises(InputError) as caught:
                prepared.query(points, aggregate="nearest")
            assert caught.value.field == "aggregate"
    minimum, hybrid = answers["min"], answers["hybrid"]
    assert np.isfinite(minimum.distance[ee])
    assert np.array_equal(minimum.distance, hybrid.distance) and np.array_equal(loop.distance, minimum.distance)
    others = np.arange(len(points)) != ee
    assert np.array_equal(loop.direction[others], minimum.direction[others])
    assert np.allclose(loop.direction[ee], hybrid.direction[ee])
    assert not np.allclose(minimum.direction[ee], hybrid.direction[ee])  # the two rules differ here, for both
    assert not np.allclose(minimum.direction[others], hybrid.direction[others])
    assert np.array_equal(per_call.distance, hybrid.distance) and np.allclose(per_call.direction, hybrid.direction)
