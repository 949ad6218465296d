"""The free-space memory (design §8a) judged by pybullet over time (issue 8, "Must show"): memory never makes an
answer optimistic while people move no faster than v_max, and above v_max every optimistic answer says it rests on
memory.

The judge is test_judge_fusion's, frame by frame: pybullet renders both cameras (160x120, the rig of
``fusion_scenes.rig(("p", "s"))`` plus a ``workspace`` box around the iiwa, which the memory remembers in 4 cm voxels),
with the iiwa drawn from its collision meshes (``iiwa_urdf``); pybullet's getClosestPoints and coal give the true
distance of each control point to the room and the hand; ``fusion_scenes.fused_bound`` gives the tolerance, with the
robot's silhouette and "behind the robot" recomputed for each frame's pose (as the ``hidden_object`` fixture does).
Frames are stamped at 30 Hz and go, in time order, to monitors that each keep their memory across frames: the default
(memory on, v_max 2 m/s), one with ``memory=False``, and in scenario 1 a broken one (v_max 0.1 m/s).

The scenes: the iiwa swings joints 1 and 2 (``joints_at``); a hand (a capsule of radius 3.5 cm) waits beside link 3,
reaches in behind it (as the principal camera sees it) from one side at 1.0 m/s and from the other at 1.9 m/s, holds
still there, and is withdrawn while the robot moves. Control points: the robot's 9, 40 fixed points behind the arm
(the space memory is for) and up to 30 around the hand each frame.

What memory can do here, and why the second camera drops out. A voxel seen free at t stays certified free until
t + D / v_max, D its cube's distance to the nearest voxel where a person may be; at 30 Hz it outlives one frame only
if D > 6.7 cm. The pockets no camera sees in this scene (behind each link, for both cameras) move with the
links by a few centimetres a frame and border the links' padded capsules, which the memory never certifies (design
§8a's Robot_k lies inside the meshes, and the layer round it is seen by no camera): a correct memory then has
nothing to remember there (measured: it raises
no distance in a frame without a dropout). Space becomes unseen at once when a camera loses part of its image: the
second camera reads 0 (no measurement, as an infrared dropout gives) over the part of its image that shows the robot
(``DROPOUT``) for three frames while the hand is away and again while it reaches in at 1.9 m/s; the memory then keeps
what it saw a frame before, and the hand reaches into space that no camera sees.

Scenario 4 (issue 35's judge): a hand 25 mm thick slides into the space both cameras' views of a link hide, at up to
v_max and at three times v_max, and rests there 5 mm from the link while the robot moves.

The whole file takes 30-45 s on the shared 2-core machine (numba limited to one thread, see ``world``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numba
import numpy as np
import pybullet as p
import pytest
from scipy import ndimage

import coal  # noqa: F401  (a judge: a missing one must fail, never skip)
import depthguard as dg
import fusion_scenes as fs
import pybullet_scenes as ps
from depthguard.depthgrid import build_map
from depthguard.robots import RobotModel
from test_judge_fusion import (BEHIND_ALONG_RAY, BEHIND_CLEARANCE, HIDDEN_BEHIND, HIDDEN_Q, MARGIN, PAD, RHO,
                               ROBOT_SILHOUETTE_GROWTH, iiwa_urdf)  # noqa: F401  (iiwa_urdf: a fixture)
from test_judge_pybullet import EPS, JUDGES_AGREE

#: Frames per second, and the box the memory remembers (world, metres): around the iiwa, inside the room.
FPS = 30.0
WORKSPACE = [[-1.2, -1.2, 0.0], [1.5, 1.3, 1.6]]

#: The hand: a capsule (radius, axis length, metres), and how far (metres) sideways from its place behind the link
#: it waits before it reaches in, as the principal camera sees it.
HAND = (0.035, 0.12)
REACH = 0.24

#: The iiwa's motion: joints 1 and 2 swing sinusoidally about HIDDEN_Q (amplitudes in radians, frequency in Hz).
SWING = np.array([0.25, 0.12, 0.0, 0.0, 0.0, 0.0, 0.0])
SWING_HZ = 0.5

#: Fixed control points in the space behind the robot as the principal camera sees it (``World.probes``), and how
#: many tries each frame places around the hand (``fusion_scenes.points_near``).
PROBES = 40
NEAR_HAND = 30

#: The second camera's pixels that read 0 (no measurement, as an infrared dropout gives) in some frames: the part of
#: its image that shows the robot and the space behind it. Without memory that space is then seen by no camera.
DROPOUT = (slice(20, 100), slice(40, 120))  # rows, columns


def joints_at(t: float) -> np.ndarray:
    phase = 2.0 * math.pi * SWING_HZ * t
    return HIDDEN_Q + SWING * np.array([math.sin(phase), math.sin(phase + 0.7), 0, 0, 0, 0, 0])


def rig() -> dg.Rig:
    """test_judge_fusion's two 160x120 cameras and a workspace box around the iiwa."""
    base = fs.rig(("p", "s"))
    return dg.Rig(dict(base.cameras), principal="p", workspace=WORKSPACE)


@dataclass
class Step:
    """One set of frames to render: capture time, joints, the hand's centre, whether the second camera drops out."""

    t: float
    q: np.ndarray
    hand: np.ndarray
    dropout: bool = False
    phase: str = ""
    hand_R: np.ndarray | None = None  # the hand's orientation (world from hand; its axis the third column)
    hand_size: tuple | None = None  # (radius, axis length), metres; None: HAND


class World:
    """pybullet clients: one with the iiwa, the room and the hand (rendered, measured), one with the iiwa alone (ray
    casts for the judge's 'behind the robot'); the rig, its depth grid, the hand's place and the fixed probes."""

    def __init__(self, urdf: str):
        self.client = p.connect(p.DIRECT)
        self.robot_only = p.connect(p.DIRECT)
        self.bodies = [p.loadURDF(urdf, useFixedBase=True, physicsClientId=c) for c in (self.client, self.robot_only)]
        self.probe = p.createCollisionShape(p.GEOM_SPHERE, radius=1e-5, physicsClientId=self.robot_only)
        self.robot = RobotModel.default()
        self.rig = rig()
        self.grid = build_map(self.rig, "p")
        self.eye = np.array(fs.EYES["p"])
        self.room = ps.room()
        # The hand's place: HIDDEN_BEHIND metres behind link 3's axis along the principal's line of sight, parallel to
        # the link (as in test_judge_fusion's hidden object), with the robot half-way through the reach sequence; it
        # comes in along ``lateral``, square to the line of sight and to the link.
        control = self.robot.control_point_positions(joints_at(0.75))
        anchor = 0.5 * (control[1] + control[2])
        axis = (control[2] - control[1]) / np.linalg.norm(control[2] - control[1])
        sight = (anchor - self.eye) / np.linalg.norm(anchor - self.eye)
        side = np.cross(axis, [1.0, 0.0, 0.0])
        side /= np.linalg.norm(side)
        self.hand_R = np.stack([side, np.cross(axis, side), axis], 1)
        self.place = anchor + HIDDEN_BEHIND * sight
        self.lateral = np.cross(sight, axis) / np.linalg.norm(np.cross(sight, axis))
        # Fixed points along the principal's lines of sight through points of the arm, 0.1 to 0.5 m behind them,
        # scattered by 5 cm.
        rng = np.random.default_rng(7)
        on_arm = np.array([control[i] + rng.uniform() * (control[i + 1] - control[i])
                           for i in rng.integers(0, len(control) - 1, PROBES)])
        rays = (on_arm - self.eye) / np.linalg.norm(on_arm - self.eye, axis=1, keepdims=True)
        self.probes = on_arm + rng.uniform(0.1, 0.5, (PROBES, 1)) * rays + rng.normal(0.0, 0.05, (PROBES, 3))

    def close(self):
        p.disconnect(self.robot_only)
        p.disconnect(self.client)

    def hand(self, centre, R=None, size=None) -> ps.Primitive:
        return ps.Primitive("capsule", HAND if size is None else size,
                            ps.pose(self.hand_R if R is None else R, centre))

    def pose_robot(self, q):
        for joint in range(7):
            for c, body in zip((self.client, self.robot_only), self.bodies):
                p.resetJointState(body, joint, q[joint], physicsClientId=c)

    def behind_robot(self, points_world):
        """As in test_judge_fusion's hidden_object: the principal's line of sight to the point meets the robot at
        least BEHIND_ALONG_RAY in front of it, and the point is at least BEHIND_CLEARANCE from the robot."""
        hits = p.rayTestBatch(points_world.tolist(), [self.eye.tolist()] * len(points_world),
                              physicsClientId=self.robot_only)
        out = np.zeros(len(points_world), bool)
        for k, (B, hit) in enumerate(zip(points_world, hits)):
            along = hit[0] == self.bodies[1] and np.linalg.norm(np.asarray(hit[3]) - B) >= BEHIND_ALONG_RAY
            near = p.getClosestPoints(bodyA=-1, bodyB=self.bodies[1], distance=BEHIND_CLEARANCE,
                                      collisionShapeA=self.probe, collisionShapePositionA=B.tolist(),
                                      physicsClientId=self.robot_only)
            out[k] = along and not near
        return out

    def hidden_from_principal(self, points_world) -> bool:
        """Whether the robot (at its current pose) blocks the principal's line of sight to every point."""
        hits = p.rayTestBatch([self.eye.tolist()] * len(points_world), np.asarray(points_world).tolist(),
                              physicsClientId=self.robot_only)
        return all(hit[0] == self.bodies[1] for hit in hits)


@dataclass
class Frame:
    """One set of frames: the step, the hand, the control points and what the judge measured about them, and each
    monitor's answer."""

    step: Step
    hand: ps.Primitive
    points: np.ndarray
    kind: np.ndarray  # (n,) "robot" (the iiwa's control points), "probe" (World.probes) or "hand" (around the hand)
    truth: ps.Truth
    bound: np.ndarray
    how: np.ndarray
    hand_pixels: dict  # camera name -> pixels showing the hand (a dropout's pixels show nothing)
    results: dict = field(default_factory=dict)  # monitor label -> DistanceResult

    def over(self, label: str) -> np.ndarray:
        """(n,) the monitor's distance minus (truth + tolerance), metres; a point reported free (inf) gets +inf if
        truth + tolerance lies within rho, else -inf. Above EPS: optimistic."""
        reported = self.results[label].distance
        within = self.truth.distance + self.bound + EPS < RHO
        with np.errstate(invalid="ignore"):
            return np.where(np.isfinite(reported), reported - self.truth.distance - self.bound,
                            np.where(within, np.inf, -np.inf))

    def remembered(self, label: str) -> np.ndarray:
        return np.array([dg.Flag.REMEMBERED in f for f in self.results[label].flags])

    def describe(self, label: str, i: int) -> str:
        r = self.results[label]
        return (f"t = {self.step.t:.4f} s ({self.step.phase}), {self.kind[i]} point {self.points[i].tolist()}: "
                f"{label} {r.distance[i]:.6f} m, true {self.truth.distance[i]:.6f} m (nearest "
                f"{self.truth.nearest_world[i].tolist()}, primitive {self.truth.primitive[i]}), tolerance "
                f"{self.bound[i]:.6f} m ({self.how[i]}); flags {r.flags[i].names}; hand {self.hand.centre.tolist()}, "
                f"pixels {self.hand_pixels}, dropout {self.step.dropout}")


def image(depth: np.ndarray, cam: dg.PinholeCamera, t: float) -> dg.DepthImage:
    """A rendered depth map (optical z, inf for nothing) as a float32 frame stamped ``t``."""
    return dg.depth_image(np.where(np.isfinite(depth), depth, 0.0).astype(np.float32), cam, timestamp=t)


def play(world: World, steps, monitors: dict, rng, before_query=None):
    """Render, measure and query every step; yields a Frame per step. ``before_query(index, step)`` may change a
    step's hand before it is rendered. Control points: the robot's 9, the probes and up to NEAR_HAND around the hand
    (points inside the hand are left out)."""
    for index, step in enumerate(steps):
        if before_query is not None:
            before_query(index, step)
        hand = world.hand(step.hand, step.hand_R, step.hand_size)
        world.pose_robot(step.q)
        scene = ps.PybulletScene(world.client, world.room + [hand])
        try:
            depths, segmentation = {}, {}
            for name, cam in world.rig.cameras.items():
                depths[name], segmentation[name] = ps.render_depth(world.client, cam)
            shows_hand = {n: segmentation[n] == scene.bodies[-1] for n in segmentation}
            control = world.robot.control_point_positions(step.q)
            near_hand = fs.points_near(scene, rng, [len(world.room)], NEAR_HAND, RHO)
            points = np.concatenate([control, world.probes, near_hand])
            kind = np.array(["robot"] * len(control) + ["probe"] * len(world.probes) + ["hand"] * len(near_hand))
            truth = scene.measure(points, RHO + 0.2)
        finally:
            scene.remove()
        assert truth.judges_gap <= JUDGES_AGREE, f"t = {step.t}: pybullet and coal differ by {truth.judges_gap:.3g} m"
        if step.dropout:
            depths["s"][DROPOUT] = np.inf  # read as 0: no measurement
            shows_hand["s"][DROPOUT] = False
        hand_pixels = {n: int(np.count_nonzero(shows)) for n, shows in shows_hand.items()}
        outside = truth.distance > 0.0
        truth = ps.Truth(truth.distance[outside], truth.nearest_world[outside], truth.primitive[outside],
                         truth.judges_gap)
        points, kind = points[outside], kind[outside]
        maybe_robot = ndimage.binary_dilation(segmentation["p"] == world.bodies[0], structure=np.ones((3, 3), bool),
                                              iterations=ROBOT_SILHOUETTE_GROWTH)
        bound, how = fs.fused_bound(world.rig.cameras["p"], depths["p"], truth.nearest_world, world.grid,
                                    [(world.rig.cameras["s"], depths["s"])], MARGIN, PAD, maybe_robot=maybe_robot,
                                    behind_robot=world.behind_robot)
        frame = Frame(step, hand, points, kind, truth, bound, how, hand_pixels)
        images = {n: image(depths[n], world.rig.cameras[n], step.t) for n in depths}
        for label, mon in monitors.items():
            frame.results[label] = mon.query(images, points, joints=step.q, now=step.t)
        yield frame


def monitor(world: World, **kwargs) -> dg.DistanceMonitor:
    return dg.DistanceMonitor(world.rig, rho=RHO, aggregate="min", robot=world.robot, fusion_margin=MARGIN,
                              fusion_pixels=PAD, **kwargs)


@pytest.fixture(scope="module")
def world(iiwa_urdf):  # noqa: F811
    # One numba thread: the answers do not depend on it, and on a small machine that other jobs share, parallel
    # kernels on 160x120 images spend far longer waiting for each other than working.
    threads = numba.get_num_threads()
    numba.set_num_threads(1)
    w = World(iiwa_urdf)
    try:
        yield w
    finally:
        w.close()
        numba.set_num_threads(threads)


def path(waypoints):
    """A piecewise-linear path from [(position, speed, hold seconds)]: from each position to the next at ``speed``
    m/s (the first waypoint's speed is unused), holding still at each for its hold time. Returns (centre(t),
    leg(t), the (start, end) times of each move, the end time); leg(t) is the index of the leg at t: 2k holds at
    waypoint k, 2k + 1 moves from it to the next."""
    legs, moves = [], []  # (t0, t1, a, b)
    t = 0.0
    for k, (a, _, hold) in enumerate(waypoints):
        a = np.asarray(a, dtype=np.float64)
        legs.append((t, t + hold, a, a))
        t += hold
        if k + 1 < len(waypoints):
            b, speed, _ = waypoints[k + 1]
            duration = float(np.linalg.norm(np.asarray(b) - a)) / speed
            legs.append((t, t + duration, a, np.asarray(b, dtype=np.float64)))
            moves.append((t, t + duration))
            t += duration

    def leg(time):
        return next((k for k, (_, t1, _, _) in enumerate(legs) if time <= t1), len(legs) - 1)

    def centre(time):
        t0, t1, a, b = legs[leg(time)]
        return a + (0.0 if t1 == t0 else min(max(time - t0, 0.0) / (t1 - t0), 1.0)) * (b - a)

    return centre, leg, moves, t


# ------------------------------------------------------------------------------------ 1. reaching at up to v_max

def reach_steps(world: World) -> list[Step]:
    """Scenario 1: the hand waits REACH metres to one side of its place behind link 3 (the second camera drops out
    for frames 3-5 meanwhile), comes in at 1.0 m/s, holds still, leaves to the other side at 1.9 m/s while the robot
    moves, comes back in from there at 1.9 m/s (the second camera dropping out from the start of that move until two
    frames after its end: the hand then reaches into space no camera sees), holds still, and leaves at 1.0 m/s."""
    a = world.place + REACH * world.lateral
    b = world.place - REACH * world.lateral
    centre, leg, moves, end = path([(a, None, 7 / FPS), (world.place, 1.0, 3 / FPS), (b, 1.9, 1 / FPS),
                                    (world.place, 1.9, 3 / FPS), (a, 1.0, 0.0)])
    phases = ["away", "in (1.0 m/s)", "still", "out (1.9 m/s)", "away", "in (1.9 m/s)", "still", "out (1.0 m/s)",
              "away"]
    back_in = moves[2]
    steps = []
    for k in range(int(end * FPS + 1e-9) + 1):
        t = k / FPS
        dropout = 3 <= k <= 5 or back_in[0] <= t <= back_in[1] + 2 / FPS
        steps.append(Step(t, joints_at(t), centre(t), dropout, phases[leg(t)]))
    return steps


#: The monitors fed scenario 1's frames: the default memory (v_max 2 m/s), none, and a broken one that takes people
#: to be 20 times slower than they are (it remembers free space 20 times too long).
SLOW_V_MAX = 0.1


@pytest.fixture(scope="module")
def reaching(world):
    monitors = {"memory": monitor(world), "none": monitor(world, memory=False),
                "slow": monitor(world, v_max=SLOW_V_MAX)}
    assert monitors["memory"].memory is not None and monitors["none"].memory is None
    return list(play(world, reach_steps(world), monitors, np.random.default_rng(0)))


def check_memory_frame(f: Frame, label: str = "memory") -> None:
    """At one frame, for the monitor ``label``: no point above truth + tolerance (flagged or not); never below the
    monitor without memory (to 1e-9 m); every distance memory raised carries ``remembered``."""
    over = f.over(label)
    bad = np.flatnonzero(over > EPS)
    if len(bad):
        i = bad[np.argmax(over[bad])]
        pytest.fail(f"{label} optimistic at {len(bad)} points; worst {over[i] * 1e3:.2f} mm beyond truth + tolerance: "
                    f"{f.describe(label, i)}; without memory {f.results['none'].distance[i]:.6f} m")
    mem, none = f.results[label].distance, f.results["none"].distance
    below = np.flatnonzero(mem < none - 1e-9)
    assert len(below) == 0, f"{label} below no memory: {f.describe(label, below[0])}; without {none[below[0]]:.6f} m"
    unflagged = np.flatnonzero((mem > none + 1e-9) & ~f.remembered(label))
    assert len(unflagged) == 0, f"raised by memory, not flagged: {f.describe(label, unflagged[0])}"


def test_memory_is_never_optimistic_at_up_to_v_max(reaching):
    """Scenario 1 (``reach_steps``), every frame and every point, flagged or not: memory <= truth + tolerance, memory
    >= no memory (to 1e-9 m), and a distance memory raised carries ``remembered``. The scenario holds what it says:
    the hand never moves faster than 1.9 m/s, it is hidden from the principal camera (at most 3 of its pixels) while
    it holds still, and in some frames neither camera shows it (at most 3 principal pixels, none of the second
    camera's). Memory is not idle: it raises distances while the hand is away.

    Measured: 36 frames (1.2 s), 2844 points; the hand in space neither camera sees in 3 frames; largest memory -
    (truth + tolerance) -0.01 mm (the tolerance is tight, and memory never went past it); memory raised 31 distances
    by more than 1 mm, by up to 136 mm, all flagged: 15 while the hand was away (the first dropout) and 16 while it
    reached in from the second side (the second dropout), none in a frame without a dropout; 28 of them probes behind
    the arm, 3 near the hand, none of the robot's own 9 control points (the space right behind a link borders the
    link, see the module docstring).
    """
    frames = reaching
    step_lengths = [np.linalg.norm(b.step.hand - a.step.hand) for a, b in zip(frames[:-1], frames[1:])]
    assert max(step_lengths) <= 1.9 / FPS + 1e-9
    assert all(f.hand_pixels["p"] <= 3 for f in frames if f.step.phase == "still")
    unseen = [f for f in frames if f.hand_pixels["p"] <= 3 and f.hand_pixels["s"] == 0]
    assert unseen, "the hand must reach into space no camera sees"

    counts: dict = {}
    kinds: dict = {}
    worst, n_points, largest_gain, raised_without_dropout = -np.inf, 0, 0.0, 0
    for f in frames:
        check_memory_frame(f)
        over = f.over("memory")
        worst = max(worst, float(over[np.isfinite(over)].max()))
        n_points += len(f.points)
        mem = np.minimum(f.results["memory"].distance, RHO)
        none = np.minimum(f.results["none"].distance, RHO)
        up = mem > none + 1e-3
        largest_gain = max(largest_gain, float(np.max(mem - none)))
        c = counts.setdefault(f.step.phase, np.zeros(3, int))
        c += (1, up.sum(), f.remembered("memory").sum())
        raised_without_dropout += 0 if f.step.dropout else int(up.sum())
        for k in np.unique(f.kind[up]):
            kinds[str(k)] = kinds.get(str(k), 0) + int(np.count_nonzero(f.kind[up] == k))
    print(f"\nscenario 1: {len(frames)} frames, {n_points} points, the hand hidden from both cameras in "
          f"{len(unseen)} frames; largest memory - (truth + tolerance) {worst * 1e3:.2f} mm; per phase (frames, "
          f"raised by memory by > 1 mm, flagged remembered): { {k: v.tolist() for k, v in counts.items()} }; raised "
          f"by kind {kinds}, in frames without a dropout {raised_without_dropout}; largest gain "
          f"{largest_gain * 1e3:.1f} mm")
    assert counts["away"][1] >= 5, "memory must raise distances while the hand is away"


# ------------------------------------------------------------------------------------------ 2. faster than v_max

#: Where the hand waits before it is teleported behind the robot and after (world, metres): in the room's corner,
#: more than 2 m from anywhere it lands (it covers that in 1/30 s: above 60 m/s).
FAR = np.array([-1.9, 1.9, 0.4])


def remembered_place(world: World, mon: dg.DistanceMonitor, q, t: float):
    """Where the hand (HAND, oriented as in scenario 1) lies behind the robot at joints q as the principal camera
    sees it (the robot blocks the lines of sight to 10 points of its surface), at least 3 cm from the robot, with
    every voxel of its bounding cube (grown by a voxel) certified free at time t by ``mon``'s memory (arrival time
    later than t, design §8a): the candidate whose voxels stay free longest, and that time. Candidates: along the
    principal's lines of sight through points of the arm, 0.12 to 0.6 m behind them. (None, t) if there is none."""
    memory = mon.memory
    box, arrival = memory.box, memory.arrival
    control = world.robot.control_point_positions(q)
    world.pose_robot(q)
    shape = p.createCollisionShape(p.GEOM_CAPSULE, radius=HAND[0], height=HAND[1], physicsClientId=world.robot_only)
    R = world.hand_R
    ends = [s * 0.5 * HAND[1] * R[:, 2] for s in (-1.0, 1.0)]
    surface = np.array([e + HAND[0] * d for e in ends for d in (R[:, 0], -R[:, 0], R[:, 1], -R[:, 1])] + ends)
    quaternion = ps._matrix_to_quaternion(R)
    best, best_score = None, t
    for i in range(len(control) - 1):
        for w in (0.0, 0.5):
            on_arm = control[i] + w * (control[i + 1] - control[i])
            ray = (on_arm - world.eye) / np.linalg.norm(on_arm - world.eye)
            for behind in np.arange(0.12, 0.6, 0.03):
                centre = on_arm + behind * ray
                lo = np.floor((centre - 0.5 * HAND[1] - HAND[0] - box.lo) / box.voxel).astype(int) - 1
                hi = np.floor((centre + 0.5 * HAND[1] + HAND[0] - box.lo) / box.voxel).astype(int) + 1
                if np.any(lo < 0) or np.any(hi >= box.shape):
                    continue
                score = arrival[lo[0]:hi[0] + 1, lo[1]:hi[1] + 1, lo[2]:hi[2] + 1].min()
                if score <= best_score or not world.hidden_from_principal(centre + surface):
                    continue
                if p.getClosestPoints(bodyA=-1, bodyB=world.bodies[1], distance=0.03, collisionShapeA=shape,
                                      collisionShapePositionA=centre.tolist(),
                                      collisionShapeOrientationA=quaternion, physicsClientId=world.robot_only):
                    continue
                best, best_score = centre, score
    return best, best_score


def test_above_v_max_a_hand_a_camera_sees_is_not_cleared(world):
    """Above v_max, as documented (design §8a, ``DistanceMonitor``: "a body part moving faster than v_max is outside the
    guarantee"): the hand waits in the room's corner (FAR) while the robot moves, is teleported in one frame (more
    than 2 m in 1/30 s) behind the robot into voxels the memory certifies free at that time (found from the memory's
    own arrival times, ``remembered_place``), stays there 4 frames and is teleported back. Any optimistic answer must
    carry ``remembered``, so that an unflagged answer is never optimistic; without memory, no answer is optimistic.

    The memory forgets a voxel in which a camera measures a surface now (the monitor's hardening): the second camera
    sees the hand there, so the voxels that hold its seen surface are not cleared. Before that hardening, this test
    measured 23, 18, 15 and 9 optimistic points in the 4 frames the hand stays (all flagged, by up to 93.5 mm); with
    it, none. A hand that jumps faster than v_max into space that no camera sees is still outside the guarantee.

    Measured: the hand jumps 2.99 m (90 m/s) to (0.578, 0.229, 0.381), where the principal camera shows 1-2 of its
    pixels and the second camera 27, in voxels remembered free until 0.175 s (it lands at 0.133 s); optimistic points
    per frame: [0, 0, 0, 0, 0, 1, 0, 0, 0, 0], flagged, 4.6 mm over. (With the erosion's old voxel-diagonal rounding,
    none: the memory then forgot the voxel behind the hand's seen surface sooner. The forgetting covers the voxels
    holding the seen surface, not the hand's hidden back in the next voxel.) At most 2 such points, under 1 cm.
    """
    monitors = {"memory": monitor(world), "none": monitor(world, memory=False)}
    steps = [Step(k / FPS, joints_at(k / FPS), FAR.copy(), phase="far") for k in range(10)]
    landed = {}

    def teleport(index, step):
        if index == 4:
            centre, until = remembered_place(world, monitors["memory"], step.q, step.t)
            assert centre is not None, "the memory remembers no place behind the robot that holds the hand"
            landed.update(centre=centre, until=until)
        if 4 <= index <= 7:
            step.hand, step.phase = landed["centre"].copy(), "teleported"

    optimistic, worst, hidden, n_points = [], -np.inf, [], 0
    for f in play(world, steps, monitors, np.random.default_rng(1), before_query=teleport):
        over = f.over("memory")
        over_none = f.over("none")
        assert not np.any(over_none > EPS), f"without memory: {f.describe('none', int(np.argmax(over_none)))}"
        mem, none = f.results["memory"].distance, f.results["none"].distance
        assert np.all(mem >= none - 1e-9)
        bad = np.flatnonzero(over > EPS)
        unflagged = bad[~f.remembered("memory")[bad]]
        assert len(unflagged) == 0, f"optimistic and not flagged: {f.describe('memory', unflagged[0])}"
        optimistic.append(len(bad))
        if len(bad):
            worst = max(worst, float(over[bad].max()))
        if f.step.phase == "teleported":
            hidden.append((f.hand_pixels["p"], f.hand_pixels["s"]))
        n_points += len(f.points)
    jump = np.linalg.norm(landed["centre"] - FAR)
    print(f"\nabove v_max: the hand jumps {jump:.2f} m in 1/30 s ({jump * FPS:.0f} m/s) to {landed['centre'].round(3)} "
          f"(remembered free until {landed['until']:.3f} s; pixels of the hand there (principal, second) {hidden}); "
          f"optimistic points per frame {optimistic} (all flagged remembered), largest excess "
          f"{worst * 1e3:.1f} mm; {n_points} points")
    assert jump > 2.0
    assert all(p + s > 0 for p, s in hidden), "a camera must see the hand where it lands"
    assert sum(optimistic) <= 2 and worst < 0.01, "a hand a camera sees was cleared by memory"


# ------------------------------------------------------------------------------------- 3. the judge can catch it

def test_the_judge_catches_a_memory_that_remembers_too_long(reaching):
    """The check of scenario 1 (``check_memory_frame``) can fail: on the same frames, a monitor that takes people to
    move at 0.1 m/s (20 times slower than the default v_max: it keeps space free 20 times too long) fails it. (A
    larger v_max, such as 50 m/s, is the cautious side: remembered space then lasts D / 50 s, less
    than a frame here, where D is at most 0.8 m, half the workspace's height, the layer outside the box counting as
    possibly occupied.)

    Measured: the check fails in 1 of the 36 frames (1 optimistic point, 5.6 mm beyond truth + tolerance, flagged
    remembered, while the hand is away). Before the monitor forgot the voxels in which a camera measures a surface
    now, it failed in 11 frames (41 points, up to 37.9 mm): with that hardening, a memory that keeps space far too long
    still clears a hand only where no camera sees its surface.
    """
    failures, found = [], []
    for f in reaching:
        try:
            check_memory_frame(f, "slow")
        except pytest.fail.Exception as failure:
            failures.append(str(failure))
        bad = np.flatnonzero(f.over("slow") > EPS)
        if len(bad):
            found.append((f.step.phase, len(bad), float(f.over("slow")[bad].max()),
                          int(np.count_nonzero(f.remembered("slow")[bad]))))
    print(f"\nv_max {SLOW_V_MAX} m/s: the check fails in {len(failures)} of {len(reaching)} frames; optimistic points "
          f"{sum(c for _, c, _, _ in found)} in all (flagged remembered: {sum(r for *_, r in found)}); largest excess "
          f"{max(e for _, _, e, _ in found) * 1e3:.1f} mm; phases {sorted({ph for ph, *_ in found})}")
    assert len(failures) >= 1 and all("optimistic" in failure for failure in failures)


# ------------------------------------------- 4. a thin hand resting in the space every camera's view of a link hides

#: Issue 35's thin hand: a capsule 25 mm thick (radius, axis length, metres) that rests against lbr_iiwa_link_4
#: (pybullet's link 3), in the space that both cameras' views of the link hide, and moves with the link. Its place in
#: the link's frame: its axis along the frame's z axis, its centre SHADOW_ALONG metres along that axis and
#: SHADOW_RADIUS metres out from it, at SHADOW_ANGLE from the frame's x axis towards its y axis. Found by searching
#: the link's surroundings for places 3-10 mm from the link where pybullet's renderings show the hand to neither
#: camera; ``test_the_thin_hand_scene_is_what_it_claims`` checks it in every frame.
THIN_HAND = (0.0125, 0.08)
SHADOW_LINK = 3
SHADOW_ALONG, SHADOW_RADIUS, SHADOW_ANGLE = 0.05, 0.09, math.radians(15.0)
#: How far (metres) out from its resting place the hand waits, seen by both cameras, before it slides in along the
#: same direction; and the frames it waits and rests.
SHADOW_REACH = 0.25
SHADOW_WAIT, SHADOW_REST = 6, 24


def link_pose(world: World, q) -> tuple[np.ndarray, np.ndarray]:
    """(position (3,), rotation (3, 3)) of pybullet's link SHADOW_LINK at joints q, world frame."""
    world.pose_robot(q)
    state = p.getLinkState(world.bodies[1], SHADOW_LINK, computeForwardKinematics=True,
                           physicsClientId=world.robot_only)
    return np.array(state[4]), np.array(p.getMatrixFromQuaternion(state[5])).reshape(3, 3)


def shadow_steps(world: World, speed: float) -> list[Step]:
    """The robot swings (``joints_at``); the thin hand waits SHADOW_REACH metres out from its place against the link
    for SHADOW_WAIT frames, slides in at ``speed`` m/s relative to the link, then rests there for SHADOW_REST frames,
    moving with the link (its speed in the world: ``speed`` plus the link's, at most 0.15 m/s more here)."""
    out = np.array([math.cos(SHADOW_ANGLE), math.sin(SHADOW_ANGLE), 0.0])  # in the link's frame, as all below
    place = np.array([0.0, 0.0, SHADOW_ALONG]) + SHADOW_RADIUS * out
    hand_R = np.eye(3)  # its axis along the link's z axis
    n_in = int(math.ceil(SHADOW_REACH / speed * FPS))
    steps = []
    for k in range(SHADOW_WAIT + n_in + SHADOW_REST):
        t = k / FPS
        q = joints_at(t)
        s = SHADOW_REACH if k < SHADOW_WAIT else max(0.0, SHADOW_REACH - (k - SHADOW_WAIT) * speed / FPS)
        pos, R = link_pose(world, q)
        phase = "waits" if k < SHADOW_WAIT else ("slides in" if s > 0.0 else "rests")
        steps.append(Step(t, q, pos + R @ (place + s * out), phase=phase, hand_R=R @ hand_R, hand_size=THIN_HAND))
    return steps


#: A broken memory for the judge to catch: its Robot_k (design §8a, where no person can be) is the padded capsules
#: grown by this much (metres), so that it takes the space round the links, where the hand waits, for the robot.
SWALLOWING = 0.3


def swallowing_monitor(world: World) -> dg.DistanceMonitor:
    robot = RobotModel.default()
    radii = np.array([capsule.radius for capsule in robot.capsules]) + SWALLOWING

    def inner_capsules_world(q, *, check=True):
        return np.column_stack([robot.capsule_segments(q, check=False).reshape(-1, 6), radii])

    object.__setattr__(robot, "inner_capsules_world", inner_capsules_world)  # RobotModel is a frozen dataclass
    return dg.DistanceMonitor(world.rig, rho=RHO, aggregate="min", robot=robot, fusion_margin=MARGIN,
                              fusion_pixels=PAD)


def hand_gap(world: World, f: Frame) -> float:
    """The true distance (metres, pybullet) from the frame's hand to the robot at the frame's joints."""
    world.pose_robot(f.step.q)
    radius, length = f.hand.size
    shape = p.createCollisionShape(p.GEOM_CAPSULE, radius=radius, height=length, physicsClientId=world.robot_only)
    try:
        found = p.getClosestPoints(bodyA=-1, bodyB=world.bodies[1], distance=1.0, collisionShapeA=shape,
                                   collisionShapePositionA=f.hand.centre.tolist(),
                                   collisionShapeOrientationA=ps._matrix_to_quaternion(f.hand.T_world_obstacle[:3, :3]),
                                   physicsClientId=world.robot_only)
    finally:
        p.removeCollisionShape(shape, physicsClientId=world.robot_only)
    return min(point[8] for point in found)


@pytest.fixture(scope="module")
def shadow(world):
    """Scenario 4 at 1.5 m/s (relative to the link) to the default memory, none and the swallowing one."""
    monitors = {"memory": monitor(world), "none": monitor(world, memory=False), "swallowing": swallowing_monitor(world)}
    return list(play(world, shadow_steps(world, 1.5), monitors, np.random.default_rng(4)))


def test_the_thin_hand_scene_is_what_it_claims(world, shadow):
    """Scenario 4 (``shadow_steps``) holds what it says: the hand never moves faster than 1.9 m/s in the world; both
    cameras show it while it waits; while it rests the principal camera shows none of its pixels, the second at most
    one, and in at least half the frames neither shows any; it rests 2-10 mm from the robot and never touches it."""
    speeds = [np.linalg.norm(b.step.hand - a.step.hand) * FPS for a, b in zip(shadow[:-1], shadow[1:])]
    gaps = np.array([hand_gap(world, f) for f in shadow])
    resting = np.array([f.step.phase == "rests" for f in shadow])
    print(f"\nscenario 4: {len(shadow)} frames; hand speed up to {max(speeds):.2f} m/s; gap to the robot while it "
          f"rests {gaps[resting].min() * 1e3:.1f}-{gaps[resting].max() * 1e3:.1f} mm; pixels while it waits "
          f"{[tuple(f.hand_pixels.values()) for f in shadow if f.step.phase == 'waits']}")
    assert max(speeds) <= 1.9
    assert all(min(f.hand_pixels.values()) > 0 for f in shadow if f.step.phase == "waits")
    pixels = np.array([(f.hand_pixels["p"], f.hand_pixels["s"]) for f in shadow if f.step.phase == "rests"])
    assert np.all(pixels[:, 0] == 0) and np.all(pixels[:, 1] <= 1) and np.mean(pixels.sum(1) == 0) >= 0.5
    assert resting.sum() == SHADOW_REST
    assert np.all(gaps > 0.0) and 0.002 <= gaps[resting].min() and gaps[resting].max() <= 0.01


def test_a_thin_hand_resting_where_no_camera_sees_is_never_read_too_far(shadow):
    """Issue 35's judge (its item 7): the 25 mm hand slides at up to v_max into the space that both cameras' views of
    a link hide and rests there within 1 cm of the link while the robot moves. At every frame and point, flagged or
    not: memory <= truth + tolerance, memory >= no memory, and a distance the memory raised carries ``remembered``
    (``check_memory_frame``).

    Why it holds today: the hand at rest lies within the self-filter's shell round the link, which every answer counts
    as possibly occupied, and the memory clears nothing there (design §8a). The judge is for the day it does: a memory
    that clears the shell must still leave this hand (``test_the_judge_catches_a_memory_that_swallows_the_hand``).

    Measured: 35 frames, the largest memory - (truth + tolerance) -0.66 mm; the memory raises no distance here.
    """
    worst, raised = -np.inf, 0
    for f in shadow:
        check_memory_frame(f)
        over = f.over("memory")
        worst = max(worst, float(over[np.isfinite(over)].max()))
        raised += int(np.count_nonzero(np.minimum(f.results["memory"].distance, RHO)
                                       > np.minimum(f.results["none"].distance, RHO) + 1e-3))
    print(f"\nscenario 4: largest memory - (truth + tolerance) {worst * 1e3:.2f} mm; distances raised by memory "
          f"{raised}")


def test_faster_than_v_max_a_thin_hand_read_too_far_is_flagged_remembered(world):
    """Scenario 4 with the hand sliding in at 6 m/s (three times v_max): outside the guarantee, so an answer above
    truth + tolerance may come, but only with ``remembered``; without memory none comes. Measured: none comes (the
    hand is in the self-filter's shell, as at v_max)."""
    monitors = {"memory": monitor(world), "none": monitor(world, memory=False)}
    optimistic = 0
    for f in play(world, shadow_steps(world, 6.0), monitors, np.random.default_rng(5)):
        over, over_none = f.over("memory"), f.over("none")
        assert not np.any(over_none > EPS), f"without memory: {f.describe('none', int(np.argmax(over_none)))}"
        bad = np.flatnonzero(over > EPS)
        unflagged = bad[~f.remembered("memory")[bad]]
        assert len(unflagged) == 0, f"optimistic and not flagged: {f.describe('memory', unflagged[0])}"
        optimistic += len(bad)
    print(f"\nscenario 4 at 6 m/s: {optimistic} points above truth + tolerance, all flagged remembered")


def test_the_judge_catches_a_memory_that_swallows_the_hand(shadow):
    """The judge of scenario 4 can fail: a memory whose Robot_k is the padded capsules grown by SWALLOWING (it takes
    the space where the hand waits for the robot's inside) fails ``check_memory_frame``: it reads points too far while
    the hand slides in, and raises distances without ``remembered``. Measured: the check fails in all 35 frames;
    points too far in 3 frames while the hand slides in, by up to 12.6 mm."""
    failures, optimistic, worst = [], [], -np.inf
    for f in shadow:
        try:
            check_memory_frame(f, "swallowing")
        except (AssertionError, pytest.fail.Exception) as failure:
            failures.append(str(failure))
        over = f.over("swallowing")
        if np.any(over > EPS):
            optimistic.append(f.step.phase)
        worst = max(worst, float(over[np.isfinite(over)].max()))
    print(f"\nswallowing memory: the check fails in {len(failures)} of {len(shadow)} frames; points too far in "
          f"{len(optimistic)} frames ({sorted(set(optimistic))}), by up to {worst * 1e3:.1f} mm")
    assert optimistic and len(failures) >= len(optimistic)
