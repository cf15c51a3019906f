"""cathsim-eval: run a policy on a (task, aorta) pair and report the paper's metrics.

    cathsim-eval task=bca aorta=type2 policy=expert episodes=20 seed=0
    cathsim-eval policy=outputs/train/bca-type1/<run>      # a trained agent
    cathsim-eval -m task=bca,lcca aorta=type1,type2 policy=expert   # one combined table

Writes into the run folder: metrics.json, metrics.md, trajectories.npz, path.png
(tip paths over the AP view), forces.png, and a video of the first episode.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np
from tqdm import tqdm

log = logging.getLogger("cathsim-eval")

METRICS_JSON = "metrics.json"
METRICS_MD = "metrics.md"


def run_episodes(env, policy, episodes: int, seed: int, recorder, video_frames=None, video_size=240,
                 show_progress: bool = True):
    """Roll out `policy` for `episodes` seeded episodes into `recorder`; returns per-episode summaries."""
    from cathsim_dmc.metrics import remaining_centerline_length_m
    from cathsim_dmc.observables import CameraCache, video_frame

    cameras = CameraCache()
    summaries = []
    max_steps = env.task.max_steps
    centerline = env.task.aorta.centerline(env.task.target_name)
    progress = tqdm(total=episodes * max_steps, unit="step", desc="evaluating", disable=not show_progress)
    for episode in range(episodes):
        observation, info = env.reset(seed=seed + episode)
        recorder.start_episode(info["tip_position_m"], remaining_centerline_length_m(centerline, info["tip_position_m"]),
                               observation)
        total, done = 0.0, False
        while not done:
            action = policy(observation, env)
            observation, reward, terminated, truncated, info = env.step(action)
            recorder.record(action, reward, info, terminated, truncated, observation)
            total += reward
            done = terminated or truncated
            progress.update(max_steps - info["step"] + 1 if done else 1)
            if video_frames is not None and episode == 0:
                video_frames.append(video_frame(env.physics, video_size, cache=cameras))
        summaries.append({
            "episode": episode, "seed": seed + episode, "steps": info["step"], "return": total,
            "success": bool(info["success"]), "diverged": bool(info["diverged"]),
            "final_distance_m": info["target_distance_m"],
        })
        log.info("episode %d: %s", episode, summaries[-1])
    progress.close()
    return summaries


def write_report(arrays: dict, asset, label: dict, out_dir, episodes: list | None = None) -> dict:
    """metrics.json, metrics.md, path.png and forces.png for one policy on one (task, aorta)."""
    from cathsim_dmc import metrics, plots
    from cathsim_dmc.trajectory import wall_forces_n

    out_dir = Path(out_dir)
    per_episode = metrics.trajectory_metrics(arrays)
    summary = metrics.summarize(per_episode)
    report = {**label, "summary": summary, "per_episode": [vars(m) for m in per_episode], "episodes": episodes or []}
    (out_dir / METRICS_JSON).write_text(json.dumps(report, indent=2))
    (out_dir / METRICS_MD).write_text(metrics.markdown_table([(_row_label(label), summary)]))
    target = label["task"]
    rows = [arrays["episode"] == e for e in range(len(arrays["start_tip_position_m"]))]
    title = f"{label['policy']} on {target}/{label['aorta']}: success {summary['success_pct']['mean']:.0f}%"
    plots.path_plot(asset, target, arrays["start_tip_position_m"], [arrays["tip_position_m"][r] for r in rows],
                    [bool(arrays["success"][r].any()) for r in rows], out_dir / "path.png", title)
    forces = wall_forces_n(arrays)
    plots.force_plots([forces[r] for r in rows], out_dir / "forces.png", title=title)
    return report


def _row_label(label: dict) -> dict:
    policy = label["policy"] if label.get("seed") is None else f"{label['policy']} (seed {label['seed']})"
    return {"Target": label["task"].upper(), "Aorta": label["aorta"], "Policy": policy}


def combine_reports(folder) -> str:
    """One Markdown table from every report under `folder` (a multirun sweep).

    Reads `<job>/metrics.json` (cathsim-eval) and `<job>/eval/metrics.json`
    (cathsim-train). Runs that differ only by seed also get a pooled row over all their
    episodes, labelled with the number of seeds.
    """
    from cathsim_dmc import metrics

    folder = Path(folder)
    paths = sorted(folder.glob(f"*/{METRICS_JSON}")) + sorted(folder.glob(f"*/eval/{METRICS_JSON}"))
    reports = [json.loads(p.read_text()) for p in paths]
    if not reports:
        return ""
    reports.sort(key=lambda r: (r["task"], r["aorta"], r["policy"], r.get("seed") is None, r.get("seed") or 0))
    rows = [(_row_label(r), r["summary"]) for r in reports]
    seeded = {}
    for r in reports:
        if r.get("seed") is not None:
            seeded.setdefault((r["task"], r["aorta"], r["policy"]), []).append(r)
    for (task, aorta, policy), group in sorted(seeded.items()):
        if len(group) < 2:
            continue
        episodes = [metrics.EpisodeMetrics(**e) for r in group for e in r["per_episode"]]
        label = {"task": task, "aorta": aorta, "policy": f"{policy} ({len(group)} seeds)"}
        rows.append((_row_label(label), metrics.summarize(episodes)))
    table = metrics.markdown_table(rows)
    (folder / METRICS_MD).write_text(table)
    (folder / METRICS_JSON).write_text(json.dumps(reports, indent=2))
    return table


def evaluate_policy(env, policy, policy_name: str, episodes: int, seed: int, out_dir, video: bool = True,
                    video_size: int = 240, video_format: str = "gif", save_observations: bool = False,
                    show_progress: bool = True, label: dict | None = None) -> dict:
    """Evaluate `policy` on `env` (a CathSimEnv) and write the full report into `out_dir`.

    `label` adds fields to the report (cathsim-train adds its training seed).
    """
    from cathsim_dmc.trajectory import TrajectoryRecorder

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    task = env.task
    recorder = TrajectoryRecorder(task.target_name, env.aorta_name, task.target_position_m,
                                  policy=policy_name, record_observations=save_observations)
    frames = [] if video else None
    summaries = run_episodes(env, policy, episodes, seed, recorder, frames, video_size, show_progress)
    recorder.save(out_dir / "trajectories.npz")
    if frames:
        write_video(out_dir / f"video.{video_format}", frames)
    label = {"task": task.target_name, "aorta": env.aorta_name, "policy": policy_name, **(label or {})}
    return write_report(recorder.arrays(), task.aorta.asset, label, out_dir, summaries)


def write_video(path, frames, fps: int = 10) -> Path:
    import imageio.v3 as iio

    path = Path(path)
    if path.suffix == ".gif":
        iio.imwrite(path, np.stack(frames), duration=1000 // fps, loop=0)
    else:  # mp4 through OpenCV's bundled FFmpeg: no extra dependency
        import cv2

        height, width = frames[0].shape[:2]
        writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, (width, height))
        for frame in frames:
            writer.write(cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
        writer.release()
    return path


def image_options(obs_cfg) -> dict:
    """Renderer and style of the image observations, from an `obs` config node."""
    return {key: obs_cfg[key] for key in ("renderer", "style") if obs_cfg.get(key) is not None}


def evaluate(cfg) -> dict:
    from hydra.core.hydra_config import HydraConfig
    from omegaconf import OmegaConf

    from cathsim_dmc.gym import CathSimEnv
    from cathsim_dmc.policies import CheckpointPolicy, make_policy

    if cfg.video_format not in ("gif", "mp4"):
        raise ValueError(f"video_format={cfg.video_format!r}; choose one of ['gif', 'mp4']")
    out_dir = Path(HydraConfig.get().runtime.output_dir)
    policy = make_policy(str(cfg.policy), seed=cfg.seed)
    obs, images = cfg.obs.name, image_options(cfg.obs)
    extra = {}
    if isinstance(policy, CheckpointPolicy):  # evaluated on what it was trained on
        obs, images = policy.obs_preset, {**images, **policy.image_options}
        extra.update(policy.env_options)
    params = cfg.aorta.get("params")
    if params is not None:
        extra["aorta_params"] = OmegaConf.to_container(params)
    env = CathSimEnv(task=cfg.task.target, aorta=cfg.aorta.name, obs=obs, **extra, **images,
                     delta_m=cfg.task.delta_m, success_reward=cfg.task.success_reward,
                     dense=cfg.task.dense, max_steps=cfg.task.max_steps)
    name = Path(str(cfg.policy)).name if isinstance(policy, CheckpointPolicy) else str(cfg.policy)
    try:
        report = evaluate_policy(env, policy, name, cfg.episodes, cfg.seed, out_dir, cfg.video, cfg.video_size,
                                 cfg.video_format, cfg.save_observations)
    finally:
        env.close()
    print((out_dir / METRICS_MD).read_text(), end="")
    print(f"results in {out_dir}")
    return report


def main():
    from cathsim_dmc.cli._common import run_hydra
    from cathsim_dmc.observables import OBSERVATION_PRESETS
    from cathsim_dmc.policies import BUILTIN_POLICIES
    from cathsim_dmc.tasks import TARGETS, aorta_choices

    run_hydra(evaluate, "eval", {
        "task": lambda: TARGETS, "aorta": aorta_choices,
        "policy": lambda: sorted(BUILTIN_POLICIES), "obs": lambda: sorted(OBSERVATION_PRESETS),
    }, paths_allowed=("policy",))


if __name__ == "__main__":
    main()
