"""The single-camera query kernels against their full-scan NumPy twin, the corrections of design §4-5 on
constructed scenes, and real data."""

import json
import os
import subprocess
import sys

import numpy as np
import pytest

import depthguard as dg
import naive
from depthguard.scenes import Box, Capsule, Sphere, render_depth, scene_distance
from depthguard.transforms import look_at

AGGREGATES = ("min", "mean", "hybrid")


def small_camera(pose, noise=None, depth_range=(0.3, 6.0), width=160, height=120):
    f = 525.0 * width / 640
    return dg.PinholeCamera("cam", width, height, f, f, (width - 1) / 2, (height - 1) / 2, pose,
                            depth_range=depth_range, noise=noise or dg.NoiseModel.none())


def random_scene(rng):
    prims = [Box.from_bounds([-4, -4, -0.1], [4, 4, 0.0])]
    for _ in range(rng.integers(2, 6)):
        kind = rng.integers(3)
        c = rng.uniform([-0.8, -0.8, 0.1], [0.8, 0.8, 1.2])
        if kind == 0:
            angle = rng.uniform(0, np.pi)
            R = np.array([[np.cos(angle), -np.sin(angle), 0], [np.sin(angle), np.cos(angle), 0], [0, 0, 1]])
            prims.append(Box(tuple(c), tuple(rng.uniform(0.05, 0.3, 3)), R))
        elif kind == 1:
            prims.append(Sphere(tuple(c), rng.uniform(0.05, 0.25)))
        else:
            prims.append(Capsule(tuple(c), tuple(c + rng.uniform(-0.4, 0.4, 3)), rng.uniform(0.03, 0.15)))
    return prims


def random_points(rng, n=12):
    """Points around the obstacles, some behind the camera or far outside its view."""
    pts = rng.uniform([-1.2, -1.2, 0.0], [1.2, 1.2, 1.6], (n, 3))
    pts[0] = [6.0, 6.0, 1.0]  # far outside the view
    pts[1] = rng.uniform(-0.2, 0.2, 3) + [2.6, 0.0, 1.5]  # near the camera
    return pts


def check_against_twin(occupancy, points, rho, aggregate, unseen):
    """Distances, directions (a tie between pixels at the same distance may pick another nearest point: one of the
    twin's), counts, invalid counts, flags and blind distances, against the full-scan twin."""
    result = dg.single_camera_distances(occupancy, points, rho, aggregate, unseen)
    distance, direction, count, invalid_count, flags, blind, tied = naive.query_reference(occupancy, points, rho,
                                                                                          aggregate, unseen)
    naive.assert_same_answers(result, distance, direction, count, invalid_count, flags, blind, tied)


@pytest.mark.parametrize("seed", range(6))
def test_kernels_equal_full_scan_twin(seed):
    rng = np.random.default_rng(seed)
    eye = rng.uniform([1.5, -1.5, 0.8], [3.0, 1.5, 2.5])
    camera = small_camera(look_at(eye, rng.uniform([-0.3, -0.3, 0.2], [0.3, 0.3, 0.8])))
    prims = random_scene(rng)
    depth = render_depth(camera, prims)
    depth[rng.random(depth.shape) < 0.03] = 0.0  # scattered holes
    depth[40:46, 60:70] = np.nan  # one larger hole
    image = dg.depth_image(depth, camera)
    points = random_points(rng)
    rho = float(rng.choice([0.2, 0.4, 0.6]))
    for invalid in ("occupied", "neighbors", "free"):
        occupancy = dg.prepare_depth(image, camera, invalid)
        for aggregate in AGGREGATES:
            for unseen in ("occupied", "free"):
                check_against_twin(occupancy, points, rho, aggregate, unseen)


def test_kernels_equal_twin_on_full_size_image_with_noise_margin():
    rng = np.random.default_rng(11)
    camera = dg.PinholeCamera("cam", 640, 480, 525.0, 525.0, 319.5, 239.5, look_at([2.2, 0.4, 1.6], [0, 0, 0.6]),
                              depth_range=(0.4, 8.0))  # default (Kinect-like) noise margin
    prims = random_scene(rng) + [Box.from_bounds([-2.5, -4, 0], [-2.4, 4, 3])]
    depth_mm = np.round(render_depth(camera, prims) * 1000).astype(np.uint16)
    occupancy = dg.prepare_depth(dg.depth_image(depth_mm, camera), camera)
    points = random_points(rng, 6)
    for aggregate in AGGREGATES:
        check_against_twin(occupancy, points, 0.4, aggregate, "occupied")


def test_paper_method_equals_its_twin():
    rng = np.random.default_rng(5)
    camera = small_camera(look_at([2.0, 0.3, 1.4], [0, 0, 0.5]))
    prims = random_scene(rng) + [Box.from_bounds([-2.5, -4, 0], [-2.4, 4, 3])]
    occupancy = dg.prepare_depth(dg.depth_image(render_depth(camera, prims), camera), camera)
    points = random_points(rng)
    for aggregate in AGGREGATES:
        result = dg.single_camera_distances(occupancy, points, 0.4, aggregate, "free", method="paper")
        distance, direction = naive.paper_query_reference(occupancy, points, 0.4, aggregate)
        np.testing.assert_allclose(result.distance, distance, rtol=0, atol=1e-10)
        np.testing.assert_allclose(result.direction, direction, rtol=0, atol=1e-9)


def test_never_above_exact_geometry_on_exact_images():
    """On exact ray-cast images (noise-free camera), the min distance is at most the true distance plus the pixel
    discretisation: the footprint at the obstacle's depth (times 2 for surfaces seen obliquely)."""
    rng = np.random.default_rng(3)
    for _ in range(4):
        camera = small_camera(look_at(rng.uniform([1.8, -1, 1.0], [2.5, 1, 2.0]), [0, 0, 0.5]), width=320,
                              height=240)
        prims = random_scene(rng) + [Box.from_bounds([-2.5, -4, 0], [-2.4, 4, 3])]
        occupancy = dg.prepare_depth(dg.depth_image(render_depth(camera, prims), camera), camera)
        points = rng.uniform([-1, -1, 0.05], [1, 1, 1.5], (200, 3))
        truth = scene_distance(prims, points)
        result = dg.single_camera_distances(occupancy, points, 0.4, "min")
        depth = camera.world_to_camera(points)[:, 2]
        tolerance = 2.0 * (depth + 0.4) / camera.fx
        near = truth < 0.4
        assert np.all(result.distance[near] <= truth[near] + tolerance[near])


def test_gray_area_obstacle_closer_than_papers_distance():
    """design §4 on a constructed scene: a plate off the optical axis hides an obstacle in its gray area. The
    papers' fixed-depth distance says that obstacle is farther away than it is; the exact distance does not."""
    camera = dg.PinholeCamera("cam", 640, 480, 525.0, 525.0, 319.5, 239.5, np.eye(4), depth_range=(0.2, 10.0),
                              noise=dg.NoiseModel.none())
    # A plate facing the camera at z = 1, spanning x in [0.5, 0.7]: its shadow is x >= 0.5 z behind it.
    plate = Box.from_bounds([0.5, -0.1, 1.0], [0.7, 0.1, 1.0001])  # thin, so its shadow starts at x = 0.5 z
    back = Box.from_bounds([-5, -5, 6.0], [5, 5, 6.1])
    P = np.array([0.5, 0.0, 1.4])  # beside the shadow: 0.2 m from it at P's own depth
    inward = np.array([1.0, 0.0, -0.5]) / np.linalg.norm([1.0, 0.0, -0.5])  # unit normal into the shadow
    gap = abs(P[0] - 0.5 * P[2]) / np.linalg.norm([1.0, 0.0, -0.5])  # perpendicular distance to x = 0.5 z
    foot = P + gap * inward  # the nearest point of the shadow, nearer to the camera than P
    hidden = Sphere(tuple(foot + 0.016 * inward), 0.01)  # just inside the shadow
    depth = render_depth(camera, [plate, back, hidden])
    assert np.array_equal(depth, render_depth(camera, [plate, back]))  # the camera cannot see the sphere
    occupancy = dg.prepare_depth(dg.depth_image(depth, camera), camera)
    truth = scene_distance([hidden], P[None])[0]
    exact = dg.single_camera_distances(occupancy, P[None], 0.4, "min").distance[0]
    paper = dg.single_camera_distances(occupancy, P[None], 0.4, "min", method="paper").distance[0]
    assert exact <= truth
    assert paper > truth + 0.01, (paper, truth)  # the papers' answer is optimistic by more than a centimetre


def test_papers_window_misses_an_obstacle_the_corrected_region_finds():
    """design §5: rho = 0.4 m, P at 2 m depth, an obstacle 0.3 m beside P at the same depth."""
    camera = dg.PinholeCamera("cam", 640, 480, 525.0, 525.0, 319.5, 239.5, np.eye(4), depth_range=(0.2, 10.0),
                              noise=dg.NoiseModel.none())
    obstacle = Box.from_bounds([0.29, -0.05, 1.95], [0.39, 0.05, 2.05])
    back = Box.from_bounds([-6, -6, 8.0], [6, 6, 8.1])
    occupancy = dg.prepare_depth(dg.depth_image(render_depth(camera, [obstacle, back]), camera), camera)
    P = np.array([[0.0, 0.0, 2.0]])
    truth = scene_distance([obstacle], P)[0]
    exact = dg.single_camera_distances(occupancy, P, 0.4, "min").distance[0]
    paper = dg.single_camera_distances(occupancy, P, 0.4, "min", method="paper").distance[0]
    assert truth == pytest.approx(0.29)
    assert exact <= truth and exact > 0.25
    assert paper == np.inf  # missed entirely


def test_real_tum_frame_never_farther_than_nearest_back_projected_point(real_data):
    """Real Kinect data: every back-projected pixel centre lies in its pixel's occupied set, so the depth-space
    minimum distance can never exceed the distance to the nearest back-projected point (plus 1 mm for float32)."""
    camera = dg.PinholeCamera("tum", 640, 480, 525.0, 525.0, 319.5, 239.5, np.eye(4), depth_scale=1 / 5000,
                              noise=dg.NoiseModel.none())
    image = dg.load_depth(os.path.join(real_data, "tum-rgbd-frame", "TUM_depth.png"), camera)
    occupancy = dg.prepare_depth(image, camera, invalid="free")
    from scipy.spatial import cKDTree

    from depthguard.baselines import point_cloud

    cloud = point_cloud(image, camera)
    rng = np.random.default_rng(0)
    v, u = rng.integers(0, 480, 400), rng.integers(0, 640, 400)
    d = image.metres()[v, u]
    ok = np.isfinite(d)
    points = camera.back_project(u[ok], v[ok], d[ok] + rng.uniform(-0.4, 0.3, ok.sum()))
    points += rng.normal(scale=0.1, size=points.shape)
    nearest, _ = cKDTree(cloud).query(points)
    for unseen in ("free", "occupied"):
        result = dg.single_camera_distances(occupancy, points, 0.5, "min", unseen)
        inside = nearest < 0.499
        assert inside.sum() > 200
        assert np.all(result.distance[inside] <= nearest[inside] + 1e-3)
    # And the gray area makes it strictly smaller for many points behind surfaces.
    assert np.mean(result.distance[inside] < nearest[inside] - 0.01) > 0.2


_JIT_SCRIPT = r"""
import json, sys
import numpy as np
sys.path.insert(0, sys.argv[1])
import depthguard as dg
from depthguard.scenes import Box, Sphere, render_depth
from depthguard.transforms import look_at
cam = dg.PinholeCamera("cam", 48, 36, 40.0, 40.0, 23.5, 17.5, look_at([2.0, 0.3, 1.4], [0, 0, 0.5]),
                       depth_range=(0.3, 6.0))
prims = [Box.from_bounds([-4, -4, -0.1], [4, 4, 0.0]), Sphere((0.1, 0.2, 0.5), 0.3), Box.from_bounds([-3, -4, 0], [-2.9, 4, 3])]
depth = render_depth(cam, prims)
depth[10:12, 20:23] = 0
occ = dg.prepare_depth(dg.depth_image(depth, cam), cam, "neighbors")
pts = np.array([[0.5, 0.2, 0.6], [0.0, -0.4, 0.3], [0.1, 0.2, 0.5], [5.0, 5.0, 1.0]])
out = {}
for agg in ("min", "mean", "hybrid"):
    for method in ("exact", "paper"):
        r = dg.single_camera_distances(occ, pts, 0.5, agg, method=method)
        out[agg + method] = [np.where(np.isinf(r.distance), -1, r.distance).tolist(), r.direction.tolist(),
                             r.count.tolist(), [int(f) for f in r.flags]]
d, _ = dg.frustum_distance(pts, np.array([[0.01, 0.02, -0.01, 0.0]] * 4), np.array([0.5, np.inf]))
out["frustum"] = d.tolist()
print(json.dumps(out))
"""


def test_kernels_run_without_jit_and_agree():
    """NUMBA_DISABLE_JIT=1 runs the kernels' bodies as plain Python (so coverage sees them); results must agree."""
    repo = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    outputs = []
    for disable in ("1", "0"):
        env = dict(os.environ, NUMBA_DISABLE_JIT=disable)
        done = subprocess.run([sys.executable, "-c", _JIT_SCRIPT, repo], env=env, capture_output=True, text=True,
                              timeout=600)
        assert done.returncode == 0, done.stderr[-2000:]
        outputs.append(json.loads(done.stdout))
    plain, jitted = outputs
    for key in jitted:
        assert np.allclose(np.array(plain[key][0] if key != "frustum" else plain[key]),
                           np.array(jitted[key][0] if key != "frustum" else jitted[key]), atol=1e-9), key
        if key != "frustum":
            assert np.allclose(plain[key][1], jitted[key][1], atol=1e-9), key
            assert plain[key][2:] == jitted[key][2:], key
