"""depthguard.rendering judged against exact ray casting and against pybullet's own renderer.

Judges:

- the same triangles, ray-cast through every pixel centre in float64 (Möller-Trumbore, below): depth within
  ``DEPTH_TOL`` and the same label on every pixel whose centre is farther than ``EDGE_MARGIN`` pixels from every
  projected triangle edge. At an edge the renderer may go either way: llvmpipe snaps vertices to a 1/256-pixel grid
  before deciding coverage, so a centre within about 1/256 pixel of an edge may be decided for the other side (seen
  at 1.4e-3 pixel). Pixels within the margin are counted and must be few;
- :func:`depthguard.scenes.render_depth` (exact ray casting of boxes, spheres, capsules);
- pybullet's TinyRenderer (``getCameraImage``) drawing the KUKA iiwa's collision meshes, with the projection of
  ``tests/pybullet_scenes.py`` that puts our pixel (u, v) on TinyRenderer's sample.

Measured (``pytest -s`` prints them): largest depth error off the edges about 1e-5 m (float32), no label
disagreement off the edges; robot mask IoU against pybullet 0.9997-1.0 (a half-pixel shift of the projection gives
0.96-0.97).
"""

from __future__ import annotations

import os
import shutil
import xml.etree.ElementTree as ET

import numpy as np
import pybullet as p
import pybullet_data
import pytest
import trimesh
from scipy.spatial.transform import Rotation

import depthguard as dg
from depthguard.errors import DepthguardError, InputError, RenderingError
from depthguard.rendering import MeshInstance, Renderer, RenderResult, primitive_mesh, primitive_mesh_excess
from depthguard.scenes import Box, Capsule, Sphere, render_depth
from depthguard.transforms import look_at

#: Depth agreement with exact ray casting off the edges, metres.
DEPTH_TOL = 1e-4
#: Pixel centres nearer than this to a projected triangle edge may be covered either way, pixels.
EDGE_MARGIN = 4e-3
#: Two surfaces of different labels this close in depth (metres) on a pixel may be seen in either order.
TIE_TOL = 1e-5


@pytest.fixture(scope="module")
def renderer():
    r = Renderer()
    yield r
    r.release()


# ------------------------------------------------------------------------------------------------- NumPy judges

def pixel_rays(camera) -> np.ndarray:
    """(h*w, 3) optical-frame directions through the pixel centres, z = 1 (so a ray parameter is a depth)."""
    u, v = camera.pixel_grid()
    return np.stack([(u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, np.ones_like(u)], -1).reshape(-1, 3)


def ray_cast_triangles(camera, triangles_world) -> np.ndarray:
    """Möller-Trumbore in float64: (t, h*w) depth at which each pixel-centre ray meets each triangle (inf: miss)."""
    d = pixel_rays(camera)
    triangles = camera.world_to_camera(triangles_world.reshape(-1, 3)).reshape(-1, 3, 3)
    hits = np.full((len(triangles), len(d)), np.inf)
    for k, (a, b, c) in enumerate(triangles):
        e1, e2 = b - a, c - a
        p = np.cross(d, e2)
        det = p @ e1
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / det
            s = (p @ -a) * inv
            q = np.cross(-a, e1)
            r = (d @ q) * inv
            t = (e2 @ q) * inv
        hit = (det != 0) & (s >= 0) & (r >= 0) & (s + r <= 1) & (t > 0)
        hits[k] = np.where(hit, t, np.inf)
    return hits


def edge_distance(camera, triangles_world) -> np.ndarray:
    """(h, w) distance in pixels from each pixel centre to the nearest projected triangle edge (all vertices must
    lie in front of the camera)."""
    u, v = camera.pixel_grid()
    centres = np.stack([u.ravel(), v.ravel()], -1)
    pu, pv, z = camera.project(camera.world_to_camera(triangles_world.reshape(-1, 3)))
    assert np.all(z > 0)
    corners = np.stack([pu, pv], -1).reshape(-1, 3, 2)
    best = np.full(len(centres), np.inf)
    for tri in corners:
        for i in range(3):
            a, ab = tri[i], tri[(i + 1) % 3] - tri[i]
            s = np.clip(((centres - a) @ ab) / max(ab @ ab, 1e-300), 0.0, 1.0)
            best = np.minimum(best, np.linalg.norm(centres - (a + s[:, None] * ab), axis=1))
    return best.reshape(camera.shape)


def random_camera(rng, width, height, eye, target) -> dg.PinholeCamera:
    """Non-square pixels, principal point off-centre."""
    f = rng.uniform(0.7, 1.4) * width
    return dg.PinholeCamera("cam", width, height, f, f * rng.uniform(0.8, 1.25),
                            width / 2 + rng.uniform(-0.15, 0.15) * width,
                            height / 2 + rng.uniform(-0.15, 0.15) * height, look_at(eye, target))


def random_pose(rng, spread) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.random(random_state=rng.integers(2**31)).as_matrix()
    T[:3, 3] = rng.uniform(-spread, spread, 3)
    return T


BOX_CORNERS = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=float)
BOX_FACES = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                      [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
TETRA_FACES = np.array([[0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3]])


def random_meshes(rng, camera, count):
    """Random boxes and tetrahedra around the camera's target, and one large thin plate seen at 80-88 degrees from
    its normal. Returns [(vertices in the mesh frame, faces, T_world_mesh)]."""
    meshes = []
    for _ in range(count):
        if rng.random() < 0.5:
            meshes.append((BOX_CORNERS * rng.uniform(0.03, 0.4, 3), BOX_FACES, random_pose(rng, 0.8)))
        else:
            meshes.append((rng.normal(size=(4, 3)) * 0.3, TETRA_FACES, random_pose(rng, 0.8)))
    # a plate whose normal makes 80-88 degrees with the view direction
    eye, view = camera.T_world_camera[:3, 3], camera.T_world_camera[:3, 2]
    theta = np.radians(rng.uniform(80.0, 88.0))
    side = np.cross(view, rng.normal(size=3))
    side /= np.linalg.norm(side)
    normal = -np.cos(theta) * view + np.sin(theta) * side
    a = np.cross(normal, rng.normal(size=3))
    a /= np.linalg.norm(a)
    T = np.eye(4)
    T[:3, :3] = np.stack([a, np.cross(normal, a), normal], 1)
    T[:3, 3] = eye + view * np.linalg.norm(eye) * rng.uniform(0.8, 1.0)
    meshes.append((BOX_CORNERS * [0.8, 0.8, 0.002], BOX_FACES, T))
    return meshes


# ------------------------------------------------------------------------------------------- exactness: triangles

@pytest.mark.parametrize("seed, width, height", [(0, 161, 121), (1, 128, 97), (2, 203, 150), (3, 97, 131)])
def test_triangles_match_exact_ray_casting(renderer, seed, width, height):
    rng = np.random.default_rng(seed)
    direction = rng.normal(size=3)
    eye = 2.2 * direction / np.linalg.norm(direction)
    camera = random_camera(rng, width, height, eye, rng.uniform(-0.2, 0.2, 3))
    meshes = random_meshes(rng, camera, count=8)
    instances, triangles, labels = [], [], []
    for label, (vertices, faces, T) in enumerate(meshes):
        instances.append(MeshInstance(renderer.add_mesh(vertices, faces), T, label=label, albedo=0.7))
        world = vertices @ T[:3, :3].T + T[:3, 3]
        triangles.append(world[faces])
        labels += [label] * len(faces)
    triangles, labels = np.concatenate(triangles), np.array(labels)

    hits = ray_cast_triangles(camera, triangles)
    first = np.argmin(hits, axis=0)
    pixels = np.arange(hits.shape[1])
    exact = hits[first, pixels]
    exact_label = np.where(np.isfinite(exact), labels[first], -1).reshape(camera.shape)
    other = np.where(labels[:, None] != labels[first][None, :], hits, np.inf).min(axis=0)
    with np.errstate(invalid="ignore"):
        tie = (np.isfinite(other) & (other - exact < TIE_TOL)).reshape(camera.shape)
    exact = np.where(np.isfinite(exact), exact, 0.0).reshape(camera.shape)

    result = renderer.render(camera, instances)
    assert isinstance(result, RenderResult)
    assert result.depth.shape == camera.shape and result.depth.dtype == np.float32
    assert result.label.dtype == np.int32 and result.intensity.dtype == np.float32
    off_edge = edge_distance(camera, triangles) > EDGE_MARGIN
    error = np.abs(result.depth.astype(np.float64) - exact)
    covered = exact > 0
    disagree = (error > DEPTH_TOL) | ((result.label != exact_label) & ~tie)
    n_edge, n_disagree = np.count_nonzero(~off_edge), np.count_nonzero(disagree)
    print(f"\n{width}x{height}: {covered.sum()} covered pixels; {n_edge} within {EDGE_MARGIN} px of an edge, "
          f"{n_disagree} of them disagree; max depth error off the edges {error[off_edge].max():.2e} m; "
          f"ties {np.count_nonzero(tie & off_edge)}")
    assert covered.sum() > 0.1 * covered.size  # the scene is not empty
    assert error[off_edge].max() <= DEPTH_TOL
    assert np.array_equal(result.label[off_edge & ~tie], exact_label[off_edge & ~tie])
    assert n_disagree <= 0.001 * covered.sum() + 2  # the pixels that went the other way at an edge are few
    # the depth-only path gives the same depth
    assert np.array_equal(renderer.render_depth(camera, instances), result.depth)


def test_projection_puts_pixel_centres_on_the_rays(renderer):
    """A tiny triangle around the ray of one pixel centre lights exactly that pixel (odd size, off-centre cx, cy)."""
    camera = dg.PinholeCamera("c", 33, 21, 40.0, 55.0, 10.3, 12.8, np.eye(4))
    for u, v in [(0, 0), (32, 20), (7, 15), (20, 3)]:
        z = 2.0
        x, y = (u - camera.cx) / camera.fx * z, (v - camera.cy) / camera.fy * z
        s = 0.2 * z / camera.fx  # a fifth of a pixel
        vertices = np.array([[x - s, y - s, z], [x + s, y - s, z], [x, y + s, z]])
        mesh = renderer.add_mesh(vertices, [[0, 1, 2]])
        depth = renderer.render_depth(camera, [MeshInstance(mesh, np.eye(4))])
        assert list(zip(*np.nonzero(depth))) == [(v, u)]
        assert depth[v, u] == pytest.approx(z, rel=1e-6)


# -------------------------------------------------------------------------------------------- primitives

def primitive_scene(rng):
    camera = random_camera(rng, 160, 120, [2.2, -1.5, 1.6], [0.0, 0.0, 0.5])
    boxes = [Box(tuple(rng.uniform(-0.5, 0.5, 3) + [0, 0, 0.5]), tuple(rng.uniform(0.05, 0.3, 3)),
                 Rotation.random(random_state=int(rng.integers(2**31))).as_matrix()) for _ in range(4)]
    return camera, boxes


@pytest.mark.parametrize("seed", [0, 1])
def test_boxes_match_scenes_render_depth(renderer, seed):
    camera, boxes = primitive_scene(np.random.default_rng(seed))
    instances, triangles = [], []
    for box in boxes:
        vertices, faces = primitive_mesh(box)
        assert len(faces) == 12 and primitive_mesh_excess(box) == 0.0
        instances.append(MeshInstance(renderer.add_mesh(vertices, faces, closed=True), np.eye(4)))
        triangles.append(vertices[faces])
    exact = render_depth(camera, boxes).astype(np.float64)
    depth = renderer.render_depth(camera, instances)
    off_edge = edge_distance(camera, np.concatenate(triangles)) > EDGE_MARGIN
    assert (exact > 0).sum() > 1000
    assert np.abs(depth - exact)[off_edge].max() <= DEPTH_TOL


@pytest.mark.parametrize("kind", ["sphere", "capsule"])
def test_curved_primitives_are_circumscribed(renderer, kind):
    """The mesh lies between the true solid and the solid inflated by primitive_mesh_excess, so its depth on every
    pixel lies between theirs (exact ray casting of both) and it covers every pixel the true shape covers."""
    rng = np.random.default_rng(7)
    camera = random_camera(rng, 180, 140, [1.5, -1.2, 1.4], [0.0, 0.0, 0.5])
    if kind == "sphere":
        shapes = [Sphere(tuple(rng.uniform(-0.4, 0.4, 3) + [0, 0, 0.5]), float(rng.uniform(0.1, 0.3)))
                  for _ in range(3)]
    else:
        shapes = []
        for _ in range(3):
            p0 = rng.uniform(-0.4, 0.4, 3) + [0, 0, 0.5]
            shapes.append(Capsule(tuple(p0), tuple(p0 + rng.normal(size=3) * 0.2), float(rng.uniform(0.05, 0.15))))
    for segments in (12, 48):
        instances, inflated = [], []
        for shape in shapes:
            vertices, faces = primitive_mesh(shape, segments=segments)
            instances.append(MeshInstance(renderer.add_mesh(vertices, faces, closed=True), np.eye(4)))
            grow = primitive_mesh_excess(shape, segments)
            assert 0 < grow < (0.07 if segments == 12 else 0.0043) * shape.radius
            if kind == "sphere":
                inflated.append(Sphere(shape.center, shape.radius + grow))
            else:
                inflated.append(Capsule(shape.p0, shape.p1, shape.radius + grow))
            # every vertex lies within the inflated shape and outside (or on) the true one
            assert np.all(shape.distance(vertices) <= grow * (1 + 1e-9))
        depth = renderer.render_depth(camera, instances).astype(np.float64)
        inner = render_depth(camera, shapes).astype(np.float64)
        outer = render_depth(camera, inflated).astype(np.float64)
        assert np.all(depth[inner > 0] > 0)  # covers every pixel the true shape covers
        hit = inner > 0
        assert np.all(depth[hit] <= inner[hit] + 1e-5)  # never behind the true surface: conservative
        seen = (depth > 0) & (outer > 0)
        assert np.all(depth[seen] >= outer[seen] - 1e-5)  # never in front of the inflated surface
        assert np.count_nonzero((depth > 0) & (outer == 0)) <= 3  # only snapping at the outer silhouette


def test_primitive_mesh_rejects_bad_input():
    with pytest.raises(InputError):
        primitive_mesh(Sphere((0, 0, 0), -1.0))
    with pytest.raises(InputError):
        primitive_mesh(Sphere((0, 0, 0), 1.0), segments=3)
    with pytest.raises(InputError):
        primitive_mesh("box")


# -------------------------------------------------------------------------------------- farthest surface, culling

def test_depth_max(renderer):
    # a single planar face seen frontally: nearest and farthest coincide
    camera = dg.PinholeCamera("c", 81, 61, 70.0, 75.0, 41.2, 29.7, np.eye(4))
    quad = renderer.add_mesh([[-1, -1, 2.5], [1, -1, 2.5], [1, 1, 2.5], [-1, 1, 2.5]], [[0, 1, 2], [0, 2, 3]])
    near = renderer.render_depth(camera, [MeshInstance(quad, np.eye(4))])
    far = renderer.render_depth_max(camera, [MeshInstance(quad, np.eye(4))])
    assert (near > 0).sum() > 1000 and np.array_equal(near, far)
    assert np.all(near[near > 0] == np.float32(2.5))
    # boxes and a sphere: the farthest surface equals the last exact hit of the same triangles off the edges,
    # with and without culling
    camera, boxes = primitive_scene(np.random.default_rng(0))
    meshes = [primitive_mesh(b) for b in boxes] + [primitive_mesh(Sphere((0.0, 0.0, 0.5), 0.2), segments=12)]
    triangles = np.concatenate([v[f] for v, f in meshes])
    hits = ray_cast_triangles(camera, triangles)
    last = np.where(np.isfinite(hits), hits, -np.inf).max(axis=0)
    exact = np.where(np.isfinite(last), last, 0.0).reshape(camera.shape)
    off_edge = edge_distance(camera, triangles) > EDGE_MARGIN
    for closed in (False, True):
        instances = [MeshInstance(renderer.add_mesh(v, f, closed=closed), np.eye(4)) for v, f in meshes]
        near = renderer.render_depth(camera, instances)
        far = renderer.render_depth_max(camera, instances)
        assert np.array_equal(near > 0, far > 0) and (near > 0).sum() > 1000
        assert np.all(far >= near)
        assert np.any(far > near + 0.05)
        assert np.abs(far - exact)[off_edge].max() <= DEPTH_TOL


def test_closed_meshes_render_the_same_with_culling(renderer):
    """closed=True culls the faces turned away; the images must not change, also with the camera inside a mesh."""
    rng = np.random.default_rng(11)
    camera, boxes = primitive_scene(rng)
    shapes = boxes + [Sphere((0.1, 0.2, 0.6), 0.25), Capsule((0.0, -0.3, 0.2), (0.3, 0.1, 0.9), 0.1)]
    meshes = [primitive_mesh(s, segments=16) for s in shapes]
    T = random_pose(rng, 0.1)
    open_ = [MeshInstance(renderer.add_mesh(v, f), T, label=i) for i, (v, f) in enumerate(meshes)]
    closed = [MeshInstance(renderer.add_mesh(v, f, closed=True), T, label=i) for i, (v, f) in enumerate(meshes)]
    inside = camera.replace(T_world_camera=look_at(T[:3, :3] @ [0.1, 0.2, 0.6] + T[:3, 3], [0, 0, 0]))
    for cam in (camera, inside):
        a, b = renderer.render(cam, open_), renderer.render(cam, closed)
        assert (a.depth > 0).sum() > 100
        assert np.array_equal(a.depth, b.depth) and np.array_equal(a.label, b.label)
        assert np.array_equal(renderer.render_depth_max(cam, open_), renderer.render_depth_max(cam, closed))
    # the camera inside the sphere sees its inside everywhere
    assert np.all(renderer.render_depth(inside, closed[4:5]) > 0)


def test_depth_passes_drawn_in_their_rectangle_equal_the_whole_image(renderer):
    """The depth passes clear, rasterise and read back only the pixels the instances' bounding spheres can cover;
    the image is bit for bit the one drawn whole: a small shape in the middle, shapes cut by the image's edge, one
    behind the camera, one reaching the near plane (drawn whole), and none at all."""
    rng = np.random.default_rng(21)
    camera = random_camera(rng, 160, 120, [2.2, -1.5, 1.6], [0.0, 0.0, 0.5])
    shapes = [Sphere((0.0, 0.0, 0.5), 0.08), Capsule((-0.2, 0.1, 0.3), (0.1, -0.1, 0.7), 0.06),
              Box((1.2, 1.4, 0.8), (0.3, 0.2, 0.4)), Box((4.0, -3.0, 2.5), (0.2, 0.2, 0.2))]
    closed = [MeshInstance(renderer.add_mesh(*primitive_mesh(shape, 16), closed=True), np.eye(4)) for shape in shapes]
    eye = camera.T_world_camera[:3, 3]
    near = MeshInstance(renderer.add_mesh(*primitive_mesh(Sphere(tuple(eye), 0.3), 16), closed=True), np.eye(4))
    cropped = 0
    for instances in (closed[:1], closed[:2], closed[1:3], closed[3:], closed, closed[:1] + [near], []):
        rect = renderer._drawn_rect(camera, instances)
        cropped += rect is not None and rect[2] * rect[3] < camera.width * camera.height
        for kind in (dict(nearest=True), dict(nearest=False), dict(nearest=True, back_faces=True)):
            part = renderer._depth_pass(camera, instances, crop=True, **kind)
            whole = renderer._depth_pass(camera, instances, crop=False, **kind)
            assert np.array_equal(part, whole), (len(instances), kind)
            assert (whole > 0).any() == bool(instances and instances != closed[3:])
    assert cropped >= 3


def test_closed_is_checked(renderer):
    vertices, faces = primitive_mesh(Box((0, 0, 0), (1, 1, 1)))
    with pytest.raises(InputError, match="watertight"):
        renderer.add_mesh(vertices, faces[1:], closed=True)
    with pytest.raises(InputError, match="counter-clockwise"):
        renderer.add_mesh(vertices, faces[:, ::-1], closed=True)


# --------------------------------------------------------------------------------------------------- intensity

def test_intensity_is_lambertian(renderer):
    from depthguard import config

    camera = dg.PinholeCamera("c", 64, 48, 40.0, 40.0, 30.0, 20.0, np.eye(4))
    plane = renderer.add_mesh([[-9, -9, 2], [9, -9, 2], [9, 9, 2], [-9, 9, 2]], [[0, 1, 2], [0, 2, 3]])
    result = renderer.render(camera, [MeshInstance(plane, np.eye(4), label=5, albedo=0.8)])
    rays = pixel_rays(camera)
    cosine = (1.0 / np.linalg.norm(rays, axis=1)).reshape(camera.shape)  # normal (0, 0, -1) against the ray
    expected = 0.8 * (config.RENDER_AMBIENT + (1 - config.RENDER_AMBIENT) * cosine)
    assert np.abs(result.intensity - expected).max() < 1e-4
    assert np.all(result.label == 5) and np.all(result.depth == np.float32(2.0))
    empty = renderer.render(camera, [])
    assert np.all(empty.depth == 0) and np.all(empty.label == -1) and np.all(empty.intensity == 0)


# --------------------------------------------------------------------------------------- the KUKA iiwa vs pybullet

def _iiwa_collision_links(urdf_path):
    """{link name: (mesh path, T_link_collision)} from the URDF's <collision> elements."""
    links = {}
    for link in ET.parse(urdf_path).getroot().findall("link"):
        collision = link.find("collision")
        if collision is None:
            continue
        origin = collision.find("origin")
        T = np.eye(4)
        if origin is not None:
            T[:3, :3] = Rotation.from_euler("xyz", [float(x) for x in origin.get("rpy", "0 0 0").split()]).as_matrix()
            T[:3, 3] = [float(x) for x in origin.get("xyz", "0 0 0").split()]
        mesh = collision.find("geometry/mesh")
        links[link.get("name")] = (os.path.join(os.path.dirname(urdf_path), mesh.get("filename")), T)
    return links


def test_kuka_iiwa_mask_matches_pybullet(renderer, tmp_path):
    """pybullet draws the URDF's visual meshes; a copy of the URDF whose visuals are the collision STL files makes
    it draw exactly the geometry depthguard renders. Link frames from pybullet's forward kinematics."""
    import pybullet_scenes as ps

    source = os.path.join(pybullet_data.getDataPath(), "kuka_iiwa")
    shutil.copytree(os.path.join(source, "meshes"), tmp_path / "meshes")
    text = open(os.path.join(source, "model.urdf")).read()
    assert text.count(".obj") == 8
    (tmp_path / "model.urdf").write_text(text.replace(".obj", ".stl"))
    links = _iiwa_collision_links(str(tmp_path / "model.urdf"))
    assert len(links) == 8
    meshes = {}
    for name, (path, T_link_collision) in links.items():
        mesh = trimesh.load(path, force="mesh")
        meshes[name] = (renderer.add_mesh(mesh.vertices, mesh.faces), T_link_collision)

    client = p.connect(p.DIRECT)
    try:
        body = p.loadURDF(str(tmp_path / "model.urdf"), useFixedBase=True, physicsClientId=client)
        joints = {p.getJointInfo(body, j, physicsClientId=client)[12].decode(): j
                  for j in range(p.getNumJoints(body, physicsClientId=client))}
        rng = np.random.default_rng(0)
        for trial in range(3):
            for j in range(7):
                p.resetJointState(body, j, rng.uniform(-1.5, 1.5), physicsClientId=client)
            eye = rng.uniform([1.2, -1.2, 0.5], [2.0, 1.2, 1.8])
            camera = dg.PinholeCamera("cam", 640, 480, 500.0, 540.0, 330.2, 230.7, look_at(eye, [0, 0, 0.6]))
            instances = []
            for name, (mesh, T_link_collision) in meshes.items():
                if name in joints:
                    state = p.getLinkState(body, joints[name], computeForwardKinematics=True,
                                           physicsClientId=client)
                    position, orientation = state[4], state[5]  # the URDF link frame
                else:  # the base: pybullet reports its inertial frame
                    com_position, com_orientation = p.getBasePositionAndOrientation(body, physicsClientId=client)
                    local_position, local_orientation = p.getDynamicsInfo(body, -1, physicsClientId=client)[3:5]
                    inv_position, inv_orientation = p.invertTransform(local_position, local_orientation)
                    position, orientation = p.multiplyTransforms(com_position, com_orientation, inv_position,
                                                                 inv_orientation)
                T_world_link = np.eye(4)
                T_world_link[:3, :3] = np.array(p.getMatrixFromQuaternion(orientation)).reshape(3, 3)
                T_world_link[:3, 3] = position
                instances.append(MeshInstance(mesh, T_world_link @ T_link_collision, label=1))
            pybullet_depth, segmentation = ps.render_depth(client, camera)
            ours = renderer.render(camera, instances)
            theirs, mine = segmentation >= 0, ours.label >= 0
            iou = np.count_nonzero(theirs & mine) / np.count_nonzero(theirs | mine)
            both = theirs & mine
            gap = np.abs(pybullet_depth[both] - ours.depth[both])
            print(f"\niiwa pose {trial}: IoU {iou:.4f} ({np.count_nonzero(mine)} pixels, "
                  f"{np.count_nonzero(theirs ^ mine)} differ), depth gap median {np.median(gap):.1e} m, "
                  f"p99 {np.percentile(gap, 99):.1e} m")
            assert np.count_nonzero(mine) > 3000
            assert iou >= 0.98
            assert np.median(gap) < 1e-5 and np.percentile(gap, 99) < 1e-4
    finally:
        p.disconnect(client)


# ----------------------------------------------------------------------------------------- errors and contexts

def test_no_egl_is_a_clear_error():
    with pytest.raises(RenderingError, match="libegl1") as info:
        Renderer(libegl="libEGL_does_not_exist.so.1")
    assert isinstance(info.value, DepthguardError)
    assert "libEGL_does_not_exist.so.1" in str(info.value)


def test_bad_inputs(renderer):
    with pytest.raises(InputError):
        renderer.add_mesh(np.zeros((3, 2)), [[0, 1, 2]])
    with pytest.raises(InputError):
        renderer.add_mesh([[0, 0, 0], [1, 0, 0], [np.nan, 1, 0]], [[0, 1, 2]])
    with pytest.raises(InputError):
        renderer.add_mesh(np.eye(3), [[0, 1, 3]])
    with pytest.raises(InputError):
        renderer.add_mesh(np.eye(3), [[0.0, 1.0, 2.0]])
    with pytest.raises(InputError):
        renderer.add_mesh(np.eye(3), np.zeros((0, 3), int))
    mesh = renderer.add_mesh(np.eye(3), [[0, 1, 2]])
    with pytest.raises(InputError):
        MeshInstance(mesh, np.eye(3))
    with pytest.raises(InputError):
        MeshInstance(mesh, np.full((4, 4), np.inf))
    with pytest.raises(InputError):
        MeshInstance(mesh, np.eye(4), label=-1)
    with pytest.raises(InputError):
        MeshInstance(mesh, np.eye(4), albedo=1.5)
    with pytest.raises(InputError):
        MeshInstance(mesh, np.diag([1.0, 1.0, 0.0, 1.0]))
    camera = dg.PinholeCamera("c", 8, 6, 5.0, 5.0, 4.0, 3.0, np.eye(4))
    with pytest.raises(InputError, match="mesh_id"):
        renderer.render_depth(camera, [MeshInstance(10**6, np.eye(4))])
    with pytest.raises(InputError):
        renderer.render(camera, [np.eye(4)])
    with pytest.raises(InputError, match="PinholeCamera"):
        renderer.render_depth_max("cam", [])
    renderer.remove_mesh(mesh)
    with pytest.raises(InputError, match="removed"):
        renderer.render_depth(camera, [MeshInstance(mesh, np.eye(4))])


def test_two_renderers_keep_their_own_context(renderer):
    camera = dg.PinholeCamera("c", 40, 30, 30.0, 30.0, 20.0, 15.0, np.eye(4))
    box = primitive_mesh(Box((0.0, 0.0, 2.0), (0.5, 0.4, 0.3)))
    mine = [MeshInstance(renderer.add_mesh(*box), np.eye(4))]
    before = renderer.render_depth(camera, mine)
    with Renderer() as other:
        theirs = [MeshInstance(other.add_mesh(*box), np.eye(4) @ np.diag([1, 1, 1, 1.0]))]
        theirs_depth = other.render_depth(camera.replace(width=50), theirs)
        assert np.array_equal(renderer.render_depth(camera, mine), before)
        assert theirs_depth.shape == (30, 50)
    assert np.array_equal(renderer.render_depth(camera, mine), before)
    released = Renderer()
    released.release()
    with pytest.raises(RenderingError):
        released.render_depth(camera, [])
