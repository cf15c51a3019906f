"""The results tables of README.md and docs/, written from one file of records.

    python scripts/results_tables.py render            # rewrite the tables from docs/results.json
    python scripts/results_tables.py render --check    # exit 1 if a page differs from its records
    python scripts/results_tables.py record expert_random /path/to/multirun/dir --commit d6b8ade

docs/results.json holds each measured result once: its rows, the date, the commit, the
machine and the command that reproduces it. `render` writes every table that shows it (the
docs' full tables and the README's one-line summaries), so the two cannot disagree.
`record` replaces a record's rows from the output of the command that measured them:
`expert_shipped` and `expert_random` from a `cathsim-eval -m` sweep folder, `speed` from
the table `cathsim-bench` prints (saved to a file), `navigators_random` from
`cathsim-eval` run folders given as LABEL=DIR (several DIRs for seeds, comma-separated).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
RECORDS = ROOT / "docs" / "results.json"

# the order of the group columns of the random-arch tables
GROUPS = ("type I", "type II", "type III", "separate", "close ostia", "bovine")


def _pct(value: float) -> str:
    return f"{value:.0f}"


def _mean_std(cell: list, digits: int) -> str:
    return f"{cell[0]:.{digits}f} ± {cell[1]:.{digits}f}"


def _median_cell(values: list) -> str:
    if len(values) == 1:
        return _pct(values[0])
    return f"{_pct(statistics.median(values))} ({', '.join(_pct(v) for v in values)})"


def _table(header: list, rows: list) -> list:
    return ["| " + " | ".join(header) + " |", "|" + "---|" * len(header), *("| " + " | ".join(r) + " |" for r in rows)]


# --- the docs' tables -------------------------------------------------------------------


def expert_shipped_table(record: dict) -> list:
    header = [
        "Target",
        "Aorta",
        "Force (N)",
        "Path Length (cm)",
        "Episode Length",
        "Safety (%)",
        "Success (%)",
        "SPL (%)",
    ]
    rows = [
        [
            r["target"],
            r["aorta"],
            _mean_std(r["force_n"], 2),
            _mean_std(r["path_length_cm"], 1),
            _mean_std(r["episode_length"], 0),
            _mean_std(r["safety_pct"], 0),
            _mean_std(r["success_pct"], 0),
            _mean_std(r["spl_pct"], 0),
        ]
        for r in record["rows"]
    ]
    return _table(header, rows)


def _group_cells(groups: dict) -> list:
    return [f"{groups[g][0]}/{groups[g][1]}" if g in groups else "-" for g in GROUPS]


def expert_random_table(record: dict) -> list:
    header = ["target", "success", "safe success", *GROUPS]
    rows = [
        [
            r["target"],
            f"**{r['success']}/{r['episodes']}**",
            f"{r['safe_success']}/{r['episodes']}",
            *_group_cells(r["groups"]),
        ]
        for r in record["rows"]
    ]
    return _table(header, rows)


def navigators_random_table(record: dict) -> list:
    """One row per (target, policy): success % as the median over seeds (each seed in
    parentheses), safe success, then success by group."""
    header = ["target", "policy", "seeds", "success %", "safe success %", *GROUPS]
    rows = []
    for r in record["rows"]:
        seeds = r["seeds"]
        success = _median_cell([s["success"] / s["episodes"] * 100 for s in seeds])
        name = f"{r['policy']}, **shipped**" if r.get("shipped") else r["policy"]
        groups = [
            _median_cell([s["groups"][g][0] / s["groups"][g][1] * 100 for s in seeds])
            if g in seeds[0]["groups"]
            else "-"
            for g in GROUPS
        ]
        rows.append(
            [
                r["target"],
                name,
                str(len(seeds)),
                f"**{success}**" if r.get("shipped") else success,
                _median_cell([s["safe_success"] / s["episodes"] * 100 for s in seeds]),
                *groups,
            ]
        )
    return _table(header, rows)


def speed_table(record: dict) -> list:
    header = [
        "aorta",
        "obs",
        "renderer",
        "physics",
        "control steps/s",
        "x real time",
        "raw mj_step steps/s",
        "overhead",
        "contacts",
        "build s",
        "reset ms",
        "peak RSS MB",
        "image ms",
    ]
    rows = [
        [
            r["aorta"],
            r["obs"],
            r["renderer"],
            r["physics"],
            f"{r['steps_per_s']:.1f}",
            f"{r['real_time']:.2f}",
            f"{r['raw_steps_per_s']:.1f}",
            f"{r['overhead']:.2f}",
            f"{r['contacts']:.0f}",
            f"{r['build_s']:.2f}",
            f"{r['reset_ms']:.1f}",
            f"{r['peak_rss_mb']:.0f}",
            f"{r['image_ms']:.2f}",
        ]
        for r in record["rows"]
    ]
    return _table(header, rows)


# --- the README's summary rows -----------------------------------------------------------


def _by_target(rows: list, key: str) -> dict:
    found: dict = {}
    for r in rows:
        found.setdefault(r[key], {})[r["target"]] = r
    return found


def _readme_row(what: str, result: str, record: dict, link: str) -> list:
    when = record.get("when") or f"{record['date']}, {record['commit']}"
    return [what, result, f"`{record['command']}` ([{link.split('#')[0]}]({link}))", when]


def readme_table(records: dict) -> list:
    rows = []
    shipped = records["expert_shipped"]
    per_aorta = _by_target(shipped["rows"], "aorta")
    cells = [
        f"{aorta} {_pct(t['BCA']['success_pct'][0])} / {_pct(t['LCCA']['success_pct'][0])}%"
        for aorta, t in per_aorta.items()
    ]
    episodes = shipped["episodes_per_cell"]
    rows.append(
        _readme_row(
            f"scripted expert, success of {episodes} episodes per shipped aorta, BCA / LCCA",
            ", ".join(cells),
            shipped,
            "docs/benchmarks.md#on-the-shipped-aortas",
        )
    )
    specialist = records["specialist"]
    cells = [f"{r['arch']} {r['target']} {' / '.join(_pct(v) for v in r['success_pct'])}%" for r in specialist["rows"]]
    rows.append(
        _readme_row(
            "specialist (the default recipe, one arch), 8,000 steps, best.zip over 50 episodes, seeds 0 / 1 / 2",
            ", ".join(cells),
            specialist,
            "docs/paper.md",
        )
    )
    navigators = records["navigators_random"]
    expert = {r["target"]: r for r in records["expert_random"]["rows"]}
    shipped_rows = {r["target"]: r for r in navigators["rows"] if r.get("shipped")}
    cells = []
    for target in ("BCA", "LCCA"):
        seeds = shipped_rows[target]["seeds"]
        median = statistics.median(s["success"] / s["episodes"] * 100 for s in seeds)
        e = expert[target]
        cells.append(f"{target} {_pct(median)}% (expert {_pct(e['success'] / e['episodes'] * 100)}%)")
    # a row measured before the record's latest rows carries its own "when"; the others the record's
    whens = sorted({r.get("when") or f"{navigators['date']}, {navigators['commit']}" for r in shipped_rows.values()})
    rows.append(
        _readme_row(
            "navigators for unseen anatomy (`policy=pretrained`), 100 held-out arches of `aorta=random`, "
            "median over seeds",
            ", ".join(cells),
            navigators | {"when": "; ".join(whens)},
            "docs/training.md#unseen-anatomy",
        )
    )
    speed = records["speed"]
    cells = [
        f"`{r['physics']}` `{r['obs']}` {r['steps_per_s']:.1f} steps/s ({r['real_time']:.1f}x real time)"
        for r in speed["rows"]
    ]
    rows.append(
        _readme_row(
            f"speed, {speed['rows'][0]['aorta']}, control steps of 0.1 s",
            ", ".join(cells),
            speed,
            "docs/benchmarks.md#speed",
        )
    )
    return _table(["what", "result", "command", "date, commit"], rows)


# page -> [(the header row that identifies the table, renderer)]
TABLES = {
    "README.md": [("| what | result | command | date, commit |", readme_table)],
    "docs/benchmarks.md": [
        ("| Target | Aorta | Force (N) |", lambda records: expert_shipped_table(records["expert_shipped"])),
        ("| target | success | safe success |", lambda records: expert_random_table(records["expert_random"])),
        ("| aorta | obs | renderer | physics |", lambda records: speed_table(records["speed"])),
    ],
    "docs/training.md": [
        (
            "| target | policy | seeds | success % |",
            lambda records: navigators_random_table(records["navigators_random"]),
        ),
    ],
}
# the record each docs table shows: its section of the page gives the record's date and commit
RECORD_OF_TABLE = {
    "| Target | Aorta | Force (N) |": "expert_shipped",
    "| target | success | safe success |": "expert_random",
    "| aorta | obs | renderer | physics |": "speed",
    "| target | policy | seeds | success % |": "navigators_random",
}


def section_of(text: str, header: str) -> str:
    """The lines of the page's section (heading to heading) that holds the table."""
    lines = text.splitlines()
    at = next(i for i, line in enumerate(lines) if line.startswith(header))
    start = max([i for i in range(at) if lines[i].startswith("#")], default=0)
    end = next((i for i in range(at, len(lines)) if lines[i].startswith("#")), len(lines))
    return "\n".join(lines[start:end])


def load_records(path: Path = RECORDS) -> dict:
    return json.loads(path.read_text())


def render_page(text: str, tables: list, records: dict) -> str:
    """`text` with each table whose header row starts with a key replaced by its rendering.
    A page that lacks one of its tables is an error: the records would show nowhere."""
    lines = text.splitlines()
    for header, render in tables:
        starts = [i for i, line in enumerate(lines) if line.startswith(header)]
        if len(starts) != 1:
            raise ValueError(f"expected one table starting {header!r}, found {len(starts)}")
        start = end = starts[0]
        while end < len(lines) and lines[end].startswith("|"):
            end += 1
        lines[start:end] = render(records)
    return "\n".join(lines) + ("\n" if text.endswith("\n") else "")


def render(check: bool, records: dict | None = None, root: Path = ROOT) -> list:
    """Write (or with `check`, compare) every page; returns the pages that differ."""
    records = records if records is not None else load_records()
    differ = []
    for page, tables in TABLES.items():
        path = root / page
        text = path.read_text()
        new = render_page(text, tables, records)
        if new != text:
            differ.append(page)
            if not check:
                path.write_text(new)
    return differ


# --- records from the tools' output ------------------------------------------------------


def _run_dirs(sweep: Path) -> list:
    return sorted((p for p in sweep.iterdir() if (p / "metrics.json").is_file()), key=lambda p: int(p.name))


def shipped_rows(sweep: Path) -> list:
    rows = []
    for run in _run_dirs(sweep):
        metrics = json.loads((run / "metrics.json").read_text())
        summary = metrics["summary"]
        rows.append(
            {"target": metrics["task"].upper(), "aorta": metrics["aorta"]}
            | {k: [summary[k]["mean"], summary[k]["std"]] for k in ("force_n", "path_length_cm", "episode_length")}
            | {k: [summary[k]["mean"], summary[k]["std"]] for k in ("safety_pct", "success_pct", "spl_pct")}
        )
    return sorted(rows, key=lambda r: (r["target"], r["aorta"]))


def random_row(run: Path, labels: tuple) -> dict:
    """Success, safe success and success by group of one cathsim-eval run on a random pool;
    `labels` is (arch name -> type, arch name -> variant)."""
    metrics = json.loads((run / "metrics.json").read_text())
    episodes = metrics["episodes"]
    safe = [e["safe_success_pct"] > 0 for e in metrics["per_episode"]]
    groups: dict = {}
    for e in episodes:
        for group in (f"type {labels[0][e['aorta']]}", labels[1][e["aorta"]]):
            ok, n = groups.get(group, (0, 0))
            groups[group] = (ok + bool(e["success"]), n + 1)
    return {
        "target": metrics["task"].upper(),
        "episodes": len(episodes),
        "success": sum(bool(e["success"]) for e in episodes),
        "safe_success": sum(safe),
        "groups": {g: list(groups[g]) for g in GROUPS if g in groups},
        "misses": [int(e["aorta"].rsplit("-", 1)[1]) for e in episodes if not e["success"]],
    }


def heldout_labels() -> tuple:
    sys.path.insert(0, str(ROOT / "scripts"))
    from generalisation import _pool_labels

    return _pool_labels()


def speed_rows(table: Path) -> list:
    """The rows of the markdown table cathsim-bench prints."""
    lines = [line for line in table.read_text().splitlines() if line.startswith("|")]
    header = [c.strip() for c in lines[0].strip("|").split("|")]
    names = {
        "control steps/s": "steps_per_s",
        "x real time": "real_time",
        "raw mj_step steps/s": "raw_steps_per_s",
        "overhead": "overhead",
        "contacts": "contacts",
        "build s": "build_s",
        "reset ms": "reset_ms",
        "peak RSS MB": "peak_rss_mb",
        "image ms": "image_ms",
    }
    rows = []
    for line in lines[2:]:
        cells = dict(zip(header, (c.strip() for c in line.strip("|").split("|")), strict=True))
        row = {k: cells[k] for k in ("aorta", "obs", "renderer", "physics")}
        rows.append(row | {name: float(cells[col].strip("*")) for col, name in names.items()})
    return rows


def record(name: str, sources: list, records: dict, commit: str | None, date: str | None) -> dict:
    """`records` with `name`'s rows replaced from `sources` (and its date and commit, if given)."""
    entry = dict(records[name])
    if name == "expert_shipped":
        entry["rows"] = shipped_rows(Path(sources[0]))
    elif name == "expert_random":
        labels = heldout_labels()
        entry["rows"] = [random_row(run, labels) for run in _run_dirs(Path(sources[0]))]
    elif name == "speed":
        entry["rows"] = speed_rows(Path(sources[0]))
    elif name == "navigators_random":
        labels = heldout_labels()
        old = {(r["target"], r["policy"]): r for r in entry["rows"]}
        for source in sources:
            label, dirs = source.split("=", 1)
            seeds = [random_row(Path(d), labels) for d in dirs.split(",")]
            key = (seeds[0]["target"], label)
            old[key] = old.get(key, {"target": key[0], "policy": label}) | {"seeds": seeds}
        entry["rows"] = sorted(old.values(), key=lambda r: r["target"])
    else:
        raise ValueError(
            f"record: {name!r} is not one of ['expert_shipped', 'expert_random', 'speed', 'navigators_random']"
        )
    if commit:
        entry["commit"] = commit
    if date:
        entry["date"] = date
    return records | {name: entry}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    render_parser = sub.add_parser("render", help="write the tables of README.md and docs/ from docs/results.json")
    render_parser.add_argument("--check", action="store_true", help="only compare; exit 1 if a page differs")
    record_parser = sub.add_parser("record", help="replace one record's rows from a tool's output")
    record_parser.add_argument("name", choices=["expert_shipped", "expert_random", "speed", "navigators_random"])
    record_parser.add_argument("sources", nargs="+")
    record_parser.add_argument("--commit")
    record_parser.add_argument("--date")
    args = parser.parse_args(argv)
    if args.command == "record":
        records = record(args.name, args.sources, load_records(), args.commit, args.date)
        RECORDS.write_text(json.dumps(records, indent=1) + "\n")
    differ = render(check=args.command == "render" and args.check)
    if args.command == "render" and args.check and differ:
        print(f"out of date with docs/results.json: {', '.join(differ)} (python scripts/results_tables.py render)")
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
