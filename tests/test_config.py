"""cathsim-train's typed config (cathsim_dmc/app/train_schema.py): unknown keys, wrong types and
out-of-range values fail in one line before any work; every default is defined once; a run
folder of another run format is refused in one line."""

import dataclasses
import json
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from omegaconf import OmegaConf

from cathsim_dmc.app import tool_schemas as config_tools
from cathsim_dmc.app import train_schema as config
from cathsim_dmc.core import run_files, task_defaults
from cathsim_dmc.core.registry import EXTRA_OBSERVATIONS
from cathsim_dmc.core.settings import check_section
from cathsim_dmc.core.shipped import conf_root
from cathsim_dmc.learning.rl.settings import TrainerConfig

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

    assert check_extra_observations(list(EXTRA_OBSERVATIONS)) == EXTRA_OBSERVATIONS
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


def test_the_task_defaults_the_schema_shows_are_the_task_constants():
    # Every constant of core/task_defaults.py, by the schema key that shows it; the Python
    # API's reward and start pose take the same ones.
    from cathsim_dmc.tasks.navigate import StartPose
    from cathsim_dmc.tasks.rewards import NavigationReward

    shown_as = {
        "SUCCESS_RADIUS_M": "delta_m",
        "SUCCESS_REWARD": "success_reward",
        "DENSE_REWARD": "dense",
        "MAX_STEPS": "max_steps",
        "PHYSICS": "physics",
        "START_ROTATION_RAD": "start_rotation_rad",
        "START_ROTATION_JITTER_RAD": "start_rotation_jitter_rad",
        "START_INSERTION_JITTER_M": "start_insertion_jitter_m",
        "SAFE_FORCE_N": "safe_force_n",
    }
    constants = {name: value for name, value in vars(task_defaults).items() if name.isupper()}
    assert set(constants) == set(shown_as)
    schema = _schema_defaults(config.TaskConfig)
    assert {shown_as[name]: value for name, value in constants.items()} == {
        key: schema[key] for key in shown_as.values()
    }
    reward, start = NavigationReward(), StartPose()
    assert (reward.success_reward, reward.dense) == (schema["success_reward"], schema["dense"])
    assert (start.rotation_rad, start.rotation_jitter_rad, start.insertion_jitter_m) == (
        schema["start_rotation_rad"],
        schema["start_rotation_jitter_rad"],
        schema["start_insertion_jitter_m"],
    )


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
        check_section(name, schema, _schema_defaults(schema))
    assert [spec.name for spec in dataclasses.fields(TrainerConfig) if spec.metadata]


def _run_folder(path, policy: dict | None):
    """A cathsim-train run folder as far as resuming reads it first: its config.yaml and
    policy.json (None: none, as a run stopped before its first checkpoint leaves it)."""
    path.mkdir()
    cfg = OmegaConf.create(_compose(overrides=["obs=internal", "demos=none"]))
    (path / config.RUN_CONFIG).write_text(OmegaConf.to_yaml(cfg))
    if policy is not None:
        (path / run_files.POLICY_FILE).write_text(json.dumps(policy))


@pytest.mark.parametrize(
    "version, expected",
    [
        (None, f"older cathsim-dmc (run format 0, this version reads {run_files.RUN_FORMAT}); train it again"),
        (run_files.RUN_FORMAT - 1, f"(run format {run_files.RUN_FORMAT - 1}, this version reads"),
        (run_files.RUN_FORMAT + 1, f"newer cathsim-dmc (run format {run_files.RUN_FORMAT + 1}, this version reads"),
    ],
)
def test_resuming_a_run_of_another_run_format_fails_in_one_line_before_any_work(version, expected, tmp_path):
    run = tmp_path / "old_run"
    policy = {"algo": "sac", "obs": "internal", "task": "bca", "aorta": "type1"}
    _run_folder(run, policy if version is None else {run_files.FORMAT_KEY: version, **policy})
    line = _one_line(_train([f"resume={run}", f"hydra.run.dir={tmp_path / 'log'}"], tmp_path))
    assert f"{run} was written by" in line and expected in line
    assert sorted(p.name for p in run.iterdir()) == sorted([config.RUN_CONFIG, run_files.POLICY_FILE])


def test_resuming_a_folder_without_policy_json_says_there_is_nothing_to_resume(tmp_path):
    run = tmp_path / "run"
    _run_folder(run, None)
    line = _one_line(_train([f"resume={run}", f"hydra.run.dir={tmp_path / 'log'}"], tmp_path))
    assert f"nothing to resume in {run}: no {run_files.POLICY_FILE}" in line


def test_the_image_keys_the_schema_accepts_are_the_students():
    from cathsim_dmc.learning.supervised.bc import PRESET_FOR_IMAGE

    assert set(config_tools.IMAGE_KEYS) == set(PRESET_FOR_IMAGE)


@pytest.mark.parametrize("tool", ["eval", "collect", "bc", "force", "bench", "export"])
def test_every_tools_shipped_defaults_lie_in_its_schemas_ranges(tool):
    from cathsim_dmc.app.tool_schemas import TOOL_SCHEMAS

    cfg = OmegaConf.create(_compose(tool))
    config_tools.validate(cfg, tool)
    assert set(cfg) - {"hydra"} == {spec.name for spec in dataclasses.fields(TOOL_SCHEMAS[tool])}


def test_every_image_preset_trains_with_the_image_recipe_and_the_others_with_the_default():
    # One shared encoder and batch 64 on images: batch 256 costs several times as much per
    # update (the cost measured in conf/algo_for_obs/sac_tuned_fluoro.yaml).
    default = _compose()["algo"]
    for option in sorted(path.stem for path in (conf_root() / "obs").glob("*.yaml")):
        algo = _compose(overrides=[f"obs={option}"])["algo"]
        images = _yaml("obs", option).get("renderer") is not None
        expected = (64, True) if images else (default["batch_size"], default["share_features_extractor"])
        assert (algo["batch_size"], algo["share_features_extractor"]) == expected, option
