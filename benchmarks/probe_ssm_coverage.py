"""What speed and separation monitoring needs to let the robot move in scenario B's workcell (issue 9), layout by layout.

With no person in the room (scenario_b_reach.yaml at 5.2 s, the person gone), SSM lets a control point move only when
its distance from the link's surface to the nearest possibly occupied space is at least S_p at rest. This probe
prints, per layout, that distance for every control point and the nearest possibly occupied point (the monitor's
``min`` answer: the point minus distance times direction), so that what stands in the way can be read off; what those
answers may hide next to a surface (``DistanceMonitor.query_hidden_band``: SSM on them is refused above ISO 13855's
70 mm); whether the detectable space with the loop's settings is allowed; and the distances SSM may use with the
settings that are sound, ``DistanceMonitor(detection_capability=d)`` with no robot zone (possibly occupied regions
thinner than the detection capability left out: ``depthguard.freespace.DetectableSpace``; the robot's inside counts
free), for d = 40 mm, and in the SSM layout also 55 and 70 mm (ISO 13855's largest; its C: 8 (d - 14) mm up to
40 mm, 850 mm above):

    .venv/bin/python benchmarks/probe_ssm_coverage.py [--time 5.2] [--rho 1.5] [--loop]
    .venv/bin/python benchmarks/probe_ssm_coverage.py --bound [--start 3.5] [--settle 0.5] [--two] [--fine 0.007]
    .venv/bin/python benchmarks/probe_ssm_coverage.py --margins [--time 5.2] [--nearer 0.45]

``--bound`` prints only the factor SSM allows along the task from an ideal sound memory opened by d beside the
project's (issue 35 item 6; :func:`bound`; figures in ``docs/figures/probe_ssm_coverage_bound.md``); with ``--fine S``,
beside a sound rule's rounding of that ideal on a grid of S (``docs/figures/probe_ssm_coverage_bound_fine.md`` for 1 cm,
``..._fine_7mm.md`` for 0.007).

Layouts (the variants are written from the packaged scene files into a temporary directory):
- ``two``: the scene's two front cameras, workspace top z = 1.5 m (the principal sees up to about z = 1.5 there);
- ``four``: issue 8's four cameras;
- ``four+ceiling``: the four, and a wide-angle camera 3.2 m up looking down as the depth grid's principal (512 x 512,
  120 degrees, as a binned wide-field ToF), the workspace up to z = 2.2 m and 0.1 m wider;
- ``... known``: the same with the floor, the walls and the pedestal given to the monitor as known static solids
  (``DistanceMonitor(static=...)``);
- ``... wide pedestal``: a 0.5 m pedestal instead of 0.3 m;
- ``scenario_b_ssm.yaml``: the packaged SSM layout (the four and the ceiling camera, time-of-flight-class noise),
  the solids known.
"""

from __future__ import annotations

import argparse
import math
import tempfile
from importlib import resources
from pathlib import Path

import numpy as np

import depthguard as dg
from depthguard.avoidance import intrusion_distance
from depthguard import config
from depthguard_lab.simulation import load_workcell
from depthguard_lab.simulation._episode import sense_at
from _common import report

PACKAGE = resources.files("depthguard_lab.simulation")

CEILING = """  - name: ceiling          # 3.2 m up, looking straight down: the depth grid's principal
    width: 512
    height: 512
    fx: 147.8
    fy: 147.8
    cx: 255.5
    cy: 255.5
    look_at: {eye: [0.3, 0.0, 3.2], target: [0.3, 0.0, 0.0], up: [1.0, 0.0, 0.0]}
    depth_range: [0.25, 5.46]
    noise: {a: 0.001504, b: -0.00152, c: 0.0019, k: 3.0}
"""


def _variant(directory: Path, name: str, ceiling: bool, wide_pedestal: bool) -> Path:
    reach = (PACKAGE / "scenario_b_reach.yaml").read_text()
    if name != "two":
        four = (PACKAGE / "scenario_b_four.yaml").read_text()
        start = four.index("  - name: third")
        end = four.index("\n\n", four.index("  - name: fourth"))
        reach = reach.replace("\n# No intensity", "\n" + four[start:end] + "\n\n# No intensity", 1)
    if ceiling:
        reach = reach.replace("\n# No intensity", "\n" + CEILING + "\n# No intensity", 1)
        reach = reach.replace("principal: principal ", "principal: ceiling   ")
        reach = reach.replace("workspace: [[-1.5, -1.5, -0.5], [1.5, 1.5, 1.5]]",
                              "workspace: [[-1.6, -1.6, -0.5], [1.9, 1.6, 2.2]]")
    if wide_pedestal:
        reach = reach.replace("box: {min: [-0.15, -0.15, -0.5], max: [0.15, 0.15, 0.0]}",
                              "box: {min: [-0.25, -0.25, -0.5], max: [0.25, 0.25, 0.0]}")
    path = directory / f"{name}_{int(ceiling)}{int(wide_pedestal)}.yaml"
    path.write_text(reach)
    return path


def probe(path: Path, t: float, rho: float, known: bool, layout: Path | None = None, capabilities=(0.04,)):
    """At time t with the person gone: (the depth grid's distances from each link's surface, its nearest possibly
    occupied point per control point, the detectable distances from each link's surface by detection capability
    (metres -> (9,) metres), what the loop's settings would hide (band, why, refusal), names).

    The depth grid's answers use the loop's settings (robot zone 6 cm, invalid="neighbors"). SSM's detectable space
    with those settings is refused (d + the band they hide is above ISO 13855's 70 mm), so its distances here are
    those of the settings that are sound: no robot zone, holes occupied; the robot's inside (Robot_k) counts free,
    the layer between it and what the cameras see free does not."""
    workcell = load_workcell(path, layout=layout)
    robot = workcell.robot
    static = workcell.background_parts() if known else None
    loop = dict(rho=rho, robot=robot, aggregate="min", invalid="neighbors", robot_zone=config.LOOP_ROBOT_ZONE,
                static=static)
    monitor = dg.DistanceMonitor(workcell.rig, **loop)
    band, why = monitor.query_hidden_band()
    try:
        dg.DistanceMonitor(workcell.rig, **loop, detection_capability=config.SSM_DETECTION_CAPABILITY)
        refusal = None
    except dg.InputError as error:
        refusal = str(error)
    q = workcell.joints_at(t)
    (frame,) = sense_at(workcell, [t])
    points = robot.control_point_positions(q)
    result = monitor.prepare_set(frame.depth, joints=q, now=t).query(points)
    radii = robot.control_point_radii
    detectable = {}
    for d in capabilities:
        sound = dg.DistanceMonitor(workcell.rig, rho=rho, robot=robot, aggregate="min", static=static,
                                   detection_capability=d)
        distance = sound.prepare_set(frame.depth, joints=q, now=t).detectable_distances(points, limit=rho).distance
        detectable[d] = np.maximum(distance - radii, 0.0)
    nearest = points - np.where(np.isfinite(result.distance), result.distance, 0.0)[:, None] * result.direction
    return (result.distance - radii, nearest, detectable, (band, why, refusal), list(robot.control_point_names))


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--time", type=float, default=5.2, help="seconds into scenario_b_reach.yaml (default 5.2)")
    parser.add_argument("--rho", type=float, default=1.5, help="the monitor's rho, metres (default 1.5)")
    parser.add_argument("--loop", action="store_true",
                        help="also run the demo's mode ssm in its cell with the sound settings (about a minute per d)")
    parser.add_argument("--bound", action="store_true",
                        help="only the factor an ideal sound memory opened by d allows in the SSM cell, beside the "
                             "project's, along the task (about 15 minutes)")
    parser.add_argument("--start", type=float, default=3.5, help="--bound: seconds, where the memories start")
    parser.add_argument("--settle", type=float, default=0.5, help="--bound: seconds of start-up not counted")
    parser.add_argument("--two", action="store_true", help="--bound: in the scene's two-camera layout")
    parser.add_argument("--fine", type=_grid_spacing, default=None,
                        help="--bound: only the ideal with every margin on its 1 cm grid, beside a sound rule's "
                             "rounding of it on a grid this fine (metres, at most 0.02), and the project")
    parser.add_argument("--margins", action="store_true",
                        help="only what holds the project's detectable distances at 0 in the SSM cell: its voxels, "
                             "the robot's inside and each margin, one at a time (about 3 minutes)")
    parser.add_argument("--nearer", type=float, default=None,
                        help="--margins: every camera this fraction of its distance from where it looks (0-1]")
    return parser


def figure_name(args: argparse.Namespace) -> str | None:
    """The figure a run writes (``docs/figures/<name>.md``), or None for the default tables: ``--bound`` in
    probe_ssm_coverage_bound[_two][_fine | _fine_7mm] (``_fine`` for 1 cm, the first such figure), ``--margins`` in
    probe_ssm_coverage_margins[_nearer]."""
    if args.bound:
        fine = "" if args.fine is None else "_fine" if math.isclose(args.fine, 0.01) else \
            f"_fine_{args.fine * 1000:g}mm"
        return "probe_ssm_coverage_bound" + ("_two" if args.two else "") + fine
    if args.margins:
        return "probe_ssm_coverage_margins" + ("_nearer" if args.nearer is not None else "")
    return None


def main(argv=None) -> None:
    args = _parser().parse_args(argv)
    if args.bound:
        bound(args.start, args.settle, verbose=True, two=args.two, fine=args.fine)
        return
    if args.margins:
        margins(args.time, args.nearer)
        return
    ssm_layout = Path(str(PACKAGE / "scenario_b_ssm.yaml"))
    rows = [("two", False, False, False, None), ("four", False, False, False, None),
            ("four+ceiling", True, False, False, None), ("four+ceiling known", True, False, True, None),
            ("four+ceiling known wide pedestal", True, True, True, None),
            ("scenario_b_ssm.yaml known (ToF noise)", False, False, True, ssm_layout)]
    print(f"distances from the links' surfaces, metres; t = {args.time} s; detectable: the detection capability d "
          "on each row\n")
    with tempfile.TemporaryDirectory() as tmp:
        for label, ceiling, wide, known, layout in rows:
            base = "two" if label == "two" else "four"
            path = _variant(Path(tmp), base, ceiling, wide) if layout is None else PACKAGE / "scenario_b_reach.yaml"
            capabilities = (0.04, 0.055, 0.07) if layout is not None else (0.04,)
            distance, nearest, detectable, (band, why, refusal), names = probe(Path(str(path)), args.time,
                                                                                 args.rho, known, layout, capabilities)
            worst = int(np.argmin(distance))
            print(f"{label:38s} grid       {' '.join(f'{d:5.2f}' for d in distance)}   least {distance[worst]:.2f} "
                  f"({names[worst]}), nearest possibly occupied point {np.round(nearest[worst], 2).tolist()}")
            print(f"{'':38s} what the grid's answers may hide next to a surface: {band:.3f} m ({why}): SSM on them "
                  f"{'refused' if band > config.SSM_INTRUSION_LIMIT else 'allowed'}")
            print(f"{'':38s} detectable with the loop's settings: "
                  f"{'refused: ' + refusal.split(': ', 1)[-1][:110] if refusal else 'allowed'}")
            for d, row in detectable.items():
                print(f"{'':38s} detectable, sound, d {d * 1000:2.0f} mm {' '.join(f'{x:5.2f}' for x in row)}   "
                      f"least {row.min():.2f} ({names[int(np.argmin(row))]})")
    print("\ncolumns: " + " ".join(names))
    if args.loop:
        closed_loop()


def _grid_spacing(text: str) -> float:
    """--fine's value: metres, finite, in (0, 0.02] (a grid step no longer than the ball's radius, d / 2 = 20 mm)."""
    value = float(text)
    if not 0.0 < value <= 0.02:  # also refuses nan and inf
        raise argparse.ArgumentTypeError(f"a grid spacing in metres in (0, 0.02], got {text!r}")
    return value


def closed_loop(capabilities=(0.04, 0.07)) -> None:
    """The demo's mode ssm in its cell (``avoidance_demo.ssm_scene``) over the scene's whole span, with the settings
    that are sound there (no robot zone, unmeasured pixels occupied, SSM's C for d): the speed factor it applied."""
    import dataclasses

    from depthguard.avoidance import SSMParams
    from depthguard_lab.experiments.avoidance_demo import ssm_scene
    from depthguard_lab.simulation._closed_loop import run_closed_loop

    cell, settings = ssm_scene()
    print(f"\nclosed loop, mode ssm in its cell (scenario_b_ssm.yaml), {cell.duration:g} s, the person reaching in "
          "and leaving, no robot zone, holes occupied: the speed factor applied at the control steps")
    print(f"  {'d mm':>5s} {'C mm':>5s} {'steps':>6s} {'factor > 0':>10s} {'mean':>6s} {'p90':>6s} {'max':>6s}")
    for d in capabilities:
        run = dataclasses.replace(settings, monitor=dict(aggregate="min", invalid="occupied", robot_zone=0.0),
                                  ssm=SSMParams(detection_capability=d))
        scale = run_closed_loop(cell, "ssm", settings=run).scale
        print(f"  {d * 1000:5.0f} {intrusion_distance(d) * 1000:5.0f} {len(scale):6d} {np.mean(scale > 0):10.1%} "
              f"{scale.mean():6.2f} {np.quantile(scale, 0.9):6.2f} {scale.max():6.2f}")


def _loop_ssm(robot, settings, d: float):
    """The demo's SSM (its rho, the joints' braking, the robot's reaches) with C for detection capability d."""
    from depthguard.avoidance import JointLimits, SpeedSeparationMonitor, SSMParams

    limits = JointLimits.from_robot(robot, acceleration=settings.acceleration)
    return SpeedSeparationMonitor(SSMParams(detection_capability=d), rho=settings.ssm_rho, braking=limits.acceleration,
                                  reaches=robot.joint_reaches())


def _sound_options(cell, settings, d: float) -> dict:
    """``DistanceMonitor`` options of SSM's sound settings in ``cell``: no robot zone, holes occupied, the solids
    known, detection capability d."""
    return dict(rho=settings.ssm_rho, robot=cell.robot, aggregate="min", invalid="occupied", robot_zone=0.0,
                static=cell.background_parts(), detection_capability=d)


def _from_spheres(distance: np.ndarray, radii: np.ndarray, rho: float) -> np.ndarray:
    """(m,) metres from the control points' spheres: ``distance`` less ``radii``, inf counted as rho, at least 0."""
    return np.maximum(np.where(np.isfinite(distance), distance, rho) - radii, 0.0)


#: --bound: the ideal's grid, a box round the task's control points (they span x 0-0.55, y -0.17-0.08,
#: z 0.19-0.89 m) 0.65 m wider on every side but the floor (z = -0.5); SSM at d = 40 mm needs at most 0.46 m from
#: any point's sphere for the whole speed, so an answer "at least to the box's side" costs no factor.
BOUND_BOX = ((-0.65, -0.82, -0.5), (1.2, 0.73, 1.54))


def bound(start: float, settle: float, d: float = 0.04, spacing: float = 0.01, verbose: bool = False,
          two: bool = False, fine: float | None = None) -> None:
    """Issue 35 item 6 for SSM: along the task in the SSM cell (``avoidance_demo.ssm_scene``, the robot where its
    script puts it, not slowed), the factor SSM allows each frame from the distances of an ideal sound memory opened
    by d (:class:`depthguard_lab.experiments.ideal_memory.IdealMemory` with ``opening=d``: exact ray casts, the
    robot's exact volume, erosion at v_max; on the exact renders, on the frames as the cameras measured them with
    their noise margins, a pixel without a measurement seeing nothing free, and on those with the project's
    calibration margin and pixel of pad too: ``fusion_margin``, ``fusion_pixels``) and from the project's
    detectable distances (the loop's sound settings: no robot zone, holes occupied, the solids known), on the same
    frames, with the same SSM (C for d, the joints' braking, T_r = one frame's latency + one control step, the
    task's command) and the loop's look-ahead. Both memories start at ``start`` seconds with everything possibly
    occupied; the first ``settle`` seconds are not counted. ``two``: in the scene's own layout (its two front
    Kinect-class cameras) instead of the SSM cell's five. ``fine`` (metres): only the ideal with every margin, on
    its ``spacing`` grid (the bound), and what a sound rule with the ideal's exact tests would give on a grid of
    ``fine`` (s): the ideal's points stand for themselves (a ball centred on a grid point, free points only at grid
    points), which is generous; a sound rule keeps a grid point as a ball's centre unless a free point lies within
    r - s sqrt(3) / 2 of it (then every point of its cube has one within r) and counts its distance from the cube
    less r. That row is the ideal on the fine grid with the radius r' = r - s sqrt(3) / 2 and its distances less a
    whole diagonal, s sqrt(3). Since each opened grid point lies within r' of a centre, such a rule's distance is at
    most the opened points' distance less s sqrt(3) / 2: at most half a diagonal above the row's. The project's rule
    differs: 1 cm voxels each wholly free, the robot's inside from inner balls, a cell's footprint of pixels."""
    from depthguard_lab.experiments.avoidance_demo import ssm_scene
    from depthguard_lab.experiments.ideal_memory import IdealMemory, measured_depths
    from depthguard_lab.simulation._closed_loop import _detectable, _ssm_factor, beyond_rho
    from depthguard_lab.simulation._episode import SceneRenderer, sense
    from depthguard_lab.simulation._truth import TruthComputer

    cell, settings = ssm_scene()
    layout = "scenario_b_ssm.yaml"
    if two:
        cell, layout = load_workcell(Path(str(PACKAGE / "scenario_b_reach.yaml"))), "its own two cameras"
    robot = cell.robot
    points_robot = robot.with_surface_points(settings.surface_tolerance)
    radii = points_robot.control_point_radii
    ssm = _loop_ssm(robot, settings, d)
    dt = 1.0 / settings.control_rate
    reaction = settings.latency + dt
    monitor = dg.DistanceMonitor(cell.rig, **_sound_options(cell, settings, d))
    margins = dict(noise_margin=True, measured=True, bounds=BOUND_BOX, opening=d,
                   calibration=monitor.settings.fusion_margin, pad=monitor.settings.fusion_pixels)
    if fine is None:
        ideals = {"ideal, exact": IdealMemory(cell, spacing=spacing, bounds=BOUND_BOX, opening=d),
                  "ideal, measured": IdealMemory(cell, spacing=spacing, noise_margin=True, measured=True,
                                                 bounds=BOUND_BOX, opening=d),
                  "ideal, margins": IdealMemory(cell, spacing=spacing, **margins)}
        less = dict.fromkeys(ideals, 0.0)  # metres taken from each one's distances
    else:  # a sound rule's rounding on the fine grid: the centre's radius less half a cube's diagonal
        half = fine * math.sqrt(3.0) / 2.0
        rule = f"sound rule, {fine * 1000:g} mm"
        ideals = {f"ideal, margins, {spacing * 1000:g} mm": IdealMemory(cell, spacing=spacing, **margins),
                  rule: IdealMemory(cell, spacing=fine, **{**margins, "opening": d - 2.0 * half})}
        less = {name: 2.0 * half if name == rule else 0.0 for name in ideals}
    rows = {name: [] for name in ["project", *ideals]}
    least = {name: [] for name in rows}
    truth = TruthComputer(robot)
    parts = {name: cell.part_names(name) for name in cell.obstacle_names}
    scene = SceneRenderer(cell, None)
    static = {o.name for o in cell.static_objects}
    person = []
    print(f"\nthe bound for SSM (issue 35 item 6): {cell.duration:g} s of scenario_b_reach.yaml in "
          f"{layout}, the robot on its script, d = {d * 1000:.0f} mm "
          f"(C = {intrusion_distance(d) * 1000:.0f} mm), "
          f"T_r = {reaction * 1000:.0f} ms; the memories start at {start:g} s, counted from {start + settle:g} s; "
          f"the ideal's grid {spacing * 100:g} cm{f' and {fine * 1000:g} mm' if fine else ''} over {BOUND_BOX}")
    try:
        for index in range(int(round(start * cell.rate)), int(round(cell.duration * cell.rate)) + 1):
            t = index / cell.rate
            q = cell.joints_at(t).copy()
            frame = sense(cell, scene, truth, parts, q, t, index, 0)
            prepared = monitor.prepare_set(frame.depth, joints=q, now=t)
            for ideal in ideals.values():
                ideal.update(t, q, measured_depths(frame.depth) if ideal.measured else frame.depth_exact, frame.label)
            if t < start + settle - 1e-9:
                continue
            points, jacobians = points_robot.control_point_kinematics(q)
            later = min(t + dt, cell.duration)  # the task's command (at the end: the step before)
            dq = (cell.joints_at(later) - cell.joints_at(later - dt)) / dt
            moving = [i for i, name in enumerate(frame.truth.obstacles) if name not in static]
            person.append(float(np.min(frame.truth.distances[:, moving], initial=np.inf)))
            asks = {"project": (prepared, lambda p, x: _detectable(p, x, settings.ssm_rho))}
            for name, ideal in ideals.items():
                asks[name] = (ideal, lambda p, x, less=less[name]: beyond_rho(np.maximum(p.nearest(x) - less, 0.0),
                                                                            settings.ssm_rho))
            for name, (source, ask) in asks.items():
                distance = ask(source, points)
                least[name].append(float(np.min(_from_spheres(distance, radii, settings.ssm_rho))))
                rows[name].append(_ssm_factor(ssm, source, distance, points, jacobians, dq, reaction, radii,
                                              settings.ssm_lookahead, ask))
            if verbose and (index % 3 == 0):
                print(f"  {t:5.2f} s person {person[-1]:5.2f} m " + "  ".join(
                    f"{name} {rows[name][-1]:4.2f} ({least[name][-1]:5.3f} m)" for name in rows))
    finally:
        scene.release()
    person = np.asarray(person)
    far = person > 1.5
    print(f"  {len(person)} frames, the person more than 1.5 m from every control point in {int(far.sum())}")
    print(f"  {'memory':16s} {'factor > 0':>10s} {'mean':>6s} {'p50':>6s} {'mean, person > 1.5 m':>20s} "
          f"{'least detectable distance, p50':>30s}")
    for name, factor in rows.items():
        factor = np.asarray(factor)
        mean_far = f"{factor[far].mean():.2f}" if far.any() else "-"
        print(f"  {name:16s} {np.mean(factor > 0):10.1%} {factor.mean():6.2f} {np.median(factor):6.2f} "
              f"{mean_far:>20s} {np.median(least[name]):30.3f}")


def _nearer_layout(directory: Path, fraction: float) -> Path:
    """scenario_b_ssm.yaml with every camera moved towards the point it looks at, to ``fraction`` of its distance."""
    import re

    def move(match):
        eye, target = (np.array([float(x) for x in match.group(i).split(",")]) for i in (1, 2))
        eye = target + fraction * (eye - target)
        return f"look_at: {{eye: [{', '.join(f'{x:.3f}' for x in eye)}], target: [{match.group(2)}],"

    text = re.sub(r"look_at: \{eye: \[([^\]]*)\], target: \[([^\]]*)\],", move,
                  (PACKAGE / "scenario_b_ssm.yaml").read_text())
    path = directory / f"scenario_b_ssm_nearer_{fraction:g}.yaml"
    path.write_text(text)
    return path


def margins(t: float, nearer: float | None = None) -> None:
    """What holds SSM's detectable distances at 0 in the SSM cell (``avoidance_demo.ssm_scene``, the person gone at
    ``t``): the project's detectable distances at the demo's 21 control points and the factor SSM allows there (as
    :func:`bound` computes it), with its sound settings (no robot zone, holes occupied, the solids known), and with
    one thing changed at a time:

    - ``6 mm``: the detectable space's voxels 6 mm instead of 1 cm, over :data:`BOUND_BOX` (the whole cell at 6 mm
      is over ``config.FREESPACE_MAX_VOXELS``; beyond the box counts possibly occupied, so no distance reaches
      beyond its side, about 0.5 m: enough for d = 40 mm's whole speed, 0.46 m, never for the 850 mm of C above
      40 mm);
    - ``inside 6 mm``: the robot's inside from balls found on a 6 mm grid, up to 1500 a link (about 5,000 for the
      iiwa, 23 s to find, nearly its exact inside), instead of ``config.INNER_BALLS`` on 1 cm;
    - ``exact``: the noise-free renders instead of the sensor's frames (no noise, no dropouts);
    - the margins: the noise margin (k = 3 sigma, ``k 0``: none), the calibration margin (``fusion_margin``, 10 mm)
      and the pixel of pad (``fusion_pixels``).

    Dropping a margin is not sound: these rows only say what each costs. ``nearer``: every camera moved towards the
    point it looks at, to that fraction of its distance (its noise margin and its pixels' footprint shrink)."""
    import dataclasses

    import depthguard.robots._inner as inner
    import depthguard.robots._model as robot_model
    from depthguard_lab.experiments.avoidance_demo import ssm_scene
    from depthguard_lab.simulation._closed_loop import _detectable, _ssm_factor

    cell, settings = ssm_scene()
    if nearer is not None:
        with tempfile.TemporaryDirectory() as tmp:
            cell = load_workcell(Path(str(PACKAGE / "scenario_b_reach.yaml")), layout=_nearer_layout(Path(tmp), nearer))
        print(f"every camera at {nearer:g} of its distance from where it looks: " + "; ".join(
            f"{name} {np.linalg.norm(camera.T_world_camera[:3, 3] - [0.3, 0.0, 0.6]):.2f} m from the arm's middle"
            for name, camera in cell.rig.cameras.items()))
    robot = cell.robot
    points_robot = robot.with_surface_points(settings.surface_tolerance)
    radii = points_robot.control_point_radii
    dt = 1.0 / settings.control_rate
    times = [t - i / cell.rate for i in (3, 2, 1, 0)]
    frames = sense_at(cell, times)
    q = frames[-1].joints
    points, jacobians = points_robot.control_point_kinematics(q)
    dq = (cell.joints_at(t) - cell.joints_at(t - dt)) / dt
    exact = [{name: dataclasses.replace(image, data=np.round(np.asarray(f.depth_exact[name]) / image.depth_scale)
                                        .astype(np.uint16)) for name, image in f.depth.items()} for f in frames]
    rig = cell.rig
    noiseless = dataclasses.replace(rig, cameras={name: dataclasses.replace(c, noise=dataclasses.replace(c.noise,
                                                                                                         k=0.0))
                                                  for name, c in rig.cameras.items()})
    fine = dict(detectable_voxel=0.006)
    free = dict(fusion_margin=0.0, fusion_pixels=0)
    rows = [  # (label, dense inside, rig, box, options, exact)
        ("sound settings (1 cm voxels over the cell)", False, rig, False, {}, False),
        ("6 mm", False, rig, True, fine, False),
        ("6 mm, exact, no margin", False, noiseless, True, {**fine, **free}, True),
        ("6 mm, inside 6 mm", True, rig, True, fine, False),
        ("6 mm, inside 6 mm, exact, no margin", True, noiseless, True, {**fine, **free}, True),
        ("... and the noise margin (3 sigma)", True, rig, True, {**fine, **free}, True),
        ("... or the calibration margin (10 mm)", True, noiseless, True, {**fine, "fusion_pixels": 0}, True),
        ("... or the pixel of pad", True, noiseless, True, {**fine, "fusion_margin": 0.0}, True),
        ("6 mm, inside 6 mm, sensor frames, no margin", True, noiseless, True, {**fine, **free}, False),
        ("6 mm, inside 6 mm, d 55 mm", True, rig, True, {**fine, "detection_capability": 0.055}, False),
        ("6 mm, inside 6 mm, d 70 mm", True, rig, True, {**fine, "detection_capability": 0.07}, False),
    ]
    print(f"what holds SSM's detectable distances at 0: the SSM cell at {t:g} s (the person gone), the demo's "
          f"{len(points)} control points, distances from their spheres, metres; the factor SSM allows for the task's "
          "command there (T_r one frame + one control step)")
    print(f"  {'':46s} {'d mm':>4s} {'C mm':>4s} {'points > 0':>10s} {'least':>6s} {'median':>6s} {'factor':>6s}")
    original = inner.inner_balls
    try:
        for label, dense, row_rig, box, options, use_exact in rows:
            if dense and inner.inner_balls is original:  # the model's balls are cached per process: found again
                inner.inner_balls = lambda mesh, link: original(mesh, link, spacing=0.006, count=1500)
                robot_model._INNER_CAPSULES.clear()
            options = {**_sound_options(cell, settings, 0.04), **options}
            row_rig = dataclasses.replace(row_rig, workspace=np.asarray(BOUND_BOX)) if box else row_rig
            monitor = dg.DistanceMonitor(row_rig, **options)
            for f, depth in zip(frames, exact if use_exact else [f.depth for f in frames]):
                prepared = monitor.prepare_set(depth, joints=f.joints, now=f.time)
            d = options["detection_capability"]
            ssm = _loop_ssm(robot, settings, d)
            distance = _detectable(prepared, points, settings.ssm_rho)
            surface = _from_spheres(distance, radii, settings.ssm_rho)
            factor = _ssm_factor(ssm, prepared, distance, points, jacobians, dq, settings.latency + dt, radii,
                                 settings.ssm_lookahead, lambda p, x: _detectable(p, x, settings.ssm_rho))
            print(f"  {label:46s} {d * 1000:4.0f} {intrusion_distance(d) * 1000:4.0f} "
                  f"{f'{int(np.sum(surface > 0))} / {len(surface)}':>10s} {surface.min():6.3f} "
                  f"{np.median(surface):6.3f} {factor:6.2f}", flush=True)
    finally:
        inner.inner_balls = original
        robot_model._INNER_CAPSULES.clear()


if __name__ == "__main__":
    # Parsed once before the figure is opened, so that a refused value writes no figure.
    with report(__file__, name=figure_name(_parser().parse_args())):
        main()
