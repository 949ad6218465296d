"""Workcell simulation speed: frames per second of reference scenario B (two 640x480 depth cameras, the KUKA iiwa
tracing its hexagon, one scripted person), with the Kinect-like sensor model and ground truth.

Reported (medians, the machine is shared and noisy):

- building the workcell (scene file, robot model, the hexagon's IK for every frame) and the IK tracking error;
- one frame of ``simulate`` (every camera rendered, sensor model, intensity images, ground truth), then its parts:
  people's poses, one camera's rendering, one camera's sensor model, the ground truth;
- one frame of ``write_episode`` (the same plus PNGs and CSV rows on disk);
- a check of the sensor model: measured noise on a flat wall against sigma(d).

    .venv/bin/python benchmarks/bench_simulation.py [--frames 60]
"""

from __future__ import annotations

from depthguard_lab import config as lab_config
import argparse
import os
import sys
import tempfile
import time

import numpy as np
from PIL import Image

sys.path.insert(0, os.path.dirname(__file__))

import depthguard as dg  # noqa: E402
from depthguard import config  # noqa: E402
from depthguard_lab.simulation import (  # noqa: E402
    SceneRenderer,
    SensorModel,
    TruthComputer,
    default_workcell,
    simulate,
    simulate_depth,
    write_episode,
)
from _common import report, timings  # noqa: E402


def frame_times(generator, n: int) -> np.ndarray:
    """Seconds per frame of a generator of frames, first frame excluded (it pays for uploading meshes)."""
    next(generator)
    out = np.empty(n)
    for i in range(n):
        t = time.perf_counter()
        next(generator)
        out[i] = time.perf_counter() - t
    return out


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=60, help="frames timed per measurement")
    args = parser.parse_args(argv)
    n = args.frames

    t = time.perf_counter()
    wc = default_workcell()
    build = time.perf_counter() - t
    cameras = ", ".join(f"{c.name} {c.width}x{c.height}" for c in wc.rig.cameras.values())
    print(f"scenario B: {wc.duration:g} s at {wc.rate:g} Hz ({wc.n_frames} frames); depth cameras: {cameras}; "
          f"{os.cpu_count()} CPUs")
    print(f"building the workcell (scene, robot, hexagon IK for {len(wc.trajectory.times)} samples): {build:.2f} s "
          f"(first in the process)")
    errors = wc.trajectory.errors
    print(f"hexagon IK tracking error: max {errors.max() * 1e3:.2e} mm, median {np.median(errors) * 1e3:.2e} mm")

    frames = np.linspace(0, wc.n_frames - 1, n + 1).astype(int)  # spread over the episode: every case
    per_frame = frame_times(simulate(wc, seed=0, frames=frames), n)
    print(f"\n{'per frame (2 depth cameras, sensor model, truth)':58s} {'median ms':>10s} {'fps':>7s}")
    print(f"{'simulate()':58s} {np.median(per_frame) * 1e3:10.1f} {1 / np.median(per_frame):7.1f}")

    with tempfile.TemporaryDirectory() as tmp:
        t = time.perf_counter()
        write_episode(wc, tmp, seed=0, progress=False, frames=frames)
        total = time.perf_counter() - t
    print(f"{'write_episode() (PNGs + CSVs), mean incl. setup':58s} {total / len(frames) * 1e3:10.1f} "
          f"{len(frames) / total:7.1f}")

    print(f"\n{'parts of one frame':58s} {'median ms':>10s}")
    renderer = SceneRenderer(wc)
    truth = TruthComputer(wc.robot)
    names = {name: wc.part_names(name) for name in wc.obstacle_names}
    cycle = iter(np.tile(frames, 100))
    camera = wc.rig.cameras["principal"]

    def state():
        t = next(cycle) / wc.rate
        q = wc.joints_at(t)
        return t, q, wc.obstacles_at(t)

    tm = timings(lambda: wc.obstacles_at(next(cycle) / wc.rate), n)
    print(f"{'people and objects at t (obstacles_at)':58s} {np.median(tm) * 1e3:10.2f}")
    t0, q0, obstacles0 = state()
    instances = renderer.instances(wc.robot.link_poses(q0), obstacles0)
    tm = timings(lambda: renderer.render(camera, instances), n)
    print(f"{'render one camera (depth + label + intensity)':58s} {np.median(tm) * 1e3:10.2f}")
    result = renderer.render(camera, instances)
    cosine = renderer.cosine(result)
    rng = np.random.default_rng(0)
    tm = timings(lambda: simulate_depth(result.depth, cosine, camera, wc.sensors[camera.name], rng), n)
    print(f"{'sensor model, one camera (noise, dropouts, range, mm)':58s} {np.median(tm) * 1e3:10.2f}")
    tm = timings(lambda: truth(*state()[1:], names), n)
    print(f"{'ground truth (control point distances + coal clearance)':58s} {np.median(tm) * 1e3:10.2f}")
    data = simulate_depth(result.depth, cosine, camera, wc.sensors[camera.name], rng)
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "d.png")
        tm = timings(lambda: dg.depth.write_depth_png(path, data), n)
        print(f"{'one 16-bit depth PNG, depthguard.depth.write_depth_png':58s} {np.median(tm) * 1e3:10.2f}")
        image = Image.fromarray(data)
        tm = timings(lambda: image.save(path, compress_level=lab_config.SIM_PNG_COMPRESSION), n)
        print(f"{f'the same at zlib level {lab_config.SIM_PNG_COMPRESSION} (what write_episode uses)':58s} "
              f"{np.median(tm) * 1e3:10.2f}")
    renderer.release()

    print("\nsensor noise on a flat fronto-parallel 640x480 wall (Kinect v1 sigma(d) of the rig):")
    flat = dg.PinholeCamera("flat", 640, 480, 525.0, 525.0, 319.5, 239.5, np.eye(4), depth_range=(0.4, 8.0),
                            noise=camera.noise)
    for d in (1.0, 2.0, 3.0, 4.0):
        exact = np.full(flat.shape, d, dtype=np.float32)
        image = simulate_depth(exact, np.ones(flat.shape, np.float32), flat, SensorModel(),
                               np.random.default_rng(1)) * flat.depth_scale
        sigma = camera.noise.a + camera.noise.b * d + camera.noise.c * d * d
        print(f"  d = {d:.1f} m: sigma(d) {sigma * 1e3:5.2f} mm, measured std {image.std() * 1e3:5.2f} mm "
              f"({image.std() / sigma - 1:+.1%}), mean error {(image.mean() - d) * 1e3:+.3f} mm, "
              f"dropouts {np.mean(image == 0):.1%}")


if __name__ == "__main__":
    with report(__file__):
        main()
