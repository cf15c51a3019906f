"""scripts/results_tables.py: the README's results table and the docs' tables are written
from docs/results.json and agree with it; a record is read from the tools' real output."""

import copy
import json
import subprocess
import sys

import pytest
from conftest import load_script


@pytest.fixture(scope="module")
def tables(repo_root):
    return load_script(repo_root / "scripts" / "results_tables.py")


def test_the_readme_and_the_docs_show_what_the_records_hold(tables, repo_root):
    differ = tables.render(check=True, root=repo_root)
    assert not differ, f"run `python scripts/results_tables.py render`: {differ} differ from docs/results.json"


def test_each_docs_table_is_dated_with_its_records_date_and_commit(tables, repo_root):
    records = tables.load_records(repo_root / "docs" / "results.json")
    for page, found in tables.TABLES.items():
        for header, _ in found:
            name = tables.RECORD_OF_TABLE.get(header)
            if name is None:
                continue
            section = tables.section_of((repo_root / page).read_text(), header)
            assert records[name]["date"] in section and records[name]["commit"] in section, (page, name)


def _rendered(tables, repo_root, records, page):
    return tables.render_page((repo_root / page).read_text(), tables.TABLES[page], records)


def test_a_changed_record_changes_its_docs_table_and_the_readme_row(tables, repo_root):
    records = tables.load_records(repo_root / "docs" / "results.json")
    changed = copy.deepcopy(records)
    lcca = next(r for r in changed["expert_random"]["rows"] if r["target"] == "LCCA")
    lcca["success"] = 37
    shipped = next(r for r in changed["navigators_random"]["rows"] if r["target"] == "BCA" and r.get("shipped"))
    shipped["seeds"] = [dict(shipped["seeds"][0], success=s) for s in (40, 60, 50)]

    readme = _rendered(tables, repo_root, changed, "README.md")
    assert "BCA 50% (expert" in readme and "(expert 37%)" in readme
    assert readme != _rendered(tables, repo_root, records, "README.md")
    assert "| LCCA | **37/100** |" in _rendered(tables, repo_root, changed, "docs/benchmarks.md")
    assert "| 3 | **50 (40, 60, 50)** |" in _rendered(tables, repo_root, changed, "docs/training.md")


def test_a_page_without_its_table_is_refused(tables):
    with pytest.raises(ValueError, match="expected one table starting"):
        tables.render_page("# no tables here\n", [("| what |", lambda records: [])], {})


def test_records_are_read_from_a_real_evaluation_sweep_and_the_bench_table(tables, tmp_path):
    sweep = tmp_path / "sweep"
    evaluate = [
        sys.executable,
        "-m",
        "cathsim_dmc.app.cli.eval",
        "-m",
        "task=bca,lcca",
        "aorta=type1",
        "policy=expert",
        "episodes=1",
        "seed=0",
        "video=false",
        f"hydra.sweep.dir={sweep}",
    ]
    subprocess.run(evaluate, check=True, capture_output=True, cwd=tmp_path)
    rows = tables.shipped_rows(sweep)
    assert [(r["target"], r["aorta"]) for r in rows] == [("BCA", "type1"), ("LCCA", "type1")]
    for row, run in zip(rows, ("0", "1"), strict=True):
        summary = json.loads((sweep / run / "metrics.json").read_text())["summary"]
        assert row["success_pct"] == [summary["success_pct"]["mean"], summary["success_pct"]["std"]]
        assert row["force_n"][0] == summary["force_n"]["mean"] > 0
    table = tables.expert_shipped_table({"rows": rows})
    assert table[2].startswith("| BCA | type1 | ") and len(table) == 4

    bench = [sys.executable, "-m", "cathsim_dmc.app.cli.bench", "presets=[internal]", "physics_settings=[fast]"]
    printed = subprocess.run([*bench, "steps=5", "repeats=1"], check=True, capture_output=True, text=True, cwd=tmp_path)
    (tmp_path / "bench.md").write_text(printed.stdout)
    (speed,) = tables.speed_rows(tmp_path / "bench.md")
    assert (speed["aorta"], speed["obs"], speed["physics"]) == ("type1", "internal", "fast")
    assert speed["steps_per_s"] > 0 and speed["real_time"] == pytest.approx(speed["steps_per_s"] / 10, abs=0.01)
