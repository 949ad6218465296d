"""Where a ball of the detection capability fits in possibly occupied space (depthguard.freespace.DetectableSpace),
judged against exact geometry: balls and slabs whose distances are known in closed form, and an independent opening
with scipy."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import ndimage

from depthguard.errors import InputError
from depthguard.freespace import DetectableSpace, VoxelBox, robot_voxels, solid_voxels
from depthguard.freespace._detectable import closed_faces
from depthguard.scenes import Box

D = 0.04  # the detection capability, metres
R = D / 2
S = 0.01  # voxel side


def _corners(box: VoxelBox) -> np.ndarray:
    """(nx, ny, nz, 8, 3): every voxel's corners, metres."""
    xs, ys, zs = (box.lo[a] + np.arange(box.shape[a] + 1) * box.voxel for a in range(3))
    X, Y, Z = np.meshgrid(xs, ys, zs, indexing="ij")
    grid = np.stack([X, Y, Z], -1)
    return np.stack([grid[a:a + box.shape[0], b:b + box.shape[1], c:c + box.shape[2]]
                     for a in (0, 1) for b in (0, 1) for c in (0, 1)], axis=3)


def _free_outside_balls(box: VoxelBox, centres, radii) -> np.ndarray:
    """The voxels entirely outside every ball (exactly: the cube's nearest point to each centre is beyond its
    radius)."""
    lo = box.lo + np.stack(np.meshgrid(*(np.arange(n) for n in box.shape), indexing="ij"), -1) * box.voxel
    free = np.ones(box.shape, dtype=bool)
    for c, r in zip(centres, radii):
        gap = np.maximum(np.maximum(lo - c, 0.0), c - (lo + box.voxel))
        free &= np.sqrt((gap ** 2).sum(-1)) > r
    return free


def test_every_ball_of_the_capability_in_occupied_space_is_kept():
    """Possibly occupied space = random balls of radius >= d / 2 (each a place where a person's part at least d
    thick could be): no point's reported distance exceeds its exact distance to any of them."""
    rng = np.random.default_rng(3)
    box = VoxelBox([-0.4, -0.4, -0.4], [0.4, 0.4, 0.4], S)
    checked = 0
    for _ in range(6):
        n = 5
        centres = rng.uniform(-0.3, 0.3, (n, 3))
        radii = rng.uniform(R, 0.08, n)
        space = DetectableSpace(box, D)
        space.update(_free_outside_balls(box, centres, radii))
        points = rng.uniform(-0.35, 0.35, (300, 3))
        reported = space.distances(points)
        exact = np.min(np.maximum(np.linalg.norm(points[:, None] - centres[None], axis=2) - radii, 0.0), axis=1)
        assert np.all(reported <= exact + 1e-9), np.max(reported - exact)
        checked += int(np.sum(exact > 0.05))
        # and not far below either (the box's outside counts occupied): within the voxels' cost, s (1 + sqrt 3)
        to_outside = np.minimum(points - box.lo, box.hi - points).min(1) - R
        assert np.all(reported >= np.minimum(exact, to_outside) - S * (1 + math.sqrt(3)) - 1e-9)
    assert checked > 500


def test_a_band_thinner_than_the_capability_is_dropped_and_a_thick_one_is_kept():
    box = VoxelBox([-0.5, -0.5, -0.5], [0.5, 0.5, 0.5], S)
    z = box.lo[2] + (np.arange(box.shape[2]) + 0.5) * S
    point = np.array([[0.0, 0.0, 0.0]])
    for thickness, dropped in ((D - 2 * S, True), (D + 2 * S * math.sqrt(3) + S, False)):
        # a slab of possibly occupied space round z = 0.2, as many voxels thick as it takes to cover it
        occupied = np.abs(z - 0.2) < thickness / 2 + S / 2
        free = np.broadcast_to(~occupied, box.shape).copy()
        space = DetectableSpace(box, D)
        space.update(free)
        reported = space.distances(point)[0]
        slab = 0.2 - np.max(np.abs(z[occupied] - 0.2)) - S / 2  # exact distance to the voxels' slab
        border = 0.5 - R  # the box's faces count as occupied (a person may come from outside)
        if dropped:
            assert reported == pytest.approx(border), (thickness, reported)
            assert reported > slab
        else:
            assert reported <= slab + 1e-9


def test_the_opening_matches_scipys():
    """E_vox is scipy's binary erosion of the possibly occupied voxels by the ball of offsets within d / 2 (outside
    the box occupied), and the distances are the brute-force distances to its cubes minus d / 2."""
    rng = np.random.default_rng(7)
    box = VoxelBox([0.0, 0.0, 0.0], [0.3, 0.25, 0.2], S)
    occupied = ndimage.binary_dilation(rng.random(box.shape) < 0.02, iterations=2)
    space = DetectableSpace(box, D)
    space.update(~occupied)
    offsets = np.indices((5, 5, 5)) - 2
    ball = (offsets ** 2).sum(0) <= 4
    expected = ndimage.binary_erosion(occupied, structure=ball, border_value=1)
    np.testing.assert_array_equal(space.fits, expected)
    points = rng.uniform(box.lo, box.hi, (200, 3))
    lo = box.lo + np.argwhere(expected) * S
    gap = np.maximum(np.maximum(lo[None] - points[:, None], 0.0), points[:, None] - (lo[None] + S))
    to_fits = np.sqrt((gap ** 2).sum(-1)).min(1)
    to_outside = np.minimum(points - box.lo, box.hi - points).min(1)
    np.testing.assert_allclose(space.distances(points), np.maximum(np.minimum(to_fits, to_outside) - R, 0.0),
                               atol=1e-9)
    limited = space.distances(points, limit=0.01)
    np.testing.assert_allclose(limited, np.minimum(space.distances(points), 0.01), atol=1e-9)


def test_robot_voxels_mark_nothing_outside_the_sub_box_they_return():
    """``robot_voxels`` returns slices outside which it marked nothing: for capsules across the box's faces, thin
    ones that reach no voxel's centre, and (the whole box) one that is not finite."""
    box = VoxelBox([-0.3, -0.3, -0.3], [0.3, 0.3, 0.3], S)
    rng = np.random.default_rng(3)
    for _ in range(40):
        n = int(rng.integers(1, 4))
        capsules = np.concatenate([rng.uniform(-0.45, 0.45, (n, 6)), rng.uniform(0.0, 0.08, (n, 1))], axis=1)
        zone = float(rng.choice([0.0, 0.03]))
        marked = np.zeros(box.shape, dtype=bool)
        region = robot_voxels(box, capsules, zone, marked)
        inside = np.zeros(box.shape, dtype=bool)
        inside[region] = True
        assert not np.any(marked & ~inside)
    thin = np.zeros(box.shape, dtype=bool)
    assert robot_voxels(box, np.array([[0.0, 0.0, 0.0, 0.1, 0.0, 0.0, 0.001]]), 0.0, thin) == (slice(0, 0),) * 3
    assert not thin.any()
    whole = robot_voxels(box, np.array([[0.0, 0.0, np.nan, 0.1, 0.0, 0.0, 0.05]]), 0.0, np.zeros(box.shape, bool))
    assert whole == tuple(slice(0, n) for n in box.shape)


def test_robot_and_solid_voxels_lie_inside_what_they_stand_for():
    box = VoxelBox([-0.3, -0.3, -0.3], [0.3, 0.3, 0.3], S)
    corners = _corners(box)
    p0, p1, radius, zone = np.array([-0.1, 0.0, 0.0]), np.array([0.12, 0.05, 0.02]), 0.05, 0.03
    marked = np.zeros(box.shape, dtype=bool)
    robot_voxels(box, np.concatenate([p0, p1, [radius]])[None], zone, marked)
    axis = p1 - p0
    t = np.clip(((corners - p0) @ axis) / (axis @ axis), 0.0, 1.0)
    to_axis = np.linalg.norm(corners - (p0 + t[..., None] * axis), axis=-1).max(-1)
    assert marked.sum() > 500
    assert np.all(to_axis[marked] <= radius + zone + 1e-9)
    assert np.all(marked[to_axis <= radius + zone - S * math.sqrt(3)])  # and nothing deep inside is left out

    c, half = np.array([0.02, -0.01, 0.03]), np.array([0.15, 0.08, 0.1])
    angle = 0.4
    rotation = np.array([[math.cos(angle), -math.sin(angle), 0.0], [math.sin(angle), math.cos(angle), 0.0],
                         [0.0, 0.0, 1.0]])
    for grow in (0.0, 0.02):
        inside = np.zeros(box.shape, dtype=bool)
        solid_voxels(box, [Box(tuple(c), tuple(half), rotation)], inside, grow=grow)
        local = np.abs((corners - c) @ rotation)
        assert inside.sum() > 500
        assert np.all(np.all(local <= half + grow + 1e-9, axis=-1).all(-1)[inside])
        assert np.all(inside[np.all(local <= half + grow - S * math.sqrt(3), axis=-1).all(-1)])


def test_a_floor_under_the_box_closes_its_bottom_face_as_far_as_it_reaches():
    box = VoxelBox([-1.0, -1.0, -0.5], [1.0, 1.0, 1.5], 0.02)
    floor = Box.from_bounds([-3.0, -3.0, -1.0], [3.0, 3.0, -0.5])
    small = Box.from_bounds([-0.5, -3.0, -1.0], [0.5, 3.0, -0.5])  # does not cover the whole face
    tilted = Box((0.0, 0.0, -0.75), (3.0, 3.0, 0.25), np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]))
    np.testing.assert_allclose(closed_faces(box, [floor]), [0, 0, 0, 0, 0.5, 0], atol=1e-12)
    np.testing.assert_allclose(closed_faces(box, [small, tilted]), np.zeros(6))
    point = np.array([[0.0, 0.0, -0.3]])
    for beyond, expected in ((None, 0.2), ([0, 0, 0, 0, 0.5, 0], 0.7)):
        space = DetectableSpace(box, D, beyond)
        space.update(np.ones(box.shape, dtype=bool))
        assert space.distances(point)[0] == pytest.approx(expected - R)


@pytest.mark.parametrize("field, make", [
    ("capability", lambda box: DetectableSpace(box, 0.0)),
    ("capability", lambda box: DetectableSpace(box, float("nan"))),
    ("capability", lambda box: DetectableSpace(box, "0.04")),
    ("capability", lambda box: DetectableSpace(box, 0.015)),  # voxels coarser than d / 2
    ("box", lambda box: DetectableSpace("box", 0.04)),
    ("free", lambda box: DetectableSpace(box, 0.04).update(np.zeros((2, 2, 2), dtype=bool))),
    ("free", lambda box: DetectableSpace(box, 0.04).update(np.zeros(box.shape, dtype=np.uint8))),
    ("free", lambda box: DetectableSpace(box, 0.04).update(None)),
    ("points_world", lambda box: DetectableSpace(box, 0.04).distances([[0.0, float("nan"), 0.0]])),
    ("limit", lambda box: DetectableSpace(box, 0.04).distances([[0.0, 0.0, 0.0]], limit=-1.0)),
    ("beyond", lambda box: DetectableSpace(box, 0.04, beyond=[0.0] * 5)),
    ("beyond", lambda box: DetectableSpace(box, 0.04, beyond=[0.0] * 5 + [-1.0])),
    ("beyond", lambda box: DetectableSpace(box, 0.04, beyond=[0.0] * 5 + [float("inf")])),
    ("beyond", lambda box: DetectableSpace(box, 0.04, beyond="floor")),
])
def test_bad_input_is_refused_naming_the_field(field, make):
    box = VoxelBox([0.0, 0.0, 0.0], [0.1, 0.1, 0.1], S)
    with pytest.raises(InputError) as caught:
        make(box)
    assert caught.value.field == field


def test_before_any_update_and_outside_the_box_everything_counts_occupied():
    box = VoxelBox([0.0, 0.0, 0.0], [0.2, 0.2, 0.2], S)
    space = DetectableSpace(box, D)
    assert np.all(space.distances([[0.1, 0.1, 0.1]]) == 0.0)
    space.update(np.ones(box.shape, dtype=bool))
    assert space.distances([[0.1, 0.1, 0.1]])[0] == pytest.approx(0.1 - R)
    assert space.distances([[0.5, 0.1, 0.1]])[0] == 0.0


def _workcell_frames(times):
    """(workcell, [(t, q, frame)]) of scenario_b_reach.yaml in the four-camera layout at ``times``."""
    from importlib import resources
    from pathlib import Path

    from depthguard_lab.simulation import load_workcell
    from depthguard_lab.simulation._episode import sense_at

    package = resources.files("depthguard_lab.simulation")
    workcell = load_workcell(Path(str(package / "scenario_b_reach.yaml")),
                             layout=Path(str(package / "scenario_b_four.yaml")))
    return workcell, [(frame.time, frame.joints, frame) for frame in sense_at(workcell, times)]


@pytest.mark.slow
def test_the_monitors_detectable_distances_never_exceed_the_truth_to_a_person():
    """Scenario B's person (every part at least 10 cm thick, so a ball of d fits everywhere in them) walking in and
    reaching for the arm, four cameras: at points round the arm (not on it: with no robot zone the layer round the
    robot that no camera sees free is possibly occupied, so the detectable space counts it as an obstacle; its inside
    is free), the detectable distance is at most the
    exact distance to the person plus 2.5 footprints of the farthest camera + 1 mm (the fused answers' tolerance,
    tests/test_fusion_workcell.py). Known static solids (floor, walls, pedestal) are given too: their inside is free,
    what they hide still counts."""
    import depthguard as dg

    workcell, frames = _workcell_frames([1.3, 1.5, 1.6, 1.7, 1.8, 1.9, 3.3, 3.5])
    robot = workcell.robot
    static = workcell.background_parts()
    monitor = dg.DistanceMonitor(workcell.rig, rho=1.5, robot=robot, aggregate="min", static=static,
                                 detection_capability=D)
    focal = min(camera.fx for camera in workcell.rig.cameras.values())
    rng = np.random.default_rng(5)
    near, checked = 0, 0
    for t, q, frame in frames:
        prepared = monitor.prepare_set(frame.depth, joints=q, now=t)
        points = rng.uniform([-1.0, -1.0, 0.2], [1.0, 1.0, 1.8], (300, 3))
        capsules = robot.capsules_world(q)
        off_robot = np.min([c.distance(points) for c in capsules], axis=0) > 0.1
        points = points[off_robot]
        parts = workcell.obstacles_at(t)[workcell.people[0].name]
        truth = np.min([part.distance(points) for part in parts], axis=0)
        reported = prepared.detectable_distances(points).distance
        far = max(np.linalg.norm(points - camera.T_world_camera[:3, 3], axis=1).max()
                  for camera in workcell.rig.cameras.values())
        tolerance = 2.5 * far / focal + 1e-3
        assert np.all(reported <= truth + tolerance), (t, np.max(reported - truth))
        checked += len(points)
        near += int(np.sum((truth < 0.4) & (reported > 0.05)))
    assert checked >= 1000 and near >= 20, (checked, near)  # the person was near points the space saw round
    # the memory's remembered voxels (4 cm) count free on the detectable space's 1 cm voxels, each inside its own
    memory = monitor.memory
    from depthguard.freespace import FreeSources

    fine = FreeSources(remembered=monitor._remembered_coarse(monitor.detectable.box, memory.time)).mask(
        monitor.detectable.box)
    i, j, k = np.indices(fine.shape, sparse=True)
    np.testing.assert_array_equal(fine, memory.free_at(memory.time)[i // 4, j // 4, k // 4])
    assert fine.any() and not fine.all()


def test_the_monitor_refuses_a_capability_whose_concessions_hide_more_than_iso_13855_covers():
    """ISO 13855 gives C for detection capabilities up to 70 mm only. The monitor adds to d the band its concessions
    count free next to a surface (the robot zone with the capsules' padding and gap to the meshes; with
    invalid="neighbors" the widest object a filled hole hides) and refuses the sum above 70 mm: a forearm 45 mm
    thick lying in a 60 mm zone would otherwise be left out with C taken for a hand."""
    import depthguard as dg
    from depthguard import config

    workcell, _ = _workcell_frames([])
    robot = workcell.robot
    for options in (dict(robot=robot, robot_zone=config.LOOP_ROBOT_ZONE), dict(invalid="neighbors"),
                    dict(robot=robot, robot_zone=0.005)):
        with pytest.raises(InputError) as caught:
            dg.DistanceMonitor(workcell.rig, detection_capability=D, **options)
        assert caught.value.field == "detection_capability" and "70 mm" in str(caught.value), options
    for d in (0.0701, 0.1, 0.3):
        with pytest.raises(InputError) as caught:
            dg.DistanceMonitor(workcell.rig, detection_capability=d)
        assert caught.value.field == "detection_capability"
    # Nothing that hides: d itself (no robot zone, holes occupied).
    monitor = dg.DistanceMonitor(workcell.rig, robot=robot, detection_capability=0.07, detectable_voxel=0.03)
    assert monitor.hidden_band == 0.0


def test_the_monitor_refuses_a_detection_capability_it_cannot_use():
    import depthguard as dg
    from depthguard.cameras import Rig

    workcell, _ = _workcell_frames([])
    with pytest.raises(InputError) as caught:
        dg.DistanceMonitor(workcell.rig, detection_capability=0.04, detectable_voxel=0.03)
    assert caught.value.field == "detectable_voxel"
    for bad in (-1.0, 0.0, float("nan"), float("inf"), "0.04", True, [0.04]):
        with pytest.raises(InputError) as caught:
            dg.DistanceMonitor(workcell.rig, detection_capability=bad)
        assert caught.value.field == "detection_capability", bad
    for bad in (0.0, -0.01, float("nan"), "0.01", 1e-6):  # 1e-6: far more voxels than a box may have
        with pytest.raises(InputError) as caught:
            dg.DistanceMonitor(workcell.rig, detection_capability=0.04, detectable_voxel=bad)
        assert caught.value.field == "detectable_voxel", bad
    no_workspace = Rig(cameras=workcell.rig.cameras, principal=workcell.rig.principal)
    with pytest.raises(InputError) as caught:
        dg.DistanceMonitor(no_workspace, detection_capability=0.04)
    assert caught.value.field == "detection_capability"
    monitor = dg.DistanceMonitor(workcell.rig)
    prepared = monitor.prepare_set({})
    with pytest.raises(InputError) as caught:
        prepared.detectable_distances([[0.0, 0.0, 0.0]])
    assert caught.value.field == "detection_capability"
    # with one: no usable frame gives 0 everywhere; bad points and limits are refused naming them
    prepared = dg.DistanceMonitor(workcell.rig, detection_capability=0.04, detectable_voxel=0.02).prepare_set({})
    assert np.all(prepared.detectable_distances([[0.0, 0.0, 0.5], [1.0, 0.0, 0.5]]).distance == 0.0)
    for points in ([[0.0, float("nan"), 0.0]], [[0.0, 0.0]], "points"):
        with pytest.raises(InputError):
            prepared.detectable_distances(points)
    for limit in (-1.0, float("nan"), "1"):
        with pytest.raises(InputError) as caught:
            prepared.detectable_distances([[0.0, 0.0, 0.5]], limit=limit)
        assert caught.value.field == "limit"


def test_the_robot_counts_free_only_where_it_is_at_every_frames_joints(monkeypatch):
    """Frames captured at different joints: the space free as the robot is the robot's (grown) capsules at all of
    them, not at any one. With nothing seen free (every camera's view made blind), the voxels deep inside both poses'
    capsules hold no ball, and those deep inside one pose's only do."""
    import depthguard as dg
    from depthguard import config, freespace

    workcell, frames = _workcell_frames([1.3])
    (t, q, frame), robot = frames[0], workcell.robot
    moved = q.copy()
    moved[0] += 0.8  # the arm swung about its base between two captures
    views = freespace.CameraViews.of.__func__
    monkeypatch.setattr(freespace.CameraViews, "of", classmethod(  # every camera blind: it sees nothing free
        lambda cls, cameras, free_images, **kwargs: views(cls, cameras, [None] * len(cameras), **kwargs)))
    # The mechanism only: with the iiwa's capsules (2 cm padding, up to 6.7 cm from its meshes) any robot zone makes
    # the monitor refuse d = 4 cm (the test above). Here the band is taken as 0 to look at the zone's voxels.
    monkeypatch.setattr(dg.DistanceMonitor, "_hidden_band", lambda self: (0.0, "none"))
    monitor = dg.DistanceMonitor(workcell.rig, rho=1.2, robot=robot, robot_zone=config.LOOP_ROBOT_ZONE, memory=False,
                                 detection_capability=D, detectable_voxel=0.02)
    names = list(workcell.rig.cameras)
    joints = {name: (q if i else moved) for i, name in enumerate(names)}
    fits = monitor.prepare_set(frame.depth, camera_joints=joints, now=t).detectable.fits
    box = monitor.detectable.box
    centres = np.stack(np.meshgrid(*box.axis_centres(), indexing="ij"), -1)

    def inside(pose, depth):  # voxels whose centre is at least depth inside the pose's capsules (without the zone)
        out = np.zeros(box.shape, dtype=bool)
        for c in robot.capsules_world(pose):
            p0, p1 = np.asarray(c.p0), np.asarray(c.p1)
            axis = p1 - p0
            s = np.clip(((centres - p0) @ axis) / max(axis @ axis, 1e-12), 0.0, 1.0)
            out |= np.linalg.norm(centres - (p0 + s[..., None] * axis), axis=-1) <= c.radius - depth
        return out

    both = inside(q, 0.0) & inside(moved, 0.0)
    only_one = inside(q, 0.0) & ~inside(moved, -0.1)  # at q, and 0.1 m clear of the capsules at the other joints
    assert both.sum() > 50 and only_one.sum() > 50
    assert not fits[both].any()  # the robot at every frame: no person there
    assert fits[only_one].all()  # the robot at one frame only: possibly a person now


@pytest.mark.parametrize("zone", [0.0, 0.03])
def test_a_watched_space_gives_the_whole_masks_answers_bit_for_bit(zone, monkeypatch):
    """The monitor decides the detectable space block by block, where queries reach (DetectableSpace.watch). Its
    twin computes every voxel of the box with the whole-box kernels (FreeSources.mask, then update): every distance,
    with and without a limit, at the robot's control points and anywhere in the box, and every voxel of E_vox agree
    exactly, so the speed-up clears nothing the twin keeps. Four cameras of scenario B, known solids, the memory,
    the robot's inside, and with a robot zone the robot's capsules at two joint sets (frames captured at different
    joints)."""
    import depthguard as dg

    if zone:  # the mechanism only (with the iiwa's capsules any zone makes d = 4 cm refused, see above)
        monkeypatch.setattr(dg.DistanceMonitor, "_hidden_band", lambda self: (0.0, "none"))
    workcell, frames = _workcell_frames([1.3, 1.7, 3.3])
    robot = workcell.robot
    monitor = dg.DistanceMonitor(workcell.rig, rho=1.5, robot=robot, aggregate="min", static=workcell.background_parts(),
                                 detection_capability=D, robot_zone=zone)
    rng = np.random.default_rng(11)
    names = list(workcell.rig.cameras)
    compared = remembered = 0
    for t, q, frame in frames:
        moved = q.copy()
        moved[1] += 0.3
        joints = {name: (moved if zone and i == 1 else q) for i, name in enumerate(names)}
        space = monitor.prepare_set(frame.depth, camera_joints=joints, now=t).detectable
        sources = space._watched[0]
        assert sources.views.count == 4 and sources.static is not None
        # with a zone the padded capsules grown by it, without one the robot's inside (Robot_k, design §8a)
        assert sources.robot is not None and sources.robot[1] == zone and sources.remembered is not None
        remembered += int(sources.remembered[0].sum())
        if zone:
            assert sources.robot[0].shape[0] == 2
        twin = DetectableSpace(space.box, D, space.beyond)
        twin.update(sources.mask(space.box))
        box = space.box
        control = robot.control_point_positions(q)
        anywhere = rng.uniform(np.asarray(box.lo) - 0.1, np.asarray(box.hi) + 0.1, (150, 3))
        for points, limit in ((control, 1.2), (control, math.inf), (anywhere, 0.5), (anywhere, math.inf)):
            lazy = space.distances(points, limit)
            np.testing.assert_array_equal(lazy, twin.distances(points, limit))
            compared += int(np.sum((lazy > 0.0) & (lazy < limit)))
        np.testing.assert_array_equal(space.fits, twin.fits)
    assert compared > 100  # distances that neither limit nor an occupied point decided
    assert remembered > 0  # the memory's voxels were among the sources
