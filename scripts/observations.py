"""Draw docs/observations.png: the 80x80 observations of one state, GL vs raster
renderer, camera vs fluoro style, and the guidewire masks; print how they agree.

    .venv/bin/python scripts/observations.py [--out docs/observations.png] [--steps 60]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

import cathsim_dmc  # noqa: F401  (GL backend before dm_control)
from cathsim_dmc import tasks
from cathsim_dmc.sim import raster
from cathsim_dmc.sim.render import TopView


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=str(Path(__file__).resolve().parents[1] / "docs" / "observations.png"))
    parser.add_argument("--steps", type=int, default=60)
    parser.add_argument("--aorta", default="type1")
    args = parser.parse_args()

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    # The state of tests/test_images.py: insertion with rotation one way, then the other.
    env = tasks.load("bca", args.aorta, obs="internal", seed=0)
    env.reset()
    for i in range(args.steps):
        env.step(np.array([1.0, 0.6 if i < args.steps // 2 else -0.6]))
    task, physics = env.task, env.physics
    views = {
        r: TopView(80, renderer=r, wire=task.guidewire, vessel_geom_id=task.aorta.visual_geom_id)
        for r in ("gl", "raster")
    }
    images = {
        (r, c): (v.mask(physics) if c == "mask" else v.image(physics, c))[..., 0]
        for r, v in views.items()
        for c in ("camera", "fluoro", "mask")
    }

    gl_mask, raster_mask = images["gl", "mask"] > 0, images["raster", "mask"] > 0
    print(f"mask IoU (raster vs GL): {(gl_mask & raster_mask).sum() / (gl_mask | raster_mask).sum():.3f}")
    away = ~raster_mask
    gl_vessel = images["gl", "camera"] > 10
    for r in ("raster", "gl"):
        fluoro = images[r, "fluoro"] < 255 * raster.FLUORO_BACKGROUND - 2
        print(
            f"vessel silhouette IoU ({r} fluoro vs GL camera, off the wire): "
            f"{(gl_vessel & fluoro & away).sum() / ((gl_vessel | fluoro) & away).sum():.3f}"
        )

    fig, axes = plt.subplots(2, 3, figsize=(7.5, 5.8))
    for row, r in enumerate(("gl", "raster")):
        for col, c in enumerate(("camera", "fluoro", "mask")):
            ax = axes[row, col]
            ax.imshow(images[r, c], cmap="gray", vmin=0, vmax=255, interpolation="nearest")
            ax.set_title(f"{'GL' if r == 'gl' else 'raster'}: {c if c == 'mask' else c + ' style'}", fontsize=10)
            ax.set_xticks([])
            ax.set_yticks([])
    fig.suptitle(f"80x80 observations, {args.aorta}, after {args.steps} steps of insertion with rotation", fontsize=10)
    fig.tight_layout()
    fig.savefig(args.out, dpi=80)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
