"""``python -m mosd.app.tuning_benchmark``: MOPSO variants on the presets' own tuning problems.

Each preset (``conf/experiment/NAME.yaml``) is composed and built as ``python -m mosd
+experiment=NAME`` builds it (:func:`mosd.app.presets.preset_setup`), and
:func:`mosd.optim.benchmarks.preset_table` runs the algorithms on its tuning problem. The
composition lives here, in the layer that may load Hydra; the benchmark itself stays in
:mod:`mosd.optim.benchmarks`, which imports nothing above the optimisers.
"""
from __future__ import annotations

import argparse
import os
import sys
import time

from ..optim.benchmarks import DEFAULT_NAME, ISSUE14_NAME, format_ratios, format_table, preset_table
from ..validation import ConfigError, Interval, check_choice, check_in
from .presets import preset_setup

#: The presets whose tuning problems are run by default (paper 000's is the MO-SS-DEWMA chart problem).
PRESETS = ("paper000", "paper001", "paper002", "paper003")


def main(argv=None) -> int:
    """Print the median-HV table and the ratios of the first algorithm to the others as Markdown."""
    parser = argparse.ArgumentParser(prog="python -m mosd.app.tuning_benchmark", description=__doc__.splitlines()[0])
    parser.add_argument("presets", nargs="*", metavar="PRESET", help=f"default: {' '.join(PRESETS)}")
    parser.add_argument("--algorithms", nargs="+", default=[DEFAULT_NAME, ISSUE14_NAME], metavar="NAME",
                        help="names of python -m mosd.optim.benchmarks (default: the default and the issue-14 default)")
    parser.add_argument("--seeds", type=int, default=3, help="seeds 1..N (default 3)")
    parser.add_argument("--budget-scale", type=float, default=1.0,
                        help="the preset's generations times this (default 1)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")
    args = parser.parse_args(argv)
    try:
        budget_scale = check_in("benchmark.budget_scale", args.budget_scale, Interval(0.0, 10.0, open_low=True))
        start = time.perf_counter()
        names = [check_choice("benchmark.presets", name, PRESETS) for name in args.presets or PRESETS]
        setups = {name: preset_setup(name) for name in names}
        rows = preset_table(setups, args.algorithms, tuple(range(1, args.seeds + 1)), budget_scale,
                            progress=not args.no_progress)
    except ConfigError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    first = rows[0]["algorithm"]
    budgets = ", ".join(f"{row['problem']} {row['n_eval']:,}" for row in rows if row["algorithm"] == first)
    print(f"Median normalised hypervolume on the presets' tuning problems over seeds 1-{args.seeds} "
          f"(evaluations per run: {budgets}); objectives normalised by all final archives of a preset\n")
    print(format_table(rows))
    print()
    names = list(dict.fromkeys(row["algorithm"] for row in rows))
    print(format_ratios(rows, algorithm=names[0], references=names[1:]))
    load = " ".join(f"{value:.2f}" for value in os.getloadavg())
    print(f"\n{sum(len(row['hv']) for row in rows)} runs in {time.perf_counter() - start:.0f} s; "
          f"load average at the end {load}")
    return 0


if __name__ == "__main__":
    # the importable module's main, as python -m mosd.optim.benchmarks does
    from mosd.app.tuning_benchmark import main as _main

    raise SystemExit(_main())
