"""The CathSim paper's evaluation metrics, computed from trajectories.

Per episode (units as in the paper's tables):

  force_n           mean over steps of the total wire-vessel contact force (N)
  path_length_cm    sum of tip displacements, from the tip at reset (cm)
  episode_length    control steps taken
  safety_pct        share of steps with total force below `SAFE_FORCE_N` (%)
  success_pct       100 if the tip came within the success radius, else 0 (%)
  spl_pct           success weighted by optimal / max(path, optimal) (%), the optimal
                    path being the centerline length from the start to the target
  safe_success_pct  100 if the tip came within the success radius and no step's force
                    was above the task's `safe_force_n` (default `SAFE_SUCCESS_FORCE_N`), else 0 (%)

The first six are the paper's (`METRIC_COLUMNS`); reports add safe success (`REPORT_COLUMNS`).

A step's force is the total wall force averaged over its physics steps
(`mean_contact_force_n`, see `trajectory.wall_forces_n`), not the force at the step's
end: that one physics step of twenty is zero in 82-87% of the scripted expert's steps
and correlates 0.2-0.4 with the step mean (docs/model.md, "Contact forces").

`summarize` turns per-episode values into mean and standard deviation over episodes;
`markdown_table` prints rows of summaries in the paper's layout.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from cathsim_dmc.core import task_defaults

SAFE_FORCE_N = 2.0  # the paper's safety threshold
# Safe success's threshold when a trajectory file does not record its task's (`safe_force_n`).
SAFE_SUCCESS_FORCE_N = task_defaults.SAFE_FORCE_N

METRIC_COLUMNS = {
    # key: (header, format for the mean and std)
    "force_n": ("Force (N)", "{:.2f}"),
    "path_length_cm": ("Path Length (cm)", "{:.1f}"),
    "episode_length": ("Episode Length", "{:.0f}"),
    "safety_pct": ("Safety (%)", "{:.0f}"),
    "success_pct": ("Success (%)", "{:.0f}"),
    "spl_pct": ("SPL (%)", "{:.0f}"),
}
# Every report's columns: the paper's, then safe success (absent from reports written before it).
REPORT_COLUMNS = {**METRIC_COLUMNS, "safe_success_pct": ("Safe Success (%)", "{:.0f}")}


@dataclass(frozen=True)
class EpisodeMetrics:
    force_n: float
    path_length_cm: float
    episode_length: int
    safety_pct: float
    success_pct: float
    spl_pct: float
    safe_success_pct: float | None = None  # None: a report written before it was measured


def polyline_length_m(points) -> float:
    points = np.asarray(points, dtype=float)
    return float(np.linalg.norm(np.diff(points, axis=0), axis=1).sum()) if len(points) > 1 else 0.0


def remaining_centerline_length_m(centerline_m, position_m) -> float:
    """Arc length from the centerline point closest to `position_m` to the centerline's end.

    The centerline runs from the entry to the target, so this is the shortest path a
    tip at `position_m` has to travel to reach the target along the vessel.
    """
    points = np.asarray(centerline_m, dtype=float)
    p = np.asarray(position_m, dtype=float)
    a, b = points[:-1], points[1:]
    ab = b - a
    t = np.clip(np.einsum("ij,ij->i", p - a, ab) / np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-18), 0.0, 1.0)
    closest = a + t[:, None] * ab
    i = int(np.argmin(np.linalg.norm(closest - p, axis=1)))
    segment_lengths = np.linalg.norm(ab, axis=1)
    return float((1.0 - t[i]) * segment_lengths[i] + segment_lengths[i + 1 :].sum())


def episode_metrics(
    start_tip_m,
    tip_positions_m,
    contact_forces_n,
    success: bool,
    optimal_path_m: float,
    safe_force_n: float = SAFE_SUCCESS_FORCE_N,
) -> EpisodeMetrics:
    """Metrics of one episode.

    Args:
      start_tip_m: tip position at reset (3,), metres.
      tip_positions_m: tip after each step (T, 3), metres.
      contact_forces_n: total contact force of each step (T,), newtons: the step
        mean (`mean_contact_force_n`).
      success: whether the episode reached the target.
      optimal_path_m: shortest path from the start to the target, metres.
      safe_force_n: a success is safe if no step's force is above this, newtons.
    """
    tips = np.vstack([np.asarray(start_tip_m, dtype=float)[None], np.asarray(tip_positions_m, dtype=float)])
    forces = np.asarray(contact_forces_n, dtype=float)
    if len(forces) == 0:
        raise ValueError("an episode needs at least one step")
    path_m = polyline_length_m(tips)
    spl = float(success) * optimal_path_m / max(path_m, optimal_path_m) if optimal_path_m > 0 else float(success)
    return EpisodeMetrics(
        force_n=float(forces.mean()),
        path_length_cm=100.0 * path_m,
        episode_length=int(len(forces)),
        safety_pct=100.0 * float(np.mean(forces < SAFE_FORCE_N)),
        success_pct=100.0 * float(success),
        spl_pct=100.0 * spl,
        safe_success_pct=100.0 * float(success and bool(np.all(forces <= safe_force_n))),
    )


def trajectory_metrics(arrays: dict) -> list:
    """Per-episode metrics from a trajectory file's arrays (see `cathsim_dmc.evaluation.trajectory`);
    forces from `trajectory.wall_forces_n` (the step mean), safe success's threshold the
    file's `safe_force_n` (its task's; `SAFE_SUCCESS_FORCE_N` if it has none)."""
    from cathsim_dmc.evaluation.trajectory import wall_forces_n

    forces = wall_forces_n(arrays)
    safe_force_n = float(arrays["safe_force_n"]) if "safe_force_n" in arrays else SAFE_SUCCESS_FORCE_N
    episodes = []
    for e in range(len(arrays["start_tip_position_m"])):
        rows = arrays["episode"] == e
        if not rows.any():
            continue
        episodes.append(
            episode_metrics(
                arrays["start_tip_position_m"][e],
                arrays["tip_position_m"][rows],
                forces[rows],
                bool(arrays["success"][rows].any()),
                float(arrays["optimal_path_length_m"][e]),
                safe_force_n,
            )
        )
    return episodes


def summarize(episodes) -> dict:
    """{metric: {"mean", "std", "n"}} over episodes (population std, as numpy's default),
    for every metric of `REPORT_COLUMNS` that all episodes have."""
    if not episodes:
        raise ValueError("no episodes to summarize")
    table = [asdict(e) for e in episodes]
    return {
        key: {
            "mean": float(np.mean([row[key] for row in table])),
            "std": float(np.std([row[key] for row in table])),
            "n": len(table),
        }
        for key in REPORT_COLUMNS
        if all(row.get(key) is not None for row in table)
    }


def markdown_table(rows) -> str:
    """A Markdown table from (label columns dict, summary) pairs, e.g.
    ({"Target": "BCA", "Aorta": "type1", "Policy": "expert"}, summarize(...)). The paper's
    columns, then safe success; a summary without it (an older report) shows "-" there."""
    rows = list(rows)
    labels = list(rows[0][0]) if rows else []
    header = labels + [h for h, _ in REPORT_COLUMNS.values()]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for label, summary in rows:
        cells = [str(label[k]) for k in labels]
        for key, (_, fmt) in REPORT_COLUMNS.items():
            if key not in summary:
                cells.append("-")
                continue
            cells.append(f"{fmt.format(summary[key]['mean'])} ± {fmt.format(summary[key]['std'])}")
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"
