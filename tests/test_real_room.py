"""Real data: the slambook2 room's views 3, 4 and 5 as a rig of three depth cameras (issue 4, item 7).

The poses of the views are approximate (the rig's calibration error). These tests check that the rig loads, that the
reprojection agreement is the README's, and that the depth grid's fusion does not clear surfaces that one secondary
camera sees and the principal does not, at the fusion margin chosen from the calibration error; and that the margin
matters: with no noise margin and no fusion margin, the other secondary camera clears a visible fraction of them.
Points are subsampled (a few hundred per camera and kind) to keep the file at a few seconds.
"""

import functools
import os

import numpy as np
import pytest

from depthguard.experiments import real_room as rr

#: Surface points per secondary camera and kind (gray area, principal hole): 4 x 600 points.
SAMPLES = 600


@functools.lru_cache(maxsize=None)
def _load(folder: str, noise: str):
    rig, frames = rr.slambook_rig(folder, noise=rr.NOISE_MODELS[noise])
    grid = rr.depth_grid(rig)
    surface = rr.secondary_surface_points(rig, frames, SAMPLES, np.random.default_rng(7))
    return rig, frames, grid, surface


@pytest.fixture
def folder(real_data):
    path = os.path.join(real_data, "slambook2-room")
    if not os.path.isfile(os.path.join(path, "pose.txt")):
        pytest.skip(f"slambook2-room data not found at {path}")
    return path


def _cleared(folder, noise, margin):
    rig, frames, grid, surface = _load(folder, noise)
    return rr.fused_query(rig, frames, grid, surface.points_world, margin) > rr.CLEARED, surface


def test_rig_loads(folder):
    rig, frames, grid, _ = _load(folder, "kinect")
    assert list(rig.cameras) == ["view3", "view4", "view5"] and rig.principal == "view3"
    assert grid.secondaries == ("view4", "view5") and grid.d_max >= 9.8
    for name, camera in rig.cameras.items():
        R = camera.T_world_camera[:3, :3]
        np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-9)
        assert abs(np.linalg.det(R) - 1.0) < 1e-9
        depth = frames[name].metres()
        assert frames[name].data.dtype == np.uint16 and depth.shape == (480, 480 * 4 // 3)
        assert 0.68 <= frames[name].valid_fraction() <= 0.73  # README: valid pixels 68-73 %
        assert 0.7 <= np.nanmin(depth) and np.nanmax(depth) <= 9.9  # README: 0.71-9.8 m
    # Views 4 and 5 stand in front of view 3, looking the same way.
    T_3_world = rig.cameras["view3"].T_camera_world
    for name, ahead in (("view4", 0.71), ("view5", 0.94)):
        position = T_3_world[:3, :3] @ rig.cameras[name].T_world_camera[:3, 3] + T_3_world[:3, 3]
        assert position[2] == pytest.approx(ahead, abs=0.01)


def test_poses_file_is_read_as_camera_to_world(folder):
    poses = rr.read_poses(os.path.join(folder, "pose.txt"))
    assert sorted(poses) == [1, 2, 3, 4, 5]
    quaternions = np.loadtxt(os.path.join(folder, "pose.txt"))[:, 3:]
    np.testing.assert_allclose(np.linalg.norm(quaternions, axis=1), 1.0, atol=1e-6)  # unit: read in the right order
    # A point straight ahead of view 3 lands at its optical axis in the world: R * (0, 0, 1) + t.
    rig, _, _, _ = _load(folder, "kinect")
    camera = rig.cameras["view3"]
    np.testing.assert_allclose(camera.camera_to_world([[0.0, 0.0, 1.0]])[0],
                               poses[3][:3, 2] + poses[3][:3, 3], atol=1e-12)


def test_reprojection_agreement_matches_readme(folder):
    rig, frames, _, _ = _load(folder, "kinect")
    agree = {}
    for source, target in (("view3", "view4"), ("view4", "view5")):
        diff, depth = rr.reprojection_differences(rig, frames, source, target)
        assert diff.size > 100_000 and np.all(depth > 0)
        agree[source, target] = np.mean(np.abs(diff) < rr.AGREEMENT)
    # README: the depths agree within 5 cm for 51 % (3->4) and 66 % (4->5) of the overlapping pixels.
    assert agree["view3", "view4"] == pytest.approx(0.51, abs=0.02)
    assert agree["view4", "view5"] == pytest.approx(0.66, abs=0.02)


def test_chosen_margin_covers_the_calibration_error(folder):
    rig, frames, _, _ = _load(folder, "kinect")
    need, margin = rr.choose_margin(rig, frames)
    # 99 % of same-surface pixels below 4 m: one secondary camera sees past the other's surface by 2-5 cm beyond
    # its noise margin: a few centimetres of calibration error, the margin rounds it up.
    assert 0.02 < need <= margin == 0.05


def test_fusion_keeps_surfaces_one_secondary_camera_sees(folder):
    _, _, _, surface = _load(folder, "kinect")
    assert len(surface) == 4 * SAMPLES
    assert surface.contested.mean() > 0.4  # the other secondary camera sees most of them: it could clear them
    cleared, _ = _cleared(folder, "kinect", 0.05)
    # Not exactly 0: of 16,000 points the experiment finds 3 (0.02 %) cleared at this margin, all beyond 4 m: 2 mixed
    # ("flying") pixels on depth edges, depths between a foreground and a background that the other camera sees
    # through (no margin up to 0.2 m keeps them), and 1 beyond 6 m, where the sensor's own noise is centimetres.
    assert cleared.mean() < 0.005
    assert not np.any(cleared & (surface.depth < rr.WORKSPACE_DEPTH))


def test_margin_matters(folder):
    """Without a noise margin the fusion margin alone covers the calibration error: at 0 the other secondary camera
    clears a visible fraction of the surfaces (about 3 %, beyond 3 m), at 0.1 m a tenth of that. A larger margin
    clears a subset of what a smaller one clears."""
    fractions = {}
    previous = None
    for margin in (0.0, 0.05, 0.1, 0.2):
        cleared, surface = _cleared(folder, "none", margin)
        fractions[margin] = cleared.mean()
        if previous is not None:
            assert not np.any(cleared & ~previous)  # monotone: a larger margin never clears more
        previous = cleared
    assert fractions[0.0] > 0.01
    assert fractions[0.1] < fractions[0.0] / 3
    assert fractions[0.2] < 0.005
    cleared, _ = _cleared(folder, "kinect", 0.0)
    kept, _ = _cleared(folder, "kinect", 0.05)
    assert not np.any(kept & ~cleared)
