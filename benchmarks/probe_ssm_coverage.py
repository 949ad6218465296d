"""What speed and separation monitoring needs to let the robot move in scenario B's workcell (issue 9), layout by layout.

With no person in the room (scenario_b_reach.yaml at 5.2 s, the person gone), SSM lets a control point move only when
its distance from the link's surface to the nearest possibly occupied space is at least S_p at rest. This probe
prints, per layout, that distance for every control point and the nearest possibly occupied point (the monitor's
``min`` answer: the point minus distance times direction), so that what stands in the way can be read off; what those
answers may hide next to a surface (``DistanceMonitor.query_hidden_band``: SSM on them is refused above ISO 13855's
70 mm); whether the detectable space with the loop's settings is allowed; and the distances SSM may use with the
settings that are sound, ``DistanceMonitor(detection_capability=d)`` with no robot zone (possibly occupied regions
thinner than the detection capability left out: ``depthguard.freespace.DetectableSpace``; the robot's inside counts
free), for d = 40 mm, and in the SSM layout also 55 and 70 mm (ISO 13855's largest; C = 8 (d - 14) mm grows with it):

    .venv/bin/python benchmarks/probe_ssm_coverage.py [--time 5.2] [--rho 1.5] [--loop]

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
import tempfile
from importlib import resources
from pathlib import Path

import numpy as np

import depthguard as dg
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


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--time", type=float, default=5.2, help="seconds into scenario_b_reach.yaml (default 5.2)")
    parser.add_argument("--rho", type=float, default=1.5, help="the monitor's rho, metres (default 1.5)")
    parser.add_argument("--loop", action="store_true",
                        help="also run the demo's mode ssm in its cell with the sound settings (about a minute per d)")
    args = parser.parse_args(argv)
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
        print(f"  {d * 1000:5.0f} {8 * (d * 1000 - 14):5.0f} {len(scale):6d} {np.mean(scale > 0):10.1%} "
              f"{scale.mean():6.2f} {np.quantile(scale, 0.9):6.2f} {scale.max():6.2f}")


if __name__ == "__main__":
    with report(__file__):
        main()
