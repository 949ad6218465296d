"""Soak of ``depthguard live`` (design §12b): cameras at 30 Hz and joint states at 500 Hz through zenoh into the
node, for minutes, with the ROS side played by this script (no ROS installed).

Scene: scenario B (the person reaching, the KUKA iiwa moving), 640x480 depth cameras: two (scenario_b.yaml) or four
(scenario_b_four.yaml). A pool of frames is rendered once and played forwards and backwards, each set restamped on
the host's clock when it is published, with the joint states of the pool's time at 500 Hz: the frames and the joints
agree, as a real cell's do. This process is a zenoh peer listening on 127.0.0.1 and publishes in rmw_zenoh's layout;
the node is ``depthguard live`` in a process of its own, connected as a client, writing ``--out``.

Reported: frames expected and received per camera (and missed: replaced before the node used them, or lost);
answers, sets dropped; deadline misses (an answer later than max_age after its newest frame stamp, on the host's
clock); latency from the newest stamp to the answer, p50 / p99 / max; the node's CPU (per cent of one core) and
resident memory over time (its growth per minute after the first minute). Goals (2 cores): deadline misses <= 0.1 %,
latency p99 <= 33 ms, memory growth <= 1 MB per minute.

Not part of the test suite (minutes long, timing): run by hand.

    .venv/bin/python benchmarks/soak_live.py [--minutes 10] [--cameras 2|4] [--pool 60] [--ssm]

``--ssm``: the node also publishes the speed factor (``live --ssm --ssm-joint-speed 0.5``: SSM on the
detectable space of the robot's surface spheres, design §9); the report adds how the factors were spread.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import socket
import subprocess
import sys
import tempfile
import threading
import time
from importlib import resources
from pathlib import Path

import numpy as np

import depthguard as dg
from depthguard import config
from depthguard.io.ros_messages import depth_messages, joint_state_message
from depthguard.live import wire
from depthguard_lab.simulation import load_workcell
from depthguard_lab.simulation._episode import sense_at
from _common import report

RATE = 30.0
JOINT_RATE = 500.0
START = 0.5  # seconds into the scenario where the pool starts


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def stamped(payload: bytes, ns: int) -> bytes:
    """A CDR message whose first field is a std_msgs/Header, restamped: sec and nanosec follow the 4-byte
    encapsulation header, little endian."""
    out = bytearray(payload)
    out[4:8] = (ns // 1_000_000_000).to_bytes(4, "little", signed=True)
    out[8:12] = (ns % 1_000_000_000).to_bytes(4, "little")
    return bytes(out)


class Publisher:
    """The cameras' and the robot's drivers: a zenoh peer publishing the pool in real time."""

    def __init__(self, workcell, frames, endpoint: str):
        import zenoh

        conf = zenoh.Config()
        conf.insert_json5("mode", json.dumps("peer"))
        conf.insert_json5("listen/endpoints", json.dumps([endpoint]))
        conf.insert_json5("scouting/multicast/enabled", "false")
        self.session = zenoh.open(conf)
        store = wire.type_store()
        self.cameras = list(workcell.rig.cameras)
        self.frames = frames
        self.times = np.array([f.time for f in frames])
        self.joints = np.array([f.joints for f in frames])
        self.names = list(workcell.robot.joint_names)
        self.store = store
        self.pubs = {}
        self.sequence = {}
        self.images = []  # per pool frame: {camera: (info bytes, image bytes)}
        for frame in frames:
            out = {}
            for name in self.cameras:
                info, image = depth_messages(store, 0, workcell.rig.cameras[name], frame.depth[name].data)
                out[name] = (wire.serialize(info, "sensor_msgs/msg/CameraInfo"),
                             wire.serialize(image, "sensor_msgs/msg/Image"))
            self.images.append(out)
        for name in self.cameras:
            self._declare(f"/{name}/depth/image_raw", "sensor_msgs/msg/Image")
            self._declare(f"/{name}/depth/camera_info", "sensor_msgs/msg/CameraInfo")
        self._declare("/joint_states", "sensor_msgs/msg/JointState")
        self.published = {name: 0 for name in self.cameras}
        self.stop = threading.Event()

    def _declare(self, topic, msgtype):
        self.pubs[topic] = self.session.declare_publisher(wire.data_key(topic, msgtype))
        self.sequence[topic] = 0

    def put(self, topic, payload):
        self.sequence[topic] += 1
        self.pubs[topic].put(payload, attachment=wire.attachment_bytes(self.sequence[topic], time.time_ns(),
                                                                       b"soak-publisher-1"))

    def pool_time(self, t: float) -> float:
        """Seconds into the pool, played forwards then backwards."""
        span = self.times[-1] - self.times[0]
        k = t % (2 * span)
        return self.times[0] + (k if k <= span else 2 * span - k)

    def run(self, seconds: float):
        start = time.time()
        next_frame = start
        next_joint = start
        while not self.stop.is_set():
            now = time.time()
            if now - start >= seconds:
                return
            if now >= next_joint:
                ns = time.time_ns()
                tp = self.pool_time(ns / 1e9 - start)
                q = np.array([np.interp(tp, self.times, self.joints[:, j]) for j in range(self.joints.shape[1])])
                self.put("/joint_states", wire.serialize(joint_state_message(self.store, ns, self.names, q),
                                                         "sensor_msgs/msg/JointState"))
                next_joint += 1.0 / JOINT_RATE
            if now >= next_frame:
                ns = time.time_ns()
                tp = self.pool_time(ns / 1e9 - start)
                index = int(np.argmin(np.abs(self.times - tp)))
                for name in self.cameras:
                    info, image = self.images[index][name]
                    self.put(f"/{name}/depth/camera_info", stamped(info, ns))
                    self.put(f"/{name}/depth/image_raw", stamped(image, ns))
                    self.published[name] += 1
                next_frame += 1.0 / RATE
            time.sleep(max(0.0, min(next_joint, next_frame) - time.time()))

    def close(self):
        self.session.close()


def proc_sample(pid: int) -> tuple[float, float]:
    """(CPU seconds, resident MB) of process pid."""
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    cpu = (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    with open(f"/proc/{pid}/status") as f:
        rss = next(int(line.split()[1]) for line in f if line.startswith("VmRSS:")) / 1024.0
    return cpu, rss


SSM_OPTIONS = ["--ssm", "--ssm-joint-speed", "0.5"]


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=10.0)
    parser.add_argument("--cameras", type=int, choices=(2, 4), default=2)
    parser.add_argument("--pool", type=int, default=60, help="frames rendered and played back and forth")
    parser.add_argument("--ssm", action="store_true", help="the node also publishes /depthguard/speed_scaling")
    args = parser.parse_args(argv)
    package = resources.files("depthguard_lab.simulation")
    scene = Path(str(package / "scenario_b.yaml"))
    layout = Path(str(package / "scenario_b_four.yaml")) if args.cameras == 4 else None
    workcell = load_workcell(scene, layout=layout)
    print(f"rendering {args.pool} sets of {len(workcell.rig.cameras)} cameras ...", flush=True)
    frames = sense_at(workcell, START + np.arange(args.pool) / workcell.rate)
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    publisher = Publisher(workcell, frames, endpoint)
    seconds = args.minutes * 60.0
    with tempfile.TemporaryDirectory() as folder:
        rig_file = Path(folder) / "rig.yaml"
        dg.save_rig(workcell.rig, rig_file)
        out = Path(folder) / "live.csv"
        node = subprocess.Popen([sys.executable, "-m", "depthguard.cli", "live", "--rig", str(rig_file), "--robot",
                                 "iiwa", "--connect", endpoint, "--out", str(out), "--duration", str(seconds + 5),
                                 *SSM_OPTIONS * args.ssm],
                                stderr=subprocess.PIPE, text=True)
        samples = []
        time.sleep(3.0)  # the node starts, connects, compiles nothing (warm cache) and makes its renderer
        thread = threading.Thread(target=publisher.run, args=(seconds,))
        t0 = time.time()
        thread.start()
        while thread.is_alive():
            try:
                samples.append((time.time() - t0, *proc_sample(node.pid)))
            except (OSError, StopIteration):
                break
            thread.join(5.0)
        stopped = time.time()  # the publisher's last frame went out: later answers are the node's idle ones
        _, err = node.communicate(timeout=120)
        publisher.close()
        with open(out, newline="") as f:
            rows = [r for r in csv.DictReader(f)]
    first_point = workcell.robot.control_point_names[0]
    # While the cameras ran: after the publisher stops, the node keeps answering (idle, the frames ageing until they
    # are stale), and those answers' latency is the cameras' silence, not the node's.
    tail = sum(1 for r in rows if r["control_point"] == first_point and float(r["time"]) > stopped)
    answers = [r for r in rows if r["control_point"] == first_point and float(r["time"]) <= stopped]
    latency = np.array([float(r["latency_ms"]) for r in answers])
    fresh = [r for r in answers if r["cameras"] == ";".join(workcell.rig.cameras)]
    misses = int((latency > config.DEFAULT_MAX_AGE * 1e3).sum())
    summary = [line for line in err.splitlines() if "answers" in line]
    # What else the node said (a kernel compiled at run time stalls it for seconds; a warning names its cause).
    said = [line for line in err.splitlines() if line not in summary and "listening" not in line]
    print(f"\n{len(workcell.rig.cameras)} cameras x {RATE:g} Hz, joint states {JOINT_RATE:g} Hz, {args.minutes:g} min; "
          f"node: depthguard live (rmw_zenoh layout, max_age {config.DEFAULT_MAX_AGE:g} s"
          f"{', ' + ' '.join(SSM_OPTIONS) if args.ssm else ''})")
    print(f"  frames published per camera: {', '.join(f'{n} {c}' for n, c in publisher.published.items())}")
    print(f"  node: {summary[-1].split(': ', 1)[1] if summary else err[-300:]}")
    print(f"  answers while the cameras ran {len(answers)} ({len(fresh)} with every camera seen, "
          f"{len(answers) / seconds:.1f} per second); {tail} idle answers after they stopped, not counted below")
    steady = np.array([float(r["latency_ms"]) for r in answers if float(r["time"]) - float(answers[0]["time"]) >= 60.0])
    if len(steady):
        print(f"  after the first minute: latency p50 {np.percentile(steady, 50):.1f}, p99 {np.percentile(steady, 99):.1f}"
              f", max {steady.max():.1f} ms; deadline misses {int((steady > config.DEFAULT_MAX_AGE * 1e3).sum())} of "
              f"{len(steady)} ({100 * (steady > config.DEFAULT_MAX_AGE * 1e3).mean():.2f} %)")
    if len(latency):
        print(f"  latency, newest stamp to answer, ms: p50 {np.percentile(latency, 50):.1f}, p99 "
              f"{np.percentile(latency, 99):.1f}, max {latency.max():.1f} (goal p99 <= 33: "
              f"{'met' if np.percentile(latency, 99) <= 33 else 'NOT met'})")
        print(f"  deadline misses (latency > max_age): {misses} of {len(latency)} ({100 * misses / len(latency):.2f} "
              f"%; goal <= 0.1 %: {'met' if misses <= 0.001 * len(latency) else 'NOT met'})")
    if args.ssm and answers:
        factor = np.array([float(r["speed_factor"]) for r in answers])
        reaction = np.array([float(r["reaction_ms"]) for r in answers])
        starting = np.array([r.get("starting") == "true" for r in answers])
        times = np.array([float(r["time"]) for r in answers])
        last_minute = times >= times.max() - 60.0
        print(f"  speed factor: 0 in {100 * (factor == 0).mean():.1f} % of the answers, 1 in "
              f"{100 * (factor == 1).mean():.1f} %, median {np.median(factor):.3f}; reaction time T_r p50 "
              f"{np.percentile(reaction, 50):.0f}, p99 {np.percentile(reaction, 99):.0f} ms; \"starting\" (may rest "
              f"on space not seen since start-up) in {100 * starting.mean():.1f} % of the answers, in the last "
              f"minute's {100 * starting[last_minute].mean():.1f} %")
    if said:
        print(f"  the node also said ({len(said)} lines): " + " | ".join(line[:160] for line in said[:5]))
    if len(samples) >= 3:
        s = np.array(samples)
        cpu = (s[-1, 1] - s[0, 1]) / (s[-1, 0] - s[0, 0]) * 100
        later = s[s[:, 0] >= 60.0]
        growth = np.polyfit(later[:, 0] / 60.0, later[:, 2], 1)[0] if len(later) >= 3 else None
        verdict = "n/a (under two minutes)" if growth is None else \
            f"{growth:+.2f} MB/min (goal <= 1: {'met' if growth <= 1.0 else 'NOT met'})"
        print(f"  node CPU {cpu:.0f} % of one core; resident memory {s[0, 2]:.0f} MB at start, {s[:, 2].max():.0f} MB "
              f"peak, {s[-1, 2]:.0f} MB at the end; growth after the first minute {verdict}")
        print("  resident MB over time: " + ", ".join(f"{t / 60:.1f} min {m:.0f}" for t, _, m in s[::max(1, len(s) // 10)]))


if __name__ == "__main__":
    cameras = 4 if "--cameras" in sys.argv and sys.argv[sys.argv.index("--cameras") + 1:][:1] == ["4"] else 2
    ssm = "_ssm" if "--ssm" in sys.argv else ""
    with report(__file__, name=f"soak_live_{cameras}_cameras{ssm}"):  # docs/figures/soak_live_<n>_cameras.md
        main()
