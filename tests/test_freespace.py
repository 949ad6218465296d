"""The free-space memory (design §8a): the distance transform against scipy, the voxels seen free against a slow
judge of the confirmation rule, the memory's arrival times against brute-force box-to-box distances (never later than
the recursion's exact arrival, at most a voxel diagonal earlier), and its promises in time."""

import itertools
import math
import os
import subprocess
import sys

import numpy as np
import pytest
from scipy import ndimage

import depthguard as dg
from depthguard import config
from depthguard.depthgrid import free_image
from depthguard.freespace import FreeSpaceMemory, VoxelBox, seen_free_voxels, squared_distance_transform
from depthguard.scenes import Box, render_depth
from depthguard_lab.simulation import standing_person
from depthguard.transforms import look_at



# ------------------------------------------------------------------------------------------------------- the judges


def scipy_squared(sites):
    """Squared distances (voxels) to the nearest site or the layer outside the array, from scipy's nearest-site
    indices (exact whole numbers)."""
    padded = ~np.pad(sites, 1, constant_values=True)
    indices = ndimage.distance_transform_edt(padded, return_distances=False, return_indices=True)
    grid = np.indices(padded.shape)
    return ((indices - grid) ** 2).sum(axis=0)[1:-1, 1:-1, 1:-1]


def judge_seen_free(box, cameras, free_images, margin, pad):
    """design §8's confirmation rule for every voxel and every pixel, in plain Python: the voxel's 8 corners in
    front of the camera, every pixel whose footprint meets the corners' projected box (grown by pad) in the image
    and free at least to the largest corner depth plus margin."""
    nx, ny, nz = box.shape
    s = box.voxel
    out = np.zeros(box.shape, dtype=bool)
    for i, j, k in itertools.product(range(nx), range(ny), range(nz)):
        for camera, free in zip(cameras, free_images):
            if free is None:
                continue
            T = camera.T_camera_world
            z_near = max(camera.depth_range[0], 1e-6)
            us, vs, zs = [], [], []
            for a, b, c in itertools.product((0, 1), repeat=3):
                x, y, z = (box.lo[0] + (i + a) * s, box.lo[1] + (j + b) * s, box.lo[2] + (k + c) * s)
                p = [T[r, 0] * x + T[r, 1] * y + T[r, 2] * z + T[r, 3] for r in range(3)]
                zs.append(p[2])
                if p[2] >= z_near:
                    us.append(camera.fx * p[0] / p[2] + camera.cx)
                    vs.append(camera.fy * p[1] / p[2] + camera.cy)
            if min(zs) < z_near:
                continue
            x_lo, x_hi, y_lo, y_hi = min(us) - pad, max(us) + pad, min(vs) - pad, max(vs) + pad
            need = max(zs) + margin
            sees = True
            for v in range(math.floor(y_lo) - 1, math.ceil(y_hi) + 2):
                for u in range(math.floor(x_lo) - 1, math.ceil(x_hi) + 2):
                    if u - 0.5 <= x_hi and u + 0.5 >= x_lo and v - 0.5 <= y_hi and v + 0.5 >= y_lo:
                        inside = 0 <= u < camera.width and 0 <= v < camera.height
                        if not (inside and float(free[v, u]) >= need):
                            sees = False
            if sees:
                out[i, j, k] = True
                break
    return out


def box_distances(box, sites):
    """(nx, ny, nz) metres: each voxel's box-to-box distance to the nearest voxel of ``sites`` or of the layer just
    outside the box, brute force over every pair: between voxels whose indices differ by d, s * |max(|d| - 1, 0)|."""
    padded = np.pad(sites, 1, constant_values=True)
    targets = np.argwhere(padded) - 1
    cells = np.indices(box.shape).reshape(3, -1).T
    gaps = np.maximum(np.abs(cells[:, None, :] - targets[None, :, :]) - 1, 0)
    return box.voxel * np.sqrt((gaps ** 2).sum(axis=2)).min(axis=1).reshape(box.shape)


def exact_arrival(box, v_max, old, t, seen, robot):
    """The recursion with exact box-to-box distances: U = (old <= t) & ~seen & ~robot, the new arrival
    max(old, t + box distance to U / v_max)."""
    u = (old <= t) & ~seen & ~robot
    return np.maximum(old, t + box_distances(box, u) / v_max), u


# ------------------------------------------------------------------------------------------ the distance transform


@pytest.mark.parametrize("shape", [(1, 1, 1), (1, 1, 9), (7, 1, 1), (3, 41, 2), (5, 7, 3), (13, 17, 11), (24, 9, 16)])
def test_distance_transform_equals_scipy(shape):
    rng = np.random.default_rng(sum(shape))
    masks = [np.zeros(shape, bool), np.ones(shape, bool)] + [rng.random(shape) < p for p in (0.003, 0.05, 0.4, 0.9)]
    thin = np.zeros(shape, bool)  # a plane, a line and a single voxel
    thin[shape[0] // 2] = True
    line = np.zeros(shape, bool)
    line[:, shape[1] // 2, shape[2] // 3] = True
    dot = np.zeros(shape, bool)
    dot[tuple(n // 3 for n in shape)] = True
    for sites in masks + [thin, line, dot]:
        ours = squared_distance_transform(sites)
        assert ours.dtype == np.int32
        np.testing.assert_array_equal(ours, scipy_squared(sites))
        # And through scipy's distances, as the docstring says.
        reference = ndimage.distance_transform_edt(~np.pad(sites, 1, constant_values=True))[1:-1, 1:-1, 1:-1]
        np.testing.assert_allclose(ours, reference ** 2, rtol=0, atol=1e-9)


def test_distance_transform_refuses_bad_masks():
    for bad in (np.zeros((3, 3)), np.zeros((3, 3, 3), np.uint8), np.zeros((0, 3, 3), bool), [[[True]]]):
        with pytest.raises(dg.InputError, match="sites"):
            squared_distance_transform(bad)


# ------------------------------------------------------------------------------------------------ seen free voxels


def random_views(rng, box, n_cameras=3):
    """Cameras of 64x48 pixels around ``box`` (one of them close, with a minimum range, so that some corners are
    behind or too near) and free images: a far wall with random nearer obstacles, dropped pixels (0), and single
    pixels free only to about the camera's distance from the box (+-0.2 m), where the voxels' far depths lie."""
    centre = (box.lo + box.hi) / 2
    cameras, images = [], []
    for c in range(n_cameras):
        direction = rng.normal(size=3)
        direction[2] = abs(direction[2]) + 0.3
        distance = 0.45 if c == 0 else rng.uniform(1.0, 1.8)
        eye = centre + distance * direction / np.linalg.norm(direction)
        target = centre + rng.normal(scale=0.1, size=3)
        f = rng.uniform(40.0, 60.0)
        camera = dg.PinholeCamera(f"c{c}", 64, 48, f, f * rng.uniform(0.9, 1.1), rng.uniform(28, 36),
                                  rng.uniform(20, 28), look_at(eye, target),
                                  depth_range=(0.3 if c == 0 else 0.0, 8.0))
        free = np.full((48, 64), 3.0, dtype=np.float32)
        for _ in range(10):
            r, q = rng.integers(0, 48), rng.integers(0, 64)
            free[r:r + rng.integers(2, 10), q:q + rng.integers(2, 14)] = rng.uniform(0.3, 2.4)
        free[rng.random(free.shape) < 0.005] = 0.0
        near = rng.random(free.shape) < 0.01
        free[near] = (distance + rng.uniform(-0.2, 0.2, near.sum())).astype(np.float32)
        cameras.append(camera)
        images.append(free)
    return cameras, images


@pytest.mark.parametrize("seed", range(3))
def test_seen_free_voxels_agree_with_the_judge(seed):
    rng = np.random.default_rng(seed)
    lo = rng.uniform(-0.5, 0.5, 3)
    box = VoxelBox(lo, lo + rng.uniform([0.7, 0.5, 0.4], [0.8, 0.6, 0.5]), 0.1)
    assert 150 <= box.size <= 500
    cameras, images = random_views(rng, box)
    if seed == 2:
        images[1] = None  # a blind camera sees nothing
    for margin, pad in ((0.0, 0), (0.02, 0), (0.0, 2), (0.02, 2)):
        ours = seen_free_voxels(box, cameras, images, margin=margin, pad=pad)
        judge = judge_seen_free(box, cameras, images, margin, pad)
        np.testing.assert_array_equal(ours, judge)
        assert 0.05 * box.size < judge.sum() < 0.95 * box.size  # the test says something
        # Each camera alone, and the union of them is what all of them see.
        alone = [seen_free_voxels(box, [c], [im], margin=margin, pad=pad) for c, im in zip(cameras, images)]
        np.testing.assert_array_equal(ours, np.logical_or.reduce(alone))
    # A larger margin or pad never sees more.
    assert not np.any(seen_free_voxels(box, cameras, images, 0.05, 3) & ~seen_free_voxels(box, cameras, images))


def test_blocks_seen_whole_agree_with_voxels_seen_one_by_one(monkeypatch):
    """A rendered scene (a floor, a pillar, a person) seen by three cameras: testing blocks of 2, 4, 8 or 16 voxels
    whole first changes nothing against testing each voxel alone (block 1), which the judge holds."""
    scene = [Box.from_bounds([-3, -3, -0.05], [3, 3, 0.0]), Box.from_bounds([-0.1, -0.1, 0.0], [0.1, 0.1, 0.9])]
    scene += standing_person((0.45, 0.2), facing=np.pi, reach=0.8)
    cameras, images = [], []
    for n, eye in enumerate(([2.0, -1.5, 1.6], [1.8, 1.8, 1.7], [-2.0, 0.3, 2.0])):
        camera = dg.PinholeCamera(f"c{n}", 160, 120, 130.0, 130.0, 79.5, 59.5, look_at(eye, [0.1, 0.0, 0.6]),
                                  depth_range=(0.4, 6.0))
        cameras.append(camera)
        images.append(free_image(dg.depth_image(render_depth(camera, scene), camera), camera))
    box = VoxelBox([-0.7, -0.6, 0.0], [0.9, 0.7, 1.3], 0.05)  # 32 x 26 x 26
    results = {}
    for block in (1, 2, 4, 8, 16):
        monkeypatch.setattr(config, "FREESPACE_BLOCK", block)
        results[block] = seen_free_voxels(box, cameras, images, margin=0.01, pad=1)
    for block in (2, 4, 8, 16):
        np.testing.assert_array_equal(results[block], results[1])
    assert 0.3 < results[1].mean() < 0.95


def test_seen_free_voxels_of_a_camera_seeing_nothing_and_the_near_limit():
    box = VoxelBox([-0.2, -0.2, 0.8], [0.2, 0.2, 1.2], 0.1)
    camera = dg.PinholeCamera("c", 64, 48, 50.0, 50.0, 31.5, 23.5, np.eye(4), depth_range=(0.0, 8.0))
    far = np.full((48, 64), 5.0, dtype=np.float32)
    assert seen_free_voxels(box, [camera], [far]).all()  # the box fills the middle of the image, nearer than 5 m
    assert not seen_free_voxels(box, [camera], [np.zeros((48, 64), np.float32)]).any()
    assert not seen_free_voxels(box, [], []).any()
    assert not seen_free_voxels(box, [camera], [None]).any()
    # Free to the far face (1.2 m; float32(1.2) lies a hair beyond) passes; a margin beyond it does not, for the
    # voxels that reach the far face only.
    exact = np.full((48, 64), 1.2, np.float32)
    assert exact[0, 0] >= box.hi[2]
    assert seen_free_voxels(box, [camera], [exact]).all()
    seen = seen_free_voxels(box, [camera], [exact], margin=0.01)
    assert seen[:, :, :3].all() and not seen[:, :, 3].any()
    assert not seen_free_voxels(box, [camera], [exact - np.float32(1e-6)])[:, :, 3].any()
    # A box wider than the view: only the voxels whose whole footprint (grown by pad) lies in the image are seen.
    wide = VoxelBox([-2.0, -0.05, 1.0], [2.0, 0.05, 1.1], 0.1)
    u_lo = 50.0 * (wide.lo[0] + np.arange(40) * 0.1) / 1.0 + 31.5  # the near face's corners are the widest
    u_hi = 50.0 * (wide.lo[0] + np.arange(1, 41) * 0.1) / 1.0 + 31.5
    for pad in (0, 3):
        inside = (np.ceil(u_lo - 0.5) - pad >= 0) & (np.floor(u_hi + 0.5) + pad <= 63)
        np.testing.assert_array_equal(seen_free_voxels(wide, [camera], [far], pad=pad)[:, 0, 0], inside)
        assert 3 <= inside.sum() <= 30
    # Voxels nearer than the camera's minimum range are not seen.
    near = dg.PinholeCamera("c", 64, 48, 50.0, 50.0, 31.5, 23.5, np.eye(4), depth_range=(1.0, 8.0))
    seen = seen_free_voxels(box, [near], [far])
    assert not seen[:, :, :2].any() and seen[:, :, 2:].all()


def test_seen_free_voxels_refuses_bad_arguments():
    box = VoxelBox([0, 0, 1], [0.2, 0.2, 1.2], 0.1)
    camera = dg.PinholeCamera("c", 64, 48, 50.0, 50.0, 31.5, 23.5, np.eye(4))
    free = np.ones((48, 64), np.float32)
    cases = [((None, [camera], [free]), {}, "box"),
             ((box, camera, [free]), {}, "cameras"),
             ((box, ["c"], [free]), {}, "cameras"),
             ((box, [camera], free), {}, "free_images"),
             ((box, [camera], []), {}, "free_images"),
             ((box, [camera], [free.astype(np.float64)]), {}, "free_images"),
             ((box, [camera], [free[:, :10]]), {}, "free_images"),
             ((box, [camera], [np.full((48, 64), np.nan, np.float32)]), {}, "free_images"),
             ((box, [camera], [free]), {"margin": -0.1}, "margin"),
             ((box, [camera], [free]), {"margin": np.nan}, "margin"),
             ((box, [camera], [free]), {"pad": 1.5}, "pad"),
             ((box, [camera], [free]), {"pad": -1}, "pad"),
             ((box, [camera], [free]), {"pad": True}, "pad")]
    for args, kwargs, field in cases:
        with pytest.raises(dg.InputError) as info:
            seen_free_voxels(*args, **kwargs)
        assert info.value.field == field, (field, str(info.value))


# ------------------------------------------------------------------------------------------------------- the memory


def test_voxel_box_grows_to_whole_voxels_and_refuses_bad_boxes():
    box = VoxelBox([0.1, 0.0, -1.0], [0.4, 0.25, 1.0], 0.1)
    assert box.shape == (3, 3, 20) and box.size == 180  # 0.3 / 0.1 is 3.0000000000000004: no sliver voxel
    np.testing.assert_allclose(box.hi, [0.4, 0.3, 1.0])
    np.testing.assert_allclose(box.axis_centres()[1], [0.05, 0.15, 0.25])
    assert VoxelBox([-1.5, -1.5, 0], [1.5, 1.5, 2], 0.04).shape == (75, 75, 50)
    cases = [(([0, 0], [1, 1, 1], 0.1), "lo"), (([0, 0, np.nan], [1, 1, 1], 0.1), "lo"),
             (("abc", [1, 1, 1], 0.1), "lo"), (([0, 0, 0], [1, 1, np.inf], 0.1), "hi"),
             (([0, 0, 0], [1, 0, 1], 0.1), "hi"), (([0, 0, 0], [1, 1, 1e5], 0.1), "hi"),
             (([0, 0, 0], [1, 1, 1], 0.0), "voxel"), (([0, 0, 0], [1, 1, 1], -0.1), "voxel"),
             (([0, 0, 0], [1, 1, 1], np.nan), "voxel"), (([0, 0, 0], [1, 1, 1], "0.1"), "voxel"),
             (([0, 0, 0], [3, 3, 2], 0.005), "voxel"),  # 144 M voxels
             (([0, 0, 0], [1000, 0.1, 0.1], 0.01), "voxel")]  # 100 000 along x
    for args, field in cases:
        with pytest.raises(dg.InputError) as info:
            VoxelBox(*args)
        assert info.value.field == field, (args, str(info.value))


def test_memory_steps_against_brute_force_box_distances():
    """Every update against the recursion's exact arrival from the same U_k (brute-force box-to-box distances):
    never later (never optimistic), at most a voxel diagonal's travel earlier; and the whole run against the
    recursion with exact distances throughout, which the memory never outruns."""
    rng = np.random.default_rng(7)
    box = VoxelBox([0.0, 0.0, 0.0], [0.9, 0.8, 0.6], 0.1)  # 9 x 8 x 6
    v_max = 0.5
    memory = FreeSpaceMemory(box, v_max=v_max)
    judge = np.full(box.shape, -np.inf)
    t = 10.0
    certified = 0
    for step in range(10):
        t += 0.0 if step == 3 else rng.uniform(0.005, 0.15)
        seen = rng.random(box.shape) < rng.uniform(0.5, 1.0)
        robot = rng.random(box.shape) < 0.1 if step % 2 else None
        no_robot = np.zeros(box.shape, bool) if robot is None else robot
        old = memory.arrival.copy()
        memory.update(t, seen, robot)
        exact, u = exact_arrival(box, v_max, old, t, seen, no_robot)
        ours = memory.arrival
        # Exactly the recursion with box-to-box distances (never later, so never optimistic; float rounding only).
        assert np.all(ours <= exact)
        np.testing.assert_allclose(ours, exact, rtol=0, atol=1e-9)
        assert np.all(ours[u] == t)
        judge, _ = exact_arrival(box, v_max, judge, t, seen, no_robot)
        assert np.all(ours <= judge)
        for dt in (0.0, 0.01, 0.05):
            now = (seen | no_robot) if dt == 0.0 else np.zeros(box.shape, bool)  # F_k = ... | Seen_k | Robot_k
            assert not np.any(memory.free_at(t + dt) & ~((judge > t + dt) | now))
        assert np.all(memory.free_at(t)[seen | no_robot])  # free at t_k, even next to U_k ...
        touching = (box_distances(box, u) == 0.0) & (old <= t)  # not remembered, its cube touching U_k's
        assert not np.any(memory.free_at(np.nextafter(t, np.inf))[touching])  # ... not an instant later
        certified += memory.free_at(t).sum()
    assert certified > 20  # the memory does certify something


def test_never_seen_voxels_stay_not_free():
    rng = np.random.default_rng(3)
    box = VoxelBox([0, 0, 0], [1.0, 1.0, 0.6], 0.1)
    memory = FreeSpaceMemory(box)
    assert memory.time is None and not memory.free_at(0.0).any()
    ever_seen = np.zeros(box.shape, bool)
    never = np.zeros(box.shape, bool)
    never[2:5, 3:7, 1:4] = True
    t = 0.0
    for _ in range(6):
        seen = (rng.random(box.shape) < 0.9) & ~never
        ever_seen |= seen
        memory.update(t, seen)
        for dt in (0.0, 1e-6, 0.1):
            assert not memory.free_at(t + dt)[~ever_seen].any()
        assert memory.free_at(t).any()
        t += 0.01


@pytest.mark.parametrize("t0", [100.0, 1.7e9])
def test_a_voxel_seen_with_clearance_r_stays_free_until_r_over_v_max(t0):
    """Everything seen at t0 except one voxel: a voxel whose cube lies r from the unseen voxel's cube (or from the
    outside of the box) stays free exactly while t < t0 + r / v_max; never beyond (at epoch times too, where the
    float sum rounds)."""
    box = VoxelBox([0, 0, 0], [0.6, 0.6, 0.6], 0.05)  # 12^3
    s, v_max = box.voxel, config.FREESPACE_V_MAX
    seen = np.ones(box.shape, bool)
    seen[4, 6, 5] = False
    memory = FreeSpaceMemory(box)
    memory.update(t0, seen)
    idx = np.indices(box.shape)
    n = np.array(box.shape)[:, None, None, None]
    to_outside = np.minimum(idx, n - 1 - idx).min(axis=0)  # voxels between the cube and the box's face
    gaps = np.maximum(np.abs(idx - np.array([4, 6, 5])[:, None, None, None]) - 1, 0)
    to_hole = np.sqrt((gaps ** 2).sum(axis=0))
    r = s * np.minimum(to_outside, to_hole)
    until = r / v_max  # seconds after t0
    arrival = memory.arrival
    assert np.all(arrival - t0 <= until)  # exact subtraction: arrival and t0 are close
    np.testing.assert_allclose(arrival - t0, until, rtol=0, atol=1e-9 if t0 < 1e6 else 1e-6)
    assert until.max() > 0.05
    if t0 < 1e6:
        for dt in (0.0, 0.01, 0.02, 0.04, 0.06):
            far = np.abs(until - dt) > 1e-9
            np.testing.assert_array_equal(memory.free_at(t0 + dt)[far], (until > dt)[far])


def test_a_missing_update_lets_possibly_occupied_space_grow_at_v_max():
    """After one update, frames that see nothing: the free set at each time lies between what the first update
    promised (no faster than v_max, counting its voxel diagonal) and the exact growth of U_0 at v_max (no slower)."""
    rng = np.random.default_rng(11)
    box = VoxelBox([0, 0, 0], [1.0, 0.9, 0.7], 0.1)
    v_max = 0.5
    memory = FreeSpaceMemory(box, v_max=v_max)
    seen = np.ones(box.shape, bool)
    seen[rng.random(box.shape) < 0.03] = False
    memory.update(1.0, seen)
    first = memory.arrival.copy()
    u0 = ~seen
    exact = 1.0 + box_distances(box, u0) / v_max
    nothing = np.zeros(box.shape, bool)
    t = 1.0
    for _ in range(8):
        t += rng.uniform(0.002, 0.02)
        memory.update(t, nothing)
        assert np.all(memory.arrival >= first)  # nothing seen: nothing forgotten
        for dt in (0.0, 0.005, 0.02):
            free = memory.free_at(t + dt)
            assert not np.any((first > t + dt) & ~free)
            assert not np.any(free & ~(exact > t + dt))
    assert memory.free_at(t).any() and not memory.free_at(t + 1.0).any()


def test_the_robot_is_no_place_for_a_person():
    box = VoxelBox([0, 0, 0], [0.8, 0.8, 0.8], 0.1)
    memory = FreeSpaceMemory(box, v_max=1.0)
    seen = np.zeros(box.shape, bool)
    seen[2:6, 2:6, 2:6] = True
    robot = np.zeros(box.shape, bool)
    robot[3:5, 3:5, 3:5] = True
    memory.update(0.0, seen & ~robot, robot)
    with_robot = memory.arrival.copy()
    other = FreeSpaceMemory(box, v_max=1.0)
    other.update(0.0, seen & ~robot)
    assert np.all(with_robot >= other.arrival) and np.any(with_robot > other.arrival)
    assert not other.free_at(0.0)[3:5, 3:5, 3:5].any()


def test_memory_refuses_bad_arguments():
    box = VoxelBox([0, 0, 0], [0.3, 0.3, 0.3], 0.1)
    for v_max in (0.0, -1.0, np.inf, np.nan, "2"):
        with pytest.raises(dg.InputError, match="v_max") as info:
            FreeSpaceMemory(box, v_max=v_max)
        assert info.value.field == "v_max"
    with pytest.raises(dg.InputError, match="box"):
        FreeSpaceMemory("box")
    memory = FreeSpaceMemory(box)
    ok = np.ones(box.shape, bool)
    cases = [((np.nan, ok), "t"), ((np.inf, ok), "t"), (("1", ok), "t"), ((1.0, ok.astype(np.uint8)), "seen"),
             ((1.0, ok[:2]), "seen"), ((1.0, ok.tolist()), "seen"), ((1.0, ok, ok[:, :2]), "robot"),
             ((1.0, ok, np.zeros(box.shape)), "robot")]
    for args, field in cases:
        with pytest.raises(dg.InputError) as info:
            memory.update(*args)
        assert info.value.field == field, (args[:1], str(info.value))
    assert memory.time is None  # nothing was taken in
    memory.update(2.0, ok)
    memory.update(2.0, ok)  # the same time again is fine
    for call in (lambda: memory.update(1.9, ok), lambda: memory.free_at(1.5), lambda: memory.free_at(np.nan)):
        with pytest.raises(dg.InputError) as info:
            call()
        assert info.value.field == "t"
    assert memory.time == 2.0
    assert memory.nbytes == box.size * 16
    with pytest.raises(ValueError):
        memory.arrival[0, 0, 0] = 1e9  # read-only


KERNELS_AS_PYTHON = r"""
import numpy as np
import depthguard as dg
from depthguard.freespace import FreeSpaceMemory, VoxelBox, seen_free_voxels, squared_distance_transform
box = VoxelBox([-0.2, -0.2, 0.7], [0.2, 0.2, 1.0], 0.1)
camera = dg.PinholeCamera("c", 16, 12, 12.0, 12.0, 7.5, 5.5, np.eye(4))
free = np.full((12, 16), 1.05, np.float32)
free[3:5, 4:9] = 0.8
seen = seen_free_voxels(box, [camera], [free], pad=1)
memory = FreeSpaceMemory(box)
memory.update(0.0, seen)
memory.update(0.01, seen, np.zeros(box.shape, bool))
sites = np.zeros((4, 3, 5), bool)
sites[1, 2, 3] = True
print(repr((seen.tolist(), memory.arrival.tolist(), squared_distance_transform(sites).tolist())))
"""


def test_kernels_run_as_python_with_jit_disabled():
    """The kernels' bodies run as plain Python (NUMBA_DISABLE_JIT=1, for coverage) and give what the compiled ones
    give."""
    runs = []
    for disable in ("1", "0"):
        env = dict(os.environ, NUMBA_DISABLE_JIT=disable)
        done = subprocess.run([sys.executable, "-c", KERNELS_AS_PYTHON], capture_output=True, text=True,
                              timeout=300, env=env)
        assert done.returncode == 0, done.stderr[-3000:]
        runs.append(done.stdout)
    assert runs[0] == runs[1]
    seen = eval(runs[0])[0]
    assert any(v for plane in seen for row in plane for v in row) and not all(
        v for plane in seen for row in plane for v in row)


def test_surface_voxels_hold_the_measured_points_and_forget_makes_them_possibly_occupied():
    """The monitor's hardening: the voxels that hold a surface a camera measures now (``surface_voxels``, each valid
    pixel's measured point on its centre ray, the robot's pixels and holes left out) are forgotten (arrival -inf),
    so the next update counts them where a person may be even when the memory remembered them free."""
    from depthguard.freespace._near import surface_voxels

    camera = dg.PinholeCamera("c", 32, 24, 26.0, 26.0, 15.5, 11.5, look_at([0.0, -0.4, 2.0], [0.0, 0.0, 0.0]),
                              depth_range=(0.1, 5.0), noise=dg.NoiseModel.none())
    box = VoxelBox([-1.0, -1.0, -0.2], [1.0, 1.0, 1.8], 0.1)
    scene = [Box.from_bounds([-0.3, -0.3, 0.4], [0.3, 0.3, 0.6])]  # a slab whose top, z = 0.6, the camera sees
    depth = dg.depth_image(render_depth(camera, scene), camera)
    occupancy = dg.prepare_depth(depth, camera)
    marked = np.zeros(box.shape, dtype=bool)
    surface_voxels(box, camera, depth, occupancy, marked)
    # The judge: every valid pixel's measured point, voxel by voxel.
    expected = np.zeros(box.shape, dtype=bool)
    for v in range(camera.height):
        for u in range(camera.width):
            d = float(depth.data[v, u])
            if d > 0:
                p = camera.T_world_camera @ np.array([(u - camera.cx) / camera.fx * d, (v - camera.cy) / camera.fy * d,
                                                     d, 1.0])
                i, j, k = np.floor((p[:3] - box.lo) / box.voxel).astype(int)
                if 0 <= i < box.shape[0] and 0 <= j < box.shape[1] and 0 <= k < box.shape[2]:
                    expected[i, j, k] = True
    assert marked.any() and np.array_equal(marked, expected)
    assert set(np.unique(np.nonzero(marked)[2])) <= {6, 7, 8}  # the slab, z 0.4-0.6 m: voxel layers 6-8
    # Remembered free everywhere, then forgotten where a surface is seen now.
    memory = FreeSpaceMemory(box, v_max=2.0)
    memory.update(0.0, np.ones(box.shape, dtype=bool))
    assert memory.free_at(0.0)[marked].all()
    memory.forget(marked)
    assert not memory.free_at(0.0)[marked].any() and memory.free_at(0.0)[~marked].any()
    memory.update(0.01, np.zeros(box.shape, dtype=bool))
    assert not memory.free_at(0.01)[marked].any()


def two_cameras_see_a_capsule():
    """(p0, p1, radius, cameras, free images): a capsule (the robot) 0.5-0.6 m above a floor, seen by two 320x240
    cameras."""
    from depthguard.scenes import Capsule

    p0, p1, radius = np.array([-0.25, 0.0, 0.5]), np.array([0.25, 0.05, 0.6]), 0.07
    scene = [Box.from_bounds([-3, -3, -0.05], [3, 3, 0.0]), Capsule(tuple(p0), tuple(p1), radius)]
    cameras, images = [], []
    for n, eye in enumerate(([1.6, -1.4, 1.8], [1.5, 1.6, 1.6])):
        camera = dg.PinholeCamera(f"c{n}", 320, 240, 260.0, 260.0, 159.5, 119.5, look_at(eye, [0.0, 0.0, 0.5]),
                                  depth_range=(0.4, 6.0))
        cameras.append(camera)
        images.append(free_image(dg.depth_image(render_depth(camera, scene), camera), camera))
    return p0, p1, radius, cameras, images


def test_mixed_voxels_combine_cameras_and_the_robot_within_a_voxel():
    """design §8a: a voxel counts free when every point of it is seen free by some camera or lies inside the robot.
    Two cameras see a floor and a rendered capsule (the robot; its inner capsule 2 mm thinner); the voxels next to it
    that neither camera sees whole and that are not wholly inside it are judged piece by piece
    (``mixed_voxels``). Judge: every point of a 9^3 lattice in each voxel that passes is inside the inner capsule or
    seen free by a camera on the pixel it projects to (free there at least to its depth plus the margin). Some pass
    only by the two cameras together; none that holds the robot's surface passes (the layer the margins leave between
    the seen-free space and the robot's inside is neither); a voxel in two inner capsules passes by the robot alone."""
    from depthguard.freespace import CameraViews
    from depthguard.freespace._memory import mixed_voxels

    p0, p1, radius, cameras, images = two_cameras_see_a_capsule()
    margin = 0.005
    box = VoxelBox([-0.4, -0.2, 0.35], [0.4, 0.24, 0.76], 0.04)
    seen = seen_free_voxels(box, cameras, images, margin=margin, pad=0)
    inner = np.array([[*p0, *p1, radius - 0.002]])
    idx = np.indices(box.shape).reshape(3, -1).T

    def inside(points):
        axis = p1 - p0
        s = np.clip((points - p0) @ axis / (axis @ axis), 0.0, 1.0)
        return np.linalg.norm(points - (p0 + s[:, None] * axis), axis=1) < radius - 0.002

    lattice = np.stack(np.meshgrid(*[np.linspace(0.0, 1.0, 9)] * 3, indexing="ij"), -1).reshape(-1, 3)
    whole_inside = np.array([inside(box.lo + (v + lattice) * box.voxel).all() for v in idx]).reshape(box.shape)
    candidates = np.argwhere(~seen & ~whole_inside)
    views = CameraViews.of(cameras, images, margin, 0)

    def seen_by(points, c):
        camera, free = cameras[c], images[c]
        local = camera.world_to_camera(points)
        u = np.floor(camera.fx * local[:, 0] / local[:, 2] + camera.cx + 0.5).astype(int)
        v = np.floor(camera.fy * local[:, 1] / local[:, 2] + camera.cy + 0.5).astype(int)
        ok = (u >= 0) & (u < camera.width) & (v >= 0) & (v < camera.height) & (local[:, 2] > 0.4)
        out = np.zeros(len(points), bool)
        out[ok] = free[v[ok], u[ok]] >= local[ok, 2] + margin - 1e-6
        return out

    passed = {}
    for name, capsules, levels in (("both", inner, 2), ("cameras", np.zeros((0, 7)), 2), ("coarse", inner, 1)):
        passed[name] = mixed_voxels(box, views, candidates, capsules, levels)
    kinds = {"robot and cameras": 0, "two cameras": 0}
    for m in np.flatnonzero(passed["both"]):
        points = box.lo + (candidates[m] + lattice) * box.voxel
        by = [seen_by(points, c) for c in range(2)]
        robot = inside(points)
        assert np.all(robot | by[0] | by[1]), f"voxel {candidates[m]} passed with a point neither seen nor inside"
        if robot.any():
            kinds["robot and cameras"] += 1
        elif by[0].any() and by[1].any() and not (by[0].all() or by[1].all()):
            kinds["two cameras"] += 1
    print(f"\n{len(candidates)} voxels neither seen whole nor inside: {passed['both'].sum()} pass in 1 cm pieces "
          f"({kinds}), {passed['cameras'].sum()} without the robot, {passed['coarse'].sum()} in 2 cm pieces")
    assert kinds["two cameras"] > 0
    assert not np.any(passed["cameras"] & ~passed["both"])  # the robot only adds
    assert passed["coarse"].sum() < passed["both"].sum()
    # No voxel that holds the robot's surface passes with these cameras: every such voxel has a piece across the
    # layer between what a camera sees free (its measurement less the margins) and the inner capsule.
    assert kinds["robot and cameras"] == 0
    # The robot's pieces: a voxel half in each of two inner capsules (neither holds it whole) passes with no camera.
    blind = CameraViews.of([], [], 0.0, 0)
    one = VoxelBox([0.0, 0.0, 0.0], [0.04, 0.04, 0.04], 0.04)
    halves = np.array([[-0.1, 0.02, 0.02, 0.0, 0.02, 0.02, 0.035], [0.04, 0.02, 0.02, 0.14, 0.02, 0.02, 0.035]])
    assert mixed_voxels(one, blind, np.zeros((1, 3), int), halves, 1)[0]
    assert not mixed_voxels(one, blind, np.zeros((1, 3), int), halves[:1], 2)[0]
    assert not mixed_voxels(one, blind, np.zeros((1, 3), int), halves, 0)[0]


def test_the_voxels_next_to_the_robot_are_looked_for_in_its_sub_box_only_with_the_same_answer():
    """``remember_frames`` with ``near_region`` (the sub-box ``robot_voxels`` returns) takes the same voxels next to
    the robot as with the whole box searched: the same voxels seen free and the same arrival times, over a box much
    larger than the robot's sub-box (as a cell's is)."""
    from depthguard.freespace import remember_frames, robot_inside_voxels, robot_voxels

    p0, p1, radius, cameras, images = two_cameras_see_a_capsule()
    box = VoxelBox([-1.2, -1.0, 0.0], [1.2, 1.0, 1.4], 0.04)
    inner = np.array([[*p0, *p1, radius - 0.002]])
    robot = robot_inside_voxels(box, [inner])
    near = np.zeros(box.shape, dtype=bool)
    region = robot_voxels(box, np.array([[*p0, *p1, radius]]), box.voxel * math.sqrt(3.0), near)
    sub = np.zeros(box.shape, dtype=bool)
    sub[region] = True
    assert near.any() and not np.any(near & ~sub)
    assert sub.sum() * 20 < sub.size  # the robot's sub-box is a small part of the box
    answers = []
    for searched in (None, region):
        memory = FreeSpaceMemory(box)
        seen = remember_frames(memory, 1.0, cameras, images, [], margin=0.005, pad=0, robot=robot, near_robot=near,
                               inner=inner, near_region=searched)
        answers.append((seen, memory.arrival.copy()))
    np.testing.assert_array_equal(answers[0][0], answers[1][0])
    np.testing.assert_array_equal(answers[0][1], answers[1][1])
    by_pieces = answers[0][0] & near & ~seen_free_voxels(box, cameras, images, margin=0.005, pad=0) & ~robot
    assert by_pieces.any()  # some voxels next to the robot were certified piece by piece, so the search mattered
    for bad in ((slice(0, 2),) * 2, (slice(0, 4, 2),) * 3, [slice(None)] * 3, 5):
        with pytest.raises(dg.InputError, match="near_region") as info:
            remember_frames(FreeSpaceMemory(box), 2.0, cameras, images, [], margin=0.005, pad=0, robot=robot,
                            near_robot=near, inner=inner, near_region=bad)
        assert info.value.field == "near_region"
