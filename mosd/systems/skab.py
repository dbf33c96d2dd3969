"""SKAB scored by SKAB's own leaderboard rules: ``python -m mosd.systems.skab --root DIR [--families]``.

Prints SKAB's published outlier-detection leaderboard with mosd's rows inserted (sorted by F1 as the
leaderboard is): the literature row T²+Q reproduced with mosd's PCA (:mod:`mosd.systems.skab_t2q`), and each
chosen family's front, five designs at 5, 10, 15, 20 and 25 % cross-validated FAR, tuned and scored under the
protocol of :mod:`mosd.systems.skab_study` (fixed before any result; docs/systems/skab.md, "Benchmark"). Then
the detection-delay table and each family's best row per folder.

Keys (``--json`` prints them as one JSON object): ``skab_far_<family>_b<budget>``, ``skab_mar_<family>_b<budget>``
(%), ``skab_f1_<family>_b<budget>`` (budget 5, 10, 15, 20, 25), ``skab_lit_t2q_far``, ``skab_lit_t2q_mar``,
``skab_lit_t2q_f1``. ``--out DIR`` writes ``skab_front.png`` (FAR against MAR: the leaderboard's points and each
family's front) and ``skab_benchmark.json`` (every row with its designs per fold). ``--wide-box`` adds the
labelled rows ``<family>_wide`` (keys ``skab_far_<family>_wide_b<budget>`` ...): a box widened after the first
results were seen, :data:`mosd.systems.skab_study.WIDE`, never a headline row. ``--ideas`` (default off, so the
headline command's output is unchanged) adds the labelled rows of :data:`mosd.systems.skab_ideas.IDEAS`, design
ideas tried after the first results (keys ``skab_far_<idea>_b<budget>`` ..., each row marked "added after the
first results, 2026-11-29", dashed in the figure). The data are SKAB's ``data/`` folder (GPL-3.0, never shipped:
:mod:`mosd.data.skab` reads it).
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path
from typing import Sequence

import numpy as np

from ..data.skab import ANOMALY_GROUPS, check_groups, check_root, read_experiments
from ..validation import ConfigError
from .cli import check_writable_folder
from .skab_ideas import ADDED, IDEAS, run_idea
from .skab_study import FAMILIES, WIDE, WIDE_LABEL, check_families, run_family
from .skab_t2q import literature_rows

#: SKAB's published outlier-detection leaderboard (README at b2c0d46): name, F1, FAR %, MAR %
LEADERBOARD = (
    ("Conv-AE", 0.78, 13.55, 28.02), ("MSET", 0.78, 39.73, 14.13),
    ("T²+Q (PCA, scaled, 85 % variance, p 0.999, rolling median of 5)", 0.76, 26.62, 24.92),
    ("LSTM-AE", 0.74, 29.96, 25.92), ("T²", 0.66, 19.21, 42.60), ("LSTM-VAE", 0.56, 9.13, 55.03),
    ("Vanilla LSTM", 0.54, 12.54, 59.53), ("MSCRED", 0.36, 49.94, 69.88), ("Vanilla AE", 0.39, 2.59, 75.15),
    ("Isolation forest", 0.29, 2.56, 82.89),
)
LIT_PUBLISHED = "mosd: T²+Q, SKAB's limits (literature row reproduced)"
LIT_TEXTBOOK = "mosd: T²+Q, textbook Jackson–Mudholkar Q limit (labelled variant)"


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors (exit 2)."""

    def error(self, message):
        usage = " ".join(self.format_usage().split()).removeprefix("usage: ")
        raise ConfigError(f"{message}; allowed: {usage}")


def parser() -> argparse.ArgumentParser:
    p = _Parser(prog="python -m mosd.systems.skab", description=__doc__.splitlines()[0])
    p.add_argument("--root", required=True, help="SKAB's data/ folder (a clone of github.com/waico/SKAB)")
    p.add_argument("--families", action="store_true", help=f"every family: {', '.join(FAMILIES)}")
    p.add_argument("--family", action="append", nargs="+", default=[], metavar="NAME", help="one or more families")
    p.add_argument("--seed", type=int, default=0, help="the folds', FastICA's and the autoencoder's seed")
    p.add_argument("--json", action="store_true", help="print the keys as one JSON object on stdout, the tables on stderr")
    p.add_argument("--out", help="folder for skab_front.png and skab_benchmark.json")
    p.add_argument("--train-groups", help="tune on these folders only (comma-separated), no cross-validation")
    p.add_argument("--test-groups", help="score these folders only (comma-separated)")
    p.add_argument("--wide-box", action="store_true", help="also the labelled rows <family>_wide: "
                   + WIDE_LABEL)
    p.add_argument("--ideas", action="store_true", help=f"also the labelled rows {', '.join(IDEAS)}: {ADDED}")
    return p


def _groups(text: str | None, option: str) -> tuple[str, ...] | None:
    if text is None:
        return None
    names = [g.strip() for g in text.split(",") if g.strip()]
    for name in names:
        if name not in ANOMALY_GROUPS:
            raise ConfigError(f"{option}: {name!r} is not a SKAB folder with anomalies; allowed: "
                              f"{', '.join(ANOMALY_GROUPS)} (comma-separated)")
    return check_groups(names, option)


def study(root, families: Sequence[str] = (), seed: int = 0, train_groups=None, test_groups=None,
          log=sys.stderr, wide: bool = False, ideas: Sequence[str] = ()) -> dict:
    """Everything the CLI prints: ``{"literature", "families", "keys", "seconds", "scored"}`` (module docstring).

    ``ideas``: names among :data:`mosd.systems.skab_ideas.IDEAS`, run after the families, their rows labelled.
    """
    experiments = read_experiments(root, key="--root")
    if (train_groups is None) != (test_groups is None):
        raise ConfigError("--train-groups and --test-groups go together; allowed: both (disjoint folders) or "
                          "neither (5-fold cross-validation over every experiment)")
    train = test = None
    if train_groups is not None:
        if set(train_groups) & set(test_groups):
            raise ConfigError(f"--train-groups and --test-groups share {sorted(set(train_groups) & set(test_groups))}"
                              f"; allowed: disjoint folders among {', '.join(ANOMALY_GROUPS)}")
        train = np.array([e.group in train_groups for e in experiments])
        test = np.array([e.group in test_groups for e in experiments])
    scored = [e for i, e in enumerate(experiments) if test is None or test[i]]
    t0 = time.perf_counter()
    literature = literature_rows(scored)
    print(f"skab: literature T²+Q on {len(scored)} experiments", file=log, flush=True)
    rows = {f: run_family(f, experiments, seed, train, test, log) for f in families}
    if wide:
        # the labelled variant (skab_study.WIDE): after the headline rows, never in their place
        rows.update({f"{f}_wide": {**run_family(f, experiments, seed, train, test, log, WIDE), "label": WIDE_LABEL}
                     for f in families})
    # the labelled ideas (skab_ideas): after every other row, never in their place
    rows.update({name: run_idea(name, experiments, seed, train, test, log) for name in ideas})
    mode = "CV" if train is None else f"tuned on {','.join(train_groups)},"
    return {"literature": literature, "families": rows, "keys": keys(literature, rows), "mode": mode,
            "seconds": time.perf_counter() - t0, "scored": [e.name for e in scored],
            "load_average": os.getloadavg()}


def keys(literature: dict, rows: dict) -> dict:
    """The benchmark's keys (module docstring)."""
    out = {f"skab_lit_t2q_{m}": float(literature["published"][m]) for m in ("far", "mar", "f1")}
    for family, result in rows.items():
        for budget, row in result["budgets"].items():
            for m in ("far", "mar", "f1"):
                out[f"skab_{m}_{family}_b{budget}"] = float(row[m])
    return out


def table_rows(result: dict) -> list[tuple[str, float, float, float]]:
    """The leaderboard with mosd's rows, sorted by F1 (two decimals, as published; stable)."""
    rows = [(f"SKAB: {name}", f1, far, mar) for name, f1, far, mar in LEADERBOARD]
    for label, name in ((LIT_PUBLISHED, "published"), (LIT_TEXTBOOK, "textbook")):
        r = result["literature"][name]
        rows.append((label, r["f1"], r["far"], r["mar"]))
    for family, res in result["families"].items():
        for budget, r in res["budgets"].items():
            note = (f" ({res['added']})" if "added" in res
                    else " (labelled: box widened after the first results)" if "label" in res else "")
            rows.append((f"mosd: {family}{note}, {result.get('mode', 'CV')} FAR budget {budget} %", r["f1"], r["far"],
                         r["mar"]))
    return sorted(rows, key=lambda r: -round(r[1], 2))


def report(result: dict) -> str:
    """The three tables as Markdown."""
    lines = []
    if result.get("mode", "CV") != "CV":
        scored = ", ".join(result["scored"])
        lines += [f"SKAB's published rows score all 34 experiments; mosd's rows score only {scored} (not comparable "
                  "with the published ones)", ""]
    lines += ["| algorithm | F1 | FAR % | MAR % |", "|---|---|---|---|"]
    lines += [f"| {name} | {f1:.2f} | {far:.2f} | {mar:.2f} |" for name, f1, far, mar in table_rows(result)]
    lines += ["", "Detection delay after each changepoint (SKAB's average_time, 60 s window to the right):", "",
              "| row | mean delay s | missed / changepoints | false change points |", "|---|---|---|---|"]
    named = [(LIT_PUBLISHED, result["literature"]["published"]), (LIT_TEXTBOOK, result["literature"]["textbook"])]
    named += [(f"mosd: {f}, budget {b} %", r) for f, res in result["families"].items()
              for b, r in res["budgets"].items()]
    for name, r in named:
        d = r["delay"]
        lines.append(f"| {name} | {d['mean_s']:.1f} | {d['missed']} / {d['changepoints']} | {d['false']} |")
    if result["families"]:
        folders = list(dict.fromkeys(g for res in result["families"].values() for r in res["budgets"].values()
                                     for g in r["folders"]))
        lines += ["", "Each family's best row (highest F1) per folder, FAR % / MAR %:", "",
                  "| row | " + " | ".join(folders) + " |", "|---|" + "---|" * len(folders)]
        for family, res in result["families"].items():
            budget, r = max(res["budgets"].items(), key=lambda item: item[1]["f1"])
            cells = [f"{r['folders'][g]['far']:.2f} / {r['folders'][g]['mar']:.2f}" if g in r["folders"] else "-"
                     for g in folders]
            lines.append(f"| {family}, budget {budget} % | " + " | ".join(cells) + " |")
    seconds = sum(res["seconds"] for res in result["families"].values())
    load = ", ".join(f"{v:.2f}" for v in result["load_average"])
    lines += ["", f"Scored experiments: {len(result['scored'])}; wall time {result['seconds']:.1f} s "
              f"(families {seconds:.1f} s); load average {load}"]
    return "\n".join(lines)


def figure(result: dict, path: Path) -> Path:
    """FAR against MAR: the leaderboard's points, the reproduced T²+Q and each family's front."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 6))
    for name, _, far, mar in LEADERBOARD:
        ax.scatter(far, mar, color="0.5", marker="s")
        ax.annotate(name.split(" (")[0], (far, mar), fontsize=7, xytext=(3, 3), textcoords="offset points")
    lit = result["literature"]["published"]
    ax.scatter(lit["far"], lit["mar"], color="k", marker="x", s=60, label="T²+Q reproduced (mosd)")
    for family, res in result["families"].items():
        pts = np.array([(r["far"], r["mar"]) for r in res["budgets"].values()])
        added = "added" in res  # the labelled ideas: dashed, marked in the legend
        ax.plot(pts[:, 0], pts[:, 1], marker="o", linestyle="--" if added else "-",
                label=f"{family} ({'added 2026-11-29, ' if added else ''}CV front)")
    ax.set_xlabel("FAR %")
    ax.set_ylabel("MAR %")
    ax.set_title("SKAB: FAR against MAR (SKAB's binary metric, test rows of every experiment)")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7 if len(result["families"]) < 12 else 5)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def _clean(value):
    """JSON-ready copy (NumPy scalars and arrays to Python)."""
    if isinstance(value, dict):
        return {str(k): _clean(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_clean(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    return value


def main(argv: Sequence[str] | None = None) -> int:
    try:
        args = parser().parse_args(argv)
        check_root(args.root, "--root")
        families = FAMILIES if args.families else check_families([n for group in args.family for n in group])
        train = _groups(args.train_groups, "--train-groups")
        test = _groups(args.test_groups, "--test-groups")
        out = Path(args.out) if args.out else None
        if out is not None:
            check_writable_folder(out, "--out")
        result = study(args.root, families, args.seed, train, test, wide=args.wide_box,
                       ideas=tuple(IDEAS) if args.ideas else ())
    except ConfigError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        figure(result, out / "skab_front.png")
        (out / "skab_benchmark.json").write_text(json.dumps(_clean(result), indent=1))
    if args.json:  # the keys on stdout for a pipe, the tables on stderr for the reader (as mosd.bench --json)
        print(report(result), file=sys.stderr)
        print(json.dumps(result["keys"], indent=1, sort_keys=True))
    else:
        print(report(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
