"""cathsim-eval: run a policy on a (task, aorta) pair and write its trajectories and a video.

    cathsim-eval task=bca aorta=type1 policy=forward episodes=1
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np
from tqdm import tqdm

log = logging.getLogger("cathsim-eval")


def run_episodes(env, policy, episodes: int, seed: int, recorder, video_frames=None, video_size=240,
                 show_progress: bool = True):
    """Roll out `policy` for `episodes` seeded episodes; returns per-episode summaries."""
    from cathsim_dmc.observables import CameraCache, video_frame

    cameras = CameraCache()
    summaries = []
    max_steps = env.task.max_steps
    progress = tqdm(total=episodes * max_steps, unit="step", desc="evaluating", disable=not show_progress)
    for episode in range(episodes):
        observation, info = env.reset(seed=seed + episode)
        recorder.start_episode(info["tip_position_m"])
        total, forces, done = 0.0, [], False
        while not done:
            action = policy(observation, env)
            observation, reward, terminated, truncated, info = env.step(action)
            recorder.record(action, reward, info, terminated, truncated)
            total += reward
            forces.append(info["contact_force_n"])
            done = terminated or truncated
            progress.update(max_steps - info["step"] + 1 if done else 1)
            if video_frames is not None and episode == 0:
                video_frames.append(video_frame(env.physics, video_size, cache=cameras))
        summaries.append({
            "episode": episode, "seed": seed + episode, "steps": info["step"], "return": total,
            "success": bool(info["success"]), "diverged": bool(info["diverged"]),
            "final_distance_m": info["target_distance_m"], "mean_contact_force_n": float(np.mean(forces)),
        })
        log.info("episode %d: %s", episode, summaries[-1])
    progress.close()
    return summaries


def evaluate(cfg) -> dict:
    from hydra.core.hydra_config import HydraConfig
    from omegaconf import OmegaConf

    from cathsim_dmc.gym import CathSimEnv
    from cathsim_dmc.policies import make_policy
    from cathsim_dmc.trajectory import TrajectoryRecorder

    out_dir = Path(HydraConfig.get().runtime.output_dir)
    params = cfg.aorta.get("params")
    extra = {"aorta_params": OmegaConf.to_container(params)} if params is not None else {}
    env = CathSimEnv(task=cfg.task.target, aorta=cfg.aorta.name, obs=cfg.obs, **extra,
                     delta_m=cfg.task.delta_m, success_reward=cfg.task.success_reward,
                     dense=cfg.task.dense, max_steps=cfg.task.max_steps)
    policy = make_policy(cfg.policy, seed=cfg.seed)
    recorder = TrajectoryRecorder(cfg.task.target, cfg.aorta.name, env.task.target_position_m)
    frames = [] if cfg.video else None
    summaries = run_episodes(env, policy, cfg.episodes, cfg.seed, recorder, frames, cfg.video_size)
    env.close()

    recorder.save(out_dir / "trajectories.npz")
    if frames:
        import imageio.v3 as iio

        iio.imwrite(out_dir / "video.gif", np.stack(frames), duration=100, loop=0)
    report = {
        "task": cfg.task.target, "aorta": cfg.aorta.name, "policy": cfg.policy, "episodes": summaries,
        "success_rate": float(np.mean([s["success"] for s in summaries])),
    }
    (out_dir / "summary.json").write_text(json.dumps(report, indent=2))
    print(f"{cfg.policy} on {cfg.task.target}/{cfg.aorta.name}: success {report['success_rate']:.0%} "
          f"over {cfg.episodes} episode(s); results in {out_dir}")
    return report


def main():
    from cathsim_dmc.cli._common import run_hydra
    from cathsim_dmc.policies import BUILTIN_POLICIES
    from cathsim_dmc.observables import OBSERVATION_PRESETS
    from cathsim_dmc.tasks import TARGETS, aorta_choices

    run_hydra(evaluate, "eval", {
        "task": lambda: TARGETS, "aorta": aorta_choices,
        "policy": lambda: sorted(BUILTIN_POLICIES), "obs": lambda: sorted(OBSERVATION_PRESETS),
    })


if __name__ == "__main__":
    main()
