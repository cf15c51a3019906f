"""aorta=random: the anatomy redrawn from a pool every N episodes (tasks/randomized.py)."""

import json
import subprocess
import sys

import numpy as np
import pytest

from cathsim_dmc import tasks
from cathsim_dmc.anatomy import load_asset
from cathsim_dmc.core.shipped import resolve_asset
from cathsim_dmc.suite.gym import CathSimEnv

POOL = {"assets": ["type1", "type2"]}


def _anatomies(env, episodes):
    names = []
    for _ in range(episodes):
        env.reset()
        names.append(env.anatomy_name)
        # The task is the drawn anatomy's: its target is that asset's BCA site.
        np.testing.assert_allclose(
            env.task.target_position_m, load_asset(resolve_asset(names[-1])).sites["bca"], atol=1e-6
        )
        env.step([1.0, 0.0])
    return names


def test_every_episode_draws_from_the_pool_and_a_seed_repeats_the_draws():
    env = tasks.load("bca", "random", seed=3, aorta_params=dict(POOL, resample_every=1))
    first = _anatomies(env, 8)
    assert set(first) == {"type1", "type2"}
    env2 = tasks.load("bca", "random", seed=3, aorta_params=dict(POOL, resample_every=1))
    assert _anatomies(env2, 8) == first
    env.close()
    env2.close()


def test_the_anatomy_changes_only_every_resample_every_episodes():
    env = tasks.load("bca", "random", seed=0, aorta_params=dict(POOL, resample_every=3))
    names = _anatomies(env, 12)
    for block in range(4):
        assert len(set(names[3 * block : 3 * block + 3])) == 1
    env.close()


def test_the_gymnasium_info_names_the_episodes_anatomy():
    env = CathSimEnv("lcca", "random", aorta_params=dict(POOL, resample_every=1))
    seen = set()
    for seed in range(6):
        _, info = env.reset(seed=seed)
        assert info["aorta"] == env.dm_env.anatomy_name
        _, _, _, _, info = env.step(np.array([1.0, 0.0], dtype=np.float32))
        seen.add(info["aorta"])
    assert seen == {"type1", "type2"}
    fixed = CathSimEnv("lcca", "type1")
    assert fixed.reset(seed=0)[1]["aorta"] == "type1"
    env.close()
    fixed.close()


def test_cycle_order_visits_every_anatomy_in_turn():
    env = tasks.load("bca", "random", seed=0, aorta_params=dict(POOL, order="cycle", resample_every=2))
    assert _anatomies(env, 6) == ["type1", "type1", "type2", "type2", "type1", "type1"]
    env.close()


@pytest.mark.parametrize(
    "params, needle",
    [
        ({"order": "shuffled", **POOL}, "order='shuffled'"),
        ({"pool_size": 0}, "pool_size=0"),
        ({"resample_every": 0, **POOL}, "resample_every=0"),
        ({"arch_width": 2}, "'arch_width'"),
    ],
)
def test_bad_pool_settings_name_themselves(params, needle):
    with pytest.raises(ValueError, match=needle):
        tasks.load("bca", "random", aorta_params=params)


def test_cathsim_eval_records_each_episodes_anatomy(tmp_path):
    run = tmp_path / "run"
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "cathsim_dmc.app.cli.eval",
            "task=bca",
            "aorta=random",
            "aorta.params.assets=[type1,type2]",
            "policy=expert",
            "episodes=4",
            "video=false",
            f"hydra.run.dir={run}",
        ],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert result.returncode == 0, result.stderr
    data = np.load(run / "trajectories.npz")
    assert str(data["aorta"]) == "random" and len(data["episode_aorta"]) == 4
    assert set(data["episode_aorta"]) <= {"type1", "type2"}
    for name, target in zip(data["episode_aorta"], data["episode_target_position_m"]):
        np.testing.assert_allclose(target, load_asset(resolve_asset(str(name))).sites["bca"], atol=1e-5)
    report = json.loads((run / "metrics.json").read_text())
    assert report["aorta"] == "random" and report["summary"]["success_pct"]["mean"] == 100
    assert [e["aorta"] for e in report["episodes"]] == list(data["episode_aorta"])
    # Each episode's end is placed on its own anatomy's centerlines: at the target.
    assert all(e["ended"] == "reached the target" and e["end_along_vessel_mm"] < 5 for e in report["episode_ends"])
    assert not (run / "path.png").exists()  # one anatomy's picture cannot hold the others' paths


@pytest.mark.slow
def test_a_generated_pool_holds_different_valid_arches_and_grows_without_redrawing():
    from cathsim_dmc.tasks.randomized import anatomy_pool

    small = anatomy_pool(pool_size=2, pool_seed=7)
    larger = anatomy_pool(pool_size=3, pool_seed=7)
    assert larger[:2] == small and len(set(larger)) == 3
    widths = {json.loads((folder / "meta.json").read_text())["params"]["arch_width_m"] for folder in larger}
    assert len(widths) == 3
    env = tasks.load("bca", "random", seed=0, aorta_params={"pool_size": 2, "pool_seed": 7})
    env.reset()
    assert env.anatomy_name in {"random7-0", "random7-1"}
    env.close()
