"""The ``depthguard-lab`` command line: the simulations and experiments beside the library.

    depthguard-lab demo [--out DIR] [--duration S] [--mode none|avoid|ssm ...] [--cameras 4|2] [--no-bag]
                        [--ssm-in-layout]
    depthguard-lab simulate [SCENE.yaml] --out DIR [--seed N] [--duration S] [--bag]
    depthguard-lab workcell [--out DIR] [--duration S]
    depthguard-lab fusion-workcell [--out DIR] [--scene SCENE.yaml ...] [--all-frames]
    depthguard-lab scenario-a [--out DIR] [--repeats N]
    depthguard-lab real-room [--out DIR] [--data FOLDER]

As ``depthguard``'s: bad input ends with exit status 2 and one line on standard error, exit status 3 means a bug.
Numeric options are checked where they are parsed: ``--duration`` finite seconds, at least one frame period of the
scene (1/30 s for the packaged scenes; longer than the scene simulates the whole scene); ``--seed`` a whole number in
[0, ``config.MAX_SEED``]; ``--repeats`` in [1, ``config.MAX_REPEATS``].
"""

from __future__ import annotations

import math
import sys

from depthguard import config
from depthguard.cli import Parser, real_option, run, whole_option

PROGRAM = "depthguard-lab"
SIM_RATE = 30.0  # Hz, the packaged scenes' camera rate: the shortest --duration is one frame period
_SECONDS = real_option(0.0, math.inf, "seconds", above_minimum=True)


def _build_parser() -> Parser:
    parser = Parser(prog=PROGRAM, description="depthguard's lab: simulated workcells, the demo and the experiments "
                                              "that judge the library against exact geometry.")
    commands = parser.add_subparsers(dest="command", required=True, parser_class=Parser)

    demo = commands.add_parser("demo", help="the Quick start's main job: a robot doing its task next to a person "
                                            "in closed loop, without avoidance, with the papers' avoidance and "
                                            "with speed and separation monitoring, judged by exact geometry")
    demo.add_argument("--out", default="out/demo", help="output folder for plots and summary.json")
    demo.add_argument("--duration", type=_SECONDS, default=None,
                      help="only the first S seconds, at least one frame (1/30 s) (default: the whole scene, 5.5 s)")
    demo.add_argument("--mode", action="append", choices=("none", "avoid", "ssm"),
                      help="run only this mode (repeatable; default: none, avoid and ssm)")
    demo.add_argument("--cameras", type=int, choices=(2, 4), default=4,
                      help="four depth cameras round the robot (default) or the scene's two front ones (faster)")
    demo.add_argument("--no-bag", action="store_true",
                      help="do not write the avoid run as a recording (DIR/bag_avoid, an MCAP file)")
    demo.add_argument("--ssm-in-layout", action="store_true",
                      help="try ssm in the other modes' camera layout instead of scenario_b_ssm.yaml's five cameras")

    simulate = commands.add_parser("simulate", help="simulate a workcell and write its frames, rig, joint states "
                                                     "and ground truth")
    simulate.add_argument("scene", nargs="?", help="scene YAML (default: reference scenario B)")
    simulate.add_argument("--out", required=True, help="output folder")
    simulate.add_argument("--seed", type=whole_option(0, config.MAX_SEED), default=None,
                          help="sensor-noise seed (default: the scene's)")
    simulate.add_argument("--duration", type=_SECONDS, default=None,
                          help="simulate only the first S seconds (at least one frame period)")
    simulate.add_argument("--bag", action="store_true", help="also write the recording as a ROS 2 bag (MCAP) into "
                                                             "OUT/bag/ (depth images, camera_info, joint_states)")

    workcell = commands.add_parser("workcell", help="the simulated workcell of reference scenario B, each camera's "
                                                    "distances on its own against the truth")
    workcell.add_argument("--out", default="out/workcell", help="output folder for plots and summary.json")
    workcell.add_argument("--duration", type=_SECONDS, default=None,
                          help="only the first S seconds, at least one frame (1/30 s) (default: all 12)")

    fusion = commands.add_parser("fusion-workcell", help="scenario B's shadow and hidden-hand cases: a camera alone "
                                                         "against all fused through the depth grid, without and with "
                                                         "the free-space memory")
    fusion.add_argument("--out", default="out/fusion-workcell", help="output folder for plots and summary.json")
    fusion.add_argument("--scene", action="append", metavar="SCENE", help="a camera layout (scene YAML) to run "
                                                                           "(repeatable; default: scenario_b.yaml and "
                                                                           "scenario_b_four.yaml)")
    fusion.add_argument("--all-frames", action="store_true", help="simulate the whole episode (default: the two "
                                                                  "cases and 0.5 s around them)")

    room = commands.add_parser("real-room", help="real data: three calibrated views of a room fused through the "
                                                 "depth grid; the calibration error and the fusion margin it needs")
    room.add_argument("--out", default="out/real-room", help="output folder for plots and summary.json")
    room.add_argument("--data", default=None, help="the slambook2-room folder (default: ../shared/data/real/...)")

    scenario_a = commands.add_parser("scenario-a", help="reference scenario A of the 2015 paper: plots and a "
                                                        "timing table")
    scenario_a.add_argument("--out", default="out/scenario-a", help="output folder for plots and tables")
    scenario_a.add_argument("--repeats", type=whole_option(1, config.MAX_REPEATS), default=20,
                            help="timing repetitions per control point position")
    return parser


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    args = _build_parser().parse_args(argv)
    return run(lambda: _COMMANDS[args.command](args), PROGRAM)


def _demo(args) -> int:
    from depthguard_lab.experiments import avoidance_demo

    return avoidance_demo.main(out=args.out, duration=_duration(args.duration, SIM_RATE), modes=args.mode,
                               bag=not args.no_bag, cameras=args.cameras, ssm_cell=not args.ssm_in_layout)


def _simulate(args) -> int:
    from pathlib import Path

    from depthguard.errors import InputError
    from depthguard_lab.simulation import default_workcell, load_workcell, write_episode

    if args.bag and (Path(args.out) / "bag").exists():  # refused before the simulation, not after it
        raise InputError(f"--bag: {Path(args.out) / 'bag'} exists already; a bag is written into a new folder")
    workcell = load_workcell(args.scene) if args.scene else default_workcell()
    duration = _duration(args.duration, workcell.rate)
    frames = None if duration is None else range(min(workcell.n_frames, int(round(duration * workcell.rate))))
    n = workcell.n_frames if frames is None else len(frames)
    print(f"simulating {n} frames of {', '.join(workcell.rig.cameras)} at {workcell.rate:g} Hz into {args.out}")
    out = write_episode(workcell, args.out, seed=args.seed, progress=True, frames=frames)
    print(f"wrote {out}: rig.yaml, frames.csv, depth/, intensity/, joint_states.csv, ground_truth.csv, scene.yaml")
    if args.bag:
        from depthguard.io.recordings import open_recording, write_bag

        bag = write_bag(open_recording(out), out / "bag")
        print(f"wrote {bag}: ROS 2 bag (MCAP) with the same frames and joint states, and rig.yaml")
    return 0


def _workcell(args) -> int:
    from depthguard_lab.experiments import workcell

    return workcell.main(out=args.out, duration=_duration(args.duration, SIM_RATE))


def _fusion_workcell(args) -> int:
    from depthguard_lab.experiments import fusion_workcell

    return fusion_workcell.main(out=args.out, scenes=args.scene, all_frames=args.all_frames)


def _real_room(args) -> int:
    from depthguard_lab.experiments import real_room

    return real_room.main(args.out, folder=args.data)


def _scenario_a(args) -> int:
    from depthguard_lab.experiments import _scenario_a_plots as report

    return report.main(out=args.out, repeats=args.repeats)


def _duration(value, rate: float):
    """``--duration`` (finite seconds, or None): at least one frame period of a scene simulated at ``rate`` Hz."""
    from depthguard.errors import InputError

    if value is not None and value < 1.0 / rate:
        raise InputError(f"--duration must be at least one frame period (1/{rate:g} s), got {value:g} s")
    return value


_COMMANDS = {"demo": _demo, "simulate": _simulate, "workcell": _workcell, "fusion-workcell": _fusion_workcell,
             "real-room": _real_room, "scenario-a": _scenario_a}


if __name__ == "__main__":
    sys.exit(main())
