"""The image-based collision test (issue 10's figures, so far): verdicts for a whole configuration table, and the
per-set work for four cameras.

1. Verdicts for K configurations (default 8,192, the paper's table) against one set of revised obstacle images,
   four cameras with 64 x 64 tiles, from :class:`ConfigurationTable`'s bitsets (random configurations of the KUKA
   iiwa within its limits, their padded capsules projected; obstacles and possible obstacles 5 % of the tiles each). Goal: <= 20 ms. Baseline in the same run: the same
   verdicts one configuration at a time through :func:`camera_collisions` and :func:`verdict` on unpacked images
   (a sample of configurations, scaled up).
2. Per set of four 704 x 576 images (random grey levels), step by step: tile features and difference images,
   obstacle images and the revised obstacle images with the epipolar bands, plus the robot's tile images at the
   current configuration (the KUKA iiwa's padded capsules projected).
3. The whole pipeline (``observe`` + one ``test``) on scenario C's simulated images, intensity and depth, with
   ``robot_pixels`` (the default) and without it (the paper's Table I, the baseline in the same run): goal >= 200 Hz.

    .venv/bin/python benchmarks/bench_collision.py [--configurations 8192] [--repeats 20]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

import depthguard as dg
from depthguard.collision import (
    OBSTACLE,
    POSSIBLE,
    ConfigurationTable,
    ImageCollisionTest,
    camera_collisions,
    difference_image,
    obstacle_image,
    revised_obstacle_images,
    tile_features,
    verdict,
)
from depthguard.robots import RobotModel
from depthguard.transforms import look_at
from _common import report


def _camera(name, eye, target=(0.2, 0.0, 0.5), width=704, height=576, f=600.0):
    return dg.PinholeCamera(name, width, height, f, f, (width - 1) / 2, (height - 1) / 2, look_at(eye, target))


def _median_ms(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return float(np.median(times)) * 1e3


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--configurations", type=int, default=8192)
    parser.add_argument("--repeats", type=int, default=20)
    args = parser.parse_args()
    eyes = [(2.4, -1.8, 1.8), (2.4, 1.8, 1.8), (-2.0, 2.0, 2.0), (-2.0, -2.0, 1.6)]
    rig = dg.Rig({f"c{k}": _camera(f"c{k}", eye) for k, eye in enumerate(eyes)})
    robot = RobotModel.default()
    workspace = [[-1.0, -1.0, -0.1], [1.2, 1.0, 1.5]]
    test = ImageCollisionTest(rig, robot, workspace, tiles=(64, 64), theta=1, robot_pixels=False)  # Table I's steps
    rng = np.random.default_rng(0)

    # 1. Verdicts for the whole table: K random configurations within the joint limits, their tile images projected.
    k = args.configurations
    configurations = rng.uniform(robot.lower, robot.upper, (k, robot.n_joints))
    start = time.perf_counter()
    table = ConfigurationTable(test, configurations)
    build = time.perf_counter() - start
    robot_tiles = np.stack([np.stack(test.projector.unpack(table.bits[:, j])) for j in range(k)], axis=1)
    labels = rng.choice([0, OBSTACLE, POSSIBLE], size=(len(test.grids), 64, 64), p=[0.9, 0.05, 0.05])
    revised = [label.astype(np.uint8) for label in labels]
    fast = _median_ms(lambda: table.verdicts(revised), args.repeats)
    sample = 256

    def one_at_a_time():
        for j in range(sample):
            flags = [camera_collisions(revised[c], robot_tiles[c, j]) for c in range(len(test.grids))]
            verdict([f[0] for f in flags], [f[1] for f in flags], 1)

    slow = _median_ms(one_at_a_time, max(3, args.repeats // 5)) * k / sample
    collision, klass = table.verdicts(revised)
    for j in rng.choice(k, 64, replace=False):  # the bitsets give the slow path's verdicts
        flags = [camera_collisions(revised[c], robot_tiles[c, j]) for c in range(len(test.grids))]
        v = verdict([f[0] for f in flags], [f[1] for f in flags], 1)
        assert (collision[j], klass[j]) == (v.collision, v.klass)
    print(f"table of {k} configurations' tile images (projected capsules, 4 cameras): built in {build:.2f} s")
    print(f"verdicts for {k} configurations, 4 cameras, 64 x 64 tiles: {fast:.2f} ms (goal 20 ms); one at a time "
          f"{slow:.0f} ms ({slow / fast:.0f}x)")

    # 2. Per set of four 704 x 576 images.
    images = {name: rng.integers(0, 256, cam.shape).astype(np.uint8) for name, cam in rig.cameras.items()}
    references = [tile_features(images[name], grid) for name, grid in zip(test.names, test.grids)]
    q = np.array([0.0, 0.5, 0.0, -1.4, 0.0, 0.8, 0.0])
    steps = {}
    steps["tile features + difference"] = _median_ms(
        lambda: [difference_image(tile_features(images[name], grid), ref)
                 for name, grid, ref in zip(test.names, test.grids, references)], args.repeats)
    robot_now = test.robot_image(q)
    steps["robot tile images (projected, 4 cameras)"] = _median_ms(lambda: test.robot_image(q), args.repeats)
    foreground = [rng.random((64, 64)) < 0.05 for _ in test.grids]
    obstacles = [obstacle_image(f, r) for f, r in zip(foreground, robot_now)]
    steps["obstacle + revised images (Tables I, III)"] = _median_ms(
        lambda: revised_obstacle_images(obstacles, test.bands, 1), args.repeats)
    test.reference = references
    test.observe(images, q)
    steps["one future test (projection + Table IV)"] = _median_ms(lambda: test.test(q), args.repeats)
    total = sum(steps.values())
    print(f"per set of four 704 x 576 images, by step (random grey levels): {total:.1f} ms, {1e3 / total:.0f} Hz")
    for name, ms in steps.items():
        print(f"  {name:44s} {ms:7.2f} ms")

    # 3. The whole pipeline on scenario C's images (simulated: the xArm 6, a person reaching, the light dimmed):
    #    observe (difference images with the light's gain, Tables I and III) + one future configuration's verdict.
    from importlib import resources

    from depthguard_lab.simulation import load_workcell, simulate

    with resources.as_file(resources.files("depthguard_lab.simulation").joinpath("scenario_c.yaml")) as path:
        workcell = load_workcell(path)
    frames = {f.index: f for f in simulate(workcell, frames=list(range(0, 45, 5)) + [100])}
    future = workcell.joints_at(7.0)
    print("whole pipeline on scenario C (observe + one future test), four 704 x 576 cameras, 64 x 64 tiles:")
    # robot_pixels off: the paper's Table I, the baseline of the pixel rule (the robot's render per camera and set)
    for kind, order, pixels in (("intensity", False, False), ("intensity", False, True), ("depth", False, False),
                                ("depth", False, True), ("depth", True, True)):
        source = (lambda f: f.intensity) if kind == "intensity" else (lambda f: {n: d.data for n, d in f.depth.items()})
        c_test = ImageCollisionTest(workcell.rig, workcell.robot, workcell.rig.workspace, images=kind,
                                    depth_order=order, robot_pixels=pixels)
        c_test.set_reference({name: [source(frames[i])[name] for i in range(0, 45, 5)] for name in workcell.rig.cameras},
                             joints=[frames[i].joints for i in range(0, 45, 5)])
        images, joints = source(frames[100]), frames[100].joints

        def pipeline():
            c_test.observe(images, joints)
            return c_test.test(future)

        ms = _median_ms(pipeline, args.repeats)
        label = kind + (", robot_pixels" if pixels else ", Table I alone") + (", depth order" if order else "")
        print(f"  {label:40s} {ms:6.2f} ms, {1e3 / ms:5.0f} Hz (goal 200 Hz; the paper: about 7 Hz)")


if __name__ == "__main__":
    with report(__file__):
        main()
