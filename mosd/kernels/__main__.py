"""``python -m mosd.kernels``: compile every numerical kernel once, into numba's on-disk cache.

Not needed after an install: a run compiles the kernels it calls when it first
calls them, and only those. This command compiles them all ahead, e.g. for a
machine image or a cluster's shared cache (``--modules`` picks some); afterwards
every process loads them from the cache.
The modules compile in parallel processes (``--jobs``, default: the CPUs).
Exit code 0 when every kernel compiled, 1 otherwise.
"""
from __future__ import annotations

import argparse
import multiprocessing
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor, as_completed


def main(argv: list[str] | None = None) -> int:
    from . import MODULES, available, compile_module, enabled

    parser = argparse.ArgumentParser(prog="python -m mosd.kernels", description=__doc__.splitlines()[0])
    parser.add_argument("--jobs", type=int, default=os.cpu_count() or 1, help="parallel compiling processes")
    parser.add_argument("--modules", default=",".join(MODULES),
                        help=f"comma-separated kernel modules to compile (default: all of {', '.join(MODULES)})")
    args = parser.parse_args(argv)
    chosen = [m.strip() for m in args.modules.split(",") if m.strip()]
    unknown = [m for m in chosen if m not in MODULES]
    if unknown or not chosen:
        parser.error(f"--modules {','.join(unknown) or args.modules!r} is not a kernel module; allowed: "
                     f"{', '.join(MODULES)}")
    if not available() or not enabled():
        print("mosd.kernels: numba is missing or MOSD_KERNELS=numpy: nothing to compile", file=sys.stderr)
        return 0
    t0 = time.perf_counter()
    failed = 0
    # the slowest first, so that the parallel compiles end together
    slowest = ("cubature", "imm", "wavelet", "chart", "entropy", "plants", "ewma")
    order = sorted(chosen, key=lambda name: slowest.index(name) if name in slowest else len(slowest))
    # spawned, not forked: a fork of a process with threads (a caller's pools) can inherit a held lock
    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max(1, min(args.jobs, len(order))), mp_context=context) as pool:
        futures = {pool.submit(compile_module, name): name for name in order}
        for future in as_completed(futures):
            try:
                name, seconds = future.result()
                print(f"mosd.kernels: {name:9s} ready in {seconds:5.1f} s", file=sys.stderr)
            except Exception as exc:  # noqa: BLE001 - report every module, then fail
                failed += 1
                print(f"mosd.kernels: {futures[future]} failed: {type(exc).__name__}: {exc}", file=sys.stderr)
    print(f"mosd.kernels: {len(order) - failed} of {len(order)} kernel modules ready in "
          f"{time.perf_counter() - t0:.1f} s" + (" (cached for later runs)" if not failed else ""), file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
