"""Reference scenario C (design §12, issue 10): the image-based collision test on the simulated workcell of
``scenario_c.yaml`` (four 704 x 576 cameras, a UFACTORY xArm 6, a person walking in and reaching, the light dimming by
20 %), for intensity and depth images, judged by the exact ground truth (coal: the robot's collision meshes against
the person's capsules).

The reference images are the median of the first 3 s (the robot moving, nobody in view), each pixel's median over
the images whose robot does not cover its tile (``set_reference(..., joints=...)``). Every third frame after
that is observed; at each, future configurations are tested: the trajectory's configuration 0.2 - 1.0 s ahead,
random configurations around one of them (+-0.6 rad per joint), as many anywhere within the joint limits (at most
+-pi), and a quarter as many chosen as the nearest to the person among 300 random ones (so that some touch it). A configuration that truly touches the person (clearance
< 0) and is not reported as a collision is a miss; a reported collision whose true clearance exceeds 0.15 m is a
false alarm.

    .venv/bin/python benchmarks/probe_collision_scenario_c.py [--every 3] [--future 40] [--images intensity depth]

With depth images, more rules (issue 27): ``+ depth order`` (ImageCollisionTest(depth_order=True), class B
colliding), and ``depth grid``: the library's DepthGridCollisionTest (a configuration collides unless every
sphere over its moving links, ``with_surface_points(0.01)``, lies farther than its radius plus 2.5 pixel footprints
+ 1 mm from possibly occupied space, the space between links checked like the rest; a DistanceMonitor with its
defaults but rho = 0.3 m, the free-space memory on; unmeasured pixels occupied, and again filled from their
neighbours). ``no slack`` is a diagnosis, not a rule: the same without the slack of 2.5 pixel footprints + 1 mm; it
can miss what the pixel grid places beyond the truth.
``disagree`` counts the configurations on which a rule and the default image rule differ.

``--ideal SPACING`` adds the bound (issue 35): an ideal sound memory (:mod:`depthguard_lab.experiments.ideal_memory`:
exact ray casts per frame, the robot's exact volume free, the erosion at v_max, on a grid of SPACING metres), fed
the same observed frames as the depth grid's monitor, once on the exact depths and once less each camera's noise
margin. A configuration collides by it when a grid point it leaves possibly occupied lies inside the robot's meshes
at that configuration. ``--ideal-only`` prints only those rows (and the depth grid's, with holes occupied, beside
them).
"""

from __future__ import annotations

import argparse
import time
from importlib import resources

import numpy as np

from depthguard import config

from depthguard.collision import ConfigurationTable, ImageCollisionTest
from depthguard_lab.simulation import load_workcell, simulate
from depthguard_lab.simulation._truth import TruthComputer
from _common import report

FALSE_ALARM_CLEARANCE = 0.15


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--every", type=int, default=3)
    parser.add_argument("--future", type=int, default=40, help="random future configurations per observed frame")
    parser.add_argument("--images", nargs="+", default=["intensity", "depth"], choices=["intensity", "depth"])
    parser.add_argument("--verbose", action="store_true", help="print every missed collision")
    parser.add_argument("--ideal", type=float, metavar="SPACING",
                        help="also the ideal sound memory's verdicts on a grid of SPACING metres (the bound)")
    parser.add_argument("--ideal-only", action="store_true",
                        help="with --ideal: only the ideal rows and the depth grid's (holes occupied)")
    args = parser.parse_args()
    workcell, reference_frames, observed, frames, futures, clearances = scenario_c(args.every, args.future)
    robot = workcell.robot
    truth = TruthComputer(robot)
    part_names = {name: workcell.part_names(name) for name in workcell.obstacle_names}
    print(f"scenario C: {len(observed)} observed frames, {sum(len(v) for v in futures.values())} future "
          f"configurations, {sum(int((v < 0).sum()) for v in clearances.values())} of them touch the person")
    print(f"{'images':10s} {'rule':22s} {'touching':>9s} {'missed':>7s} {'free > 0.15 m':>14s} {'false alarms':>13s} "
          f"{'gain range':>11s} {'ms per set':>11s}")
    rules = [("paper (theta 1, B free)", 1, "free"), ("theta 1, B occupied", 1, "occupied"),
             ("theta 2, B occupied", 2, "occupied"), ("default (C-1, occupied)", None, "occupied")]
    defaults = {}
    if args.ideal and args.ideal_only:
        depth_grid_rule(workcell, frames, observed, futures, clearances, "occupied", defaults)
        for noise_margin in (False, True):
            ideal_rule(workcell, frames, observed, futures, clearances, args.ideal, noise_margin)
        return
    for kind in args.images:
        source = (lambda f: f.intensity) if kind == "intensity" else (lambda f: {n: d.data for n, d in f.depth.items()})
        ordered = [("theta 1 + depth order", 1, "occupied"), ("theta 2 + depth order", 2, "occupied"),
                   ("default + depth order", None, "occupied")]
        for rule, theta, unseen in rules + (ordered if kind == "depth" else []):
            test = ImageCollisionTest(workcell.rig, robot, workcell.rig.workspace, tiles=(64, 64), theta=theta,
                                      images=kind, unseen=unseen, depth_order=rule.endswith("depth order"))
            test.set_reference({name: [source(frames[i])[name] for i in reference_frames]
                                for name in workcell.rig.cameras},
                               joints=[frames[i].joints for i in reference_frames])
            touching = missed = free = alarms = 0
            gains, times = [], []
            for i in observed:
                start = time.perf_counter()
                test.observe(source(frames[i]), frames[i].joints)
                collision, _ = ConfigurationTable(test, futures[i]).verdicts()
                if kind == "depth" and rule == "default (C-1, occupied)":
                    defaults[i] = collision
                times.append(time.perf_counter() - start)
                gains += list(test.gains)
                c = clearances[i]
                touching += int((c < 0).sum())
                missed += int(((c < 0) & ~collision).sum())
                if args.verbose:
                    for k in np.flatnonzero((c < 0) & ~collision):
                        pair = truth(futures[i][k], workcell.obstacles_at(frames[i].time), part_names).clearance_pair
                        print(f"  missed: frame {i} ({frames[i].time:.2f} s), clearance {c[k]:.3f} m, {pair}, "
                              f"{test.test(futures[i][k])}")
                free += int((c > FALSE_ALARM_CLEARANCE).sum())
                alarms += int(((c > FALSE_ALARM_CLEARANCE) & collision).sum())
            gain_text = f"{np.nanmin(gains):.2f}-{np.nanmax(gains):.2f}" if kind == "intensity" else "-"
            print(f"{kind:10s} {rule:22s} {touching:9d} {missed:7d} {free:14d} {alarms:7d} ({alarms / max(free, 1):4.0%}) "
                  f"{gain_text:>11s} {np.median(times) * 1e3:11.1f}")
    if "depth" in args.images:
        for invalid in ("occupied", "neighbors"):
            depth_grid_rule(workcell, frames, observed, futures, clearances, invalid, defaults)
        # the closed loop's concessions (a robot zone round the links and filled holes; flagged, each able to hide a
        # hand next to the robot): what the sound rule gives up to be useful
        depth_grid_rule(workcell, frames, observed, futures, clearances, "neighbors", defaults,
                        robot_zone=config.LOOP_ROBOT_ZONE)
    if args.ideal:
        for noise_margin in (False, True):
            ideal_rule(workcell, frames, observed, futures, clearances, args.ideal, noise_margin)


def ideal_rule(workcell, frames, observed, futures, clearances, spacing: float, noise_margin: bool) -> None:
    """The bound's verdicts (the module's docstring, ``--ideal``), printed as a row: what an ideal sound memory fed
    the observed frames leaves possibly occupied inside the robot at each future configuration."""
    from depthguard_lab.experiments.ideal_memory import IdealMemory

    ideal = IdealMemory(workcell, spacing=spacing, noise_margin=noise_margin)
    touching = missed = free = alarms = 0
    times = []
    for i in observed:
        frame = frames[i]
        start = time.perf_counter()
        ideal.update(frame.time, frame.joints, frame.depth_exact, frame.label)
        possibly = ideal.possibly
        collision = np.array([bool(np.any(possibly & ideal.inside_robot(q))) for q in futures[i]])
        times.append(time.perf_counter() - start)
        c = clearances[i]
        touching += int((c < 0).sum())
        missed += int(((c < 0) & ~collision).sum())
        free += int((c > FALSE_ALARM_CLEARANCE).sum())
        alarms += int(((c > FALSE_ALARM_CLEARANCE) & collision).sum())
    rule = f"ideal {spacing * 100:g} cm, {'noise' if noise_margin else 'exact'}"
    print(f"{'depth':10s} {rule:22s} {touching:9d} {missed:7d} {free:14d} {alarms:7d} ({alarms / max(free, 1):4.0%}) "
          f"{'-':>11s} {np.median(times) * 1e3:11.1f}   (the bound: exact geometry, not a rule)")


def scenario_c(every: int = 3, future: int = 40):
    """(workcell, reference frame indices, observed frame indices, frames by index, future configurations by
    observed frame ((k, joints) radians), their true clearances by observed frame ((k,) metres, coal)): the
    module's docstring's sets, seeded."""
    with resources.as_file(resources.files("depthguard_lab.simulation").joinpath("scenario_c.yaml")) as path:
        workcell = load_workcell(path)
    robot = workcell.robot
    reference_frames = range(0, int(3.0 * workcell.rate), 5)
    observed = range(int(3.0 * workcell.rate), workcell.n_frames, every)
    frames = {f.index: f for f in simulate(workcell, frames=sorted(set(reference_frames) | set(observed)))}
    truth = TruthComputer(robot)
    part_names = {name: workcell.part_names(name) for name in workcell.obstacle_names}
    rng = np.random.default_rng(0)
    futures = {}
    for i in observed:
        t = frames[i].time
        ahead = [workcell.joints_at(min(t + s, workcell.duration)) for s in (0.2, 0.4, 0.6, 0.8, 1.0)]
        base = ahead[rng.integers(len(ahead))]
        spread = np.clip(base + rng.uniform(-0.6, 0.6, (future // 2, robot.n_joints)), robot.lower, robot.upper)
        anywhere = rng.uniform(np.maximum(robot.lower, -np.pi), np.minimum(robot.upper, np.pi),
                               (future - future // 2, robot.n_joints))
        # and the configurations nearest the person among 300 candidates anywhere (so that some touch it)
        candidates = rng.uniform(np.maximum(robot.lower, -np.pi), np.minimum(robot.upper, np.pi),
                                 (300, robot.n_joints))
        obstacles = workcell.obstacles_at(t)
        near = np.array([truth(q, obstacles, part_names).clearance for q in candidates])
        futures[i] = np.vstack([ahead, spread, anywhere, candidates[np.argsort(near)[: future // 4]]])
    clearances = {i: np.array([truth(q, workcell.obstacles_at(frames[i].time), part_names).clearance
                               for q in futures[i]]) for i in observed}
    return workcell, reference_frames, observed, frames, futures, clearances


def depth_grid_rule(workcell, frames, observed, futures, clearances, invalid: str, defaults: dict,
                    robot_zone: float = 0.0) -> None:
    """The depth grid's verdict (see the module's docstring), printed as a row, and the diagnosis without the space
    between links as another; ``invalid``: the monitor's policy for pixels without a measurement ("neighbors" fills
    holes: a concession whose band is printed); ``defaults``: the default image rule's verdicts by frame;
    ``robot_zone``: the monitor's robot zone (metres; a concession, flagged ROBOT_ZONE)."""
    import depthguard as dg
    from depthguard.collision import DepthGridCollisionTest

    robot = workcell.robot
    test = DepthGridCollisionTest(robot, 0.01)
    monitor = dg.DistanceMonitor(workcell.rig, robot=robot, rho=0.3, invalid=invalid, robot_zone=robot_zone)
    holes = ("holes occ." if invalid == "occupied" else "holes filled") + \
        (f", zone {robot_zone * 100:g} cm" if robot_zone else "")
    rows = {"grid, " + holes: [0] * 5, "no slack, " + holes: [0] * 5}  # touching, missed, free, alarms, disagree
    times, conceded = [], {}
    for i in observed:
        frame = frames[i]
        start = time.perf_counter()
        images = {n: dg.depth_image(d.data, workcell.rig.cameras[n], timestamp=frame.time) for n, d in frame.depth.items()}
        prepared = monitor.prepare_set(images, joints=frame.joints, now=frame.time)
        verdicts = test.verdicts(prepared, futures[i])
        times.append(time.perf_counter() - start)
        points = np.concatenate([test.surface.control_point_positions(q) for q in futures[i]])
        dropped = (prepared.query(points).distance.reshape(len(futures[i]), -1) <= test.radii).any(axis=1)
        for f, c in zip(verdicts.conceded, verdicts.collision):
            if not c:
                for name in f.names:
                    conceded[name] = conceded.get(name, 0) + 1
        c = clearances[i]
        for key, collision in zip(rows, (verdicts.collision, dropped)):
            row = rows[key]
            row[0] += int((c < 0).sum())
            row[1] += int(((c < 0) & ~collision).sum())
            row[2] += int((c > FALSE_ALARM_CLEARANCE).sum())
            row[3] += int(((c > FALSE_ALARM_CLEARANCE) & collision).sum())
            row[4] += int((collision != defaults[i]).sum()) if i in defaults else 0
    for key, (touching, missed, free, alarms, disagree) in rows.items():
        ms = f"{np.median(times) * 1e3:11.1f}" if key.startswith("grid") else f"{'-':>11s}"
        print(f"{'depth':10s} {key:22s} {touching:9d} {missed:7d} {free:14d} {alarms:7d} "
              f"({alarms / max(free, 1):4.0%}) {'-':>11s} {ms}   disagree {disagree}")
    print(f"{'':10s} (free verdicts resting on a concession: {conceded or 'none'})")
    if invalid != "occupied":
        band, why = monitor.query_hidden_band()
        print(f"{'':10s} (what the concessions may hide next to a surface: {why})")


if __name__ == "__main__":
    import sys

    with report(__file__, name="probe_collision_scenario_c_ideal" if "--ideal-only" in sys.argv else None):
        main()
