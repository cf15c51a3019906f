"""Bad input, as a new user types it: one table per surface, so the list can grow.

A command-line tool must answer with one line on stderr that names the bad value (and
the valid choices), exit status 2, no traceback, and must fail before any work: its run
folder holds nothing but what Hydra writes on start (.hydra/ and the log). The Python
API must raise ValueError or RuntimeError naming the parameter.
"""

import subprocess
import sys

import numpy as np
import pytest

# Files Hydra itself writes into a run folder before the tool's code runs.
HYDRA_FILES = {".hydra"}


def _tool(tool: str, args, cwd):
    return subprocess.run([sys.executable, "-m", f"cathsim_dmc.cli.{tool}", *args], cwd=cwd,
                          capture_output=True, text=True, timeout=900)


def _write(path, content):
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(content)


# (tool, arguments, text the one line must contain, whether it fails before any work).
# `{tmp}` is the test's folder, `{run}` a real training run whose agent sees obs=internal.
# A few failures need the environment first (the replay-buffer memory estimate reads the
# observation space): those are marked False and only need to be one line.
CLI_CASES = [
    # cathsim-eval
    ("eval", ["task=xyz"], "bca", True),
    ("eval", ["aorta=xyz"], "type1", True),
    ("eval", ["policy=xyz"], "forward", True),
    ("eval", ["policy=/no/such/checkpoint.zip"], "checkpoint", True),
    ("eval", ["video_format=avi"], "mp4", True),
    # used to run the episode, then blame a missing OpenGL backend for the framebuffer's size
    ("eval", ["video_size=640"], "video_size=640 is larger than the offscreen framebuffer; choose 1 to 480", True),
    ("eval", ["episodes=abc"], "episodes='abc'", True),
    ("eval", ["episodes=0"], "episodes=0", True),  # used to leave an empty trajectories.npz
    ("eval", ["episodes=2.5"], "episodes=2.5", True),
    ("eval", ["seed=-1"], "seed=-1", True),
    ("eval", ["task.max_steps=0"], "max_steps=0", True),
    ("eval", ["task.delta_m=-1"], "delta_m=-1", True),
    ("eval", ["task.physics=quick"], "physics='quick' is not a physics setting; choose one of ['accurate', 'fast', 'fast_field']",
     True),
    ("eval", ["task.catheter=cobra"], "catheter='cobra' is not a catheter; choose one of ['angled_5f']", True),
    ("eval", ["policy={run}", "obs=enn"], "obs='internal'", True),
    # cathsim-train
    ("train", ["obs=xyz"], "enn", True),
    ("train", ["algo=ppo"], "sac", True),
    ("train", ["aorta=nope"], "type1", True),
    ("train", ["reward=xyz"], "progress", True),
    ("train", ["demos=xyz"], "expert", True),
    ("train", ["resume=/nonexistent/run"], "resume", True),
    ("train", ["seed=abc"], "seed='abc'", True),
    ("train", ["algo.learning_rate=abc"], "algo.learning_rate='abc'", True),
    ("train", ["algo.batch_size=0"], "algo.batch_size=0", True),
    ("train", ["trainer.total_timesteps=0"], "trainer.total_timesteps=0", True),
    ("train", ["trainer.total_timesteps=-5"], "trainer.total_timesteps=-5", True),
    ("train", ["trainer.n_envs=0"], "n_envs", True),
    ("train", ["trainer.device=tpu"], "cuda", True),
    ("train", ["trainer.eval_episodes=0", "trainer.final_eval_episodes=null"], "trainer.eval_episodes=0", True),
    ("train", ["task.max_steps=0"], "max_steps=0", True),
    ("train", ["task.dense=maybe"], "task.dense='maybe'", True),
    ("train", ["trainer.final_policy=median"], "trainer.final_policy='median'; choose one of ['best', 'last']", True),
    ("train", ["demos.episodes=-4"], "demos.episodes=-4", True),
    ("train", ["algo.gamma=1.5"], "algo.gamma=1.5 must lie in [0, 1]", True),
    ("train", ["experimental.extra_observations=[slack]"], "experimental.extra_observations=['slack']", True),
    ("train", ["+obs.extra=[wire_slack]"], "experimental.extra_observations", True),
    ("train", ["algo.actor_average_tau=2"], "actor_average_tau", True),
    ("train", ["demos.episodes=1", "demos.share=1.5"], "demos.share=1.5 must lie in [0, 1]", True),
    # 1e9 transitions of two 80x80 images: far beyond any machine's memory.
    ("train", ["obs=enn", "algo.buffer_size=1000000000", "trainer.total_timesteps=1000000000"], "algo.buffer_size",
     False),
    # cathsim-collect
    ("collect", ["policy=/no/such/agent"], "checkpoint", True),
    ("collect", ["task=xyz"], "bca", True),
    ("collect", ["episodes=0"], "episodes", True),
    ("collect", ["seed=abc"], "seed='abc'", True),
    ("collect", ["out={tmp}/a_file.npz"], "a_file.npz", True),
    ("collect", ["out={tmp}/data"], "manifest.json", True),  # {tmp}/data/manifest.json is corrupt
    # any tool: what Hydra itself refuses (it would print several lines and exit 1)
    ("train", ["trainer.totl_timesteps=5"], "trainer.totl_timesteps", True),
    ("train", ["+task.target_mm=5"], "unknown option task.target_mm", True),  # `+` adds past the schema
    ("eval", ["task.delta=1"], "task.delta", True),  # the task group is typed for every tool
    ("eval", ["seed=[1"], "seed=[1", True),
    ("bench", ["hydra/launcher=nope"], "nope", True),
    ("bench", ["physics_settings=[accurate,quick]"], "quick", True),
    # cathsim-forcecheck (more cases: test_forcecheck.py)
    ("forcecheck", ["mean_n=1", "std_n=1"], "trajectories=", True),
    ("forcecheck", ["trajectories={tmp}/a_file.npz", "mean_n=abc", "std_n=1"], "mean_n='abc'", True),
]


@pytest.fixture(scope="module")
def internal_run(tmp_path_factory):
    """A run folder as cathsim-train leaves it: an (untrained) SAC agent on obs=internal."""
    from stable_baselines3 import SAC

    from cathsim_dmc.gym import CathSimEnv
    from cathsim_dmc.rl.checkpoints import FINAL_MODEL, write_policy_file

    run = tmp_path_factory.mktemp("internal_run")
    env = CathSimEnv("bca", "type1", obs="internal", max_steps=5)
    SAC("MultiInputPolicy", env, buffer_size=10, learning_starts=0, device="cpu").save(run / FINAL_MODEL)
    env.close()
    write_policy_file(run, "internal", "bca", "type1")
    return run


@pytest.mark.parametrize("tool, args, expected, before_work", CLI_CASES,
                         ids=[f"{c[0]} {' '.join(c[1])}" for c in CLI_CASES])
def test_command_line(tool, args, expected, before_work, tmp_path, request):
    run = request.getfixturevalue("internal_run") if any("{run}" in a for a in args) else None
    _write(tmp_path / "a_file.npz", "an existing file, not a dataset folder")
    _write(tmp_path / "data" / "manifest.json", '{"format": "cathsim-collect", "episodes": ')
    args = [a.format(tmp=tmp_path, run=run) for a in args]
    if tool == "train" and not any(a.startswith("trainer.total_timesteps=") for a in args):
        args.append("trainer.total_timesteps=10")
    out = tmp_path / "out"
    result = _tool(tool, [*args, f"hydra.run.dir={out}"], tmp_path)
    assert result.returncode == 2, result.stderr[-3000:]
    # Libraries print warnings (torch, gymnasium); the tool's own answer is the rest.
    lines = [line for line in result.stderr.strip().splitlines() if line.strip() and "Warning" not in line]
    assert len(lines) == 1 and expected in lines[0] and "Traceback" not in result.stderr, result.stderr[-3000:]
    assert lines[0].startswith("error: ")
    if before_work and out.is_dir():
        left = {p.name for p in out.iterdir() if not p.name.endswith(".log")}
        assert left <= HYDRA_FILES, f"{sorted(left)} written before the error"


def _corrupt_manifest_collect(tmp_path):
    from cathsim_dmc.supervised.collect import collect

    _write(tmp_path / "data" / "manifest.json", "{not json")
    collect(tmp_path / "data", "bca", "type1", "forward", episodes=1, episodes_per_shard=1, seed=0)


def _corrupt_manifest_read(tmp_path):
    from cathsim_dmc.supervised.data import expand_paths

    _write(tmp_path / "data" / "manifest.json", "{not json")
    expand_paths(tmp_path / "data")


def _load(**kwargs):
    from cathsim_dmc import tasks

    return lambda tmp_path: tasks.load("bca", "type1", **kwargs)


def _load_random(**kwargs):
    from cathsim_dmc import tasks

    return lambda tmp_path: tasks.load("bca", "random", **kwargs)


def _gym_env(**kwargs):
    from cathsim_dmc.gym import CathSimEnv

    return lambda tmp_path: CathSimEnv(**kwargs)


def _step_before_reset(tmp_path):
    from cathsim_dmc.gym import CathSimEnv

    env = CathSimEnv("bca", "type1", max_steps=2)
    try:
        env.step(np.zeros(2, np.float32))
    finally:
        env.close()


def _step_after_the_end(tmp_path):
    from cathsim_dmc.gym import CathSimEnv

    env = CathSimEnv("bca", "type1", max_steps=1)
    try:
        env.reset(seed=0)
        _, _, terminated, truncated, _ = env.step(np.zeros(2, np.float32))
        assert truncated or terminated
        env.step(np.zeros(2, np.float32))
    finally:
        env.close()


def _evaluate_zero_episodes(tmp_path):
    from cathsim_dmc.evaluation import evaluate_policy
    from cathsim_dmc.gym import CathSimEnv
    from cathsim_dmc.policies import ForwardPolicy

    env = CathSimEnv("bca", "type1", max_steps=2)
    try:
        evaluate_policy(env, ForwardPolicy(), "forward", 0, 0, tmp_path / "eval", video=False)
    finally:
        env.close()
    assert not (tmp_path / "eval" / "trajectories.npz").exists()


def _train(algo=None, trainer=None):
    def run(tmp_path):
        from cathsim_dmc.rl.train import check_training

        check_training({"learning_rate": 3e-4, "batch_size": 16, "buffer_size": 100, "learning_starts": 0,
                        "gamma": 0.99, **(algo or {})},
                       {"total_timesteps": 10, "n_envs": 1, "checkpoint_every": 0, "eval_every": 0,
                        "eval_episodes": 1, "device": "cpu", **(trainer or {})})

    return run


# (id, call with the test's tmp_path, exception type, text the message must contain)
API_CASES = [
    ("tasks.load(image_size=0)", _load(image_size=0), ValueError, "image_size=0"),
    ("tasks.load(image_size=300, renderer='gl')", _load(obs="pixels", image_size=300, renderer="gl"), ValueError,
     "image_size=300 is too large for the gl renderer and the camera style"),
    ("tasks.load(obs='enn', image_size=200, renderer='gl')", _load(obs="enn", image_size=200, renderer="gl"),
     ValueError, "choose 1 to 120"),
    ("tasks.load(obs='pixels', image_size=300)", _load(obs="pixels", image_size=300), ValueError,
     "image_size=300 is too large for the raster renderer and the camera style"),
    ("CathSimEnv(render_size=960)", _gym_env(render_mode="rgb_array", render_size=960), ValueError,
     "render_size=960"),
    ("tasks.load(delta_m=-1)", _load(delta_m=-1), ValueError, "delta_m=-1"),
    ("tasks.load(max_steps=0)", _load(max_steps=0), ValueError, "max_steps=0"),
    ("tasks.load(success_reward=nan)", _load(success_reward=float("nan")), ValueError, "success_reward=nan"),
    ("tasks.load(aim_weight=2)", _load(aim_weight=2.0), ValueError, "aim_weight was removed on 2026-11-27"),
    ("tasks.load(insertion_limit_margin_m=0)", _load(insertion_limit_margin_m=0.0), ValueError,
     "insertion_limit_margin_m was removed on 2026-11-27"),
    ("tasks.load(aorta='random', aim_weight=2)", _load_random(aim_weight=2.0), ValueError,
     "aim_weight was removed"),
    ("tasks.load(physics='quick')", _load(physics="quick"), ValueError, "choose one of ['accurate', 'fast', 'fast_field']"),
    ("negative Young's modulus", _load(guidewire={"youngs_modulus_pa": -40e9}), ValueError, "youngs_modulus_pa"),
    ("negative tip modulus", _load(guidewire={"tip_youngs_modulus_pa": -1.0}), ValueError, "tip_youngs_modulus_pa"),
    ("step before reset", _step_before_reset, RuntimeError, "reset()"),
    ("step after the end", _step_after_the_end, RuntimeError, "reset()"),
    ("corrupt manifest (collect)", _corrupt_manifest_collect, ValueError, "manifest.json"),
    ("corrupt manifest (readers)", _corrupt_manifest_read, ValueError, "manifest.json"),
    ("evaluate_policy(episodes=0)", _evaluate_zero_episodes, ValueError, "episodes=0"),
    ("total_timesteps=0", _train(trainer={"total_timesteps": 0}), ValueError, "trainer.total_timesteps=0"),
    ("batch_size=0", _train(algo={"batch_size": 0}), ValueError, "algo.batch_size=0"),
    ("learning_rate='abc'", _train(algo={"learning_rate": "abc"}), ValueError, "algo.learning_rate='abc'"),
    ("eval_episodes=0", _train(trainer={"eval_episodes": 0}), ValueError, "trainer.eval_episodes=0"),
]


@pytest.mark.parametrize("call, error, expected", [c[1:] for c in API_CASES], ids=[c[0] for c in API_CASES])
def test_api(call, error, expected, tmp_path):
    with pytest.raises(error) as raised:
        call(tmp_path)
    assert expected in str(raised.value)
    assert "\n" not in str(raised.value)
