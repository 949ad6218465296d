"""Camera placement: which space within rho of the robot no camera of a rig can clear.

"A correct positioning of the cameras is crucial" (2016 paper). For a rig and a robot, at a few robot poses, this
renders what each camera would see of the robot alone in an empty room (the robot and a floor, nothing else) and
asks the monitor itself, through the depth grid, which space near the robot it clears:

- Frames: per pose and camera, noise-free ``float32`` metres: the robot's collision meshes
  (:class:`~depthguard.self_filter.RobotSilhouette`, ``geometry="meshes"``, no padding) and a floor at the bottom of
  the rig's workspace (:func:`~depthguard.scenes.render_depth`), the nearer of the two per pixel. The room is empty:
  a ray that meets neither within the camera's ``depth_range`` reads the range's far end (or
  ``config.DEPTH_GRID_UNBOUNDED_END`` when it has none), "seen empty up to there", not "no measurement".
- Samples: a grid of ``spacing`` metres (3 cm) around the robot, kept where the distance to the robot's padded link
  capsules (:meth:`~depthguard.robots.RobotModel.capsules_world`) is between ``clearance`` (2 cm) and rho, and far
  enough above the floor that the floor's own measurement does not reach them.
- Clearable: a :class:`~depthguard.DistanceMonitor` of the rig with ``rho = spacing``, ``aggregate="min"``, the
  robot filtered out and no memory (``memory=False``) is queried at every sample, on the noise-free frames. A
  sample is **not clearable** when the monitor's fully conservative distance, ``min(distance, blind_distance)``, is
  below ``spacing``: some space that no camera clears lies within one sample spacing of it. Two kinds:

  - *occupied*: ``distance < spacing``, space the monitor counts as possibly occupied because no secondary camera
    sees through it (design §8). This is what makes control points' distances small: false alarms.
  - *unchecked*: only ``blind_distance < spacing``, space hidden behind the robot that the monitor does not check
    and flags ``robot_blind_spot``. With one camera, everything behind the robot as it sees it; with several, none:
    the depth grid checks the space behind the robot and between its links (docs/design.md, "Several
    cameras"). It depends on the principal camera's view only, not on where the other cameras are.

  The fractions are of the samples, per pose and over all poses.
- Control points: among those farther than rho + ``USEFUL_MARGIN`` from the floor (the only thing in the room), the
  share whose fused distance (the user's rho, the monitor's defaults: ``hybrid``, self-filter ``hulls``; no memory)
  is below rho: the false alarms the rig gives for points on the robot with nothing but the robot in the room. Twice:
  on the noise-free frames (what the placement alone leaves), and on the same frames with the axial noise of the
  rig's noise model (:func:`with_noise`), as real cameras measure. The latter is what ``fusion-workcell`` measures for
  the same layout (its ``fused`` column, without memory) in frames where the person is far.

The numbers answer different questions. A control point's distance is small as soon as any occupied space lies
within rho of it, however thin: a shell a few centimetres thick behind each link, that no other camera sees through
(within its noise margin of the link), puts the control points of that link below rho while it is a small share of
the volume around the robot.

A rig of one camera is not refused: the monitor answers by the single-camera method, whose blind spot is everything
behind the robot as that camera sees it, and every sample there is not clearable (unchecked).

Left out: sensor dropouts, other objects and walls (their shadows), people, and the free-space memory (design section
8a), which clears more over time.

One more camera (:func:`suggest_camera`, ``--suggest``): of 36 places round the robot, the one whose line of sight
reaches past most of the samples the rig cannot clear; the command then runs the coverage again with it.

    depthguard coverage --rig RIG.yaml [--robot URDF|iiwa|panda] [--trajectory joint_states.csv] [--rho 0.4]
                        [--out DIR] [--suggest]
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

import depthguard as dg
from depthguard import config
from depthguard.io.files import atomic_write
from depthguard.errors import InputError
from depthguard.validation import check_real

#: Sample spacing, metres; also the rho of the monitor queried at the samples.
SPACING = 0.03
#: Samples start this far outside the robot's padded link capsules, metres.
CLEARANCE = 0.02
#: At most this many poses are taken from a trajectory, evenly spread over its rows.
MAX_POSES = 20
#: The default poses of pybullet_data's KUKA iiwa: scenario B's posture and its poses at 0, 0.9375, 1.875 and
#: 2.8125 s, a quarter lap of the hexagon apart (the lab's scenario_b.yaml, the joints its trajectory gives then),
#: radians in the robot's joint order.
IIWA_POSES = (
    ("posture", (0.0, 0.5, 0.0, -1.5, 0.0, 0.8, 0.0)),
    ("t=0 s", (0.24693957322781496, 0.32832450781954975, 0.21194599440962722, -1.3930643345102558,
               0.03900507001940794, 0.7852892567540108, 5.192295566304192e-18)),
    ("t=0.9375 s", (-0.00042396856440594087, 0.12240663577118355, 0.00043187817167778344, -1.1984038647325612,
                    0.00025339576458312545, 0.7400656004643819, 4.931631850646225e-19)),
    ("t=1.875 s", (-0.24436479870928343, 0.3260082965334595, -0.210244788056201, -1.3957893566169253,
                   -0.038302586401182864, 0.7857805854044835, 1.8870710037391187e-18)),
    ("t=2.8125 s", (-2.1688753924421333e-05, 0.49676386943502565, 4.297538063542834e-07, -1.6588200763669645,
                    0.00012220082368162436, 0.855948331183612, 1.1728351199773781e-18)),
)
#: Control points count as far from everything when farther than rho + this from the floor (fusion-workcell's
#: "useful" margin).
USEFUL_MARGIN = 0.05
#: Seed of the noise added to the frames (:func:`with_noise`); pose i draws from ``default_rng([NOISE_SEED, i])``.
NOISE_SEED = 8
#: Poses drawn in the picture.
PLOTTED_POSES = 4
#: rho, metres: at least the clearance plus one spacing (else no sample), at most 1 m (the samples fill rho around
#: the robot: about 10^6 of them at 1 m).
RHO_RANGE = (0.05, 1.0)


@dataclass
class PoseCoverage:
    """One pose's coverage. Shapes: s samples, m control points.

    Attributes:
        label: how the pose was chosen (``"posture"``, ``"t=0.94 s"``, ``"row 12, t=0.4 s"``, ``"zero"``).
        joints: (n,) float64, radians (metres for prismatic joints), ``robot.joint_names`` order.
        samples: (s, 3) float64, metres, world frame: the sample points.
        distance: (s,) float64, metres: the monitor's distance at rho = spacing (inf: nothing within it).
        blind_distance: (s,) float64, metres: the monitor's distance to unchecked space behind the robot (inf: none
            within rho = spacing).
        occupied: (s,) bool: ``distance < spacing``.
        unchecked: (s,) bool: ``blind_distance < spacing`` and not ``occupied``.
        control_points: (m, 3) float64, metres, world frame.
        control_distance: (m,) float64, metres: the fused distance at rho on the noise-free frames (inf: nothing
            within rho).
        control_distance_noisy: (m,) float64, metres: the same on the frames with the rig's noise
            (:func:`with_noise`).
        control_far: (m,) bool: the control point is farther than rho + USEFUL_MARGIN from the floor.
        capsules: (k, 2, 3) float64 end points, metres, world frame, of the link capsules' axes (for the picture).
        rho: metres, the control points' surveillance radius.
    """

    label: str
    joints: np.ndarray
    samples: np.ndarray
    distance: np.ndarray
    blind_distance: np.ndarray
    occupied: np.ndarray
    unchecked: np.ndarray
    control_points: np.ndarray
    control_distance: np.ndarray
    control_distance_noisy: np.ndarray
    control_far: np.ndarray
    capsules: np.ndarray
    rho: float

    @property
    def not_clearable(self) -> np.ndarray:
        """(s,) bool: occupied or unchecked: ``min(distance, blind_distance) < spacing``."""
        return self.occupied | self.unchecked

    @property
    def control_alarms(self) -> np.ndarray:
        """(m,) bool: far control points whose fused distance on the noise-free frames is below rho."""
        return self.control_far & (self.control_distance < self.rho)

    @property
    def control_alarms_noisy(self) -> np.ndarray:
        """(m,) bool: far control points whose fused distance on the frames with the rig's noise is below rho."""
        return self.control_far & (self.control_distance_noisy < self.rho)


@dataclass
class Coverage:
    """A rig's coverage over some robot poses."""

    cameras: dict              # camera name -> (3,) optical centre, metres, world frame
    robot: str                 # the robot's name
    rho: float                 # metres
    spacing: float             # metres
    clearance: float           # metres
    floor: float               # world z of the floor, metres
    poses: list                # PoseCoverage, one per pose
    seconds: float             # wall-clock time

    def summary(self) -> dict:
        """Plain data for coverage.json: the settings, the figures over all poses, then each pose's."""
        return {"robot": self.robot, "rho": self.rho, "spacing": self.spacing, "clearance": self.clearance,
                "floor": self.floor, "useful_margin": USEFUL_MARGIN,
                "cameras": {n: [round(float(x), 4) for x in eye] for n, eye in self.cameras.items()},
                "seconds": self.seconds, **figures(self.poses),
                "poses": [{"label": p.label, "joints": [float(x) for x in p.joints], **figures([p]),
                           "control_distance": _metres(p.control_distance),
                           "control_distance_noisy": _metres(p.control_distance_noisy)}
                          for p in self.poses]}


def _metres(values) -> list:
    """Distances for JSON: None for inf (nothing within rho)."""
    return [float(x) if np.isfinite(x) else None for x in values]


def figures(poses) -> dict:
    """Counts and shares over ``poses`` (PoseCoverage): samples; not clearable, occupied and unchecked samples
    (counts, and ``*_fraction`` of the samples); far control points and those below rho on the noise-free frames
    (``control_alarm_fraction``: of the far ones) and with the rig's noise (``*_noisy``)."""
    samples = sum(len(p.samples) for p in poses)
    out = {"samples": samples}
    for key in ("not_clearable", "occupied", "unchecked"):
        count = sum(int(getattr(p, key).sum()) for p in poses)
        out[key] = count
        out[f"{key}_fraction"] = count / samples if samples else 0.0
    far = sum(int(p.control_far.sum()) for p in poses)
    out["control_points_far"] = far
    for suffix in ("", "_noisy"):
        alarms = sum(int(getattr(p, "control_alarms" + suffix).sum()) for p in poses)
        out["control_points_below_rho" + suffix] = alarms
        out["control_alarm_fraction" + suffix] = alarms / far if far else 0.0
    return out


def table_row(label: str, numbers: dict) -> str:
    """One line of the printed table from :func:`figures`."""
    far = numbers["control_points_far"]
    alarms = [f"{numbers['control_points_below_rho' + s]}/{far} {numbers['control_alarm_fraction' + s]:6.1%}"
              for s in ("", "_noisy")]
    return (f"{label:22s} {numbers['samples']:8d} {numbers['not_clearable_fraction']:14.2%} "
            f"{numbers['occupied_fraction']:9.2%} {numbers['unchecked_fraction']:10.2%} {alarms[0]:>16s} "
            f"{alarms[1]:>16s}")


TABLE_HEADER = (f"{'pose':22s} {'samples':>8s} {'not clearable':>14s} {'occupied':>9s} {'unchecked':>10s} "
                f"{'cp < rho, exact':>16s} {'cp < rho, noisy':>16s}")


# ------------------------------------------------------------------------------------------------------- poses

def default_poses(robot) -> list[tuple[str, np.ndarray]]:
    """(label, joints) of the default poses: with pybullet_data's KUKA iiwa, :data:`IIWA_POSES` (scenario B's
    posture and four poses of its trajectory); with any other robot, its zero configuration (clipped into the joint
    limits)."""
    from depthguard.robots import default_robot_path

    if robot.n_joints == len(IIWA_POSES[0][1]) and _same_file(robot.urdf_path, default_robot_path):
        return [(label, np.array(q, dtype=np.float64)) for label, q in IIWA_POSES]
    zero = np.clip(np.zeros(robot.n_joints), robot.lower, robot.upper)
    return [("zero", zero)]


def _same_file(path, default) -> bool:
    """Whether ``path`` is the file ``default()`` names (False when that file is not installed)."""
    try:
        return Path(path).resolve() == default().resolve()
    except Exception:  # the built-in robots' data is not installed (the robots extra): not that robot
        return False


def trajectory_poses(robot, path, max_poses: int = MAX_POSES) -> list[tuple[str, np.ndarray]]:
    """(label, joints) of at most ``max_poses`` rows, evenly spread, of a ``time,<joint names...>`` CSV file (a
    recording's joint_states.csv). Its columns must be the robot's joints (any order)."""
    from depthguard.io.recordings import read_joint_states_csv

    names, times, positions = read_joint_states_csv(Path(path))
    missing = [n for n in robot.joint_names if n not in names]
    unknown = [n for n in names if n not in robot.joint_names]
    if missing or unknown:
        raise InputError("the trajectory's joints are not the robot's (" + robot.name + "): " + "; ".join(
            part for part in (f"missing {', '.join(missing)}" if missing else "",
                              f"not the robot's {', '.join(unknown)}" if unknown else "") if part),
            source=str(path), field="joints")
    order = [names.index(n) for n in robot.joint_names]
    rows = np.unique(np.round(np.linspace(0, len(times) - 1, min(len(times), max_poses))).astype(int))
    return [(f"row {i + 1}, t={times[i]:g} s", robot.joint_vector(positions[i, order])) for i in rows]


# ----------------------------------------------------------------------------------------------------- frames

def floor_height(rig, robot, poses) -> float:
    """World z of the floor: the bottom of the rig's workspace, else the lowest point of the robot's capsules over
    the poses."""
    if rig.workspace is not None:
        return float(rig.workspace[0][2])
    return float(min(min(min(c.p0[2], c.p1[2]) - c.radius for c in robot.capsules_world(q)) for _, q in poses))


def floor_box(cameras, floor: float):
    """The floor: a box 5 cm thick whose top is at ``floor``, wide enough for the view of each of ``cameras``."""
    from depthguard.scenes import Box

    cameras = list(cameras)
    eyes = np.array([camera.T_world_camera[:3, 3] for camera in cameras])
    reach = float(np.abs(eyes[:, :2]).max()) + max(_far_end(camera) for camera in cameras)
    return Box.from_bounds([-reach, -reach, floor - 0.05], [reach, reach, floor])


def _far_end(camera) -> float:
    """Where the empty room ends for ``camera``: its depth range's far end, else config.DEPTH_GRID_UNBOUNDED_END."""
    far = camera.depth_range[1]
    return float(far) if np.isfinite(far) else config.DEPTH_GRID_UNBOUNDED_END


def _float32_range(near: float, far: float) -> tuple[np.float32, np.float32]:
    """The float32 depths nearest to [near, far] that lie inside it: a float32 that rounds past the range's end
    would read as no measurement."""
    low, high = np.float32(near), np.float32(far)
    if float(low) < near:
        low = np.nextafter(low, np.float32(np.inf))
    if float(high) > far:
        high = np.nextafter(high, np.float32(0.0))
    return low, high


def empty_room_frames(rig, silhouette, joints, floor, timestamp: float = 0.0) -> dict:
    """camera name -> noise-free :class:`~depthguard.DepthImage` (float32 metres, stamped ``timestamp``) of the
    robot at ``joints`` (``silhouette``: a :class:`~depthguard.self_filter.RobotSilhouette`, e.g. meshes without
    padding) above a floor at z = ``floor`` (a :class:`~depthguard.scenes.Box`), nothing else: the nearer of the two
    per pixel. A pixel that meets neither within the camera's depth range reads the range's far end (the empty
    room seen up to there)."""
    from depthguard.scenes import render_depth

    return {name: dg.depth_image(_room_depth(camera, render_depth(camera, [floor]), silhouette.render(camera, joints)),
                                 camera, timestamp=timestamp)
            for name, camera in rig.cameras.items()}


def _room_depth(camera, ground: np.ndarray, arm: np.ndarray) -> np.ndarray:
    """(h, w) float32 metres: the nearer of the floor's and the robot's rendered depths (0: nothing), the range's far
    end where neither lies within it."""
    depth = np.where(arm > 0, np.minimum(arm, np.where(ground > 0, ground, np.inf)), ground)
    far = _float32_range(camera.depth_range[0], _far_end(camera))[1]
    return np.where((depth <= 0) | (depth > far), far, depth).astype(np.float32)


def with_noise(frames: dict, rig, rng: np.random.Generator) -> dict:
    """The noise-free ``frames`` (:func:`empty_room_frames`) as the rig's cameras would measure them: on every
    surface within a camera's depth range, Gaussian axial noise of its noise model's sigma(d) = a + b d + c d^2
    (``camera.noise``), kept within the range, then rounded to the camera's ``depth_scale`` (a ``uint16`` sensor).
    The empty room past the range is left as it is. ``rng`` draws the noise, camera after camera in rig order."""
    noisy = {}
    for name, camera in rig.cameras.items():
        exact = np.asarray(frames[name].data, dtype=np.float64)
        near, far = float(camera.depth_range[0]), _far_end(camera)
        noise = camera.noise
        sigma = np.maximum(noise.a + exact * (noise.b + noise.c * exact), 0.0)
        measured = exact + sigma * rng.standard_normal(exact.shape)
        measured = np.round(measured / camera.depth_scale) * camera.depth_scale
        measured = np.clip(measured.astype(np.float32), *_float32_range(near, far))
        surface = (exact >= near) & (exact < far)
        noisy[name] = dg.depth_image(np.where(surface, measured, frames[name].data), camera,
                                     timestamp=frames[name].timestamp)
    return noisy


# ---------------------------------------------------------------------------------------------------- samples

def sample_points(robot, joints, rho: float, spacing: float = SPACING, clearance: float = CLEARANCE,
                  floor: float = -np.inf, rig=None) -> np.ndarray:
    """(s, 3) float64, metres, world frame: the points of a grid of ``spacing`` metres (aligned to the world's
    origin) whose distance to the robot's padded link capsules at ``joints`` lies in [``clearance``, ``rho``] and that
    lie above the floor (z = ``floor``) by more than ``spacing``. With ``rig``, also by more than the largest noise
    margin of its cameras at the point's depth plus ``config.DEFAULT_FUSION_MARGIN``: nearer, the floor's own
    measurement makes the space possibly occupied, which says nothing about the cameras' placement."""
    capsules = robot.capsules_world(joints)
    ends = np.array([[c.p0, c.p1] for c in capsules])
    radii = np.array([c.radius for c in capsules])
    grow = (radii.max() + rho)
    lo = np.floor((ends.reshape(-1, 3).min(axis=0) - grow) / spacing).astype(int)
    hi = np.ceil((ends.reshape(-1, 3).max(axis=0) + grow) / spacing).astype(int)
    axes = [np.arange(a, b + 1) * spacing for a, b in zip(lo, hi)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    above = grid[:, 2] - floor
    keep = above > spacing
    if rig is not None:
        margin = np.zeros(len(grid))
        for camera in rig.cameras.values():
            depth = np.maximum(camera.world_to_camera(grid)[:, 2], 0.0)
            margin = np.maximum(margin, camera.noise.margin(depth))
        keep &= above > spacing + margin + config.DEFAULT_FUSION_MARGIN
    grid = grid[keep]
    gap = np.full(len(grid), np.inf)
    for capsule in capsules:
        gap = np.minimum(gap, capsule.distance(grid))  # to the capsule's surface; 0 inside
    return np.ascontiguousarray(grid[(gap >= clearance) & (gap <= rho)])


# ----------------------------------------------------------------------------------------------------- the run

def coverage(rig, robot, poses, rho: float = config.DEFAULT_RHO, spacing: float = SPACING,
             clearance: float = CLEARANCE, progress: bool = False) -> Coverage:
    """The coverage of ``rig`` around ``robot`` at ``poses`` ((label, joints) pairs); see the module docstring."""
    from depthguard.self_filter import RobotSilhouette

    rho = check_real(rho, "rho", minimum=RHO_RANGE[0], maximum=RHO_RANGE[1], unit="metres", field="rho")
    spacing = check_real(spacing, "spacing", minimum=0.0, above_minimum=True, maximum=rho, unit="metres",
                         field="spacing")
    clearance = check_real(clearance, "clearance", minimum=0.0, maximum=rho, unit="metres", field="clearance")
    if not poses:
        raise InputError("no robot poses to check", field="poses")
    start = time.perf_counter()
    floor = floor_height(rig, robot, poses)
    ground = floor_box(rig.cameras.values(), floor)
    samples_monitor = dg.DistanceMonitor(rig, rho=spacing, aggregate="min", robot=robot, memory=False)
    control_monitor = dg.DistanceMonitor(rig, rho=rho, robot=robot, memory=False)
    silhouette = RobotSilhouette(robot, geometry="meshes", padding=0.0)
    results = []
    for i, (label, joints) in enumerate(poses):
        q = robot.joint_vector(joints)
        frames = empty_room_frames(rig, silhouette, q, ground, timestamp=float(i))
        samples = sample_points(robot, q, rho, spacing, clearance, floor, rig)
        distance = blind = np.zeros(0)
        if len(samples):
            answer = samples_monitor.query(frames, samples, joints=q)
            distance, blind = answer.distance, answer.blind_distance
        points = robot.control_point_positions(q)
        control = control_monitor.query(frames, points, joints=q)
        noisy = with_noise(frames, rig, np.random.default_rng([NOISE_SEED, i]))
        control_noisy = control_monitor.query(noisy, points, joints=q)
        occupied = distance < spacing
        results.append(PoseCoverage(label=label, joints=q, samples=samples, distance=distance, blind_distance=blind,
                                    occupied=occupied, unchecked=(blind < spacing) & ~occupied, control_points=points,
                                    control_distance=np.asarray(control.distance, dtype=np.float64),
                                    control_distance_noisy=np.asarray(control_noisy.distance, dtype=np.float64),
                                    control_far=points[:, 2] - floor > rho + USEFUL_MARGIN,
                                    capsules=np.array([[c.p0, c.p1] for c in robot.capsules_world(q)]), rho=rho))
        if progress:
            print("  " + table_row(label, figures(results[-1:])), flush=True)
    eyes = {name: camera.T_world_camera[:3, 3].copy() for name, camera in rig.cameras.items()}
    return Coverage(cameras=eyes, robot=robot.name, rho=rho, spacing=spacing, clearance=clearance, floor=floor,
                    poses=results, seconds=time.perf_counter() - start)


# ---------------------------------------------------------------------------------------------- one more camera

#: Where :func:`suggest_camera` tries one more camera: heights above the floor (metres) and how many azimuths round
#: the robot, at the rig's cameras' median horizontal distance from the robot (at least SUGGEST_MIN_RADIUS metres).
SUGGEST_HEIGHTS = (0.6, 1.4, 2.2)
SUGGEST_AZIMUTHS = 12
SUGGEST_MIN_RADIUS = 1.5


@dataclass
class Suggestion:
    """One more camera for the rig, and what it would clear.

    Attributes:
        camera: a :class:`~depthguard.PinholeCamera` named "suggested": the principal's intrinsics, range and noise
            model, at ``eye`` looking at ``target`` (world, metres).
        sees_past: the share of the rig's not-clearable samples, over every pose, that this camera sees past: each
            one's line of sight from the camera meets neither the robot nor the floor before the sample, and the
            nearest surface the camera measures within a pixel of it lies beyond it by more than twice its noise
            margin, the monitor's fusion margin and a sample spacing (:func:`sees_past`).
        tried: how many candidate places were tried.
    """

    camera: object
    eye: np.ndarray
    target: np.ndarray
    sees_past: float
    tried: int


def candidate_cameras(rig, robot, poses, floor: float) -> tuple[np.ndarray, list]:
    """(target, cameras): the places :func:`suggest_camera` tries (see SUGGEST_HEIGHTS), cameras named "suggested"
    with the principal's intrinsics, range and noise, each looking at ``target``, the centre of the robot's control
    points over ``poses`` ((3,) world metres)."""
    from depthguard.transforms import look_at

    model = rig.cameras[rig.principal]
    target = np.mean([robot.control_point_positions(robot.joint_vector(q)) for _, q in poses], axis=(0, 1))
    eyes = np.array([camera.T_world_camera[:3, 3] for camera in rig.cameras.values()])
    radius = max(SUGGEST_MIN_RADIUS, float(np.median(np.linalg.norm(eyes[:, :2] - target[:2], axis=1))))
    out = []
    for height in SUGGEST_HEIGHTS:
        for k in range(SUGGEST_AZIMUTHS):
            angle = 2.0 * np.pi * k / SUGGEST_AZIMUTHS
            eye = np.array([target[0] + radius * np.cos(angle), target[1] + radius * np.sin(angle), floor + height])
            out.append(model.replace(name="suggested", T_world_camera=look_at(eye, target)))
    return target, out


def sees_past(camera, depth: np.ndarray, samples: np.ndarray, spacing: float) -> np.ndarray:
    """(s,) bool: whether ``camera`` sees past each of ``samples`` ((s, 3) world metres) in its noise-free ``depth``
    ((h, w) optical z, metres; the far end of its range where it sees nothing): the sample lies in its view and
    range, and every pixel within one of the sample's reads farther than the sample by more than twice the noise
    margin there, the monitor's default fusion margin and ``spacing`` (metres)."""
    local = camera.world_to_camera(np.asarray(samples, dtype=np.float64))
    z = local[:, 2]
    out = np.zeros(len(local), dtype=bool)
    ahead = z > camera.depth_range[0]
    u = np.full(len(local), -1, dtype=np.int64)
    v = np.full(len(local), -1, dtype=np.int64)
    u[ahead] = np.round(camera.fx * local[ahead, 0] / z[ahead] + camera.cx).astype(np.int64)
    v[ahead] = np.round(camera.fy * local[ahead, 1] / z[ahead] + camera.cy).astype(np.int64)
    inside = ahead & (u >= 1) & (u < camera.width - 1) & (v >= 1) & (v < camera.height - 1)
    if not inside.any():
        return out
    nearest = depth.astype(np.float64)
    for axis in (0, 1):  # the smallest depth within one pixel (3 x 3)
        nearest = np.minimum(np.minimum(nearest, np.roll(nearest, 1, axis)), np.roll(nearest, -1, axis))
    seen = nearest[v[inside], u[inside]]
    need = z[inside] + 2.0 * camera.noise.margin(seen) + config.DEFAULT_FUSION_MARGIN + spacing
    out[inside] = seen > need
    return out


def suggest_camera(rig, robot, poses, result: "Coverage") -> "Suggestion | None":
    """Where one more camera would see past most of what ``rig`` cannot clear (``result``, its :func:`coverage` at
    ``poses``): of :func:`candidate_cameras`, the one that :func:`sees_past` the largest share of the not-clearable
    samples over every pose; None when every sample is clearable. A proxy, fast enough to try many places: run
    :func:`coverage` on the rig with the suggested camera to know what it clears (``depthguard coverage --suggest``
    does)."""
    from depthguard.scenes import render_depth
    from depthguard.self_filter import RobotSilhouette

    targets = [(p.joints, p.samples[p.not_clearable]) for p in result.poses]
    total = sum(len(samples) for _, samples in targets)
    if total == 0:
        return None
    target, candidates = candidate_cameras(rig, robot, poses, result.floor)
    ground = floor_box(list(rig.cameras.values()) + candidates, result.floor)
    silhouette = RobotSilhouette(robot, geometry="meshes", padding=0.0)
    best, best_count = None, -1
    for camera in candidates:
        floor_depth = render_depth(camera, [ground])
        count = 0
        for joints, samples in targets:
            if len(samples):
                depth = _room_depth(camera, floor_depth, silhouette.render(camera, joints))
                count += int(np.count_nonzero(sees_past(camera, depth, samples, result.spacing)))
        if count > best_count:
            best, best_count = camera, count
    return Suggestion(camera=best, eye=best.T_world_camera[:3, 3].copy(), target=target,
                      sees_past=best_count / total, tried=len(candidates))


# ---------------------------------------------------------------------------------------------------- picture

def plot(result: Coverage, path, poses: int = PLOTTED_POSES) -> Path:
    """A PNG: for each of the first ``poses`` poses, a top view (x-y) and a side view (x-z) of the samples
    (clearable: light blue; occupied: red; unchecked: orange; drawn over the clearable ones), the robot's capsule
    axes (black), its control points and the cameras (blue triangles)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    shown = result.poses[:poses]
    fig, axes = plt.subplots(len(shown), 2, figsize=(13, 5.2 * len(shown)), squeeze=False)
    eyes = np.array(list(result.cameras.values()))
    for row, pose in zip(axes, shown):
        numbers = figures([pose])
        kinds = ((~pose.not_clearable, dict(s=1, c="#9ecae1", alpha=0.2, label="clearable")),
                 (pose.unchecked, dict(s=4, c="tab:orange", alpha=0.6, label="unchecked (behind the robot)")),
                 (pose.occupied, dict(s=9, c="tab:red", alpha=0.9, label="occupied (no camera sees through)")))
        for ax, (a, b), view in zip(row, ((0, 1), (0, 2)), ("top view (x-y)", "side view (x-z)")):
            for mask, style in kinds:
                ax.scatter(pose.samples[mask, a], pose.samples[mask, b], lw=0, rasterized=True, **style)
            for p0, p1 in pose.capsules:
                ax.plot([p0[a], p1[a]], [p0[b], p1[b]], "k-", lw=2.5)
            ax.plot(pose.control_points[:, a], pose.control_points[:, b], "k.", ms=7, label="control points")
            ax.plot(eyes[:, a], eyes[:, b], "b^", ms=9, label="cameras")
            places: dict = {}  # cameras that coincide in this view share one label
            for name, eye in result.cameras.items():
                places.setdefault((round(float(eye[a]), 2), round(float(eye[b]), 2)), []).append(name)
            for place, names in places.items():
                ax.annotate(", ".join(names), place, textcoords="offset points", xytext=(5, 5), fontsize=8,
                            color="tab:blue")
            if b == 2:
                ax.axhline(result.floor, color="grey", lw=0.8, ls="--")
            ax.set_aspect("equal", adjustable="datalim")
            ax.set_xlabel("x [m]")
            ax.set_ylabel("y [m]" if b == 1 else "z [m]")
            ax.set_title(f"{pose.label}, {view}\n{numbers['samples']} samples: occupied "
                         f"{numbers['occupied_fraction']:.2%}, unchecked {numbers['unchecked_fraction']:.2%}; control "
                         f"points < rho: {numbers['control_points_below_rho']}/{numbers['control_points_far']} "
                         f"(with noise {numbers['control_points_below_rho_noisy']})",
                         fontsize=9)
            ax.grid(alpha=0.3)
    handles, labels = axes[0][0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="upper center", ncol=len(labels), fontsize=9, markerscale=2,
               bbox_to_anchor=(0.5, 1.0 - 0.35 / fig.get_figheight()))
    fig.suptitle(f"{result.robot}: space within rho = {result.rho:g} m of the robot that no camera clears (samples "
                 f"every {result.spacing * 100:g} cm, from {result.clearance * 100:g} cm outside the padded capsules)",
                 y=1.0 - 0.1 / fig.get_figheight(), fontsize=11)
    fig.tight_layout(rect=(0, 0, 1, 1.0 - 0.75 / fig.get_figheight()))
    path = Path(path)
    with atomic_write(path, "wb") as f:
        fig.savefig(f, format=Path(path).suffix[1:].lower() or None, dpi=80)  # as savefig(path) picks it
    plt.close(fig)
    return path


# ------------------------------------------------------------------------------------------------------ the CLI



