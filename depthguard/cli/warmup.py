"""``depthguard warmup``: compile every numba kernel that is not cached yet, so that no query has to."""

from __future__ import annotations

import sys

from depthguard.kernels import jit
from depthguard.warmup import warm_up

HELP = 'compile every numba kernel that is not cached yet (after an install or an upgrade), so that no query has to'


def add_arguments(parser) -> None:
    parser.add_argument("--processes", type=int, default=None, metavar="N",
                        help="compile in N processes at once (default: one per core, at most one per workload, when "
                             "the largest kernels are not cached; 1: in this process only)")


def run(args) -> int:
    """``depthguard warmup``: compile what is not cached yet and say what and how long."""
    started = []

    def progress(kernel):
        if not started:
            print("depthguard warmup: compiling the numba kernels that are not cached yet (after an install or an "
                  "upgrade; once)", flush=True)
        started.append(kernel)
        print(f"  compiling {kernel} ...", flush=True)

    if args.processes is not None and args.processes < 1:
        print(f"depthguard warmup: --processes must be at least 1, got {args.processes}", file=sys.stderr)
        return 2
    report = warm_up(progress, processes=args.processes)
    if jit.uncached_kernels():
        print(f"depthguard warmup: {jit.uncached_kernels()} kernels have no writable cache folder: they were compiled "
              "for this process only (see the warning above)")
    if not report.compiles:
        print(f"depthguard warmup: every kernel was already compiled and cached; checked in {report.seconds:.1f} s")
        return 0
    top = report.top_level
    print(f"depthguard warmup: compiled {len(top)} kernel signatures in {report.seconds:.1f} s "
          f"({report.compile_seconds:.1f} s of compiling, summed over {report.processes} process"
          f"{'es' if report.processes > 1 else ''}); the slowest:")
    for c in sorted(top, key=lambda c: -c.seconds)[:10]:
        print(f"  {c.seconds:6.1f} s  {c.kernel}")
    return 0
