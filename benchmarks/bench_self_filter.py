"""Self-filtering time: rendering the robot into a 640x480 camera and preparing frames without it (issue 3).

Goals: robot depth rendering with its collision geometry <= 3 ms per 640x480 camera; self-filtering two cameras
<= 8 ms in all. The KUKA iiwa at several poses, two cameras about 4 m apart; medians, because this machine is noisy.

    .venv/bin/python benchmarks/bench_self_filter.py [--repeats 100]
"""

from __future__ import annotations

import argparse
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(__file__))

import depthguard as dg  # noqa: E402
from depthguard.rendering import Renderer  # noqa: E402
from depthguard.robots import RobotModel  # noqa: E402
from depthguard.scenes import Box, render_depth  # noqa: E402
from depthguard.self_filter import RobotSilhouette  # noqa: E402
from depthguard.transforms import look_at  # noqa: E402
from _common import nearer, report, timings  # noqa: E402


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=100)
    args = parser.parse_args(argv)
    robot = RobotModel.default()
    cameras = [dg.PinholeCamera(name, 640, 480, 525.0, 525.0, 319.5, 239.5, look_at(eye, [0.0, 0.0, 0.7]),
                                depth_range=(0.4, 8.0))
               for name, eye in (("principal", [2.0, -1.2, 1.6]), ("second", [-1.2, 2.0, 1.6]))]
    rng = np.random.default_rng(0)
    poses = [rng.uniform(robot.lower * 0.6, robot.upper * 0.6) for _ in range(8)]
    room = [Box.from_bounds([-3, -3, -0.1], [3, 3, 0.0]), Box.from_bounds([-2.5, -3, 0], [-2.4, 3, 3])]
    renderer = Renderer()
    silhouettes = {g: RobotSilhouette(robot, renderer, geometry=g) for g in ("hulls", "meshes", "capsules")}
    print(f"robot: {robot.name}, {len(robot.link_names)} links; two 640x480 cameras; {len(poses)} poses; "
          f"{renderer.gl_renderer}")
    print(f"\n{'geometry':10s} {'triangles':>9s} {'render ms':>10s} {'robot px':>9s}")
    for geometry, silhouette in silhouettes.items():
        i = iter(range(10**9))
        t = timings(lambda: silhouette.render(cameras[next(i) % 2], poses[next(i) % len(poses)]), args.repeats)
        pixels = np.mean([(silhouette.render(c, q) > 0).sum() for c in cameras for q in poses[:3]])
        print(f"{geometry:10s} {silhouette.triangles():9d} {np.median(t) * 1e3:10.2f} {pixels:9.0f}")

    # Full self-filtering of a frame pair: render the robot (default hulls) and prepare each camera's frame.
    frames = {}
    for camera in cameras:
        exact = silhouettes["meshes"].render(camera, poses[0])
        scene = render_depth(camera, room)
        depth = nearer(exact, scene)
        frames[camera.name] = dg.depth_image(np.round(depth * 1000).astype(np.uint16), camera)

    def filter_pair():
        for camera in cameras:
            near = silhouettes["hulls"].render(camera, poses[0])
            dg.prepare_depth(frames[camera.name], camera, robot_near=near)

    def prepare_pair():
        for camera in cameras:
            dg.prepare_depth(frames[camera.name], camera)

    t_filter = timings(filter_pair, args.repeats)
    t_prepare = timings(prepare_pair, args.repeats)
    print(f"\nself-filtering two cameras (render hulls + prepare), median: {np.median(t_filter) * 1e3:.2f} ms "
          f"(goal <= 8 ms); frame preparation alone for both: {np.median(t_prepare) * 1e3:.2f} ms")
    render = timings(lambda: silhouettes["hulls"].render(cameras[0], poses[0]), args.repeats)
    print(f"robot depth rendering, default geometry (padded hulls), per 640x480 camera: {np.median(render) * 1e3:.2f} "
          f"ms median (goal <= 3 ms)")


if __name__ == "__main__":
    with report(__file__):
        main()
