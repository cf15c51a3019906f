"""Record, then compare, the actions and rewards of fixed-seed runs: a refactoring must
leave them identical to the bit.

    python experiments/behaviour_check.py record before.npz     # on the old commit
    python experiments/behaviour_check.py record after.npz      # on the new one
    python experiments/behaviour_check.py compare before.npz after.npz

What is recorded:

* one expert episode (seed 0, BCA, `internal` observations, default physics) on every
  shipped aorta: every action and reward;
* one 300-step `cathsim-train` run (seed 0, the default recipe with SAC updates from step
  100, a periodic evaluation every 100 steps and a 2-episode final report): every action
  and reward of every environment step in the process (the expert's demonstrations, the
  training steps, the periodic and the final evaluations);
* one episode of each shipped navigator (`cathsim-eval policy=pretrained`, seed 0, on the
  type2 aorta): every action and reward.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

TRAIN_OVERRIDES = [
    "task=bca",
    "aorta=type1",
    "seed=0",
    "trainer.total_timesteps=300",
    "algo.learning_starts=100",
    "trainer.eval_every=100",
    "trainer.eval_episodes=1",
    "trainer.final_eval_episodes=2",
    "trainer.video=false",
    "trainer.progress_bar=false",
]


def expert_episodes() -> dict:
    from cathsim_dmc.control.policies import make_policy
    from cathsim_dmc.core.shipped import available_aortas
    from cathsim_dmc.suite.gym import CathSimEnv

    arrays = {}
    for aorta in available_aortas():
        env = CathSimEnv(task="bca", aorta=aorta, obs="internal")
        policy = make_policy("expert", seed=0)
        observation, _ = env.reset(seed=0)
        actions, rewards = [], []
        done = False
        while not done:
            action = np.asarray(policy(observation, env), dtype=np.float64)
            observation, reward, terminated, truncated, _ = env.step(action)
            actions.append(action)
            rewards.append(reward)
            done = terminated or truncated
        env.close()
        arrays[f"expert/{aorta}/actions"] = np.array(actions)
        arrays[f"expert/{aorta}/rewards"] = np.array(rewards, dtype=np.float64)
        print(f"expert {aorta}: {len(rewards)} steps, return {sum(rewards):.6f}", flush=True)
    return arrays


def _recorded_tool_run(main, argv: list) -> tuple:
    """Runs a command-line tool's `main` in this process with `argv`; returns the action
    and reward of every CathSimEnv.step it took."""
    from cathsim_dmc.suite import gym as cs_gym

    actions, rewards = [], []
    original_step = cs_gym.CathSimEnv.step

    def recording_step(self, action):
        result = original_step(self, action)
        actions.append(np.asarray(action, dtype=np.float64).copy())
        rewards.append(float(result[1]))
        return result

    cs_gym.CathSimEnv.step = recording_step
    saved_argv = sys.argv
    with tempfile.TemporaryDirectory() as run_dir:
        sys.argv = [*argv, f"hydra.run.dir={run_dir}"]
        try:
            main()
        finally:
            sys.argv = saved_argv
            cs_gym.CathSimEnv.step = original_step
    return np.array(actions), np.array(rewards, dtype=np.float64)


def training_run() -> dict:
    """Runs cathsim-train in this process; every CathSimEnv.step is recorded."""
    from cathsim_dmc.app.cli import train as cli_train

    actions, rewards = _recorded_tool_run(cli_train.main, ["cathsim-train", *TRAIN_OVERRIDES])
    print(f"training run: {len(rewards)} environment steps, return {rewards.sum():.6f}", flush=True)
    return {"train/actions": actions, "train/rewards": rewards}


def navigator_episodes() -> dict:
    """One episode of each shipped navigator through cathsim-eval; every step recorded."""
    from cathsim_dmc.app.cli import eval as cli_eval

    arrays = {}
    for target in ("bca", "lcca"):
        argv = [
            "cathsim-eval",
            "policy=pretrained",
            f"task={target}",
            "aorta=type2",
            "episodes=1",
            "seed=0",
            "video=false",
        ]
        actions, rewards = _recorded_tool_run(cli_eval.main, argv)
        print(f"navigator {target}: {len(rewards)} steps, return {rewards.sum():.6f}", flush=True)
        arrays[f"navigator/{target}/actions"] = actions
        arrays[f"navigator/{target}/rewards"] = rewards
    return arrays


def compare(before: Path, after: Path) -> int:
    a, b = np.load(before), np.load(after)
    differ = 0
    for key in sorted(set(a.files) | set(b.files)):
        if key not in a.files or key not in b.files:
            print(f"{key}: only in {'after' if key not in a.files else 'before'}")
            differ += 1
        elif a[key].shape != b[key].shape or a[key].tobytes() != b[key].tobytes():
            print(f"{key}: differs (shapes {a[key].shape} and {b[key].shape})")
            differ += 1
        else:
            print(f"{key}: identical ({a[key].shape[0]} steps)")
    print("bit-identical" if not differ else f"{differ} arrays differ")
    return 1 if differ else 0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    record = sub.add_parser("record")
    record.add_argument("out", type=Path)
    record.add_argument("--only", choices=("expert", "train", "navigator"))
    comp = sub.add_parser("compare")
    comp.add_argument("before", type=Path)
    comp.add_argument("after", type=Path)
    args = parser.parse_args()
    if args.command == "compare":
        return compare(args.before, args.after)
    arrays = {}
    if args.only in (None, "expert"):
        arrays.update(expert_episodes())
    if args.only in (None, "train"):
        arrays.update(training_run())
    if args.only in (None, "navigator"):
        arrays.update(navigator_episodes())
    np.savez(args.out, **arrays)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
