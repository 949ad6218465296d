"""Multi-camera scenes rendered by pybullet, and the tolerance a fused (depth grid) distance is judged with.

The cameras, the room and the primitives are those of ``pybullet_scenes`` (its conventions, exact box visuals,
sphere and capsule meshes that contain the true shapes, coal + pybullet distances). Here: rigs of two or four cameras
looking at the middle of the room, random obstacles there, and :func:`fused_bound`.

Tolerance of a fused distance (:func:`fused_bound`). Let Q be the true nearest obstacle point of control point P. If
some point B is certainly occupied for the fused query, then fused <= |P - B| <= |P - Q| + |Q - B|; the tolerance is
the distance from Q to the nearest such B. It is worked out from the rendered images the library was given (pybullet's
output, noise-free float32 metres: a pixel's value is the depth of the first drawn surface on its centre ray), with
what design §3 and §8 say stays occupied:

- Q unseen by the principal camera: 0; otherwise the distance from Q to the boundary of its observed volume
  (unseen space counts as occupied);
- for each principal pixel k of the 3 x 3 block around Q's pixel (depth d_k on its centre ray): the measured
  surface's own grid cell [d_k, end of d_k's cell] is certain (case iii; case ii keeps even more), and so is
  everything beyond the grid's far end d_max behind d_k. Candidate: B_k = Q's tangents clamped into k's footprint, at
  depth clamp(z_Q, d_k, end) (end = inf when d_k or z_Q lies beyond d_max). This is the single-camera bound of
  ``pybullet_scenes.discretisation_bound`` with one change: behind a surface only its first cell is certain,
  because the gray area beyond it is what the other cameras may clear;
- when z_Q lies in k's gray area: B_k at depth z_Q, if every secondary camera confirms B_k's grid cell by the
  corrected rule, evaluated here from the cameras and the rendered images alone (:func:`cell_confirmed`: one pixel
  of the cell's footprint, grown by ``pad``, measured a surface nearer than the cell's far depth plus the fusion
  margin; or the footprint leaves the image). For Q's own pixel the cell holds Q, an obstacle point, and B_k = Q:
  tolerance 0. This is where a wrong confirmation rule shows: the papers' rule (clear when the secondary's depth is
  beyond the cell's near depth) clears a cell that holds the obstacle the secondary sees;
- pixels that may show the robot (``maybe_robot``): B_k at depth max(z_Q, d_k) only if it lies beyond where the
  self-filter stops counting the robot's own volume (``behind_robot``, the caller's test) and the secondary cameras
  confirm its cell.

So the tolerance is the principal camera's pixel discretisation at Q; the secondary cameras add nothing when their
pixels around Q see the obstacle (or anything in front of it), and when they see beyond it, Q's cell may honestly be
cleared and only the other candidates count.
"""

from __future__ import annotations

import numpy as np

import depthguard as dg
import pybullet_scenes as ps
from depthguard.transforms import look_at

#: Image size and focal length (pixels) of every camera: a 640x480 Kinect (f = 525) scaled down four times.
WIDTH, HEIGHT, FOCAL = 160, 120, 131.25

#: Measured range of every camera, metres: the whole closed room lies within it, so every pixel is valid.
DEPTH_RANGE = (0.3, 8.0)

#: Where the cameras look: the middle of the room, above the floor.
TARGET = (0.2, 0.0, 0.6)

#: Camera positions (world, metres). "p" is the principal; "s" is 3.49 m from it; "t" and "w" complete a ring of four.
EYES = {
    "p": (-2.0, -1.0, 1.9),
    "s": (-0.6, 2.2, 1.9),
    "t": (2.0, 1.4, 2.0),
    "w": (1.5, -2.1, 1.6),
}

#: Random obstacles: centres uniform in this box (world, metres), well inside every camera's view.
OBSTACLE_LOW = (-0.8, -1.0, 0.15)
OBSTACLE_HIGH = (1.2, 1.0, 1.4)


def camera(name: str, eye, target=TARGET) -> dg.PinholeCamera:
    """A noise-free 160x120 camera at ``eye`` looking at ``target`` (world, metres)."""
    return dg.PinholeCamera(name, WIDTH, HEIGHT, FOCAL, FOCAL, (WIDTH - 1) / 2.0, (HEIGHT - 1) / 2.0,
                            look_at(np.asarray(eye, dtype=np.float64), np.asarray(target, dtype=np.float64)),
                            depth_range=DEPTH_RANGE, noise=dg.NoiseModel.none())


def rig(names=("p", "s")) -> dg.Rig:
    """The cameras ``names`` of :data:`EYES`, principal "p"."""
    return dg.Rig({name: camera(name, EYES[name]) for name in names}, principal="p")


def random_obstacles(rng, count: int) -> list[ps.Primitive]:
    """``count`` random boxes, spheres and capsules, randomly turned, centred in the middle of the room."""
    primitives = []
    for _ in range(count):
        kind = str(rng.choice(["box", "sphere", "capsule"]))
        centre = rng.uniform(OBSTACLE_LOW, OBSTACLE_HIGH)
        if kind == "box":
            size = tuple(rng.uniform(0.04, 0.3, 3))
        elif kind == "sphere":
            size = (rng.uniform(0.05, 0.25),)
        else:
            size = (rng.uniform(0.04, 0.15), rng.uniform(0.1, 0.6))
        primitives.append(ps.Primitive(kind, size, ps.pose(ps.random_rotation(rng), centre)))
    return primitives


def depth_frame(depth: np.ndarray, cam: dg.PinholeCamera) -> dg.DepthImage:
    """A rendered depth map (optical z, metres, inf for nothing) as a float32 depthguard frame (0: no measurement)."""
    return dg.depth_image(np.where(np.isfinite(depth), depth, 0.0).astype(np.float32), cam)


def points_near(scene: ps.PybulletScene, rng, indices, per_primitive: int, rho: float) -> np.ndarray:
    """(n, 3) world points off the surfaces of the primitives ``indices`` of ``scene`` (as
    ``pybullet_scenes.sample_points_near``: along the outward direction from a random nearby point to its nearest
    surface point), half at distances log-uniform in [1 mm, rho] (where discretisation shows), half uniform in
    (0, rho). Points may lie inside other obstacles; the caller drops those."""
    chunks = []
    for j in indices:
        prim = scene.primitives[j]
        extent = float(np.linalg.norm(prim.size)) + rho
        X = prim.centre + rng.uniform(-extent, extent, (per_primitive, 3))
        distance, nearest = scene.closest_coal(X)
        Q, d = nearest[:, j], distance[:, j]
        outside = d > 1e-6
        m = int(outside.sum())
        offset = np.where(np.arange(m) % 2 == 0, np.exp(rng.uniform(np.log(1e-3), np.log(rho), m)),
                          rng.uniform(0.0, rho, m))
        chunks.append(Q[outside] + offset[:, None] * (X[outside] - Q[outside]) / d[outside, None])
    return np.concatenate(chunks)


#: Ties at pixel edges and float32 depths: the judge gives the library the benefit of 1 um.
TIE = 1e-6


def cell_confirmed(principal: dg.PinholeCamera, u: int, v: int, z0: float, z1: float, cam: dg.PinholeCamera,
                   depth: np.ndarray, margin: float, pad: int) -> bool:
    """Whether secondary camera ``cam`` (its rendered ``depth``) confirms the principal's grid cell [z0, z1] of pixel
    (u, v) under design §8's rule, computed here from the cameras alone: the cell's 8 corners projected into
    ``cam``; confirmed if a corner is nearer than its minimum range, if the footprint (pixels whose square meets the
    corners' bounding box, grown by ``pad``) leaves the image, or if one footprint pixel measured nothing or a surface
    nearer than the cell's far depth plus ``margin``. Ties go against confirming (the footprint is shrunk by TIE)."""
    us = np.array([u - 0.5, u + 0.5, u - 0.5, u + 0.5] * 2)
    vs = np.array([v - 0.5, v - 0.5, v + 0.5, v + 0.5] * 2)
    zs = np.array([z0] * 4 + [z1] * 4)
    corners = cam.world_to_camera(principal.camera_to_world(principal.back_project(us, vs, zs)))
    z = corners[:, 2]
    if np.any(z <= max(cam.depth_range[0], 1e-6)):
        return True
    x = cam.fx * corners[:, 0] / z + cam.cx
    y = cam.fy * corners[:, 1] / z + cam.cy
    q_lo = int(np.ceil(x.min() - 0.5 + TIE)) - pad
    q_hi = int(np.floor(x.max() + 0.5 - TIE)) + pad
    r_lo = int(np.ceil(y.min() - 0.5 + TIE)) - pad
    r_hi = int(np.floor(y.max() + 0.5 - TIE)) + pad
    if q_lo < 0 or r_lo < 0 or q_hi > cam.width - 1 or r_hi > cam.height - 1:
        return True
    seen = depth[r_lo : r_hi + 1, q_lo : q_hi + 1]
    lo, hi = cam.depth_range
    with np.errstate(invalid="ignore"):
        invalid = ~np.isfinite(seen) | (seen < lo) | (seen > hi)
        return bool(np.any(invalid | (seen < z.max() + margin - TIE)))


def fused_bound(principal: dg.PinholeCamera, depth: np.ndarray, nearest_world, grid, secondaries, margin: float,
                pad: int, maybe_robot: np.ndarray | None = None, behind_robot=None):
    """The tolerance of each fused distance (module docstring).

    Args:
        principal: the principal camera; depth: its rendered (h, w) optical z, metres (inf: nothing drawn).
        nearest_world: (n, 3) the true nearest obstacle point Q of each control point, world frame.
        grid: the depth grid map (only its d_min, delta_d and n_cells: design §12's grid).
        secondaries: list of (camera, rendered depth) of the secondary cameras.
        margin, pad: the monitor's ``fusion_margin`` (metres) and ``fusion_pixels``.
        maybe_robot: (h, w) bool, principal pixels that may show the robot's padded geometry.
        behind_robot: function (m, 3) world points -> (m,) bool: the point lies so far behind the robot, as the
            principal sees it, that the library counts it as the robot's blind spot, not as the robot's volume.

    Returns (bound (n,) metres, how (n,) str): "unseen" (Q outside the principal's view), "boundary" (the boundary
    of its view is nearest), "surface" (a certain cell of a measured surface), "confirmed" (a gray cell that every
    secondary camera confirms).
    """
    nearest_world = np.asarray(nearest_world, dtype=np.float64)
    Q = principal.world_to_camera(nearest_world)
    n = len(Q)
    fx, fy, cx, cy = principal.fx, principal.fy, principal.cx, principal.cy
    W, H = principal.width, principal.height
    z_min, z_max = principal.depth_range
    d_min, delta_d = grid.d_min, grid.delta_d
    d_max = d_min + grid.n_cells * delta_d
    maybe_robot = np.zeros(principal.shape, bool) if maybe_robot is None else maybe_robot
    bound = np.full(n, np.inf)
    how = np.full(n, "unseen", dtype=object)
    tx0, tx1 = (-0.5 - cx) / fx, (W - 0.5 - cx) / fx
    ty0, ty1 = (-0.5 - cy) / fy, (H - 0.5 - cy) / fy

    def cell(z):
        return d_min + np.floor((z - d_min) / delta_d) * delta_d

    for i in range(n):
        X, Y, Z = Q[i]
        if not (z_min < Z < z_max):
            bound[i] = 0.0
            continue
        tx, ty = X / Z, Y / Z
        if not (tx0 < tx < tx1 and ty0 < ty < ty1):
            bound[i] = 0.0
            continue
        bound[i] = min((X - tx0 * Z) / np.hypot(1.0, tx0), (tx1 * Z - X) / np.hypot(1.0, tx1),
                       (Y - ty0 * Z) / np.hypot(1.0, ty0), (ty1 * Z - Y) / np.hypot(1.0, ty1), Z - z_min, z_max - Z)
        how[i] = "boundary"
        u0, v0 = int(np.rint(fx * tx + cx)), int(np.rint(fy * ty + cy))
        for u in range(u0 - 1, u0 + 2):
            for v in range(v0 - 1, v0 + 2):
                if not (0 <= u < W and 0 <= v < H):
                    continue
                d = float(np.float32(depth[v, u]))  # what the library reads
                if not (np.isfinite(d) and z_min <= d <= z_max):
                    continue
                x = np.clip(tx, (u - 0.5 - cx) / fx, (u + 0.5 - cx) / fx)
                y = np.clip(ty, (v - 0.5 - cy) / fy, (v + 0.5 - cy) / fy)

                def offer(z, label):
                    distance = float(np.linalg.norm(np.array([x * z, y * z, z]) - Q[i]))
                    if distance < bound[i]:
                        bound[i], how[i] = distance, label

                def confirmed(z):
                    if z < d_min or z >= d_max:
                        return True  # outside the grid: occupied as it stands
                    z0 = cell(z)
                    return all(cell_confirmed(principal, u, v, z0, z0 + delta_d, cam, image, margin, pad)
                               for cam, image in secondaries)

                if not maybe_robot[v, u]:
                    # the measured surface's own cell (and, beyond the grid, everything behind it) is certain
                    end = np.inf if (d >= d_max or Z >= d_max) else (cell(d) + delta_d if d >= d_min else d_min)
                    offer(min(max(Z, d), end), "surface")
                    if Z > end and confirmed(Z):  # Q's depth lies in the gray area behind that cell
                        offer(Z, "confirmed")
                else:
                    # the robot, or a surface the self-filter may give to the robot: occupied behind it only where
                    # the robot's blind spot starts and the other cameras confirm
                    z = max(Z, d)
                    B_world = principal.camera_to_world(np.array([[x * z, y * z, z]]))
                    if behind_robot is not None and behind_robot(B_world)[0] and confirmed(z):
                        offer(z, "confirmed")
    return bound, how
