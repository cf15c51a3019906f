"""The shipped navigators (`policy=pretrained`): they load from the package, act, and
come with a model card. Their success is measured in docs/training.md, not here."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from cathsim_dmc.agents.pretrained import load_pretrained, policy_files, shipped_targets
from cathsim_dmc.suite.gym import CathSimEnv
from cathsim_dmc.tasks.presets import OBSERVATION_PRESETS


def test_both_targets_ship_a_small_actor_with_a_card_naming_its_observations():
    assert shipped_targets() == ("bca", "lcca")
    for target in shipped_targets():
        weights, meta_path, card_path = policy_files(target)
        assert weights.stat().st_size < 5e6  # the actor only: no critic, optimiser or buffer
        meta = json.loads(meta_path.read_text())
        assert meta["target"] == target and meta["obs"] in OBSERVATION_PRESETS
        card = card_path.read_text()
        assert f"`{meta['obs']}`" in card and meta["trained"]["command"] in card
        assert "## Results" in card and "## Known limits" in card


@pytest.mark.parametrize("target", ["bca", "lcca"])
def test_a_shipped_navigator_loads_and_acts_deterministically(target):
    policy = load_pretrained(target)
    env = CathSimEnv(task=target, aorta="type2", obs=policy.obs_preset, **policy.image_options, **policy.env_options)
    try:
        obs, _ = env.reset(seed=0)
        for _ in range(5):
            action = policy(obs, env)
            assert action.shape == env.action_space.shape and np.all(np.abs(action) <= 1.0)
            np.testing.assert_array_equal(action, policy(obs, env))
            obs, *_ = env.step(action)
    finally:
        env.close()


def test_cathsim_eval_runs_the_pretrained_policy_on_an_asset_folder(tmp_path, repo_root):
    script = Path(sys.executable).with_name("cathsim-eval")
    proc = subprocess.run(
        [
            str(script),
            "policy=pretrained",
            "task=lcca",
            f"aorta={repo_root / 'assets' / 'type3'}",
            "episodes=1",
            "video=false",
            f"hydra.run.dir={tmp_path}",
        ],
        capture_output=True,
        text=True,
        timeout=600,
        cwd=tmp_path,
    )
    assert proc.returncode == 0, proc.stderr
    report = json.loads((tmp_path / "metrics.json").read_text())
    assert report["policy"] == "pretrained" and report["task"] == "lcca" and len(report["episodes"]) == 1


def test_a_target_without_a_shipped_navigator_is_refused_in_one_line(tmp_path):
    with pytest.raises(ValueError, match=r"no pretrained navigator for task='lsa'; shipped: \['bca', 'lcca'\]"):
        load_pretrained("lsa")
