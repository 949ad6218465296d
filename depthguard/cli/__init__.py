"""The ``depthguard`` command line: the commands a cell runs (the lab's simulations and experiments are
``depthguard-lab``'s).

    depthguard distance --rig RIG.yaml --depth NAME=PATH --points POINTS [--rho 0.4] [--aggregate hybrid] ...
    depthguard build-map --rig RIG.yaml [--principal NAME] [--d-min M --d-max M --delta-d M] --out MAP
    depthguard replay RECORDING --out RESULTS.csv [--robot URDF|iiwa|panda] [--points POINTS] [--rho 0.4] ...
    depthguard coverage --rig RIG.yaml [--robot URDF|iiwa|panda] [--trajectory joint_states.csv] [--rho 0.4] ...
    depthguard collide --rig RIG.yaml --reference NAME=GLOB ... --image NAME=PATH ... --robot URDF|iiwa|panda|xarm6
                       --current VALUES --future VALUES [...] [--motion "VALUES;VALUES"] [--theta N] [--json]
    depthguard plan --rig RIG.yaml --reference NAME=GLOB ... --image NAME=PATH ... --robot URDF --current VALUES
                    --goal VALUES [--counts N,N,...] [--json]
    depthguard warmup

Bad input ends with exit status 2 and one line on standard error that says what is wrong (exit status 3 means a bug).
Numeric options are checked where they are parsed (``inf``, ``nan`` and ``1e999`` are refused), in these ranges:

- ``--rho``: metres in [``config.RHO_MIN``, ``config.RHO_MAX``] (``coverage``: in ``coverage.RHO_RANGE``);
- ``--d-min``, ``--d-max``, ``--delta-d``: metres in (0, ``config.COORDINATE_LIMIT``], with d-max > d-min and at
  most ``config.DEPTH_GRID_MAX_CELLS`` cells;
- ``--joints``: finite numbers (radians, or metres for prismatic joints).

Each command is one module of this package (the table :data:`COMMANDS`), with its ``HELP``, its
``add_arguments(parser)`` and its ``run(args)`` (the exit status); :mod:`depthguard.cli.options` holds what they
share. A module is imported when the parser is built; each imports what its work needs when it runs.
"""

from __future__ import annotations

import importlib
import os
import sys

from depthguard.cli.options import Parser, attach_number_lists, parse_joints, real_option, whole_option
from depthguard.errors import DepthguardError, one_line

__all__ = ["COMMANDS", "Parser", "attach_number_lists", "build_parser", "main", "parse_joints", "real_option", "run",
           "whole_option"]

#: The commands, in the order ``depthguard --help`` lists them: name -> the module that runs it.
COMMANDS = {
    "distance": "depthguard.cli.distance",
    "build-map": "depthguard.cli.build_map",
    "replay": "depthguard.cli.replay",
    "coverage": "depthguard.cli.coverage",
    "collide": "depthguard.cli.collide",
    "plan": "depthguard.cli.plan",
    "warmup": "depthguard.cli.warmup",
    "live": "depthguard.cli.live",
}


def build_parser() -> Parser:
    """The ``depthguard`` parser: one subcommand per entry of :data:`COMMANDS`."""
    parser = Parser(prog="depthguard", description="Distances between a robot and unknown obstacles, computed in "
                                                     "the depth space of calibrated depth cameras.")
    commands = parser.add_subparsers(dest="command", required=True, parser_class=Parser)
    for name, path in COMMANDS.items():
        module = importlib.import_module(path)
        module.add_arguments(commands.add_parser(name, help=module.HELP))
    return parser


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    args = build_parser().parse_args(attach_number_lists(argv))
    return run(lambda: importlib.import_module(COMMANDS[args.command]).run(args), "depthguard")


def run(command, program: str) -> int:
    """Run ``command()`` (a command's body, returning its exit status) as every depthguard command line does: a
    :class:`~depthguard.DepthguardError` (bad input) or an ``OSError`` ends with exit status 2 and one line on
    standard error, ``<program>: error: ...``; any other exception is a bug: exit status 3 and one line
    (``DEPTHGUARD_DEBUG=1`` raises it instead, with its traceback)."""
    from depthguard.io.files import named_stdout

    try:
        with named_stdout():  # standard output's write errors name it (docs/bad-input.md)
            return command()
    except DepthguardError as exc:
        print(f"{program}: error: {exc}", file=sys.stderr)  # one line already (DepthguardError)
        return 2
    except OSError as exc:
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"{program}: error: {one_line(where + str(exc.strerror or exc))}", file=sys.stderr)
        return 2
    except Exception as exc:  # a bug, not bad input: still one line, the traceback on request
        if os.environ.get("DEPTHGUARD_DEBUG"):
            raise
        print(f"{program}: internal error: {type(exc).__name__}: {one_line(str(exc))} (set DEPTHGUARD_DEBUG=1 for the "
              "traceback)",
              file=sys.stderr)
        return 3
