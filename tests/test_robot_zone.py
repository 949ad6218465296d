"""The robot zone (``DistanceMonitor(robot_zone=...)``, docs/design.md "Several cameras"): fused answers may take space within a
stated thickness of the robot's padded capsules for the robot, in every direction.

- The kernel's cell test (``zoned_cells``) against a slow judge written here: every cell it puts in the zone has its 8
  corners within the thickness of one capsule (the grown capsule is convex, so the whole cell is in it); and every cell
  whose 8 corners lie within the thickness minus the cell's diameter of the capsule is put in it (the test is not
  vacuous).
- In scenario B with four time-of-flight-class cameras, judged by the scene's exact geometry (coal): with a 3 cm zone no
  distance exceeds the truth plus this file's tolerance plus the thickness, no distance falls (the zone only takes
  occupied space away), and some rise; with the zone off the answers are the monitor's usual ones.
- Bad values are refused, naming the field.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

import numpy as np
import pytest

import depthguard as dg
from depthguard.kernels import depthgrid as K
from depthguard.depthgrid._fusion import _zone_arrays
from depthguard_lab.experiments.workcell import scene_distance
from depthguard_lab.simulation import load_workcell, simulate

SCENE = Path(str(resources.files("depthguard_lab.simulation") / "scenario_b_four_tof.yaml"))
RHO = 0.4
ZONE = 0.03
#: Footprints and metres of quantisation a fused distance may exceed the truth by (as tests/test_fusion_workcell.py
#: states it: 2.5 principal footprints at the point's depth plus rho, 1 mm for the millimetre images).
FOOTPRINTS = 2.5
QUANTISATION = 1e-3


def _segment_distance(points, a, b):
    ab = b - a
    t = np.clip(((points - a) @ ab) / max(float(ab @ ab), 1e-300), 0.0, 1.0)
    return np.linalg.norm(points - (a + t[..., None] * ab), axis=-1)


def zone_grid(d_min, delta_d, n_cells, zone, params):
    """A GridState that holds only the robot zone (zoned_cells reads nothing else)."""
    empty3 = np.zeros((0, 1, 1, 3))
    return K.GridState(d_min, delta_d, n_cells, empty3, np.zeros((0, 3)), np.zeros((0, 1, 1), np.float32),
                       np.zeros((0, 2), np.int64), np.zeros(0), 0.0, np.zeros((1, 1, 1), np.uint8),
                       np.zeros((1, 1), np.uint8), np.zeros((0, 0, 0), np.uint8), np.zeros(0), np.zeros((1, 1), np.int64),
                       np.zeros((1, 1), np.int64), zone, params, np.zeros((0, 7)), np.zeros(K.CAPSULE_PARAMS),
                       np.zeros((1, 1), np.float32), np.zeros((1, 1), np.float32))


def test_zoned_cells_against_corners():
    rng = np.random.default_rng(7)
    camera = dg.PinholeCamera("p", 160, 120, 131.25, 131.25, 79.5, 59.5, np.eye(4))
    d_min, delta_d, n_cells = 0.5, 0.01, 300
    checked = zoned = 0
    for _ in range(40):
        centre = np.array([rng.uniform(-0.4, 0.4), rng.uniform(-0.3, 0.3), rng.uniform(1.0, 3.0)])
        axis = rng.normal(size=3)
        axis *= rng.uniform(0.0, 0.3) / np.linalg.norm(axis)
        capsules = np.array([np.r_[centre - axis, centre + axis, rng.uniform(0.03, 0.12)]])
        thickness = rng.uniform(0.0, 0.08)
        zone, params = _zone_arrays((capsules, thickness), camera)  # camera at the world origin: optical = world
        u_c = int(round(centre[0] / centre[2] * camera.fx + camera.cx))
        v_c = int(round(centre[1] / centre[2] * camera.fy + camera.cy))
        for _ in range(20):
            u = int(np.clip(u_c + rng.integers(-12, 13), 0, camera.width - 1))
            v = int(np.clip(v_c + rng.integers(-12, 13), 0, camera.height - 1))
            k_a = int(np.clip((centre[2] - 0.3 - d_min) / delta_d, 0, n_cells - 64))
            grid = zone_grid(d_min, delta_d, n_cells, zone, params)
            bits = int(K.zoned_cells(u, v, k_a, k_a + 63, grid, np.uint64(0)))
            # cells settled by another test (the memory, asked first) are skipped, the rest answered the same
            settled = int(rng.integers(0, 2**63)) | int(rng.integers(0, 2)) << 63
            assert int(K.zoned_cells(u, v, k_a, k_a + 63, grid, np.uint64(settled))) == bits & ~settled
            for i in range(64):
                z0 = d_min + (k_a + i) * delta_d
                corners = np.array([[(uu - camera.cx) / camera.fx * z, (vv - camera.cy) / camera.fy * z, z]
                                    for uu in (u - 0.5, u + 0.5) for vv in (v - 0.5, v + 0.5)
                                    for z in (z0, z0 + delta_d)])
                inside = _segment_distance(corners, capsules[0, :3], capsules[0, 3:6]) - capsules[0, 6]
                diameter = max(np.linalg.norm(a - b) for a in corners for b in corners)
                checked += 1
                if bits >> i & 1:
                    zoned += 1
                    assert inside.max() <= thickness + 1e-9, (u, v, k_a + i, inside.max(), thickness)
                elif inside.max() <= thickness - diameter:
                    pytest.fail(f"cell {(u, v, k_a + i)} lies well inside the zone and was not put in it")
    assert zoned > 100, (zoned, checked)


@pytest.fixture(scope="module")
def answers():
    """Per frame of scenario B's hidden-hand and shadow cases (every 20th): truth, tolerance, and the distances with
    the zone off and with it."""
    workcell = load_workcell(SCENE)
    robot = workcell.robot
    monitors = {zone: dg.DistanceMonitor(workcell.rig, rho=RHO, aggregate="hybrid", invalid="neighbors", robot=robot,
                                         memory=False, robot_zone=zone) for zone in (0.0, ZONE)}
    background = workcell.background_parts()
    principal = workcell.rig.cameras[workcell.rig.principal]
    kinds = ("shadow", "hidden_hand")
    times = [t for s in workcell.timeline() if s.kind in kinds for t in np.linspace(s.hold_start, s.end - 0.1, 4)]
    rows = []
    for frame in simulate(workcell, frames=[int(round(t * workcell.rate)) for t in times]):
        points = robot.control_point_positions(frame.joints)
        truth = np.minimum(frame.truth.distance, scene_distance(background, points))
        depth = np.maximum(principal.world_to_camera(points)[:, 2], 0.1)
        tolerance = FOOTPRINTS * (depth + RHO) / principal.fx + QUANTISATION
        got = {zone: m.query(dict(frame.depth), points, joints=frame.joints) for zone, m in monitors.items()}
        rows.append((truth, tolerance, got))
    return rows


@pytest.mark.slow
def test_the_zone_is_within_its_stated_tolerance_and_only_raises(answers):
    raised = 0
    for truth, tolerance, got in answers:
        off, on = got[0.0].distance, got[ZONE].distance
        assert np.all(np.minimum(on, RHO) <= truth + tolerance + ZONE), (on, truth)
        assert np.all(off <= truth + tolerance)
        assert np.all(on >= off - 1e-9)
        raised += int(np.count_nonzero(np.minimum(on, RHO) > off + 1e-3))
    print(f"the zone raised {raised} of {sum(len(t) for t, _, _ in answers)} distances")
    assert raised > 0


@pytest.mark.parametrize("value", [-0.01, float("nan"), float("inf"), 0.5, "0.03", True, None])
def test_bad_zone_is_refused(value):
    rig = dg.Rig({"a": dg.PinholeCamera("a", 64, 48, 60.0, 60.0, 31.5, 23.5, np.eye(4))})
    with pytest.raises(dg.InputError, match="robot_zone"):
        dg.DistanceMonitor(rig, robot_zone=value)
