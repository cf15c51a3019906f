#!/usr/bin/env python
"""Render every shipped aorta into one labelled PNG (docs/gallery.png).

    python scripts/gallery.py                      # all shipped variants, and each one's card image
    python scripts/gallery.py type1 bovine --out /tmp/g.png --crops /tmp/aortas

Each variant is drawn with MuJoCo (its `Aorta` entity in the `OperatingArena`,
all at the same scale) from the `top` camera (antero-posterior, as in
fluoroscopy) and the `side` camera (lateral), with its target sites marked and
the arch-type distance (top of the arch down to the BCA origin) drawn on the AP
view. Each variant's panel is also saved on its own (`--crops`, docs/aortas/<name>.png:
the image of its card in assets/<name>/README.md).
"""

import argparse
import pathlib
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import matplotlib  # noqa: E402

import cathsim_dmc  # noqa: E402,F401  (selects the headless GL backend first)

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from dm_control import mjcf  # noqa: E402
from dm_control.mujoco.engine import Camera  # noqa: E402
from dm_control.mujoco.wrapper.core import MjvOption  # noqa: E402

from cathsim_dmc.core.shipped import available_aortas  # noqa: E402
from cathsim_dmc.entities import Aorta  # noqa: E402
from cathsim_dmc.sim import geom_groups  # noqa: E402
from cathsim_dmc.sim.arena import OperatingArena, top_camera_matrix  # noqa: E402

PIXELS = 420
SITE_COLOURS = {"bca": "#1f77b4", "lcca": "#2ca02c", "lsa": "#ff7f0e"}
ORDER = ("type1", "type2", "type3", "aneurysm", "low_tortuosity", "bovine")


def render(name: str, bounds):
    arena = OperatingArena()
    aorta = Aorta(asset=name, rgba=(0.80, 0.33, 0.33, 0.55))
    arena.attach(aorta)
    arena.frame_cameras(bounds, margin=1.04)
    physics = mjcf.Physics.from_mjcf_model(arena.mjcf_model)
    option = MjvOption()
    option.geomgroup[:] = 0
    option.geomgroup[geom_groups.VISUAL] = 1
    option.sitegroup[:] = 0
    images, projections = {}, {}
    for camera in ("top", "side"):
        cam = Camera(physics, PIXELS, PIXELS, camera)
        rgb = cam.render(scene_option=option).copy()
        background = cam.render(segmentation=True, scene_option=option)[..., 0] < 0
        rgb[background] = 255
        images[camera] = rgb
        projections[camera] = top_camera_matrix(physics, camera, PIXELS)
    return aorta.asset, images, projections


def project(matrix, points):
    p = np.c_[np.atleast_2d(points), np.ones(len(np.atleast_2d(points)))] @ matrix.T
    return p[:, 0], p[:, 1]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("names", nargs="*", help="variants (default: every shipped one)")
    parser.add_argument("--out", type=pathlib.Path, default=ROOT / "docs" / "gallery.png")
    parser.add_argument(
        "--crops",
        type=pathlib.Path,
        default=ROOT / "docs" / "aortas",
        help="folder for one image per variant (its panel of the gallery)",
    )
    args = parser.parse_args(argv)
    shipped = available_aortas()
    names = args.names or [n for n in ORDER if n in shipped] + [n for n in shipped if n not in ORDER]
    unknown = [n for n in names if n not in shipped]
    if unknown:
        print(f"error: unknown aorta {', '.join(unknown)}; valid choices: {', '.join(shipped)}", file=sys.stderr)
        return 2
    from cathsim_dmc.anatomy import load_asset
    from cathsim_dmc.core.shipped import resolve_asset

    # One frame for all, so the variants are drawn at the same scale.
    bounds = np.array([load_asset(resolve_asset(n)).bounds for n in names])
    common = np.stack([bounds[:, 0].min(axis=0), bounds[:, 1].max(axis=0)])
    scale_px_per_mm = PIXELS / (max(np.ptp(common[:, 0]), np.ptp(common[:, 1])) * 1.04 * 1e3)

    cols = 3
    rows = int(np.ceil(len(names) / cols))
    fig = plt.figure(figsize=(cols * 5.6, rows * 4.6), dpi=110, facecolor="white")
    outer = fig.add_gridspec(rows, cols, wspace=0.04, hspace=0.16, left=0.01, right=0.99, top=0.875, bottom=0.02)
    panels = {}
    for k, name in enumerate(names):
        asset, images, proj = render(name, common)
        inner = outer[k // cols, k % cols].subgridspec(1, 2, width_ratios=[1.0, 0.42], wspace=0.02)
        ax_top, ax_side = fig.add_subplot(inner[0]), fig.add_subplot(inner[1])
        panels[name] = (ax_top, ax_side)
        ax_top.imshow(images["top"])
        # Lateral view: keep the columns that show the vessel.
        side = images["side"]
        used = np.nonzero(np.any(side.min(axis=2) < 250, axis=0))[0]
        c0 = max(int(used.min()) - 12, 0) if len(used) else 0
        c1 = min(int(used.max()) + 12, PIXELS) if len(used) else PIXELS
        ax_side.imshow(side[:, c0:c1])
        offsets = {"bca": (-8, 2, "right"), "lcca": (0, 9, "center"), "lsa": (8, 2, "left")}
        for b, p in sorted(asset.sites.items()):
            colour = SITE_COLOURS.get(b, "white")
            u, v = project(proj["top"], p)
            ax_top.plot(u, v, "o", ms=6, mec="black", mfc=colour, mew=0.8)
            dx, dy, ha = offsets.get(b, (6, 2, "left"))
            ax_top.annotate(
                b.upper(),
                (u[0], v[0]),
                xytext=(dx, dy),
                textcoords="offset points",
                color=colour,
                fontsize=8,
                fontweight="bold",
                ha=ha,
                va="bottom",
            )
            u, v = project(proj["side"], p)
            ax_side.plot(u - c0, v, "o", ms=5, mec="black", mfc=colour, mew=0.8)
        u, v = project(proj["top"], asset.entry_position)
        ax_top.plot(u, v, "^", ms=7, mec="black", mfc="white", mew=0.8)
        ax_top.annotate(
            "entry", (u[0], v[0]), xytext=(-8, 0), textcoords="offset points", fontsize=8, ha="right", va="center"
        )
        meta = asset.meta
        title = name
        if asset.arch_type_distance_m is not None:
            # Arch-type distance: from the top of the outer curvature down to the BCA origin.
            ostium = np.asarray(meta["ostia"]["bca"])
            top = ostium + [0.0, asset.arch_type_distance_m, 0.0]
            (ub, vb), (ut, vt) = (np.ravel(project(proj["top"], q)) for q in (ostium, top))
            x = ub - 45
            for vv in (vb, vt):
                ax_top.plot([x - 8, ub + 60], [vv, vv], color="black", lw=0.9, ls="--")
            ax_top.annotate(
                "", (x, vb), (x, vt), arrowprops=dict(arrowstyle="<->", lw=1.2, color="black", shrinkA=0, shrinkB=0)
            )
            ax_top.text(
                x - 10,
                0.5 * (vb + vt),
                f"{asset.arch_type_distance_m * 1e3:.1f} mm",
                ha="right",
                va="center",
                fontsize=8,
            )
            ratio = asset.arch_type_distance_m / asset.cca_diameter_m
            tort = meta.get("tortuosity", {})
            extra = ""
            if meta.get("params", {}).get("aneurysm_diameter_m", 0):
                extra = f", {meta['max_aortic_diameter_m'] * 1e3:.0f} mm aneurysm"
            if meta.get("params", {}).get("bovine"):
                extra = ", common BCA-LCCA origin"
            if meta.get("params", {}).get("arch_rotation_deg"):
                extra = f", obliquity {meta['arch_obliquity_deg']:.1f} deg"
            title = (
                f"{name}: type {meta.get('arch_type', '?')}{extra}; tortuosity {tort.get('arch', float('nan')):.2f}\n"
                f"BCA origin {asset.arch_type_distance_m * 1e3:.1f} mm = {ratio:.2f} CCA diameters below arch top"
            )
        ax_top.set_title(title, fontsize=9.5, loc="left")
        ax_top.text(6, PIXELS - 8, "AP", fontsize=8, color="#444444")
        ax_side.text(
            0.5,
            0.01,
            "lateral",
            transform=ax_side.transAxes,
            fontsize=8,
            color="#444444",
            ha="center",
            va="bottom",
            bbox=dict(facecolor="white", edgecolor="none", pad=1),
        )
        # 5 cm scale bar.
        bar = 50 * scale_px_per_mm
        ax_top.plot([PIXELS - 12 - bar, PIXELS - 12], [PIXELS - 14] * 2, color="black", lw=2)
        ax_top.text(PIXELS - 12 - bar / 2, PIXELS - 20, "5 cm", ha="center", fontsize=7)
        for ax in (ax_top, ax_side):
            ax.set_xticks([])
            ax.set_yticks([])
            for spine in ax.spines.values():
                spine.set_color("#bbbbbb")
    fig.suptitle(
        "cathsim-dmc shipped aortas, all at the same scale: AP (top camera) and lateral (side camera) views\n"
        "sites: BCA blue, LCCA green, LSA orange; dashed lines: arch top and BCA origin (their distance sets "
        "the arch type); tortuosity: path/chord of the arch",
        fontsize=11,
    )
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=110, facecolor="white")
    print(f"wrote {args.out}")
    from matplotlib.transforms import Bbox

    args.crops.mkdir(parents=True, exist_ok=True)
    renderer = fig.canvas.get_renderer()
    for name, axes in panels.items():
        # The panel's two views with their title, in inches, as savefig crops.
        box = Bbox.union([ax.get_tightbbox(renderer) for ax in axes]).transformed(fig.dpi_scale_trans.inverted())
        path = args.crops / f"{name}.png"
        fig.savefig(path, dpi=110, facecolor="white", bbox_inches=box.padded(0.05))
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
