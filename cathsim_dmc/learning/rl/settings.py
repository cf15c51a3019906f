"""The settings of SAC training (`train`'s `algo`, `demos` and `trainer` dicts): one
dataclass each, with every option's default and range.

`cathsim_dmc.learning.rl.train` fills in what a Python caller leaves out from them and
checks the ranges (`cathsim_dmc.core.settings`); cathsim-train's config schema
(cathsim_dmc/app/train_schema.py) is built from them, so its `algo`, `demos` and `trainer`
groups have the same defaults and ranges. Importing this module needs neither a
simulator nor torch.
"""

from dataclasses import dataclass
from typing import List, Optional

from cathsim_dmc.control.policies import EXPERT_POLICIES
from cathsim_dmc.core.settings import count, setting

DEVICES = ("auto", "cpu", "cuda")  # or cuda:<index>
FINAL_POLICIES = ("best", "last")
DEMONSTRATORS = tuple(EXPERT_POLICIES)  # the scripted experts that can demonstrate


@dataclass
class AlgoConfig:
    """`algo`: SAC. The defaults are the paper's settings (CathSim's table of SAC settings);
    conf/algo/sac_tuned.yaml and sac_cpu.yaml change a few."""

    name: str = "sac"
    learning_rate: float = setting(3.0e-4, above=0.0)
    buffer_size: int = count(1_000_000, minimum=1)  # transitions; refused up front if it would not fit in memory
    batch_size: int = count(256, minimum=1)
    tau: float = setting(0.005, minimum=0.0, maximum=1.0)
    gamma: float = setting(0.99, minimum=0.0, maximum=1.0)
    train_freq: int = count(1, minimum=1)
    gradient_steps: int = 1  # SB3's: -1 means as many as environment steps
    target_update_interval: int = count(1, minimum=1)
    target_entropy: float = -2.0  # = -dim(action)
    # The paper lists the entropy coefficient as 1 next to a target entropy. A target only
    # matters when the coefficient is learned, so "1" is read as its initial value: SB3's
    # "auto_1.0" (learned, starting at 1.0). A number fixes it.
    ent_coef: str = "auto_1.0"
    learning_starts: int = count(1000)  # random actions before the first update
    net_arch: List[int] = setting([256, 256], minimum=1, whole=True)  # actor and critic heads on the features
    share_features_extractor: bool = False  # true: one ENN for actor and critic (faster on a CPU)
    critic_layer_norm: bool = False  # true: LayerNorm after each hidden layer of the critics (RLPD)
    # > 0: evaluate (and keep as best.zip) an exponential average of the actor's weights
    actor_average_tau: float = setting(0.0, minimum=0.0, maximum=1.0)


@dataclass
class DemosConfig:
    """`demos`: demonstrations mixed into training. The defaults are plain SAC (none);
    conf/demos/expert.yaml is the recipe's."""

    episodes: int = count(0)  # expert episodes recorded before training (0: none)
    share: float = setting(0.5, minimum=0.0, maximum=1.0)  # of every batch (RLPD's symmetric sampling)
    capacity: int = count(20_000, minimum=1)  # most demonstration transitions kept (100 expert episodes: ~6-16k)
    pretrain_actor_steps: int = count(0)  # behavioural-cloning steps of the actor before SAC starts
    critic_warmup_steps: int = count(0)  # critic-only updates on the demonstrations after that
    # behavioural-cloning term in the actor's loss, x mean|Q|, counted on every
    # demonstration state of the batch (TD3+BC's form; 0: plain SAC)
    bc_weight: float = setting(0.0, minimum=0.0)
    # rounds of takeover demonstrations after pre-training (0: none): the actor drives, the
    # expert takes over at a random step, its part joins the demonstrations and the actor
    # is re-trained on them (half of pretrain_actor_steps)
    takeover_rounds: int = count(0)
    takeover_episodes: int = count(20, minimum=1)  # episodes per round
    takeover_max_student_steps: int = count(200)  # the expert takes over at a step drawn from 0..this
    # rounds of expert labels after pre-training (DAgger; 0: none): the actor drives
    # dagger_episodes episodes, the expert labels every state it reaches with its own
    # action, and the actor is re-trained (pretrain_actor_steps) on the demonstrations and
    # all labels so far; the cloning term (bc_weight) then covers the labels' states too
    dagger_rounds: int = count(0)
    dagger_episodes: int = count(50, minimum=1)
    dagger_capacity: int = count(200_000, minimum=1)  # most expert labels kept
    path: Optional[str] = None  # a cathsim-collect folder to take them from instead of recording the expert
    # the scripted expert that records the demonstrations, takes over and labels: expert, or
    # expert_steady (no turns where the path runs straight ahead of the tip)
    expert: str = setting("expert", choices=DEMONSTRATORS)


@dataclass
class TrainerConfig:
    """`trainer`: the training run around the algorithm."""

    # with demos=expert every default-recipe run so far chose its best.zip within its
    # first 7k steps (docs/training.md); demos=none needs ~100k, the paper 600000
    total_timesteps: int = count(8000, minimum=1)
    n_envs: int = count(1, minimum=1)  # > 1: one subprocess per environment
    # steps between deterministic evaluations (TensorBoard, evaluations.jsonl, best.zip; 0: none)
    eval_every: int = count(1000)
    eval_episodes: int = count(10, minimum=1)  # of each periodic evaluation (and the final one, if not below)
    # also evaluate the pre-trained policy before the first step, so that it competes for best.zip
    eval_at_start: bool = False
    final_eval_episodes: Optional[int] = count(20, minimum=1)  # of the final report (null: eval_episodes)
    # when several periodic evaluations share the best success rate, more episodes for each
    # of them (at most 3) decide best.zip (0: the earlier of a tie is kept)
    tie_break_episodes: int = count(20)
    # steps between checkpoints; null: with every periodic evaluation (eval_every; 1000 steps
    # without one), so a killed run resumes from its last evaluation; 0: only at the end
    checkpoint_every: Optional[int] = count(None)
    save_replay_buffer: bool = False  # also checkpoint the replay buffer (large with images)
    device: str = setting("auto", choices=DEVICES, prefix="cuda:")  # or cuda:<index>
    # 1 thread: 71 ms per SAC update against 478 ms with 2 on a busy 2-core machine; 0: torch's default
    torch_threads: int = count(1)
    progress_bar: bool = True
    video: bool = True  # video of the first evaluation episode
    # which policy the final report evaluates (best: best.zip of the periodic evaluations, when eval_every > 0)
    final_policy: str = setting("best", choices=FINAL_POLICIES)
