"""The robot: kinematics (pinocchio), collision meshes, capsules and control points, from a URDF file."""

from __future__ import annotations

import math
import numbers
import threading
import types
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import pinocchio as pin
import trimesh

from depthguard import config
from depthguard.errors import InputError, RigError, RobotError
from depthguard.validation import (NOT_A_NUMBER, check_real, check_real_positive, check_transform, real_or_nan,
                                   real_vector, short_repr)
from depthguard.robots._capsules import LinkCapsule, fit_capsule
from depthguard.robots._urdf import UrdfDescription, collision_mesh, parse_urdf
from depthguard.scenes import Capsule


def _pybullet_data_path(relative: str) -> Path:
    """A file of pybullet's ``pybullet_data`` folder, which ships the default robots' URDFs and meshes."""
    try:
        import pybullet_data
    except ImportError:
        raise RobotError(f"the built-in robot {relative!r} comes from pybullet's 'pybullet_data' folder, and "
                         "pybullet is not installed: 'pip install depthguard[robots]', or load your own URDF with "
                         "RobotModel.from_urdf(path)") from None
    path = Path(pybullet_data.getDataPath()) / relative
    if not path.is_file():
        raise RobotError(f"the built-in robot {relative!r} is missing from pybullet_data", source=str(path))
    return path


def default_robot_path() -> Path:
    """The default robot's URDF: the KUKA LBR iiwa of ``pybullet_data`` (``config.DEFAULT_ROBOT_URDF``).

    pybullet must be installed (the ``robots`` extra, ``pip install depthguard[robots]``; a cell with its own URDF needs
    none of it); a :class:`RobotError` says so otherwise.
    """
    return _pybullet_data_path(config.DEFAULT_ROBOT_URDF)


def panda_robot_path() -> Path:
    """The Franka Emika Panda's URDF in ``pybullet_data`` (``config.PANDA_URDF``); needs pybullet, as above."""
    return _pybullet_data_path(config.PANDA_URDF)


def xarm6_robot_path() -> Path:
    """The UFACTORY xArm 6's URDF in ``pybullet_data`` (``config.XARM6_URDF``); needs pybullet, as above."""
    return _pybullet_data_path(config.XARM6_URDF)


@dataclass(frozen=True)
class ControlPoint:
    """A point fixed to a robot link whose distance to obstacles is monitored (the papers' control points).

    Attributes:
        name: unique among the robot's control points.
        link: the URDF link it is fixed to.
        offset: (3,) float64, metres, link frame: its position relative to the link's origin.
        radius: metres, or None: the sphere round the point that stands for the robot there (a distance from the
            point minus it is a distance from the robot's surface); None: the radius of its link's capsule
            (:attr:`RobotModel.control_point_radii`).
    """

    name: str
    link: str
    offset: np.ndarray = field(default_factory=lambda: np.zeros(3))
    radius: float | None = None

    def __post_init__(self):
        if not isinstance(self.name, str) or not self.name:
            raise RobotError(f"control point name must be a non-empty string, got {self.name!r}",
                             field="control_points")
        if not isinstance(self.link, str) or not self.link:
            raise RobotError(f"control point {self.name!r}: link must be a non-empty string, got {self.link!r}",
                             field="control_points")
        try:
            offset = np.array(self.offset, dtype=np.float64)
        except NOT_A_NUMBER:
            offset = None
        if offset is None or offset.shape != (3,) or not np.all(np.isfinite(offset)):
            raise RobotError(f"control point {self.name!r}: offset must be 3 finite numbers (metres, link frame), "
                             f"got {self.offset!r}", field="control_points")
        offset.setflags(write=False)
        object.__setattr__(self, "offset", offset)
        if self.radius is not None:
            check_real(self.radius, f"control point {self.name!r}: radius", minimum=0.0,
                       maximum=config.COORDINATE_LIMIT, unit="metres", error=RobotError, field="control_points")


class _Kinematics:
    """pinocchio's model plus the index maps between depthguard's joint order and pinocchio's, and one
    ``pinocchio.Data`` per thread (a work buffer: every call recomputes from q, nothing carries over)."""

    def __init__(self, model: pin.Model, description: UrdfDescription):
        self.model = model
        joints = description.movable_joints
        self.n = len(joints)
        self.q_index = np.empty(self.n, dtype=np.int64)
        self.v_index = np.empty(self.n, dtype=np.int64)
        self.continuous = np.zeros(self.n, dtype=bool)
        for i, joint in enumerate(joints):
            if not model.existJointName(joint.name):
                raise RobotError(f"joint {joint.name!r} is not in pinocchio's model of the URDF",
                                 source=str(description.path))
            joint_model = model.joints[model.getJointId(joint.name)]
            if joint_model.nv != 1 or joint_model.nq not in (1, 2):
                raise RobotError(f"joint {joint.name!r}: pinocchio made a joint with nq={joint_model.nq}, "
                                 f"nv={joint_model.nv}; only one-degree-of-freedom joints are supported",
                                 source=str(description.path))
            self.q_index[i] = joint_model.idx_q
            self.v_index[i] = joint_model.idx_v
            self.continuous[i] = joint_model.nq == 2  # an unbounded revolute joint: (cos, sin) in pinocchio
        if model.nv != self.n:
            raise RobotError(f"pinocchio's model has {model.nv} degrees of freedom, the URDF {self.n} movable joints",
                             source=str(description.path))
        self.identity_order = (not self.continuous.any() and model.nq == self.n
                               and np.array_equal(self.q_index, np.arange(self.n)))
        self.frame_ids = {}
        for link in description.links:
            if not model.existFrame(link, pin.FrameType.BODY):
                raise RobotError(f"link {link!r} is not in pinocchio's model of the URDF", source=str(description.path))
            self.frame_ids[link] = model.getFrameId(link, pin.FrameType.BODY)
        self._local = threading.local()

    def data(self) -> pin.Data:
        data = getattr(self._local, "data", None)
        if data is None:
            data = self._local.data = self.model.createData()
        return data

    def pin_configuration(self, q: np.ndarray) -> np.ndarray:
        if self.identity_order:
            return q
        q_pin = np.zeros(self.model.nq)
        plain = ~self.continuous
        q_pin[self.q_index[plain]] = q[plain]
        q_pin[self.q_index[self.continuous]] = np.cos(q[self.continuous])
        q_pin[self.q_index[self.continuous] + 1] = np.sin(q[self.continuous])
        return q_pin

    def anchors(self, links, offsets) -> "_Anchors":
        """Where points fixed to links sit in pinocchio's joint frames (precomputed once per set of points).

        ``links``: (m,) link names; ``offsets``: (m, 3) metres, each in its link's frame.
        """
        joints, positions = [], []
        for link, offset in zip(links, offsets):
            frame = self.model.frames[self.frame_ids[link]]
            joints.append(frame.parentJoint)
            positions.append(frame.placement.act(np.asarray(offset, dtype=np.float64)))
        unique = sorted(set(joints))
        return _Anchors(
            joints=tuple(joints),
            placements=tuple(pin.SE3(np.eye(3), p) for p in positions),
            unique_joints=tuple(unique),
            row=np.array([unique.index(j) for j in joints], dtype=np.int64),
            p_joint=np.array(positions, dtype=np.float64).reshape(-1, 3),
        )


@dataclass(frozen=True, eq=False)
class _Anchors:
    """Points fixed to links, in pinocchio's terms: parent joint id and position in that joint's frame (metres).

    ``placements`` are the same positions as ``pinocchio.SE3`` (identity rotation) for ``getFrameJacobian``;
    ``unique_joints`` the joints carrying points, ``row`` (m,) each point's index into them, ``p_joint`` (m, 3).
    """

    joints: tuple[int, ...] = ()
    placements: tuple = ()
    unique_joints: tuple[int, ...] = ()
    row: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    p_joint: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))

    def positions(self, data: pin.Data, T_world_base: np.ndarray) -> np.ndarray:
        """(m, 3) float64, metres, world frame, after ``data`` went through forward kinematics."""
        oMi = data.oMi
        T_base_joint = np.array([oMi[joint].homogeneous for joint in self.unique_joints])[self.row]
        p_base = np.einsum("mij,mj->mi", T_base_joint[:, :3, :3], self.p_joint) + T_base_joint[:, :3, 3]
        return p_base @ T_world_base[:3, :3].T + T_world_base[:3, 3]


@dataclass(frozen=True, eq=False)
class RobotModel:
    """A robot arm read from a URDF: kinematics, collision geometry, capsules and control points.

    Build it with :meth:`from_urdf`, :meth:`default` (KUKA LBR iiwa) or :meth:`panda`. It holds no joint state:
    every method takes the configuration ``q`` and recomputes from it (thread-safe).

    Joint vectors ``q``: (n,) float64, radians (revolute, continuous) or metres (prismatic), in the order of
    :attr:`joint_names` (the movable joints in the order the URDF file lists them). Build them by name with
    :meth:`joint_vector`. ``<mimic>`` tags are ignored: a mimicking joint is a joint of its own, as in ROS
    ``joint_states`` and in pybullet.

    Frames: the URDF's root link is the robot's base; ``T_world_base`` (4, 4) float64 places it in the world.
    Everything the methods return is in the world frame unless said otherwise.

    Attributes:
        name: the URDF's robot name.
        urdf_path: the URDF file.
        joint_names: (n,) movable joints, the documented order of joint vectors.
        lower, upper: (n,) float64 joint limits, rad or m (-inf/+inf for continuous joints). Read-only.
        velocity_limits: (n,) float64, rad/s or m/s. Read-only.
        link_names: links that carry collision geometry, in URDF order.
        all_link_names: every link of the URDF, in URDF order (the keys of :meth:`link_poses`).
        control_points: the monitored points; :attr:`end_effector` names the end-effector's.
        end_effector: name of the end-effector control point.
        collision_meshes: link -> ``trimesh.Trimesh`` in the link frame, metres (URDF collision geometry with its
            origins applied; primitives as meshes that contain them). Shared, do not modify.
        capsules: one :class:`LinkCapsule` per link of :attr:`link_names`, in the link frame, containing its
            collision mesh plus ``padding``.
        padding: metres added to the capsules' radii.
        T_world_base: (4, 4) float64 pose of the root link in the world. Read-only.
    """

    name: str
    urdf_path: Path
    joint_names: tuple[str, ...]
    lower: np.ndarray
    upper: np.ndarray
    velocity_limits: np.ndarray
    link_names: tuple[str, ...]
    all_link_names: tuple[str, ...]
    control_points: tuple[ControlPoint, ...]
    end_effector: str
    collision_meshes: Mapping[str, trimesh.Trimesh]
    capsules: tuple[LinkCapsule, ...]
    padding: float
    T_world_base: np.ndarray
    _description: UrdfDescription = field(repr=False)
    _kinematics: _Kinematics = field(repr=False)
    _anchors: _Anchors = field(default_factory=_Anchors, repr=False)  # the control points
    _capsule_anchors: _Anchors = field(default_factory=_Anchors, repr=False)  # p0, p1 of each capsule in turn

    # -------------------------------------------------------------------------------------------- construction

    @classmethod
    def from_urdf(cls, path, package_dirs=None, control_points=None, padding: float = config.DEFAULT_ROBOT_PADDING,
                  T_world_base=None, end_effector: str | None = None) -> "RobotModel":
        """Read a robot from a URDF file.

        Args:
            path: the URDF file. Mesh names may be relative to it, ``package://`` or ``file://`` URLs.
            package_dirs: directories in which ``package://pkg/...`` names are looked up (as ``<dir>/pkg/...``);
                default: the URDF's directory.
            control_points: a sequence of :class:`ControlPoint` or of ``(name, link, offset)`` triples; default:
                one at the middle of each moving link's capsule axis (named after the link), then one named
                ``end_effector`` at the origin of the chain's tip link (see ``UrdfDescription.tip``).
            padding: metres added to every capsule's radius (>= 0).
            T_world_base: (4, 4) pose of the URDF's root link in the world; default identity.
            end_effector: the name of the end-effector control point; default: the last control point.

        Raises :class:`RobotError` naming the file and the link or joint when the URDF or a mesh is missing or
        malformed, a joint type is not supported, or a control point names no link.
        """
        padding = _check_padding(padding)
        description = parse_urdf(path, package_dirs)
        try:
            model = pin.buildModelFromXML(description.xml)  # the text parse_urdf read and checked
        except Exception as exc:  # pinocchio raises RuntimeError or ValueError with urdfdom's message
            raise RobotError(f"pinocchio cannot build the kinematic model ({exc})",
                             source=str(description.path)) from None
        kinematics = _Kinematics(model, description)
        meshes, capsules = {}, []
        for link, items in description.collisions.items():
            mesh = collision_mesh(items, description.path)
            meshes[link] = mesh
            capsules.append(fit_capsule(mesh.vertices, link=link, padding=padding))
        joints = description.movable_joints
        limits = {}
        for key in ("lower", "upper", "velocity"):
            array = np.array([getattr(joint, key) for joint in joints], dtype=np.float64)
            array.setflags(write=False)
            limits[key] = array
        robot = cls(
            name=description.name,
            urdf_path=description.path,
            joint_names=tuple(joint.name for joint in joints),
            lower=limits["lower"],
            upper=limits["upper"],
            velocity_limits=limits["velocity"],
            link_names=tuple(description.collisions),
            all_link_names=description.links,
            control_points=(),
            end_effector="",
            collision_meshes=types.MappingProxyType(meshes),
            capsules=tuple(capsules),
            padding=padding,
            T_world_base=_check_base(np.eye(4) if T_world_base is None else T_world_base),
            _description=description,
            _kinematics=kinematics,
            _capsule_anchors=kinematics.anchors([c.link for c in capsules for _ in (0, 1)],
                                                [end for c in capsules for end in (c.p0, c.p1)]),
        )
        if control_points is None:
            control_points = robot._default_control_points()
        return robot.with_control_points(control_points, end_effector=end_effector)

    @classmethod
    def default(cls, **kwargs) -> "RobotModel":
        """The default robot: pybullet_data's KUKA LBR iiwa (7 revolute joints) with the papers' 9 control points
        (``config.IIWA_CONTROL_POINTS``). Keyword arguments go to :meth:`from_urdf`. Needs pybullet installed."""
        kwargs.setdefault("control_points", config.IIWA_CONTROL_POINTS)
        return cls.from_urdf(default_robot_path(), **kwargs)

    @classmethod
    def panda(cls, **kwargs) -> "RobotModel":
        """pybullet_data's Franka Emika Panda: 7 revolute arm joints then 2 prismatic finger joints (9 in all),
        with ``config.PANDA_CONTROL_POINTS``. Keyword arguments go to :meth:`from_urdf`. Needs pybullet."""
        kwargs.setdefault("control_points", config.PANDA_CONTROL_POINTS)
        return cls.from_urdf(panda_robot_path(), **kwargs)

    @classmethod
    def xarm6(cls, **kwargs) -> "RobotModel":
        """pybullet_data's UFACTORY xArm 6: 6 revolute joints (a 6-joint arm as in Henrich & Gecks' scenario C),
        with the default control points (one per moving link, then the end-effector). Keyword arguments go to
        :meth:`from_urdf`. Needs pybullet."""
        return cls.from_urdf(xarm6_robot_path(), **kwargs)

    @classmethod
    def builtin(cls, name: str) -> "RobotModel":
        """A built-in robot by name: "iiwa" (:meth:`default`), "panda" or "xarm6"."""
        makers = {"iiwa": cls.default, "panda": cls.panda, "xarm6": cls.xarm6}
        if name not in makers:
            raise RobotError(f"unknown built-in robot {name!r}; choose one of {', '.join(makers)}", field="robot")
        return makers[name]()

    def with_base(self, T_world_base) -> "RobotModel":
        """The same robot mounted at ``T_world_base`` ((4, 4), pose of the root link in the world)."""
        return replace(self, T_world_base=_check_base(T_world_base))

    def with_control_points(self, control_points, end_effector: str | None = None) -> "RobotModel":
        """The same robot with other control points (see :meth:`from_urdf`)."""
        points = []
        for item in control_points:
            point = item if isinstance(item, ControlPoint) else _control_point(item)
            if point.link not in self._kinematics.frame_ids:
                raise RobotError(f"control point {point.name!r}: no link {point.link!r} in the URDF",
                                 field="control_points", source=str(self.urdf_path))
            points.append(point)
        if not points:
            raise RobotError("a robot needs at least one control point", field="control_points")
        names = [point.name for point in points]
        duplicates = sorted({name for name in names if names.count(name) > 1})
        if duplicates:
            raise RobotError(f"control point names used twice: {', '.join(duplicates)}", field="control_points")
        if end_effector is None:
            end_effector = names[-1]
        elif end_effector not in names:
            raise RobotError(f"end_effector {end_effector!r} is not a control point (control points: "
                             f"{', '.join(names)})", field="end_effector")
        anchors = self._kinematics.anchors([p.link for p in points], [p.offset for p in points])
        return replace(self, control_points=tuple(points), end_effector=end_effector, _anchors=anchors)

    def _default_control_points(self) -> list[ControlPoint]:
        description = self._description
        points = []
        for capsule in self.capsules:
            if description.moves(capsule.link):
                points.append(ControlPoint(capsule.link, capsule.link, 0.5 * (capsule.p0 + capsule.p1)))
        tip = description.tip()
        name = "end_effector" if "end_effector" not in [p.name for p in points] else f"end_effector_{tip}"
        points.append(ControlPoint(name, tip, np.zeros(3)))
        return points

    # --------------------------------------------------------------------------------------------------- joints

    @property
    def n_joints(self) -> int:
        """Number of movable joints n (the length of joint vectors)."""
        return len(self.joint_names)

    @property
    def control_point_names(self) -> tuple[str, ...]:
        """Names of the control points, in the order of the rows of the positions and Jacobians."""
        return tuple(point.name for point in self.control_points)

    @property
    def control_point_radii(self) -> np.ndarray:
        """(m,) float64 metres, each control point's radius: its own (``ControlPoint.radius``), else its link capsule's
        (padding included; 0 for a link without geometry): a distance from the control point minus it is the
        distance from the link's surface there (the point taken as the centre of a sphere of that radius)."""
        radii = {capsule.link: capsule.radius for capsule in self.capsules}
        return np.array([point.radius if point.radius is not None else radii.get(point.link, 0.0)
                         for point in self.control_points], dtype=np.float64)

    def with_tool(self, link: str, solid) -> "RobotModel":
        """The same robot carrying a tool or a gripped piece fixed to ``link``: ``solid`` is a
        :class:`depthguard.scenes.Box`, :class:`~depthguard.scenes.Sphere` or :class:`~depthguard.scenes.Capsule` in
        the link's frame (metres). It becomes part of the link's collision geometry (a mesh that contains it), so
        everything that takes the robot takes it too: self-filtering renders it, the link's capsule is fitted again
        round both (padding included), ``with_surface_points`` covers it, and the ground truth's meshes hold it.
        Call again for more pieces. Raises :class:`RobotError` naming ``link`` for a link without kinematics, and
        :class:`InputError` for a solid that is not one of those, or not finite."""
        from depthguard.rendering import primitive_mesh
        from depthguard.scenes import Box, Capsule, Sphere

        if not isinstance(link, str) or link not in self._kinematics.frame_ids:
            raise RobotError(f"with_tool: no link {link!r} in the URDF", field="link", source=str(self.urdf_path))
        if not isinstance(solid, (Box, Sphere, Capsule)):
            raise InputError(f"a tool must be a depthguard.scenes Box, Sphere or Capsule in the link's frame, got "
                             f"{short_repr(solid)}", field="tool")
        vertices, faces = primitive_mesh(solid)
        if not np.all(np.isfinite(vertices)) or np.abs(vertices).max() > config.COORDINATE_LIMIT:
            raise InputError("a tool's geometry must be finite and within the coordinate limit", field="tool")
        piece = trimesh.Trimesh(vertices, faces, process=False)
        meshes = dict(self.collision_meshes)
        meshes[link] = piece if link not in meshes else trimesh.util.concatenate([meshes[link], piece])
        capsule = fit_capsule(meshes[link].vertices, link=link, padding=self.padding)
        names = list(self.link_names)
        capsules = list(self.capsules)
        if link in names:
            capsules[names.index(link)] = capsule
        else:
            names.append(link)
            capsules.append(capsule)
        anchors = self._kinematics.anchors([c.link for c in capsules for _ in (0, 1)],
                                           [end for c in capsules for end in (c.p0, c.p1)])
        return replace(self, link_names=tuple(names), collision_meshes=types.MappingProxyType(meshes),
                       capsules=tuple(capsules), _capsule_anchors=anchors)

    def with_surface_points(self, tolerance: float = config.SSM_ROBOT_UNCERTAINTY) -> "RobotModel":
        """The same robot with control points whose spheres cover every moving link's whole padded capsule, each no
        more than ``tolerance`` metres (> 0) beyond it, and the end-effector's control point kept (last, the
        end-effector): design §9, "distances from the robot's surface".

        Along each moving link's capsule axis (length L, radius r, padding included), k >= 2 points evenly spaced
        (k = 1 for a ball), spacing h = L / (k - 1) <= 2 sqrt((r + t)^2 - r^2), each the centre of a sphere of
        radius sqrt(r^2 + (h / 2)^2) <= r + t: every point of the capsule is within r of its axis, and every point
        of the axis within h / 2 of a centre. So a distance from a point minus its radius is at most the distance
        from the capsule, and at least that minus t. Names ``<link>/<i>``."""
        tolerance = float(check_real_positive(tolerance, "tolerance"))
        points = []
        for capsule, moves in zip(self.capsules, self.moving_links()):
            if not moves:
                continue
            p0, p1, r = np.asarray(capsule.p0), np.asarray(capsule.p1), float(capsule.radius)
            length = float(np.linalg.norm(p1 - p0))
            spacing = 2.0 * math.sqrt((r + tolerance) ** 2 - r * r)
            k = 1 if length == 0.0 else max(2, int(math.ceil(length / spacing)) + 1)
            h = 0.0 if k == 1 else length / (k - 1)
            radius = math.sqrt(r * r + 0.25 * h * h)
            for i in range(k):
                offset = p0 if k == 1 else p0 + (p1 - p0) * (i / (k - 1))
                points.append(ControlPoint(f"{capsule.link}/{i}", capsule.link, offset, radius))
        points.append(next(p for p in self.control_points if p.name == self.end_effector))
        return self.with_control_points(points, end_effector=self.end_effector)

    @property
    def end_effector_index(self) -> int:
        """Row of the end-effector control point in :meth:`control_point_positions`."""
        return self.control_point_names.index(self.end_effector)

    def joint_vector(self, joints, *, limit_tolerance: float = config.JOINT_LIMIT_TOLERANCE) -> np.ndarray:
        """A checked joint vector q: (n,) float64, rad or m, in :attr:`joint_names` order.

        ``joints`` is either a mapping joint name -> value, which must name every movable joint and nothing else
        (no joint silently defaults to zero), or a sequence of exactly n values in :attr:`joint_names` order.

        Limits: a value at most ``limit_tolerance`` (rad or m; default ``config.JOINT_LIMIT_TOLERANCE``) beyond its
        joint's limits is returned as given, not clipped (a measured state may overshoot a little, and the geometry
        must stay where the robot is); further out is an error, as it means wrong units, order or model. Pass
        ``limit_tolerance=math.inf`` to accept any finite value.

        Raises :class:`InputError` (field ``joints``) naming the missing, unknown, non-finite or out-of-limit
        joints, or the wrong length.
        """
        if isinstance(joints, Mapping):
            unknown = [name for name in joints if name not in self.joint_names]
            missing = [name for name in self.joint_names if name not in joints]
            if unknown or missing:
                parts = []
                if missing:
                    parts.append(f"missing joints: {', '.join(map(str, missing))}")
                if unknown:
                    parts.append(f"unknown joints: {', '.join(map(str, unknown))}")
                raise InputError(f"{'; '.join(parts)} (the robot's movable joints: {', '.join(self.joint_names)})",
                                 field="joints")
            values = [joints[name] for name in self.joint_names]
        elif isinstance(joints, (str, bytes)):
            raise InputError(f"expected a mapping or a sequence of {self.n_joints} numbers, got a string",
                             field="joints")
        else:
            values = joints
        q = real_vector(values, self.n_joints, "joints", "radians or metres")
        if q.shape != (self.n_joints,):
            raise InputError(f"expected {self.n_joints} values (one per joint: {', '.join(self.joint_names)}), got "
                             f"shape {q.shape}", field="joints")
        self._check_values(q, limit_tolerance, "joints")
        return q

    def _check_values(self, q: np.ndarray, limit_tolerance: float, field_name: str) -> None:
        bad = ~np.isfinite(q)
        if bad.any():
            names = [f"{self.joint_names[i]}={q[i]}" for i in np.flatnonzero(bad)]
            raise InputError(f"joint values must be finite: {', '.join(names)}", field=field_name)
        tolerance = real_or_nan(limit_tolerance)  # +inf accepts any finite value; NaN and overflow fail
        if not tolerance >= 0:
            raise InputError(f"limit_tolerance must be a number >= 0 (or inf), got {short_repr(limit_tolerance)}",
                             field="limit_tolerance")
        limit_tolerance = tolerance
        out = (q < self.lower - limit_tolerance) | (q > self.upper + limit_tolerance)
        if out.any():
            names = [f"{self.joint_names[i]}={q[i]:.6g} not in [{self.lower[i]:.6g}, {self.upper[i]:.6g}]"
                     for i in np.flatnonzero(out)]
            raise InputError(f"joint values beyond their limits by more than {limit_tolerance:g} (wrong units, "
                             f"order or model?): {'; '.join(names)}", field=field_name)

    def _q(self, q, check: bool) -> np.ndarray:
        if not check:
            return np.ascontiguousarray(q, dtype=np.float64)
        q = real_vector(q, self.n_joints, "q", "radians or metres")
        if q.shape != (self.n_joints,):
            raise InputError(f"expected shape ({self.n_joints},) in the order of joint_names, got {q.shape}; build "
                             "it by name with joint_vector()", field="q")
        tol = config.JOINT_LIMIT_TOLERANCE
        if not (np.isfinite(q).all() and (q >= self.lower - tol).all() and (q <= self.upper + tol).all()):
            self._check_values(q, tol, "q")  # raises, naming the joints
        return np.ascontiguousarray(q)

    # ----------------------------------------------------------------------------------------------- kinematics

    def _forward(self, q, check: bool) -> pin.Data:
        kin = self._kinematics
        data = kin.data()
        pin.forwardKinematics(kin.model, data, kin.pin_configuration(self._q(q, check)))
        return data

    def link_poses(self, q, *, check: bool = True) -> dict[str, np.ndarray]:
        """Pose of every link (:attr:`all_link_names`) at ``q``: link name -> (4, 4) float64 ``T_world_link``.

        ``q``: (n,) float64 joint vector in :attr:`joint_names` order. ``check=False`` skips its validation (shape,
        finite values, limits) for the hot loop.
        """
        kin = self._kinematics
        data = self._forward(q, check)
        pin.updateFramePlacements(kin.model, data)
        T_world_base = self.T_world_base
        return {link: T_world_base @ data.oMf[fid].homogeneous for link, fid in kin.frame_ids.items()}

    def control_point_positions(self, q, *, check: bool = True) -> np.ndarray:
        """Control point positions at ``q``: (m, 3) float64, metres, world frame, rows in :attr:`control_points`
        order. ``q`` as in :meth:`link_poses`."""
        data = self._forward(q, check)
        return self._positions(data)

    def _positions(self, data) -> np.ndarray:
        return self._anchors.positions(data, self.T_world_base)

    def control_point_jacobians(self, q, *, check: bool = True) -> np.ndarray:
        """Positional Jacobians of the control points at ``q``: (m, 3, n) float64, metres per radian (or per metre
        for prismatic joints), world frame: ``J[i] @ dq`` is control point i's velocity for joint velocities dq
        (in :attr:`joint_names` order). ``q`` as in :meth:`link_poses`."""
        return self.control_point_kinematics(q, check=check)[1]

    def control_point_kinematics(self, q, *, check: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """Positions (m, 3) and Jacobians (m, 3, n) of the control points in one pass (see the two methods above)."""
        kin = self._kinematics
        model, data = kin.model, kin.data()
        pin.computeJointJacobians(model, data, kin.pin_configuration(self._q(q, check)))
        frame = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
        anchors = self._anchors
        jacobians = np.array([pin.getFrameJacobian(model, data, joint, placement, frame)[:3]
                              for joint, placement in zip(anchors.joints, anchors.placements)])
        if not kin.identity_order:
            jacobians = jacobians[:, :, kin.v_index]
        return self._positions(data), np.matmul(self.T_world_base[:3, :3], jacobians)

    # ------------------------------------------------------------------------------------------------- geometry

    def capsules_world(self, q, *, check: bool = True) -> list[Capsule]:
        """The link capsules at ``q`` as :class:`depthguard.scenes.Capsule` in the world frame (metres), in
        :attr:`link_names` order; their radii include the padding."""
        data = self._forward(q, check)
        ends = self._capsule_anchors.positions(data, self.T_world_base)
        return [Capsule(tuple(ends[2 * i]), tuple(ends[2 * i + 1]), capsule.radius)
                for i, capsule in enumerate(self.capsules)]

    def capsule_segments(self, q, *, check: bool = True) -> np.ndarray:
        """The core segments of the link capsules at ``q``: (m, 2, 3) float64, metres, world frame, rows in
        :attr:`link_names` order (radii: ``capsule.radius`` of :attr:`capsules`, padding included)."""
        data = self._forward(q, check)
        return self._capsule_anchors.positions(data, self.T_world_base).reshape(-1, 2, 3)

    def inner_capsules_world(self, q, *, check: bool = True) -> np.ndarray:
        """(k, 7) float64, metres, world frame: capsules (p0 (3), p1 (3), radius) that lie inside the robot's collision
        meshes at ``q``, never in their padding: the robot's own volume, where no person can be (design §8a's
        Robot_k). Balls (p0 = p1), up to ``config.INNER_BALLS`` a link, that fit in the link's mesh with its open ends
        closed (:func:`depthguard.robots._inner.inner_balls`); found once per model and cached. A link whose mesh the
        fans cannot close adds none."""
        radii, anchors = self._inner_capsules()
        out = np.empty((len(radii), 7))
        if len(radii):
            ends = anchors.positions(self._forward(q, check), self.T_world_base)
            out[:, 0:3] = ends[0::2]
            out[:, 3:6] = ends[1::2]
            out[:, 6] = radii
        return out

    def _inner_capsules(self) -> tuple[np.ndarray, "_Anchors"]:
        from depthguard.robots._inner import inner_balls

        key = (str(self.urdf_path), tuple((c.link, tuple(c.p0), tuple(c.p1), c.radius) for c in self.capsules))
        with _GAP_LOCK:
            if key not in _INNER_CAPSULES:
                pieces = [piece for capsule in self.capsules
                          for piece in inner_balls(self.collision_meshes[capsule.link], capsule.link)]
                anchors = self._kinematics.anchors([c.link for c in pieces for _ in (0, 1)],
                                                   [end for c in pieces for end in (c.p0, c.p1)])
                _INNER_CAPSULES[key] = (np.array([c.radius for c in pieces], dtype=np.float64), anchors)
            return _INNER_CAPSULES[key]

    def reach(self) -> float:
        """Metres: a radius about the base's origin (``T_world_base``) that holds every capsule of the robot at every
        configuration: for the links a joint moves, the longest chain of rigid offsets from the base to their
        capsules (the first joint's placement plus :meth:`joint_reaches`), for the others their capsules' ends plus
        radius."""
        model = self._kinematics.model
        reaches = self.joint_reaches()
        out = 0.0
        for i, name in enumerate(self.joint_names):
            joint = model.getJointId(name)
            chain, k = 0.0, joint
            while k > 0:  # the rigid offsets from the root to this joint
                chain += float(np.linalg.norm(model.jointPlacements[k].translation))
                k = model.parents[k]
            out = max(out, chain + float(reaches[i]))
        for capsule, moves in zip(self.capsules, self.moving_links()):
            if not moves:
                ends = self.capsules_world(np.clip(np.zeros(self.n_joints), self.lower, self.upper), check=False)
                fixed = ends[self.link_names.index(capsule.link)]
                origin = self.T_world_base[:3, 3]
                out = max(out, max(np.linalg.norm(np.subtract(fixed.p0, origin)),
                                   np.linalg.norm(np.subtract(fixed.p1, origin))) + capsule.radius)
        return out

    def capsule_gap(self) -> float:
        """Metres: how thick a layer between a link's capsule and the robot's collision meshes can be, so how thick an
        object lying on the robot inside its capsules may be (the padding not counted: add ``padding``). Measured
        once per model (a few seconds, then cached): at ``config.CAPSULE_GAP_CONFIGURATIONS`` configurations (all
        zeros, then seeded random ones within the limits), the largest distance from a sample of a capsule's
        surface, its radius less the padding, to the nearest sample of every link's mesh surface (the meshes of
        the neighbouring links close a link's open ends), plus the spacing of those samples. A monitor that counts
        the capsules as the robot can hide an object of that thickness plus the padding (and its robot zone) on
        the robot (``DistanceMonitor``'s hidden band)."""
        key = (str(self.urdf_path), self.padding, tuple(map(tuple, self.T_world_base)),
               tuple((c.link, tuple(c.p0), tuple(c.p1), c.radius) for c in self.capsules))  # tools included
        with _GAP_LOCK:
            if key not in _CAPSULE_GAPS:
                _CAPSULE_GAPS[key] = self._measure_capsule_gap()
            return _CAPSULE_GAPS[key]

    def _measure_capsule_gap(self) -> float:
        from scipy.spatial import cKDTree

        rng = np.random.default_rng(config.CAPSULE_GAP_SEED)
        low = np.where(np.isfinite(self.lower), self.lower, -math.pi)
        high = np.where(np.isfinite(self.upper), self.upper, math.pi)
        configurations = [np.clip(np.zeros(self.n_joints), low, high)] + \
            [rng.uniform(low, high) for _ in range(config.CAPSULE_GAP_CONFIGURATIONS - 1)]
        moving = self.moving_links()
        gap = 0.0
        for q in configurations:
            poses = self.link_poses(q)
            meshes = []
            for link, mesh in self.collision_meshes.items():
                placed = mesh.copy()
                placed.apply_transform(poses[link])
                meshes.append(placed)
            union = trimesh.util.concatenate(meshes)
            count = config.CAPSULE_GAP_MESH_SAMPLES
            samples, _ = trimesh.sample.sample_surface(union, count, seed=int(rng.integers(2**31)))
            spacing = math.sqrt(float(union.area) / count)  # the samples' typical spacing: added to the gap
            tree = cKDTree(samples)
            for capsule, is_moving in zip(self.capsules_world(q, check=False), moving):
                if not is_moving:
                    continue
                p0, p1 = np.array(capsule.p0), np.array(capsule.p1)
                radius = max(capsule.radius - self.padding, 0.0)
                n = config.CAPSULE_GAP_SURFACE_SAMPLES
                directions = rng.normal(size=(n, 3))
                directions /= np.linalg.norm(directions, axis=1)[:, None]
                points = p0 + rng.uniform(0.0, 1.0, (n, 1)) * (p1 - p0) + radius * directions
                distance, _ = tree.query(points)
                gap = max(gap, float(distance.max()) + spacing)
        return gap

    def moving_links(self) -> np.ndarray:
        """(m,) bool per link of :attr:`link_names`: whether a movable joint moves it (False for the base and links
        fixed to it)."""
        return np.array([joint != 0 for joint in self._capsule_anchors.joints[::2]], dtype=bool)

    def joint_reaches(self) -> np.ndarray:
        """(n,) float64, for every joint (:attr:`joint_names` order) a bound, valid at every configuration, on how
        fast any point of the padded capsules moves per unit of that joint's velocity: metres per radian for a
        revolute joint (the point's distance from the joint's axis), 1 for a prismatic one.

        The bound for a revolute joint is the longest chain of rigid offsets from the joint's origin to a point of a
        capsule it moves (the joint placements' translations on the way, plus the capsule end's offset and radius),
        plus the travel of any prismatic joint on the way (its largest absolute limit)."""
        kin = self._kinematics
        model = kin.model
        ends = self._capsule_anchors
        radii = np.repeat([capsule.radius for capsule in self.capsules], 2)
        reaches = np.zeros(self.n_joints)
        for i, name in enumerate(self.joint_names):
            joint = model.getJointId(name)
            if "P" in model.joints[joint].shortname().replace("JointModel", ""):
                reaches[i] = 1.0
                continue
            for parent, p_joint, radius in zip(ends.joints, ends.p_joint, radii):
                chain, k = 0.0, parent
                while k > joint:  # pinocchio numbers every joint after its parent
                    chain += float(np.linalg.norm(model.jointPlacements[k].translation))
                    travel = model.joints[k].shortname().replace("JointModel", "")
                    if "P" in travel:
                        index = self.joint_names.index(model.names[k])
                        chain += float(max(abs(self.lower[index]), abs(self.upper[index])))
                    k = model.parents[k]
                if k == joint:
                    reaches[i] = max(reaches[i], chain + float(np.linalg.norm(p_joint)) + float(radius))
        return reaches

    def __repr__(self) -> str:
        return (f"RobotModel(name={self.name!r}, joints={len(self.joint_names)}, links with geometry="
                f"{len(self.link_names)}, control points={len(self.control_points)}, padding={self.padding:g})")


_CAPSULE_GAPS: dict = {}  # (urdf, padding, base) -> metres, RobotModel.capsule_gap
_GAP_LOCK = threading.Lock()
_INNER_CAPSULES: dict = {}  # (urdf, capsules) -> (radii, anchors), RobotModel.inner_capsules_world


def _control_point(item) -> ControlPoint:
    try:
        name, link, offset = item
    except (TypeError, ValueError):
        raise RobotError(f"a control point must be a ControlPoint or (name, link, offset), got {item!r}",
                         field="control_points") from None
    return ControlPoint(name, link, offset)


def _check_padding(padding) -> float:
    if isinstance(padding, bool) or not isinstance(padding, (int, float, np.floating, np.integer)):
        raise RobotError(f"must be a number of metres, got {padding!r}", field="padding")
    if not (math.isfinite(padding) and padding >= 0):
        raise RobotError(f"must be finite and >= 0 metres, got {padding!r}", field="padding")
    return float(padding)


def _check_base(T_world_base) -> np.ndarray:
    try:
        T = check_transform(T_world_base, field="T_world_base")
    except RigError as exc:
        raise RobotError(exc.message, field="T_world_base") from None
    T.setflags(write=False)
    return T
