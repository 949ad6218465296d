"""``depthguard build-map``: build the depth grid map of a rig's principal camera (design §8) and save it."""

from __future__ import annotations

from depthguard import config
from depthguard.cli.options import GRID_METRES

HELP = "build the depth grid map of a rig's principal camera (design section 8) and save it"


def add_arguments(parser) -> None:
    parser.add_argument("--rig", required=True, help="rig YAML file")
    parser.add_argument("--principal", help="principal camera (default: the rig's principal, else its first camera)")
    parser.add_argument("--d-min", type=GRID_METRES, default=None,
                        help="grid start, metres (default: from the rig, as the monitor's: where the principal sees the "
                             "rig's workspace, within its depth_range)")
    parser.add_argument("--d-max", type=GRID_METRES, default=None, help="grid end, metres (default: from the rig)")
    parser.add_argument("--delta-d", type=GRID_METRES, default=None,
                        help=f"cell depth, metres (default {config.DEPTH_GRID_DELTA_D:g}; at most "
                             f"{config.DEPTH_GRID_MAX_CELLS} cells in all)")
    parser.add_argument("--out", required=True, help="map file to write (.npz)")


def run(args) -> int:
    import time
    from pathlib import Path

    from depthguard import load_rig
    from depthguard.depthgrid import build_map, save_map
    from depthguard.errors import InputError

    out = Path(args.out)
    if out.exists() and not out.is_file():  # a folder, a FIFO, a device: never written to
        raise InputError(f"--out {args.out}: exists and is not a regular file")
    rig = load_rig(args.rig)
    start = time.perf_counter()
    try:
        grid = build_map(rig, args.principal, d_min=args.d_min, d_max=args.d_max, delta_d=args.delta_d)
    except InputError as exc:
        if exc.field not in ("d_min", "d_max", "delta_d", "n_cells"):
            raise
        raise InputError(f"--{exc.field.replace('_', '-')}: {exc.message}") from None
    save_map(grid, args.out)
    camera = rig.cameras[grid.principal]
    print(f"depth grid of {grid.principal!r} ({camera.width}x{camera.height}x{grid.n_cells} cells, "
          f"{grid.d_min:g}-{grid.d_max:g} m) to {', '.join(grid.secondaries)}: {grid.nbytes / 1e6:.1f} MB, built in "
          f"{time.perf_counter() - start:.2f} s, written to {args.out}")
    return 0
