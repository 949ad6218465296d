"""The kernels on extreme numbers (issue 12): exact within the ranges the public functions accept (rho in
[config.RHO_MIN, config.RHO_MAX], coordinates within config.COORDINATE_LIMIT), and beyond them (``check=False``)
memory-safe, finished, and conservative where they cannot compute.

The scene is a flat wall at z = 2 m in front of a camera looking along +z (optical frame = world frame, no noise
margin), seen by a second camera from the side for fusion. Everything at z >= 2 m in the principal camera's view is
the wall or hidden behind it: possibly occupied, distance 0. The runs beyond the ranges happen in a child process
with a time limit, so that a crash or a hang fails the test instead of killing pytest.
"""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

import depthguard as dg
from depthguard import config
from depthguard.depthgrid import FusedFrames, build_map, seen_free
from depthguard.transforms import look_at

WIDTH, HEIGHT, F, CX, CY = 64, 48, 50.0, 31.5, 23.5
WALL = 2.0
AGGREGATES = ("min", "mean", "hybrid")

SCENE = r"""
import numpy as np
import depthguard as dg
from depthguard.depthgrid import FusedFrames, build_map, seen_free
from depthguard.scenes import Box, render_depth
from depthguard.transforms import look_at


def plane_depth(camera, z_wall):
    u, v = np.meshgrid(np.arange(camera.width), np.arange(camera.height))
    rays = np.stack([(u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, np.ones(u.shape)], axis=-1)
    rays_world = rays @ camera.T_world_camera[:3, :3].T
    t = (z_wall - camera.T_world_camera[2, 3]) / rays_world[..., 2]
    return np.where(t > 0, t, 0.0).astype(np.float32)


def wall_scene(width, height, f, cx, cy, z_wall, occluder=False):
    principal = dg.PinholeCamera("principal", width, height, f, f, cx, cy, np.eye(4), depth_range=(0.3, np.inf),
                                 noise=dg.NoiseModel.none())
    second = dg.PinholeCamera("second", width, height, f, f, cx, cy,
                              look_at([1.0, 0.0, 0.0], [0.0, 0.0, z_wall], up=(0.0, -1.0, 0.0)),
                              depth_range=(0.3, np.inf), noise=dg.NoiseModel.none())
    rig = dg.Rig({"principal": principal, "second": second}, principal="principal")
    images = {}
    for name, camera in rig.cameras.items():
        depth = plane_depth(camera, z_wall)
        if occluder:  # a box in front of the wall, whose shadow the second camera sees into
            box = render_depth(camera, [Box.from_bounds([-0.6, 0.1, 1.0], [-0.4, 0.3, 1.2])])
            depth = np.where(box > 0, np.minimum(box, depth), depth)
        images[name] = dg.depth_image(depth, camera)
    occupancy = {name: dg.prepare_depth(images[name], rig.cameras[name]) for name in rig.cameras}
    grid = build_map(rig, "principal")
    fused = FusedFrames(grid, rig, occupancy["principal"],
                        {"second": seen_free(images["second"], occupancy["second"])})
    return rig, images, occupancy, grid, fused
"""
exec(SCENE)  # noqa: S102 - the same scene here and in the child processes


@pytest.fixture(scope="module")
def wall():
    return wall_scene(WIDTH, HEIGHT, F, CX, CY, WALL)  # noqa: F821 - defined by SCENE


def behind_the_wall(rng, n, z_max):
    """n points in the principal camera's view at depths in [WALL, z_max] (log-uniform), a fifth of them projecting
    exactly onto pixel borders or corners."""
    z = WALL * (z_max / WALL) ** rng.uniform(0.0, 1.0, n)
    u = rng.uniform(0.0, WIDTH - 1.0, n)
    v = rng.uniform(0.0, HEIGHT - 1.0, n)
    corner = rng.uniform(size=n) < 0.2
    u[corner] = np.floor(u[corner]) + 0.5
    v[corner] = np.floor(v[corner]) + 0.5
    return np.stack([(u - CX) / F * z, (v - CY) / F * z, z], axis=1)


@pytest.mark.parametrize("rho", [config.RHO_MIN, 1e-3, 0.4, config.RHO_MAX])
@pytest.mark.parametrize("aggregate", AGGREGATES)
def test_points_on_and_behind_the_wall_get_zero(wall, rho, aggregate):
    """On the wall or anywhere behind it, as far as the coordinate limit: distance 0 for every rho in range, one
    camera and two fused; never "nothing within rho". A point's own pixel is always looked at, whatever the
    rounding of its window."""
    _, _, occupancy, _, fused = wall
    rng = np.random.default_rng(7)
    points = np.concatenate([
        [[0.0, 0.0, WALL], [0.3, -0.2, WALL], [-0.42 * WALL, -0.06 * WALL, WALL]],  # on the wall, one on a corner
        [[0.0, 0.0, config.COORDINATE_LIMIT], [0.5e4, -0.3e4, 1e4], [-0.6e4, 0.45e4, 1e4]],  # far behind it
        behind_the_wall(rng, 200, config.COORDINATE_LIMIT)])
    single = dg.single_camera_distances(occupancy["principal"], points, rho, aggregate)
    both = fused.distances(points, rho, aggregate)
    np.testing.assert_array_equal(single.distance, 0.0)
    np.testing.assert_array_equal(both.distance, 0.0)


@pytest.mark.parametrize("aggregate", ["min", "hybrid"])
def test_in_front_of_the_wall_the_distance_is_the_gap(wall, aggregate):
    """A point on the optical axis at depth z < 2 m is 2 - z from the wall (straight ahead), or nearer to the edge
    of the view (unseen space: the plane y = 0.48 z at 0.48 z / sqrt(1 + 0.48^2)); nothing within a smaller rho."""
    _, _, occupancy, _, fused = wall
    points = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.9], [0.0, 0.0, 2.0 - 1e-4], [0.0, 0.0, 2.0 - 1e-6]])
    z = points[:, 2]
    expected = np.minimum(WALL - z, (HEIGHT / 2 / F) * z / np.hypot(1.0, HEIGHT / 2 / F))
    for rho in (config.RHO_MIN * 2, 0.2, 0.6, 1.5, config.RHO_MAX):
        for result in (dg.single_camera_distances(occupancy["principal"], points, rho, aggregate),
                       fused.distances(points, rho, aggregate)):
            np.testing.assert_allclose(result.distance, np.where(expected < rho, expected, np.inf), rtol=0,
                                       atol=1e-9)


# Runs in a child process: the kernels with check=False on numbers the public functions refuse. Prints, as JSON,
# per case the distances (null for NaN).
BEYOND = SCENE + r"""
import json, sys
rig, images, occupancy, grid, fused = wall_scene(64, 48, 50.0, 31.5, 23.5, 2.0)
cases = json.loads(sys.argv[1])
out = {}
for name, (points, rho) in cases.items():
    points = np.array(points, dtype=np.float64)
    for aggregate in ("min", "mean", "hybrid"):
        single = dg.single_camera_distances(occupancy["principal"], points, rho, aggregate, check=False)
        both = fused.distances(points, rho, aggregate, check=False)
        out[f"{name} {aggregate}"] = [[None if d != d else d for d in r.distance] for r in (single, both)]
print(json.dumps(out))
"""

INSIDE = [[0.0, 0.0, 2.0], [0.1, 0.05, 2.5], [0.0, 0.0, 1e4]]  # on and behind the wall
HUGE = [[0.0, 0.0, 1e160], [1e159, -1e159, 1e160], [1e160, 1e160, 1e160], [0.0, 0.0, -1e160], [1e300, 0.0, 1e-300]]
NOT_FINITE = [[np.nan, 0.0, 2.0], [0.0, np.inf, 2.0], [0.0, 0.0, np.nan], [-np.inf, np.nan, np.inf]]


def run_child(code, args, timeout=300):
    done = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, timeout=timeout)
    assert done.returncode == 0, f"exit status {done.returncode} (negative: killed by a signal)\n{done.stderr[-3000:]}"
    return json.loads(done.stdout.strip().splitlines()[-1])


def test_beyond_the_ranges_the_kernels_finish_and_stay_conservative():
    """check=False with rho = 1e-200, NaN, negative or 1e200, and points at 1e160, at 1e300 by 1e-300, NaN or
    infinite: no crash, no hang; a point inside the wall still gets 0, and so does a point that is not finite, or
    one far behind the wall (all of it possibly occupied)."""
    cases = {"tiny rho": (INSIDE, 1e-200), "NaN rho": (INSIDE, float("nan")), "negative rho": (INSIDE, -1.0),
             "huge rho": (INSIDE, 1e200), "huge points": (HUGE, 0.4), "huge points, tiny rho": (HUGE, 1e-200),
             "not finite": (NOT_FINITE, 0.4)}
    out = run_child(BEYOND, [json.dumps(cases, allow_nan=True)])
    for aggregate in AGGREGATES:
        for name in ("tiny rho", "NaN rho", "negative rho", "huge rho"):
            for per_method in out[f"{name} {aggregate}"]:
                assert per_method == [0.0, 0.0, 0.0], (name, aggregate, per_method)
        for per_method in out[f"not finite {aggregate}"]:
            assert per_method == [0.0] * len(NOT_FINITE), (aggregate, per_method)
        for name in ("huge points", "huge points, tiny rho"):
            for per_method in out[f"{name} {aggregate}"]:
                # In the view behind the wall (the first two), out of the view, behind the camera: all 0.
                assert per_method[:4] == [0.0] * 4, (name, aggregate, per_method)
                assert per_method[4] is None or per_method[4] >= 0.0


NAN_MAP = SCENE + r"""
import json, sys
rig, images, occupancy, grid, fused = wall_scene(64, 48, 50.0, 31.5, 23.5, 2.0, occluder=True)
rng = np.random.default_rng(3)
u = rng.uniform(0, 63, 300)
v = rng.uniform(0, 47, 300)
z = rng.uniform(0.4, 3.5, 300)
points = np.stack([(u - 31.5) / 50 * z, (v - 23.5) / 50 * z, z], axis=1)
free = {"second": seen_free(images["second"], occupancy["second"])}
blind = FusedFrames(grid, rig, occupancy["principal"], {"second": None})
out = {"clean": fused.distances(points, 0.4, "min").distance.tolist(),
       "blind": blind.distances(points, 0.4, "min").distance.tolist()}
for name in ("all corners", "some corners", "offsets"):
    # A map refuses NaN when it is made; this one is corrupted afterwards, in memory.
    bad = build_map(rig, "principal")
    corners, offsets = bad.corners.copy(), bad.offsets.copy()
    if name == "all corners":
        corners[:] = np.nan
    elif name == "some corners":
        corners[0, ::3, ::2, rng.integers(0, 3)] = np.nan
    else:
        offsets[0, 2] = np.nan
    object.__setattr__(bad, "corners", corners)
    object.__setattr__(bad, "offsets", offsets)
    runs = [FusedFrames(bad, rig, occupancy["principal"], free, check=False).distances(points, 0.4, "min",
                                                                                        check=False).distance
            for _ in range(2)]
    out[name] = [r.tolist() for r in runs]
print(json.dumps(out))
"""


def test_nan_in_the_map_clears_nothing_it_touches():
    """A depth grid map with NaN in its geometry: the cells whose footprint it touches cannot be cleared. The
    answers are the same run after run, never larger than with the clean map, and never smaller than with no
    secondary camera at all (nothing cleared); with every corner NaN they equal the latter."""
    out = run_child(NAN_MAP, [])
    clean, blind = np.array(out["clean"]), np.array(out["blind"])
    assert np.all(blind <= clean)
    assert np.any(blind < clean)  # the second camera does clear something here
    for name in ("all corners", "some corners", "offsets"):
        first, second = (np.array(r) for r in out[name])
        np.testing.assert_array_equal(first, second)
        assert np.all(first <= clean) and np.all(first >= blind), name
    np.testing.assert_array_equal(np.array(out["all corners"][0]), blind)
    np.testing.assert_array_equal(np.array(out["offsets"][0]), blind)


CELL_TESTS = r"""
import json
import numpy as np
from depthguard.kernels import depthgrid as K

eroded = np.full((48, 64), 10.0, dtype=np.float32)  # a camera that saw 10 m everywhere
corners = np.zeros((3, 3, 3))
corners[..., 2] = 1.0  # every corner 1 m ahead of the secondary camera, at pixel (20, 20)
corners[..., 0] = 20.0
corners[..., 1] = 20.0
offset = np.zeros(3)
out = {"clean": K.face_box(corners, offset, 0, 0, 1.0, 0.1)[0],
       "box clean": K.box_seen_through(eroded, 64, 48, 19.6, 20.4, 19.6, 20.4, 1.0)}
for k, name in ((0, "x"), (1, "y"), (2, "z")):
    bad = corners.copy()
    bad[1, 1, k] = np.nan
    out[f"corner {name} NaN"] = K.face_box(bad, offset, 0, 0, 1.0, 0.1)[0]
out["offset NaN"] = K.face_box(corners, np.array([0.0, 0.0, np.nan]), 0, 0, 1.0, 0.1)[0]
for name, box in (("x_lo", (np.nan, 20.4, 19.6, 20.4)), ("y_hi", (19.6, 20.4, 19.6, np.nan)),
                  ("inf", (-np.inf, np.inf, 19.6, 20.4)), ("huge", (19.6, 1e300, 19.6, 20.4))):
    out[f"box {name}"] = K.box_seen_through(eroded, 64, 48, *box, 1.0)
out["need NaN"] = K.box_seen_through(eroded, 64, 48, 19.6, 20.4, 19.6, 20.4, np.nan)
print(json.dumps({k: bool(v) for k, v in out.items()}))
"""


def test_a_footprint_that_is_not_a_number_clears_nothing():
    """The confirmation rule's two steps on NaN and infinite footprints (a corrupted map): a corner that is not a
    finite point makes the face unusable, and a box with NaN or infinite bounds, or a NaN depth to see beyond, is
    never seen through; finite inputs still are."""
    out = run_child(CELL_TESTS, [])
    assert out.pop("clean") and out.pop("box clean")
    assert not any(out.values()), out
