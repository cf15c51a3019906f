"""cathsim-collect: shards written and read back, resume, Z from an ENN agent, bad input."""

import json
import subprocess
import sys

import numpy as np
import pytest

from cathsim_dmc.agents.collect import collect
from cathsim_dmc.learning.datasets import MANIFEST, load_arrays, read_keys

TINY = {"max_steps": 6}


def _collect(args, cwd):
    return subprocess.run(
        [sys.executable, "-m", "cathsim_dmc.app.cli.collect", *args],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=600,
    )


def test_dataset_round_trip_and_resume(tmp_path):
    out = tmp_path / "data"
    manifest = collect(
        out, "bca", "type1", "expert", episodes=3, episodes_per_shard=2, seed=5, task_options=TINY, show_progress=False
    )
    assert [s["file"] for s in manifest["shards"]] == ["shard_00000.npz", "shard_00001.npz"]
    assert manifest["episodes"] == 3 and manifest["samples"] == 18
    assert json.loads((out / MANIFEST).read_text())["samples"] == 18
    shard = read_keys(
        out / "shard_00001.npz",
        (
            "obs_pixels",
            "obs_guidewire_mask",
            "obs_joint_pos",
            "obs_joint_vel",
            "action",
            "contact_force_n",
            "mean_contact_force_n",
            "first_episode",
        ),
    )
    assert shard["obs_pixels"].shape == (6, 1, 80, 80) and shard["obs_pixels"].dtype == np.uint8
    assert set(np.unique(shard["obs_guidewire_mask"])) <= {0, 255} and shard["obs_guidewire_mask"].max() == 255
    assert int(shard["first_episode"]) == 2
    assert shard["mean_contact_force_n"].shape == (6,)

    # Read back across shards: episode ids unique, rows in order.
    arrays = load_arrays([out], ("obs_pixels", "action", "contact_force_n"))
    assert len(arrays["action"]) == 18 and list(np.unique(arrays["episode"])) == [0, 1, 2]
    assert np.array_equal(arrays["obs_pixels"][12:], shard["obs_pixels"])
    # Paired with the observation the action was chosen from: the previous row's, or
    # the reset observation for step 1 (which differs from the first row's).
    before = load_arrays([out], ("obs_pixels",), before_action=True)["obs_pixels"]
    assert np.array_equal(before[1:6], arrays["obs_pixels"][0:5])
    start = read_keys(out / "shard_00000.npz", ("start_obs_pixels",))["start_obs_pixels"]
    assert np.array_equal(before[0], start[0]) and not np.array_equal(before[0], arrays["obs_pixels"][0])

    # Resume: growing the dataset keeps the finished shard, recollects the short one,
    # and reproduces the same episodes (episode e is seeded with seed + e).
    first_mtime = (out / "shard_00000.npz").stat().st_mtime_ns
    manifest = collect(
        out, "bca", "type1", "expert", episodes=4, episodes_per_shard=2, seed=5, task_options=TINY, show_progress=False
    )
    assert manifest["episodes"] == 4 and (out / "shard_00000.npz").stat().st_mtime_ns == first_mtime
    again = read_keys(out / "shard_00001.npz", ("action", "episode"))
    assert np.array_equal(again["action"][again["episode"] == 0], shard["action"])
    with pytest.raises(ValueError, match="policy"):
        collect(
            out,
            "bca",
            "type1",
            "forward",
            episodes=4,
            episodes_per_shard=2,
            seed=5,
            task_options=TINY,
            show_progress=False,
        )
    # A dataset holds what its manifest lists: asking for fewer episodes leaves the later
    # shard file on disk but out of the dataset. A manifest from before action noise
    # existed continues as noise-free.
    manifest = json.loads((out / MANIFEST).read_text())
    del manifest["action_noise_std"]
    (out / MANIFEST).write_text(json.dumps(manifest))
    collect(
        out, "bca", "type1", "expert", episodes=2, episodes_per_shard=2, seed=5, task_options=TINY, show_progress=False
    )
    assert (out / "shard_00001.npz").is_file() and len(load_arrays([out], ("action",))["action"]) == 12


def test_an_agent_collects_with_the_options_it_was_trained_with(tmp_path):
    # As cathsim-eval evaluates it: an agent trained with an extra observation drives with
    # it (it cannot act at all without it).
    from stable_baselines3.common.vec_env import DummyVecEnv

    from cathsim_dmc.learning.rl.checkpoints import write_policy_file
    from cathsim_dmc.learning.rl.train import build_sac, make_env_fn

    trained_with = {"extra_observations": ["wire_slack"]}
    env = DummyVecEnv([make_env_fn("bca", "type1", "internal", 0, {"max_steps": 3, **trained_with})])
    algo = dict(
        learning_rate=3e-4,
        buffer_size=100,
        learning_starts=10,
        batch_size=8,
        tau=0.005,
        gamma=0.99,
        train_freq=1,
        gradient_steps=1,
        target_update_interval=1,
        target_entropy=-2.0,
        ent_coef="auto_1.0",
        net_arch=[16],
        share_features_extractor=False,
    )
    model = build_sac(env, algo, 0, "cpu", None)
    env.close()
    agent = tmp_path / "agent"
    agent.mkdir()
    model.save(agent / "final_model.zip")
    write_policy_file(agent, "internal", "bca", "type1", env_options=trained_with)

    manifest = collect(
        tmp_path / "data",
        "bca",
        "type1",
        str(agent),
        episodes=1,
        episodes_per_shard=1,
        seed=0,
        task_options={"max_steps": 3},
        show_progress=False,
    )
    assert manifest["task_options"] == {"max_steps": 3, **trained_with} and manifest["samples"] == 3
    # A second run into the folder continues it: the options compare equal after the JSON round trip.
    again = collect(
        tmp_path / "data",
        "bca",
        "type1",
        str(agent),
        episodes=1,
        episodes_per_shard=1,
        seed=0,
        task_options={"max_steps": 3},
        show_progress=False,
    )
    assert again["samples"] == 3


def test_enn_agent_records_its_features(tmp_path):
    from stable_baselines3.common.vec_env import DummyVecEnv

    from cathsim_dmc.learning.rl.checkpoints import write_policy_file
    from cathsim_dmc.learning.rl.train import build_sac, make_env_fn

    env = DummyVecEnv([make_env_fn("bca", "type1", "enn", 0, {"max_steps": 4})])
    algo = dict(
        learning_rate=3e-4,
        buffer_size=100,
        learning_starts=10,
        batch_size=8,
        tau=0.005,
        gamma=0.99,
        train_freq=1,
        gradient_steps=1,
        target_update_interval=1,
        target_entropy=-2.0,
        ent_coef="auto_1.0",
        net_arch=[32, 32],
        share_features_extractor=False,
    )
    model = build_sac(env, algo, 0, "cpu", None)
    env.close()
    agent = tmp_path / "agent"
    agent.mkdir()
    model.save(agent / "final_model.zip")
    write_policy_file(agent, "enn", "bca", "type1")

    manifest = collect(
        tmp_path / "data",
        "bca",
        "type1",
        str(agent),
        episodes=1,
        episodes_per_shard=1,
        seed=0,
        task_options={"max_steps": 4},
        show_progress=False,
    )
    assert manifest["feature_z"] and manifest["policy"] == "agent"
    data = read_keys(tmp_path / "data" / "shard_00000.npz", ("feature_z", "start_feature_z", "obs_pixels"))
    assert data["feature_z"].shape == (4, 640) and data["start_feature_z"].shape == (1, 640)
    # Z is the actor's extractor applied to that row's observation.
    import torch

    obs = {
        k: read_keys(tmp_path / "data" / "shard_00000.npz", (f"obs_{k}",))[f"obs_{k}"][2:3]
        for k in ("pixels", "guidewire_mask", "joint_pos", "joint_vel")
    }
    with torch.no_grad():
        tensor, _ = model.policy.obs_to_tensor({k: v[0] for k, v in obs.items()})
        z = model.actor.extract_features(tensor, model.actor.features_extractor)[0].numpy()
    np.testing.assert_allclose(data["feature_z"][2], z, rtol=1e-5, atol=1e-6)

    # Distillation reads Z paired with the image the action was chosen from.
    from cathsim_dmc.learning.supervised.bc import BCConfig, train_bc

    arrays = load_arrays([tmp_path / "data"], ("obs_pixels", "action", "feature_z"), before_action=True)
    np.testing.assert_array_equal(arrays["feature_z"][0], data["start_feature_z"][0])
    np.testing.assert_array_equal(arrays["feature_z"][3], data["feature_z"][2])
    result = train_bc(
        arrays["obs_pixels"],
        arrays["action"],
        arrays["episode"],
        BCConfig(epochs=1, distill_coef=1.0, val_fraction=0.0),
        z=arrays["feature_z"],
    )
    assert result.net.z_dim == 640 and "train_z_mse" in result.history[0]


def test_collect_cli_writes_a_dataset(tmp_path):
    result = _collect(
        ["episodes=1", "task.max_steps=3", "progress_bar=false", f"hydra.run.dir={tmp_path}/run"], tmp_path
    )
    assert result.returncode == 0, result.stderr[-2000:]
    assert json.loads((tmp_path / "run" / MANIFEST).read_text())["samples"] == 3


def test_noise_injection_keeps_the_clean_expert_label(tmp_path):
    manifest = collect(
        tmp_path / "data",
        "bca",
        "type1",
        "expert",
        episodes=1,
        episodes_per_shard=1,
        seed=0,
        task_options=TINY,
        show_progress=False,
        action_noise_std=0.3,
    )
    assert manifest["action_noise_std"] == 0.3
    data = read_keys(tmp_path / "data" / "shard_00000.npz", ("action", "expert_action"))
    executed, clean = data["action"], data["expert_action"]
    assert clean.shape == executed.shape == (6, 2) and np.all(np.abs(executed) <= 1.0)
    assert not np.allclose(executed, clean)
    # The expert's first action from the reset state does not depend on the noise.
    plain = collect(
        tmp_path / "plain",
        "bca",
        "type1",
        "expert",
        episodes=1,
        episodes_per_shard=1,
        seed=0,
        task_options=TINY,
        show_progress=False,
    )
    first = read_keys(tmp_path / "plain" / "shard_00000.npz", ("action",))["action"][0]
    assert plain["action_noise_std"] == 0.0 and np.allclose(clean[0], first)
    with pytest.raises(ValueError, match="expert_action"):
        read_keys(tmp_path / "plain" / "shard_00000.npz", ("expert_action",))
