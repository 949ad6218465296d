"""Real data: the slambook2 room's views 3, 4 and 5 as a rig of three depth cameras (issue 4, item 7).

The poses of the views are approximate (the rig's calibration error). These tests check the experiment's figures
against what the data and the rule imply, not against figures copied from a run:

- the rig and its frames against an independent reading of the files (the PGM images parsed here, the poses turned
  into rotations by scipy);
- the reprojection differences against a direct NumPy computation (own pinhole projection), and a view against
  itself (every difference 0);
- the chosen fusion margin against its definition (the percentile of the see-past excess, recomputed from the
  direct differences) and what it promises (it covers that share of the same-surface pixels);
- what the depth grid's fusion clears, against the rule (design §8: a cell is free only if some secondary
  camera measured beyond its far depth plus its noise margin and the fusion margin, on every pixel of its grown
  footprint), evaluated here on the raw images: a point is never cleared unless a camera saw past it (necessary),
  and always cleared where a camera clearly saw past everything near it and the principal has no surface there
  (sufficient); surfaces that one secondary camera sees stay occupied within the workspace at the chosen margin;
  a larger margin never clears more.

Points are subsampled (a few hundred per camera and kind) to keep the file at a few seconds.
"""

import functools
import math
import os

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from depthguard_lab.experiments import real_room as rr

#: Surface points per secondary camera and kind (gray area, principal hole): 4 x 600 points; free-space points of
#: the principal per kind (gray area, holes): 2 x 600.
SAMPLES = 600

#: The views' intrinsics, pixels, as the source's own program states them (slambook2 ch5/rgbd/joinMap.cpp), and its
#: depth unit: millimetres.
FX, FY, CX, CY = 518.0, 519.0, 325.5, 253.5
WIDTH, HEIGHT = 640, 480
DEPTH_UNIT = 0.001

#: Every grid cell within rr.CLEARED (0.02 m) of a point lies within REACH of it: a cell is 0.01 m deep and one
#: principal pixel wide (under 1.2 cm up to SUFFICIENT_DEPTH), so its diagonal is under 0.02 m: 0.02 + 0.02.
REACH = 0.04
#: Points at most this deep in the principal (metres) are judged by the sufficient rule (REACH holds there).
SUFFICIENT_DEPTH = 6.0
#: Float32 depths in the library against float64 here, metres.
EPS = 1e-5


# ------------------------------------------------------------------------------------- the files, read here

def read_pgm(path) -> np.ndarray:
    """(h, w) uint16 of a binary 16-bit PGM (P5, big-endian), parsed here."""
    raw = open(path, "rb").read()
    fields, pos = [], 0
    while len(fields) < 4:
        while raw[pos:pos + 1].isspace():
            pos += 1
        start = pos
        while not raw[pos:pos + 1].isspace():
            pos += 1
        fields.append(raw[start:pos])
    width, height, maxval = (int(f) for f in fields[1:])
    assert fields[0] == b"P5" and maxval > 255
    return np.frombuffer(raw[pos + 1:pos + 1 + 2 * width * height], dtype=">u2").reshape(height, width)


@functools.lru_cache(maxsize=None)
def raw_views(folder: str):
    """view -> ((h, w) float64 metres, NaN where no measurement; (4, 4) T_world_camera), from the files: pose.txt
    lines are ``tx ty tz qx qy qz qw``, camera-to-world (scipy's quaternion order is the same, scalar last)."""
    rows = np.loadtxt(os.path.join(folder, "pose.txt"))
    views = {}
    for view in rr.VIEWS:
        depth = read_pgm(os.path.join(folder, "depth", f"{view}.pgm")).astype(np.float64) * DEPTH_UNIT
        depth[depth == 0] = np.nan
        T_world_camera = np.eye(4)
        T_world_camera[:3, :3] = Rotation.from_quat(rows[view - 1, 3:]).as_matrix()
        T_world_camera[:3, 3] = rows[view - 1, :3]
        views[view] = (depth, T_world_camera)
    return views


def project(T_world_camera, points_world):
    """Nearest pixels (col, row: (n,) int, 0 where outside), optical z (n,) and inside (n,) bool of world points."""
    T_camera_world = np.linalg.inv(T_world_camera)
    q = points_world @ T_camera_world[:3, :3].T + T_camera_world[:3, 3]
    z = q[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        col, row = np.round(FX * q[:, 0] / z + CX), np.round(FY * q[:, 1] / z + CY)
        inside = (z > 0) & (col >= 0) & (col <= WIDTH - 1) & (row >= 0) & (row <= HEIGHT - 1)
    return np.where(inside, col, 0).astype(int), np.where(inside, row, 0).astype(int), z, inside


def back_project(depth, T_world_camera):
    """Every measured pixel of ``depth`` as a world point: (n, 3)."""
    row, col = np.nonzero(np.isfinite(depth))
    z = depth[row, col]
    q = np.stack([(col - CX) / FX * z, (row - CY) / FY * z, z], axis=1)
    return q @ T_world_camera[:3, :3].T + T_world_camera[:3, 3]


def direct_reprojection(folder, source: int, target: int):
    """(diff, depth) as rr.reprojection_differences defines them, computed here."""
    views = raw_views(folder)
    (depth_s, T_s), (depth_t, T_t) = views[source], views[target]
    col, row, z, inside = project(T_t, back_project(depth_s, T_s))
    measured = depth_t[row, col]
    both = inside & np.isfinite(measured)
    return measured[both] - z[both], z[both]


def noise_margin(noise, d):
    """m(d) = max(k (a + b d + c d^2), 0) metres (docs/design.md, "Noise margin"), from the model's coefficients."""
    return np.maximum(noise.k * (noise.a + noise.b * d + noise.c * d * d), 0.0)


# ------------------------------------------------------------------------------------- the rule, evaluated here

def seen_past(folder, view: int, noise, points_world) -> np.ndarray:
    """(n,) metres: how far beyond each point ``view`` measured on its nearest pixel, less the noise margin
    (d - m(d) - z); -inf where the point is outside its image or the pixel has no measurement."""
    depth, T = raw_views(folder)[view]
    col, row, z, inside = project(T, points_world)
    d = np.where(inside, depth[row, col], np.nan)
    excess = d - noise_margin(noise, d) - z
    return np.where(np.isfinite(excess), excess, -np.inf)


def _windows(image, col, row, radius):
    """Per point, the pixels of ``image`` within ``radius`` (n,) of (col, row); None where the window leaves it."""
    for c, r, k in zip(col, row, radius):
        if c - k < 0 or r - k < 0 or c + k >= image.shape[1] or r + k >= image.shape[0]:
            yield None
        else:
            yield image[r - k:r + k + 1, c - k:c + k + 1]


@functools.lru_cache(maxsize=None)
def clear_by(folder, noise_name: str, which: str, pixels: int = 1) -> np.ndarray:
    """(n,) metres: the largest fusion margin at which, by the rule, the fused distance of each sample point
    (``which``: "surface" or "free", as :func:`_load` draws them) must exceed rr.CLEARED; -inf where the rule
    promises nothing. Sufficient conditions, evaluated on the raw images:

    Every cell within CLEARED of the point lies within REACH of it. Such a cell is free if (1) it is not a certain
    cell of the principal: no principal pixel near the point measured a surface within REACH (plus a cell and the
    noise margin) of its depth, and the point lies well inside the principal's image, depth range and grid; and (2)
    some secondary camera does not confirm it: every pixel of its footprint, grown by ``pixels``, measured d with
    d - m(d) at least its far depth (< the point's depth there + REACH) plus the fusion margin. The footprint of
    everything within REACH lies within f REACH / (z - REACH) + 1/2 pixels of the point's nearest pixel."""
    noise = rr.NOISE_MODELS[noise_name]
    rig, _, grid, surface, free = _load(folder, noise_name)
    points_world = (surface if which == "surface" else free).points_world
    views = raw_views(folder)
    depth_p, T_p = views[rr.PRINCIPAL]
    col, row, z, inside = project(T_p, points_world)
    ok = inside & (z < SUFFICIENT_DEPTH) & (z - REACH > max(rig.cameras[rig.principal].depth_range[0], grid.d_min))
    radius = np.ceil(FY * REACH / np.maximum(z - REACH, 1e-3) + 0.5).astype(int)
    for i, window in enumerate(_windows(depth_p, col, row, radius)):
        if window is None:
            ok[i] = False
            continue
        d = window[np.isfinite(window)]
        near = (d - noise_margin(noise, d) < z[i] + REACH + 0.01) & (d + 0.01 > z[i] - REACH - 0.01)
        ok[i] &= not near.any()
    best = np.full(len(ok), -np.inf)
    for view in rr.VIEWS:
        if view == rr.PRINCIPAL:
            continue
        depth, T = views[view]
        col, row, z, inside = project(T, points_world)
        radius = np.ceil(FY * REACH / np.maximum(z - REACH, 1e-3) + 0.5).astype(int) + pixels
        for i, window in enumerate(_windows(depth, col, row, radius)):
            if ok[i] and inside[i] and window is not None and np.isfinite(window).all():
                best[i] = max(best[i], (window - noise_margin(noise, window)).min() - z[i] - REACH)
    return np.where(ok, best, -np.inf)


# ------------------------------------------------------------------------------------------------- the tests

@functools.lru_cache(maxsize=None)
def _load(folder: str, noise: str):
    rig, frames = rr.slambook_rig(folder, noise=rr.NOISE_MODELS[noise])
    grid = rr.depth_grid(rig)
    rng = np.random.default_rng(7)
    surface = rr.secondary_surface_points(rig, frames, SAMPLES, rng)
    free = rr.free_space_points(rig, frames, SAMPLES, rng)
    return rig, frames, grid, surface, free


@pytest.fixture
def folder(real_data):
    path = os.path.join(real_data, "slambook2-room")
    if not os.path.isfile(os.path.join(path, "pose.txt")):
        pytest.skip(f"slambook2-room data not found at {path}")
    return path


@functools.lru_cache(maxsize=None)
def _fused(folder, noise, margin, which="surface"):
    rig, frames, grid, surface, free = _load(folder, noise)
    points = (surface if which == "surface" else free).points_world
    return rr.fused_query(rig, frames, grid, points, margin)


def _cleared(folder, noise, margin):
    return _fused(folder, noise, margin) > rr.CLEARED, _load(folder, noise)[3]


def _surface_of(surface, folder):
    """(n, 3): the measured surface point behind each surface sample (rr.SURFACE_OFFSET further from the camera
    that measured it)."""
    eyes = {rr.camera_name(v): raw_views(folder)[v][1][:3, 3] for v in rr.VIEWS}
    eye = np.array([eyes[name] for name in surface.seen_by])
    away = surface.points_world - eye
    return surface.points_world + rr.SURFACE_OFFSET * away / np.linalg.norm(away, axis=1, keepdims=True)


def _others_seen_past(folder, noise, surface):
    """(n,) metres: how far the secondary camera that did not measure each surface sample saw past its surface
    (:func:`seen_past` of the surface point), the largest over such cameras."""
    behind = _surface_of(surface, folder)
    best = np.full(len(surface), -np.inf)
    for view in rr.VIEWS:
        name = rr.camera_name(view)
        if name == rr.camera_name(rr.PRINCIPAL):
            continue
        other = surface.seen_by != name
        best = np.where(other, np.maximum(best, seen_past(folder, view, rr.NOISE_MODELS[noise], behind)), best)
    return best


def test_rig_loads(folder):
    rig, frames, grid, _, _ = _load(folder, "kinect")
    views = raw_views(folder)
    assert list(rig.cameras) == ["view3", "view4", "view5"] and rig.principal == "view3"
    assert grid.secondaries == ("view4", "view5") and grid.d_max >= rr.GRID_D_MAX - 1e-9
    for view, (depth, T_world_camera) in views.items():
        camera = rig.cameras[rr.camera_name(view)]
        assert (camera.fx, camera.fy, camera.cx, camera.cy, camera.width, camera.height) == (FX, FY, CX, CY, WIDTH,
                                                                                            HEIGHT)
        np.testing.assert_allclose(camera.T_world_camera, T_world_camera, rtol=0, atol=1e-9)
        frame = frames[camera.name]
        assert frame.data.dtype == np.uint16 and frame.data.shape == depth.shape
        np.testing.assert_array_equal(np.isnan(frame.metres()), np.isnan(depth))
        np.testing.assert_allclose(frame.metres(), depth, rtol=1e-6, equal_nan=True)
        assert frame.valid_fraction() == np.isfinite(depth).mean()
        # Every measurement lies in the sensor's declared range (the rig would call the rest no measurement).
        assert camera.depth_range[0] <= np.nanmin(depth) and np.nanmax(depth) <= camera.depth_range[1]
    # Views 4 and 5 stand in front of view 3 (mostly along its optical axis), looking about the same way.
    T_3_world = np.linalg.inv(views[3][1])
    for view in (4, 5):
        position = T_3_world[:3, :3] @ views[view][1][:3, 3] + T_3_world[:3, 3]
        assert position[2] > np.hypot(position[0], position[1]) > 0
        axis_angle = math.degrees(math.acos(views[3][1][:3, 2] @ views[view][1][:3, 2]))
        assert axis_angle < 30.0


def test_poses_file_is_read_as_camera_to_world(folder):
    poses = rr.read_poses(os.path.join(folder, "pose.txt"))
    assert sorted(poses) == [1, 2, 3, 4, 5]
    quaternions = np.loadtxt(os.path.join(folder, "pose.txt"))[:, 3:]
    np.testing.assert_allclose(np.linalg.norm(quaternions, axis=1), 1.0, atol=1e-6)  # unit: read in the right order
    # A point straight ahead of view 3 lands at its optical axis in the world: R * (0, 0, 1) + t.
    rig, _, _, _, _ = _load(folder, "kinect")
    camera = rig.cameras["view3"]
    np.testing.assert_allclose(camera.camera_to_world([[0.0, 0.0, 1.0]])[0],
                               poses[3][:3, 2] + poses[3][:3, 3], atol=1e-12)


def test_reprojection_differences_match_a_direct_computation(folder):
    rig, frames, _, _, _ = _load(folder, "kinect")
    agree = {}
    for source, target in ((3, 4), (4, 5), (5, 4), (3, 3)):
        diff, depth = rr.reprojection_differences(rig, frames, rr.camera_name(source), rr.camera_name(target))
        expected, expected_depth = direct_reprojection(folder, source, target)
        # The same pixels in the same order (source's row-major order), the same numbers up to float32 depths.
        assert diff.shape == expected.shape and diff.size > 100_000
        np.testing.assert_allclose(depth, expected_depth, rtol=1e-6)
        np.testing.assert_allclose(diff, expected, rtol=0, atol=EPS)
        agree[source, target] = np.mean(np.abs(diff) < rr.AGREEMENT)
        if source == target:  # a view against itself: every measured pixel, on itself
            assert diff.size == np.isfinite(raw_views(folder)[source][0]).sum()
            assert np.abs(diff).max() < EPS
            continue
        assert agree[source, target] == pytest.approx(np.mean(np.abs(expected) < rr.AGREEMENT), abs=1e-4)
        # A calibrated rig: on the same surface (|diff| below the occlusion cut) the differences are centred on 0
        # within the sensor's noise (one sigma, m(d) / k, at the median depth).
        same = np.abs(expected) < rr.OCCLUSION
        noise = rr.NOISE_MODELS["kinect"]
        assert abs(np.median(expected[same])) < noise_margin(noise, np.median(expected_depth)) / noise.k
    # Views 4 and 5 stand 4 times closer together than 3 and 4: less parallax, fewer occlusions, better agreement.
    assert agree[4, 5] > agree[3, 4]


def test_chosen_margin_covers_the_calibration_error(folder):
    rig, frames, _, _, _ = _load(folder, "kinect")
    need, margin = rr.choose_margin(rig, frames)
    noise = rr.NOISE_MODELS["kinect"]
    excess = []
    for source, target in ((4, 5), (5, 4)):  # the secondary cameras, the only ones that clear cells
        diff, depth = direct_reprojection(folder, source, target)
        same = (np.abs(diff) < rr.OCCLUSION) & (depth < rr.WORKSPACE_DEPTH)
        excess.append(diff[same] - noise_margin(noise, depth[same]))
    excess = np.concatenate(excess)
    assert need == pytest.approx(np.percentile(excess, rr.CHOICE_PERCENTILE), abs=EPS)
    assert margin == min(m for m in rr.MARGINS if m >= need)
    # What the margin promises: one secondary camera sees past the other's surface by more than its noise margin plus
    # the fusion margin on no more than 1 - CHOICE_PERCENTILE of the same-surface pixels in the workspace; and the
    # poses are approximate, so without a fusion margin more do.
    assert np.mean(excess > margin) <= 1 - rr.CHOICE_PERCENTILE / 100
    assert np.mean(excess > 0) > 1 - rr.CHOICE_PERCENTILE / 100


def test_fusion_keeps_surfaces_one_secondary_camera_sees(folder):
    _, _, _, surface, _ = _load(folder, "kinect")
    assert len(surface) == 4 * SAMPLES
    # The experiment's "contested" (another secondary camera measured no more than CONTESTED_SLACK in front of the
    # point: it could clear it) is what the images say, and the other camera could clear many of them.
    nearer = np.full(len(surface), False)
    for view in (4, 5):
        other = surface.seen_by != rr.camera_name(view)
        nearer |= other & (seen_past(folder, view, rr.NOISE_MODELS["none"], surface.points_world)
                           >= -rr.CONTESTED_SLACK - EPS)
    np.testing.assert_array_equal(surface.contested, nearer)
    assert np.any(surface.contested & (surface.depth < rr.WORKSPACE_DEPTH))  # else the claim below proves nothing
    margin = rr.choose_margin(*_load(folder, "kinect")[:2])[1]
    cleared, _ = _cleared(folder, "kinect", margin)
    # The safety claim: no surface one secondary camera sees is cleared where a robot works.
    assert not np.any(cleared & (surface.depth < rr.WORKSPACE_DEPTH))
    # Beyond it, only where the other camera saw past the surface by its noise margin plus the fusion margin.
    assert np.all(_others_seen_past(folder, "kinect", surface)[cleared] >= margin - EPS)


@pytest.mark.parametrize("noise", ["none", "kinect"])
def test_fusion_clears_by_the_rule(folder, noise):
    """For every margin: a surface sample is cleared only if the secondary camera that did not measure it saw past its
    surface by the noise margin plus the fusion margin (its surface's cell is confirmed by the camera that measured
    it, so only the other can free it); a larger margin never clears more; and every sample (surface or the
    principal's free space) that a camera clearly saw past, with no principal surface near it, is cleared."""
    _, _, _, surface, free = _load(folder, noise)
    past = _others_seen_past(folder, noise, surface)
    previous = None
    judged = 0
    for margin in (0.0, 0.05, 0.1, 0.2):
        cleared = _fused(folder, noise, margin) > rr.CLEARED
        freed = _fused(folder, noise, margin, "free") > rr.CLEARED
        assert np.all(past[cleared] >= margin - EPS), margin
        if previous is not None:
            assert not np.any(cleared & ~previous[0]) and not np.any(freed & ~previous[1])  # monotone
        previous = cleared, freed
        for which, result in (("surface", cleared), ("free", freed)):
            must = clear_by(folder, noise, which) > margin + EPS
            assert np.all(result[must]), (which, margin, np.flatnonzero(must & ~result))
            judged += int(must.sum())
    assert judged > 0, "the sufficient rule judged no point: the test would prove nothing"


def test_margin_matters(folder):
    """Without a noise margin the fusion margin alone must cover the calibration error: at 0 the other secondary
    camera clears surfaces it sees past (the poses are approximate); a margin above the farthest any camera saw past
    a sampled surface clears none of them. With the Kinect noise margin, a larger fusion margin clears a subset."""
    _, _, _, surface, _ = _load(folder, "none")
    cleared, _ = _cleared(folder, "none", 0.0)
    assert cleared.any()
    above = float(_others_seen_past(folder, "none", surface).max()) + 0.01  # metres: occlusion edges see far past
    assert not np.any(_cleared(folder, "none", above)[0])
    cleared, _ = _cleared(folder, "kinect", 0.0)
    kept, _ = _cleared(folder, "kinect", 0.05)
    assert not np.any(kept & ~cleared)
