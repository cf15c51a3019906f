"""Figures for evaluation reports and training runs: tip paths over the AP view, contact forces, learning curves."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")  # files only; no display on the machines this runs on
    import matplotlib.pyplot as plt

    return plt


def path_plot(asset, target: str, start_tips_m, tip_paths_m, successes, out_path, title: str = "") -> Path:
    """Tip paths (one per episode) over the vessel seen from the top (AP) camera, in mm.

    The lumen is drawn as its projected triangles on the x-y plane, which is what the
    top camera looks at along -z.
    """
    from matplotlib.collections import PolyCollection

    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(5, 6))
    triangles = asset.visual_vertices[asset.visual_faces][..., :2] * 1e3
    ax.add_collection(PolyCollection(triangles, facecolors=(0.9, 0.55, 0.55, 0.15), edgecolors="none"))
    centerline = asset.centerlines[target].points * 1e3
    ax.plot(centerline[:, 0], centerline[:, 1], "--", color="0.4", lw=1, label=f"{target} centerline")
    for start, path, ok in zip(start_tips_m, tip_paths_m, successes):
        path = np.vstack([start, path]) * 1e3
        ax.plot(path[:, 0], path[:, 1], "-", lw=1, color="tab:green" if ok else "tab:red", alpha=0.8)
    target_mm = asset.sites[target] * 1e3
    ax.add_patch(plt.Circle(target_mm[:2], 4.0, fill=False, color="tab:blue", lw=1))
    ax.plot(*target_mm[:2], "*", color="tab:blue", ms=10, label=f"target ({target}, 4 mm)")
    lo, hi = asset.bounds * 1e3
    ax.set_xlim(lo[0] - 5, hi[0] + 5)
    ax.set_ylim(lo[1] - 5, hi[1] + 5)
    ax.set_aspect("equal")
    ax.set_xlabel("x, patient left (mm)")
    ax.set_ylabel("y, superior (mm)")
    ax.plot([], [], color="tab:green", label="tip path, success")
    ax.plot([], [], color="tab:red", label="tip path, failure")
    ax.legend(loc="lower left", fontsize=7)
    ax.set_title(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(out_path, dpi=110)
    plt.close(fig)
    return Path(out_path)


def force_plots(forces_per_episode, out_path, safe_force_n: float = 2.0, title: str = "") -> Path:
    """Total contact force over time (every episode) and its histogram over all steps."""
    plt = _pyplot()
    fig, (ax_t, ax_h) = plt.subplots(1, 2, figsize=(9, 3.2))
    for forces in forces_per_episode:
        ax_t.plot(np.arange(1, len(forces) + 1), forces, lw=0.8, alpha=0.7)
    for ax in (ax_t,):
        ax.axhline(safe_force_n, color="k", ls=":", lw=1, label=f"safety threshold {safe_force_n:g} N")
    ax_t.set_xlabel("control step")
    ax_t.set_ylabel("total contact force, step mean (N)")
    ax_t.legend(fontsize=7)
    every = np.concatenate([np.asarray(f) for f in forces_per_episode]) if forces_per_episode else np.zeros(0)
    ax_h.hist(every, bins=40, color="tab:gray")
    ax_h.axvline(safe_force_n, color="k", ls=":", lw=1)
    ax_h.set_xlabel("total contact force (N)")
    ax_h.set_ylabel("steps")
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(out_path, dpi=110)
    plt.close(fig)
    return Path(out_path)


def seed_spread(seeds: list) -> tuple:
    """(steps, median, low, high) of success over seeds, each seed a list of evaluations.jsonl
    records ({"step", "success_rate"}); a step counts the seeds that reached it."""
    by_step: dict = {}
    for evaluations in seeds:
        for e in evaluations:
            by_step.setdefault(int(e["step"]), []).append(float(e["success_rate"]))
    steps = sorted(by_step)
    values = [by_step[s] for s in steps]
    return (
        np.array(steps),
        np.array([np.median(v) for v in values]),
        np.array([min(v) for v in values]),
        np.array([max(v) for v in values]),
    )


def learning_curves_plot(panels: dict, out_path, aim: float | None = None, ylabel: str = "success") -> Path:
    """One panel per key of `panels` ({label: [each seed's evaluations]}): the median success
    over seeds against environment steps, the band from the lowest to the highest seed."""
    plt = _pyplot()
    fig, axes = plt.subplots(1, len(panels), figsize=(4.2 * len(panels), 3.2), squeeze=False)
    for ax, (title, curves) in zip(axes[0], panels.items(), strict=True):
        for label, seeds in curves.items():
            steps, median, low, high = seed_spread(seeds)
            (line,) = ax.plot(steps, median, lw=1.5, marker="o", ms=3, label=f"{label} ({len(seeds)} seeds)")
            ax.fill_between(steps, low, high, color=line.get_color(), alpha=0.2, lw=0)
        if aim is not None:
            ax.axhline(aim, color="0.6", ls=":", lw=1)
        ax.set_title(title)
        ax.set_xlabel("environment steps")
        ax.set_ylim(-0.03, 1.03)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="lower right")
    axes[0][0].set_ylabel(ylabel)
    fig.tight_layout()
    out_path = Path(out_path)
    fig.savefig(out_path, dpi=110)
    plt.close(fig)
    return out_path
