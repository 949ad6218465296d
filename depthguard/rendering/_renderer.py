"""Exact depth, label and intensity images of triangle meshes, rendered with OpenGL (EGL, headless).

How a pixel is made exact
-------------------------
depthguard's pixel (u, v) has its centre at image coordinates (u, v) (design §1); OpenGL samples window pixel
(i, j) at its centre (i + 1/2, j + 1/2). The vertex shader maps an optical-frame point (x, y, z) to

    x_ndc = (2 fx / W) x/z + (2 cx + 1) / W - 1,      y_ndc = (2 fy / H) y/z + (2 cy + 1) / H - 1,

so the window coordinates are exactly (u + 1/2, v + 1/2): OpenGL samples every pixel on the ray through its
centre. The image is not flipped vertically: window row j *is* image row v = j, and since ``glReadPixels`` returns
rows from window row 0 upwards, the read-back buffer is already in image order (top row first). The image is the
mirror of OpenGL's usual orientation, which flips the apparent winding of triangles; face culling (below) accounts
for it.

The depth reported is the fragment's optical-frame z, interpolated perspective-correctly from the vertices into a
float32 colour attachment. z is an affine function on a planar triangle, and perspective-correct interpolation
reproduces such a function exactly, so the value is the z where the pixel-centre ray meets the triangle, up to
float32 rounding. The non-linear depth buffer is only used to decide which surface is in front (see ``_gl.py``:
a float32 buffer holding near / z, no far plane).

What is not exact: which triangle covers a pixel whose centre lies on (within about 1/256 pixel of, llvmpipe's
sub-pixel grid) an edge.

Speed: on llvmpipe the cost is per triangle (about 0.3-0.5 microseconds for each one that reaches the rasteriser),
so a mesh declared ``closed`` (watertight, wound outward) has the faces that turn away from the camera culled
before rasterisation. That is exact for the nearest surface only when the camera is outside the mesh, so the
renderer culls them only when the mesh's bounding sphere lies wholly beyond the near plane; for the farthest
surface (``render_depth_max``) the faces turned towards the camera are culled, which is exact wherever the camera
is.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import moderngl
import numpy as np

from depthguard import config
from depthguard.cameras import PinholeCamera
from depthguard.errors import InputError, RenderingError
from depthguard.rendering._gl import GLContext
from depthguard.validation import NOT_A_NUMBER

_VERTEX_HEADER = """
#version 330
uniform mat4 T_camera_mesh;   // mesh frame -> optical frame
uniform vec4 projection;      // (2 fx/W, (2 cx + 1)/W - 1, 2 fy/H, (2 cy + 1)/H - 1)
uniform float near;           // metres
in vec3 position_mesh;
"""

_DEPTH_VERTEX = _VERTEX_HEADER + """
out float z_camera;
void main() {
    vec4 p = T_camera_mesh * vec4(position_mesh, 1.0);
    z_camera = p.z;
    gl_Position = vec4(projection.x * p.x + projection.y * p.z, projection.z * p.y + projection.w * p.z, near, p.z);
}
"""

_DEPTH_FRAGMENT = """
#version 330
in float z_camera;
layout(location = 0) out float depth;
void main() {
    depth = z_camera;
}
"""

_FULL_VERTEX = _VERTEX_HEADER + """
out vec3 p_camera;
void main() {
    vec4 p = T_camera_mesh * vec4(position_mesh, 1.0);
    p_camera = p.xyz;
    gl_Position = vec4(projection.x * p.x + projection.y * p.z, projection.z * p.y + projection.w * p.z, near, p.z);
}
"""

_FULL_FRAGMENT = """
#version 330
in vec3 p_camera;
uniform float label_code;     // label + 1 (0 is the cleared value: nothing)
uniform float albedo;
uniform float ambient;
layout(location = 0) out float depth;
layout(location = 1) out float label;
layout(location = 2) out float intensity;
void main() {
    depth = p_camera.z;
    label = label_code;
    // The points of a 2x2 quad of fragments lie in the triangle's plane, so their differences span it.
    vec3 normal = cross(dFdx(p_camera), dFdy(p_camera));
    float n = length(normal);
    float cosine = n > 0.0 ? abs(dot(normal, p_camera)) / (n * length(p_camera)) : 1.0;
    intensity = clamp(albedo * (ambient + (1.0 - ambient) * cosine), 0.0, 1.0);
}
"""

#: Largest label (labels are stored as label + 1 in a float32 attachment, exact below 2**24).
MAX_LABEL = 2**24 - 2


@dataclass(frozen=True, eq=False)
class MeshInstance:
    """One placement of an uploaded mesh.

    Attributes:
        mesh_id: the handle :meth:`Renderer.add_mesh` returned.
        T_world_mesh: (4, 4) float, maps the mesh's frame (metres) to the world frame (metres). Usually a rigid
            transform; an affine one with a scale (a URDF mesh scale) is accepted too. Last row [0, 0, 0, 1].
        label: int in [0, 2**24 - 2], written to :attr:`RenderResult.label` where this instance is seen.
        albedo: float in [0, 1], the surface's reflectance in :attr:`RenderResult.intensity`.
    """

    mesh_id: int
    T_world_mesh: np.ndarray
    label: int = 0
    albedo: float = 0.5

    def __post_init__(self):
        if isinstance(self.mesh_id, bool) or not isinstance(self.mesh_id, (int, np.integer)) or self.mesh_id < 0:
            raise InputError(f"mesh_id must be a handle from Renderer.add_mesh, got {self.mesh_id!r}")
        object.__setattr__(self, "mesh_id", int(self.mesh_id))
        try:
            T = np.array(self.T_world_mesh, dtype=np.float64)
        except NOT_A_NUMBER:
            raise InputError(f"T_world_mesh must be a (4, 4) matrix of numbers, got {self.T_world_mesh!r}") from None
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise InputError(f"T_world_mesh must be a finite (4, 4) matrix, got shape {T.shape}")
        if not np.array_equal(T[3], [0.0, 0.0, 0.0, 1.0]):
            raise InputError(f"T_world_mesh's last row must be [0, 0, 0, 1], got {T[3].tolist()}")
        (a, b, c), (d, e, f), (g, h, i) = T[:3, :3].tolist()
        if abs(a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g)) < 1e-12:  # det (np.linalg: slow)
            raise InputError("T_world_mesh is singular")
        T.setflags(write=False)
        object.__setattr__(self, "T_world_mesh", T)
        if isinstance(self.label, bool) or not isinstance(self.label, (int, np.integer)) or not (
                0 <= self.label <= MAX_LABEL):
            raise InputError(f"label must be an integer in [0, {MAX_LABEL}], got {self.label!r}")
        object.__setattr__(self, "label", int(self.label))
        albedo = float(self.albedo)
        if not (0.0 <= albedo <= 1.0):
            raise InputError(f"albedo must lie in [0, 1], got {self.albedo!r}")
        object.__setattr__(self, "albedo", albedo)


@dataclass(frozen=True, eq=False)
class RenderResult:
    """What one camera sees of the rendered instances.

    Attributes:
        depth: (h, w) float32 metres, optical-frame z of the nearest surface on each pixel's centre ray; 0 where
            nothing is drawn.
        label: (h, w) int32, the :attr:`MeshInstance.label` of the instance seen; -1 where nothing is drawn.
        intensity: (h, w) float32 in [0, 1], Lambertian shading with the light at the camera:
            albedo * (a + (1 - a) * |cos|), |cos| between the surface normal and the ray, a =
            ``config.RENDER_AMBIENT``; 0 where nothing is drawn.
    """

    depth: np.ndarray
    label: np.ndarray
    intensity: np.ndarray


@dataclass
class _Mesh:
    vertex_buffer: object
    index_buffer: object
    n_faces: int
    depth_vao: object
    full_vao: object
    closed: bool
    centre_mesh: np.ndarray   # (3,) bounding-sphere centre, mesh frame
    radius: float             # bounding-sphere radius, metres in the mesh frame


@dataclass
class _Targets:
    """The framebuffers of one image size: colour attachments (float32) and one float32 depth buffer."""

    depth_only: object    # [z]
    full: object          # [z, label + 1, intensity]


class Renderer:
    """Renders triangle meshes into pinhole cameras: exact depth (optical z through each pixel centre), labels and
    a Lambertian intensity image, on one headless OpenGL context (EGL; Mesa's llvmpipe on a CPU-only machine).

    Meshes are uploaded once (:meth:`add_mesh`) in their own frame and placed per frame by :class:`MeshInstance`.
    Framebuffers are cached per image size. A renderer owns its context and makes it current around each call;
    use it from one thread at a time.

    Raises :class:`~depthguard.errors.RenderingError` when no EGL context can be created (missing system
    packages: libegl1, libgl1, libgl1-mesa-dri) or its OpenGL lacks glClipControl (OpenGL 4.5).
    """

    def __init__(self, libegl: str = config.EGL_LIBRARY, libgl: str = config.GL_LIBRARY,
                 near: float = config.RENDER_NEAR):
        near = float(near)
        if not (math.isfinite(near) and near > 0):
            raise InputError(f"near must be a positive number of metres, got {near!r}")
        self.near = near
        self._gl = GLContext(libegl, libgl)
        ctx = self._context()
        with ctx:
            self._depth_program = ctx.program(vertex_shader=_DEPTH_VERTEX, fragment_shader=_DEPTH_FRAGMENT)
            self._full_program = ctx.program(vertex_shader=_FULL_VERTEX, fragment_shader=_FULL_FRAGMENT)
            for program in (self._depth_program, self._full_program):
                program["near"].value = near
            self._full_program["ambient"].value = config.RENDER_AMBIENT
        self._meshes: list[_Mesh | None] = []  # None: removed
        self._targets: dict[tuple[int, int], _Targets] = {}

    @property
    def gl_renderer(self) -> str:
        """The OpenGL implementation's name (e.g. ``llvmpipe (LLVM 15.0.6, 256 bits)``)."""
        return self._gl.renderer_name

    # ----------------------------------------------------------------------------------------------- meshes

    def add_mesh(self, vertices, faces, closed: bool = False) -> int:
        """Upload a static triangle mesh once; returns its handle for :class:`MeshInstance`.

        Args:
            vertices: (n, 3) float, metres, in the mesh's own frame (stored as float32).
            faces: (m, 3) int, indices into ``vertices``. Their winding does not matter unless ``closed``.
            closed: declare the mesh watertight and wound counter-clockwise seen from outside (as
                :func:`primitive_mesh` makes them), so faces turned away from the camera may be culled (faster;
                see the module docstring). Checked: every edge must be shared by exactly two faces that traverse it
                in opposite directions, and the enclosed volume must be positive.
        """
        try:
            v = np.asarray(vertices, dtype=np.float64)
            f = np.asarray(faces)
        except (TypeError, ValueError):
            raise InputError("vertices must be an (n, 3) float array and faces an (m, 3) int array") from None
        if v.ndim != 2 or v.shape[1] != 3 or len(v) == 0:
            raise InputError(f"vertices must have shape (n, 3) with n >= 1, got {v.shape}")
        if not np.all(np.isfinite(v)):
            raise InputError("vertices contain NaN or infinity")
        if f.ndim != 2 or f.shape[1] != 3 or len(f) == 0:
            raise InputError(f"faces must have shape (m, 3) with m >= 1, got {f.shape}")
        if not np.issubdtype(f.dtype, np.integer):
            raise InputError(f"faces must be integers, got dtype {f.dtype}")
        if f.min() < 0 or f.max() >= len(v):
            raise InputError(f"faces index vertices outside [0, {len(v) - 1}]")
        if closed:
            _check_closed(v, f)
        lower, upper = v.min(axis=0), v.max(axis=0)
        centre = (lower + upper) / 2.0
        radius = float(np.linalg.norm(v - centre, axis=1).max())
        ctx = self._context()
        with ctx:
            vertex_buffer = ctx.buffer(np.ascontiguousarray(v, dtype=np.float32).tobytes())
            index_buffer = ctx.buffer(np.ascontiguousarray(f, dtype=np.uint32).tobytes())
            content = [(vertex_buffer, "3f", "position_mesh")]
            depth_vao = ctx.vertex_array(self._depth_program, content, index_buffer, index_element_size=4)
            full_vao = ctx.vertex_array(self._full_program, content, index_buffer, index_element_size=4)
        self._meshes.append(_Mesh(vertex_buffer, index_buffer, len(f), depth_vao, full_vao, bool(closed), centre,
                                  radius))
        return len(self._meshes) - 1

    def remove_mesh(self, mesh_id: int) -> None:
        """Free an uploaded mesh; its handle is invalid afterwards (handles are not reused)."""
        mesh = self._mesh(mesh_id)
        with self._context():
            for obj in (mesh.full_vao, mesh.depth_vao, mesh.index_buffer, mesh.vertex_buffer):
                obj.release()
        self._meshes[mesh_id] = None

    # ------------------------------------------------------------------------------------------- rendering

    def render(self, camera, instances) -> RenderResult:
        """Depth, label and intensity images of ``instances`` (a list of :class:`MeshInstance`) seen by ``camera``
        (a :class:`~depthguard.cameras.PinholeCamera`)."""
        instances = self._check_instances(camera, instances)
        h, w = camera.height, camera.width
        ctx = self._context()
        with ctx:
            fbo = self._targets_for(w, h).full
            self._draw(fbo, self._full_program, camera, instances, nearest=True, full=True)
            depth = np.empty((h, w), dtype=np.float32)
            label = np.empty((h, w), dtype=np.float32)
            intensity = np.empty((h, w), dtype=np.float32)
            fbo.read_into(depth, components=1, attachment=0, dtype="f4")
            fbo.read_into(label, components=1, attachment=1, dtype="f4")
            fbo.read_into(intensity, components=1, attachment=2, dtype="f4")
        return RenderResult(depth=depth, label=label.astype(np.int32) - 1, intensity=intensity)

    def render_depth(self, camera, instances) -> np.ndarray:
        """(h, w) float32 metres: optical z of the nearest surface of ``instances`` on each pixel's centre ray,
        0 where nothing is drawn. The same values as ``render(...).depth``, faster."""
        return self._depth_pass(camera, instances, nearest=True)

    def render_depth_max(self, camera, instances) -> np.ndarray:
        """(h, w) float32 metres: optical z of the *farthest* surface of ``instances`` on each pixel's centre ray
        (where the bodies end behind what the camera sees), 0 where nothing is drawn. For closed meshes it is the
        last exit point; it is >= :meth:`render_depth` everywhere."""
        return self._depth_pass(camera, instances, nearest=False)

    def render_depth_first_exit(self, camera, instances) -> np.ndarray:
        """(h, w) float32 metres: optical z where each pixel's centre ray first leaves a closed mesh of
        ``instances`` (its nearest back face), 0 where nothing is drawn. Where it is nearer than
        :meth:`render_depth_max`, the ray leaves one body and then, after a gap or not, is inside another."""
        return self._depth_pass(camera, instances, nearest=True, back_faces=True)

    def _depth_pass(self, camera, instances, nearest: bool, back_faces: bool = False,
                    crop: bool = True) -> np.ndarray:
        """One depth pass. With ``crop``, only the rectangle of pixels that the instances' bounding spheres can
        cover (:meth:`_drawn_rect`) is cleared, rasterised and read back; every pixel outside it is 0, as drawing
        the whole image would leave it (no triangle reaches it)."""
        instances = self._check_instances(camera, instances)
        ctx = self._context()
        W, H = camera.width, camera.height
        rect = self._drawn_rect(camera, instances) if crop else (0, 0, W, H)
        if rect is None:
            return np.zeros((H, W), dtype=np.float32)
        with ctx:
            fbo = self._targets_for(W, H).depth_only
            x, y, w, h = rect
            whole = rect == (0, 0, W, H)
            self._draw(fbo, self._depth_program, camera, instances, nearest=nearest, full=False,
                       back_faces=back_faces, rect=None if whole else rect)
            if whole:
                depth = np.empty((H, W), dtype=np.float32)
                fbo.read_into(depth, components=1, attachment=0, dtype="f4")
            else:
                part = np.empty((h, w), dtype=np.float32)
                fbo.read_into(part, viewport=rect, components=1, attachment=0, dtype="f4")
                depth = np.zeros((H, W), dtype=np.float32)
                depth[y:y + h, x:x + w] = part  # window row j is image row j (module docstring)
        return depth

    def _drawn_rect(self, camera, instances) -> tuple[int, int, int, int] | None:
        """(x, y, w, h): the pixels (columns x..x+w-1, rows y..y+h-1) whose centres the instances can cover, from
        their bounding spheres grown by a pixel; the whole image when a sphere reaches the near plane (it may be
        clipped, or wrap round the camera); None when none of them can reach a pixel.

        A sphere of centre (x, y, z) and radius r beyond the near plane lies in the box [x - r, x + r] x [y - r,
        y + r] x [z - r, z + r] with z - r > 0, on which x/z and y/z are monotone in each coordinate: their bounds
        are at the box's corners, and u = fx x/z + cx, v = fy y/z + cy."""
        W, H = camera.width, camera.height
        T_camera_world = camera.T_camera_world
        u_lo = v_lo = math.inf
        u_hi = v_hi = -math.inf
        if not instances:
            return None
        for instance in instances:
            centre, r = _bounding_sphere(self._meshes[instance.mesh_id], T_camera_world @ instance.T_world_mesh)
            r = r * (1.0 + 1e-6) + 1e-9  # grown by a part in a million against rounding
            if not centre[2] - r > self.near:
                return 0, 0, W, H
            x0, x1, y0, y1 = centre[0] - r, centre[0] + r, centre[1] - r, centre[1] + r
            z0, z1 = centre[2] - r, centre[2] + r
            tx = (x0 / z0, x0 / z1, x1 / z0, x1 / z1)
            ty = (y0 / z0, y0 / z1, y1 / z0, y1 / z1)
            u_lo = min(u_lo, camera.fx * min(tx) + camera.cx)
            u_hi = max(u_hi, camera.fx * max(tx) + camera.cx)
            v_lo = min(v_lo, camera.fy * min(ty) + camera.cy)
            v_hi = max(v_hi, camera.fy * max(ty) + camera.cy)
        if not (math.isfinite(u_lo) and math.isfinite(u_hi) and math.isfinite(v_lo) and math.isfinite(v_hi)):
            return 0, 0, W, H
        # Pixel (u, v) is sampled at its centre (u, v): a pixel more each way for the rasteriser's sub-pixel grid.
        q0 = max(int(math.floor(u_lo)) - 1, 0)
        q1 = min(int(math.ceil(u_hi)) + 1, W - 1)
        r0 = max(int(math.floor(v_lo)) - 1, 0)
        r1 = min(int(math.ceil(v_hi)) + 1, H - 1)
        if q0 > q1 or r0 > r1:
            return None
        return q0, r0, q1 - q0 + 1, r1 - r0 + 1

    def _draw(self, fbo, program, camera, instances, nearest: bool, full: bool, back_faces: bool = False,
              rect: tuple | None = None) -> None:
        """Draw ``instances`` into ``fbo``; only the pixels of ``rect`` ((x, y, w, h), window coordinates) when
        given."""
        ctx = self._gl.ctx
        fbo.use()
        ctx.scissor = rect  # None: the whole framebuffer
        # The depth buffer holds near / z: 1 at the near plane, 0 at infinity (see _gl.py).
        fbo.clear(0.0, 0.0, 0.0, 0.0, depth=0.0 if nearest else 1.0, viewport=rect)
        ctx.enable_only(moderngl.DEPTH_TEST)
        ctx.depth_func = ">" if nearest else "<"
        # The image is OpenGL's mirror image (module docstring), so a triangle wound counter-clockwise seen from
        # outside turns clockwise in window coordinates when it faces the camera.
        ctx.front_face = "cw"
        ctx.cull_face = "back" if nearest and not back_faces else "front"
        culling = False
        W, H = camera.width, camera.height
        program["projection"].value = (2.0 * camera.fx / W, (2.0 * camera.cx + 1.0) / W - 1.0,
                                       2.0 * camera.fy / H, (2.0 * camera.cy + 1.0) / H - 1.0)
        T_camera_world = camera.T_camera_world
        transform = program["T_camera_mesh"]
        for instance in instances:
            T_camera_mesh = T_camera_world @ instance.T_world_mesh
            transform.write(T_camera_mesh.T.astype(np.float32).tobytes())  # GLSL matrices are column-major
            mesh = self._meshes[instance.mesh_id]  # checked by _check_instances
            cull = mesh.closed and (not nearest or back_faces or self._beyond_near_plane(mesh, T_camera_mesh))
            if cull != culling:
                if cull:
                    ctx.enable(moderngl.CULL_FACE)
                else:
                    ctx.disable(moderngl.CULL_FACE)
                culling = cull
            if full:
                program["label_code"].value = float(instance.label + 1)
                program["albedo"].value = instance.albedo
                mesh.full_vao.render(moderngl.TRIANGLES)
            else:
                mesh.depth_vao.render(moderngl.TRIANGLES)

    def _beyond_near_plane(self, mesh: _Mesh, T_camera_mesh: np.ndarray) -> bool:
        """Whether the mesh's bounding sphere lies wholly beyond the near plane (then the camera is outside the
        mesh and nothing of it is clipped, so culling faces turned away from the camera is exact)."""
        centre, radius = _bounding_sphere(mesh, T_camera_mesh)
        return bool(centre[2] - radius > self.near)

    def _context(self):
        if self._gl is None:
            raise RenderingError("this Renderer was released")
        return self._gl.ctx

    def _mesh(self, mesh_id) -> _Mesh:
        if isinstance(mesh_id, (int, np.integer)) and 0 <= mesh_id < len(self._meshes):
            mesh = self._meshes[mesh_id]
            if mesh is not None:
                return mesh
            raise InputError(f"mesh_id {mesh_id} was removed")
        raise InputError(f"mesh_id {mesh_id!r} was not returned by this renderer's add_mesh "
                         f"({len(self._meshes)} meshes uploaded)")

    def _check_instances(self, camera, instances) -> list[MeshInstance]:
        if not isinstance(camera, PinholeCamera):
            raise InputError(f"camera must be a PinholeCamera, got {type(camera).__name__}")
        instances = list(instances)
        for instance in instances:
            if not isinstance(instance, MeshInstance):
                raise InputError(f"instances must be MeshInstance objects, got {type(instance).__name__}")
            self._mesh(instance.mesh_id)
        return instances

    def _targets_for(self, width: int, height: int) -> _Targets:
        key = (width, height)
        targets = self._targets.get(key)
        if targets is None:
            ctx = self._context()
            depth_buffer = self._gl.float_depth_renderbuffer(width, height)
            z, label, intensity = (ctx.renderbuffer((width, height), components=1, dtype="f4") for _ in range(3))
            targets = _Targets(depth_only=ctx.framebuffer([z], depth_buffer),
                               full=ctx.framebuffer([z, label, intensity], depth_buffer))
            self._gl.check_complete(targets.depth_only)
            self._gl.check_complete(targets.full)
            self._targets[key] = targets
        return targets

    # ------------------------------------------------------------------------------------------- lifetime

    def release(self) -> None:
        """Free the OpenGL context and everything uploaded to it. The renderer cannot be used afterwards."""
        if self._gl is not None:
            self._gl.release()
            self._gl = None
            self._meshes.clear()
            self._targets.clear()

    def __enter__(self) -> "Renderer":
        return self

    def __exit__(self, *exc) -> None:
        self.release()


def _bounding_sphere(mesh: _Mesh, T_camera_mesh: np.ndarray) -> tuple[np.ndarray, float]:
    """(centre (3,), radius): a sphere in the camera's optical frame (metres) that holds the mesh placed by
    ``T_camera_mesh`` ((4, 4), mesh frame -> optical frame): its bounding sphere's centre moved, its radius times an
    upper bound of the transform's largest scale (spectral norm: ||A||_2^2 <= max row sum of |A^T A|; exactly 1 for
    a rigid transform; the SVD that computes the norm itself costs more than drawing a link)."""
    A = T_camera_mesh[:3, :3]
    scale = float(np.sqrt(np.abs(A.T @ A).sum(axis=1).max()))
    return A @ mesh.centre_mesh + T_camera_mesh[:3, 3], scale * mesh.radius


def _check_closed(vertices: np.ndarray, faces: np.ndarray) -> None:
    """Raise InputError unless the triangles form closed surfaces wound counter-clockwise seen from outside."""
    f = faces.astype(np.int64)
    directed = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    if np.any(directed[:, 0] == directed[:, 1]):
        raise InputError("closed=True: some faces repeat a vertex")
    n = len(vertices)
    codes = directed[:, 0] * n + directed[:, 1]
    unique, counts = np.unique(codes, return_counts=True)
    reverse = directed[:, 1] * n + directed[:, 0]
    if np.any(counts != 1) or not np.all(np.isin(reverse, unique)):
        raise InputError("closed=True: the mesh is not watertight with consistent winding (every edge must be "
                         "shared by exactly two faces that traverse it in opposite directions)")
    a, b, c = (vertices[f[:, k]] for k in range(3))
    volume = np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0
    if not volume > 0:
        raise InputError(f"closed=True: the faces must be wound counter-clockwise seen from outside (enclosed volume "
                         f"{volume:.3g} m^3 is not positive)")
