"""Running a simulated episode: rendering every camera at every frame time, the sensor model, ground truth, and
writing the episode to disk."""

from __future__ import annotations

import csv
import math
from collections import deque
from collections.abc import Iterable, Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml
from PIL import Image

from depthguard import config
from depthguard_lab import config as lab_config
from depthguard.io.files import atomic_write, write_whole
from depthguard.cameras import save_rig
from depthguard.depth import depth_image
from depthguard.errors import InputError
from depthguard.rendering import MeshInstance, Renderer, RenderResult, primitive_mesh
from depthguard.scenes import Box, Capsule
from depthguard_lab.simulation._scene import Workcell
from depthguard_lab.simulation._sensors import simulate_depth, simulate_intensity
from depthguard_lab.simulation._truth import GroundTruth, TruthComputer
from depthguard.transforms import rotation_with_z


@dataclass(frozen=True, eq=False)
class SimFrame:
    """One time step of a simulated episode.

    Attributes:
        index: frame number, from 0.
        time: seconds (index / rate); also every depth image's timestamp.
        joints: (n,) float64 robot joint values, radians, ``robot.joint_names`` order.
        depth: depth camera name -> :class:`~depthguard.depth.DepthImage` (uint16 in units of the camera's
            depth_scale, millimetres by default; 0 = no measurement), as the sensor model makes it.
        depth_exact: depth camera name -> (h, w) float32 metres, the noise-free rendering (optical z of the first
            surface on each pixel-centre ray; 0 where nothing is hit, no range limit).
        intensity: camera name -> (h, w) uint8 grey levels, for every camera (depth cameras' infrared-like image
            and the intensity cameras').
        label: camera name -> (h, w) int32, what each pixel shows: an index into ``workcell.labels()`` (e.g.
            "robot/lbr_iiwa_link_4", "worker/hand_right", "table"); -1 for nothing. Exact (noise-free)
            segmentation, for tests and training.
        truth: the frame's :class:`GroundTruth`.
    """

    index: int
    time: float
    joints: np.ndarray
    depth: dict
    depth_exact: dict
    intensity: dict
    label: dict
    truth: GroundTruth


class SceneRenderer:
    """The workcell's meshes uploaded once to a :class:`~depthguard.rendering.Renderer`, each in its own frame (robot
    links in their link frames, body parts and carried boxes in theirs, static objects in the world); per frame
    only their poses change.

    Spheres and capsules are drawn as circumscribed meshes with ``workcell.render_segments`` segments: the drawn
    surface lies outside the true one by at most ``primitive_mesh_excess`` (1.7 % of the radius at 24 segments).
    The robot is drawn with its URDF collision meshes.

    Attributes:
        label_names: the name of each label value (see :attr:`SimFrame.label`).
        albedo: (len(label_names),) float64 reflectance of each label.
    """

    def __init__(self, workcell: Workcell, renderer: Renderer | None = None):
        self.workcell = workcell
        self._own = renderer is None
        self.renderer = Renderer() if renderer is None else renderer
        segments = workcell.render_segments
        labels = workcell.labels()
        label = {name: i for i, (name, _) in enumerate(labels)}.__getitem__
        r = self.renderer
        self._links = []  # (link, mesh id, label)
        for link, mesh in workcell.robot.collision_meshes.items():
            self._links.append((link, r.add_mesh(mesh.vertices, mesh.faces), label(f"robot/{link}")))
        self._static = []  # MeshInstance, fixed
        for obj in workcell.static_objects:
            vertices, faces = primitive_mesh(obj.primitive, segments)
            self._static.append(MeshInstance(r.add_mesh(vertices, faces, closed=True), np.eye(4), label(obj.name),
                                             obj.albedo))
        self._carried = {}  # name -> (mesh id, label, albedo)
        for obj in workcell.carried_objects:
            vertices, faces = primitive_mesh(Box((0.0, 0.0, 0.0), tuple(obj.size / 2.0)), segments)
            self._carried[obj.name] = (r.add_mesh(vertices, faces, closed=True), label(obj.name), obj.albedo)
        self._people = {}  # name -> list of (mesh id, label, albedo) in the person's parts order
        capsules = {}  # (length, radius) -> mesh id: left and right limbs share their meshes
        for person in workcell.people:
            entries = []
            for part, capsule in zip(person.parts, person.parts_at(0.0)):
                key = (round(float(np.linalg.norm(np.subtract(capsule.p1, capsule.p0))), 12), capsule.radius)
                if key not in capsules:
                    vertices, faces = primitive_mesh(Capsule((0.0, 0.0, 0.0), (0.0, 0.0, key[0]), key[1]), segments)
                    capsules[key] = r.add_mesh(vertices, faces, closed=True)
                a = person.skin_albedo if part.skin else person.clothes_albedo
                entries.append((capsules[key], label(f"{person.name}/{part.name}"), a))
            self._people[person.name] = entries
        self._mesh_ids = sorted({i.mesh_id for i in self._static} | {m for _, m, _ in self._links}
                                | {m for m, _, _ in self._carried.values()}
                                | {m for entries in self._people.values() for m, _, _ in entries})
        self.label_names = tuple(name for name, _ in labels)
        self.albedo = np.array([a for _, a in labels], dtype=np.float64)

    def instances(self, link_poses: dict, obstacles: dict) -> list[MeshInstance]:
        """Mesh instances for the robot's ``link_poses`` (link -> (4, 4) T_world_link) and the workcell's
        ``obstacles`` (as :meth:`Workcell.obstacles_at` returns them)."""
        out = [MeshInstance(mesh, link_poses[link], lab, self.workcell.robot_albedo) for link, mesh, lab in self._links]
        out += self._static
        for name, (mesh, lab, a) in self._carried.items():
            for box in obstacles.get(name, []):
                T = np.eye(4)
                T[:3, :3] = box.R_world_box
                T[:3, 3] = box.center
                out.append(MeshInstance(mesh, T, lab, a))
        for name, entries in self._people.items():
            for (mesh, lab, a), capsule in zip(entries, obstacles[name]):
                p0, p1 = np.asarray(capsule.p0), np.asarray(capsule.p1)
                T = np.eye(4)
                T[:3, :3] = rotation_with_z((p1 - p0) / np.linalg.norm(p1 - p0))
                T[:3, 3] = p0
                out.append(MeshInstance(mesh, T, lab, a))
        return out

    def render(self, camera, instances) -> RenderResult:
        return self.renderer.render(camera, instances)

    def cosine(self, result: RenderResult) -> np.ndarray:
        """(h, w) float32 |cos| of the angle between each pixel's surface normal and its ray (see
        :func:`cosine_from_intensity`)."""
        return cosine_from_intensity(result.intensity, result.label, self.albedo)

    def release(self) -> None:
        """Free the meshes (and the renderer, if this object created it)."""
        if self._own:
            self.renderer.release()
        else:
            for mesh_id in self._mesh_ids:
                self.renderer.remove_mesh(mesh_id)
        self._mesh_ids = []

    def __enter__(self) -> "SceneRenderer":
        return self

    def __exit__(self, *exc) -> None:
        self.release()


def cosine_from_intensity(intensity: np.ndarray, label: np.ndarray, albedo: np.ndarray) -> np.ndarray:
    """(h, w) float32 |cos| of the angle between each pixel's surface normal (the renderer's flat triangle normal)
    and its ray, recovered from the renderer's Lambertian intensity, intensity = albedo (a + (1 - a) |cos|) with
    a = ``config.RENDER_AMBIENT``. ``intensity``: (h, w) float in [0, 1]; ``label``: (h, w) int (-1: nothing, gives
    0); ``albedo``: (labels,) float, each label's albedo."""
    a = np.float32(config.RENDER_AMBIENT)
    lookup = np.concatenate([np.asarray(albedo, dtype=np.float32), [np.float32(1.0)]])  # label -1 -> the last
    cosine = (np.asarray(intensity, dtype=np.float32) / lookup[label] - a) / (np.float32(1.0) - a)
    return np.where(label >= 0, np.clip(cosine, 0.0, 1.0), np.float32(0.0)).astype(np.float32)


def check_seed(seed) -> int:
    """The sensor noise's seed: a non-negative integer, else InputError (field "seed")."""
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise InputError(f"seed must be a non-negative integer, got {seed!r}", field="seed")
    return int(seed)


def sense(workcell: Workcell, scene: SceneRenderer, truth: TruthComputer, part_names: dict, q: np.ndarray, t: float,
          index: int, seed: int) -> SimFrame:
    """What every camera of ``workcell`` captures at time ``t`` (seconds) with the robot at ``q`` ((n,) rad) and the
    people and objects where their scripts put them: frame ``index``, the sensor noise drawn from
    ``numpy.random.default_rng([seed, index])``. ``scene``: the workcell's :class:`SceneRenderer`; ``truth``: its
    :class:`TruthComputer`; ``part_names``: obstacle name -> its parts' names (``workcell.part_names``)."""
    robot = workcell.robot
    obstacles = workcell.obstacles_at(t)
    instances = scene.instances(robot.link_poses(q, check=False), obstacles)
    rng = np.random.default_rng([int(seed), int(index)])
    gain = workcell.light_gain(t)
    depth, exact, intensity, labels = {}, {}, {}, {}
    for camera in workcell.all_cameras():
        result = scene.render(camera, instances)
        labels[camera.name] = result.label
        if camera.name in workcell.rig.cameras:
            exact[camera.name] = result.depth
            data = simulate_depth(result.depth, scene.cosine(result), camera, workcell.sensors[camera.name], rng)
            depth[camera.name] = depth_image(data, camera, timestamp=t)
        lit = result.intensity * np.float32(gain) if gain != 1.0 else result.intensity
        intensity[camera.name] = simulate_intensity(lit, workcell.intensity_noise[camera.name], rng)
    return SimFrame(index=index, time=t, joints=q, depth=depth, depth_exact=exact, intensity=intensity,
                    label=labels, truth=truth(q, obstacles, part_names))


def sense_at(workcell: Workcell, times, seed: int = 0) -> list[SimFrame]:
    """What every camera captures at each of ``times`` (seconds) with the robot where its script puts it (frame
    index round(t * rate), the sensor noise of ``seed``): for probes and benchmarks that need a few moments of a
    scene, not a whole episode."""
    from depthguard_lab.simulation._truth import TruthComputer

    truth = TruthComputer(workcell.robot)
    parts = {name: workcell.part_names(name) for name in workcell.obstacle_names}
    scene = SceneRenderer(workcell, None)
    try:
        return [sense(workcell, scene, truth, parts, workcell.joints_at(t).copy(), t, int(round(t * workcell.rate)),
                      seed) for t in times]
    finally:
        scene.release()


def simulate(workcell: Workcell, seed: int | None = None, frames: Iterable[int] | None = None,
             renderer: Renderer | None = None) -> Iterator[SimFrame]:
    """Simulate the episode frame by frame: a generator of :class:`SimFrame`.

    Args:
        workcell: the scene.
        seed: seed of the sensor noise (default ``workcell.seed``). Frame i draws from
            ``numpy.random.default_rng([seed, i])``, so any excerpt of frames equals the same frames of a full run.
        frames: frame indices to simulate (default all, ``range(workcell.n_frames)``).
        renderer: a :class:`~depthguard.rendering.Renderer` to upload the meshes to (default: a new one, released
            when the generator finishes).
    """
    seed = check_seed(workcell.seed if seed is None else seed)
    indices = range(workcell.n_frames) if frames is None else [int(i) for i in frames]
    for i in indices:
        if not 0 <= i < workcell.n_frames:
            raise InputError(f"frame {i} is outside the episode (0 .. {workcell.n_frames - 1})", field="frames")
    truth = TruthComputer(workcell.robot)
    part_names = {name: workcell.part_names(name) for name in workcell.obstacle_names}
    scene = SceneRenderer(workcell, renderer)
    try:
        for i in indices:
            t = i / workcell.rate
            yield sense(workcell, scene, truth, part_names, workcell.joints_at(t), t, i, seed)
    finally:
        scene.release()


def write_episode(workcell: Workcell, out_dir, seed: int | None = None, progress: bool = True,
                  frames: Iterable[int] | None = None) -> Path:
    """Simulate the episode and write it to ``out_dir`` (created); returns ``out_dir`` as a Path.

    Files:
        rig.yaml: the depth cameras (:func:`depthguard.save_rig`; loads back with :func:`depthguard.load_rig`).
        frames.csv: ``camera, frame, time``: one row per depth image written (every depth camera, every frame, in
            frame order), capture time in seconds with 6 decimals (design §12a; read back with
            :func:`depthguard.io.recordings.open_recording`).
        intensity_rig.yaml: the intensity cameras, if the scene has any.
        depth/<camera>/<index:06d>.png: 16-bit PNG (ROS 16UC1), units of depth_scale (millimetres), 0 = none.
        intensity/<camera>/<index:06d>.png: 8-bit grey PNG, every camera.
        joint_states.csv: ``time`` (6 decimals, as in frames.csv) then one column per joint, named as
            ``robot.joint_names``, radians.
        ground_truth.csv: one row per frame and control point: ``time, frame, control_point, distance (m),
            nearest_obstacle, nearest_part, touching (0/1), clearance (m)``; distance and clearance are ``inf`` when
            there is no obstacle.
        timeline.csv: ``person, index, action, start, hold_start, end`` (seconds) of every scripted action.
        scene.yaml: the scene (a copy of its data; a relative URDF path is made absolute).

    Every file is written whole (:func:`depthguard.io.files.atomic_write`), and frames.csv last, once every frame is
    written: a folder without frames.csv is an episode that did not finish
    (:func:`~depthguard.io.recordings.open_recording` refuses it), never a shorter one that reads as complete.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / "frames.csv").unlink(missing_ok=True)  # an earlier episode's: the folder is incomplete until the end
    save_rig(workcell.rig, out / "rig.yaml")
    if workcell.intensity_rig is not None:
        save_rig(workcell.intensity_rig, out / "intensity_rig.yaml")
    scene = dict(workcell.scene)
    robot_entry = scene.get("robot")
    if isinstance(robot_entry, dict) and "urdf" in robot_entry:
        scene["robot"] = {**robot_entry, "urdf": str((workcell.base_dir / str(robot_entry["urdf"])).resolve())}
    write_whole(out / "scene.yaml", yaml.safe_dump(scene, sort_keys=False, default_flow_style=None))
    with atomic_write(out / "timeline.csv", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["person", "index", "action", "start", "hold_start", "end"])
        for span in workcell.timeline():
            writer.writerow([span.person, span.index, span.kind, f"{span.start:.6f}", f"{span.hold_start:.6f}",
                             f"{span.end:.6f}"])
    for camera in workcell.rig.cameras:
        (out / "depth" / camera).mkdir(parents=True, exist_ok=True)
    for camera in workcell.all_cameras():
        (out / "intensity" / camera.name).mkdir(parents=True, exist_ok=True)
    indices = list(range(workcell.n_frames) if frames is None else frames)
    iterator = simulate(workcell, seed=seed, frames=indices)
    if progress:
        from tqdm import tqdm

        iterator = tqdm(iterator, total=len(indices), unit="frame", desc="simulating")
    # PNGs are compressed on a second thread (zlib releases the GIL) while the next frame is simulated.
    writer = ThreadPoolExecutor(max_workers=1)
    pending: deque = deque()
    with ExitStack() as files:
        # The CSVs are renamed to their names as the block ends, in the reverse order: frames.csv last.
        frames_file = files.enter_context(atomic_write(out / "frames.csv", newline=""))
        truth_file = files.enter_context(atomic_write(out / "ground_truth.csv", newline=""))
        joints_file = files.enter_context(atomic_write(out / "joint_states.csv", newline=""))
        files.enter_context(writer)
        joints_csv, truth_csv, frames_csv = csv.writer(joints_file), csv.writer(truth_file), csv.writer(frames_file)
        joints_csv.writerow(["time", *workcell.robot.joint_names])
        frames_csv.writerow(["camera", "frame", "time"])
        truth_csv.writerow(["time", "frame", "control_point", "distance", "nearest_obstacle", "nearest_part",
                            "touching", "clearance"])
        for frame in iterator:
            pending.append(writer.submit(_write_frame, out, frame))
            while len(pending) > 2:
                pending.popleft().result()  # re-raises a failed write
            joints_csv.writerow([f"{frame.time:.6f}", *(repr(float(x)) for x in frame.joints)])
            for name, image in frame.depth.items():
                frames_csv.writerow([name, frame.index, f"{image.timestamp:.6f}"])
            truth = frame.truth
            for k, name in enumerate(truth.control_points):
                truth_csv.writerow([f"{frame.time:.6f}", frame.index, name, _number(truth.distance[k]),
                                    truth.nearest[k], truth.nearest_part[k], int(truth.touching),
                                    _number(truth.clearance)])
        while pending:
            pending.popleft().result()
    return out


def _write_frame(out: Path, frame: SimFrame) -> None:
    """The frame's depth PNGs (16-bit grey, as ``depthguard.depth.write_depth_png`` writes them, but with zlib level
    ``lab_config.SIM_PNG_COMPRESSION``: level 6 takes about 4 times as long for a 5 % smaller noisy depth image) and
    intensity PNGs (8-bit grey)."""
    stem = f"{frame.index:06d}.png"
    level = lab_config.SIM_PNG_COMPRESSION
    for name, image in frame.depth.items():
        data = np.asarray(image.data)
        if data.dtype != np.uint16 or data.ndim != 2:
            raise InputError(f"depth image of camera {name!r} is not a 2-D uint16 array")
        with atomic_write(out / "depth" / name / stem, "wb") as f:
            Image.fromarray(data).save(f, format="PNG", compress_level=level)
    for name, grey in frame.intensity.items():
        with atomic_write(out / "intensity" / name / stem, "wb") as f:
            Image.fromarray(grey).save(f, format="PNG", compress_level=level)


def _number(x: float) -> str:
    return "inf" if math.isinf(x) else f"{x:.6f}"

