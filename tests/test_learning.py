"""Learning machinery: demonstrations mixed into batches, best-checkpoint selection, the
observation normaliser's round trip. Learning outcomes are measured in docs/learning.md,
not asserted here."""

import json
import subprocess
import sys

import numpy as np
import pytest

from cathsim_dmc.suite.gym import CathSimEnv


@pytest.fixture(scope="module")
def env():
    environment = CathSimEnv("bca", "type1", obs="internal", reward="geodesic", progress_weight=1.0)
    yield environment
    environment.close()


def _add(buffer_add, env, n, reward):
    obs = {k: np.zeros((1,) + s.shape, s.dtype) for k, s in env.observation_space.spaces.items()}
    for _ in range(n):
        buffer_add(
            obs,
            obs,
            np.zeros((1, 2), np.float32),
            np.array([reward], np.float32),
            np.array([False]),
            [{"TimeLimit.truncated": False}],
        )


def test_every_batch_takes_the_demo_share_from_the_demonstrations(env):
    from cathsim_dmc.learning.rl.demos import DemoReplayBuffer

    buffer = DemoReplayBuffer(1000, env.observation_space, env.action_space, device="cpu", demo_share=0.25)
    _add(buffer.demos.add, env, 50, reward=1.0)  # demonstrations carry reward 1
    assert buffer.sample(64).rewards.sum() == 64  # no own experience yet: all from the demonstrations
    _add(buffer.add, env, 500, reward=0.0)  # the agent's own carry 0
    for _ in range(5):
        batch = buffer.sample(64)
        assert batch.rewards.shape == (64, 1)
        assert float(batch.rewards.sum()) == 16  # exactly a quarter, every batch
        assert set(batch.observations) == set(env.observation_space.spaces)


def test_expert_demonstrations_are_recorded_with_the_training_reward(env):
    from cathsim_dmc.learning.rl.demos import expert_transitions

    demos = expert_transitions(env, episodes=1, seed=0)
    assert demos.successes == 1 and demos.terminated[-1] and not demos.terminated[:-1].any()
    assert demos.rewards[-1] == 10.0
    # Progress shaping: the expert's insertion up the descending aorta is paid for.
    assert demos.rewards[:10].mean() > 0.5
    assert demos.observations["joint_pos"].shape == (len(demos), env.observation_space["joint_pos"].shape[0])
    np.testing.assert_array_equal(demos.observations["joint_pos"][1:], demos.next_observations["joint_pos"][:-1])


def test_takeover_demonstrations_start_where_the_student_left_the_wire(env):
    from cathsim_dmc.learning.rl.demos import takeover_transitions

    student_action = np.array([0.5, -0.8], np.float32)  # a student that pushes and turns one way
    demos = takeover_transitions(env, lambda obs: student_action, episodes=2, seed=3, max_student_steps=40)
    # Only the expert's part is kept: every stored action is the expert's, and the expert
    # still reaches the target from wherever the student handed over.
    assert not np.all(demos.actions == student_action, axis=1).any()
    assert demos.successes == 2 and demos.terminated.sum() == 2 and demos.rewards[demos.terminated].min() == 10.0
    assert demos.steps_taken > len(demos)  # the student's steps were taken, not kept
    # Handed over mid-episode: the first kept state is not the start, the insertion the
    # student made (at 0.5 of full speed) is already there.
    assert demos.observations["joint_pos"][0, 0] > 0.01


def test_expert_labels_cover_every_state_the_student_reaches(env):
    """DAgger's data: the student drives, the expert labels each state it reaches."""
    from cathsim_dmc.control.expert import CenterlineExpert
    from cathsim_dmc.learning.rl.demos import expert_labels

    short = CathSimEnv("bca", "type1", obs="internal", max_steps=15)
    try:
        student_action = np.array([1.0, 0.0], np.float32)
        labels = expert_labels(short, lambda obs: student_action, episodes=2, seed=7)
        assert len(labels) == 30 and labels.episodes == 2 and labels.successes == 0
        assert labels.observations["joint_pos"].shape == (30, short.observation_space["joint_pos"].shape[0])
        # The first label is what the expert does at the start, where the student's episode began.
        obs, _ = short.reset(seed=7)
        np.testing.assert_allclose(labels.actions[0], CenterlineExpert()(obs, short), atol=1e-6)
        np.testing.assert_array_equal(labels.observations["joint_pos"][0], obs["joint_pos"])
        # The student's insertion is taken, not the expert's: the wire goes in at full speed.
        assert labels.observations["joint_pos"][14, 0] > labels.observations["joint_pos"][0, 0] + 0.01
    finally:
        short.close()


def test_cloning_batches_draw_from_demonstrations_and_labels_by_their_sizes(env):
    from cathsim_dmc.learning.rl.demos import DemoReplayBuffer, Labels, add_labels

    buffer = DemoReplayBuffer(100, env.observation_space, env.action_space, device="cpu", label_capacity=1000)
    obs = {k: np.zeros((1,) + s.shape, s.dtype) for k, s in env.observation_space.spaces.items()}
    for _ in range(100):  # demonstrations act [1, 1]
        buffer.demos.add(
            obs,
            obs,
            np.ones((1, 2), np.float32),
            np.zeros(1, np.float32),
            np.array([False]),
            [{"TimeLimit.truncated": False}],
        )
    _, actions = buffer.cloning_batch(64)
    assert float(actions.min()) == 1.0  # no labels yet: all from the demonstrations
    stacked = {k: np.zeros((300,) + s.shape, s.dtype) for k, s in env.observation_space.spaces.items()}
    add_labels(buffer, Labels(stacked, -np.ones((300, 2), np.float32), 1, 0))  # labels act [-1, -1]
    assert buffer.label_count() == 300
    np.random.seed(0)
    share = np.mean([float((buffer.cloning_batch(256)[1][:, 0] < 0).float().mean()) for _ in range(20)])
    assert share == pytest.approx(0.75, abs=0.02)
    # The critic's batches never see a label (they are not transitions).
    assert float(buffer.sample(64).actions.min()) == 1.0


def test_best_checkpoint_keeps_the_highest_success_then_return(env, tmp_path):
    from stable_baselines3 import SAC

    from cathsim_dmc.learning.rl.checkpoints import best_record, keep_if_best

    model = SAC("MultiInputPolicy", env, buffer_size=100, learning_starts=10, device="cpu")
    sequence = [
        (1000, 0.2, -5.0, True),
        (2000, 0.1, 3.0, False),
        (3000, 0.2, -6.0, False),
        (4000, 0.2, -4.0, True),
        (5000, 0.6, -9.0, True),
        (6000, 0.6, -9.0, False),
    ]
    for step, success, ret, expected in sequence:
        assert keep_if_best(model, tmp_path, step, success, ret) is expected
    assert best_record(tmp_path) == {"step": 5000, "success_rate": 0.6, "mean_return": -9.0}
    assert (tmp_path / "checkpoints" / "best.zip").is_file()


def test_eval_at_start_scores_the_pre_trained_policy_before_the_first_step(tmp_path):
    from cathsim_dmc.learning.rl import train as training

    algo = dict(learning_starts=10, batch_size=16, net_arch=[32, 32])
    trainer = dict(
        total_timesteps=20,
        eval_every=10,
        eval_episodes=1,
        eval_at_start=True,
        checkpoint_every=0,
        progress_bar=False,
        video=False,
    )
    env = training.make_vec_env("bca", "type1", "internal", 0, 1, {"max_steps": 5})
    try:
        training.train(
            env,
            tmp_path,
            algo,
            trainer,
            0,
            "internal",
            "bca",
            "type1",
            make_eval_env=lambda: CathSimEnv("bca", "type1", obs="internal", max_steps=5),
        )
    finally:
        env.close()
    records = [json.loads(line) for line in (tmp_path / "evaluations.jsonl").read_text().splitlines()]
    assert [r["step"] for r in records] == [0, 10, 20]


def test_each_periodic_evaluation_replays_the_same_starts_and_best_json_keeps_the_best(tmp_path):
    """trainer.eval_every: every evaluation resets episode i with seed 20_000 + seed + i,
    writes a line of evaluations.jsonl, and best.json holds the best evaluation (success
    rate first, then return; the earlier on a tie)."""
    from hydra import compose, initialize_config_dir
    from omegaconf import OmegaConf

    from cathsim_dmc.core.shipped import conf_root
    from cathsim_dmc.learning.rl import train as training

    with initialize_config_dir(config_dir=str(conf_root()), version_base=None):
        cfg = compose("train", overrides=["obs=internal", "demos=none"])
    algo = dict(OmegaConf.to_container(cfg.algo, resolve=True), learning_starts=10, batch_size=16, net_arch=[32, 32])
    trainer = dict(
        OmegaConf.to_container(cfg.trainer, resolve=True),
        total_timesteps=60,
        eval_every=20,
        eval_episodes=2,
        checkpoint_every=0,
        progress_bar=False,
        video=False,
    )
    seeds = []

    class SeedLog(CathSimEnv):
        def reset(self, seed=None, options=None):
            seeds.append(seed)
            return super().reset(seed=seed, options=options)

    env = training.make_vec_env("bca", "type1", "internal", 0, 1, {"max_steps": 5})
    try:
        training.train(
            env,
            tmp_path,
            algo,
            trainer,
            0,
            "internal",
            "bca",
            "type1",
            make_eval_env=lambda: SeedLog("bca", "type1", obs="internal", max_steps=5),
        )
    finally:
        env.close()
    assert seeds == [20_000, 20_001] * 3
    records = [json.loads(line) for line in (tmp_path / "evaluations.jsonl").read_text().splitlines()]
    assert [(r["step"], r["episodes"]) for r in records] == [(20, 2), (40, 2), (60, 2)]
    top = max(records, key=lambda r: (r["success_rate"], r["mean_return"]))  # max keeps the first of equals
    best = json.loads((tmp_path / "checkpoints" / "best.json").read_text())
    assert best == {
        "step": top["step"],
        "success_rate": top["success_rate"],
        "mean_return": top["mean_return"],
        "episodes": 2,
    }


def test_normaliser_statistics_are_saved_with_checkpoints_and_used_by_the_evaluator(tmp_path):
    from cathsim_dmc.agents.trained import load_checkpoint_policy

    run = tmp_path / "run"
    args = [
        "obs=internal",
        "reward=progress",
        "task.max_steps=20",
        "algo.learning_starts=20",
        "algo.batch_size=16",
        "algo.buffer_size=2000",
        "trainer.total_timesteps=40",
        "trainer.checkpoint_every=20",
        "trainer.eval_every=20",
        "trainer.eval_episodes=1",
        "trainer.final_eval_episodes=1",
        "trainer.video=false",
        "trainer.progress_bar=false",
        "experimental.normalize_observations=true",
        "demos.episodes=1",
        "demos.pretrain_actor_steps=5",
        "demos.critic_warmup_steps=5",
        f"hydra.run.dir={run}",
    ]
    result = subprocess.run(
        [sys.executable, "-m", "cathsim_dmc.app.cli.train", *args],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert result.returncode == 0, result.stderr[-2000:]
    checkpoints = run / "checkpoints"
    for name in ("last", "step_20", "step_40", "best"):
        assert (checkpoints / f"{name}.vecnormalize.pkl").is_file(), name
    assert json.loads((run / "policy.json").read_text())["normalize_observations"] is True
    assert len((run / "evaluations.jsonl").read_text().splitlines()) == 2

    policy = load_checkpoint_policy(checkpoints / "last.zip")
    stats = policy.normalizer.obs_rms["joint_pos"]
    # Statistics of real observations (the expert's, then the agent's): not the initial zero/one.
    assert stats.count > 20 and np.abs(stats.mean).max() > 0.01
    assert policy.normalizer.training is False
    env = CathSimEnv("bca", "type1", obs="internal")
    obs, _ = env.reset(seed=0)
    normalized = policy.normalizer.normalize_obs(obs)
    expected = np.clip((obs["joint_pos"] - stats.mean) / np.sqrt(stats.var + policy.normalizer.epsilon), -10, 10)
    np.testing.assert_allclose(normalized["joint_pos"], expected, rtol=1e-5, atol=1e-6)
    action = policy(obs, env)
    assert action.shape == (2,) and np.all(np.abs(action) <= 1)
    env.close()

    # Resuming continues the saved statistics (and the run's clock in evaluations.jsonl).
    count_before = stats.count
    again = subprocess.run(
        [
            sys.executable,
            "-m",
            "cathsim_dmc.app.cli.train",
            f"resume={run}",
            "trainer.total_timesteps=60",
            f"hydra.run.dir={tmp_path}/resume",
        ],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert again.returncode == 0, again.stderr[-2000:]
    resumed = load_checkpoint_policy(checkpoints / "last.zip").normalizer.obs_rms["joint_pos"]
    assert resumed.count > count_before + 15


def test_demonstrations_from_a_collected_dataset_match_the_live_expert(env, tmp_path):
    """Rewards recomputed from a cathsim-collect dataset's tip positions equal the live ones."""
    from cathsim_dmc.agents.collect import collect
    from cathsim_dmc.learning.rl.demos import dataset_transitions, expert_transitions

    collect(tmp_path / "data", "bca", "type1", "expert", episodes=2, episodes_per_shard=1, seed=7, show_progress=False)
    from_data = dataset_transitions(tmp_path / "data", env.task, env.observation_space)
    live = expert_transitions(env, episodes=2, seed=7)
    assert from_data.episodes == 2 and len(from_data) == len(live)
    np.testing.assert_allclose(from_data.rewards, live.rewards, rtol=1e-5, atol=1e-5)
    np.testing.assert_array_equal(from_data.terminated, live.terminated)
    np.testing.assert_allclose(from_data.actions, live.actions, atol=1e-6)
    for key in ("joint_pos", "joint_vel"):
        np.testing.assert_allclose(from_data.observations[key], live.observations[key], atol=1e-5)
        np.testing.assert_allclose(from_data.next_observations[key], live.next_observations[key], atol=1e-5)
    first_only = dataset_transitions(tmp_path / "data", env.task, env.observation_space, episodes=1)
    assert first_only.episodes == 1 and len(first_only) == int(np.flatnonzero(live.terminated)[0]) + 1


def test_demonstrations_beyond_the_capacity_are_refused(env):
    from cathsim_dmc.learning.rl.demos import DemoReplayBuffer, add_transitions, expert_transitions

    demos = expert_transitions(env, episodes=1, seed=0)
    buffer = DemoReplayBuffer(100, env.observation_space, env.action_space, device="cpu", demo_capacity=len(demos) - 1)
    with pytest.raises(ValueError, match="demos.capacity"):
        add_transitions(buffer, demos)


def test_behavioural_cloning_term_pulls_the_deterministic_action_towards_the_expert(env):
    """SACfD's BC term: the same updates from the same start, with and without it."""
    import torch
    from stable_baselines3.common.vec_env import DummyVecEnv

    from cathsim_dmc.learning.rl.demos import add_transitions, expert_transitions
    from cathsim_dmc.learning.rl.sacfd import warm_up_critic
    from cathsim_dmc.learning.rl.train import build_sac

    demos = expert_transitions(env, episodes=1, seed=0)
    algo = dict(
        learning_rate=3e-4,
        buffer_size=500,
        learning_starts=0,
        batch_size=64,
        tau=0.005,
        gamma=0.99,
        train_freq=1,
        gradient_steps=1,
        target_update_interval=1,
        target_entropy=-2.0,
        ent_coef="auto_0.05",
        net_arch=[64, 64],
        share_features_extractor=False,
        critic_layer_norm=True,
    )
    errors = {}
    for weight in (0.0, 2.0):
        model = build_sac(
            DummyVecEnv([lambda: env]), algo, 0, "cpu", None, dict(share=0.5, capacity=1000, bc_weight=weight)
        )
        add_transitions(model.replay_buffer, demos)
        model._setup_learn(1)  # SB3 sets up its logger here; train() records to it
        warm_up_critic(model, 150, batch_size=64)  # as in the recipe, at half its 300 steps
        model.train(gradient_steps=75, batch_size=64)
        with torch.no_grad():
            obs = {k: torch.as_tensor(v) for k, v in demos.observations.items()}
            mean, _, _ = model.actor.get_action_dist_params(obs)
            errors[weight] = float(((torch.tanh(mean) - torch.as_tensor(demos.actions)) ** 2).sum(dim=1).mean())
    print(errors)
    # Paired runs (same seed, same batches). Measured 0.16 against 1.06 (0.03 against 2.48
    # after 300 warm-up steps and 150 updates).
    assert errors[2.0] < 0.9 * errors[0.0]


def test_averaged_actor_trails_the_trained_one_and_is_what_best_zip_holds(env, tmp_path):
    """algo.actor_average_tau: an exponential average of the actor, swapped in for evaluation."""
    import torch
    from stable_baselines3 import SAC
    from stable_baselines3.common.vec_env import DummyVecEnv

    from cathsim_dmc.learning.rl.checkpoints import keep_if_best
    from cathsim_dmc.learning.rl.demos import add_transitions, expert_transitions
    from cathsim_dmc.learning.rl.train import build_sac

    demos = expert_transitions(env, episodes=1, seed=0)
    algo = dict(
        learning_rate=1e-3,
        buffer_size=500,
        learning_starts=0,
        batch_size=64,
        tau=0.005,
        gamma=0.99,
        train_freq=1,
        gradient_steps=1,
        target_update_interval=1,
        target_entropy=-2.0,
        ent_coef="auto_0.05",
        net_arch=[64, 64],
        share_features_extractor=False,
        critic_layer_norm=True,
        actor_average_tau=0.1,
    )
    model = build_sac(DummyVecEnv([lambda: env]), algo, 0, "cpu", None, dict(share=0.5, capacity=1000))
    add_transitions(model.replay_buffer, demos)
    model._setup_learn(1)

    def flat():
        return torch.cat([p.detach().flatten() for p in model.actor.parameters()]).clone()

    model.train(gradient_steps=1, batch_size=64)
    start = flat()  # the average starts from the actor after its first update
    for _ in range(30):
        model.train(gradient_steps=1, batch_size=64)
    trained = flat()
    with model.averaged_actor():
        averaged = flat()
        keep_if_best(model, tmp_path, step=31, success_rate=1.0, mean_return=0.0)
    assert torch.equal(flat(), trained)  # restored after the block
    # 30 updates at tau 0.1: the average has moved most of the way, not all of it.
    moved = float(torch.linalg.norm(averaged - start) / torch.linalg.norm(trained - start))
    assert 0.2 < moved < 0.95
    saved = SAC.load(tmp_path / "checkpoints" / "best.zip", device="cpu")
    saved_flat = torch.cat([p.detach().flatten() for p in saved.actor.parameters()])
    torch.testing.assert_close(saved_flat, averaged)
    # A periodic checkpoint holds the trained actor and the average beside it; cathsim-eval
    # plays the average, the policy its periodic evaluation scored.
    from cathsim_dmc.agents.trained import load_checkpoint_policy
    from cathsim_dmc.learning.rl.checkpoints import save_checkpoint, write_policy_file

    write_policy_file(tmp_path, "internal", "bca", "type1")
    step_file = save_checkpoint(model, tmp_path / "checkpoints", replay_buffer=False).with_name(
        f"step_{model.num_timesteps}.zip"
    )
    raw = SAC.load(step_file, device="cpu")
    torch.testing.assert_close(torch.cat([p.detach().flatten() for p in raw.actor.parameters()]), trained)
    played = load_checkpoint_policy(step_file).model
    torch.testing.assert_close(torch.cat([p.detach().flatten() for p in played.actor.parameters()]), averaged)


def test_a_tie_at_the_best_success_rate_is_broken_on_more_selection_episodes(env, tmp_path):
    import torch
    from stable_baselines3 import SAC

    from cathsim_dmc.agents.trained import load_checkpoint_policy
    from cathsim_dmc.learning.rl.callbacks import break_best_tie
    from cathsim_dmc.learning.rl.checkpoints import (
        append_evaluation,
        best_record,
        keep_if_best,
        save_model,
        write_policy_file,
    )

    write_policy_file(tmp_path, "internal", "bca", "type1")
    folder = tmp_path / "checkpoints"
    first = SAC("MultiInputPolicy", env, buffer_size=100, seed=0, device="cpu", policy_kwargs={"net_arch": [8]})
    other = SAC("MultiInputPolicy", env, buffer_size=100, seed=1, device="cpu", policy_kwargs={"net_arch": [8]})
    history = [(0, first, 1.0, 2.0), (1000, first, 1.0, 2.0), (2000, other, 1.0, 1.0), (3000, other, 0.5, 9.0)]
    for step, model, success, ret in history:  # step 1000: no update yet, the same weights as step 0
        save_model(model, folder / f"step_{step}.zip")
        keep_if_best(model, tmp_path, step, success, ret, episodes=10)
        append_evaluation(tmp_path, {"step": step, "success_rate": success, "mean_return": ret, "wall_s": 0.0})
    assert best_record(tmp_path)["step"] == 0

    record = break_best_tie(
        tmp_path,
        lambda: CathSimEnv("bca", "type1", obs="internal", max_steps=15),
        periodic_episodes=10,
        extra_episodes=2,
        seed=20_000,
    )
    scores = record["tie_break"]["scores"]
    assert [s["step"] for s in scores] == [0, 2000]  # 1000 played once, as step 0; 3000 not tied
    assert all(s["episodes"] == 12 for s in scores)
    assert all(s["success_rate"] <= 1.0 and s["success_rate"] >= 10 / 12 for s in scores)
    winner = max(scores, key=lambda s: (s["success_rate"], s["mean_return"]))
    assert best_record(tmp_path)["step"] == winner["step"] == record["step"]
    kept = load_checkpoint_policy(folder / "best.zip").model
    source = first if winner["step"] == 0 else other
    for a, b in zip(kept.actor.parameters(), source.actor.parameters()):
        torch.testing.assert_close(a, b)
    # Broken once for these evaluations: a finished run resumed does not play them again.
    from cathsim_dmc.learning.rl.callbacks import has_unbroken_tie

    assert not has_unbroken_tie(tmp_path)
    assert (
        break_best_tie(tmp_path, lambda: CathSimEnv("bca", "type1", obs="internal", max_steps=15), 10, 2, 20_000)
        is None
    )


@pytest.mark.parametrize(
    "overrides, episodes, capacity, takeover_rounds, expert",
    [
        ([], 100, 20_000, 0, "expert"),
        (["task=lcca"], 300, 40_000, 3, "expert"),  # the LCCA's own budget (conf/demos_for_task)
        (["task=lcca", "demos=none"], 0, 20_000, 0, "expert"),  # no demonstrations means none, whatever the target
        (
            ["task=lcca", "demos.episodes=50", "demos.takeover_rounds=0"],
            50,
            40_000,
            0,
            "expert",
        ),  # the command line wins
        (["obs=enn"], 100, 20_000, 3, "expert"),  # and the preset: the ENN's takeover rounds (conf/demos_for_obs)
        (["task=lcca", "obs=enn"], 300, 40_000, 3, "expert"),
        (["obs=enn", "demos.takeover_rounds=0", "demos.expert=expert_steady"], 100, 20_000, 0, "expert_steady"),
    ],
)
def test_the_demonstrations_follow_the_target_and_the_preset(overrides, episodes, capacity, takeover_rounds, expert):
    from hydra import compose, initialize_config_dir

    from cathsim_dmc.core.shipped import conf_root

    with initialize_config_dir(config_dir=str(conf_root()), version_base="1.3"):
        demos = compose(config_name="train", overrides=overrides).demos
    assert (demos.episodes, demos.capacity, demos.takeover_rounds, demos.expert) == (
        episodes,
        capacity,
        takeover_rounds,
        expert,
    )


def test_a_shorter_budget_is_the_start_of_a_longer_run(tmp_path):
    """trainer.total_timesteps only says where a run stops: nothing in training depends on
    it (no schedule over the budget), so a short run's evaluations and weights are the
    first part of a long run's, and its best.zip is the long run's wherever that came early
    (the reason the default budget could be cut to what the results needed)."""
    import torch
    from hydra import compose, initialize_config_dir
    from omegaconf import OmegaConf

    from cathsim_dmc.core.shipped import conf_root
    from cathsim_dmc.learning.rl import train as training
    from cathsim_dmc.learning.rl.sacfd import SACfD

    with initialize_config_dir(config_dir=str(conf_root()), version_base=None):
        cfg = compose("train", overrides=["obs=internal", "demos=none"])
    algo = dict(OmegaConf.to_container(cfg.algo, resolve=True), learning_starts=10, batch_size=16, net_arch=[32, 32])
    runs = {}
    for total in (20, 40):
        trainer = dict(
            OmegaConf.to_container(cfg.trainer, resolve=True),
            total_timesteps=total,
            eval_every=10,
            eval_episodes=2,
            checkpoint_every=20,
            progress_bar=False,
            video=False,
        )
        env = training.make_vec_env("bca", "type1", "internal", 0, 1, {"max_steps": 5})
        try:
            training.train(
                env,
                tmp_path / str(total),
                algo,
                trainer,
                0,
                "internal",
                "bca",
                "type1",
                make_eval_env=lambda: CathSimEnv("bca", "type1", obs="internal", max_steps=5),
            )
        finally:
            env.close()
        records = [json.loads(line) for line in (tmp_path / str(total) / "evaluations.jsonl").read_text().splitlines()]
        runs[total] = [{k: v for k, v in r.items() if k != "wall_s"} for r in records]  # all but the clock
    assert [r["step"] for r in runs[40]] == [10, 20, 30, 40]
    assert runs[20] == runs[40][:2]
    # Compared at step 20, after 10 updates (learning starts at step 10).
    weights = {
        total: SACfD.load(tmp_path / str(total) / "checkpoints" / "step_20.zip").policy.state_dict()
        for total in (20, 40)
    }
    assert weights[20].keys() == weights[40].keys()
    assert all(torch.equal(weights[20][k], weights[40][k]) for k in weights[20])


def test_dagger_rounds_add_labels_that_a_resumed_run_reads_back(tmp_path):
    """demos.dagger_rounds: the labels join the buffer, are saved in the checkpoint folder,
    and a resumed run (which does not pre-train again) reads them back for the cloning term."""
    from stable_baselines3.common.callbacks import BaseCallback

    from cathsim_dmc.learning.rl import train as training

    algo = dict(learning_starts=10, batch_size=16, net_arch=[32, 32])
    demos = dict(episodes=1, pretrain_actor_steps=5, dagger_rounds=2, dagger_episodes=1, bc_weight=0.5)
    counts = []

    class Count(BaseCallback):
        def _on_training_start(self):
            counts.append(self.model.replay_buffer.label_count())

        def _on_step(self):
            return True

    def run(total, resume):
        env = training.make_vec_env("bca", "type1", "internal", 0, 1, {"max_steps": 12})
        make = lambda: CathSimEnv("bca", "type1", obs="internal", max_steps=12)  # noqa: E731
        trainer = dict(total_timesteps=total, eval_every=0, progress_bar=False, video=False, checkpoint_every=0)
        try:
            training.train(
                env,
                tmp_path,
                algo,
                trainer,
                0,
                "internal",
                "bca",
                "type1",
                resume=resume,
                demos=demos,
                make_demo_env=make,
                callbacks=[Count()],
            )
        finally:
            env.close()

    run(20, resume=False)
    saved = tmp_path / "checkpoints" / training.LABELS_FILE
    with np.load(saved) as data:
        assert data["action"].shape == (24, 2)  # two rounds of one 12-step episode
        assert data["obs_joint_pos"].shape[0] == 24
    run(40, resume=True)
    assert counts == [24, 24]


def test_the_chosen_expert_records_takes_over_and_labels(tmp_path):
    """demos.expert=expert_steady: every demonstration, takeover and DAgger label comes from
    the steady expert, which never turns while the tip climbs the descending aorta (the
    default expert does turn there, at these starts)."""
    from cathsim_dmc.control.policies import BUILTIN_POLICIES
    from cathsim_dmc.learning.rl import train as training
    from cathsim_dmc.learning.rl.settings import DEMONSTRATORS

    assert set(DEMONSTRATORS) <= set(BUILTIN_POLICIES)  # every name demos.expert accepts can be built
    algo = dict(learning_starts=10, batch_size=16, net_arch=[32, 32])
    demos = dict(
        episodes=2,
        expert="expert_steady",
        pretrain_actor_steps=5,
        takeover_rounds=1,
        takeover_episodes=1,
        takeover_max_student_steps=5,
        dagger_rounds=1,
        dagger_episodes=1,
        bc_weight=0.5,
    )
    env = training.make_vec_env("bca", "type1", "internal", 0, 1, {"max_steps": 15})
    make = lambda: CathSimEnv("bca", "type1", obs="internal", max_steps=15)  # noqa: E731
    trainer = dict(total_timesteps=12, eval_every=0, progress_bar=False, video=False, checkpoint_every=0)
    try:
        result = training.train(
            env, tmp_path, algo, trainer, 0, "internal", "bca", "type1", demos=demos, make_demo_env=make
        )
    finally:
        env.close()
    buffer = result.model.replay_buffer
    recorded, labelled = buffer.demos.size(), buffer.label_count()
    assert recorded > 30 and labelled == 15  # two 15-step episodes and a takeover; one driven episode
    assert np.all(buffer.demos.actions[:recorded, 0, 1] == 0.0)
    assert np.all(buffer.labels.actions[:labelled, 0, 1] == 0.0)
    assert buffer.demos.actions[:recorded, 0, 0].max() > 0  # it does insert


def test_sb3_logs_the_success_rate_from_the_last_steps_info_and_episode_stats_the_force():
    """Through the training's vector env (DummyVecEnv of Monitor), every episode's last
    info carries is_success, from which SB3 logs rollout/success_rate; EpisodeStats adds
    the mean contact force."""
    from stable_baselines3.common.logger import KVWriter, Logger

    from cathsim_dmc.learning.rl.callbacks import EpisodeStats
    from cathsim_dmc.learning.rl.train import build_sac, make_vec_env

    class Dumps(KVWriter):
        def __init__(self):
            self.dumps = []

        def write(self, key_values, key_excluded, step=0):
            self.dumps.append(dict(key_values))

    env = make_vec_env("bca", "type1", "internal", 0, 1, dict(max_steps=3))
    model = build_sac(env, dict(learning_starts=100, batch_size=16, buffer_size=100, net_arch=[16]), 0, "cpu", None)
    dumps = Dumps()
    model.set_logger(Logger(None, [dumps]))
    model.learn(total_timesteps=9, callback=EpisodeStats(), log_interval=1)
    env.close()
    assert list(model.ep_success_buffer) == [False, False, False]  # one per episode, from info["is_success"]
    logged = [d for d in dumps.dumps if "rollout/success_rate" in d]
    assert len(logged) == 3 and all(d["rollout/success_rate"] == 0.0 for d in logged)
    assert all(d["rollout/mean_contact_force_n"] >= 0.0 and "time/env_steps_per_s" in d for d in logged)


@pytest.mark.parametrize("ent_coef", ["auto_0.05", 0.1])
def test_sacfds_copy_of_sac_train_makes_sacs_updates_bit_for_bit_without_the_cloning_term(env, ent_coef):
    """SACfD's loop with the cloning term (a copy of SB3's SAC.train, which has no hook into
    the actor's loss) on no demonstration states: the same updates as SAC.train itself from
    the same weights, batches and seed. Fails when SB3's SAC.train changes."""
    import torch
    from stable_baselines3 import SAC
    from stable_baselines3.common.vec_env import DummyVecEnv

    from cathsim_dmc.learning.rl.train import build_sac

    algo = dict(buffer_size=300, learning_starts=0, batch_size=32, target_update_interval=2, net_arch=[32, 32])
    algo["ent_coef"] = ent_coef
    models = [build_sac(DummyVecEnv([lambda: env]), algo, 0, "cpu", None) for _ in range(2)]
    space, rng = env.observation_space, np.random.default_rng(0)
    for _ in range(200):
        obs, next_obs = ({k: rng.normal(size=(1,) + s.shape).astype(s.dtype) for k, s in space.items()} for _ in "ab")
        action, reward = rng.uniform(-1, 1, (1, 2)).astype(np.float32), rng.normal(size=1).astype(np.float32)
        done = np.array([rng.random() < 0.1])
        for model in models:
            model.replay_buffer.add(obs, next_obs, action, reward, done, [{"TimeLimit.truncated": False}])
    for model, update in zip(models, (lambda m: SAC.train(m, 6, 32), lambda m: m._train_with_cloning(6, 32, 0))):
        model._setup_learn(1)
        np.random.seed(1)  # the replay buffer's draws
        torch.manual_seed(1)  # the actor's sampled actions
        update(model)

    def state(model):
        tensors = {**model.actor.state_dict(), **{f"critic.{k}": v for k, v in model.critic.state_dict().items()}}
        tensors.update({f"target.{k}": v for k, v in model.critic_target.state_dict().items()})
        optimizers = [model.actor.optimizer, model.critic.optimizer]
        if model.ent_coef_optimizer is not None:
            tensors["log_ent_coef"] = model.log_ent_coef
            optimizers.append(model.ent_coef_optimizer)
        for i, optimizer in enumerate(optimizers):
            for j, moments in enumerate(optimizer.state_dict()["state"].values()):
                tensors.update({f"optimizer{i}.{j}.{k}": v for k, v in moments.items() if torch.is_tensor(v)})
        return tensors

    sac, copy = state(models[0]), state(models[1])
    assert sac.keys() == copy.keys() and len(sac) > 20
    assert [k for k in sac if not torch.equal(sac[k], copy[k])] == []
    assert models[0]._n_updates == models[1]._n_updates == 6
    start = build_sac(DummyVecEnv([lambda: env]), algo, 0, "cpu", None).actor.state_dict()
    assert not all(torch.equal(start[k], models[0].actor.state_dict()[k]) for k in start)  # the updates moved it
