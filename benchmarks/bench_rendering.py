"""Robot rendering per 640x480 camera (issue 3 goal: robot depth <= 3 ms on this 2-core CPU, Mesa llvmpipe).

Scene: the KUKA LBR iiwa (``RobotModel.default()``) at 6 random configurations, seen by 3 cameras 1.8-2.2 m away;
each timed call renders the next (configuration, camera) pair, so a median mixes views. Robot geometry variants:

- exact: the URDF's collision meshes as they are (8 STL files, 14,758 triangles, not closed, so no face culling).
  The safety-relevant default: nothing smaller than the collision geometry, nothing simplified.
- hulls: each link's convex hull (closed, so faces turned away are culled). Contains the link, so it is allowed
  for the robot mask, but it is bigger where a link is concave.
- capsules: ``RobotModel.capsules`` (contain the meshes plus the model's padding) drawn by ``primitive_mesh`` with
  16 segments (closed; circumscribed, 3.9 % of the radius bigger).

For each variant: depth only (``render_depth``), depth + label + intensity (``render``), farthest surface
(``render_depth_max``); then how much the containing variants grow the robot mask and pull its depth forward
against the exact meshes. Then the fixed costs: clear + read-back with nothing to draw, read-back alone, and
uploading the meshes every frame instead of once. Medians, because the machine is shared and noisy.

    .venv/bin/python benchmarks/bench_rendering.py [--repeats 100]
"""

from __future__ import annotations

import argparse
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(__file__))

import depthguard as dg  # noqa: E402
from depthguard.rendering import MeshInstance, Renderer, primitive_mesh  # noqa: E402
from depthguard.robots import RobotModel  # noqa: E402
from depthguard.scenes import Capsule  # noqa: E402
from depthguard.transforms import look_at  # noqa: E402
from _common import report, timings  # noqa: E402

GOAL_MS = 3.0
CAPSULE_SEGMENTS = 16


def scenes(robot, rng, n_configurations=6):
    """[(camera, {link: T_world_link})]: every configuration seen by every camera."""
    cameras = []
    for azimuth in (0.3, 2.2, 4.1):
        distance = rng.uniform(1.8, 2.2)
        eye = [distance * np.cos(azimuth), distance * np.sin(azimuth), rng.uniform(0.9, 1.6)]
        cameras.append(dg.PinholeCamera(f"cam{len(cameras)}", 640, 480, 525.0, 525.0, 319.5, 239.5,
                                        look_at(eye, [0.0, 0.0, 0.6]), depth_range=(0.3, 6.0)))
    out = []
    for _ in range(n_configurations):
        q = rng.uniform(0.8 * robot.lower, 0.8 * robot.upper)
        poses = robot.link_poses(q)
        out.extend((camera, poses) for camera in cameras)
    return out


class Cycle:
    """Calls ``fn(camera, instances)`` on the next scene at each call."""

    def __init__(self, items):
        self.items, self.i = items, 0

    def next(self):
        item = self.items[self.i % len(self.items)]
        self.i += 1
        return item


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=100)
    args = parser.parse_args(argv)
    rng = np.random.default_rng(0)
    robot = RobotModel.default()
    views = scenes(robot, rng)
    renderer = Renderer()
    print(f"OpenGL: {renderer.gl_renderer}; {os.cpu_count()} CPUs; {len(views)} views of the iiwa, 640x480")

    # geometry variants: link -> (mesh handle, T_link_mesh)
    variants = {}
    exact = {link: renderer.add_mesh(mesh.vertices, mesh.faces) for link, mesh in robot.collision_meshes.items()}
    variants["exact"] = (exact, sum(len(m.faces) for m in robot.collision_meshes.values()))
    hulls = {}
    n_hull = 0
    for link, mesh in robot.collision_meshes.items():
        hull = mesh.convex_hull
        hulls[link] = renderer.add_mesh(hull.vertices, hull.faces, closed=True)
        n_hull += len(hull.faces)
    variants["hulls"] = (hulls, n_hull)
    capsules = {}
    n_capsule = 0
    for capsule in robot.capsules:
        vertices, faces = primitive_mesh(Capsule(tuple(capsule.p0), tuple(capsule.p1), capsule.radius),
                                         segments=CAPSULE_SEGMENTS)
        capsules[capsule.link] = renderer.add_mesh(vertices, faces, closed=True)
        n_capsule += len(faces)
    variants["capsules"] = (capsules, n_capsule)

    def instances(handles, poses):
        return [MeshInstance(mesh, poses[link], label=i) for i, (link, mesh) in enumerate(handles.items())]

    frames = {name: [(camera, instances(handles, poses)) for camera, poses in views]
              for name, (handles, _) in variants.items()}
    pixels = np.median([np.count_nonzero(renderer.render_depth(c, i)) for c, i in frames["exact"]])
    print(f"robot pixels per view: median {pixels:.0f} of {640 * 480}")

    print(f"\n{'robot geometry':42s} {'triangles':>9s} {'median ms':>10s} {'p90 ms':>8s} {'best ms':>8s}")
    medians = {}
    for name, (_, n_faces) in variants.items():
        for call, label in ((renderer.render_depth, "depth only"), (renderer.render, "depth + label + intensity"),
                            (renderer.render_depth_max, "farthest surface")):
            cycle = Cycle(frames[name])

            def fn(call=call, cycle=cycle):
                camera, inst = cycle.next()
                call(camera, inst)

            t = timings(fn, args.repeats)
            medians[name, label] = np.median(t)
            print(f"{name + ', ' + label:42s} {n_faces:9d} {np.median(t) * 1e3:10.2f} "
                  f"{np.percentile(t, 90) * 1e3:8.2f} {t.min() * 1e3:8.2f}")

    print("\nhow the containing geometry differs from the exact meshes (medians over the views):")
    for name in ("hulls", "capsules"):
        growth, forward_50, forward_90 = [], [], []
        for (camera, exact_inst), (_, inst) in zip(frames["exact"], frames[name]):
            a = renderer.render_depth(camera, exact_inst)
            b = renderer.render_depth(camera, inst)
            both = a > 0
            assert np.all(b[both] > 0) and np.all(b[both] <= a[both] + 1e-4), "containing geometry must contain"
            growth.append(np.count_nonzero(b) / np.count_nonzero(a) - 1.0)
            forward_50.append(np.median(a[both] - b[both]))
            forward_90.append(np.percentile(a[both] - b[both], 90))
        print(f"  {name:9s}: mask {100 * np.median(growth):+.0f} %, depth nearer by median "
              f"{1e3 * np.median(forward_50):.1f} mm (90th percentile {1e3 * np.median(forward_90):.1f} mm)")

    print(f"\n{'fixed costs (640x480)':60s} {'median ms':>10s}")
    camera = views[0][0]
    t = timings(lambda: renderer.render_depth(camera, []), args.repeats)
    print(f"{'render_depth with nothing to draw (clear + read-back)':60s} {np.median(t) * 1e3:10.2f}")
    t = timings(lambda: renderer.render(camera, []), args.repeats)
    print(f"{'render with nothing to draw (3 attachments)':60s} {np.median(t) * 1e3:10.2f}")
    targets = renderer._targets_for(640, 480)  # private: the read-back alone
    out = np.empty((480, 640), dtype=np.float32)

    def read_back():
        with renderer._gl.ctx:
            targets.depth_only.read_into(out, components=1, attachment=0, dtype="f4")

    t = timings(read_back, args.repeats)
    print(f"{'read-back of one float32 attachment':60s} {np.median(t) * 1e3:10.2f}")
    uploader = Renderer()
    cycle = Cycle(views)

    def per_frame_upload():
        camera, poses = cycle.next()
        handles = {link: uploader.add_mesh(m.vertices, m.faces) for link, m in robot.collision_meshes.items()}
        uploader.render_depth(camera, instances(handles, poses))
        for mesh in handles.values():
            uploader.remove_mesh(mesh)

    t = timings(per_frame_upload, max(10, args.repeats // 4))
    print(f"{'exact meshes uploaded every frame + depth only':60s} {np.median(t) * 1e3:10.2f}")
    uploader.release()

    print(f"\ngoal: robot depth <= {GOAL_MS} ms per 640x480 camera")
    for name in variants:
        ms = medians[name, "depth only"] * 1e3
        print(f"  {name:9s}: {ms:.2f} ms -> {'met' if ms <= GOAL_MS else 'NOT met'}")
    renderer.release()


if __name__ == "__main__":
    with report(__file__):
        main()
