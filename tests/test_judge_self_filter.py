"""Self-filtering judged by code the project did not write (issue 3): pybullet renders the KUKA iiwa with obstacles
beside it; depthguard filters the robot out with its own model and rendering, and its control-point distances are
compared with pybullet's getClosestPoints.

The robot's visual meshes are swapped for its collision meshes (as in test_rendering), so that pybullet draws the
geometry depthguard's model describes. Tolerance: 2.5 pixel footprints at the obstacle's depth (pixel
discretisation, see test_judge_pybullet for its derivation) plus 1 mm for pybullet's float32 depth buffer.
"""

from __future__ import annotations

import os
import shutil

import numpy as np
import pybullet as p
import pybullet_data
import pytest

import depthguard as dg
import pybullet_scenes as ps
from depthguard.robots import RobotModel
from depthguard.transforms import look_at

RHO = 0.4


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    folder = tmp_path_factory.mktemp("iiwa")
    source = os.path.join(pybullet_data.getDataPath(), "kuka_iiwa")
    shutil.copytree(os.path.join(source, "meshes"), folder / "meshes")
    (folder / "model.urdf").write_text(open(os.path.join(source, "model.urdf")).read().replace(".obj", ".stl"))
    client = p.connect(p.DIRECT)
    robot_body = p.loadURDF(str(folder / "model.urdf"), useFixedBase=True, physicsClientId=client)

    def box(lower, upper):
        half = (np.asarray(upper) - np.asarray(lower)) / 2
        shape = p.createCollisionShape(p.GEOM_BOX, halfExtents=half.tolist(), physicsClientId=client)
        visual = p.createVisualShape(p.GEOM_BOX, halfExtents=half.tolist(), physicsClientId=client)
        return p.createMultiBody(0, shape, visual, (np.asarray(lower) + half).tolist(), physicsClientId=client)

    room = [box([-3, -3, -0.1], [3, 3, 0.0]), box([-2.5, -3, 0.0], [-2.4, 3, 3.0])]
    probe_shape = p.createCollisionShape(p.GEOM_SPHERE, radius=1e-4, physicsClientId=client)
    probe = p.createMultiBody(0, probe_shape, -1, [0, 0, 5], physicsClientId=client)
    yield client, robot_body, box, room, probe
    p.disconnect(client)


def truth(client, probe, bodies, points):
    """Distance from each point to the nearest of ``bodies`` and that nearest point (pybullet getClosestPoints;
    inf and NaN beyond 1 m)."""
    out = np.full(len(points), np.inf)
    nearest = np.full((len(points), 3), np.nan)
    for i, point in enumerate(points):
        p.resetBasePositionAndOrientation(probe, point.tolist(), [0, 0, 0, 1], physicsClientId=client)
        for body in bodies:
            for contact in p.getClosestPoints(probe, body, 1.0, physicsClientId=client):
                if contact[8] + 1e-4 < out[i]:
                    out[i] = contact[8] + 1e-4  # the probe's radius
                    nearest[i] = contact[6]
    return out, nearest


@pytest.mark.parametrize("seed", range(3))
def test_filtered_distances_never_exceed_pybullet_and_are_not_the_robot(world, seed):
    client, robot_body, box, room, probe = world
    rng = np.random.default_rng(seed)
    robot = RobotModel.default()
    q = rng.uniform(robot.lower * 0.5, robot.upper * 0.5)
    for j in range(7):
        p.resetJointState(robot_body, j, q[j], physicsClientId=client)
    points = robot.control_point_positions(q)
    # An obstacle beside the arm, across the camera's line of sight so its hidden space runs past the arm.
    eye = np.array([2.2, 0.0, 1.3])
    middle = points[4]
    side = np.cross(middle - eye, [0, 0, 1.0])
    side /= np.linalg.norm(side)
    centre = middle + side * rng.uniform(0.2, 0.3) + rng.uniform(-0.05, 0.05, 3)
    obstacle = box((centre - 0.06).tolist(), (centre + 0.06).tolist())
    try:
        camera = dg.PinholeCamera("cam", 320, 240, 262.5, 262.5, 159.5, 119.5, look_at(eye, middle),
                                  depth_range=(0.2, 8.0), noise=dg.NoiseModel.none())
        depth, _ = ps.render_depth(client, camera)
        depth = np.where(np.isfinite(depth), depth, 0.0).astype(np.float32)
        image = dg.depth_image(depth, camera)
        rig = dg.Rig({"cam": camera})
        monitor = dg.DistanceMonitor(rig, rho=RHO, aggregate="min", robot=robot)
        filtered = monitor.query({"cam": image}, points, joints=q)
        unfiltered = dg.DistanceMonitor(rig, rho=RHO, aggregate="min").query({"cam": image}, points)
        true, nearest = truth(client, probe, [obstacle] + room, points)
        near = true < RHO
        assert near.sum() >= 3
        # Where the true nearest obstacle point lies behind the robot as the camera sees it, or among the pixels the
        # filter gives to the (padded) robot, one camera cannot know it: design §7's blind spot, flagged.
        occupancy = monitor.prepare("cam", image)
        u, v, z = camera.project(camera.world_to_camera(np.nan_to_num(nearest)))
        u = np.clip(np.round(u), 0, camera.width - 1).astype(int)
        v = np.clip(np.round(v), 0, camera.height - 1).astype(int)
        hidden = near & ((depth[v, u] < z - 0.01) | np.isfinite(occupancy.blind[v, u]))
        tolerance = 2.5 * z / camera.fx + 1e-3
        print(f"\nseed {seed}: truth {np.round(true, 3)}\n  filtered {np.round(filtered.distance, 3)}"
              f"\n  unfiltered {np.round(unfiltered.distance, 3)}\n  hidden {hidden.astype(int)}")
        seen = near & ~hidden
        assert seen.sum() >= 2
        # Never optimistic about what the camera can see.
        assert np.all(filtered.distance[seen] <= true[seen] + tolerance[seen])
        # Never silently optimistic about what it cannot see: above the truth only with the flag, and the blind
        # distance never is.
        above = near & (filtered.distance > true + tolerance)
        assert all(dg.Flag.ROBOT_BLIND_SPOT in filtered.flags[i] for i in np.flatnonzero(above))
        conservative = np.minimum(filtered.distance, filtered.blind_distance)
        assert np.all(conservative[near] <= true[near] + tolerance[near])
        # Without the filter the robot is its own obstacle; with it, distances are the obstacle's, not ~0.
        assert np.all(unfiltered.distance[near] < 0.02)
        assert np.median(filtered.distance[seen] / true[seen]) > 0.7
        assert np.all(filtered.distance[seen] > 0.3 * true[seen])
    finally:
        p.removeBody(obstacle, physicsClientId=client)
