"""Rollouts, reports and videos: the one place every tool evaluates a policy through.

cathsim-eval, cathsim-train (its final report and its periodic evaluation),
cathsim-collect and cathsim-bc roll out with `run_episodes`; they and cathsim-teleop
(a person's episodes) write the same report (`write_report`: metrics.json, metrics.md with
the failed episodes grouped by where they ended, path.png, forces.png), so their numbers
are comparable. A policy is a function (observation, env) -> action
(`cathsim_dmc.control.policies`).
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np
from tqdm import tqdm

from cathsim_dmc.core.shipped import aorta_label

log = logging.getLogger("cathsim-eval")

METRICS_JSON = "metrics.json"
METRICS_MD = "metrics.md"
VIDEO_FORMATS = ("gif", "mp4")


class EpisodesInterrupted(KeyboardInterrupt):
    """Ctrl-C during `run_episodes`; `summaries` holds the episodes it finished."""

    def __init__(self, summaries: list):
        super().__init__()
        self.summaries = summaries


def check_report_options(episodes: int, video_format: str = "gif", video_size: int = 240) -> None:
    """ValueError for settings `evaluate_policy` cannot honour: checked before any work."""
    from cathsim_dmc.core.checks import check_number
    from cathsim_dmc.sim.render import check_render_size

    check_number("episodes", episodes, 1, whole=True)
    check_render_size("video_size", video_size)
    if video_format not in VIDEO_FORMATS:
        raise ValueError(f"video_format={video_format!r}; choose one of {list(VIDEO_FORMATS)}")


def run_episodes(
    env,
    policy,
    episodes: int,
    seed: int,
    recorder=None,
    video_frames=None,
    video_size=240,
    show_progress: bool = True,
    log_episodes: bool = True,
):
    """Roll out `policy` for `episodes` episodes (episode i reset with `seed + i`); returns
    per-episode summaries (steps, return, success, ...).

    `recorder` (a TrajectoryRecorder) receives every step; `video_frames` (a list) the
    top view of the first episode. Ctrl-C raises EpisodesInterrupted with the finished
    episodes' summaries.
    """
    from cathsim_dmc.evaluation.metrics import remaining_centerline_length_m
    from cathsim_dmc.sim.render import CameraCache, video_frame

    cameras = CameraCache()
    summaries = []
    max_steps = env.task.max_steps
    random_anatomy = hasattr(getattr(env, "dm_env", None), "anatomy_name")  # aorta=random: a new anatomy per episode
    progress = tqdm(total=episodes * max_steps, unit="step", desc="evaluating", disable=not show_progress)
    try:
        for episode in range(episodes):
            observation, info = env.reset(seed=seed + episode)
            if recorder is not None:
                centerline = env.task.aorta.centerline(env.task.target_name)  # this episode's anatomy
                recorder.start_episode(
                    info["tip_position_m"],
                    remaining_centerline_length_m(centerline, info["tip_position_m"]),
                    observation,
                    aorta=info["aorta"] if random_anatomy else None,
                    target_position_m=env.task.target_position_m,
                )
            total, done = 0.0, False
            while not done:
                action = policy(observation, env)
                observation, reward, terminated, truncated, info = env.step(action)
                if recorder is not None:
                    recorder.record(action, reward, info, terminated, truncated, observation)
                total += reward
                done = terminated or truncated
                progress.update(max_steps - info["step"] + 1 if done else 1)
                if video_frames is not None and episode == 0:
                    video_frames.append(video_frame(env.physics, video_size, cache=cameras))
            summaries.append(
                {
                    "episode": episode,
                    "seed": seed + episode,
                    "steps": info["step"],
                    "return": total,
                    "success": bool(info["success"]),
                    "diverged": bool(info["diverged"]),
                    "final_distance_m": info["target_distance_m"],
                    **({"aorta": info["aorta"]} if random_anatomy else {}),
                    # The episode's C-arm angles (LAO, cranial; degrees), where a view is drawn per episode.
                    **({"carm_view_deg": list(env.task.carm_view_deg)} if _draws_views(env.task) else {}),
                }
            )
            if log_episodes:
                log.info("episode %d: %s", episode, summaries[-1])
    except KeyboardInterrupt as interrupt:  # the caller may keep the finished episodes
        raise EpisodesInterrupted(summaries) from interrupt
    finally:
        progress.close()
    return summaries


def _draws_views(task) -> bool:
    settings = task.observation_settings
    return settings.view_deg_range is not None or settings.cranial_deg_range is not None


def write_report(arrays: dict, asset, label: dict, out_dir, episodes: list | None = None, tree_for=None) -> dict:
    """metrics.json, metrics.md, path.png (unless `asset` is None) and forces.png for one
    policy on one (task, aorta). With `tree_for` (`episode_ends.trees_of(env)`) the report
    also says where each episode ended, and metrics.md groups the failures by it."""
    from cathsim_dmc.evaluation import episode_ends, metrics, plots
    from cathsim_dmc.evaluation.trajectory import wall_forces_n

    out_dir = Path(out_dir)
    per_episode = metrics.trajectory_metrics(arrays)
    summary = metrics.summarize(per_episode)
    report = {**label, "summary": summary, "per_episode": [vars(m) for m in per_episode], "episodes": episodes or []}
    table = metrics.markdown_table([(_row_label(label), summary)])
    if tree_for is not None:
        ends = episode_ends.episode_ends(arrays, tree_for)
        report["episode_ends"] = [vars(e) for e in ends]
        failures = episode_ends.failures_table(ends)
        table += f"\n{failures}" if failures else ""
    (out_dir / METRICS_JSON).write_text(json.dumps(report, indent=2))
    (out_dir / METRICS_MD).write_text(table)
    target = label["task"]
    rows = [arrays["episode"] == e for e in range(len(arrays["start_tip_position_m"]))]
    title = f"{label['policy']} on {target}/{label['aorta']}: success {summary['success_pct']['mean']:.0f}%"
    if asset is not None:
        plots.path_plot(
            asset,
            target,
            arrays["start_tip_position_m"],
            [arrays["tip_position_m"][r] for r in rows],
            [bool(arrays["success"][r].any()) for r in rows],
            out_dir / "path.png",
            title,
        )
    forces = wall_forces_n(arrays)  # the step-mean wall force (end of step for older files)
    plots.force_plots([forces[r] for r in rows], out_dir / "forces.png", title=title)
    return report


def _row_label(label: dict) -> dict:
    policy = label["policy"] if label.get("seed") is None else f"{label['policy']} (seed {label['seed']})"
    if label.get("partial"):  # Ctrl-C stopped the evaluation (evaluate_policy)
        policy += f" [partial: {label['episodes_finished']} of {label['episodes_requested']} episodes]"
    return {"Target": label["task"].upper(), "Aorta": aorta_label(label["aorta"]), "Policy": policy}


def combine_reports(folder) -> str:
    """One Markdown table from every report under `folder` (a multirun sweep).

    Reads `<job>/metrics.json` (cathsim-eval) and `<job>/eval/metrics.json`
    (cathsim-train). Runs that differ only by seed also get a pooled row over all their
    episodes, labelled with the number of seeds.
    """
    from cathsim_dmc.evaluation import metrics

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


def evaluate_policy(
    env,
    policy,
    policy_name: str,
    episodes: int,
    seed: int,
    out_dir,
    video: bool = True,
    video_size: int = 240,
    video_format: str = "gif",
    save_observations: bool = False,
    show_progress: bool = True,
    label: dict | None = None,
) -> dict:
    """Evaluate `policy` on `env` (a CathSimEnv) and write the full report into `out_dir`.

    `label` adds fields to the report (cathsim-train adds its training seed).
    """
    from cathsim_dmc.evaluation.episode_ends import trees_of
    from cathsim_dmc.evaluation.trajectory import TrajectoryRecorder

    check_report_options(episodes, video_format, video_size)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    task = env.task
    recorder = TrajectoryRecorder(
        task.target_name,
        env.aorta_name,
        task.target_position_m,
        policy=policy_name,
        record_observations=save_observations,
        safe_force_n=task.safe_force_n,
    )
    frames = [] if video else None
    label = {
        "task": task.target_name,
        "aorta": env.aorta_name,
        "policy": policy_name,
        "physics": task.physics_setting,
        "safe_force_n": task.safe_force_n,
        **(label or {}),
    }
    tree_for = trees_of(env)
    try:
        summaries = run_episodes(env, policy, episodes, seed, recorder, frames, video_size, show_progress)
    except EpisodesInterrupted as interrupt:
        # Ctrl-C: the finished episodes get their report, labelled partial.
        from cathsim_dmc.core.run_files import Interrupted

        summaries = interrupt.summaries
        if not summaries:
            raise Interrupted(f"evaluation stopped before its first episode ended; nothing written in {out_dir}")
        recorder.keep_episodes(len(summaries))
        label.update(partial=True, episodes_finished=len(summaries), episodes_requested=episodes)
        _write_results(recorder, frames, video_format, task, label, out_dir, summaries, tree_for)
        raise Interrupted(
            f"evaluation stopped after {len(summaries)} of {episodes} episodes; their report "
            f"(labelled partial) is in {out_dir}"
        ) from None
    return _write_results(recorder, frames, video_format, task, label, out_dir, summaries, tree_for)


def _write_results(recorder, frames, video_format, task, label, out_dir, summaries, tree_for) -> dict:
    recorder.save(out_dir / "trajectories.npz")
    if frames:
        write_video(out_dir / f"video.{video_format}", frames)
    # One anatomy's picture cannot hold paths from several (aorta=random): no path.png then.
    arrays = recorder.arrays()
    asset = None if "episode_aorta" in arrays else task.aorta.asset
    return write_report(arrays, asset, label, out_dir, summaries, tree_for)


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
