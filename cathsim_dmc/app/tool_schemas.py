"""The typed schemas of the tools other than cathsim-train (conf/<tool>.yaml), beside
cathsim_dmc/app/train_schema.py's; their registration in Hydra's ConfigStore and the check of any
tool's composed config (`validate`, on cathsim_dmc.core.settings' ranges).

Here the YAML file keeps each default and the comment that explains it; the schema holds
its type and range, so its fields are MISSING until the YAML fills them in. A value of the
wrong type (`video=maybe`) then fails while composing, one out of range
(`bc.val_fraction=1.5`) in `validate` (below): both before any work.
"""

from dataclasses import dataclass, field, fields, is_dataclass
from pathlib import Path
from typing import Any, List, Optional

from cathsim_dmc.app.train_schema import MISSING, ScenarioConfig, TaskConfig, TrainConfig
from cathsim_dmc.core.settings import check_section, setting
from cathsim_dmc.learning.rl.settings import AlgoConfig, DemosConfig

VIDEO_FORMATS = ("gif", "mp4")
IMAGE_KEYS = ("pixels", "guidewire_mask")  # the image a student (bc) or force network sees
# What cathsim-force's network predicts: the total contact force averaged over the control
# step's physics steps, or the total at its last physics step (spiky: contacts chatter).
FORCE_LABELS = ("mean_contact_force_n", "contact_force_n")


def _folder():
    """An output folder's option: an existing file there is refused."""
    return field(default=MISSING, metadata={"folder": True})


def _set(minimum=None, **check):
    """A ranged option whose default is its tool's YAML file's."""
    return setting(MISSING, minimum=minimum, **check)


@dataclass
class EvalConfig(ScenarioConfig):
    """cathsim-eval (conf/eval.yaml)."""

    policy: str = MISSING
    episodes: int = _set(1, whole=True)
    seed: int = _set(0, whole=True)
    video: bool = MISSING
    video_size: int = _set(1, whole=True)  # its upper bound depends on the renderer (check_render_size)
    video_format: str = _set(choices=VIDEO_FORMATS)
    save_observations: bool = MISSING
    overwrite: bool = MISSING


@dataclass
class CollectConfig(ScenarioConfig):
    """cathsim-collect (conf/collect.yaml)."""

    policy: str = MISSING
    episodes: int = _set(1, whole=True)
    episodes_per_shard: int = _set(1, whole=True)
    seed: int = _set(0, whole=True)
    action_noise_std: float = _set(0.0)
    out: Optional[str] = _folder()
    progress_bar: bool = MISSING


@dataclass
class BCOptions:
    """cathsim-bc's `bc` section."""

    image_key: str = _set(choices=IMAGE_KEYS)
    epochs: int = _set(1, whole=True)
    batch_size: int = _set(1, whole=True)
    learning_rate: float = setting(MISSING, above=0.0)
    entropy_coef: float = _set(0.0)
    l2_coef: float = _set(0.0)
    distill_coef: float = _set(0.0)
    val_fraction: float = _set(0.0, below=1.0)  # 1 would leave no episode to train on
    frames: int = _set(1, whole=True)


@dataclass
class BCToolConfig(ScenarioConfig):
    """cathsim-bc (conf/bc.yaml)."""

    data: Any = MISSING  # a dataset folder or a list of them
    seed: int = _set(0, whole=True)
    bc: BCOptions = field(default_factory=BCOptions)
    torch_threads: int = _set(0, whole=True)
    eval_episodes: int = _set(0, whole=True)
    eval_seed: int = _set(0, whole=True)
    video: bool = MISSING
    progress_bar: bool = MISSING


@dataclass
class ForceOptions:
    """cathsim-force's `force` section."""

    sizes: List[int] = _set(1, whole=True)
    epochs: int = _set(1, whole=True)
    min_updates: int = _set(0, whole=True)
    batch_size: int = _set(1, whole=True)
    learning_rate: float = setting(MISSING, above=0.0)
    z_coef: float = _set(0.0)
    test_fraction: float = setting(MISSING, above=0.0, below=1.0)  # 0 or 1: no test or no training episode
    val_fraction: float = _set(0.0, below=1.0)
    init_from: Optional[str] = MISSING
    outlier_n: Optional[float] = setting(MISSING, above=0.0)


@dataclass
class ForceToolConfig:
    """cathsim-force (conf/force.yaml)."""

    task: TaskConfig = MISSING
    aorta: Any = MISSING
    data: Any = MISSING
    seed: int = _set(0, whole=True)
    image_key: str = _set(choices=IMAGE_KEYS)
    label: str = _set(choices=FORCE_LABELS)
    force: ForceOptions = field(default_factory=ForceOptions)
    torch_threads: int = _set(0, whole=True)
    progress_bar: bool = MISSING


@dataclass
class BenchConfig:
    """cathsim-bench (conf/bench.yaml); the names in its lists are checked by the tool."""

    task: TaskConfig = MISSING
    aortas: List[str] = MISSING
    presets: List[str] = MISSING
    physics_settings: List[str] = MISSING
    renderers: List[str] = MISSING
    styles: List[str] = MISSING
    steps: int = _set(1, whole=True)
    repeats: int = _set(1, whole=True)


@dataclass
class ExportConfig:
    """cathsim-export (conf/export.yaml)."""

    task: TaskConfig = MISSING
    aorta: Any = MISSING
    out: str = _folder()
    seed: int = _set(0, whole=True)
    overwrite: bool = MISSING


TOOL_SCHEMAS = {
    "train": TrainConfig,
    "eval": EvalConfig,
    "collect": CollectConfig,
    "bc": BCToolConfig,
    "force": ForceToolConfig,
    "bench": BenchConfig,
    "export": ExportConfig,
}


# --- registration and validation of every tool's config -----------------------------------

SCHEMA = "schema"  # each group's schema, named in its YAML files' defaults lists
GROUP_SCHEMAS = {"task": TaskConfig, "algo": AlgoConfig, "demos": DemosConfig}
TRAIN_SCHEMA = "train_schema"  # conf/train.yaml's first default


def tool_schemas() -> dict:
    """Each tool's schema: {"train": TrainConfig, "eval": EvalConfig, ...}."""
    return TOOL_SCHEMAS


def register_schemas() -> None:
    """Put the schemas in Hydra's ConfigStore (idempotent). Composing conf/ needs them."""
    from hydra.core.config_store import ConfigStore

    store = ConfigStore.instance()
    for group, schema in GROUP_SCHEMAS.items():
        store.store(group=group, name=SCHEMA, node=schema)
    for tool, schema in tool_schemas().items():  # conf/<tool>.yaml's first default: <tool>_schema
        store.store(name=f"{tool}_schema", node=schema)


def _sections(schema) -> dict:
    """A tool schema's typed sections: name -> dataclass."""
    return {spec.name: spec.type for spec in fields(schema) if is_dataclass(spec.type)}


def check_known_keys(cfg, tool: str | None = "train") -> None:
    """ValueError naming the first key no schema knows. Composition already refuses one
    set as `key=value`; Hydra's `+key=value` adds it past the schema, and a config it
    composed would then ignore it silently. `tool`: whose whole config cfg is (its top
    level and every typed section are checked); None: only the typed groups."""
    schema = tool_schemas().get(tool)
    sections = {**GROUP_SCHEMAS, **(_sections(schema) if schema else {})}
    known = {name: {spec.name for spec in fields(section)} for name, section in sections.items()}
    if schema:
        known[""] = {spec.name for spec in fields(schema)} | {"hydra"}
    for section, names in known.items():
        node = cfg if not section else cfg.get(section)
        if node is None:
            continue
        unknown = sorted(set(node.keys()) - names)
        if unknown:
            key = f"{section}.{unknown[0]}" if section else unknown[0]
            raise ValueError(
                f"unknown option {key}: not in {(sections[section] if section else schema).__name__} "
                f"(cathsim_dmc/app/train_schema.py, cathsim_dmc/app/tool_schemas.py)"
            )


def validate(cfg, tool: str = "train") -> None:
    """Every key and range of a composed config of `tool` (cathsim-<tool>; sections it
    lacks are skipped): ValueError naming the first unknown key or value out of range.
    Types were checked when it was composed."""
    check_known_keys(cfg, tool)
    schema = tool_schemas()[tool]
    check_section("", schema, cfg)
    for name, section in _sections(schema).items():
        if cfg.get(name) is not None:
            check_section(name, section, cfg[name])
    demos = cfg.get("demos")
    if demos is not None and demos.get("path") and not Path(str(demos.path)).exists():
        raise ValueError(f"demos.path={str(demos.path)!r} does not exist; give a cathsim-collect dataset folder")
    trainer = cfg.get("trainer")
    if trainer is not None and str(trainer.get("device", "")).startswith("cuda"):
        check_cuda("trainer.device", str(trainer.device))


def check_cuda(key: str, device: str) -> None:
    """ValueError naming `key=device` (cuda or cuda:<index>) unless torch sees that GPU:
    training would otherwise fail late or, with device=auto's fallback, run on the CPU unasked."""
    import torch

    if not torch.cuda.is_available():
        raise ValueError(f"{key}={device!r}, but torch sees no CUDA GPU on this machine; choose cpu or auto")
    count, index = torch.cuda.device_count(), device.partition(":")[2]
    if index and not (index.isdigit() and int(index) < count):
        raise ValueError(
            f"{key}={device!r}: this machine has {count} CUDA GPU(s); choose cuda or cuda:0 to cuda:{count - 1}"
        )
