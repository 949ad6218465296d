"""The image-based collision test of Henrich & Gecks (design §10) judged by code the project did not write
(design §13): pybullet draws the images and pybullet measures the truth.

Scene. pybullet (DIRECT mode) holds the UFactory xArm 6 of ``pybullet_data`` (``xarm/xarm6_robot.urdf``, fixed base
at the origin), a floor of grey patches and, as the unknown obstacle, a dark violet box where many configurations of
the arm pass. Four cameras stand 2.1-2.4 m from the robot at heights of 1.1-2.0 m. pybullet's TinyRenderer
(``getCameraImage``, no shadows, one directional light) draws each camera's colour image from a view and projection
matrix derived from the depthguard camera (``tests/pybullet_scenes.py`` states the conventions); the test converts it
to 8-bit grey (ITU-R BT.601 luma). depthguard models the same robot from the same URDF (``RobotModel.from_urdf``);
joints are mapped to pybullet's by name.

The run, per resolution (352x288 in 32x32 tiles, and scenario C's 704x576 in 64x64 tiles; design §12):
reference images from nine configurations without the box; one set of images with the box and the robot at a current
configuration 0.2 m or more from it; then the verdicts (``ConfigurationTable``) of 660 future configurations, seeded:
150 uniform within the joint limits, and every configuration of a seeded pool of 6,000 that penetrates the box or
comes within 5 cm of it; and pybullet's ``getClosestPoints`` between the arm and the box for each.

Claims judged:

- No missed collision. A configuration whose true distance to the box is below the safety margin, the robot's
  padding (``RobotModel.padding``, 2 cm; penetration included), always gets ``collision=True``. Why the padding: the
  test projects the robot's capsules, which contain every link's collision mesh grown by the padding, onto the tiles,
  conservatively; pybullet measures to the convex pieces of those same meshes. Below the padding the padded solid
  meets the box in space, so in every camera the robot's tile image meets the box's. Beyond it they may still share
  a tile (a tile spans 3-9 cm at these distances) but nothing is promised. What the method assumes besides: the box
  changes the tiles it covers enough to be foreground (a contrast of ~100 grey levels; a tile it barely touches
  stays background), and the current robot's tile image meets the box's in at most theta = 1 camera (the test
  chooses the current configuration so and checks it, ``test_the_current_configuration_respects_theta``). That last
  condition is stronger than the documented meaning of theta; the last test shows the paper's theta = 1 missing
  collisions where it fails, and the default theta = C - 1 missing none. Class B counts as a collision (the default
  ``unseen="occupied"``).
- The false-alarm rate, reported (``pytest -s``): the share of collision verdicts among configurations farther than
  ``far`` from the box, ``far`` = the padding plus a tile's diagonal at the farthest workspace depth (closer than
  that, a shared tile is the tile resolution's price). Asserted only loosely (below ``FALSE_ALARM_BOUND``).
- The judge has teeth: enough true collisions and free configurations are sampled, and a blind collision test
  (thresholds no change reaches) judged the same way misses every collision.
- The images are those the camera model describes: the box's rendered pixels are exactly those whose centres its
  projected outline (depthguard's ``PinholeCamera.project``) holds, and a camera half a pixel or 0.1 degree off fails
  that check; every pixel pybullet draws of the robot lies in a tile of depthguard's robot image; depthguard's
  joints, limits and link poses are pybullet's.
- Swept volumes miss no collision of an intermediate configuration. Motions (``test_motion([a, b])``, a straight
  segment in joint space) whose two ends pybullet puts farther from the box than the padding, but whose dense samples
  come closer than it or penetrate the box, are always judged collisions. The judge samples each motion in at least
  200 equal steps and so finely that no point of the robot moves more than 5 mm between two samples (the sum of the
  joints' |change| times 1 m, which bounds every point's distance from the axis of every joint that moves it: pybullet's
  link AABBs reach 0.84 m). The motions are seeded: through configurations that penetrate or graze the box, each end
  moved out along the line to beyond 12 cm from it; and through uniform configurations (most stay clear). The
  false-alarm rate of motions whose every sample stays beyond ``far`` is reported, asserted loosely
  (``SWEPT_FALSE_ALARM_BOUND``); the teeth: testing only the two ends (``test(a)`` or ``test(b)``) misses most of
  the colliding motions, which the swept test catches.

Measured (these seeds; ``pytest -s`` prints them): 211 of the 660 configurations penetrate the box, 337 are closer
than 2 cm; none is missed at either resolution. Every configuration judged free is at least 6.3 cm (352x288) and
4.5 cm (704x576) from the box; between 2 cm and ``far`` 91 % and 97 % are judged collisions. False alarms beyond
``far`` (16.2 cm, 9.1 cm): 1 of 115 (0.9 %) and 0 of 133. The blind test misses 211 of 211. Motions: 121, of which
64 have both ends beyond 2 cm (the nearest end 3.3 cm) and pass closer, 49 of them through the box; the swept test
misses none at either resolution, testing the ends only misses 48 (352x288) and 59 (704x576) of the 64. False alarms
of motions staying beyond ``far``: 0 of 31 and 2 of 46 (4.3 %). About 25 s for the file.
What this judge cannot see: tiles are 3-9 cm wide, so a robot image without its 2 cm padding, or a difference image
without its closing, misses nothing here either (tried by mutating the library: both pass; dropping the epipolar
confirmation, halving the bands' depth range, shifting the robot image by one tile, demanding all cameras for a
collision or tripling the thresholds is caught). Nor how finely a motion is sampled: the robot is seen a tile
(3-9 cm) larger than it is and the box spans 14-18 cm, so testing every 32nd of test_motion's samples alone (about
4 configurations per motion), without widening, also misses none of the 64 (tried); only the ends alone miss.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np
import pytest

import pybullet as p  # the judge is required: a missing one must fail, never skip
import pybullet_data

import depthguard as dg
import pybullet_scenes as ps
from depthguard.collision import OBSTACLE, POSSIBLE, UNKNOWN, ConfigurationTable, ImageCollisionTest
from depthguard.robots import RobotModel
from depthguard.transforms import look_at

URDF = "xarm/xarm6_robot.urdf"

#: The obstacle: centre (world, metres), half extents (metres) and colour (dark violet: grey ~30 after shading,
#: against floor patches of grey ~90-190).
BOX_CENTRE = (0.36, 0.26, 0.30)
BOX_HALF = (0.07, 0.07, 0.09)
BOX_RGBA = (0.30, 0.0, 0.40, 1.0)
#: Where the box waits while the reference images are taken: far outside every camera's view.
BOX_AWAY = (0.0, 0.0, 60.0)

#: The floor: FLOOR_PATCHES x FLOOR_PATCHES square patches of FLOOR_PATCH metres, random greys in FLOOR_GREYS.
FLOOR_PATCHES = 12
FLOOR_PATCH = 0.5
FLOOR_GREYS = (0.35, 0.75)
LIGHT_DIRECTION = (0.6, -0.4, 1.0)

#: The cameras: (azimuth in degrees, horizontal distance from the robot's axis, height), metres; all look at TARGET.
EYES = ((0.0, 2.3, 1.6), (80.0, 2.1, 1.1), (170.0, 2.4, 2.0), (260.0, 2.2, 1.4))
TARGET = (0.15, 0.05, 0.35)
#: (width, height, focal length in pixels, tiles (rows, cols)). The principal point is off centre by a few pixels so
#: that a convention error in it shows.
RESOLUTIONS = {"352x288": (352, 288, 400.0, (32, 32)), "704x576": (704, 576, 800.0, (64, 64))}
PRINCIPAL_OFFSET = (3.7, -2.3)

#: Holds the robot (reach about 0.7 m around its shoulder at 0.27 m) and the box.
WORKSPACE = [[-0.9, -0.9, -0.05], [0.9, 0.9, 1.2]]
THETA = 1

SEED = 20240611
REFERENCE_IMAGES = 9
#: Future configurations: RANDOM_FUTURE uniform within the joint limits, plus every configuration of a seeded POOL
#: (also uniform) that penetrates the box or comes within NEAR metres of it.
RANDOM_FUTURE = 150
POOL = 6000
NEAR = 0.05

#: getClosestPoints reports pairs closer than this, metres; farther configurations count as this far.
QUERY_DISTANCE = 2.0
#: The loose bound on the false-alarm rate: the test must not pass by calling everything a collision.
FALSE_ALARM_BOUND = 0.5
#: At least this many true collisions and free configurations, or the judge has nothing to judge.
MIN_SAMPLED = 10

#: Motions (straight segments in joint space, ``test_motion([a, b])``), each through a centre configuration along a
#: seeded random direction, the first three joints (shoulder, elbow) weighted MOTION_WEIGHTS over the wrist's.
#: Crossing motions: through CROSSING_CENTRES future configurations that penetrate the box and as many that graze
#: it (closer than the padding without penetrating: the hardest case for sampling), each end moved out in
#: steps of MOTION_STEP radians (the sum of the joints' |change|) until pybullet puts it more than END_CLEARANCE from
#: the box, then up to MOTION_EXTRA further; at most MOTION_MAX per side. Free-running motions: through FREE_CENTRES
#: of the uniform future configurations, each end FREE_HALF radians away.
MOTION_WEIGHTS = (1.0, 1.0, 1.0, 0.2, 0.2, 0.2)
CROSSING_CENTRES = 40
FREE_CENTRES = 80
END_CLEARANCE = 0.12
MOTION_STEP = 0.05
MOTION_EXTRA = 0.3
MOTION_MAX = 2.5
FREE_HALF = (1.0, 2.0)
#: The judge's dense sampling of a motion: max(DENSE_SAMPLES, ceil(sum_i |b_i - a_i| AXIS_REACH / DENSE_STEP))
#: equal steps, so that no point of the robot moves more than DENSE_STEP between two samples: AXIS_REACH bounds
#: every point's distance from the axis of every joint that moves it (checked with pybullet's link AABBs).
DENSE_SAMPLES = 200
DENSE_STEP = 0.005
AXIS_REACH = 1.0
#: The loose bound on the swept test's false-alarm rate (motions that stay beyond ``far`` judged collisions).
SWEPT_FALSE_ALARM_BOUND = 0.5


# --------------------------------------------------------------------------------------------------- the world

@dataclass
class World:
    client: int
    body: int  # the arm in pybullet
    box: int  # the obstacle in pybullet
    joints: list  # pybullet joint index of each of robot.joint_names, in that order
    robot: RobotModel


@pytest.fixture(scope="module")
def world():
    client = p.connect(p.DIRECT)
    try:
        path = os.path.join(pybullet_data.getDataPath(), URDF)
        body = p.loadURDF(path, useFixedBase=True, physicsClientId=client)
        robot = RobotModel.from_urdf(path)
        by_name = {}
        for j in range(p.getNumJoints(body, physicsClientId=client)):
            info = p.getJointInfo(body, j, physicsClientId=client)
            if info[2] != p.JOINT_FIXED:
                by_name[info[1].decode()] = j
        assert set(by_name) == set(robot.joint_names), (sorted(by_name), robot.joint_names)
        rng = np.random.default_rng(SEED)
        half = FLOOR_PATCH / 2.0
        for i in range(FLOOR_PATCHES):
            for k in range(FLOOR_PATCHES):
                grey = float(rng.uniform(*FLOOR_GREYS))
                visual = p.createVisualShape(p.GEOM_BOX, halfExtents=[half, half, 0.005],
                                             rgbaColor=[grey, grey, grey, 1.0], physicsClientId=client)
                centre = [(i - FLOOR_PATCHES / 2 + 0.5) * FLOOR_PATCH, (k - FLOOR_PATCHES / 2 + 0.5) * FLOOR_PATCH,
                          -0.005]
                p.createMultiBody(0, -1, visual, basePosition=centre, physicsClientId=client)
        collision = p.createCollisionShape(p.GEOM_BOX, halfExtents=list(BOX_HALF), physicsClientId=client)
        visual = p.createVisualShape(p.GEOM_BOX, halfExtents=list(BOX_HALF), rgbaColor=list(BOX_RGBA),
                                     physicsClientId=client)
        box = p.createMultiBody(0, collision, visual, basePosition=list(BOX_CENTRE), physicsClientId=client)
        yield World(client, body, box, [by_name[name] for name in robot.joint_names], robot)
    finally:
        p.disconnect(client)


def set_joints(world: World, q) -> None:
    for j, value in zip(world.joints, q):
        p.resetJointState(world.body, j, float(value), physicsClientId=world.client)


def place_box(world: World, centre) -> None:
    p.resetBasePositionAndOrientation(world.box, list(centre), [0.0, 0.0, 0.0, 1.0], physicsClientId=world.client)


def true_distance(world: World, q) -> float:
    """pybullet's signed distance between the arm at ``q`` and the box, metres (negative: penetration)."""
    set_joints(world, q)
    contacts = p.getClosestPoints(world.body, world.box, QUERY_DISTANCE, physicsClientId=world.client)
    return min((c[8] for c in contacts), default=QUERY_DISTANCE)


def above_floor(world: World, q, clearance: float = 0.1) -> bool:
    """Whether every link frame of the arm at ``q`` is higher than ``clearance`` (a pose the renderer can show)."""
    set_joints(world, q)
    return all(p.getLinkState(world.body, j, physicsClientId=world.client)[4][2] > clearance for j in world.joints)


def cameras(resolution: str) -> dict:
    width, height, focal, _ = RESOLUTIONS[resolution]
    out = {}
    for k, (azimuth, distance, height_m) in enumerate(EYES):
        a = np.radians(azimuth)
        eye = (distance * np.cos(a), distance * np.sin(a), height_m)
        out[f"c{k}"] = dg.PinholeCamera(f"c{k}", width, height, focal, focal, (width - 1) / 2 + PRINCIPAL_OFFSET[0],
                                        (height - 1) / 2 + PRINCIPAL_OFFSET[1], look_at(eye, TARGET))
    return out


def render(world: World, camera) -> tuple[np.ndarray, np.ndarray]:
    """pybullet's image of ``camera``: ((h, w) uint8 grey, BT.601 luma of the colour image; (h, w) int body ids of
    the segmentation mask, -1 where nothing is drawn)."""
    _, _, rgba, _, segmentation = p.getCameraImage(
        camera.width, camera.height, viewMatrix=ps.view_matrix(camera), projectionMatrix=ps.projection_matrix(camera),
        renderer=p.ER_TINY_RENDERER, lightDirection=list(LIGHT_DIRECTION), shadow=0, physicsClientId=world.client)
    rgb = np.asarray(rgba, dtype=np.float64).reshape(camera.height, camera.width, 4)[..., :3]
    grey = np.rint(rgb @ np.array([0.299, 0.587, 0.114])).clip(0, 255).astype(np.uint8)
    return grey, np.asarray(segmentation).reshape(camera.height, camera.width)


def box_corners() -> np.ndarray:
    """(8, 3) the box's corners, world frame, metres."""
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=np.float64)
    return np.asarray(BOX_CENTRE) + signs * np.asarray(BOX_HALF)


def box_outline_distance(camera) -> np.ndarray:
    """(h, w) signed distance, pixels, from each pixel centre to the box's outline as depthguard's camera model
    projects it (the convex hull of its projected corners): negative inside."""
    from scipy.spatial import ConvexHull

    u, v, z = camera.project(camera.world_to_camera(box_corners()))
    assert np.all(z > 0)
    hull = ConvexHull(np.stack([u, v], axis=1))
    pu, pv = camera.pixel_grid()
    return np.max(hull.equations[:, 0, None, None] * pu + hull.equations[:, 1, None, None] * pv
                  + hull.equations[:, 2, None, None], axis=0)


def box_tiles(camera, grid) -> np.ndarray:
    """(rows, cols) bool: the tiles holding a pixel centre within the box's projected outline (hidden or not)."""
    inside = box_outline_distance(camera) < 0.0
    tile_row, tile_col = grid.tile_of_pixels()
    out = np.zeros((grid.rows, grid.cols), dtype=bool)
    rows, cols = np.nonzero(inside)
    out[tile_row[rows], tile_col[cols]] = True
    return out


def seeded_configurations(robot, rng, n: int) -> np.ndarray:
    """(n, joints) uniform within the joint limits, radians."""
    return rng.uniform(robot.lower, robot.upper, (n, robot.n_joints))


# --------------------------------------------------------------------------------------------------- the run

@dataclass
class Run:
    resolution: str
    cameras: dict
    test: ImageCollisionTest
    now: np.ndarray  # the current configuration (images with the box)
    overlap: list  # per camera: does the current robot's tile image meet the box's tiles
    revised: list  # the revised obstacle images of the observed images
    images: dict  # camera name -> grey image with the box
    configurations: np.ndarray  # (K, n) future configurations
    distance: np.ndarray  # (K,) pybullet's distance to the box, metres
    collision: np.ndarray  # (K,) verdicts
    klass: np.ndarray  # (K,) classes A-D
    blind: np.ndarray  # (K,) verdicts of a blind test (no tile is ever foreground)
    far: float  # metres: beyond it a collision verdict is a false alarm


def run(world: World, futures, resolution: str, now=None, theta=THETA) -> Run:
    """The whole collision test at ``resolution`` against pybullet's images, and its verdicts on ``futures``. The
    current configuration ``now`` ((n,) radians) is by default found by a seeded search: clear of the box by 0.2 m
    and, as the method assumes, its tile image meets the box's in exactly theta cameras."""
    robot = world.robot
    cams = cameras(resolution)
    tiles = RESOLUTIONS[resolution][3]
    test = ImageCollisionTest(dg.Rig(cams), robot, WORKSPACE, tiles=tiles, theta=theta)
    rng = np.random.default_rng(SEED)

    # Step 1: the reference, from the robot in several configurations and no box.
    place_box(world, BOX_AWAY)
    poses = []
    while len(poses) < REFERENCE_IMAGES:
        q = seeded_configurations(robot, rng, 1)[0]
        if above_floor(world, q):
            poses.append(q)
    stacks = {name: [] for name in cams}
    for q in poses:
        set_joints(world, q)
        for name, camera in cams.items():
            stacks[name].append(render(world, camera)[0])
    test.set_reference(stacks)
    place_box(world, BOX_CENTRE)

    # The current configuration: clear of the box, and its tile image meets the box's in exactly theta cameras (the
    # most the method allows; exactly, so that the epipolar revision has an unknown tile of the box to resolve).
    box_images = [box_tiles(grid.camera, grid) for grid in test.grids]
    if now is None:
        for _ in range(500):
            now = seeded_configurations(robot, rng, 1)[0]
            if true_distance(world, now) < 0.2 or not above_floor(world, now):
                continue
            if sum(bool(np.any(r & b)) for r, b in zip(test.robot_image(now), box_images)) == THETA:
                break
        else:
            raise AssertionError("no current configuration found whose image meets the box's in theta cameras")
    now = np.asarray(now, dtype=np.float64)
    overlap = [bool(np.any(r & b)) for r, b in zip(test.robot_image(now), box_images)]
    set_joints(world, now)
    images = {name: render(world, camera)[0] for name, camera in cams.items()}
    revised = test.observe(images, now)

    configurations, distance = futures
    table = ConfigurationTable(test, configurations)
    collision, klass = table.verdicts()
    # A blind test: thresholds no grey-value change reaches, so no tile is ever foreground.
    blind = ImageCollisionTest(dg.Rig(cams), robot, WORKSPACE, tiles=tiles, theta=theta, thresholds=(256.0, 2.0))
    blind.set_reference(stacks)
    blind_collision, _ = table.verdicts(blind.observe(images, now))

    # A tile's diagonal at the farthest workspace depth, metres.
    from depthguard.collision import workspace_depths

    diagonal = max(np.hypot(g.tile_w, g.tile_h) * workspace_depths(g.camera, WORKSPACE)[1] / min(g.camera.fx,
                                                                                                      g.camera.fy)
                   for g in test.grids)
    return Run(resolution, cams, test, now, overlap, revised, images, configurations, distance, collision,
               np.asarray(klass), blind_collision, robot.padding + diagonal)


@pytest.fixture(scope="module")
def futures(world) -> tuple[np.ndarray, np.ndarray]:
    """The future configurations, (K, n) radians, and pybullet's distance of each to the box, (K,) metres:
    RANDOM_FUTURE uniform within the joint limits, then every configuration of a seeded POOL that penetrates the box
    or comes within NEAR of it (the cases where a miss would show)."""
    place_box(world, BOX_CENTRE)
    rng = np.random.default_rng(SEED + 2)
    pool = seeded_configurations(world.robot, rng, POOL)
    pool_distance = np.array([true_distance(world, q) for q in pool])
    close = pool_distance < NEAR
    configurations = np.concatenate([seeded_configurations(world.robot, rng, RANDOM_FUTURE), pool[close]])
    return configurations, np.array([true_distance(world, q) for q in configurations])


@pytest.fixture(scope="module", params=sorted(RESOLUTIONS))
def judged(world, futures, request) -> Run:
    return run(world, futures, request.param)


# --------------------------------------------------------------------------------------------------- the model

def test_the_robot_model_is_pybullets(world):
    """depthguard's xArm has pybullet's joints (by name) and limits, and its link frames equal pybullet's at random
    configurations (to 1e-6 m and 1e-6 of rotation)."""
    robot = world.robot
    assert robot.n_joints == 6
    for name, j in zip(robot.joint_names, world.joints):
        info = p.getJointInfo(world.body, j, physicsClientId=world.client)
        assert info[1].decode() == name
        assert info[2] == p.JOINT_REVOLUTE
        assert np.isclose(info[8], robot.lower[robot.joint_names.index(name)])
        assert np.isclose(info[9], robot.upper[robot.joint_names.index(name)])
    rng = np.random.default_rng(SEED + 1)
    for q in seeded_configurations(robot, rng, 20):
        set_joints(world, q)
        poses = robot.link_poses(q)
        for j in range(p.getNumJoints(world.body, physicsClientId=world.client)):
            link = p.getJointInfo(world.body, j, physicsClientId=world.client)[12].decode()
            state = p.getLinkState(world.body, j, computeForwardKinematics=True, physicsClientId=world.client)
            R = np.array(p.getMatrixFromQuaternion(state[5])).reshape(3, 3)
            assert np.allclose(state[4], poses[link][:3, 3], atol=1e-6), link
            assert np.allclose(R, poses[link][:3, :3], atol=1e-6), link


# --------------------------------------------------------------------------------------------------- alignment

def outline_mismatch(camera, segmentation, box: int, robot_body: int, tolerance: float = 0.1) -> int:
    """Pixels where pybullet's box disagrees with depthguard's projection of it: box pixels whose centres lie
    outside the projected outline by more than ``tolerance`` pixels, and pixels inside it by more than that which
    show neither the box nor the robot (which may stand in front of it). TinyRenderer samples pixel centres
    (``test_judge_pybullet.test_pybullet_camera_convention``), so an aligned camera gives 0."""
    outline = box_outline_distance(camera)
    drawn = segmentation == box
    return int(np.sum(drawn & (outline > tolerance)) +
               np.sum(~drawn & (segmentation != robot_body) & (outline < -tolerance)))


def test_the_rendered_images_are_the_camera_models(world, judged):
    """pybullet's image and depthguard's camera model agree to a tenth of a pixel: the box's rendered pixels are
    exactly those whose centres lie in its projected outline, in every camera. The check has teeth: with the
    principal point half a pixel off (either axis), or the camera panned by 0.1 degree (0.7 pixel at f = 400), it
    fails. And every pixel pybullet draws of the robot (its visual meshes) lies in a tile of depthguard's robot image
    (its padded capsules) at the current configuration, so the robot's own tiles are accounted for."""
    from scipy.spatial.transform import Rotation

    set_joints(world, judged.now)
    for grid, robot_tiles in zip(judged.test.grids, judged.test.robot_image(judged.now)):
        camera = grid.camera
        _, segmentation = render(world, camera)
        drawn = int(np.sum(segmentation == world.box))
        assert drawn > 100, f"{camera.name}: the box is hardly seen ({drawn} pixels)"
        assert outline_mismatch(camera, segmentation, world.box, world.body) == 0, camera.name
        for shifted in (camera.replace(cx=camera.cx + 0.5), camera.replace(cy=camera.cy - 0.5)):
            assert outline_mismatch(shifted, segmentation, world.box, world.body) > 0, camera.name
        turn = np.eye(4)
        turn[:3, :3] = Rotation.from_euler("y", 0.1, degrees=True).as_matrix()
        turned = camera.replace(T_world_camera=camera.T_world_camera @ turn)
        assert outline_mismatch(turned, segmentation, world.box, world.body) > 0, camera.name
        tile_row, tile_col = grid.tile_of_pixels()
        rows, cols = np.nonzero(segmentation == world.body)
        outside = ~robot_tiles[tile_row[rows], tile_col[cols]]
        assert not outside.any(), f"{camera.name}: {outside.sum()} robot pixels outside depthguard's robot image"


# --------------------------------------------------------------------------------------------------- the verdicts

def test_the_current_configuration_respects_theta(world, judged):
    """The method's assumption holds for the observed images: the current robot's tile image meets the box's in
    exactly theta = 1 camera, and there the box's tiles under the robot became possible obstacles (the other three
    cameras see the box in their epipolar bands), or obstacles outright where their pixels show what the robot
    cannot be (``robot_pixels``). The current configuration itself is judged free."""
    assert sum(judged.overlap) == THETA
    for grid, overlap, revised in zip(judged.test.grids, judged.overlap, judged.revised):
        box = box_tiles(grid.camera, grid)
        if overlap:
            assert np.any(box & ((revised == POSSIBLE) | (revised == OBSTACLE))), grid.camera.name
        assert np.any(box & (revised == OBSTACLE)), f"{grid.camera.name} does not see the box"
        assert not np.any(revised == UNKNOWN)
    assert not judged.test.test(judged.now).collision


def test_no_collision_is_missed_and_false_alarms_are_few(judged):
    """Every future configuration closer to the box than the safety margin (the robot's padding) by pybullet's
    getClosestPoints, penetrating ones included, is judged a collision; among those farther than ``far`` (the padding
    plus a tile's diagonal at the farthest workspace depth), fewer than FALSE_ALARM_BOUND are judged collisions. The
    sample holds at least MIN_SAMPLED true collisions and MIN_SAMPLED configurations beyond ``far``."""
    d, collision = judged.distance, judged.collision
    margin = judged.test.robot.padding
    must = d < margin
    far = d > judged.far
    penetrating = d < 0.0
    missed = must & ~collision
    rate = float(np.mean(collision[far])) if far.any() else float("nan")
    counts = {k: int(np.sum(judged.klass == k)) for k in "ABCD"}
    print(f"\n{judged.resolution}: {len(d)} future configurations, {penetrating.sum()} penetrate the box, "
          f"{must.sum()} closer than the {margin * 100:.0f} cm margin, {far.sum()} farther than "
          f"{judged.far * 100:.1f} cm; missed {missed.sum()}; false alarms {np.sum(collision & far)} "
          f"({rate:.1%}); classes {counts}")
    for lo, hi in ((-np.inf, 0.0), (0.0, margin), (margin, judged.far), (judged.far, np.inf)):
        band = (d >= lo) & (d < hi)
        if band.any():
            print(f"  distance in [{lo:.3f}, {hi:.3f}) m: {band.sum():3d} configurations, "
                  f"{np.mean(collision[band]):.0%} judged collisions")
    free = d[~collision]
    if len(free):
        print(f"  nearest configuration judged free: {free.min() * 100:.1f} cm from the box")
    assert penetrating.sum() >= MIN_SAMPLED and far.sum() >= MIN_SAMPLED, (penetrating.sum(), far.sum())
    if missed.any():
        k = int(np.flatnonzero(missed)[np.argmin(d[missed])])
        pytest.fail(f"{judged.resolution}: {missed.sum()} missed collisions; e.g. q = "
                    f"{judged.configurations[k].tolist()} at {d[k]:.4f} m from the box judged free (class "
                    f"{judged.klass[k]}); current q = {judged.now.tolist()}")
    assert rate < FALSE_ALARM_BOUND, rate


def test_a_blind_test_misses_collisions(judged):
    """The judge has teeth: the same judge finds the collisions a blind test (thresholds no change reaches: no tile
    is foreground, the box is never seen) misses."""
    d = judged.distance
    missed = (d < 0.0) & ~judged.blind
    print(f"\n{judged.resolution}: the blind test misses {missed.sum()} of {np.sum(d < 0.0)} collisions")
    assert missed.sum() >= MIN_SAMPLED


#: A current configuration 0.21 m from the box whose tile image meets the box's tiles in two cameras (352x288): in c2
#: the robot really stands in front of the box (hides 63 % of its pixels); in c0 it hides none of it, yet its padded
#: tile image covers 6 of the box's 15 tiles.
BOX_IN_VIEW_BEHIND_ROBOT_IMAGE = (4.935, -1.735, -1.223, -0.25, -0.089, -2.401)


def test_without_the_papers_theta_a_box_behind_the_robots_tiles_is_not_missed(world, futures):
    """The paper's theta = 1 fails here: Tables I and III label a tile unknown wherever the current robot's padded tile
    image covers it, whether the robot hides what is there or not, and an unknown tile is kept only when C - theta
    other cameras (all three) see an obstacle tile in its band. The robot hides the box in one camera (c2) and its
    tile image merely overlaps the box in a second (c0): the box's tiles in c0 are dropped, and configurations that
    penetrate the box are judged free (class A): at 352x288, 20 of the 337 closer than 2 cm, the deepest 3.3 cm into
    the box (measured with theta = 1, printed). The default, theta = C - 1 (no assumption on how many cameras the
    robot hides an obstacle from), misses none of them."""
    paper = run(world, futures, "352x288", now=BOX_IN_VIEW_BEHIND_ROBOT_IMAGE, theta=1)
    paper_missed = (paper.distance < paper.test.robot.padding) & ~paper.collision
    print(f"\n352x288 with theta = 1: missed {paper_missed.sum()} of {np.sum(paper.distance < 0.02)}")
    judged = run(world, futures, "352x288", now=BOX_IN_VIEW_BEHIND_ROBOT_IMAGE, theta=None)
    assert judged.test.theta == 3
    set_joints(world, judged.now)
    hidden = []
    for name, camera in judged.cameras.items():
        drawn = int(np.sum(render(world, camera)[1] == world.box))
        hidden.append(drawn < int(np.sum(box_outline_distance(camera) < 0.0)))
    assert sum(hidden) == 1 and sum(judged.overlap) == 2, (hidden, judged.overlap)
    d = judged.distance
    missed = (d < judged.test.robot.padding) & ~judged.collision
    print(f"\n352x288, the robot hiding the box in {sum(hidden)} camera and overlapping its tiles in "
          f"{sum(judged.overlap)}: missed {missed.sum()} of {np.sum(d < judged.test.robot.padding)}")
    assert not missed.any(), f"{missed.sum()} missed, the deepest {-d[missed].min():.4f} m into the box"


# --------------------------------------------------------------------------------------------------- motions

@dataclass
class Motions:
    starts: np.ndarray  # (M, n) radians
    ends: np.ndarray  # (M, n) radians
    end_distance: np.ndarray  # (M, 2) pybullet's distance of start and end to the box, metres
    closest: np.ndarray  # (M,) the least distance among the dense samples, metres (negative: penetration)
    crossing: np.ndarray  # (M,) bool: built through a configuration closer to the box than the padding

    def pass_closer(self, margin: float) -> np.ndarray:
        """(M,) bool: both ends farther from the box than ``margin`` (metres), a dense sample closer."""
        return np.all(self.end_distance > margin, axis=1) & (self.closest < margin)


def axis_reach(world: World, q) -> float:
    """Metres: at ``q``, the farthest corner of a pybullet link AABB (collision shapes, world frame) from the axis of
    a joint that moves the link; every point of the robot lies within its link's AABB."""
    set_joints(world, q)
    n = p.getNumJoints(world.body, physicsClientId=world.client)
    boxes = [p.getAABB(world.body, k, physicsClientId=world.client) for k in range(n)]
    corners = [np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
               for lo, hi in boxes]
    out = 0.0
    for j in world.joints:  # a serial chain: joint j moves link j and every link after it
        state = p.getLinkState(world.body, j, computeForwardKinematics=True, physicsClientId=world.client)
        R = np.array(p.getMatrixFromQuaternion(state[5])).reshape(3, 3)
        axis = R @ np.asarray(p.getJointInfo(world.body, j, physicsClientId=world.client)[13], dtype=np.float64)
        for k in range(j, n):
            offset = corners[k] - np.asarray(state[4])
            out = max(out, float(np.max(np.linalg.norm(offset - np.outer(offset @ axis, axis), axis=1))))
    return out


def within_limits(robot, q) -> bool:
    return bool(np.all((q >= robot.lower) & (q <= robot.upper)))


def closest_along(world: World, a, b) -> float:
    """The least of pybullet's distances to the box over the dense samples of the segment a -> b, metres."""
    steps = max(DENSE_SAMPLES, int(np.ceil(np.sum(np.abs(b - a)) * AXIS_REACH / DENSE_STEP)))
    s = np.linspace(0.0, 1.0, steps + 1)[:, None]
    return min(true_distance(world, q) for q in a + s * (b - a))


@pytest.fixture(scope="module")
def motions(world, futures) -> Motions:
    """The seeded motions (see MOTION_WEIGHTS) and the judge's verdict on each: dense sampling with pybullet."""
    robot = world.robot
    place_box(world, BOX_CENTRE)
    rng = np.random.default_rng(SEED + 3)

    def direction():
        d = rng.standard_normal(robot.n_joints) * np.asarray(MOTION_WEIGHTS)
        return d / np.sum(np.abs(d))

    def clear_end(centre, d):
        """Along d from the centre (closer than the padding) to beyond END_CLEARANCE, then up to MOTION_EXTRA
        further."""
        for k in range(1, int(MOTION_MAX / MOTION_STEP) + 1):
            q = centre + k * MOTION_STEP * d
            if not within_limits(robot, q):
                return None
            if true_distance(world, q) > END_CLEARANCE:
                further = q + rng.uniform(0.0, MOTION_EXTRA) * d
                return further if within_limits(robot, further) else q
        return None

    configurations, distance = futures
    pairs, crossing = [], []
    penetrating = configurations[distance < 0.0][:CROSSING_CENTRES]
    grazing = configurations[(distance >= 0.0) & (distance < robot.padding)][:CROSSING_CENTRES]
    for centre in np.concatenate([penetrating, grazing]):
        for _ in range(10):
            d = direction()
            a, b = clear_end(centre, -d), clear_end(centre, d)
            if a is not None and b is not None:
                pairs.append((a, b))
                crossing.append(True)
                break
    for centre in configurations[:RANDOM_FUTURE][:FREE_CENTRES]:
        for _ in range(10):
            d = direction()
            a, b = centre - rng.uniform(*FREE_HALF) * d, centre + rng.uniform(*FREE_HALF) * d
            if within_limits(robot, a) and within_limits(robot, b):
                pairs.append((a, b))
                crossing.append(False)
                break
    starts = np.array([a for a, _ in pairs])
    ends = np.array([b for _, b in pairs])
    end_distance = np.array([[true_distance(world, a), true_distance(world, b)] for a, b in pairs])
    closest = np.array([closest_along(world, a, b) for a, b in pairs])
    return Motions(starts, ends, end_distance, closest, np.array(crossing))


def test_the_dense_sampling_moves_no_point_more_than_its_step(world):
    """The judge's step bound holds: at seeded configurations, every point of the robot (within its links' AABBs) is
    less than AXIS_REACH from the axis of every joint that moves it, so a dense step of joint changes dq moves no
    point more than sum_i |dq_i| AXIS_REACH <= DENSE_STEP."""
    rng = np.random.default_rng(SEED + 4)
    reach = max(axis_reach(world, q) for q in seeded_configurations(world.robot, rng, 50))
    print(f"\nthe farthest robot point from a joint axis moving it: {reach:.3f} m (bound {AXIS_REACH} m)")
    assert reach < AXIS_REACH


def test_swept_volumes_miss_no_collision_of_an_intermediate_configuration(judged, motions):
    """Every motion whose ends are both clear of the box by more than the safety margin (the padding) but whose dense
    samples come closer than it, or penetrate the box, is judged a collision by ``test_motion([a, b])``; at least
    MIN_SAMPLED such motions are sampled. Among motions whose every dense sample stays beyond ``far``, fewer than
    SWEPT_FALSE_ALARM_BOUND are judged collisions (reported)."""
    test = judged.test
    margin = test.robot.padding
    must = motions.pass_closer(margin)
    far = motions.closest > judged.far
    swept = np.array([test.test_motion([a, b]).collision for a, b in zip(motions.starts, motions.ends)])
    missed = must & ~swept
    rate = float(np.mean(swept[far])) if far.any() else float("nan")
    print(f"\n{judged.resolution}: {len(swept)} motions ({motions.crossing.sum()} built through the margin); "
          f"{must.sum()} with both ends beyond the {margin * 100:.0f} cm margin (nearest end "
          f"{motions.end_distance[must].min() * 100:.1f} cm) pass closer, {np.sum(must & (motions.closest < 0.0))} "
          f"through the box: swept test missed {missed.sum()}; {far.sum()} stay beyond {judged.far * 100:.1f} cm: "
          f"false alarms {np.sum(swept & far)} ({rate:.1%})")
    assert must.sum() >= MIN_SAMPLED and far.sum() >= MIN_SAMPLED, (must.sum(), far.sum())
    if missed.any():
        k = int(np.flatnonzero(missed)[np.argmin(motions.closest[missed])])
        pytest.fail(f"{judged.resolution}: {missed.sum()} motions passing within the margin judged free; e.g. a = "
                    f"{motions.starts[k].tolist()}, b = {motions.ends[k].tolist()} comes {motions.closest[k]:.4f} m "
                    f"from the box (ends {motions.end_distance[k].tolist()} m); current q = {judged.now.tolist()}")
    assert rate < SWEPT_FALSE_ALARM_BOUND, rate


def test_the_end_configurations_alone_miss_what_the_swept_test_catches(judged, motions):
    """The judge has teeth: testing only the two ends of the motions that pass closer than the margin
    (``test(a)`` or ``test(b)``) misses at least MIN_SAMPLED of them, which the swept test catches."""
    test = judged.test
    margin = test.robot.padding
    must = np.flatnonzero(motions.pass_closer(margin))
    ends = np.array([test.test(motions.starts[k]).collision or test.test(motions.ends[k]).collision for k in must])
    swept = np.array([test.test_motion([motions.starts[k], motions.ends[k]]).collision for k in must])
    print(f"\n{judged.resolution}: testing the ends only misses {np.sum(~ends)} of {len(must)} motions that pass "
          f"closer than {margin * 100:.0f} cm; the swept test catches {np.sum(~ends & swept)} of them")
    assert np.sum(~ends & swept) >= MIN_SAMPLED
