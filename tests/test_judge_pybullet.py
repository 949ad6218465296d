"""depthguard's single-camera distances judged by code the project did not write (design §13, issue 2).

The depth images come from pybullet's TinyRenderer (``getCameraImage``, DIRECT mode) and the true distances from
pybullet's ``getClosestPoints`` and coal's ``distance``; ``tests/pybullet_scenes.py`` builds the scenes (random boxes,
spheres and capsules in a closed room, a large plate and the floor seen at 60-80 degrees from their normals) and
states the conventions that make pybullet's pixel (u, v) ours, which ``test_pybullet_camera_convention`` checks.

The claim under test: with ``unseen="occupied"`` and ``invalid="occupied"`` (the defaults) and ``aggregate="min"``,
a reported distance is never larger than the true distance plus a stated tolerance.

Tolerance. Let Q be the true nearest obstacle point of the control point P, so the true distance is |P - Q|. If
some point B is certainly possibly-occupied for the library, then reported <= |P - B| <= |P - Q| + |Q - B|, so the
tolerance for P is the distance from Q to the nearest such B (:func:`pybullet_scenes.discretisation_bound`). The
library marks every pixel k occupied along its frustum from its measured depth d_k on, and unseen space occupied,
so the candidates are:

- Q itself when Q is unseen (outside the image or the depth range): tolerance 0;
- the boundary of the observed volume;
- for each pixel k of the 3 x 3 block around Q's pixel: B_k = z' (x', y', 1), with (x', y') Q's tangents clamped
  into k's footprint and z' = max(z_Q, d_k). d_k is the exact first-surface depth on k's centre ray (an analytic
  ray cast against the true boxes, spheres and capsules), raised by the renderer's error bound
  (``RENDER_DEPTH_REL`` = 1e-5 of the depth, measured at about 7e-6) and, for uint16 images, by half a millimetre
  of rounding. The noise margin only lowers d_k, so it is left out.

This is the pixel-discretisation error at Q, evaluated exactly instead of estimated. Its size is the familiar one:
a pixel's depth is sampled at its centre but stands for its whole footprint, r/f wide at range r; on a surface
inclined at theta to the ray the sampled depth differs from Q's by up to about (sqrt(2)/2) (r/f) tan(theta)
(first order; exactly r e/(1 - e) with e = (sqrt(2)/2) tan(theta)/f on a plane seen on axis), so the own-pixel
candidate grows like tan(theta); at a silhouette the pixel whose centre misses the object is covered by its
neighbour's frustum, at most one footprint (sqrt(2) z/f) away. The cap for extremely grazing angles is the minimum
over the neighbourhood: when Q's own pixel sees its surface nearly edge-on, a neighbouring pixel sees an adjacent,
less inclined face or whatever lies in front, at about one footprint. A scene where no neighbour helps (an edge-on
sliver with nothing in front) would need a large tolerance; the test refuses to hide that and asserts that the
tolerance stays below ``CAP_FOOTPRINTS`` footprints (r/f) for every point, so the tolerance is never vacuous.

Truth: both judges must agree to within pybullet's collision margin on box corners ((sqrt(3) - 1) mm; its box is
rounded by a 1 mm margin), and the smaller of the two is used. Points inside an obstacle are left out.

Measured with the seeds below (``pytest -s`` prints the figures): 5252 judged points; largest excess
(reported - true) 7.1 mm at 320x240 (a box face seen at 85 degrees; its tolerance 7.2 mm) and 1.4 mm at 640x480;
largest excess / tolerance 0.994, so the tolerance is tight, not generous; the tolerance never exceeded 0.61
footprints. Usefulness (median reported / true in front of visible surfaces): 0.931. Default noise and uint16
millimetres: largest excess 3.9 mm, within tolerance.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest

import coal  # noqa: F401,E402  (the judges are required: a missing one must fail, never skip)
import pybullet as p  # noqa: E402

import depthguard as dg  # noqa: E402
import pybullet_scenes as ps  # noqa: E402

#: Surveillance radius of the monitor, metres.
RHO = 0.4

#: Floating-point slack of the comparisons, metres (library float32 depths are covered by RENDER_DEPTH_REL).
EPS = 1e-6

#: pybullet rounds box corners and edges by its 1 mm collision margin, so its distance near a corner exceeds the
#: exact one by up to (sqrt(3) - 1) mm; coal's is exact. The two judges must agree to within this.
JUDGES_AGREE = (math.sqrt(3.0) - 1.0) * 1e-3 + 1e-6

#: The tolerance may not exceed this many footprints (r/f at Q's range r) anywhere: beyond it the scene, not the
#: library, would be what the test measures.
CAP_FOOTPRINTS = 2.0

#: 320x240 cameras (f scaled from the 640x480 Kinect's 525 px) and one 640x480 scene.
SMALL = (320, 240, 262.5)
LARGE = (640, 480, 525.0)
SEEDS_SMALL = tuple(range(10))
SEED_LARGE = 100


@pytest.fixture(scope="module")
def client():
    cid = p.connect(p.DIRECT)
    yield cid
    p.disconnect(cid)


@dataclass
class Judged:
    """One scene, its control points and everything measured about them."""

    seed: int
    camera: dg.PinholeCamera
    primitives: list
    depth: np.ndarray  # (h, w) rendered optical z, metres
    points: np.ndarray  # (n, 3) world
    truth: ps.Truth
    bound: np.ndarray  # (n,) tolerance, metres
    result: dg.DistanceResult


def rendered_image(depth: np.ndarray, camera, uint16: bool):
    """A depthguard depth image of a rendered depth map: float32 metres, or uint16 millimetres (rounded)."""
    if uint16:
        data = np.round(np.where(np.isfinite(depth), depth, 0.0) / camera.depth_scale).astype(np.uint16)
    else:
        data = np.where(np.isfinite(depth), depth, 0.0).astype(np.float32)
    return dg.depth_image(data, camera)


def judge(client, seed: int, size=SMALL, noise=None, uint16: bool = False, points=None, per_primitive: int = 30,
          uniform: int = 40) -> Judged:
    """Build scene ``seed``, render it, query the library and measure the truth at the control points.

    ``points``: a function (scene, camera, rng) -> (n, 3) world points; default: points near every primitive
    plus ``uniform`` points anywhere in the room.
    """
    rng = np.random.default_rng(seed)
    camera, primitives = ps.random_scene(rng, *size, noise=noise)
    scene = ps.PybulletScene(client, primitives)
    try:
        depth = scene.render(camera)
        lo, hi = camera.depth_range
        assert np.all((depth > lo) & (depth < hi)), "a pixel sees nothing within the depth range: room too big"
        if points is None:
            candidates = ps.sample_points_near(scene, rng, per_primitive, RHO, uniform)
        else:
            candidates = points(scene, camera, rng)
        truth = scene.measure(candidates, RHO + 0.2)
    finally:
        scene.remove()
    assert truth.judges_gap <= JUDGES_AGREE, f"seed {seed}: pybullet and coal differ by {truth.judges_gap:.3g} m"
    outside = truth.distance > 0.0
    truth = ps.Truth(truth.distance[outside], truth.nearest_world[outside], truth.primitive[outside],
                     truth.judges_gap)
    candidates = candidates[outside]
    monitor = dg.DistanceMonitor(dg.Rig({"cam": camera}), rho=RHO, aggregate="min")
    result = monitor.query({"cam": rendered_image(depth, camera, uint16)}, candidates)
    slack = 0.5 * camera.depth_scale if uint16 else 0.0
    bound = ps.discretisation_bound(primitives, camera, truth.nearest_world, depth_slack=slack)
    return Judged(seed, camera, primitives, depth, candidates, truth, bound, result)


def excess(j: Judged, reported=None) -> np.ndarray:
    """(n,) reported - true distance, metres; for a point reported free (inf) it is +inf if the truth plus the
    tolerance lies within rho (the library should have seen something) and -inf otherwise. ``reported``: another
    result's distances for the same points (default: the scene's own)."""
    reported = j.result.distance if reported is None else reported
    true = j.truth.distance
    within = true + j.bound + EPS < RHO
    with np.errstate(invalid="ignore"):
        return np.where(np.isfinite(reported), reported - true, np.where(within, np.inf, -np.inf))


def assert_never_optimistic(j: Judged, label: str) -> None:
    """Every reported distance is at most the truth plus the point's tolerance."""
    over = excess(j) - j.bound
    if np.any(over > EPS):
        i = int(np.argmax(over))
        Q = j.truth.nearest_world[i]
        kind = j.primitives[j.truth.primitive[i]].kind
        theta = ps.surface_inclination(j.camera, j.points[i : i + 1], Q[None])[0]
        pytest.fail(
            f"{label}, seed {j.seed}: optimistic at P = {j.points[i].tolist()} (world): reported "
            f"{j.result.distance[i]:.6f} m, true {j.truth.distance[i]:.6f} m (nearest point {Q.tolist()} on a "
            f"{kind}, seen at {theta:.1f} deg), tolerance {j.bound[i]:.6f} m, flags {j.result.flags[i].names}"
        )


def footprint(j: Judged) -> np.ndarray:
    """(n,) r/f: a pixel's footprint at the range of each point's nearest obstacle point, metres."""
    r = np.linalg.norm(j.truth.nearest_world - j.camera.T_world_camera[:3, 3], axis=1)
    return r / min(j.camera.fx, j.camera.fy)


@pytest.fixture(scope="module")
def judged_scenes(client):
    """The main scenes, noise-free float32 images: ten 320x240 and one 640x480."""
    scenes = [judge(client, seed) for seed in SEEDS_SMALL]
    scenes.append(judge(client, SEED_LARGE, size=LARGE))
    return scenes


# ------------------------------------------------------------------------------------------------- conventions

@pytest.mark.parametrize("size", [SMALL, LARGE], ids=["320x240", "640x480"])
def test_pybullet_camera_convention(client, size):
    """pybullet's pixel (u, v) is ours and its depth buffer converts to optical z, checked analytically.

    1. A fronto-parallel plane at z = 2 m reads 2 m everywhere (measured: within 5.4e-7 m at both sizes).
    2. A box edge at image column u_e (row v_e) covers exactly the columns u > u_e (rows v > v_e): TinyRenderer
       samples each pixel at its centre. Edges at fractional offsets 0.02, 0.5 and 0.98 pin the sample position to
       better than 0.02 pixel, on both sides of the image.
    3. Over a whole random 320x240 scene the rendered depth never exceeds the exact first-surface depth on the
       pixel's centre ray (analytic ray casts) by more than RENDER_DEPTH_REL (measured: 2.0e-6 relative), and on
       boxes it matches it to that bound (measured: 3.1e-6). This is what the tolerance relies on: no pixel shows
       a surface behind the true first one, and each pixel is sampled on its centre ray.
    """
    width, height, focal = size
    camera = dg.PinholeCamera("cam", width, height, focal, focal, (width - 1) / 2.0, (height - 1) / 2.0, np.eye(4),
                              depth_range=(0.3, 6.0), noise=dg.NoiseModel.none())
    plane_z = 2.0
    big = 50.0
    backdrop = ps.Primitive("box", (big, big, 0.5), ps.pose(np.eye(3), [0.0, 0.0, 4.5]))
    plate = ps.Primitive("box", (big, big, 0.001), ps.pose(np.eye(3), [0.0, 0.0, plane_z + 0.001]))
    scene = ps.PybulletScene(client, [backdrop, plate])
    depth = scene.render(camera)
    scene.remove()
    plane_error = float(np.max(np.abs(depth - plane_z)))
    print(f"\nconvention {width}x{height}: plane at 2 m read within {plane_error:.1e} m")
    assert plane_error <= ps.RENDER_DEPTH_REL * plane_z

    # A plate covering the optical axis with one edge at a chosen image coordinate: its side faces point away from
    # the camera, so only the front face decides which pixels it covers.
    for axis, n in ((0, width), (1, height)):
        f, c = (camera.fx, camera.cx) if axis == 0 else (camera.fy, camera.cy)
        for base in (3, n // 2 - 7, n - 9):
            for frac in (0.02, 0.5, 0.98):
                edge = base + frac
                t_edge = (edge - c) / f * plane_z  # metric coordinate of the edge on the plane
                sign = 1.0 if edge < c else -1.0  # the plate extends from the edge towards the optical axis
                centre = [0.0, 0.0, plane_z + 0.001]
                centre[axis] = t_edge + sign * big
                half = [big, big, 0.001]
                scene = ps.PybulletScene(client, [backdrop, ps.Primitive("box", tuple(half),
                                                                         ps.pose(np.eye(3), centre))])
                depth = scene.render(camera)
                scene.remove()
                line = depth[height // 2, :] if axis == 0 else depth[:, width // 2]
                covered = np.nonzero(line < 3.0)[0]
                expected = np.arange(math.ceil(edge), n) if sign > 0 else np.arange(0, math.floor(edge) + 1)
                assert np.array_equal(covered, expected), (
                    f"{'column' if axis == 0 else 'row'} edge at {edge}: covered {covered.min()}..{covered.max()}, "
                    f"expected {expected.min()}..{expected.max()}"
                )

    if size == SMALL:
        rng = np.random.default_rng(7)
        camera, primitives = ps.random_scene(rng, *size)
        scene = ps.PybulletScene(client, primitives)
        depth, segmentation = ps.render_depth(client, camera)
        boxes = [body for body, prim in zip(scene.bodies, primitives) if prim.kind == "box"]
        scene.remove()
        exact = ps.exact_depth_image(primitives, camera)
        relative = (depth - exact) / exact
        assert relative.max() <= ps.RENDER_DEPTH_REL, "the renderer drew a surface behind the true one"
        on_box = np.isin(segmentation, boxes)
        assert np.abs(relative[on_box]).max() <= ps.RENDER_DEPTH_REL
        print(f"convention {width}x{height}: random scene, rendered - exact depth at most {relative.max():.2e} "
              f"relative, on boxes |rendered - exact| <= {np.abs(relative[on_box]).max():.2e} relative")


# ------------------------------------------------------------------------------------------------ never optimistic

def test_never_optimistic(judged_scenes):
    """Reported <= true + tolerance for every control point of every scene (module docstring): ten 320x240 scenes
    and one 640x480, noise-free float32 images, points at 1 mm to rho off every obstacle plus points anywhere in the
    room. Also: the tolerance stays below CAP_FOOTPRINTS footprints, at least 50 points lie within 5 cm of a surface
    seen at 60-85 degrees from its normal, and the two judges agreed (checked in :func:`judge`).

    Measured: 5252 points; largest excess (reported - true) 7.1 mm; largest excess / tolerance 0.994; where the
    tolerance is 0 (nearest point unseen or hidden) every reported distance is below the truth; the tolerance
    reached 0.61 footprints at most.
    """
    worst_excess, worst_ratio, worst_zero_tol, worst_footprints, n_points, n_grazing = 0.0, 0.0, -np.inf, 0.0, 0, 0
    for j in judged_scenes:
        assert_never_optimistic(j, "noise-free float32")
        footprints = j.bound / footprint(j)
        assert np.all(footprints <= CAP_FOOTPRINTS), "tolerance above the cap: the scene is degenerate"
        worst_footprints = max(worst_footprints, float(footprints.max()))
        e = excess(j)
        finite = np.isfinite(e)
        worst_excess = max(worst_excess, float(e[finite].max()))
        positive = finite & (j.bound > 0)
        worst_ratio = max(worst_ratio, float((e[positive] / j.bound[positive]).max()))
        zero = finite & (j.bound == 0)
        if zero.any():
            worst_zero_tol = max(worst_zero_tol, float(e[zero].max()))
        theta = ps.surface_inclination(j.camera, j.points, j.truth.nearest_world)
        n_grazing += int(np.count_nonzero((theta >= 60) & (theta <= 85) & (j.truth.distance < 0.05)))
        n_points += len(j.points)
    print(f"\nnever optimistic: {n_points} points in {len(judged_scenes)} scenes; max excess {worst_excess * 1e3:.3f} "
          f"mm; max excess/tolerance {worst_ratio:.3f}; max excess where tolerance is 0: {worst_zero_tol:.2e} m; "
          f"largest tolerance {worst_footprints:.2f} footprints; {n_grazing} points within 5 cm of surfaces seen at "
          "60-85 deg")
    assert n_grazing >= 50, "too few points near steeply seen surfaces to judge them"


def _optimistic_points(j: Judged, camera=None, method: str = "exact") -> int:
    """How many of a judged scene's points a monitor with these settings reports above truth + tolerance."""
    camera = j.camera if camera is None else camera
    monitor = dg.DistanceMonitor(dg.Rig({"cam": camera}), rho=RHO, aggregate="min", method=method)
    reported = monitor.query({"cam": rendered_image(j.depth, camera, False)}, j.points).distance
    return int(np.count_nonzero(excess(j, reported) - j.bound > EPS))


def test_judge_can_fail(judged_scenes):
    """The judge is not toothless: the papers' formulas (design §4-5 call them unsafe) and a principal point
    off by a tenth of a pixel are both caught on the same scenes (measured: 409 and 27 optimistic points)."""
    paper = sum(_optimistic_points(j, method="paper") for j in judged_scenes[:10])
    shifted = sum(_optimistic_points(j, camera=j.camera.replace(cx=j.camera.cx + 0.1)) for j in judged_scenes[:10])
    print(f"\njudge can fail: papers' formulas {paper} optimistic points, cx + 0.1 px {shifted}")
    assert paper > 0
    assert shifted > 0


# ------------------------------------------------------------------------------------------------------ usefulness

def _in_front_of_visible_surface(j: Judged) -> np.ndarray:
    """(n,) bool: P is in view and within rho of an obstacle, nothing lies on the ray from the camera to P, and the
    nearest obstacle point Q is the first surface on its own ray (exact ray casts against the true shapes)."""
    cam = j.camera
    C, R = cam.T_world_camera[:3, 3], cam.T_world_camera[:3, :3]
    P = cam.world_to_camera(j.points)
    Q = cam.world_to_camera(j.truth.nearest_world)
    u, v, _ = cam.project(P)
    lo, hi = cam.depth_range
    in_view = (P[:, 2] > lo) & (P[:, 2] < hi) & (u > -0.5) & (u < cam.width - 0.5) & (v > -0.5) \
        & (v < cam.height - 0.5)
    with np.errstate(divide="ignore", invalid="ignore"):
        hit_p = ps.first_hit(j.primitives, C, (P / P[:, 2:3]) @ R.T)
        hit_q = ps.first_hit(j.primitives, C, (Q / Q[:, 2:3]) @ R.T)
    free_before_p = hit_p >= P[:, 2]
    q_visible = (Q[:, 2] > 0) & (hit_q >= Q[:, 2] * (1.0 - 1e-9) - 1e-9)
    return in_view & free_before_p & q_visible & (j.truth.distance < RHO)


def _shell_points(scene, camera, rng) -> np.ndarray:
    return ps.sample_points_near(scene, rng, 30, RHO, offsets="uniform")


def test_useful_in_front_of_visible_surfaces(client, judged_scenes):
    """For points in front of a visible surface (:func:`_in_front_of_visible_surface`) at distances uniform in
    (0, rho) off random obstacle surfaces (a control point anywhere in its surveillance shell), noise-free images,
    the median of reported / true distance is at least 0.9.

    Ratios below 1 are the price of safety, not errors: each pixel's frustum is flat-fronted at its centre's depth,
    so within a few millimetres of an inclined surface the steps of this staircase come closer than the surface;
    and near the image border the unseen space counts as occupied. The printout also gives the median for the
    near-surface points of the main test (distances log-uniform from 1 mm) and within 1 cm, for the record.

    Measured: median 0.931 over 1219 points; for the main test's points 0.867, and 0.736 within 1 cm.
    """
    ratios = []
    for seed in SEEDS_SMALL:
        j = judge(client, seed, points=_shell_points)
        chosen = _in_front_of_visible_surface(j)
        ratios.append(j.result.distance[chosen] / j.truth.distance[chosen])
    ratios = np.concatenate(ratios)
    median = float(np.median(ratios))
    near, near_truth = [], []
    for j in judged_scenes:
        chosen = _in_front_of_visible_surface(j)
        near.append(j.result.distance[chosen] / j.truth.distance[chosen])
        near_truth.append(j.truth.distance[chosen])
    near, near_truth = np.concatenate(near), np.concatenate(near_truth)
    print(f"\nusefulness: {len(ratios)} points in front of visible surfaces, distances uniform in (0, rho): median "
          f"reported/true {median:.4f} (10th percentile {np.quantile(ratios, 0.1):.4f}); log-uniform points of the "
          f"main scenes: median {np.median(near):.4f} over {len(near)}, within 1 cm "
          f"{np.median(near[near_truth < 0.01]):.4f} over {np.count_nonzero(near_truth < 0.01)}")
    assert len(ratios) >= 200
    assert median >= 0.9


# ----------------------------------------------------------------------------------------------------- out of view

def _points_at_image_edge(scene, camera, rng, n: int = 400) -> np.ndarray:
    """Points around the image border: back-projected border pixels at 0.5-4 m, moved by up to 0.4 m."""
    side = rng.integers(0, 4, n)
    t = rng.uniform(0.0, 1.0, n)
    u = np.where(side == 0, -0.5, np.where(side == 1, camera.width - 0.5, t * camera.width - 0.5))
    v = np.where(side == 2, -0.5, np.where(side == 3, camera.height - 0.5, t * camera.height - 0.5))
    at = camera.back_project(u, v, rng.uniform(0.5, 4.0, n))
    offset = rng.normal(size=(n, 3))
    offset *= (rng.uniform(0.0, RHO, n) / np.linalg.norm(offset, axis=1))[:, None]
    world = camera.camera_to_world(at + offset)
    lo = np.array([-ps.ROOM_HALF, -ps.ROOM_HALF, 0.0]) + 1e-3
    hi = np.array([ps.ROOM_HALF, ps.ROOM_HALF, ps.ROOM_HEIGHT]) - 1e-3
    return world[np.all((world > lo) & (world < hi), axis=1)]


def test_out_of_view(client):
    """Points near the image edge or outside the field of view whose nearest obstacle point lies outside the image:
    with unseen="occupied" the reported distance is still at most the truth (+ tolerance, which is 0 for an unseen
    nearest point) and the result carries REGION_OUTSIDE_VIEW. Measured: 40 such points in the image, 160 outside."""
    inside, outside = 0, 0
    for seed in (20, 21, 22, 23):
        j = judge(client, seed, points=_points_at_image_edge)
        Q = j.camera.world_to_camera(j.truth.nearest_world)
        u, v, _ = j.camera.project(Q)
        q_out = (Q[:, 2] <= 0) | ~((u > -0.5) & (u < j.camera.width - 0.5) & (v > -0.5)
                                    & (v < j.camera.height - 0.5))
        chosen = q_out & (j.truth.distance < RHO)
        assert_never_optimistic(j, "out of view")
        for i in np.nonzero(chosen)[0]:
            assert dg.Flag.REGION_OUTSIDE_VIEW in j.result.flags[i], (
                f"seed {seed}: P = {j.points[i].tolist()} has its nearest obstacle out of view "
                f"({j.truth.distance[i]:.3f} m away) but no region_outside_view flag")
        P = j.camera.world_to_camera(j.points[chosen])
        pu, pv, _ = j.camera.project(P)
        p_in = (P[:, 2] > 0) & (pu > -0.5) & (pu < j.camera.width - 0.5) & (pv > -0.5) & (pv < j.camera.height - 0.5)
        inside += int(np.count_nonzero(p_in))
        outside += int(np.count_nonzero(~p_in))
    print(f"\nout of view: {inside} points in the image and {outside} outside, all with their nearest obstacle "
          "out of view")
    assert inside >= 30 and outside >= 30


# ------------------------------------------------------------------------------------------- noise and uint16 depth

def test_default_noise_and_uint16(client):
    """The default (Kinect-like) noise margin and uint16 millimetre images: still never above truth + tolerance
    (the tolerance grows by the half millimetre of rounding; the margin only adds occupied space).
    Measured: largest excess 3.9 mm, within each point's tolerance."""
    worst = 0.0
    for seed in SEEDS_SMALL[:4]:
        j = judge(client, seed, noise=dg.NoiseModel(), uint16=True)
        assert_never_optimistic(j, "default noise, uint16 mm")
        e = excess(j)
        worst = max(worst, float(e[np.isfinite(e)].max()))
    print(f"\ndefault noise, uint16: max excess {worst * 1e3:.3f} mm")


# --------------------------------------------------------------------------------------------------------- invariance

def test_rigid_transform_invariance(client):
    """The same scene under a random rigid transform of the whole world (camera, obstacles, points).

    1. Same depth image, camera and points moved: the distances agree to 1e-9 m (identical rendering).
    2. Re-rendered by pybullet in the moved world: every pixel's depth agrees to 2 * RENDER_DEPTH_REL (float32
       rounding; no pixel changes what it sees). Moving the start of each pixel's occupied frustum by at most
       delta = 2 * RENDER_DEPTH_REL * d moves every occupied point by at most delta * |ray| (|ray| = the length of a
       pixel ray per unit depth, largest at the image corners), so the distances agree to that.
    """
    rng = np.random.default_rng(3)
    for seed in (30, 31):
        j = judge(client, seed)
        G = ps.random_rigid_transform(rng)
        moved_camera = j.camera.replace(T_world_camera=G @ j.camera.T_world_camera)
        moved_points = j.points @ G[:3, :3].T + G[:3, 3]
        monitor = dg.DistanceMonitor(dg.Rig({"cam": moved_camera}), rho=RHO, aggregate="min")
        same_image = monitor.query({"cam": rendered_image(j.depth, moved_camera, False)}, moved_points)
        both_inf = np.isinf(same_image.distance) & np.isinf(j.result.distance)
        with np.errstate(invalid="ignore"):
            assert np.all(both_inf | (np.abs(same_image.distance - j.result.distance) <= 1e-9))
        assert same_image.flags == j.result.flags

        moved = ps.transformed(j.primitives, G)
        scene = ps.PybulletScene(client, moved)
        try:
            depth = scene.render(moved_camera)
            truth = scene.measure(moved_points, RHO + 0.2)
        finally:
            scene.remove()
        assert np.allclose(truth.distance, j.truth.distance, rtol=0.0, atol=1e-6)
        relative = np.abs(depth - j.depth) / j.depth
        assert relative.max() <= 2 * ps.RENDER_DEPTH_REL
        rerendered = monitor.query({"cam": rendered_image(depth, moved_camera, False)}, moved_points)
        corner = math.hypot(1.0, max(abs(-0.5 - j.camera.cx), abs(j.camera.width - 0.5 - j.camera.cx)) / j.camera.fx,
                            max(abs(-0.5 - j.camera.cy), abs(j.camera.height - 0.5 - j.camera.cy)) / j.camera.fy)
        allowed = 2 * ps.RENDER_DEPTH_REL * float(j.depth.max()) * corner + EPS
        d0, d1 = j.result.distance, rerendered.distance
        both_inf = np.isinf(d0) & np.isinf(d1)
        one_inf = np.isinf(d0) ^ np.isinf(d1)
        with np.errstate(invalid="ignore"):
            difference = np.abs(np.where(both_inf | one_inf, 0.0, d1 - d0))
        assert np.all(difference <= allowed)
        finite = np.where(np.isinf(d0), d1, d0)[one_inf]
        assert np.all(finite >= RHO - allowed), "one image saw something well within rho that the other did not"
        print(f"\ninvariance seed {seed}: image relative difference max {relative.max():.2e}; distance difference "
              f"max {difference.max():.2e} m (allowed {allowed:.2e})")
