"""scripts/generalisation.py's table writer: seeds grouped by their median, success by arch type."""

import json

from conftest import load_script


def _write(folder, successes, aortas, force=0.2, length=100):
    folder.mkdir(parents=True)
    rate = 100.0 * sum(successes) / len(successes)
    summary = {
        "success_pct": {"mean": rate},
        "spl_pct": {"mean": rate / 2},
        "force_n": {"mean": force},
        "episode_length": {"mean": length},
    }
    episodes = [{"episode": i, "success": s, "aorta": a} for i, (s, a) in enumerate(zip(successes, aortas))]
    (folder / "metrics.json").write_text(json.dumps({"summary": summary, "episodes": episodes}))


def test_the_report_gives_the_median_of_the_seeds_and_success_by_arch_type(tmp_path, repo_root):
    script = load_script(repo_root / "scripts" / "generalisation.py")
    aortas = ["a", "b", "c", "d"]
    types = {"a": "I", "b": "II", "c": "III", "d": "III"}
    scores = tmp_path / "scores" / "bca"
    _write(scores / "navigator_seed0_best" / "heldout", [True, True, True, False], aortas)
    _write(scores / "navigator_seed1_best" / "heldout", [True, True, False, False], aortas)
    _write(scores / "navigator_seed2_best" / "heldout", [True, True, True, True], aortas)
    _write(scores / "navigator_seed0_last" / "heldout", [False, False, False, False], aortas)
    _write(scores / "navigator_seed0_best" / "heldout_noise", [True, False, True, False], aortas)
    _write(scores / "expert" / "heldout", [True, True, True, True], aortas)
    _write(scores / "expert" / "type2", [True, False], ["type2", "type2"])
    text = script.report(tmp_path, tmp_path / "table.md", arch_types=types)
    heldout, shipped_table = text.split("Success % on the shipped aortas")
    rows = {line.split(" | ")[0].strip("| "): line for line in heldout.splitlines() if line.startswith("| ")}
    best = rows["navigator, best.zip"].split(" | ")
    assert best[1] == "3"  # seeds
    assert best[2] == "75 (75, 50, 100)"  # median success, then each seed's
    assert best[6:10] == ["100 (100, 100, 100)", "100 (100, 100, 100)", "50 (50, 0, 100)", "50 |"]  # with noise: seed 0
    assert rows["navigator, last.zip"].split(" | ")[2] == "0"
    # The shipped-aorta table: a row per anatomy, a column only for the policies scored there
    # (the expert's 1 of 2 on type II), and a dash where nothing was scored.
    lines = [line for line in shipped_table.splitlines() if line.startswith("| ")]
    assert lines[0] == "| anatomy | BCA: expert |"
    rows = {line.split(" | ")[0].strip("| "): line.split(" | ")[1].strip("| ") for line in lines[1:]}
    assert rows["type2"] == "50" and rows["type1"] == "-" and rows["corpus: noisy"] == "-"
    assert (tmp_path / "table.md").read_text() == text
