"""The shipped navigators (`policy=pretrained`, `policy=pretrained_fluoro`): they load from the package, act, and
come with a model card. Their success is measured in docs/training.md, not here."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from cathsim_dmc.agents.trained import PRETRAINED_FLUORO, load_pretrained, policy_files, shipped_targets
from cathsim_dmc.suite.gym import CathSimEnv
from cathsim_dmc.tasks.presets import C_ARM_OBSERVABLES, OBSERVATION_PRESETS

SHIPPED = [(kind, target) for kind in ("pretrained", PRETRAINED_FLUORO) for target in shipped_targets(kind=kind)]


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


def test_the_fluoroscope_navigator_ships_a_small_actor_reading_only_what_a_c_arm_shows():
    assert "lcca" in shipped_targets(kind=PRETRAINED_FLUORO)
    for target in shipped_targets(kind=PRETRAINED_FLUORO):
        weights, meta_path, card_path = policy_files(target, kind=PRETRAINED_FLUORO)
        assert weights.name == f"navigator_fluoro_{target}.pt" and weights.stat().st_size < 5e6
        meta = json.loads(meta_path.read_text())
        assert meta["target"] == target and OBSERVATION_PRESETS[meta["obs"]].enabled <= C_ARM_OBSERVABLES
        card = card_path.read_text()
        assert f"`{meta['obs']}`" in card and f"policy={PRETRAINED_FLUORO} task={target}" in card
        assert "## Results" in card and "reached by the view drawn" in card  # the held-out score by view


@pytest.mark.parametrize(("kind", "target"), SHIPPED)
def test_a_shipped_navigator_loads_and_acts_deterministically(kind, target):
    policy = load_pretrained(target, kind=kind)
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


@pytest.mark.parametrize(
    ("policy", "options"),
    [("pretrained", []), (PRETRAINED_FLUORO, ["obs.view_deg_range=[30,30]", "task.max_steps=30"])],
)
def test_cathsim_eval_runs_the_pretrained_policy_on_an_asset_folder(tmp_path, repo_root, policy, options):
    script = Path(sys.executable).with_name("cathsim-eval")
    proc = subprocess.run(
        [
            str(script),
            f"policy={policy}",
            "task=lcca",
            f"aorta={repo_root / 'assets' / 'type3'}",
            "episodes=1",
            "video=false",
            f"hydra.run.dir={tmp_path}",
            *options,
        ],
        capture_output=True,
        text=True,
        timeout=600,
        cwd=tmp_path,
    )
    assert proc.returncode == 0, proc.stderr
    report = json.loads((tmp_path / "metrics.json").read_text())
    assert report["policy"] == policy and report["task"] == "lcca" and len(report["episodes"]) == 1
    if options:  # the view chosen with the usual obs. options, not the training's range
        assert report["episodes"][0]["carm_view_deg"] == [30.0, 0.0]


def test_a_target_without_a_shipped_navigator_is_refused_in_one_line(tmp_path):
    with pytest.raises(ValueError, match=r"no pretrained navigator for task='lsa'; shipped: \['bca', 'lcca'\]"):
        load_pretrained("lsa")
