"""cathsim-train's typed config (cathsim_dmc/app/train_schema.py): unknown keys, wrong types and
out-of-range values fail in one line before any work; every default is defined once; run
folders written before an option was removed or moved still resume, or say why not."""

import dataclasses
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from omegaconf import OmegaConf

from cathsim_dmc.app import tool_schemas as config_tools
from cathsim_dmc.app import train_schema as config
from cathsim_dmc.core.shipped import conf_root

CATHSIM_TRAIN = str(Path(sys.executable).parent / "cathsim-train")  # the installed console script


def _train(args, cwd):
    return subprocess.run([CATHSIM_TRAIN, *args], cwd=cwd, capture_output=True, text=True, timeout=300)


def _one_line(result) -> str:
    lines = [line for line in result.stderr.splitlines() if line.strip() and "Warning" not in line]
    assert result.returncode == 2 and len(lines) == 1 and "Traceback" not in result.stderr, result.stderr[-2000:]
    assert lines[0].startswith("error: ")
    return lines[0]


@pytest.mark.parametrize(
    "args, expected",
    [
        (["trainer.total_timestep=5"], "unknown option trainer.total_timestep"),
        (["algo.lerning_rate=1"], "unknown option algo.lerning_rate"),
        (["demos.bc_filter=q"], "unknown option demos.bc_filter"),  # removed
        (["trainer.total_timesteps=abc"], "trainer.total_timesteps='abc'"),
        (["trainer.total_timesteps=5.5"], "trainer.total_timesteps=5.5"),
        (
            ["algo.buffer_size=1e12"],
            "algo.buffer_size=1e+12 is written as a decimal number; an integer is needed: write 1000000000000",
        ),
    ],
)
def test_a_misspelled_key_or_a_wrong_type_fails_at_composition_in_one_line(args, expected, tmp_path):
    run = tmp_path / "run"
    line = _one_line(_train([*args, f"hydra.run.dir={run}"], tmp_path))
    assert expected in line
    assert not run.exists()  # refused before Hydra made the run folder


@pytest.mark.parametrize(
    "args, expected",
    [
        (["trainer.total_timesteps=0"], "trainer.total_timesteps=0 must be a whole number >= 1"),
        (["algo.learning_rate=0"], "algo.learning_rate=0.0 must be a finite number > 0"),
        (["demos.share=1.5"], "demos.share=1.5 must lie in [0, 1]"),
        (["algo.net_arch=[256,0]"], "algo.net_arch=0"),
        (["trainer.device=tpu"], "trainer.device='tpu'; choose one of ['auto', 'cpu', 'cuda']"),
    ],
)
def test_a_value_out_of_range_fails_in_one_line_before_any_run_folder_exists(args, expected, tmp_path):
    run = tmp_path / "run"
    assert expected in _one_line(_train([*args, f"hydra.run.dir={run}"], tmp_path))
    assert not run.exists()


def _compose(name="train", overrides=()):
    from hydra import compose, initialize_config_dir

    with initialize_config_dir(config_dir=str(conf_root()), version_base="1.3"):
        return OmegaConf.to_container(compose(name, overrides=list(overrides)), resolve=True)


def _yaml(group, option) -> dict:
    return yaml.safe_load((conf_root() / group / f"{option}.yaml").read_text()) or {}


def _schema_defaults(schema) -> dict:
    return OmegaConf.to_container(OmegaConf.structured(schema))


def _effective(group, option) -> dict:
    """What a group option composes to, read from the schema and the YAML files alone."""
    body = _yaml(group, option)
    values = {}
    for parent in body.pop("defaults", []):
        if parent == config_tools.SCHEMA:
            values.update(_schema_defaults(config_tools.GROUP_SCHEMAS[group]))
        elif parent != "_self_":
            values.update(_effective(group, parent))
    return {**values, **body}


GROUP_OPTIONS = [
    (group, path.stem) for group in config_tools.GROUP_SCHEMAS for path in sorted((conf_root() / group).glob("*.yaml"))
]


@pytest.mark.parametrize("group, option", GROUP_OPTIONS, ids=[f"{g}/{o}" for g, o in GROUP_OPTIONS])
def test_each_option_file_sets_only_what_differs_from_what_it_extends(group, option):
    body = _yaml(group, option)
    parents = [p for p in body.pop("defaults", []) if p != "_self_"]
    assert parents and parents[0] in (config_tools.SCHEMA, *[o for g, o in GROUP_OPTIONS if g == group])
    inherited = (
        _schema_defaults(config_tools.GROUP_SCHEMAS[group])
        if parents[0] == config_tools.SCHEMA
        else _effective(group, parents[0])
    )
    restated = {key: value for key, value in body.items() if inherited.get(key) == value and key != "name"}
    assert not restated, f"{group}/{option}.yaml restates defaults it inherits: {restated}"
    assert set(body) <= set(inherited), "a key the schema does not know"


def test_the_lcca_budget_sets_only_what_differs_from_the_expert_demonstrations():
    lcca = _yaml("demos_for_task", "expert_lcca")
    expert = _effective("demos", "expert")
    assert lcca and all(expert[key] != value for key, value in lcca.items())


def test_the_default_train_config_is_the_schema_plus_what_the_option_files_set():
    composed = _compose()
    schema = _schema_defaults(config.TrainConfig)
    # train.yaml sets no run option of its own: seed, resume, trainer and experimental are the schema's.
    assert set(_yaml(".", "train")) <= {"defaults", "hydra"}
    for key in ("seed", "resume", "trainer", "experimental"):
        assert composed[key] == schema[key], key
    choices = {"task": "bca", "algo": "sac_tuned", "demos": "expert"}
    for group, option in choices.items():
        assert composed[group] == _effective(group, option), group
    lcca = _compose(overrides=["task=lcca"])
    assert lcca["demos"] == {**_effective("demos", "expert"), **_yaml("demos_for_task", "expert_lcca")}
    # The recipe as docs/training.md states it.
    assert (
        composed["trainer"]["total_timesteps"],
        composed["demos"]["episodes"],
        composed["demos"]["bc_weight"],
        composed["algo"]["ent_coef"],
        composed["algo"]["actor_average_tau"],
    ) == (8000, 100, 0.5, "auto_0.05", 0.005)


def test_the_schema_module_needs_no_simulator_and_no_cli():
    code = (
        "import sys, cathsim_dmc.app.train_schema; "
        "bad = [m for m in ('dm_control', 'mujoco', 'torch', 'cathsim_dmc.app.cli') if m in sys.modules]; "
        "assert not bad, bad"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


def test_the_extra_observation_names_are_the_tasks_own():
    from cathsim_dmc.tasks.observations import check_extra_observations

    assert check_extra_observations(list(config.EXTRA_OBSERVATIONS)) == config.EXTRA_OBSERVATIONS
    with pytest.raises(ValueError, match="wire_slack"):
        check_extra_observations(["wire_slackness"])


def test_the_task_defaults_are_the_python_apis():
    # tasks.load takes its keyword defaults from TaskConfig (which needs no Hydra to read):
    # a literal default written again on either side would show here.
    import inspect

    from cathsim_dmc.tasks import Navigate

    api = {name: p.default for name, p in inspect.signature(Navigate.__init__).parameters.items()}
    schema = _schema_defaults(config.TaskConfig)
    shared = [name for name in schema if name in api and name != "target"]
    assert "delta_m" in shared and "physics" in shared
    assert {name: schema[name] for name in shared} == {name: api[name] for name in shared}


def test_the_start_pose_on_the_command_line_reaches_the_task():
    # task.start_*: the robot's rotation is drawn from start_rotation_rad +- start_rotation_jitter_rad.
    from hydra import compose, initialize_config_dir

    from cathsim_dmc import tasks
    from cathsim_dmc.app.cli._common import env_kwargs

    def start_rotations(overrides, episodes=4):
        with initialize_config_dir(config_dir=str(conf_root()), version_base="1.3"):
            cfg = compose("collect", overrides=["task=lcca", "obs=internal", *overrides])
        env = tasks.load(**env_kwargs(cfg), seed=0)
        rotations = []
        for _ in range(episodes):
            env.reset()
            rotations.append(float(env.physics.bind(env.task.robot.joints).qpos[1]))
        return rotations

    one_sided = start_rotations(["task.start_rotation_rad=3.29", "task.start_rotation_jitter_rad=0.15"])
    assert all(3.14 <= r <= 3.44 for r in one_sided) and len(set(one_sided)) == len(one_sided)
    assert start_rotations(["task.start_rotation_rad=3.3", "task.start_rotation_jitter_rad=0"]) == [3.3] * 4
    default = start_rotations([])
    assert all(abs(r - 3.141592653589793) <= 0.3 for r in default) and len(set(default)) == len(default)


def test_every_ranged_option_has_a_default_inside_its_range():
    for name, schema in config.TRAIN_SECTIONS.items():
        config.check_section(name, schema, _schema_defaults(schema))
    assert [spec.name for spec in dataclasses.fields(config.TrainerConfig) if spec.metadata]


# A run folder's config.yaml as older versions wrote it (demos=none), with every option since
# moved or removed.
OLD_RUN_CONFIG = """
task: {target: bca, delta_m: 0.004, success_reward: 10.0, dense: true, max_steps: 20, insertion_limit_margin_m: null,
       physics: fast, catheter: null}
aorta: {name: type1, label: type1}
obs: {name: internal, observables: [joint_pos, joint_vel], renderer: null, style: null, lao_deg: 0}
algo: {name: sac_tuned, learning_rate: 0.0003, buffer_size: 2000, batch_size: 16, tau: 0.005, gamma: 0.99,
       train_freq: 1, gradient_steps: 1, target_update_interval: 1, target_entropy: -2.0, ent_coef: auto_0.05,
       learning_starts: 20, net_arch: [256, 256], share_features_extractor: false, critic_layer_norm: true,
       actor_average_tau: 0.005, actor_learning_rate_scale: 1.0}
reward: {name: progress, kind: geodesic, progress_weight: 1.0, aim_weight: 0.0}
demos: {episodes: 0, share: 0.5, capacity: 20000, pretrain_actor_steps: 0, critic_warmup_steps: 0, bc_weight: 0.0,
        warm_start_steps: 0, bc_filter: q, takeover_rounds: 0, takeover_episodes: 20, takeover_max_student_steps: 200,
        path: null}
seed: 0
resume: null
trainer: {total_timesteps: 30, n_envs: 1, eval_every: 0, eval_episodes: 1, final_eval_episodes: 1,
          confirm_episodes: 0, checkpoint_every: 10, save_replay_buffer: false, device: auto, torch_threads: 1,
          progress_bar: false, video: false, normalize_observations: true, final_policy: best}
experimental: {expert_end_game: strokes}
"""


def test_an_old_run_config_has_its_moved_keys_translated_and_its_inert_removed_keys_dropped(caplog):
    old = OmegaConf.create(OLD_RUN_CONFIG)
    with caplog.at_level("WARNING", logger="cathsim_dmc.app.train_schema"):
        cfg = config.upgrade_saved_config(old)
    assert cfg.experimental.normalize_observations is True and "normalize_observations" not in cfg.trainer
    assert "bc_filter" not in cfg.demos and "aim_weight" not in cfg.reward
    config_tools.validate(cfg)
    warnings = [r.getMessage() for r in caplog.records]
    assert len(warnings) == 1
    for key in config.REMOVED:
        assert key in warnings[0]
    assert cfg.trainer.total_timesteps == 30 and cfg.algo.batch_size == 16  # the run's own settings


@pytest.mark.parametrize(
    "change, expected",
    [
        ({"demos": {"episodes": 10, "bc_weight": 0.5, "bc_filter": "q"}}, "demos.bc_filter='q'"),
        ({"trainer": {"confirm_episodes": 20}}, "trainer.confirm_episodes=20"),
        ({"algo": {"actor_learning_rate_scale": 0.3}}, "algo.actor_learning_rate_scale=0.3"),
        ({"task": {"insertion_limit_margin_m": 0.02}}, "task.insertion_limit_margin_m=0.02"),
        ({"reward": {"name": "aim", "aim_weight": 2.0}}, "reward=aim"),
        ({"experimental": {"expert_end_game": "relay"}}, "experimental.expert_end_game='relay'"),
    ],
)
def test_an_old_run_that_used_a_removed_option_says_so_in_one_line(change, expected):
    old = OmegaConf.merge(OmegaConf.create(OLD_RUN_CONFIG), change)
    with pytest.raises(ValueError) as raised:
        config.upgrade_saved_config(old)
    assert expected in str(raised.value) and "removed" in str(raised.value) and "\n" not in str(raised.value)


def test_resuming_an_old_run_that_used_a_removed_option_fails_in_one_line_before_any_work(tmp_path):
    run = tmp_path / "old_run"
    run.mkdir()
    old = OmegaConf.merge(OmegaConf.create(OLD_RUN_CONFIG), {"trainer": {"confirm_episodes": 20}})
    (run / "config.yaml").write_text(OmegaConf.to_yaml(old))
    line = _one_line(_train([f"resume={run}", f"hydra.run.dir={tmp_path / 'log'}"], tmp_path))
    assert "trainer.confirm_episodes=20" in line
    assert sorted(p.name for p in run.iterdir()) == ["config.yaml"]


def test_an_old_run_folder_resumes_with_one_warning_naming_the_dropped_options(tmp_path):
    tiny = [
        "obs=internal",
        "demos=none",
        "task.max_steps=20",
        "algo.learning_starts=20",
        "algo.batch_size=16",
        "algo.buffer_size=2000",
        "trainer.checkpoint_every=20",
        "trainer.eval_every=0",
        "trainer.eval_episodes=1",
        "trainer.final_eval_episodes=1",
        "trainer.video=false",
        "trainer.progress_bar=false",
    ]
    run = tmp_path / "run"
    first = _train([*tiny, "trainer.total_timesteps=20", f"hydra.run.dir={run}"], tmp_path)
    assert first.returncode == 0, first.stderr[-2000:]
    # Rewrite its config.yaml as the version before the schema wrote it.
    saved = OmegaConf.to_container(OmegaConf.load(run / "config.yaml"))
    old = OmegaConf.to_container(OmegaConf.create(OLD_RUN_CONFIG))
    for section in ("task", "algo", "demos", "trainer"):
        old[section] = {**saved[section], **{k: v for k, v in old[section].items() if k not in saved[section]}}
    old["trainer"]["normalize_observations"] = False
    (run / "config.yaml").write_text(OmegaConf.to_yaml(OmegaConf.create(old)))
    again = _train([f"resume={run}", "trainer.total_timesteps=30", f"hydra.run.dir={tmp_path}/resume"], tmp_path)
    assert again.returncode == 0, again.stderr[-2000:]
    warnings = [line for line in (again.stdout + again.stderr).splitlines() if "dropped options" in line]
    assert len(warnings) == 1 and "demos.bc_filter" in warnings[0] and "trainer.confirm_episodes" in warnings[0]
    assert (run / "checkpoints" / "step_30.zip").is_file() or (run / "checkpoints" / "last.zip").is_file()


def test_the_image_keys_the_schema_accepts_are_the_students():
    from cathsim_dmc.learning.supervised.bc import PRESET_FOR_IMAGE

    assert set(config_tools.IMAGE_KEYS) == set(PRESET_FOR_IMAGE)


@pytest.mark.parametrize("tool", ["eval", "collect", "bc", "force", "bench", "export"])
def test_every_tools_shipped_defaults_lie_in_its_schemas_ranges(tool):
    from cathsim_dmc.app.tool_schemas import TOOL_SCHEMAS

    cfg = OmegaConf.create(_compose(tool))
    config_tools.validate(cfg, tool)
    assert set(cfg) - {"hydra"} == {spec.name for spec in dataclasses.fields(TOOL_SCHEMAS[tool])}
