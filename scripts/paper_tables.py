"""Reproduce the paper's imitation-learning and force-prediction tables from finished runs.

    python scripts/paper_tables.py \
        --expert bca=outputs/eval/bca-type1/<run> --expert lcca=outputs/eval/lcca-type1/<run> \
        --image bca=outputs/train/bca-type1/pixels/<run> \
        --bc bca=outputs/bc/bca-type1/<run> --bc lcca=outputs/bc/lcca-type1/<run> \
        --force outputs/force/<run> --out outputs/tables

Rows of the imitation table: "Expert" (the scripted expert, or an ENN agent's
cathsim-eval folder), "Image w/o expert" (SAC on obs=pixels, a cathsim-train run),
"Image w. expert" (the cathsim-bc student); columns the paper's metrics for each target.
A folder is a cathsim-eval run (metrics.json) or a cathsim-train / cathsim-bc run
(eval/metrics.json); a row without a folder says "not run". The force table is the
test MSE of a cathsim-force run per training size, with its baselines.

Writes imitation.md, force.md and tables.json into --out.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # run from a checkout without installing

ROWS = (("expert", "Expert"), ("image", "Image w/o expert"), ("bc", "Image w. expert"))
TARGETS = ("bca", "lcca")


class UsageError(Exception):
    pass


def metrics_file(folder) -> Path:
    folder = Path(folder)
    for candidate in (folder / "metrics.json", folder / "eval" / "metrics.json"):
        if candidate.is_file():
            return candidate
    raise UsageError(f"{folder} has no metrics.json or eval/metrics.json (a cathsim-eval, -train or -bc run folder)")


def parse_pairs(pairs, option) -> dict:
    out = {}
    for pair in pairs or []:
        target, sep, folder = pair.partition("=")
        if not sep or target not in TARGETS:
            raise UsageError(f"{option} {pair!r}: write TARGET=FOLDER with TARGET one of {list(TARGETS)}")
        out[target] = metrics_file(folder)
    return out


def imitation_table(runs: dict) -> tuple:
    from cathsim_dmc.metrics import METRIC_COLUMNS

    header = ["Target", "Method"] + [h for h, _ in METRIC_COLUMNS.values()] + ["Episodes", "Source"]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    records = []
    for target in TARGETS:
        for key, method in ROWS:
            path = runs[key].get(target)
            if path is None:
                cells = [target.upper(), method] + ["not run"] * len(METRIC_COLUMNS) + ["0", "-"]
                records.append({"target": target, "method": method, "run": None})
            else:
                report = json.loads(path.read_text())
                summary = report["summary"]
                cells = [target.upper(), method]
                for metric, (_, fmt) in METRIC_COLUMNS.items():
                    cells.append(f"{fmt.format(summary[metric]['mean'])} ± {fmt.format(summary[metric]['std'])}")
                cells += [str(len(report.get("per_episode", []))), f"`{report['policy']}` on {report['aorta']}"]
                records.append({"target": target, "method": method, "run": str(path.parent), "summary": summary,
                                "episodes": len(report.get("per_episode", []))})
            lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n", records


def force_table(folder) -> tuple:
    from cathsim_dmc.supervised.force import markdown

    path = Path(folder) / "force.json"
    if not path.is_file():
        raise UsageError(f"--force {folder}: no force.json (a cathsim-force run folder)")
    report = json.loads(path.read_text())
    sizes = report["sizes"]
    header = ["Test MSE (N²) [RMSE (N)]"] + [f"{r['train_samples']:,} samples" for r in sizes]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]

    def add_rows(scores):  # scores: one {"model": ..., "train_mean": ..., ...} per size
        for key, name in (("model", "Force network"), ("train_mean", "Train-set mean"),
                          ("before_fine_tuning", "Before fine-tuning")):
            lines.append("| " + " | ".join([name] + [f"{c[key]['mse_n2']:.4f} [{c[key]['rmse_n']:.3f}]"
                                                        for c in scores]) + " |")

    add_rows(sizes)
    if all("without_outliers" in r for r in sizes):
        lines.append("| " + " | ".join([f"*Without the {report['test_outliers']} test sample(s) above "
                                        f"{report['outlier_n']:g} N:*"] + [""] * len(sizes)) + " |")
        add_rows([r["without_outliers"] for r in sizes])
    return "\n".join(lines) + "\n\nDetail:\n\n" + markdown(report), report


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--expert", action="append", metavar="TARGET=FOLDER", help="expert evaluation per target")
    parser.add_argument("--image", action="append", metavar="TARGET=FOLDER", help="SAC obs=pixels run per target")
    parser.add_argument("--bc", action="append", metavar="TARGET=FOLDER", help="cathsim-bc run per target")
    parser.add_argument("--force", metavar="FOLDER", help="cathsim-force run folder")
    parser.add_argument("--out", default="outputs/tables", help="folder for imitation.md, force.md, tables.json")
    args = parser.parse_args(argv)
    try:
        runs = {key: parse_pairs(getattr(args, key), f"--{key}") for key, _ in ROWS}
        imitation, records = imitation_table(runs)
        force, force_report = force_table(args.force) if args.force else ("not run\n", None)
    except UsageError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "imitation.md").write_text(imitation)
    (out / "force.md").write_text(force)
    (out / "tables.json").write_text(json.dumps({"imitation": records, "force": force_report}, indent=2))
    print("## Imitation learning\n\n" + imitation + "\n## Force prediction\n\n" + force, end="")
    print(f"tables in {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
