"""cathsim-train end to end on tiny budgets: outputs, resume, memory check (bad input: test_bad_inputs.py)."""

import json
import subprocess
import sys
import zipfile

import numpy as np

TINY = [
    "obs=internal",
    "demos=none",
    "task.max_steps=20",
    "algo.learning_starts=20",
    "algo.batch_size=16",
    "algo.buffer_size=2000",
    "trainer.checkpoint_every=30",
    "trainer.eval_every=0",
    "trainer.eval_episodes=1",
    "trainer.final_eval_episodes=1",
    "trainer.video=false",
    "trainer.progress_bar=false",
]


def _train(args, cwd):
    return subprocess.run(
        [sys.executable, "-m", "cathsim_dmc.app.cli.train", *args], cwd=cwd, capture_output=True, text=True, timeout=900
    )


def _steps(checkpoint) -> int:
    with zipfile.ZipFile(checkpoint) as z:
        return json.loads(z.read("data"))["num_timesteps"]


def test_a_trained_run_evaluates_under_its_own_physics_and_resumes_from_its_last_checkpoint(tmp_path):
    # One run for both, as each cathsim-train start costs a torch import and a model compile.
    run = tmp_path / "run"
    first = _train([*TINY, "trainer.total_timesteps=60", "task.physics=accurate", f"hydra.run.dir={run}"], tmp_path)
    assert first.returncode == 0, first.stderr[-2000:]
    ckpt = run / "checkpoints"
    assert {"step_30.zip", "step_60.zip", "last.zip"} <= {p.name for p in ckpt.iterdir()}
    assert _steps(ckpt / "last.zip") == 60
    assert list((run / "tensorboard").glob("*/events.out.tfevents.*"))
    assert (run / "eval" / "metrics.md").read_text().startswith("| Target | Aorta | Policy |")
    policy_file = json.loads((run / "policy.json").read_text())
    assert policy_file["obs"] == "internal" and policy_file["env_options"]["physics"] == "accurate"

    def evaluate(name, *extra):
        result = subprocess.run(
            [
                sys.executable,
                "-m",
                "cathsim_dmc.app.cli.eval",
                f"policy={run}",
                "episodes=1",
                "task.max_steps=10",
                "video=false",
                f"hydra.run.dir={tmp_path}/{name}",
                *extra,
            ],
            cwd=tmp_path,
            capture_output=True,
            text=True,
            timeout=600,
        )
        assert result.returncode == 0, result.stderr[-2000:]
        return json.loads((tmp_path / name / "metrics.json").read_text())

    # The default (fast) does not silently replace the setting the agent was trained under...
    report = evaluate("eval")
    assert report["policy"] == "run" and report["summary"]["episode_length"]["mean"] == 10
    assert report["physics"] == "accurate"
    # ...but an explicit one is a transfer test.
    assert evaluate("transfer", "task.physics=fast")["physics"] == "fast"

    # A second invocation continues the same run to a larger budget: the step count
    # carries on from 60 instead of starting again.
    again = _train([f"resume={run}", "trainer.total_timesteps=90", f"hydra.run.dir={tmp_path}/resume"], tmp_path)
    assert again.returncode == 0, again.stderr[-2000:]
    assert _steps(ckpt / "last.zip") == 90 and (ckpt / "step_90.zip").is_file()
    assert _steps(run / "final_model.zip") == 90


def test_replay_buffer_is_sized_for_the_run_and_grows_on_resume():
    from stable_baselines3.common.vec_env import DummyVecEnv

    from cathsim_dmc.learning.rl.replay import grow_replay_buffer
    from cathsim_dmc.learning.rl.train import build_sac, make_env_fn

    env = DummyVecEnv([make_env_fn("bca", "type1", "internal", 0, {"max_steps": 5})])
    algo = dict(
        learning_rate=3e-4,
        buffer_size=40,
        learning_starts=100,
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
    model.learn(25)
    held = model.replay_buffer.observations["joint_pos"][:25].copy()
    grow_replay_buffer(model, 100)
    buffer = model.replay_buffer
    assert buffer.buffer_size == 100 and buffer.pos == 25 and not buffer.full
    assert np.array_equal(buffer.observations["joint_pos"][:25], held)
    assert not buffer.observations["joint_pos"][25:].any()
    grow_replay_buffer(model, 50)  # never shrinks
    assert model.replay_buffer is buffer
    env.close()


def test_the_periodic_evaluation_keeps_sb3s_evaluation_callbacks():
    """PeriodicEvaluation is an EvalCallback: SB3's callback_after_eval runs after every
    evaluation, and callback_on_new_best (here SB3's reward threshold, reading the
    evaluation's best_mean_reward) when one is the best so far."""
    from stable_baselines3.common.callbacks import BaseCallback, StopTrainingOnRewardThreshold
    from stable_baselines3.common.vec_env import DummyVecEnv

    from cathsim_dmc.learning.rl.callbacks import PeriodicEvaluation
    from cathsim_dmc.learning.rl.train import build_sac, make_env_fn
    from cathsim_dmc.suite.gym import CathSimEnv

    class Calls(BaseCallback):
        def _on_step(self):  # on_step counts the calls in n_calls
            return True

    env = DummyVecEnv([make_env_fn("bca", "type1", "internal", 0, {"max_steps": 5})])
    algo = dict(
        learning_rate=3e-4,
        buffer_size=200,
        learning_starts=1000,
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
    after = Calls()
    evaluation = PeriodicEvaluation(
        CathSimEnv("bca", "type1", obs="internal", max_steps=5), 10, 1, seed=0, callback_after_eval=after
    )
    model.learn(30, callback=evaluation)
    assert after.n_calls == 3
    # 5-step episodes never reach the target: the best is the highest return.
    assert np.isfinite(evaluation.last_mean_reward) and evaluation.best_mean_reward >= evaluation.last_mean_reward
    stop = StopTrainingOnRewardThreshold(reward_threshold=-1e9)  # any best stops training
    evaluation = PeriodicEvaluation(
        CathSimEnv("bca", "type1", obs="internal", max_steps=5), 10, 1, seed=0, callback_on_new_best=stop
    )
    model.learn(100, callback=evaluation, reset_num_timesteps=False)
    assert model.num_timesteps == 40 and stop.n_calls == 1
    env.close()


def test_short_run_with_the_papers_buffer_allocates_only_what_it_uses(tmp_path):
    # obs=enn with a 1e6 buffer needs 24.9 GiB; a 30-step run stores 30 transitions.
    run = tmp_path / "run"
    tiny = [a for a in TINY if not a.startswith(("obs=", "algo.buffer_size="))]
    result = _train(
        [*tiny, "obs=enn", "algo.buffer_size=1000000", "trainer.total_timesteps=30", f"hydra.run.dir={run}"], tmp_path
    )
    assert result.returncode == 0, result.stderr[-2000:]
    assert (run / "eval" / "metrics.md").is_file()


def test_device_option_reaches_the_model():
    import torch
    from stable_baselines3.common.vec_env import DummyVecEnv

    from cathsim_dmc.learning.rl.train import build_sac, make_env_fn

    env = DummyVecEnv([make_env_fn("bca", "type1", "internal", 0, {"max_steps": 5})])
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
    assert build_sac(env, algo, 0, "cpu", None).device.type == "cpu"
    # "cuda" is used where a GPU exists; stable-baselines3 falls back to the CPU elsewhere.
    assert build_sac(env, algo, 0, "cuda", None).device.type == ("cuda" if torch.cuda.is_available() else "cpu")
    env.close()


def test_seed_sweep_through_submitit_local_writes_one_table(tmp_path):
    # The cluster path (conf/hydra/launcher/slurm.yaml) differs from this one only in
    # the submitit executor: each run is a separate process, pickled and launched.
    sweep = tmp_path / "sweep"
    result = _train(
        [
            "-m",
            "hydra/launcher=local",
            "seed=0,1",
            *TINY,
            "trainer.total_timesteps=30",
            "trainer.final_eval_episodes=2",
            f"hydra.sweep.dir={sweep}",
        ],
        tmp_path,
    )
    assert result.returncode == 0, result.stderr[-2000:]
    runs = sorted(p.parent.parent.name for p in sweep.glob("*/eval/metrics.json"))
    assert runs == ["bca-type1-internal-seed0", "bca-type1-internal-seed1"]
    rows = (sweep / "metrics.md").read_text().strip().splitlines()[2:]
    assert [r.split(" | ")[2] for r in rows] == [
        "sac-internal (seed 0)",
        "sac-internal (seed 1)",
        "sac-internal (2 seeds)",
    ]
    # The pooled row is over all four episodes of both seeds.
    reports = json.loads((sweep / "metrics.json").read_text())
    paths = [e["path_length_cm"] for r in reports for e in r["per_episode"]]
    assert len(paths) == 4
    assert rows[2].split(" | ")[4] == f"{sum(paths) / 4:.1f} ± {float(np.std(paths)):.1f}"


def test_slurm_launcher_config_composes_with_the_shipped_settings(tmp_path):
    result = _train(
        ["hydra/launcher=slurm", "hydra.launcher.partition=gpu", "--cfg", "hydra", "-p", "hydra.launcher"], tmp_path
    )
    assert result.returncode == 0, result.stderr[-2000:]
    assert "SlurmLauncher" in result.stdout and "partition: gpu" in result.stdout
    assert "gpus_per_node: 1" in result.stdout and "mem_gb: 32" in result.stdout


def test_a_checkpoint_keeps_its_views_unless_the_command_line_fixes_one(tmp_path):
    """A tracking_2d agent trained on views drawn per episode is evaluated on such views (each
    episode's angles in metrics.json), and in the AP view with an explicit obs.view_deg_range=null."""
    run = tmp_path / "run"
    views = ["obs=tracking_2d", "obs.view_deg_range=[-45,45]"]
    trained = _train([*TINY[1:], *views, "trainer.total_timesteps=30", f"hydra.run.dir={run}"], tmp_path)
    assert trained.returncode == 0, trained.stderr[-2000:]

    def episodes(name, *extra):
        result = subprocess.run(
            [sys.executable, "-m", "cathsim_dmc.app.cli.eval", f"policy={run}", "episodes=2", "task.max_steps=3"]
            + ["video=false", f"hydra.run.dir={tmp_path}/{name}", *extra],
            cwd=tmp_path,
            capture_output=True,
            text=True,
            timeout=600,
        )
        assert result.returncode == 0, result.stderr[-2000:]
        return json.loads((tmp_path / name / "metrics.json").read_text())["episodes"]

    drawn = [e["carm_view_deg"] for e in episodes("drawn")]
    assert all(-45 <= lao <= 45 and cranial == 0 for lao, cranial in drawn) and drawn[0] != drawn[1]
    assert all("carm_view_deg" not in e for e in episodes("ap", "obs.view_deg_range=null"))
