"""The typed schemas of the tools other than cathsim-train (conf/<tool>.yaml), beside
cathsim_dmc/config.py's, which registers and checks them all.

Here the YAML file keeps each default and the comment that explains it; the schema holds
its type and range, so its fields are MISSING until the YAML fills them in. A value of the
wrong type (`video=maybe`) then fails while composing, one out of range
(`bc.val_fraction=1.5`) in `config.validate`: both before any work.
"""

from dataclasses import dataclass, field
from typing import Any, List, Optional

from cathsim_dmc.config import MISSING, ScenarioConfig, TaskConfig, TrainConfig, _number

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
    return _number(MISSING, minimum=minimum, **check)


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
    learning_rate: float = _number(MISSING, above=0.0)
    entropy_coef: float = _set(0.0)
    l2_coef: float = _set(0.0)
    distill_coef: float = _set(0.0)
    val_fraction: float = _set(0.0, below=1.0)  # 1 would leave no episode to train on
    frames: int = _set(1, whole=True)


@dataclass
class BCToolConfig(ScenarioConfig):
    """cathsim-bc (conf/bc.yaml)."""

    data: Any = MISSING                # a dataset folder or a list of them
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
    learning_rate: float = _number(MISSING, above=0.0)
    z_coef: float = _set(0.0)
    test_fraction: float = _number(MISSING, above=0.0, below=1.0)  # 0 or 1: no test or no training episode
    val_fraction: float = _set(0.0, below=1.0)
    init_from: Optional[str] = MISSING
    outlier_n: Optional[float] = _number(MISSING, above=0.0)


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


TOOL_SCHEMAS = {"train": TrainConfig, "eval": EvalConfig, "collect": CollectConfig, "bc": BCToolConfig,
                "force": ForceToolConfig, "bench": BenchConfig, "export": ExportConfig}

