"""Scene files: a YAML description of a simulated workcell, read into a :class:`Workcell`.

The file is read through ``depthguard.io.files``: a regular file of at most ``config.MAX_TEXT_FILE_BYTES`` bytes, parsed
by a safe YAML loader (no tags that run code: ``!!python/...`` is refused; no anchors or aliases, no duplicate keys,
nesting at most ``config.MAX_NESTING`` deep). Every key is
checked: a missing, unknown or malformed key raises :class:`~depthguard.errors.SceneError` whose ``field`` is the
key's path (``people[0].actions[2].reach.target``). Units are SI: metres, seconds, radians. Points are world-frame
coordinates; the world's z axis points up.

Top-level keys::

    duration: 11.5            # seconds (required)
    rate: 30                  # frames per second (default 30)
    seed: 0                   # default seed of the sensors' random noise
    floor: -0.5               # world z of the floor people stand on (default 0)
    render_segments: 24       # segments around rendered spheres and capsules (default lab_config.SIM_PRIMITIVE_SEGMENTS)
    depth_scale: 0.001        # metres per uint16 unit of the depth images (default 0.001)
    principal: principal      # the principal depth camera (rig key, design §2)
    workspace: [[x, y, z], [x, y, z]]   # optional rig key: the box watched (depth grid range, free-space memory)
    cameras: [...]            # depth cameras (at least one)
    intensity_cameras: [...]  # optional intensity (grey-level) cameras
    lighting: [[0.0, 1.0], [4.0, 1.0], [4.5, 0.8]]   # optional: (time s, gain) of the room's light, joined linearly;
                              # every intensity image is the rendered one times the gain at its time (default 1)
    robot: {...}
    static_objects: [...]     # optional
    carried_objects: [...]    # optional
    people: [...]             # optional

A depth camera has the rig-file keys of design §2 (name, width, height, fx, fy, cx, cy, depth_range, noise
{a, b, c, k}, depth_scale) with its pose either as ``T_world_camera`` (4x4, row-major, optical frame -> world) or
as ``look_at: {eye: [x, y, z], target: [x, y, z], up: [0, 0, 1]}``, plus an optional
``sensor: {noise: true, edge_threshold: 0.05, edge_dropout: 0.5, grazing_angle: 1.36, grazing_dropout: 0.9}`` (see
:class:`~depthguard_lab.simulation.SensorModel`; the simulated noise is sigma(d) = a + b d + c d^2 of ``noise``) and
``noise_sigma``, the grey-level noise of its intensity (infrared-like) image (default 2). An intensity camera has
the same intrinsics and pose keys plus ``noise_sigma``.

``robot``: ``model: iiwa``, ``model: panda`` or ``model: xarm6`` (pybullet_data's URDFs) or ``urdf: path/to/robot.urdf`` (relative to
the scene file; then optionally ``control_points: [[name, link, [x, y, z]], ...]`` and ``end_effector: name``); the
base pose as ``T_world_base`` (4x4) or ``base: {position: [x, y, z], yaw: 0.0}``; ``albedo``; and a ``trajectory``:

- ``{type: joints, waypoints: [{time: 0.0, joints: {joint_name: radians, ...}}, ...]}``: every joint by name (or a
  list in the robot's joint order), waypoint times increasing; joined by monotone cubics;
- ``{type: hexagon, center: [x, y, z], radius: 0.25, plane_normal: [1, 0, 0], speed: 0.4, start_angle: 0.0,
  direction: 1, posture: {joint_name: radians, ...}}``: the end-effector control point traces a regular hexagon
  (vertex 0 at ``start_angle`` from the plane's horizontal axis) at ``speed``; ``posture`` seeds the IK and is the
  null-space target.

``static_objects`` / ``carried_objects``: ``name`` (unique among all objects and people), one shape key, ``albedo``.
A static object's shape is ``box: {center: [..], size: [sx, sy, sz], yaw: 0.0}`` or ``box: {min: [..], max: [..]}``,
``sphere: {center: [..], radius: r}`` or ``capsule: {p0: [..], p1: [..], radius: r}``; ``obstacle: false`` makes it
known background (rendered, but not an obstacle in the ground truth: the floor, walls, the robot's pedestal). A
carried object is a box: ``size: [sx, sy, sz]`` and optionally ``rest: {center: [..], yaw: 0.0}`` where it lies
before it is first carried (without ``rest`` it appears only when carried).

``people``: ``name``, ``height`` (1.75), ``start: {position: [x, y], facing: angle | [x, y] | robot}``,
``walk_speed`` (1.3 m/s), ``clothes_albedo``, ``skin_albedo``, ``limbs`` (``default``, or ``thin``: forearms 45 mm
across, hands 25 mm thick and a finger 15 mm across, the thin-limb judges' person), and ``actions``, a list of one-key mappings run one
after another (see :mod:`depthguard_lab.simulation._people` for what each does):

- ``walk: {to: [x, y], via: [[x, y], ...], speed: 1.3, leg_swing: 0.35, backwards: false}`` (``backwards``:
  stepping back, facing the other way)
- ``stand: {duration: s, position: [x, y], via: [...], facing: ...}``
- ``reach: {hand: right, target: end_effector | control point name | [x, y, z], standoff: 0.0, duration: s,
  ramp: 0.5, position: [x, y], via: [...], facing: ...}`` (facing defaults to the target)
- ``carry: {object: name, to: [x, y], via: [...], speed: 1.0, leg_swing: 0.3, hold: 0.0,
  place_at: {center: [x, y, z], yaw: 0.0}, backwards: false}`` (a second carry of an object still held goes on
  from the hands)
- ``shadow: {camera: principal, target: control point name, distance: 1.5, duration: s, via: [...]}``
- ``hidden_hand: {camera: principal, target: control point name, behind: 0.2, stand_off: 0.6, hand: right,
  duration: s, ramp: 0.5, position: [x, y], via: [...]}``

``position`` and ``facing`` of an action are optional; a person not at ``position`` walks there first.
"""

from __future__ import annotations

import copy
import functools
import math
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

import numpy as np
import yaml

from depthguard import config
from depthguard_lab import config as lab_config
from depthguard.io.files import read_yaml, write_whole
from depthguard.cameras import PinholeCamera, Rig, rig_from_dict
from depthguard.errors import InputError, RigError, RobotError, SceneError
from depthguard.robots import RobotModel
from depthguard.scenes import Box, Capsule, Sphere
from depthguard_lab.simulation._actions import ActionContext, build_person
from depthguard_lab.simulation._fields import Section, new_name, pose_of
from depthguard_lab.simulation._people import ActionSpan, Person, box_primitive
from depthguard_lab.simulation._sensors import SensorModel
from depthguard_lab.simulation._trajectory import Hexagon, HexagonTrajectory, JointTrajectory, RobotTrajectory
from depthguard.transforms import look_at, yaw_pose
from depthguard.validation import check_transform

DEFAULT_SCENE = "scenario_b.yaml"


# ----------------------------------------------------------------------------------------------------- objects

@dataclass(frozen=True, eq=False)
class StaticObject:
    """A static solid: ``primitive`` (world frame), ``albedo``, and whether it is an ``obstacle`` in the ground
    truth (False: known background such as the floor)."""

    name: str
    primitive: object
    albedo: float
    obstacle: bool


@dataclass(frozen=True, eq=False)
class CarriedObject:
    """A box that people carry: full ``size`` (3,) metres, ``rest`` (center (3,), yaw) before its first carry or
    None, ``albedo``."""

    name: str
    size: np.ndarray
    rest: tuple | None
    albedo: float


@dataclass(frozen=True, eq=False)
class Workcell:
    """A simulated workcell: cameras, robot and trajectory, objects and scripted people, over one episode.

    Build it with :func:`load_workcell`, :func:`workcell_from_dict` or :func:`default_workcell`.

    Attributes:
        rig: the depth cameras as a :class:`~depthguard.cameras.Rig` (names, intrinsics, poses, depth_range, noise
            model, principal).
        intensity_rig: the intensity cameras as a Rig, or None when the scene has none (a Rig cannot be empty).
        sensors: depth camera name -> :class:`SensorModel`.
        intensity_noise: camera name -> grey-level noise sigma of its intensity image (every camera).
        robot: the :class:`~depthguard.robots.RobotModel`, mounted at its base pose.
        robot_albedo: the robot's reflectance in intensity images.
        trajectory: the robot's trajectory, sampled at the frame times.
        duration: seconds. rate: frames per second. seed: default sensor seed.
        floor: world z of the floor people stand on, metres.
        render_segments: segments around rendered spheres and capsules.
        static_objects, carried_objects, people: the scene's contents.
        scene: the scene as plain data (what :func:`save_workcell` writes).
        base_dir: where relative paths of the scene file are resolved.
    """

    rig: Rig
    intensity_rig: Rig | None
    sensors: dict
    intensity_noise: dict
    robot: RobotModel
    robot_albedo: float
    trajectory: RobotTrajectory
    duration: float
    rate: float
    seed: int
    floor: float
    render_segments: int
    static_objects: tuple
    carried_objects: tuple
    people: tuple
    scene: dict = field(repr=False)
    base_dir: Path = field(default=Path("."), repr=False)
    lighting: tuple = ()  # ((time s, gain), ...) increasing times; () is a constant gain of 1

    def light_gain(self, t: float) -> float:
        """The room light's gain at time ``t`` (seconds): linear between the ``lighting`` points, constant beyond
        them; 1 without any."""
        if not self.lighting:
            return 1.0
        times, gains = zip(*self.lighting)
        return float(np.interp(t, times, gains))

    # ------------------------------------------------------------------------------------------------ time

    @property
    def n_frames(self) -> int:
        """Number of frames: round(duration * rate)."""
        return int(round(self.duration * self.rate))

    def times(self) -> np.ndarray:
        """(k,) float64 frame times, seconds: i / rate for i < :attr:`n_frames`."""
        return np.arange(self.n_frames) / self.rate

    def joints_at(self, t: float) -> np.ndarray:
        """(n,) float64 robot joint values at time ``t`` (s, in [0, duration]), radians, ``robot.joint_names``
        order. Exact at frame times; linear in between."""
        return self.trajectory.joints_at(t)

    def control_points_at(self, t: float) -> np.ndarray:
        """(m, 3) float64 control point positions at time ``t``, metres, world frame."""
        return self.robot.control_point_positions(self.joints_at(t), check=False)

    # ------------------------------------------------------------------------------------------- obstacles

    @property
    def obstacle_names(self) -> tuple[str, ...]:
        """Obstacles of the ground truth, in order: people, carried objects, static objects with obstacle: true."""
        return (tuple(p.name for p in self.people) + tuple(c.name for c in self.carried_objects)
                + tuple(s.name for s in self.static_objects if s.obstacle))

    def part_names(self, name: str) -> tuple[str, ...]:
        """Names of the primitives of obstacle or object ``name`` (a person's body parts, or the object's name)."""
        for person in self.people:
            if person.name == name:
                return person.part_names
        return (name,)

    def obstacles_at(self, t: float) -> dict[str, list]:
        """Obstacles at time ``t``: name -> list of :mod:`depthguard.scenes` primitives in the world frame (a
        person's body parts in its ``part_names`` order; an object's one primitive; an empty list for a carried
        object not in the scene at ``t``). Keys in :attr:`obstacle_names` order."""
        out = {}
        for person in self.people:
            out[person.name] = person.parts_at(t)
        for obj in self.carried_objects:
            pose = self.carried_pose_at(obj.name, t)
            out[obj.name] = [] if pose is None else [box_primitive(pose[0], pose[1], obj.size)]
        for obj in self.static_objects:
            if obj.obstacle:
                out[obj.name] = [obj.primitive]
        return out

    def background(self) -> dict[str, list]:
        """Static objects that are not obstacles (known background): name -> [primitive]."""
        return {obj.name: [obj.primitive] for obj in self.static_objects if not obj.obstacle}

    def background_parts(self) -> list:
        """The known background's primitives in one list (world frame): what ``DistanceMonitor(static=...)`` takes
        when they are boxes."""
        return [p for parts in self.background().values() for p in parts]

    def primitives_at(self, t: float) -> list:
        """Every rendered primitive at ``t`` except the robot (obstacles and background), world frame."""
        out = [p for parts in self.obstacles_at(t).values() for p in parts]
        return out + self.background_parts()

    def carried_pose_at(self, name: str, t: float) -> tuple[np.ndarray, float] | None:
        """(center (3,), yaw) of carried object ``name`` at ``t``, or None when it is not in the scene."""
        obj = next(o for o in self.carried_objects if o.name == name)
        carriers = [p for p in self.people if p.carries_object(name)]
        if not carriers:
            return obj.rest
        # One carrier per object (checked when loading).
        return carriers[0].carried_box_at(name, t, obj.size, obj.rest)

    def labels(self) -> tuple[tuple[str, float], ...]:
        """(name, albedo) of every rendered thing, in label order (the values of :attr:`SimFrame.label`): the robot's
        links ("robot/<link>"), static objects, carried objects, then every person's parts ("<person>/<part>")."""
        out = [(f"robot/{link}", self.robot_albedo) for link in self.robot.collision_meshes]
        out += [(obj.name, obj.albedo) for obj in self.static_objects]
        out += [(obj.name, obj.albedo) for obj in self.carried_objects]
        for person in self.people:
            out += [(f"{person.name}/{part.name}", person.skin_albedo if part.skin else person.clothes_albedo)
                    for part in person.parts]
        return tuple(out)

    def person(self, name: str) -> Person:
        return next(p for p in self.people if p.name == name)

    def timeline(self) -> list[ActionSpan]:
        """Every person's actions with their times, sorted by start."""
        return sorted((span for p in self.people for span in p.spans), key=lambda s: (s.start, s.person))

    # ----------------------------------------------------------------------------------------------- other

    def camera(self, name: str) -> PinholeCamera:
        """A depth or intensity camera by name."""
        if name in self.rig.cameras:
            return self.rig.cameras[name]
        if self.intensity_rig is not None and name in self.intensity_rig.cameras:
            return self.intensity_rig.cameras[name]
        raise InputError(f"no camera {name!r} in the workcell", field="camera")

    def all_cameras(self) -> list[PinholeCamera]:
        """Depth cameras, then intensity cameras."""
        cameras = list(self.rig.cameras.values())
        if self.intensity_rig is not None:
            cameras += list(self.intensity_rig.cameras.values())
        return cameras

    def scaled(self, factor: float) -> "Workcell":
        """The same workcell with every camera's image scaled by ``factor`` (e.g. 0.25 for 160x120 instead of
        640x480): width, height, fx, fy scaled, pixel centres kept (c' = (c + 1/2) factor - 1/2). For fast tests."""
        def scale_rig(rig):
            if rig is None:
                return None
            cameras = {}
            for name, cam in rig.cameras.items():
                w, h = max(1, int(round(cam.width * factor))), max(1, int(round(cam.height * factor)))
                cameras[name] = cam.replace(width=w, height=h, fx=cam.fx * w / cam.width, fy=cam.fy * h / cam.height,
                                            cx=(cam.cx + 0.5) * w / cam.width - 0.5,
                                            cy=(cam.cy + 0.5) * h / cam.height - 0.5)
            return Rig(cameras=cameras, depth_scale=rig.depth_scale, principal=rig.principal, workspace=rig.workspace)

        fields = {name: getattr(self, name) for name in self.__dataclass_fields__}
        fields.update(rig=scale_rig(self.rig), intensity_rig=scale_rig(self.intensity_rig))
        return Workcell(**fields)


# ------------------------------------------------------------------------------------------------- loading

#: The keys of a scene file that make its camera layout (:func:`load_workcell`'s ``layout``).
LAYOUT_KEYS = ("cameras", "principal", "workspace")


def load_workcell(path, layout=None) -> Workcell:
    """Read a scene YAML file (safe loader) into a :class:`Workcell`; a :class:`SceneError` names the file and the
    offending field.

    layout: optional, another scene file whose camera layout (its ``cameras``, ``principal`` and ``workspace``)
    replaces this one's: the same robot, task and people seen by other cameras (for example ``scenario_b_four.yaml``'s
    four corners for a scene written with scenario B's two cameras)."""
    path = Path(path)
    data = read_yaml(path, what="scene file", max_bytes=config.MAX_TEXT_FILE_BYTES, error=SceneError)
    source = str(path)
    if layout is not None:
        layout = Path(layout)
        cameras = read_yaml(layout, what="scene file", max_bytes=config.MAX_TEXT_FILE_BYTES, error=SceneError)
        if not isinstance(data, dict) or not isinstance(cameras, dict) or "cameras" not in cameras:
            raise SceneError("a scene and a layout must both be mappings, the layout with 'cameras'",
                             source=f"{path} with the cameras of {layout}")
        data = {key: value for key, value in data.items() if key not in LAYOUT_KEYS}
        data.update({key: cameras[key] for key in LAYOUT_KEYS if key in cameras})
        source = f"{path} with the cameras of {layout}"
    try:
        return workcell_from_dict(data, base_dir=path.parent)
    except SceneError as exc:
        raise exc.with_source(source) from None


def default_workcell() -> Workcell:
    """Reference scenario B (design §12), from the package's ``scenario_b.yaml``."""
    resource = resources.files("depthguard_lab.simulation").joinpath(DEFAULT_SCENE)
    with resources.as_file(resource) as path:
        return load_workcell(path)


def save_workcell(workcell: Workcell, path) -> None:
    """Write the workcell's scene as YAML; :func:`load_workcell` reads it back to the same workcell (relative
    paths in it are resolved against the new file's folder). Written whole or not at all."""
    write_whole(Path(path), yaml.safe_dump(workcell.scene, sort_keys=False, default_flow_style=None))


def workcell_from_dict(data, base_dir=".") -> Workcell:
    """Build a :class:`Workcell` from parsed scene data (see the module docstring)."""
    scene = copy.deepcopy(data)
    top = Section(data, "")
    duration = top.number("duration", positive=True)
    rate = top.number("rate", default=lab_config.SIM_RATE, positive=True)
    seed = top.integer("seed", default=0, minimum=0)
    floor = top.number("floor", default=0.0)
    segments = top.integer("render_segments", default=lab_config.SIM_PRIMITIVE_SEGMENTS, minimum=6)
    depth_scale = top.number("depth_scale", default=config.DEFAULT_DEPTH_SCALE, positive=True)
    principal = top.get("principal", default=None)
    workspace = top.get("workspace", default=None)
    lighting = _lighting(top.get("lighting", default=[]), top.field("lighting"))
    base_dir = Path(base_dir)

    rig, sensors, noise_d = _depth_cameras(top, depth_scale, principal, base_dir, workspace)
    intensity_rig, noise_i = _intensity_cameras(top, depth_scale, base_dir, taken=set(rig.cameras))
    intensity_noise = {**noise_d, **noise_i}

    n_frames = int(round(duration * rate))
    if n_frames < 1:
        raise SceneError(f"duration {duration} s at {rate} Hz gives no frame", field="duration")
    sample_times = np.arange(n_frames + 1) / rate
    sample_times[-1] = max(sample_times[-1], duration)
    robot, albedo, trajectory = _robot(top.section("robot"), sample_times, base_dir)

    names: set[str] = set()
    static = tuple(_static_object(s, names) for s in top.sections("static_objects", default=[]))
    carried = tuple(_carried_object(s, names) for s in top.sections("carried_objects", default=[]))
    context = ActionContext(robot, trajectory, rig, intensity_rig)
    people = []
    for section in top.sections("people", default=[]):
        people.append(build_person(section, names, floor, context, {c.name: c for c in carried}, duration))
    top.done()
    carriers = {}
    for person in people:
        for carry in person.carries:
            other = carriers.setdefault(carry.name, person.name)
            if other != person.name:
                raise SceneError(f"carried object {carry.name!r} is carried by both {other!r} and {person.name!r}; "
                                 "one carrier per object", field="people")
    return Workcell(rig=rig, intensity_rig=intensity_rig, sensors=sensors, intensity_noise=intensity_noise,
                    robot=robot, robot_albedo=albedo, trajectory=trajectory, duration=duration, rate=rate, seed=seed,
                    floor=floor, render_segments=segments, static_objects=static, carried_objects=carried,
                    people=tuple(people), scene=scene, base_dir=base_dir, lighting=lighting)


def _lighting(value, field: str) -> tuple:
    """``lighting``: a list of [time, gain] pairs, times >= 0 and increasing, gains in (0, 4]."""
    if not isinstance(value, list):
        raise SceneError(f"lighting must be a list of [time, gain] pairs, got {type(value).__name__}", field=field)
    points = []
    for k, pair in enumerate(value):
        ok = isinstance(pair, list) and len(pair) == 2 and all(
            isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in pair)
        if not ok or pair[0] < 0 or not 0 < pair[1] <= 4 or (points and pair[0] <= points[-1][0]):
            raise SceneError(f"lighting[{k}] must be [time >= 0 s, increasing; gain in (0, 4]], got {pair!r}",
                             field=f"{field}[{k}]")
        points.append((float(pair[0]), float(pair[1])))
    return tuple(points)


# ------------------------------------------------------------------------------------------------- cameras

_CAMERA_KEYS = ("name", "width", "height", "fx", "fy", "cx", "cy", "depth_range", "noise", "depth_scale",
                "camera_info", "rectified", "distortion")


def _camera_entry(section: Section, extra_keys=()) -> dict:
    """The rig-file entry of a scene camera: its rig keys, with ``look_at`` turned into ``T_world_camera``."""
    entry = {key: section.get(key) for key in _CAMERA_KEYS + tuple(extra_keys) if section.has(key)}
    has_T, has_look = section.has("T_world_camera"), section.has("look_at")
    if has_T == has_look:
        raise SceneError("give the pose as exactly one of T_world_camera (4x4) or look_at {eye, target}",
                         field=section.field("T_world_camera"))
    if has_T:
        entry["T_world_camera"] = section.get("T_world_camera")
    else:
        look = section.section("look_at")
        eye, target = look.vector("eye", 3), look.vector("target", 3)
        up = look.vector("up", 3, default=[0.0, 0.0, 1.0])
        look.done()
        try:
            entry["T_world_camera"] = look_at(eye, target, up).tolist()
        except (ValueError, FloatingPointError) as exc:
            raise SceneError(f"cannot look from eye to target ({exc})", field=look.path) from None
    return entry


def _rig(entries: list[dict], depth_scale: float, principal, field: str, workspace=None) -> Rig:
    data = {"depth_scale": depth_scale, "principal": principal, "cameras": entries}
    if workspace is not None:
        data["workspace"] = workspace
    try:
        return rig_from_dict(data)
    except RigError as exc:
        where = field if exc.camera is None else f"{field}[{exc.camera}]"
        raise SceneError(exc.message, field=f"{where}.{exc.field}" if exc.field else where) from None


def _depth_cameras(top: Section, depth_scale: float, principal, base_dir: Path, workspace=None):
    sections = top.sections("cameras")
    if not sections:
        raise SceneError("needs at least one depth camera", field="cameras")
    entries, sensors, noise = [], {}, {}
    for section in sections:
        entry = _camera_entry(section)
        if "camera_info" in entry:
            entry["camera_info"] = str(base_dir / str(entry["camera_info"]))
        name = entry.get("name")
        sensors[name] = _sensor(section.section("sensor", default={}))
        noise[name] = section.number("noise_sigma", default=lab_config.SIM_INTENSITY_NOISE, minimum=0.0)
        section.done()
        entries.append(entry)
    rig = _rig(entries, depth_scale, principal, "cameras", workspace)
    return rig, sensors, noise


def _sensor(section: Section) -> SensorModel:
    model = SensorModel(
        noise=section.boolean("noise", default=True),
        edge_threshold=section.number("edge_threshold", default=lab_config.SIM_EDGE_THRESHOLD, positive=True),
        edge_dropout=section.number("edge_dropout", default=lab_config.SIM_EDGE_DROPOUT, minimum=0.0, maximum=1.0),
        grazing_angle=section.number("grazing_angle", default=lab_config.SIM_GRAZING_ANGLE, minimum=0.0,
                                     maximum=math.pi / 2),
        grazing_dropout=section.number("grazing_dropout", default=lab_config.SIM_GRAZING_DROPOUT, minimum=0.0,
                                       maximum=1.0),
    )
    section.done()
    return model


def _intensity_cameras(top: Section, depth_scale: float, base_dir: Path, taken: set):
    sections = top.sections("intensity_cameras", default=[])
    if not sections:
        return None, {}
    entries, noise = [], {}
    for section in sections:
        entry = _camera_entry(section)
        name = entry.get("name")
        if name in taken:
            raise SceneError(f"camera name {name!r} is already a depth camera's", field=section.field("name"))
        noise[name] = section.number("noise_sigma", default=lab_config.SIM_INTENSITY_NOISE, minimum=0.0)
        section.done()
        entries.append(entry)
    return _rig(entries, depth_scale, None, "intensity_cameras"), noise


# --------------------------------------------------------------------------------------------------- robot

def _robot(section: Section, sample_times: np.ndarray, base_dir: Path):
    kwargs = {}
    if section.has("T_world_base") and section.has("base"):
        raise SceneError("give the base pose as T_world_base or base, not both", field=section.field("base"))
    if section.has("T_world_base"):
        try:
            kwargs["T_world_base"] = check_transform(section.get("T_world_base"), field="T_world_base")
        except RigError as exc:
            raise SceneError(exc.message, field=section.field("T_world_base")) from None
    elif section.has("base"):
        base = section.section("base")
        position = base.vector("position", 3, default=[0.0, 0.0, 0.0])
        yaw = base.number("yaw", default=0.0)
        base.done()
        kwargs["T_world_base"] = yaw_pose(position, yaw)
    has_model, has_urdf = section.has("model"), section.has("urdf")
    if has_model == has_urdf:
        raise SceneError("give exactly one of model (iiwa, panda or xarm6) or urdf (a path)", field=section.field("model"))
    try:
        if has_model:
            robot = _builtin_robot(section.string("model", choices=("iiwa", "panda", "xarm6")))
            if "T_world_base" in kwargs:
                robot = robot.with_base(kwargs["T_world_base"])
        else:
            path = base_dir / section.string("urdf")
            if section.has("control_points"):
                kwargs["control_points"] = section.get("control_points")
            if section.has("end_effector"):
                kwargs["end_effector"] = section.string("end_effector")
            robot = RobotModel.from_urdf(path, **kwargs)
    except RobotError as exc:
        raise SceneError(exc.message + (f" ({exc.field})" if exc.field else ""),
                         field=section.field("model" if has_model else "urdf")) from None
    albedo = section.number("albedo", default=lab_config.SIM_ROBOT_ALBEDO, minimum=0.01, maximum=1.0)
    trajectory = _trajectory(section.section("trajectory"), robot, sample_times)
    section.done()
    return robot, albedo, trajectory


@functools.lru_cache(maxsize=None)
def _builtin_robot(model: str) -> RobotModel:
    """The built-in robots, read once per process (a RobotModel holds no state, so sharing it is safe)."""
    return RobotModel.builtin(model)


def _joint_values(robot: RobotModel, value, field: str) -> np.ndarray:
    try:
        return robot.joint_vector(value)
    except InputError as exc:
        raise SceneError(exc.message, field=field) from None


def _trajectory(section: Section, robot: RobotModel, sample_times: np.ndarray) -> RobotTrajectory:
    kind = section.string("type", choices=("joints", "hexagon"))
    if kind == "joints":
        waypoints = section.sections("waypoints")
        if not waypoints:
            raise SceneError("needs at least one waypoint", field=section.field("waypoints"))
        times, joints = [], []
        for waypoint in waypoints:
            times.append(waypoint.number("time", minimum=0.0))
            joints.append(_joint_values(robot, waypoint.get("joints"), waypoint.field("joints")))
            waypoint.done()
            if len(times) > 1 and times[-1] <= times[-2]:
                raise SceneError(f"waypoint times must increase ({times[-2]} then {times[-1]})",
                                 field=waypoint.field("time"))
        section.done()
        return JointTrajectory(times, joints, sample_times)
    normal = section.vector("plane_normal", 3, default=[1.0, 0.0, 0.0])
    if np.linalg.norm(normal) < 1e-9:
        raise SceneError("must not be the zero vector", field=section.field("plane_normal"))
    direction = section.integer("direction", default=1)
    if direction not in (1, -1):
        raise SceneError(f"must be 1 or -1, got {direction}", field=section.field("direction"))
    hexagon = Hexagon(center=section.vector("center", 3), radius=section.number("radius", positive=True),
                      plane_normal=normal / np.linalg.norm(normal),
                      start_angle=section.number("start_angle", default=0.0),
                      speed=section.number("speed", default=0.4, positive=True), direction=direction)
    posture = _joint_values(robot, section.get("posture"), section.field("posture"))
    section.done()
    return HexagonTrajectory(robot, hexagon, posture, sample_times, field=section.path)


# ------------------------------------------------------------------------------------------------- objects

def _static_object(section: Section, names: set) -> StaticObject:
    name = new_name(section, names)
    shapes = [key for key in ("box", "sphere", "capsule") if section.has(key)]
    if len(shapes) != 1:
        raise SceneError("needs exactly one shape key: box, sphere or capsule", field=section.field("box"))
    shape = section.section(shapes[0])
    if shapes[0] == "box":
        if shape.has("min") or shape.has("max"):
            lower, upper = shape.vector("min", 3), shape.vector("max", 3)
            if np.any(upper <= lower):
                raise SceneError(f"max must exceed min on every axis, got min {lower.tolist()} max {upper.tolist()}",
                                 field=shape.field("max"))
            primitive = Box.from_bounds(lower, upper)
        else:
            size = shape.vector("size", 3)
            if np.any(size <= 0):
                raise SceneError(f"must be positive, got {size.tolist()}", field=shape.field("size"))
            primitive = box_primitive(shape.vector("center", 3), shape.number("yaw", default=0.0), size)
    elif shapes[0] == "sphere":
        primitive = Sphere(tuple(shape.vector("center", 3)), shape.number("radius", positive=True))
    else:
        primitive = Capsule(tuple(shape.vector("p0", 3)), tuple(shape.vector("p1", 3)),
                            shape.number("radius", positive=True))
    shape.done()
    obj = StaticObject(name, primitive, section.number("albedo", default=lab_config.SIM_OBJECT_ALBEDO, minimum=0.01,
                                                       maximum=1.0), section.boolean("obstacle", default=True))
    section.done()
    return obj


def _carried_object(section: Section, names: set) -> CarriedObject:
    name = new_name(section, names)
    size = section.vector("size", 3)
    if np.any(size <= 0):
        raise SceneError(f"must be positive, got {size.tolist()}", field=section.field("size"))
    rest = pose_of(section.section("rest")) if section.has("rest") else None
    obj = CarriedObject(name, size, rest, section.number("albedo", default=lab_config.SIM_OBJECT_ALBEDO, minimum=0.01,
                                                         maximum=1.0))
    section.done()
    return obj
