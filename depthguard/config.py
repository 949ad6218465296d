"""One home for depthguard's defaults and tolerances.

Kernels never hold literals of their own: every default and tolerance that shapes a result is named here, with its
unit, so that a reviewer can see in one page what the library assumes.
"""

import math

#: Metres per unit of a ``uint16`` depth image (ROS ``16UC1`` images are in millimetres).
DEFAULT_DEPTH_SCALE = 0.001

#: Valid measurement range of a camera when the rig does not state one, metres. Nothing is unseen in depth then:
#: an invalid pixel under ``invalid="occupied"`` is occupied from the optical centre on.
DEFAULT_DEPTH_RANGE = (0.0, math.inf)

#: Radius of the surveillance region around each control point, metres.
DEFAULT_RHO = 0.4

#: Aggregation of the contributors of one control point (design §6).
DEFAULT_AGGREGATE = "hybrid"
AGGREGATES = ("min", "mean", "hybrid")

#: Policies for pixels without a valid measurement and for space no camera looks at (design §3).
DEFAULT_INVALID = "occupied"
INVALID_POLICIES = ("occupied", "neighbors", "free")
DEFAULT_UNSEEN = "occupied"
UNSEEN_POLICIES = ("occupied", "free")

#: ``exact`` is design §4-5; ``paper`` is the 2015 paper's formulas (eqs. 7-11), kept for comparison only.
DEFAULT_METHOD = "exact"
METHODS = ("exact", "paper")

#: ``invalid="neighbors"``: a hole of at most this many 8-connected pixels takes the smallest valid depth around it.
#: Depth cameras drop pixels along depth edges in thin lines (a few dozen pixels along a robot's silhouette); 64
#: pixels is about 3 x 3 cm at 2 m, too small to hide a hand.
DEFAULT_NEIGHBOR_HOLE_PIXELS = 64

#: Depth noise model sigma(d) = a + b*d + c*d**2 (metres) times k gives the noise margin m(d) (design §3).
#: The default is the axial noise of a Kinect v1 measured by Nguyen, Izadi and Lovell (3DIMPVT 2012),
#: sigma(d) = 0.0012 + 0.0019*(d - 0.4)**2, expanded into a + b*d + c*d**2, with k = 3.
DEFAULT_NOISE_SIGMA = (0.0012 + 0.0019 * 0.16, -2.0 * 0.4 * 0.0019, 0.0019)
DEFAULT_NOISE_K = 3.0

#: Largest |R^T R - I| entry and |det R - 1| accepted for a rotation read from a file.
ROTATION_TOLERANCE = 1e-6

#: A distance at or below this (metres) means the point lies inside a possibly-occupied set.
INSIDE_TOLERANCE = 1e-12

#: A mean direction shorter than this is reported as the zero vector (obstacles on all sides cancel out).
MIN_DIRECTION_NORM = 1e-9

#: Cube corners at or nearer than this depth (metres, optical frame) make the surveillance window the whole image.
NEAR_PLANE_EPSILON = 1e-6

#: Side of the square pixel blocks whose minimum depth bounds whole blocks at once, pixels.
BLOCK_SIZE = 8

#: Self-filtering: metres by which a measurement may lie in front of the rendered robot and still count as the robot
#: (calibration and joint-state timing), on top of the noise margin (design §7).
SELF_FILTER_TOLERANCE = 0.02

# ------------------------------------------------------------------------------------------------------------ robots

#: The default robot: pybullet_data's KUKA LBR iiwa 7 R800 (7 revolute joints, like the papers' KUKA LWR IV), and the
#: Franka Emika Panda. Paths are relative to ``pybullet_data.getDataPath()``, resolved only when asked for.
DEFAULT_ROBOT_URDF = "kuka_iiwa/model.urdf"
PANDA_URDF = "franka_panda/panda.urdf"
#: UFACTORY xArm 6 in pybullet_data: a 6-joint arm like Henrich & Gecks' industrial robot (scenario C).
XARM6_URDF = "xarm/xarm6_robot.urdf"

#: Padding added to every link capsule's radius, metres: the capsules contain the collision meshes plus this much.
DEFAULT_ROBOT_PADDING = 0.02

#: A joint value at most this far beyond its URDF limits (radians for revolute, metres for prismatic joints) is
#: accepted as given (a measured state may overshoot a little; it is never clipped, so the geometry stays where the
#: robot is). Further out is an error: it means wrong units (degrees), a wrong joint order or a wrong model.
JOINT_LIMIT_TOLERANCE = 0.01

#: Largest | |axis| - 1 | accepted for a movable joint's URDF <axis xyz> (tools disagree on non-unit axes).
URDF_AXIS_TOLERANCE = 1e-4

#: URDF primitive shapes become meshes that contain the true shape (their faces lie on or outside it): a cylinder is
#: a prism over a regular polygon circumscribed about its circle, a sphere a scaled icosphere.
PRIMITIVE_CYLINDER_SECTIONS = 32
PRIMITIVE_SPHERE_SUBDIVISIONS = 2

#: Capsule fit (depthguard.robots): radii scanned per axis direction (twice: coarse, then around the best), axis
#: directions tried besides the three principal axes, and Nelder-Mead iterations refining the best direction.
CAPSULE_RADIUS_SAMPLES = 64
CAPSULE_AXIS_CANDIDATES = 64
CAPSULE_REFINE_ITERATIONS = 200

#: RobotModel.capsule_gap: configurations sampled (all zeros, then seeded random ones), samples of the meshes' surface
#: per configuration and of each capsule's surface, and the seed.
CAPSULE_GAP_CONFIGURATIONS = 4
CAPSULE_GAP_MESH_SAMPLES = 300_000
CAPSULE_GAP_SURFACE_SAMPLES = 4000
CAPSULE_GAP_SEED = 20261126
#: The robot's inner volume (RobotModel.inner_capsules_world; design §8a's Robot_k) as balls inside each link's mesh
#: (depthguard.robots._inner.inner_balls): the grid of candidate centres (metres), the most balls a link, the voxel
#: side they are chosen to hold wholly (metres: the detectable space's and the memory's pieces, 1 cm), and the spacing
#: of the surface samples (metres) that bound each centre's distance to the mesh.
INNER_BALL_SPACING = 0.01
INNER_BALLS = 64
INNER_BALL_COVER_VOXEL = 0.01
INNER_SURFACE_SAMPLE = 0.0015
#: The most grid points, surface samples and (ball, grid point) pairs inner_balls handles for one link: a larger
#: link gets a coarser grid, coarser samples or every k-th point counted (bounded time and memory for any URDF mesh;
#: the built-in robots' largest links need at most 17 000 grid points, 0.9 million samples, 0.3 million pairs).
INNER_BALL_LIMITS = {"grid": 250_000, "samples": 2_000_000, "pairs": 10_000_000}

#: The default robot's 9 control points (the papers' count: Flacco et al. 2015 section 5, 2016 section VIII), as
#: (name, link, offset (3,) metres in the link frame). They lie on the arm's centre line about 0.1 m apart: three on
#: the upper arm, the elbow, three on the forearm, the wrist, and the end-effector at the flange (the top face of
#: link 7, 0.126 m beyond the wrist). Link 1 carries none: joint 1 only turns it about its own axis, so a point on it
#: cannot move away from anything. Heights are with all joints at zero (base at z = 0).
IIWA_CONTROL_POINTS = (
    ("upper_arm_1", "lbr_iiwa_link_2", (0.0, 0.1, 0.0)),  # z = 0.46
    ("upper_arm_2", "lbr_iiwa_link_3", (0.0, 0.0, 0.0)),  # z = 0.5645
    ("upper_arm_3", "lbr_iiwa_link_3", (0.0, 0.0, 0.11)),  # z = 0.6745
    ("elbow", "lbr_iiwa_link_4", (0.0, 0.0, 0.0)),  # z = 0.78
    ("forearm_1", "lbr_iiwa_link_4", (0.0, 0.09, 0.0)),  # z = 0.87
    ("forearm_2", "lbr_iiwa_link_5", (0.0, 0.0, 0.0)),  # z = 0.9645
    ("forearm_3", "lbr_iiwa_link_5", (0.0, 0.0, 0.11)),  # z = 1.0745
    ("wrist", "lbr_iiwa_link_6", (0.0, 0.0, 0.0)),  # z = 1.18
    ("end_effector", "lbr_iiwa_link_7", (0.0, 0.0, 0.045)),  # z = 1.306, the flange
)

#: The Panda's 9 control points, placed like the iiwa's along the arm (heights and reaches below are in the pose
#: q = (0, 0, 0, -1.5, 0, 1.5, 0), base at the origin): two on the upper arm (z = 0.433, 0.549), the elbow (link 4's
#: origin), two on the forearm, a third and two thirds of the way from the elbow to the wrist, the wrist centre
#: (links 5/6's origin), link 7's origin (on link 6's body), the flange (the hand's origin), and the end-effector
#: between the finger tips (panda_grasptarget, 0.105 m beyond the flange). Neighbours are 0.10-0.14 m apart.
PANDA_CONTROL_POINTS = (
    ("upper_arm_1", "panda_link2", (0.0, -0.1, 0.0)),
    ("upper_arm_2", "panda_link3", (0.0, 0.0, -0.1)),
    ("elbow", "panda_link4", (0.0, 0.0, 0.0)),
    ("forearm_1", "panda_link5", (0.055, 0.0, -0.256)),
    ("forearm_2", "panda_link5", (0.0275, 0.0, -0.128)),
    ("wrist", "panda_link6", (0.0, 0.0, 0.0)),
    ("wrist_2", "panda_link6", (0.088, 0.0, 0.0)),
    ("flange", "panda_hand", (0.0, 0.0, 0.0)),
    ("end_effector", "panda_grasptarget", (0.0, 0.0, 0.0)),
)

#: Rendering (depthguard.rendering): surfaces nearer to a camera's optical centre than this (metres, optical z) are
#: clipped. There is no far plane: the depth buffer holds near / z in float32, so its resolution is relative
#: (about 1e-7 of the depth) and does not depend on this value.
RENDER_NEAR = 1e-3

#: Rendering: ambient term of the Lambertian intensity image, intensity = albedo * (a + (1 - a) * |cos|), where
#: |cos| is the cosine between the surface normal and the ray to the camera (the light sits at the camera).
RENDER_AMBIENT = 0.1

#: Rendering: segments around a sphere or capsule in primitive_mesh (a circumscribed UV-sphere hull). At 48 the
#: mesh exceeds the true surface by at most 0.43 % of the radius.
PRIMITIVE_MESH_SEGMENTS = 48

#: Rendering: the EGL and OpenGL libraries opened for the headless context (Debian packages libegl1, libgl1; the
#: unversioned names libEGL.so / libGL.so come only with the -dev packages).
EGL_LIBRARY = "libEGL.so.1"
GL_LIBRARY = "libGL.so.1"

#: Self-filtering hulls: planes bounding each link's padded convex hull (depthguard.self_filter.padded_hull).
SELF_FILTER_HULL_PLANES = 64

# ------------------------------------------------------------------------------------------------ the depth grid

#: The depth grid's cells are DEPTH_GRID_DELTA_D metres deep along the principal camera's z (design §12's
#: scenario B), coarser only when the grid's range needs more than DEPTH_GRID_MAX_CELLS of them. The range itself
#: comes from the rig (design §8, "Grid range"; :func:`depthguard.depthgrid.grid_range`): the depths at which
#: the principal sees the rig's workspace, within its depth_range.
DEPTH_GRID_DELTA_D = 0.01

#: The depth grid's cell classes (a byte a cell) live in one array reused from set to set; every
#: CELL_CACHE_RENEWAL sets its spares are dropped and a new one made, so that the pages the sets touched go back to
#: the operating system: resident memory then holds the cells of the last few seconds' surveillance regions, not of
#: every pixel the robot ever came near (up to the whole array, 130 MB for a 640x480 principal, per array in turn).
CELL_CACHE_RENEWAL = 300

#: The depth grid never starts nearer than this (metres): a camera whose rig entry gives no minimum range.
DEPTH_GRID_NEAREST = 0.1

#: How deep the depth grid reaches (metres beyond its start) for a principal camera with neither a finite maximum range (depth_range) nor a
#: workspace in the rig. Regions beyond it are counted occupied and flagged ``outside_grid``: state depth_range or
#: workspace in the rig to avoid that.
DEPTH_GRID_UNBOUNDED_END = 10.0

#: Fusion: metres by which a secondary camera's measured surface must lie beyond a cell (on top of its noise margin)
#: for it to declare the cell free. It covers the rig's calibration error: a camera whose pose is off by this much
#: must not clear a surface that another camera sees. Measure it for a real rig (see the slambook experiment).
DEFAULT_FUSION_MARGIN = 0.01

#: Fusion: a cell's footprint in a secondary camera is grown by this many pixels on every side (calibration error).
DEFAULT_FUSION_PIXELS = 1
# Each control point's rows are shared among this many parallel tasks (every n-th row), so that one point near much
# clutter does not leave the other threads idle.
FUSION_ROW_CHUNKS = 4

# ------------------------------------------------------------------------------------------------------- input files

#: Size caps of the files depthguard reads (depthguard.io.files), bytes. A larger file is refused unread: a device or
#: a runaway file cannot make a monitor read forever or exhaust memory.
MAX_TEXT_FILE_BYTES = 1 << 20  # rig, camera_info and scene YAML files: 1 MiB
MAX_POINTS_FILE_BYTES = 16 << 20  # control-point CSV or JSON: 16 MiB (about half a million points)
#: Control points one query takes (any API entry that takes points: DistanceMonitor.query, PreparedSet.query,
#: single_camera_distances, FusedFrames.distances, the detectable distances): refused beyond this before anything is
#: allocated, with a message naming the limit (a robot has tens to thousands; a million is 24 MB of coordinates and
#: about 100 MB of results).
MAX_QUERY_POINTS = 1_000_000
MAX_DEPTH_FILE_BYTES = 256 << 20  # one depth image file: 256 MiB
MAX_MAP_FILE_BYTES = 2 << 30  # one depth-grid map: 2 GiB

#: Deepest nesting of lists and mappings accepted in a YAML file (a rig needs 5 levels, a scene about 8).
MAX_NESTING = 32

# ------------------------------------------------------------------------------------------- ranges of input values
# Values outside these ranges are refused with a named error (docs/bad-input.md): inside them, the
# kernels' float64 arithmetic represents every quantity they form (squares of coordinates, projections) exactly
# enough; outside them it might not, and a wrong number is never an answer.

#: Surveillance radius rho, metres: [RHO_MIN, RHO_MAX].
RHO_MIN = 1e-6
RHO_MAX = 100.0

#: Largest |x|, |y|, |z| of a control point or a camera position, metres (world frame).
COORDINATE_LIMIT = 1e4

#: Largest image side, pixels, of a camera or a depth image.
MAX_IMAGE_SIDE = 16384

#: Time: ``max_age`` at most this many seconds; a frame stamped later than ``now`` by more than CLOCK_SKEW_TOLERANCE
#: seconds (clocks of cameras and host disagree a little) is treated as stale and flagged, since its time is wrong.
MAX_AGE_LIMIT = 1e6
CLOCK_SKEW_TOLERANCE = 0.01

#: DistanceMonitor's default max_age, seconds: three frame periods of a 30 Hz camera. A frame that carries a
#: timestamp and is older than this at the query's ``now`` makes its camera stale (blind, flagged): a camera that
#: freezes stops clearing space within three frames. Frames without a timestamp cannot age and are not held to it.
DEFAULT_MAX_AGE = 0.1

#: Live input and replay (design §12b). A set of frames waits at most FRAME_SET_WAIT seconds (stamp clock) after its
#: first new frame for the other cameras' frames; with no new frame, an answer still comes every max_age seconds.
FRAME_SET_WAIT = 0.02
#: Live: the host's clock drives the loop LIVE_TRANSPORT seconds behind, so that a frame that took that long from its
#: stamp to the node (driver, network, decoding) still joins its set as in replay; waits and idle answers come that
#: much later.
LIVE_TRANSPORT = 0.05
#: Live: a camera whose frames arrive more than LIVE_CLOCK_OFFSET seconds after their stamps (or stamped in the
#: future) has a clock that disagrees with the host's: reported in /diagnostics and the status (ERROR).
LIVE_CLOCK_OFFSET = 1.0
#: Joints at a frame's stamp: interpolated between two joint states at most JOINT_GAP seconds apart around it.
#: JOINT_HOLD: how long after the last state a stamp may take that state as it is, when no later state came within
#: the set's wait; 0 (the default): never, since held joints would offset the self-filtered shell by the robot's joint
#: speed times the hold (5 mrad at 1 rad/s for 5 ms, about 6 mm at the iiwa's reach), a concession without a flag.
#: Otherwise the camera has no joints for that frame and counts as stale for the set (blind, named). JOINT_HISTORY
#: states are kept (8 s at 500 Hz).
JOINT_GAP = 0.05
JOINT_HOLD = 0.0
JOINT_HISTORY = 4096
#: Live and replay: a camera whose stamp jumps ahead of its last one by more than STAMP_JUMP seconds (a clock stepped,
#: a driver restarted, a camera silent that long) is reset, as one whose stamp goes back: named in the next set.
STAMP_JUMP = 1.0

#: Camera intrinsics, pixels: focal lengths fx, fy in [FOCAL_LENGTH_MIN, INTRINSICS_LIMIT], principal point
#: |cx|, |cy| <= INTRINSICS_LIMIT (a pixel's frustum slopes (u - cx) / fx then stay far from overflow).
FOCAL_LENGTH_MIN = 1e-3
INTRINSICS_LIMIT = 1e7

#: ROS distortion models whose coefficients, all zero, are the pinhole camera: a camera_info of an image that is not
#: rectified must name one of them (or none). ``equidistant`` (fisheye) with zero coefficients is not a pinhole.
PINHOLE_DISTORTION_MODELS = ("plumb_bob", "rational_polynomial")

#: Largest depth_scale, metres per uint16 unit (ROS 16UC1 images use 0.001).
DEPTH_SCALE_MAX = 1.0

#: Noise model sigma(d) = a + b*d + c*d**2: |a| (m), |b| (m/m), |c| (1/m) at most NOISE_COEFFICIENT_LIMIT, k in
#: [0, NOISE_K_MAX]. Real sensors' coefficients are millimetres; the bounds keep k*a + k*b*d + k*c*d**2 finite.
NOISE_COEFFICIENT_LIMIT = 1.0
NOISE_K_MAX = 100.0

#: Camera names: at most this many printable characters (names appear in one-line error messages).
MAX_NAME_LENGTH = 200

#: DistanceMonitor options: self_filter_tolerance in [0, SELF_FILTER_TOLERANCE_MAX] metres (more would let the
#: robot's filter swallow an obstacle that far in front of it); hole_pixels in [0, MAX_IMAGE_SIDE**2];
#: fusion_pixels in [0, MAX_IMAGE_SIDE]; fusion_margin finite and >= 0 metres.
SELF_FILTER_TOLERANCE_MAX = 1.0
MAX_HOLE_PIXELS = MAX_IMAGE_SIDE * MAX_IMAGE_SIDE
MAX_FUSION_PIXELS = MAX_IMAGE_SIDE

#: A depth grid has at most this many cells along each principal pixel (fused queries keep a byte per cell and pixel,
#: allocated as touched: 4096 cells at 640x480 is 1.3 GB at most). build-map's options and FusedFrames check it.
DEPTH_GRID_MAX_CELLS = 4096

#: Thinnest depth-grid cell, metres. Cell indices int((z - d_min) / delta_d) of any depth within the coordinate limit
#: then stay far from the integer range's end.
DEPTH_GRID_MIN_DELTA_D = 1e-6

#: Largest difference between a loaded map's geometry and the geometry rebuilt from the rig, relative to the largest
#: magnitude of each array (float64 rounding differs between machines only in the last bits).
DEPTH_GRID_GEOMETRY_TOLERANCE = 1e-9

#: Command line: --seed in [0, MAX_SEED]; --repeats in [1, MAX_REPEATS].
MAX_SEED = 2**63 - 1
MAX_REPEATS = 10_000

#: Self-filtering geometries (depthguard.self_filter): padded convex hulls, capsules, or the meshes themselves.
SELF_FILTER_GEOMETRIES = ("hulls", "capsules", "meshes")

#: Robot descriptions (depthguard.robots): a URDF file of at most MAX_URDF_BYTES, each collision mesh file of at most
#: MAX_MESH_FILE_BYTES (a device or a runaway file is never read whole).
MAX_URDF_BYTES = 16 << 20
MAX_MESH_FILE_BYTES = 128 << 20

# ----------------------------------------------------------------------------- time-bounded free space (design §8a)

#: Fastest a person (a hand) may move, metres/second: remembered free space shrinks at this speed from wherever a
#: person may be (ISO 13855's approach speed for hands). A body part moving faster is outside the guarantee.
FREESPACE_V_MAX = 2.0

#: DistanceMonitor(detection_capability=...): the side of the voxels in which it finds where a ball of that diameter
#: fits in possibly occupied space, metres (depthguard.freespace.DetectableSpace). At most half the capability; 1 cm
#: is a quarter of SSM's default 40 mm: bands thinner than 2 cm vanish, ones thicker than 7.5 cm stay.
DETECTABLE_VOXEL = 0.01

#: The monitor remembers free space (design §8a) by default, in voxels of FREESPACE_VOXEL metres over the rig's workspace.
DEFAULT_MEMORY = True
#: DistanceMonitor(robot_zone=...), metres: fused answers may take space within this much of the robot's padded
#: capsules for the robot, in every direction (the robot zone; docs/design.md, "Several cameras"). An object wholly inside it
#: is not seen, and a distance to one that reaches into it may exceed the truth by up to this much. Off (0) by default:
#: it removes few false alarms at a thickness that stays safe (benchmarks/probe_robot_zone.py).
DEFAULT_ROBOT_ZONE = 0.0
ROBOT_ZONE_MAX = 0.2
#: The avoidance loop's robot zone (run_closed_loop, ``depthguard demo``), metres. A depth camera cannot tell a hand
#: within its noise margin of the robot's surface from the robot: the self-filter takes a measurement up to its
#: tolerance (2 cm) in front of the robot for the robot, and the fusion clears space only beyond the noise margin
#: (Kinect v1, 3 sigma, 3-4 cm at the robot's 2.5-3.3 m from the cameras) plus the fusion margin (1 cm). Nothing
#: clears that shell, and it moves with the links: every control point read 0.07-0.15 m from it, the avoidance pushed
#: the arm away from its own shadow and the task never resumed. Measured in the demo's scene with four
#: cameras (36 frames, no person): 3 cm removes none of it, 6 cm nearly all (4.5 cm: the task did not resume). The
#: loop takes it as a stated tolerance: a distance may exceed the truth by up to this much for an object reaching
#: within it, so the avoidance takes it off every distance (AvoidanceParams.tolerance) and SSM adds it to Z_d.
LOOP_ROBOT_ZONE = 0.06
FREESPACE_VOXEL = 0.04

#: Largest free-space box, in voxels: its arrival times (float64), the distance transform's work space (int32) and a
#: boolean mask take 13 bytes a voxel, about 420 MB at this size. A side of at most FREESPACE_MAX_SIDE voxels keeps
#: every squared distance (in voxels) within int32.
FREESPACE_MAX_VOXELS = 32_000_000
FREESPACE_MAX_SIDE = 16384

#: A box side within this many voxels of a whole number of voxels is not grown by a sliver voxel ((0.4 - 0.1) / 0.1
#: is 3.0000000000000004 in float64). The box is then short by at most this fraction of a voxel, which is safe:
#: space outside the box counts as possibly occupied.
FREESPACE_FIT_TOLERANCE = 1e-9

#: Arrival times are lowered by this fraction of the distance they come from (and by one unit in the last place of
#: the sum), so that float rounding never makes one later than the exact value.
FREESPACE_ROUNDING = 1e-12

#: seen_free_voxels tests blocks of this many voxels a side whole first, then their halves, down to single voxels
#: (a power of 2): where a camera sees a whole block free, its voxels cost nothing more.
FREESPACE_BLOCK = 8
#: The memory judges a voxel next to the robot that no one camera sees wholly free, and that is not wholly inside the
#: robot, in pieces of FREESPACE_VOXEL / 2^FREESPACE_MIXED_LEVELS a side (1 cm at 4 cm): it is free when each piece is
#: seen free by some camera or lies inside the robot (design §8a: the two combine within one voxel).
FREESPACE_MIXED_LEVELS = 2

# ------------------------------------------------------------------------------------------ avoidance (design §9)
#: The papers' avoidance parameters (2015 paper section 5.3): rho 0.4 m, the end-effector's largest repulsive speed
#: V_max 1.5 m/s and the shape factor alpha 5 of the repulsive speed and of the risk function.
AVOID_V_MAX = 1.5
AVOID_ALPHA = 5.0
#: Joint accelerations (rad/s^2, or m/s^2 for prismatic joints) when the caller gives none: URDF has no acceleration
#: limits. 10 rad/s^2 is below what the KUKA iiwa and the Franka Panda (15 rad/s^2) allow.
JOINT_ACCELERATION = 10.0
#: Damped least squares (Nakamura and Hanafusa; Chiaverini): damping lambda^2 = DLS_LAMBDA_MAX^2 (1 - (s/eps)^2)
#: when the smallest singular value s of the task Jacobian is below eps = DLS_EPSILON, else none.
DLS_EPSILON = 0.04
DLS_LAMBDA_MAX = 0.04

# ------------------------------------------------------------------- speed and separation monitoring (design §9)

#: The human's approach speed, m/s: ISO 13855's K = 1600 mm/s, and K = 2000 mm/s when the separation is at most
#: 500 mm (a hand or arm within reach moves faster than walking).
SSM_HUMAN_SPEED = 1.6
SSM_HUMAN_SPEED_NEAR = 2.0
SSM_NEAR_SEPARATION = 0.5
#: The robot's stopping time, seconds (from its data sheet; 0.25 s is a typical category 1 stop of a light arm at
#: moderate speed), and a fixed extra stopping distance, metres, on top of the uniform deceleration's v_r T_s / 2.
SSM_STOPPING_TIME = 0.25
SSM_STOPPING_DISTANCE_EXTRA = 0.0
#: The sensors' detection capability d, metres: the smallest object they are sure to see (0.04 m: a hand).
SSM_DETECTION_CAPABILITY = 0.04
#: The loop's SSM asks the monitor again for a control point's distance on the same frames only once it has moved
#: this many metres since it was asked (meanwhile: the distance then minus how far it moved, a lower bound).
SSM_REQUERY = 0.005
#: Speed scaling (``depthguard live --ssm``, design §12b): a controller applies a speed factor at most SSM_HOLD
#: seconds with no newer one (its watchdog; then it stops), and runs every SSM_CONTROL_PERIOD seconds. Both count in
#: the reaction time T_r.
SSM_HOLD = 0.1
#: depthguard live: how long, at start-up, it asks the domain's liveliness tokens which rmw_zenoh hash style the
#: peers speak (Humble's or Jazzy's), seconds.
LIVE_DISCOVERY = 1.0
SSM_CONTROL_PERIOD = 0.002
#: Speed scaling: the largest joint speed (rad/s or m/s) and braking (rad/s^2 or m/s^2) it takes, above any arm's: a
#: larger one is a wrong value (a URDF's placeholder limit, a unit slip), and a braking that large would claim a stop
#: within no time. Refused by name.
SSM_JOINT_SPEED_MAX = 100.0
SSM_BRAKING_MAX = 1000.0
#: ISO 13855's intrusion distance C for a detection capability d: C = 8 (d - 14 mm) for 14 mm < d <= 40 mm, 0 for
#: d <= 14 mm (a finger cannot reach in unseen), 850 mm (an arm's reach) for 40 mm < d <= 70 mm. ISO 13855 gives C for
#: no coarser d (a sensor that misses a 70 mm arm sees only the trunk, and needs another formula): d above
#: SSM_INTRUSION_LIMIT is refused.
SSM_INTRUSION_SLOPE = 8.0
SSM_INTRUSION_FINGER = 0.014
SSM_INTRUSION_HAND = 0.040
SSM_INTRUSION_REACH = 0.85
SSM_INTRUSION_LIMIT = 0.070
#: The sensing uncertainty Z_d and the robot's position uncertainty Z_r, metres.
SSM_SENSING_UNCERTAINTY = 0.05
SSM_ROBOT_UNCERTAINTY = 0.01
#: Before solving for the allowed speed, the distance is lowered by this fraction of max(1 m, distance), so that float
#: rounding never makes the protective distance at the allowed (or scaled) speed exceed the distance (rounding is a
#: few 1e-16 of it).
SSM_ROUNDING = 1e-12
#: A direction whose norm differs from 1 by more than this is refused (only the exact zero vector means unknown).
SSM_UNIT_TOLERANCE = 1e-6
#: Largest accepted value of each SSMParams field (a typo such as 16 for 1.6 is refused, not obeyed).
SSM_MAXIMA = {"human_speed": 10.0, "human_speed_near": 10.0, "near_separation": 10.0, "stopping_time": 60.0,
              "stopping_distance_extra": 10.0, "detection_capability": SSM_INTRUSION_LIMIT, "sensing_uncertainty": 10.0,
              "robot_uncertainty": 10.0}

#: Image-based collision test (design §10): the range of the room light's gain (an image's brightness relative to the
#: reference images) that the difference images follow; outside it a camera sees every tile as foreground.
LIGHT_GAIN_RANGE = (0.5, 2.0)

#: Image-based collision test: the most configurations a ConfigurationTable holds (its bitsets take C x 8 x words
#: bytes each: 2 KiB for four cameras of 64 x 64 tiles, 256 MiB at the cap).
MAX_TABLE_CONFIGURATIONS = 2**17

#: Image-based collision test: the most samples of one motion's swept volume (each a configuration projected into
#: every camera; a motion across every joint's whole range takes about 2,000 with x_max = 2 cm).
MAX_MOTION_SAMPLES = 100_000
