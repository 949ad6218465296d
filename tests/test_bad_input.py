"""The monitor under bad runtime input: invalid pixels, unseen points, stale or missing frames, malformed points.

Whatever means "could not see" must give the conservative answer (distance 0 or a smaller distance) and a flag,
never a silently optimistic one (design §3 and §11).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import depthguard as dg
from depthguard import Flag
from depthguard.scenes import Box, render_depth, scene_distance
from depthguard.transforms import look_at

Z_MIN = 0.3


@pytest.fixture(scope="module")
def camera():
    # 2 m above the floor looking straight down; optical x = world x, optical y = world -y, depth = 2 - world z
    return dg.PinholeCamera("top", 64, 48, 50.0, 50.0, 31.5, 23.5, look_at([0, 0, 2], [0, 0, 0], up=(0, 1, 0)),
                            depth_range=(Z_MIN, 4.0), noise=dg.NoiseModel.none())


@pytest.fixture(scope="module")
def rig(camera):
    return dg.Rig({"top": camera})


SCENE = [Box.from_bounds([-3, -3, -0.1], [3, 3, 0.0]), Box.from_bounds([-0.2, -0.2, 0.0], [0.2, 0.2, 0.3])]


@pytest.fixture(scope="module")
def clean(camera):
    depth = render_depth(camera, SCENE)
    assert (depth > 0).all()  # every pixel sees the floor or the box
    return depth


def pixel_of(camera, point_world):
    u, v, _ = camera.project(camera.world_to_camera([point_world]))
    return int(round(u[0])), int(round(v[0]))


def hole_frustum_distance(camera, point_world, pixels):
    """Exact distance from a point to the frusta of invalid pixels, occupied from the camera's minimum range on."""
    p = camera.world_to_camera([point_world])[0]
    tangents = np.array([[(u - 0.5 - camera.cx) / camera.fx, (u + 0.5 - camera.cx) / camera.fx,
                          (v - 0.5 - camera.cy) / camera.fy, (v + 0.5 - camera.cy) / camera.fy] for u, v in pixels])
    distance, _ = dg.frustum_distance(p, tangents, [camera.depth_range[0], math.inf])
    return distance.min()


# --------------------------------------------------------------------------------------------------------------------
# invalid pixels: NaN, inf, 0, negative


POINT = [0.3, 0.1, 0.5]  # beside and above the box


def _with_hole(clean, camera, values):
    """The clean image with a 3x3 hole of ``values`` 3 pixels to the right of POINT's pixel."""
    u, v = pixel_of(camera, POINT)
    depth = clean.copy()
    cols, rows = range(u + 3, u + 6), range(v - 1, v + 2)
    block = np.resize(np.asarray(values, np.float32), (3, 3))
    depth[rows.start:rows.stop, cols.start:cols.stop] = block
    return depth, [(c, r) for r in rows for c in cols]


@pytest.mark.parametrize("values", [[np.nan], [np.inf], [0.0], [-1.0], [np.nan, np.inf, 0.0, -np.inf, -2.0]],
                         ids=["nan", "inf", "zero", "negative", "mixed"])
def test_invalid_pixels_occupied_give_a_smaller_flagged_distance(rig, camera, clean, values):
    depth, hole = _with_hole(clean, camera, values)
    occupied = dg.DistanceMonitor(rig, aggregate="min").query({"top": depth}, [POINT])
    free = dg.DistanceMonitor(rig, aggregate="min", invalid="free").query({"top": depth}, [POINT])
    reference = dg.DistanceMonitor(rig, aggregate="min").query({"top": clean}, [POINT])
    to_hole = hole_frustum_distance(camera, POINT, hole)
    assert to_hole < reference.distance[0] - 0.01  # the hole's frusta pass nearer than anything seen
    # the fail-safe answer is the nearer of what is seen and the hole's frusta, exactly
    assert occupied.distance[0] == pytest.approx(min(free.distance[0], to_hole), abs=1e-9)
    assert occupied.distance[0] < reference.distance[0]
    assert Flag.INVALID_PIXELS_USED in occupied.flags[0]
    assert occupied.invalid_count[0] >= 1
    # ignoring the hole never brings anything nearer, and does not claim to have used it
    assert free.distance[0] >= reference.distance[0] - 1e-9
    assert Flag.INVALID_PIXELS_USED not in free.flags[0]


def test_invalid_uint16_zeros(rig, camera, clean):
    units = np.round(clean * 1000).astype(np.uint16)
    u, v = pixel_of(camera, POINT)
    units[v - 1:v + 2, u + 3:u + 6] = 0
    hole = [(c, r) for r in range(v - 1, v + 2) for c in range(u + 3, u + 6)]
    result = dg.DistanceMonitor(rig, aggregate="hybrid").query({"top": units}, [POINT])
    assert result.distance[0] == pytest.approx(hole_frustum_distance(camera, POINT, hole), abs=1e-9)
    assert Flag.INVALID_PIXELS_USED in result.flags[0]


def test_neighbors_policy_lies_between_occupied_and_the_clean_image(rig, camera, clean):
    depth, _ = _with_hole(clean, camera, [np.nan])
    occupied = dg.DistanceMonitor(rig, aggregate="min").query({"top": depth}, [POINT]).distance[0]
    filled = dg.DistanceMonitor(rig, aggregate="min", invalid="neighbors", hole_pixels=9).query(
        {"top": depth}, [POINT]).distance[0]
    unfilled = dg.DistanceMonitor(rig, aggregate="min", invalid="neighbors", hole_pixels=8).query(
        {"top": depth}, [POINT]).distance[0]
    reference = dg.DistanceMonitor(rig, aggregate="min").query({"top": clean}, [POINT]).distance[0]
    assert occupied < filled <= reference + 1e-9
    assert unfilled == pytest.approx(occupied, abs=1e-12)  # a hole larger than hole_pixels stays occupied


def test_holes_never_increase_distances(rig, camera, clean):
    rng = np.random.default_rng(42)
    depth = clean.copy()
    depth[rng.random(depth.shape) < 0.05] = np.nan
    points = np.column_stack([rng.uniform(-0.8, 0.8, 150), rng.uniform(-0.6, 0.6, 150), rng.uniform(0.05, 1.5, 150)])
    for aggregate in ("min", "hybrid"):
        with_holes = dg.DistanceMonitor(rig, aggregate=aggregate).query({"top": depth}, points).distance
        reference = dg.DistanceMonitor(rig, aggregate=aggregate).query({"top": clean}, points).distance
        assert np.all(with_holes <= reference + 1e-9)
        assert np.any(with_holes < reference - 1e-3)


def test_distances_never_exceed_the_true_distance(rig, clean):
    rng = np.random.default_rng(7)
    points = np.column_stack([rng.uniform(-0.8, 0.8, 300), rng.uniform(-0.6, 0.6, 300), rng.uniform(0.0, 1.6, 300)])
    truth = scene_distance(SCENE, points)
    for aggregate in ("min", "hybrid"):
        result = dg.DistanceMonitor(rig, rho=0.4, aggregate=aggregate).query({"top": clean}, points)
        near = np.isfinite(result.distance)
        assert near.sum() > 100 and (~near).sum() >= 3
        assert np.all(result.distance[near] <= truth[near] + 1e-6)
        # "nothing within rho" (inf) only when the truth agrees
        assert np.all(truth[~near] >= 0.4 - 1e-6)


@pytest.mark.parametrize("image", ["nan", "zero float", "zero uint16", "beyond range"])
def test_all_invalid_image_puts_every_point_in_view_inside(rig, camera, image):
    depth = {"nan": np.full(camera.shape, np.nan, np.float32), "zero float": np.zeros(camera.shape, np.float32),
             "zero uint16": np.zeros(camera.shape, np.uint16),
             "beyond range": np.full(camera.shape, 9.0, np.float32)}[image]
    points = [[0.0, 0.0, 1.0], [0.5, -0.3, 0.2], [0.1, 0.1, 1.6]]  # in view, beyond the minimum range
    for aggregate in ("min", "mean", "hybrid"):
        result = dg.DistanceMonitor(rig, aggregate=aggregate).query({"top": depth}, points)
        np.testing.assert_array_equal(result.distance, 0.0)
        np.testing.assert_array_equal(result.direction, 0.0)
        for flags in result.flags:
            assert Flag.INVALID_PIXELS_USED in flags and Flag.INSIDE_OBSTACLE in flags


# --------------------------------------------------------------------------------------------------------------------
# space the camera does not see


UNSEEN = {
    "behind the camera": [0.0, 0.0, 2.5],
    "beside the view": [3.0, 0.0, 0.5],
    "nearer than the minimum range": [0.0, 0.0, 2.0 - Z_MIN / 2],
    "beyond the maximum range": [0.0, 0.0, -2.5],
    "at the optical centre": [0.0, 0.0, 2.0],
}


@pytest.mark.parametrize("where", UNSEEN)
def test_unseen_point_is_flagged_and_zero(rig, clean, where):
    point = UNSEEN[where]
    for aggregate in ("min", "mean", "hybrid"):
        result = dg.DistanceMonitor(rig, aggregate=aggregate).query({"top": clean}, [point])
        assert result.distance[0] == 0.0
        assert Flag.REGION_OUTSIDE_VIEW in result.flags[0]
    permissive = dg.DistanceMonitor(rig, unseen="free").query({"top": clean}, [point])
    assert Flag.REGION_OUTSIDE_VIEW in permissive.flags[0]  # flagged either way


def test_region_leaving_the_view_is_bounded_by_the_view_edge(rig, camera, clean):
    point = [0.8, 0.0, 0.5]  # depth 1.5, x/z = 0.53 < 0.64: in view, 0.135 m from its side
    edge = (0.64 * 1.5 - 0.8) / math.hypot(1.0, 0.64)  # the plane x = 0.64 z through the image's edge
    result = dg.DistanceMonitor(rig, rho=0.4, aggregate="min").query({"top": clean}, [point])
    assert Flag.REGION_OUTSIDE_VIEW in result.flags[0]
    assert 0.0 < result.distance[0] <= edge + 1e-9
    assert result.distance[0] == pytest.approx(edge, abs=1e-6)
    # the direction points back into the view (away from the edge, towards -x)
    assert result.direction[0, 0] < -0.5
    permissive = dg.DistanceMonitor(rig, rho=0.4, aggregate="min", unseen="free").query({"top": clean}, [point])
    assert Flag.REGION_OUTSIDE_VIEW in permissive.flags[0]
    assert permissive.distance[0] > 0.4 or math.isinf(permissive.distance[0])


# --------------------------------------------------------------------------------------------------------------------
# points


@pytest.mark.parametrize("points", [[], np.zeros((0, 3)), np.zeros((0,))], ids=["list", "array", "flat"])
def test_empty_point_list_gives_empty_result(rig, clean, points):
    result = dg.DistanceMonitor(rig).query({"top": clean}, points)
    assert len(result) == 0
    assert result.distance.shape == (0,) and result.direction.shape == (0, 3) and result.flags == ()
    assert result.records(np.zeros((0, 3))) == []
    assert len(dg.DistanceMonitor(rig).query({}, points)) == 0


@pytest.mark.parametrize(
    "points",
    [
        [[1.0, 2.0]],
        np.zeros((2, 4)),
        np.zeros((2, 3, 1)),
        [1.0, 2.0],
        [[1.0, 2.0, 3.0], [1.0, 2.0]],
        [[1.0, "x", 3.0]],
        "points",
        [[1.0, None, 3.0]],
    ],
    ids=["pair", "four columns", "3-D", "flat pair", "ragged", "string entry", "string", "None"],
)
def test_points_of_wrong_shape_or_type(rig, clean, points):
    with pytest.raises(dg.InputError):
        dg.DistanceMonitor(rig).query({"top": clean}, points)


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_non_finite_points_are_refused_and_named(rig, clean, bad):
    points = [[0.0, 0.0, 1.0], [0.1, bad, 0.5], [0.0, 0.0, 1.2]]
    with pytest.raises(dg.InputError) as exc_info:
        dg.DistanceMonitor(rig).query({"top": clean}, points)
    assert "#1" in str(exc_info.value)


def test_single_point_as_flat_triple(rig, clean):
    flat = dg.DistanceMonitor(rig).query({"top": clean}, [0.3, 0.1, 0.5])
    nested = dg.DistanceMonitor(rig).query({"top": clean}, [[0.3, 0.1, 0.5]])
    assert len(flat) == 1 and flat.distance[0] == nested.distance[0]


# --------------------------------------------------------------------------------------------------------------------
# frames: stale, missing, foreign, several, malformed


IN_VIEW = [[0.0, 0.0, 1.0], [0.3, 0.1, 0.5]]


def test_stale_frame_counts_as_blind(rig, camera, clean):
    monitor = dg.DistanceMonitor(rig, max_age=0.1)
    frame = dg.depth_image(clean, camera, timestamp=0.0)
    stale = monitor.query({"top": frame}, IN_VIEW, now=1.0)
    np.testing.assert_array_equal(stale.distance, 0.0)
    assert all(Flag.STALE_CAMERA in f for f in stale.flags)
    fresh = monitor.query({"top": frame}, IN_VIEW, now=0.05)
    assert np.all(fresh.distance > 0.1)
    assert all(Flag.STALE_CAMERA not in f for f in fresh.flags)
    assert fresh.timestamps == {"top": 0.0}
    np.testing.assert_array_equal(fresh.distance, dg.DistanceMonitor(rig).query({"top": clean}, IN_VIEW).distance)


def test_frame_without_timestamp_is_stale_when_age_matters(rig, camera, clean):
    monitor = dg.DistanceMonitor(rig, max_age=0.1)
    for frame in (dg.depth_image(clean, camera), clean):
        result = monitor.query({"top": frame}, IN_VIEW, now=0.0)
        np.testing.assert_array_equal(result.distance, 0.0)
        assert all(Flag.STALE_CAMERA in f for f in result.flags)


def test_max_age_needs_now(rig, camera, clean):
    with pytest.raises(dg.InputError, match="now"):
        dg.DistanceMonitor(rig, max_age=0.1).query({"top": dg.depth_image(clean, camera, timestamp=0.0)}, IN_VIEW)


def test_no_frames_means_missing_camera(rig):
    result = dg.DistanceMonitor(rig).query({}, IN_VIEW)
    np.testing.assert_array_equal(result.distance, 0.0)
    np.testing.assert_array_equal(result.direction, 0.0)
    assert all(Flag.MISSING_CAMERA in f for f in result.flags)
    assert result.records(IN_VIEW)[0]["flags"] == ["missing_camera"]


def test_frame_for_unknown_camera_is_named(rig, clean):
    with pytest.raises(dg.DepthguardError) as exc_info:
        dg.DistanceMonitor(rig).query({"ceiling": clean}, IN_VIEW)
    assert "'ceiling'" in str(exc_info.value)


def test_frames_of_two_cameras_are_fused_and_a_stale_one_flagged(camera, clean):
    side = camera.replace(name="side", T_world_camera=look_at([2, 0, 1], [0, 0, 0.3]))
    rig2 = dg.Rig({"top": camera, "side": side}, principal="top")
    monitor = dg.DistanceMonitor(rig2, max_age=0.1)
    top = dg.depth_image(clean, camera, timestamp=1.0)
    fresh = monitor.query({"top": top, "side": dg.depth_image(render_depth(side, SCENE), side, timestamp=1.0)},
                          IN_VIEW, now=1.05)
    assert fresh.cameras == ("top", "side") and fresh.principal == ("top",) * len(IN_VIEW)
    assert not any(dg.Flag.STALE_CAMERA in f for f in fresh.flags)
    stale = monitor.query({"top": top, "side": dg.depth_image(render_depth(side, SCENE), side, timestamp=0.5)},
                          IN_VIEW, now=1.05)
    assert all(dg.Flag.STALE_CAMERA in f for f in stale.flags)
    single = dg.DistanceMonitor(dg.Rig({"top": camera})).query({"top": clean}, IN_VIEW)
    assert np.all(stale.distance <= single.distance + 1e-12)  # a stale camera clears nothing
    assert np.all(fresh.distance >= stale.distance - 1e-12)


def test_frame_taken_by_another_camera_is_refused(camera, clean):
    side = camera.replace(name="side")
    rig2 = dg.Rig({"top": camera, "side": side})
    with pytest.raises(dg.InputError) as exc_info:
        dg.DistanceMonitor(rig2).query({"top": dg.depth_image(clean, side)}, IN_VIEW)
    assert "'side'" in str(exc_info.value) and "'top'" in str(exc_info.value)


@pytest.mark.parametrize("shape", [(47, 64), (48, 63), (64, 48)])
def test_frame_of_wrong_size_names_camera(rig, shape):
    with pytest.raises(dg.DepthImageError) as exc_info:
        dg.DistanceMonitor(rig).query({"top": np.ones(shape, np.float32)}, IN_VIEW)
    assert "'top'" in str(exc_info.value) and "width/height" in str(exc_info.value)


def test_frame_of_wrong_dtype_names_camera(rig, camera):
    with pytest.raises(dg.DepthImageError) as exc_info:
        dg.DistanceMonitor(rig).query({"top": np.ones(camera.shape, np.int32)}, IN_VIEW)
    assert "'top'" in str(exc_info.value) and "dtype" in str(exc_info.value)


def test_frames_must_be_a_mapping(rig, clean):
    with pytest.raises(dg.InputError):
        dg.DistanceMonitor(rig).query([clean], IN_VIEW)


def test_callers_buffer_changes_do_not_reach_a_prepared_frame(rig, camera, clean):
    buffer = clean.copy()
    frame = dg.depth_image(buffer, camera, timestamp=0.0)
    monitor = dg.DistanceMonitor(rig, aggregate="min")
    before = monitor.query({"top": frame}, IN_VIEW).distance.copy()
    buffer[:] = np.nan  # the driver reuses its buffer
    after = monitor.query({"top": frame}, IN_VIEW).distance
    np.testing.assert_array_equal(after, before)
    # whereas a new frame made from the changed buffer does see the change
    assert np.all(monitor.query({"top": dg.depth_image(buffer, camera)}, IN_VIEW).distance == 0.0)


@pytest.mark.parametrize(
    "options",
    [dict(rho=0.0), dict(rho=-0.4), dict(rho=math.nan), dict(rho=math.inf), dict(rho="0.4"),
     dict(aggregate="max"), dict(invalid="ignore"), dict(unseen="maybe"), dict(method="fast"),
     dict(max_age=0.0), dict(max_age=-1.0), dict(max_age=math.nan), dict(hole_pixels=-1), dict(hole_pixels=2.5)],
    ids=lambda o: f"{next(iter(o))}={next(iter(o.values()))!r}",
)
def test_monitor_refuses_bad_options(rig, options):
    with pytest.raises(dg.InputError) as exc_info:
        dg.DistanceMonitor(rig, **options)
    assert next(iter(options)) in str(exc_info.value)


def test_monitor_needs_a_rig(camera):
    with pytest.raises(dg.InputError):
        dg.DistanceMonitor({"top": camera})
