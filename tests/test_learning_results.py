"""scripts/learning_results.py: every variant composes into a cathsim-train config, and the
report reads finished runs into the table."""

import json

import pytest
from conftest import load_script


@pytest.fixture(scope="module")
def learning_results(repo_root):
    return load_script(repo_root / "scripts" / "learning_results.py")


def test_every_variant_composes_with_the_training_config(learning_results):
    from hydra import compose, initialize_config_dir

    from cathsim_dmc.core.shipped import conf_root

    with initialize_config_dir(config_dir=str(conf_root()), version_base=None):
        for variant, (_, budget) in learning_results.VARIANTS.items():
            for task in learning_results.TASKS:
                overrides = learning_results.new_run_overrides(variant, task, 1, 1000, budget, save_replay_buffer=True)
                cfg = compose("train", overrides=overrides)
                assert [cfg.task.target, cfg.aorta.name] == task.split("-")
                assert cfg.trainer.total_timesteps == budget and cfg.seed == 1
                assert cfg.trainer.final_eval_episodes == learning_results.FINAL_EPISODES
    # The default recipe is the training default, at its default budget.
    with initialize_config_dir(config_dir=str(conf_root()), version_base=None):
        default = compose("train")
        overrides, budget = learning_results.VARIANTS["demos_internal"]
        assert compose("train", overrides=overrides) == default
    assert budget == default.trainer.total_timesteps


def test_report_reads_runs_and_an_empty_root(learning_results, tmp_path):
    folder = learning_results.run_dir(tmp_path, "demos_internal", "bca-type1", 0)
    (folder / "eval").mkdir(parents=True)
    evaluations = [
        {"step": 1000, "success_rate": 0.5, "wall_s": 60},
        {"step": 2000, "success_rate": 0.9, "wall_s": 180},
        {"step": 3000, "success_rate": 1.0, "wall_s": 300},
    ]
    (folder / "evaluations.jsonl").write_text("".join(json.dumps(e) + "\n" for e in evaluations))
    (folder / "eval" / "metrics.json").write_text(json.dumps({"summary": {"success_pct": {"mean": 96.0}}}))
    out = tmp_path / "table.md"
    learning_results.report(tmp_path, out, None)
    rows = [line for line in out.read_text().splitlines() if line.startswith("| demos_internal")]
    assert rows == ["| demos_internal | bca-type1 | 1 | 2,000 | 96% | seed 0: 2,000, 3 min, final 96% |"]

    empty = tmp_path / "empty"
    empty.mkdir()
    learning_results.report(empty, out, None)
    assert len(out.read_text().splitlines()) == 2  # the header alone
