"""Reading a URDF file: its kinematic tree, joint limits and collision geometry, with errors that name the file and
the link or joint.

Kinematics itself is pinocchio's (see ``_model.py``); this module reads what pinocchio does not hand back in a usable
form: the file order of the joints, their limits, and each link's ``<collision>`` elements, which it turns into
:class:`trimesh.Trimesh` objects in the link frame.

Mesh file names are resolved as ROS and pinocchio do: ``package://pkg/rel/path`` is looked up as ``<dir>/pkg/rel/path``
in each of ``package_dirs`` (and as ``<dir>/rel/path`` when ``<dir>`` is itself called ``pkg``), ``file:///abs`` is an
absolute path, and any other name is relative to the URDF's directory.

What a URDF may read (a URDF is input from outside, like a rig file):

- Mesh files must lie, after following ``..`` and symbolic links, inside the URDF's folder or inside one of the
  ``package_dirs`` given explicitly. A mesh name that leads elsewhere (``../../secret.stl``, ``file:///etc/...``, a
  symbolic link out of the folder) is a :class:`RobotError` naming the link and the path; to use meshes kept
  elsewhere, pass their folder in ``package_dirs``.
- The URDF and each mesh are regular files (not a device, pipe or folder) of at most ``config.MAX_URDF_BYTES`` and
  ``config.MAX_MESH_FILE_BYTES`` bytes, read once through :mod:`depthguard.io.files`; a mesh is decoded from those
  bytes by trimesh, which opens no other file (an OBJ's material library is not read: collision needs none).
- The XML may not have a document type declaration (``<!DOCTYPE ...>``): no DTD, no entity declarations, so no
  entity expansion (internal or external) and no file or network access while parsing. The same bytes go to
  pinocchio, which therefore builds its model from exactly the text that was checked.

Every number in the URDF that pinocchio's parser (urdfdom) or depthguard reads is checked once, before either reads
it (``_NUMBERS``): a plain decimal number (``nan``, ``inf``, hexadecimal and ``1_000`` are refused: Python and urdfdom
read them differently), finite (``1e400`` is refused), and within its range: positions (``<origin xyz>``) and joint
limits within ``config.COORDINATE_LIMIT``, as a rig's coordinates; box sizes, cylinder radii and lengths and sphere
radii in [0, ``config.COORDINATE_LIMIT``]; effort and mass >= 0; angles (``rpy``), axes, velocities, inertias and the
rest finite. Where depthguard uses a number it also checks what that use needs: a collision shape's sizes and mesh
scale components > 0 (a negative scale mirrors the mesh, which flips its faces' winding, and is refused; a
``<visual>``, which depthguard does not use, may be flat or mirrored), a movable joint's unit axis, positive velocity
limit and ordered position limits, and a link's collision geometry, scaled and placed, within
``config.COORDINATE_LIMIT`` of the link's origin on every axis. Each refusal is a :class:`RobotError` naming the
file, the link or joint, the element and the attribute.
"""

from __future__ import annotations

import io
import math
import os
import re
import xml.etree.ElementTree as ET
import xml.parsers.expat
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import trimesh

from depthguard import config
from depthguard.io.files import read_bytes
from depthguard.errors import RobotError
from depthguard.validation import check_path, short_repr

#: Joint types with one degree of freedom, which depthguard accepts.
MOVABLE_TYPES = ("revolute", "continuous", "prismatic")
_ALL_TYPES = MOVABLE_TYPES + ("fixed", "floating", "planar")


@dataclass(frozen=True)
class UrdfJoint:
    """One ``<joint>``: its name, type, parent and child links, and limits.

    ``lower``/``upper`` are radians (revolute) or metres (prismatic); -inf/+inf for a continuous joint without limits
    and for fixed joints. ``velocity`` is rad/s or m/s (NaN for fixed joints).
    """

    name: str
    type: str
    parent: str
    child: str
    lower: float
    upper: float
    velocity: float


@dataclass(frozen=True)
class UrdfCollision:
    """One ``<collision>`` element of a link.

    ``kind`` is ``mesh``, ``box``, ``cylinder`` or ``sphere``; ``T_link_geometry`` is its (4, 4) float64 origin;
    ``params`` holds the mesh's resolved path and (3,) scale, or the primitive's dimensions in metres.
    """

    link: str
    kind: str
    T_link_geometry: np.ndarray
    params: dict


@dataclass(frozen=True)
class UrdfDescription:
    """What depthguard reads from a URDF besides pinocchio's kinematic model.

    Attributes:
        path: the URDF file.
        name: the ``<robot name=...>``.
        links: every link's name, in file order.
        joints: every joint, in file order.
        root: the link that is no joint's child.
        collisions: link name -> its collision elements (only links that have some), in file order.
        xml: the URDF's text as it was read and checked (pinocchio builds its model from it).
    """

    path: Path
    name: str
    links: tuple[str, ...]
    joints: tuple[UrdfJoint, ...]
    root: str
    collisions: dict[str, tuple[UrdfCollision, ...]]
    xml: str = field(default="", repr=False)

    @property
    def movable_joints(self) -> tuple[UrdfJoint, ...]:
        """The joints with one degree of freedom, in file order: the order of depthguard's joint vectors."""
        return tuple(joint for joint in self.joints if joint.type in MOVABLE_TYPES)

    def parent_joint(self, link: str) -> UrdfJoint | None:
        """The joint whose child is ``link`` (None for the root)."""
        for joint in self.joints:
            if joint.child == link:
                return joint
        return None

    def chain(self, link: str) -> list[UrdfJoint]:
        """The joints from the root to ``link``, root first."""
        joints = []
        joint = self.parent_joint(link)
        while joint is not None:
            joints.append(joint)
            joint = self.parent_joint(joint.parent)
        return joints[::-1]

    def moves(self, link: str) -> bool:
        """True if a movable joint lies between the root and ``link``."""
        return any(joint.type in MOVABLE_TYPES for joint in self.chain(link))

    def tip(self) -> str:
        """The end of the kinematic chain: the leaf link with the most joints above it; when several leaves tie
        (a hand with two fingers and a tool frame), their deepest common ancestor."""
        children = {joint.parent for joint in self.joints}
        leaves = [link for link in self.links if link not in children]
        depth = {link: len(self.chain(link)) for link in leaves}
        deepest = max(depth.values())
        tied = [link for link in leaves if depth[link] == deepest]
        if len(tied) == 1:
            return tied[0]
        paths = [[self.root] + [joint.child for joint in self.chain(link)] for link in tied]
        common = self.root
        for level in zip(*paths):
            if len(set(level)) != 1:
                break
            common = level[0]
        return common


# --------------------------------------------------------------------------------------------------------- parsing

#: A plain decimal number, as urdfdom and Python both read it the same way.
_NUMBER = re.compile(r"[+-]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][+-]?[0-9]+)?")

#: Ranges of _NUMBERS: (lowest, highest).
_ANY = (-math.inf, math.inf)
_NON_NEGATIVE = (0.0, math.inf)
_LENGTH = (-config.COORDINATE_LIMIT, config.COORDINATE_LIMIT)
_SIZE = (0.0, config.COORDINATE_LIMIT)

#: Every number of a URDF that urdfdom (pinocchio's parser) or depthguard reads: element tag -> attribute -> (how
#: many numbers, range), for elements inside a <link>'s <inertial>, <visual> and <collision>, a <joint>, and a
#: top-level <material>. Lengths in metres (joint limits: metres or radians) within config.COORDINATE_LIMIT, as a
#: rig's coordinates; sizes not below zero (a collision shape's must be positive: _collision).
_NUMBERS = {
    "origin": {"xyz": (3, _LENGTH), "rpy": (3, _ANY)},
    "axis": {"xyz": (3, _ANY)},
    "limit": {"lower": (1, _LENGTH), "upper": (1, _LENGTH), "effort": (1, _NON_NEGATIVE), "velocity": (1, _ANY)},
    "dynamics": {"damping": (1, _ANY), "friction": (1, _ANY)},
    "safety_controller": {key: (1, _ANY) for key in ("soft_lower_limit", "soft_upper_limit", "k_position",
                                                      "k_velocity")},
    "calibration": {key: (1, _ANY) for key in ("rising", "falling", "reference_position")},
    "mimic": {"multiplier": (1, _ANY), "offset": (1, _ANY)},
    "mass": {"value": (1, _NON_NEGATIVE)},
    "inertia": {key: (1, _ANY) for key in ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")},
    "box": {"size": (3, _SIZE)},
    "cylinder": {"radius": (1, _SIZE), "length": (1, _SIZE)},
    "sphere": {"radius": (1, _SIZE)},
    "mesh": {"scale": (3, _ANY)},
    "color": {"rgba": (4, _ANY)},
}


def _check_numbers(root_element, source: Path) -> None:
    """Every number ``_NUMBERS`` lists, wherever urdfdom reads it, is plain, finite and in range; else
    :class:`RobotError` naming the link, joint or material, the element and the attribute (module docstring)."""
    stack = []  # (element, what names its parent: "link 'arm' <collision>"); a stack, so any nesting depth will do
    for element in root_element:
        if element.tag in ("link", "joint", "material"):
            what = f"{element.tag} {element.get('name')!r}"
            stack.extend((child, what) for child in element
                         if element.tag != "link" or child.tag in ("inertial", "visual", "collision"))
    stack.reverse()  # the first fault in file order is the one reported
    while stack:
        element, what = stack.pop()
        for name, (count, (low, high)) in _NUMBERS.get(element.tag, {}).items():
            text = element.get(name)
            if text is None:
                continue
            tokens = text.split()
            values = [float(token) for token in tokens if _NUMBER.fullmatch(token)]
            if len(tokens) != count or len(values) != count or \
                    not all(math.isfinite(value) and low <= value <= high for value in values):
                if math.isinf(low) and math.isinf(high):
                    bounds = ""
                elif math.isinf(high):
                    bounds = f" >= {low:g}"
                else:
                    bounds = f" in [{low:g}, {high:g}]"
                numbers = "a finite number" if count == 1 else f"{count} finite numbers"
                raise RobotError(f"{what} <{element.tag} {name}> must be {numbers}{bounds}, got {short_repr(text)}",
                                 source=str(source))
        stack.extend((child, f"{what} <{element.tag}>") for child in reversed(element))


def _floats(text: str | None, count: int, *, what: str, source: Path, default=None) -> np.ndarray:
    if text is None:
        if default is None:
            raise RobotError(f"{what} is missing", source=str(source))
        return np.array(default, dtype=np.float64)
    try:
        values = np.array([float(x) for x in text.split()], dtype=np.float64)
    except ValueError:
        raise RobotError(f"{what} must be {count} numbers, got {text!r}", source=str(source)) from None
    if values.shape != (count,) or not np.all(np.isfinite(values)):
        raise RobotError(f"{what} must be {count} finite numbers, got {text!r}", source=str(source))
    return values


def _attr_float(element, name: str, *, what: str, source: Path, default: float | None = None) -> float:
    text = element.get(name)
    if text is None:
        if default is None:
            raise RobotError(f"{what} has no attribute {name!r}", source=str(source))
        return default
    try:
        value = float(text)
    except ValueError:
        raise RobotError(f"{what}: attribute {name!r} must be a number, got {text!r}", source=str(source)) from None
    if math.isnan(value):
        raise RobotError(f"{what}: attribute {name!r} is NaN", source=str(source))
    return value


def rpy_to_matrix(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """(3, 3) rotation of URDF roll-pitch-yaw angles (radians): Rz(yaw) @ Ry(pitch) @ Rx(roll), fixed axes."""
    cr, sr, cp, sp, cy, sy = math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch), math.cos(yaw), \
        math.sin(yaw)
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )


def _origin(element, *, what: str, source: Path) -> np.ndarray:
    """(4, 4) float64 transform of an element's ``<origin xyz rpy>`` (identity when absent)."""
    T = np.eye(4)
    origin = element.find("origin")
    if origin is None:
        return T
    xyz = _floats(origin.get("xyz"), 3, what=f"{what} <origin xyz>", source=source, default=(0.0, 0.0, 0.0))
    rpy = _floats(origin.get("rpy"), 3, what=f"{what} <origin rpy>", source=source, default=(0.0, 0.0, 0.0))
    T[:3, :3] = rpy_to_matrix(*rpy)
    T[:3, 3] = xyz
    return T


def parse_urdf(path, package_dirs=None) -> UrdfDescription:
    """Read the kinematic tree, limits and collision elements of the URDF file at ``path``.

    ``package_dirs``: directories in which ``package://`` mesh names are looked up (default: the URDF's directory).
    Raises :class:`RobotError` naming the file and the link or joint when the file is missing, is not a URDF, has a
    joint type depthguard does not accept (floating, planar), lacks the limits of a movable joint, or names a mesh
    file that does not exist.
    """
    path = check_path(path, "URDF file", RobotError)
    if not _exists(path):
        raise RobotError("URDF file not found", source=str(path))
    data = read_bytes(path, what="URDF file", max_bytes=config.MAX_URDF_BYTES, error=RobotError)
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError:
        raise RobotError("not UTF-8 text (a URDF is UTF-8 XML)", source=str(path)) from None
    _refuse_doctype(data, path)
    try:
        root_element = ET.fromstring(text)
    except ET.ParseError as exc:
        raise RobotError(f"not valid XML ({exc})", source=str(path)) from None
    if root_element.tag != "robot":
        raise RobotError(f"not a URDF: the root element is <{root_element.tag}>, not <robot>", source=str(path))
    _check_numbers(root_element, path)
    dirs = _package_dirs(path, package_dirs)

    links, collisions = [], {}
    for element in root_element.findall("link"):
        name = element.get("name")
        if not name:
            raise RobotError("a <link> has no name", source=str(path))
        if name in links:
            raise RobotError(f"link {name!r} is defined twice", source=str(path))
        links.append(name)
        items = tuple(_collision(c, name, path, dirs) for c in element.findall("collision"))
        if items:
            collisions[name] = items
    if not links:
        raise RobotError("the URDF has no <link>", source=str(path))

    joints = []
    for element in root_element.findall("joint"):
        joints.append(_joint(element, path, set(links)))
    names = [joint.name for joint in joints]
    duplicates = sorted({name for name in names if names.count(name) > 1})
    if duplicates:
        raise RobotError(f"joint names defined twice: {', '.join(duplicates)}", source=str(path))
    children = [joint.child for joint in joints]
    twice = sorted({child for child in children if children.count(child) > 1})
    if twice:
        raise RobotError(f"links with more than one parent joint: {', '.join(twice)}", source=str(path))
    roots = [link for link in links if link not in children]
    if len(roots) != 1:
        raise RobotError(f"the URDF must have exactly one root link, found {roots or 'none (a cycle)'}",
                         source=str(path))
    return UrdfDescription(path=path, name=root_element.get("name", ""), links=tuple(links), joints=tuple(joints),
                           root=roots[0], collisions=collisions, xml=text)


def _refuse_doctype(data: bytes, path: Path) -> None:
    """RobotError if the XML ``data`` has a document type declaration (a DTD: entity declarations, external
    entities). Scanned with expat before ElementTree parses it, so no declared entity is ever expanded."""

    def refuse(*_):
        raise RobotError("a URDF may not have a document type declaration (<!DOCTYPE ...>): DTDs and entities are "
                         "not read", source=str(path))

    scanner = xml.parsers.expat.ParserCreate()
    scanner.SetParamEntityParsing(xml.parsers.expat.XML_PARAM_ENTITY_PARSING_NEVER)
    scanner.StartDoctypeDeclHandler = refuse
    scanner.EntityDeclHandler = refuse
    scanner.ExternalEntityRefHandler = refuse
    try:
        scanner.Parse(data, True)
    except xml.parsers.expat.ExpatError as exc:
        raise RobotError(f"not valid XML ({exc})", source=str(path)) from None


def _exists(path: Path) -> bool:
    try:
        return path.exists()
    except (OSError, ValueError):  # a name too long, an embedded null byte
        return False



def _joint(element, path: Path, links: set) -> UrdfJoint:
    name = element.get("name")
    if not name:
        raise RobotError("a <joint> has no name", source=str(path))
    what = f"joint {name!r}"
    kind = element.get("type")
    if kind not in _ALL_TYPES:
        raise RobotError(f"{what}: unknown type {kind!r}", source=str(path))
    if kind in ("floating", "planar"):
        raise RobotError(f"{what}: joints of type {kind!r} are not supported (only fixed, revolute, continuous and "
                         "prismatic)", source=str(path))
    ends = {}
    for end in ("parent", "child"):
        tag = element.find(end)
        link = tag.get("link") if tag is not None else None
        if not link:
            raise RobotError(f"{what}: <{end} link=...> is missing", source=str(path))
        if link not in links:
            raise RobotError(f"{what}: its {end} link {link!r} is not defined", source=str(path))
        ends[end] = link
    lower, upper, velocity = -math.inf, math.inf, math.nan
    if kind in MOVABLE_TYPES:
        axis_element = element.find("axis")
        axis = _floats(axis_element.get("xyz") if axis_element is not None else None, 3, what=f"{what} <axis xyz>",
                       source=path, default=(1.0, 0.0, 0.0))
        if abs(np.linalg.norm(axis) - 1.0) > config.URDF_AXIS_TOLERANCE:
            # pinocchio normalises the axis, pybullet moves a prismatic joint by q times it: refuse the ambiguity.
            raise RobotError(f"{what}: <axis xyz> must be a unit vector, got {axis.tolist()} (norm "
                             f"{np.linalg.norm(axis):.6g})", source=str(path))
        limit = element.find("limit")
        if limit is None:
            raise RobotError(f"{what}: a {kind} joint needs <limit ... velocity=...> (depthguard bounds joint "
                             "velocities with it)", source=str(path))
        velocity = _attr_float(limit, "velocity", what=f"{what} <limit>", source=path)
        if not (velocity > 0 and math.isfinite(velocity)):
            raise RobotError(f"{what}: <limit velocity> must be positive and finite, got {velocity}",
                             source=str(path))
        if kind != "continuous":
            lower = _attr_float(limit, "lower", what=f"{what} <limit>", source=path, default=0.0)
            upper = _attr_float(limit, "upper", what=f"{what} <limit>", source=path, default=0.0)
            if not (math.isfinite(lower) and math.isfinite(upper) and lower <= upper):
                raise RobotError(f"{what}: <limit> needs finite lower <= upper, got [{lower}, {upper}]",
                                 source=str(path))
    return UrdfJoint(name=name, type=kind, parent=ends["parent"], child=ends["child"], lower=lower, upper=upper,
                     velocity=velocity)


def _collision(element, link: str, path: Path, dirs: list[Path]) -> UrdfCollision:
    what = f"link {link!r} <collision>"
    T = _origin(element, what=what, source=path)
    T.setflags(write=False)
    geometry = element.find("geometry")
    shapes = list(geometry) if geometry is not None else []
    if len(shapes) != 1:
        raise RobotError(f"{what}: <geometry> must hold exactly one shape", source=str(path))
    shape = shapes[0]
    kind = shape.tag
    if kind == "mesh":
        filename = shape.get("filename")
        if not filename:
            raise RobotError(f"{what}: <mesh> has no filename", source=str(path))
        scale = _floats(shape.get("scale"), 3, what=f"{what} <mesh scale>", source=path, default=(1.0, 1.0, 1.0))
        params = {"filename": filename, "path": resolve_mesh_path(filename, path, dirs, link=link), "scale": scale}
    elif kind == "box":
        size = _floats(shape.get("size"), 3, what=f"{what} <box size>", source=path)
        params = {"size": size}
    elif kind == "cylinder":
        params = {key: _attr_float(shape, key, what=f"{what} <cylinder>", source=path) for key in ("radius", "length")}
    elif kind == "sphere":
        params = {"radius": _attr_float(shape, "radius", what=f"{what} <sphere>", source=path)}
    else:
        raise RobotError(f"{what}: unsupported geometry <{kind}> (only mesh, box, cylinder, sphere)", source=str(path))
    for key, value in params.items():
        if key in ("size", "radius", "length") and not np.all(np.asarray(value) > 0):
            raise RobotError(f"{what}: <{kind} {key}> must be positive, got {value}", source=str(path))
    if kind == "mesh" and not np.all(params["scale"] > 0):
        raise RobotError(f"{what}: <mesh scale> must be 3 positive numbers (a zero flattens the mesh, a negative one "
                         f"mirrors it and flips its faces' winding), got {params['scale'].tolist()}", source=str(path))
    return UrdfCollision(link=link, kind=kind, T_link_geometry=T, params=params)


def _package_dirs(path: Path, package_dirs) -> list[Path]:
    if package_dirs is None:
        return [path.parent]
    if isinstance(package_dirs, (str, os.PathLike)):
        package_dirs = [package_dirs]
    if not isinstance(package_dirs, (list, tuple)) or not all(
            isinstance(d, (str, os.PathLike)) and "\0" not in str(d) for d in package_dirs):
        raise RobotError(f"package_dirs must be a folder or a list of folders, got {short_repr(package_dirs)}",
                         field="package_dirs", source=str(path))
    return [Path(d) for d in package_dirs]


def _allowed_roots(urdf_path: Path, package_dirs: list[Path]) -> list[Path]:
    """The folders mesh files may come from, symbolic links resolved: the URDF's own and the package_dirs."""
    roots = []
    for folder in [urdf_path.parent, *package_dirs]:
        try:
            roots.append(folder.resolve())
        except (OSError, RuntimeError):  # a symbolic link loop: nothing can be inside it
            continue
    return roots


def resolve_mesh_path(filename: str, urdf_path: Path, package_dirs: list[Path], *, link: str) -> Path:
    """The file a URDF mesh name refers to, symbolic links resolved; :class:`RobotError` naming the link and every
    place looked in, or the path when it leads out of the URDF's folder and the ``package_dirs`` (module docstring).
    """
    if "\0" in filename:
        raise RobotError(f"link {link!r}: collision mesh name contains a NUL character", source=str(urdf_path))
    if filename.startswith("package://"):
        rest = filename[len("package://"):]
        package, _, relative = rest.partition("/")
        candidates = []
        for directory in package_dirs:
            candidates.append(directory / rest)
            if directory.name == package and relative:
                candidates.append(directory / relative)
    elif filename.startswith("file://"):
        candidates = [Path(filename[len("file://"):])]
    else:
        candidates = [Path(filename) if os.path.isabs(filename) else urdf_path.parent / filename]
    for candidate in candidates:
        if _exists(candidate):  # a file, or something the bounded reader refuses by name (a FIFO, a device)
            resolved = candidate.resolve()
            roots = _allowed_roots(urdf_path, package_dirs)
            if not any(resolved.is_relative_to(root) for root in roots):
                raise RobotError(f"link {link!r}: collision mesh {filename!r} resolves to {str(resolved)!r}, outside "
                                 f"the URDF's folder and package_dirs ({', '.join(str(r) for r in roots)}); pass its "
                                 "folder in package_dirs to allow it", source=str(urdf_path))
            return resolved
    raise RobotError(f"link {link!r}: collision mesh {filename!r} not found (looked for "
                     f"{', '.join(str(c) for c in candidates)})", source=str(urdf_path))


# ---------------------------------------------------------------------------------------------------------- meshes


def collision_mesh(collisions: tuple[UrdfCollision, ...], source: Path) -> trimesh.Trimesh:
    """One mesh, in the link frame (metres), of all of a link's collision elements with their origins applied.

    Mesh files are read with trimesh (STL, OBJ, PLY, OFF, GLB; COLLADA needs ``pycollada``). Primitive shapes become
    meshes that contain them (see ``config.PRIMITIVE_CYLINDER_SECTIONS``). Every vertex, scaled and placed, must lie
    within ``config.COORDINATE_LIMIT`` of the link's origin on every axis; else :class:`RobotError` naming the link.
    """
    parts = []
    for item in collisions:
        if item.kind == "mesh":
            mesh = _load_mesh(item.params["path"], item.link, source)
            mesh.apply_scale(item.params["scale"])
        elif item.kind == "box":
            mesh = trimesh.creation.box(extents=item.params["size"])
        elif item.kind == "cylinder":
            mesh = _cylinder_mesh(item.params["radius"], item.params["length"])
        else:
            mesh = _sphere_mesh(item.params["radius"])
        mesh.apply_transform(item.T_link_geometry)
        reach = float(np.abs(mesh.vertices).max())
        if not reach <= config.COORDINATE_LIMIT:  # NaN too: a huge scale times a mesh's coordinates
            raise RobotError(f"link {item.link!r}: collision {item.kind} reaches {reach:.3g} m from the link's origin, "
                             f"beyond config.COORDINATE_LIMIT ({config.COORDINATE_LIMIT:g} m): check its scale and "
                             "units", source=str(source))
        parts.append(mesh)
    return parts[0] if len(parts) == 1 else trimesh.util.concatenate(parts)


def _load_mesh(mesh_path: Path, link: str, source: Path) -> trimesh.Trimesh:
    try:
        data = read_bytes(mesh_path, what="collision mesh", max_bytes=config.MAX_MESH_FILE_BYTES, error=RobotError)
    except RobotError as exc:
        raise RobotError(f"link {link!r}: collision mesh {str(mesh_path)!r}: {exc.message}", source=str(source)) \
            from None
    try:
        # From the bytes just read, by the suffix's format: trimesh opens no file of its own (no resolver).
        mesh = trimesh.load(io.BytesIO(data), file_type=mesh_path.suffix.lower().lstrip("."), force="mesh",
                            process=False)
    except Exception as exc:  # trimesh raises many kinds of errors for unreadable files
        raise RobotError(f"link {link!r}: cannot read collision mesh {str(mesh_path)!r} ({type(exc).__name__}: "
                         f"{exc})", source=str(source)) from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.vertices) == 0:
        raise RobotError(f"link {link!r}: collision mesh {str(mesh_path)!r} holds no triangles", source=str(source))
    if not np.all(np.isfinite(mesh.vertices)):
        raise RobotError(f"link {link!r}: collision mesh {str(mesh_path)!r} has non-finite vertices",
                         source=str(source))
    return mesh


def _cylinder_mesh(radius: float, length: float) -> trimesh.Trimesh:
    """A prism along z, centred at the origin, over a regular polygon circumscribed about the circle of ``radius``."""
    sections = config.PRIMITIVE_CYLINDER_SECTIONS
    return trimesh.creation.cylinder(radius=radius / math.cos(math.pi / sections), height=length, sections=sections)


def _sphere_mesh(radius: float) -> trimesh.Trimesh:
    """An icosphere scaled so that every face plane is at least ``radius`` from the centre."""
    mesh = trimesh.creation.icosphere(subdivisions=config.PRIMITIVE_SPHERE_SUBDIVISIONS, radius=1.0)
    inner = np.min(np.einsum("ij,ij->i", mesh.face_normals, mesh.triangles[:, 0]))
    mesh.apply_scale(radius / inner)
    return mesh
