"""Bad input, as a new user types it: one table per surface, so the list can grow.

A command-line tool must answer with one line on stderr that names the bad value (and
the valid choices), exit status 2, no traceback, and must fail before any work: its run
folder holds nothing but what Hydra writes on start (.hydra/ and the log). The Python
API must raise ValueError or RuntimeError naming the parameter.
"""

import json
import subprocess
import sys

import numpy as np
import pytest

# Files Hydra itself writes into a run folder before the tool's code runs.
HYDRA_FILES = {".hydra"}


def _tool(tool: str, args, cwd):
    return subprocess.run(
        [sys.executable, "-m", f"cathsim_dmc.app.cli.{tool}", *args],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=900,
    )


def _write(path, content):
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(content)


def _has_cuda() -> bool:
    import torch

    return torch.cuda.is_available()


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
    (
        "eval",
        ["task.physics=quick"],
        "physics='quick' is not a physics setting; choose one of ['accurate', 'fast', 'fast_field']",
        True,
    ),
    ("eval", ["task.catheter=cobra"], "catheter='cobra' is not a catheter; choose one of ['angled_5f']", True),
    ("eval", ["task.start_rotation_jitter_rad=4"], "start_rotation_jitter_rad=4.0 rad is more than a half turn", True),
    ("collect", ["task.start_insertion_jitter_m=-0.001"], "start_insertion_jitter_m=-0.001 must be", True),
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
    (
        "train",
        ["obs=enn", "algo.buffer_size=1000000000", "trainer.total_timesteps=1000000000"],
        "algo.buffer_size",
        False,
    ),
    # cathsim-collect
    ("collect", ["policy=/no/such/agent"], "checkpoint", True),
    ("collect", ["task=xyz"], "bca", True),
    ("collect", ["episodes=0"], "episodes", True),
    ("collect", ["seed=abc"], "seed='abc'", True),
    ("collect", ["out={tmp}/a_file.npz"], "a_file.npz", True),
    ("collect", ["out={tmp}/data"], "manifest.json", True),  # {tmp}/data/manifest.json is corrupt
    # an output folder that cannot be made: a file stands where its parent would be
    ("collect", ["out={tmp}/a_file.npz/data"], "out='{tmp}/a_file.npz/data' cannot be made", True),
    # a run folder without the run's checkpoint: another .zip in it is not the agent
    ("eval", ["policy={tmp}/no_final"], "holds none of checkpoints/best.zip, final_model.zip", True),
    ("collect", ["policy={tmp}/no_final"], "holds none of checkpoints/best.zip, final_model.zip", True),
    # an agent trained on the wire alone: a catheter's joints would not fit its observations
    ("eval", ["policy={run}", "task.catheter=angled_5f"], "was trained without a catheter", True),
    ("collect", ["policy={run}", "task.catheter=angled_5f"], "was trained without a catheter", True),
    # any tool: what Hydra itself refuses (it would print several lines and exit 1)
    ("train", ["trainer.totl_timesteps=5"], "trainer.totl_timesteps", True),
    ("train", ["+task.target_mm=5"], "unknown option task.target_mm", True),  # `+` adds past the schema
    ("eval", ["task.delta=1"], "task.delta", True),  # the task group is typed for every tool
    ("eval", ["seed=[1"], "seed=[1", True),
    ("bench", ["hydra/launcher=nope"], "nope", True),
    ("bench", ["physics_settings=[accurate,quick]"], "quick", True),
    # every tool's values are typed and ranged before any work (cathsim_dmc/app/tool_schemas.py)
    ("eval", ["video=maybe"], "video='maybe'", True),
    ("eval", ["save_observations=maybe"], "save_observations='maybe'", True),
    ("eval", ["video_format=mov"], "video_format='mov'; choose one of ['gif', 'mp4']", True),
    ("eval", ["task.delta_m=5"], "delta_m=5", True),  # every episode would succeed at step 1
    ("eval", ["aorta=random", "aorta.params.order=bogus", "aorta.params.pool_size=500"], "order='bogus'", True),
    ("collect", ["episodes=-4"], "episodes=-4", True),
    ("collect", ["action_noise_std=-1"], "action_noise_std=-1", True),
    ("bc", ["data={tmp}/data", "bc.val_fraction=1.5"], "bc.val_fraction=1.5 must lie in [0, 1)", True),
    ("bc", ["data={tmp}/data", "bc.image_key=depth"], "bc.image_key='depth'", True),
    ("bc", ["data={tmp}/data", "bc.epochs=0"], "bc.epochs=0", True),
    ("force", ["data={tmp}/data", "force.sizes=[1000,0]"], "force.sizes=0", True),
    ("force", ["data={tmp}/data", "force.test_fraction=1"], "force.test_fraction=1", True),
    ("force", ["data={tmp}/data", "label=peak"], "label='peak'", True),
    ("bench", ["steps=0"], "steps=0", True),  # used to flood warnings
    ("bench", ["repeats=-1"], "repeats=-1", True),
    ("export", ["out={tmp}/a_file.npz"], "a_file.npz' is a file", True),  # used to raise NotADirectoryError
    ("export", ["seed=abc"], "seed='abc'", True),
    ("train", ["algo.buffer_size=1e12"], "write 1000000000000", True),
    ("train", ["demos.path={tmp}/no_such_data"], "no_such_data' does not exist", True),
    pytest.param(
        "train",
        ["trainer.device=cuda"],
        "no CUDA GPU",
        True,
        marks=pytest.mark.skipif(_has_cuda(), reason="this machine has a CUDA GPU"),
    ),
    *[
        (tool, ["task.dense=maybe", *extra], "task.dense='maybe'", True)  # the task group, typed for every tool
        for tool, extra in (
            ("eval", []),
            ("collect", []),
            ("train", []),
            ("bc", ["data={tmp}/data"]),
            ("force", ["data={tmp}/data"]),
            ("bench", []),
            ("export", []),
        )
    ],
    # a generated arch's sizes are guarded: 5 m used to build for 30-90 s before failing
    ("eval", ["aorta=custom", "+aorta.params.arch_width_m=5"], "arch_width_m=5.0 m is larger", True),
    ("eval", ["aorta=custom", "+aorta.params.sdf_spacing_m=0.00001"], "sdf_spacing_m=1e-05", True),
    # cathsim-forcecheck (more cases: test_forcecheck.py)
    ("forcecheck", ["mean_n=1", "std_n=1"], "trajectories=", True),
    ("forcecheck", ["trajectories={tmp}/a_file.npz", "mean_n=abc", "std_n=1"], "mean_n='abc'", True),
    ("forcecheck", ["trajectories=[{tmp}/forces.csv]", "mean_n=1", "std_n=1"], "is not a trajectory file", True),
]


def _case_id(case) -> str:
    values = case.values if hasattr(case, "values") else case
    return f"{values[0]} {' '.join(values[1])}"


@pytest.fixture(scope="module")
def internal_run(tmp_path_factory):
    """A run folder as cathsim-train leaves it: an (untrained) SAC agent on obs=internal."""
    from stable_baselines3 import SAC

    from cathsim_dmc.learning.rl.checkpoints import FINAL_MODEL, write_policy_file
    from cathsim_dmc.suite.gym import CathSimEnv

    run = tmp_path_factory.mktemp("internal_run")
    env = CathSimEnv("bca", "type1", obs="internal", max_steps=5)
    SAC("MultiInputPolicy", env, buffer_size=10, learning_starts=0, device="cpu").save(run / FINAL_MODEL)
    env.close()
    write_policy_file(run, "internal", "bca", "type1")
    return run


@pytest.mark.parametrize("tool, args, expected, before_work", CLI_CASES, ids=[_case_id(c) for c in CLI_CASES])
def test_command_line(tool, args, expected, before_work, tmp_path, request):
    run = request.getfixturevalue("internal_run") if any("{run}" in a for a in args) else None
    _write(tmp_path / "a_file.npz", "an existing file, not a dataset folder")
    _write(tmp_path / "data" / "manifest.json", '{"format": "cathsim-collect", "episodes": ')
    _write(tmp_path / "forces.csv", "step,force_n\n0,0.1\n1,0.2\n")
    _write(tmp_path / "no_final" / "checkpoints" / "step_20.zip", "a periodic checkpoint, not the run's agent")
    _write(tmp_path / "no_final" / "policy.json", '{"algo": "sac", "obs": "internal", "task": "bca", "aorta": "type1"}')
    args = [a.format(tmp=tmp_path, run=run) for a in args]
    expected = expected.format(tmp=tmp_path)
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


@pytest.mark.parametrize(
    "tool, arg",
    [("eval", "obs=nope"), ("train", "aorta=nope"), ("collect", "policy=nope"), ("train", "algo.batch_size=0")],
)
def test_a_refused_command_line_loads_no_simulator_or_network(tool, arg, tmp_path):
    # The choices and ranges are checked from conf/ alone, so a typo costs about a second,
    # not the import of MuJoCo, SciPy and torch.
    code = (
        f"import sys\nsys.argv = ['cathsim-{tool}', {arg!r}]\nfrom cathsim_dmc.app.cli.{tool} import main\n"
        "try:\n    main()\nexcept SystemExit as exit:\n    print(exit.code)\n"
        "print(sorted(m for m in ('mujoco', 'dm_control', 'scipy', 'torch') if m in sys.modules))"
    )
    result = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert result.stdout.split("\n")[:2] == ["2", "[]"], (result.stdout, result.stderr[-2000:])


@pytest.mark.parametrize(
    "tool, arg, expected",
    [
        ("eval", "task.max_steps=0", "max_steps=0"),
        ("train", "task.delta_m=5", "delta_m=5"),
        ("collect", "task.catheter=cobra", "catheter='cobra'"),
    ],
)
def test_a_bad_task_value_is_refused_before_hydra_makes_the_run_folder(tool, arg, expected, tmp_path):
    out = tmp_path / "out"
    result = _tool(tool, [arg, f"hydra.run.dir={out}"], tmp_path)
    assert result.returncode == 2 and expected in result.stderr, result.stderr[-2000:]
    assert not out.exists()


def test_the_obs_choices_on_the_command_line_are_the_python_apis_presets():
    from cathsim_dmc.core.registry import config_choices
    from cathsim_dmc.tasks.presets import OBSERVATION_PRESETS

    assert config_choices("obs") == sorted(OBSERVATION_PRESETS)


def _corrupt_manifest_collect(tmp_path):
    from cathsim_dmc.agents.collect import collect

    _write(tmp_path / "data" / "manifest.json", "{not json")
    collect(tmp_path / "data", "bca", "type1", "forward", episodes=1, episodes_per_shard=1, seed=0)


def _corrupt_manifest_read(tmp_path):
    from cathsim_dmc.learning.datasets import expand_paths

    _write(tmp_path / "data" / "manifest.json", "{not json")
    expand_paths(tmp_path / "data")


def _load(**kwargs):
    from cathsim_dmc import tasks

    return lambda tmp_path: tasks.load("bca", "type1", **kwargs)


def _load_random(**kwargs):
    from cathsim_dmc import tasks

    return lambda tmp_path: tasks.load("bca", "random", **kwargs)


def _gym_env(**kwargs):
    from cathsim_dmc.suite.gym import CathSimEnv

    return lambda tmp_path: CathSimEnv(**kwargs)


def _step_before_reset(tmp_path):
    from cathsim_dmc.suite.gym import CathSimEnv

    env = CathSimEnv("bca", "type1", max_steps=2)
    try:
        env.step(np.zeros(2, np.float32))
    finally:
        env.close()


def _step_after_the_end(tmp_path):
    from cathsim_dmc.suite.gym import CathSimEnv

    env = CathSimEnv("bca", "type1", max_steps=1)
    try:
        env.reset(seed=0)
        _, _, terminated, truncated, _ = env.step(np.zeros(2, np.float32))
        assert truncated or terminated
        env.step(np.zeros(2, np.float32))
    finally:
        env.close()


def _evaluate_zero_episodes(tmp_path):
    from cathsim_dmc.control.policies import ForwardPolicy
    from cathsim_dmc.evaluation.rollouts import evaluate_policy
    from cathsim_dmc.suite.gym import CathSimEnv

    env = CathSimEnv("bca", "type1", max_steps=2)
    try:
        evaluate_policy(env, ForwardPolicy(), "forward", 0, 0, tmp_path / "eval", video=False)
    finally:
        env.close()
    assert not (tmp_path / "eval" / "trajectories.npz").exists()


def _train(algo=None, trainer=None):
    def run(tmp_path):
        from cathsim_dmc.learning.rl.train import check_training

        check_training(
            {
                "learning_rate": 3e-4,
                "batch_size": 16,
                "buffer_size": 100,
                "learning_starts": 0,
                "gamma": 0.99,
                **(algo or {}),
            },
            {
                "total_timesteps": 10,
                "n_envs": 1,
                "checkpoint_every": 0,
                "eval_every": 0,
                "eval_episodes": 1,
                "device": "cpu",
                **(trainer or {}),
            },
        )

    return run


def _entity(factory_name, **kwargs):
    def build(tmp_path):
        from cathsim_dmc import entities

        factory = getattr(entities, factory_name)
        return factory("type1", **kwargs) if factory_name == "Aorta" else factory(**kwargs)

    return build


def _gym_make(**kwargs):
    def make(tmp_path):
        import gymnasium

        import cathsim_dmc.suite.gym  # noqa: F401  (registers the ids)

        gymnasium.make("cathsim_dmc/bca-type1-v0", **kwargs)

    return make


def _site_outside_the_lumen(tmp_path):
    import json
    import shutil

    from cathsim_dmc import tasks
    from cathsim_dmc.core.shipped import resolve_asset

    folder = tmp_path / "far_site"
    shutil.copytree(resolve_asset("type1"), folder)
    meta = json.loads((folder / "meta.json").read_text())
    meta["sites"]["bca"] = [5.0, 0.07, 0.0]  # 5 m away, as in the reported asset
    (folder / "meta.json").write_text(json.dumps(meta))
    tasks.load("bca", str(folder))


def _random_pool_order(tmp_path):
    from cathsim_dmc import tasks

    # 500 generated arches would take hours: the order must be refused before the pool
    tasks.load("bca", "random", aorta_params={"order": "bogus", "pool_size": 500})


def _csv_trajectory(reader):
    def read(tmp_path):
        from cathsim_dmc.evaluation.trajectory import load_trajectories
        from cathsim_dmc.learning.datasets import read_keys

        _write(tmp_path / "forces.csv", "step,force_n\n0,0.1\n")
        if reader == "load_trajectories":
            load_trajectories(tmp_path / "forces.csv")
        else:
            read_keys(tmp_path / "forces.csv", ["action"])

    return read


# (id, call with the test's tmp_path, exception type, text the message must contain)
API_CASES = [
    (
        "Guidewire(tip_angle_deg=nan)",
        _entity("Guidewire", tip_angle_deg=float("nan")),
        ValueError,
        "Guidewire tip_angle_deg=nan must be a finite number",
    ),
    ("Guidewire(friction=-1)", _entity("Guidewire", friction=-1.0), ValueError, "Guidewire friction=-1.0"),
    ("Guidewire(n_segments=nan)", _entity("Guidewire", n_segments=float("nan")), ValueError, "n_segments=nan"),
    (
        "FollowerRobot(max_insertion_speed_m_s=nan)",
        _entity("FollowerRobot", max_insertion_speed_m_s=float("nan")),
        ValueError,
        "FollowerRobot max_insertion_speed_m_s=nan",
    ),
    (
        "FollowerRobot(max_insertion_force_n=inf)",
        _entity("FollowerRobot", max_insertion_force_n=float("inf")),
        ValueError,
        "FollowerRobot max_insertion_force_n=inf",
    ),
    ("Aorta(friction=nan)", _entity("Aorta", friction=float("nan")), ValueError, "Aorta friction=nan"),
    (
        "Aorta(contact_margin_m=inf)",
        _entity("Aorta", contact_margin_m=float("inf")),
        ValueError,
        "Aorta contact_margin_m=inf",
    ),
    (
        "tasks.load(guidewire={tip_angle_deg: nan})",
        _load(guidewire={"tip_angle_deg": float("nan")}),
        ValueError,
        "tip_angle_deg=nan",
    ),
    ("tasks.load(blood_drag=-1)", _load(blood_drag=-1), ValueError, "blood_drag=-1"),
    ("tasks.load(blood_drag='yes')", _load(blood_drag="yes"), ValueError, "blood_drag='yes'"),
    ("tasks.load(delta_m=5)", _load(delta_m=5), ValueError, "delta_m=5 m is larger than any meaningful success radius"),
    ("tasks.load(bogus=1)", _load(bogus=1), ValueError, "tasks.load: unknown keyword argument 'bogus'; valid: "),
    (
        "tasks.load(guidewire={bogus: 1})",
        _load(guidewire={"bogus": 1}),
        ValueError,
        "guidewire: unknown keyword argument 'bogus'; valid: contact_solimp",
    ),
    (
        "tasks.load(robot={speed: 1})",
        _load(robot={"speed": 1}),
        ValueError,
        "robot: unknown keyword argument 'speed'; valid: channel_clearance_m",
    ),
    ("gymnasium.make(bogus=1)", _gym_make(bogus=1), ValueError, "unknown keyword argument 'bogus'"),
    ("a target site outside the lumen", _site_outside_the_lumen, ValueError, "cathsim-aorta validate"),
    ("aorta order='bogus'", _random_pool_order, ValueError, "order='bogus'; choose one of"),
    ("a CSV as a trajectory file", _csv_trajectory("load_trajectories"), ValueError, "is not a trajectory file"),
    ("a CSV as a dataset file", _csv_trajectory("read_keys"), ValueError, "not an .npz archive"),
    ("tasks.load(image_size=0)", _load(image_size=0), ValueError, "image_size=0"),
    (
        "tasks.load(image_size=300, renderer='gl')",
        _load(obs="pixels", image_size=300, renderer="gl"),
        ValueError,
        "image_size=300 is too large for the gl renderer and the camera style",
    ),
    (
        "tasks.load(obs='enn', image_size=200, renderer='gl')",
        _load(obs="enn", image_size=200, renderer="gl"),
        ValueError,
        "choose 1 to 120",
    ),
    (
        "tasks.load(obs='pixels', image_size=300)",
        _load(obs="pixels", image_size=300),
        ValueError,
        "image_size=300 is too large for the raster renderer and the camera style",
    ),
    ("CathSimEnv(render_size=960)", _gym_env(render_mode="rgb_array", render_size=960), ValueError, "render_size=960"),
    ("tasks.load(delta_m=-1)", _load(delta_m=-1), ValueError, "delta_m=-1"),
    ("tasks.load(max_steps=0)", _load(max_steps=0), ValueError, "max_steps=0"),
    ("tasks.load(success_reward=nan)", _load(success_reward=float("nan")), ValueError, "success_reward=nan"),
    # a removed argument is an unknown one
    (
        "tasks.load(aim_weight=2)",
        _load(aim_weight=2.0),
        ValueError,
        "tasks.load: unknown keyword argument 'aim_weight'",
    ),
    (
        "tasks.load(aorta='random', aim_weight=2)",
        _load_random(aim_weight=2.0),
        ValueError,
        "tasks.load: unknown keyword argument 'aim_weight'; valid: ",
    ),
    (
        "tasks.load(physics='quick')",
        _load(physics="quick"),
        ValueError,
        "choose one of ['accurate', 'fast', 'fast_field']",
    ),
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


def test_continuing_a_dataset_records_a_truncated_shard_again(tmp_path):
    # A collection killed while writing a shard used to make the next run fail with BadZipFile.
    from cathsim_dmc.agents.collect import SHARD_FORMAT, collect

    settings = dict(
        task="bca",
        aorta="type1",
        policy="forward",
        episodes_per_shard=1,
        seed=0,
        task_options={"max_steps": 3},
        show_progress=False,
    )
    collect(tmp_path, episodes=2, **settings)
    shard = tmp_path / SHARD_FORMAT.format(1)
    whole = shard.read_bytes()
    shard.write_bytes(whole[: len(whole) // 2])
    manifest = collect(tmp_path, episodes=2, **settings)
    assert manifest["episodes"] == 2 and shard.read_bytes() == whole  # the same episode, recorded again


def test_a_training_size_beyond_the_data_is_labelled_with_the_samples_it_has():
    # force.sizes=[1000000] on a small dataset used to show "1,000,000 samples" while training on all there is.
    from cathsim_dmc.learning.supervised.force import ForceConfig, markdown, train_force_sizes

    rng = np.random.default_rng(0)
    episodes = np.repeat(np.arange(6), 4)
    images = rng.integers(0, 255, (len(episodes), 1, 80, 80), dtype=np.uint8)
    labels = []
    report = train_force_sizes(
        images,
        rng.random(len(episodes)),
        episodes,
        ForceConfig(sizes=(1_000_000,), epochs=1, min_updates=1, test_fraction=0.34),
        progress=lambda size, epoch, epochs, best: labels.append(size),
    )
    trained = report["sizes"][0]["train_samples"]
    assert trained < 1_000_000 and set(labels) == {trained}
    assert f"{trained:,} (all there is; 1,000,000 asked)" in markdown(report)


def test_a_generated_arch_too_large_is_refused_before_any_build(tmp_path):
    result = subprocess.run(
        [sys.executable, "-m", "cathsim_dmc.app.cli.aorta", "build", "arch_width_m=5", f"out={tmp_path / 'arch'}"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=300,
    )
    lines = [line for line in result.stderr.strip().splitlines() if line.strip()]
    assert result.returncode == 2 and len(lines) == 1 and "arch_width_m=5.0 m is larger" in lines[0], result.stderr
    assert not any(tmp_path.iterdir()), "nothing may be written before the error"


# -- the front door: what a tool takes from a trained run, and the folders it writes ---------


def _one_line(result) -> str:
    lines = [line for line in result.stderr.strip().splitlines() if line.strip() and "Warning" not in line]
    assert result.returncode == 2 and len(lines) == 1, result.stderr[-3000:]
    assert lines[0].startswith("error: ") and "Traceback" not in result.stderr
    return lines[0]


@pytest.fixture(scope="module")
def lcca_run(tmp_path_factory):
    """A run folder of an (untrained) agent for the LCCA of the type II arch, obs=internal."""
    from stable_baselines3 import SAC

    from cathsim_dmc.learning.rl.checkpoints import FINAL_MODEL, write_policy_file
    from cathsim_dmc.suite.gym import CathSimEnv

    run = tmp_path_factory.mktemp("lcca_run")
    env = CathSimEnv("lcca", "type2", obs="internal", max_steps=5)
    SAC("MultiInputPolicy", env, buffer_size=10, learning_starts=0, device="cpu").save(run / FINAL_MODEL)
    env.close()
    write_policy_file(run, "internal", "lcca", "type2")
    return run


TINY_EVAL = ["episodes=1", "task.max_steps=3", "video=false"]


def test_a_run_is_evaluated_on_the_task_and_aorta_it_was_trained_for(lcca_run, tmp_path):
    # It used to be scored on the default task (the BCA of type I) without a word.
    result = _tool("eval", [f"policy={lcca_run}", *TINY_EVAL, f"hydra.run.dir={tmp_path}/own"], tmp_path)
    assert result.returncode == 0, result.stderr[-3000:]
    assert "evaluating on task=lcca aorta=type2 from the run's policy.json" in result.stdout
    report = json.loads((tmp_path / "own" / "metrics.json").read_text())
    assert (report["task"], report["aorta"]) == ("lcca", "type2")
    # A task given on the command line wins (a transfer test); the aorta still comes from the run.
    result = _tool("eval", [f"policy={lcca_run}", "task=bca", *TINY_EVAL, f"hydra.run.dir={tmp_path}/bca"], tmp_path)
    assert result.returncode == 0, result.stderr[-3000:]
    assert "evaluating on aorta=type2 from the run's policy.json" in result.stdout
    report = json.loads((tmp_path / "bca" / "metrics.json").read_text())
    assert (report["task"], report["aorta"]) == ("bca", "type2")


def test_a_run_is_replayed_for_a_dataset_on_its_own_task_and_aorta(lcca_run, tmp_path):
    out = tmp_path / "data"
    result = _tool(
        "collect",
        [f"policy={lcca_run}", "episodes=1", "task.max_steps=3", "progress_bar=false", f"out={out}"],
        tmp_path,
    )
    assert result.returncode == 0, result.stderr[-3000:]
    assert "collecting on task=lcca aorta=type2 from the run's policy.json" in result.stdout
    manifest = json.loads((out / "manifest.json").read_text())
    assert (manifest["task"], manifest["aorta"]) == ("lcca", "type2")


def test_an_evaluation_that_cannot_write_its_folder_is_refused_before_any_work(tmp_path):
    _write(tmp_path / "a_file", "a file where a folder would go")
    result = _tool("eval", ["policy=forward", *TINY_EVAL, f"hydra.run.dir={tmp_path}/a_file/out"], tmp_path)
    assert "hydra.run.dir=" in _one_line(result) and "a_file is a file, not a folder" in result.stderr
    assert result.stdout == ""  # not one episode ran


def test_an_evaluation_into_a_finished_ones_folder_is_refused_unless_overwrite(tmp_path):
    out = tmp_path / "eval"
    first = _tool("eval", ["policy=forward", *TINY_EVAL, f"hydra.run.dir={out}"], tmp_path)
    assert first.returncode == 0, first.stderr[-3000:]
    kept = {name: (out / name).read_bytes() for name in ("metrics.json", "trajectories.npz", ".hydra/config.yaml")}
    again = _tool("eval", ["policy=expert", *TINY_EVAL, f"hydra.run.dir={out}"], tmp_path)
    line = _one_line(again)
    assert "holds the results of an evaluation (metrics.json, trajectories.npz)" in line and "overwrite=true" in line
    assert {name: (out / name).read_bytes() for name in kept} == kept  # Hydra's copy of the config too
    replaced = _tool("eval", ["policy=expert", *TINY_EVAL, "overwrite=true", f"hydra.run.dir={out}"], tmp_path)
    assert replaced.returncode == 0, replaced.stderr[-3000:]
    assert json.loads((out / "metrics.json").read_text())["policy"] == "expert"


def _aorta(args, cwd):
    return subprocess.run(
        [sys.executable, "-m", "cathsim_dmc.app.cli.aorta", *args], cwd=cwd, capture_output=True, text=True, timeout=300
    )


def test_an_import_that_cannot_write_its_folder_is_refused_before_any_work(tmp_path):
    import trimesh

    trimesh.creation.box(extents=(20.0, 20.0, 20.0)).export(tmp_path / "box.stl")  # a closed lumen, in mm
    _write(tmp_path / "a_file", "a file where a folder would go")
    args = ["import", "mesh=box.stl", "units=mm", "entry=[0,0,-5]", "sites.bca=[0,0,5]", f"out={tmp_path}/a_file/box"]
    line = _one_line(_aorta(args, tmp_path))
    assert f"out='{tmp_path}/a_file/box' cannot be made" in line
    line = _one_line(_aorta(["build", f"out={tmp_path}/a_file/arch"], tmp_path))
    assert f"out='{tmp_path}/a_file/arch' cannot be made" in line


@pytest.mark.parametrize(
    "vertices, faces, expected",
    [
        ([[0, 0, 0], [10, 0, 0], [0, 10, 0]], [[0, 1, 2]], "1 triangle with an area"),
        # a flat 2 x 2 grid: enough triangles, but no volume
        (
            [[x, y, 0] for y in (0, 10, 20) for x in (0, 10, 20)],
            [t for i in (0, 1, 3, 4) for t in ([i, i + 1, i + 4], [i, i + 4, i + 3])],
            "all its vertices lie in one plane",
        ),
    ],
    ids=["one triangle", "flat"],
)
def test_a_mesh_that_encloses_no_volume_is_no_vessel_surface(vertices, faces, expected, tmp_path):
    # It used to be reported as an entry "within 0.4 mm of the surface", after the volume repair.
    import trimesh

    trimesh.Trimesh(np.array(vertices, float), np.array(faces), process=False).export(tmp_path / "surface.stl")
    args = ["import", "mesh=surface.stl", "units=mm", "entry=[1,1,0]", "sites.bca=[2,2,0]", f"out={tmp_path}/x"]
    line = _one_line(_aorta(args, tmp_path))
    assert "surface.stl: not a closed vessel surface" in line and expected in line
    assert not (tmp_path / "x").exists()


def _saved_run(folder, overrides):
    """A cathsim-train run folder as far as resuming reads it first: its config.yaml and the
    run format of its policy.json."""
    from hydra import compose, initialize_config_dir
    from omegaconf import OmegaConf

    from cathsim_dmc.core.run_files import FORMAT_KEY, POLICY_FILE, RUN_FORMAT
    from cathsim_dmc.core.shipped import conf_root

    with initialize_config_dir(config_dir=str(conf_root()), version_base="1.3"):
        cfg = compose("train", overrides=overrides)
    _write(folder / "config.yaml", OmegaConf.to_yaml(cfg, resolve=True))
    _write(folder / POLICY_FILE, json.dumps({FORMAT_KEY: RUN_FORMAT, "algo": "sac", "obs": "internal"}))
    return folder


def test_resuming_with_a_setting_other_than_the_runs_is_refused_naming_it(tmp_path):
    run = _saved_run(tmp_path / "run", ["task=lcca", "trainer.total_timesteps=100"])
    # It used to continue the LCCA run and drop task=bca without a word.
    line = _one_line(_tool("train", [f"resume={run}", "task=bca"], tmp_path))
    assert "task=bca (the run has task.target='lcca')" in line and "trainer.total_timesteps" in line
    line = _one_line(_tool("train", [f"resume={run}", "task=lcca", "seed=3", "algo=sac"], tmp_path))
    assert "seed=3 (the run has seed=0)" in line and "algo=sac (the run has algo.name='sac_tuned')" in line
    assert "task=lcca" not in line  # the run's own value is no difference
    # Its own settings and a larger budget pass the check; this folder then has no checkpoint to resume.
    line = _one_line(_tool("train", [f"resume={run}", "task=lcca", "trainer.total_timesteps=200"], tmp_path))
    assert "nothing to resume: no last.zip" in line
