#!/usr/bin/env python
"""Meshed lumen radius of each branch against its nominal radius (a pinched branch shows up here).

    python experiments/lumen_radius.py --pool-seed 100 --pool-size 50 --out /tmp/pool100   # build + measure
    python experiments/lumen_radius.py --assets type1 type2 assets/bovine                    # measure only
    python experiments/lumen_radius.py --pool-seed 100 --indices 42 --validate               # + holes/intrusion
    python experiments/lumen_radius.py --mesher-version 1 --out /tmp/pool100_v1              # the old mesher

The pool's arches are drawn exactly as `aorta=random` draws them (`tasks.randomized.anatomy_pool`:
`sample_arch_params(default_rng([pool_seed, i]), name=f"random{pool_seed}-{i}")`, with
conf/aorta/random.yaml's distribution, which is `sample_arch_params`'s default) and built with
`build_asset` into `--out/<i>` (a folder already there is measured, not rebuilt, whatever
mesher version it was built with: each row shows it, `v<version>`), with the current lumen
mesher or `--mesher-version`.

Per branch, on the branch centreline of the parametric model (`build_arch`) sampled every
0.5 mm from the ostium (the nominal aortic wall) to one end radius short of the closed end
(the hemispherical tip is not a tube), the distance to the nearest lumen triangle of
visual.stl over the model's nominal radius there (tapered). Reported: the minimum of that
ratio from the ostium to the site ("to site") and over the whole branch, and where the
branch minimum lies (mm past the ostium). The same ratio from meta.json's centerline radii
(`radius_m`, the path to the site) is `meta`.
"""

from __future__ import annotations

import argparse
import json
import pathlib
import statistics
import sys
import time

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from cathsim_dmc.anatomy import BRANCHES, arch_params, build_arch, build_asset, load_asset  # noqa: E402
from cathsim_dmc.anatomy.asset import recorded_mesher_version  # noqa: E402
from cathsim_dmc.anatomy.generate import sample_arch_params  # noqa: E402
from cathsim_dmc.anatomy.lumen import MESHER_VERSION, MESHER_VERSIONS  # noqa: E402
from cathsim_dmc.anatomy.sdf import unsigned_distance  # noqa: E402


def pool_params(pool_seed: int, i: int):
    """The i-th arch of the pool drawn with `pool_seed`, as tasks/randomized.py draws it."""
    return sample_arch_params(np.random.default_rng([int(pool_seed), int(i)]), name=f"random{pool_seed}-{i}")


def branch_samples(model, b):
    """(points, nominal radius, mm past the ostium, mask up to the site) along branch `b`."""
    br = model.branches[b]
    u = br.arclength
    s = model.aorta.arclength
    r_a = float(np.interp(model.branch_origin_s[b], s, model.aorta.radius))
    keep = (u >= r_a) & (u <= u[-1] - br.radius[-1])
    past = u[keep] - r_a
    return br.points[keep], br.radius[keep], past * 1e3, past <= model.params.site_depth_m + 1e-9


def measure(folder) -> dict:
    """{branch: {...ratios...}} for the asset folder (generated: its meta holds the params)."""
    asset = load_asset(folder)
    params = arch_params({k: v for k, v in asset.params.items()})
    model = build_arch(params)
    v = asset.visual_vertices.astype(np.float64)
    f = asset.visual_faces.astype(np.int64)
    out = {}
    for b in BRANCHES:
        pts, r_nom, past_mm, to_site = branch_samples(model, b)
        ratio = unsigned_distance(v, f, pts) / r_nom
        i = int(np.argmin(ratio))
        row = {
            "nominal_mm": float(r_nom[0] * 1e3),
            "to_site": float(ratio[to_site].min()),
            "branch": float(ratio.min()),
            "at_mm": float(past_mm[i]),
            "radius_min_mm": float(ratio[i] * r_nom[i] * 1e3),
        }
        # meta.json's centreline radii past the ostium (path to the site).
        c = asset.centerlines[b]
        d_ost = np.linalg.norm(c.points - np.asarray(asset.meta["ostia"][b]), axis=1)
        beyond = np.zeros(len(d_ost), dtype=bool)
        beyond[int(np.argmin(d_ost)) :] = True
        nearest = np.argmin(np.linalg.norm(c.points[beyond][:, None] - pts[None], axis=2), axis=1)
        row["meta"] = float((c.radius[beyond] / r_nom[nearest]).min())
        out[b] = row
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--pool-seed", type=int, default=100)
    ap.add_argument("--pool-size", type=int, default=50)
    ap.add_argument("--indices", type=int, nargs="*", help="only these pool indices")
    ap.add_argument("--out", default="/tmp/lumen_radius_pool", help="folder for the built arches")
    ap.add_argument("--assets", nargs="*", help="measure these asset folders or shipped names instead")
    ap.add_argument(
        "--mesher-version",
        type=int,
        choices=MESHER_VERSIONS,
        default=MESHER_VERSION,
        help="lumen mesher version the pool is built with (default: the current one)",
    )
    ap.add_argument("--validate", action="store_true", help="also run validate_asset (holes, intrusion)")
    ap.add_argument("--json", help="write the rows here")
    args = ap.parse_args(argv)

    rows = []
    if args.assets:
        from cathsim_dmc.core.shipped import resolve_asset

        jobs = [(str(a), pathlib.Path(resolve_asset(a)), None) for a in args.assets]
    else:
        idx = args.indices if args.indices else range(args.pool_size)
        jobs = [(str(i), pathlib.Path(args.out) / str(i), pool_params(args.pool_seed, i)) for i in idx]
    for label, folder, params in jobs:
        seconds = None
        if params is not None and not (folder / "meta.json").is_file():
            t0 = time.perf_counter()
            build_asset(params, folder, mesher_version=args.mesher_version)
            seconds = time.perf_counter() - t0
        m = measure(folder)
        meta = json.loads((folder / "meta.json").read_text())
        row = {
            "arch": label,
            "type": meta.get("arch_type"),
            "mesher_version": recorded_mesher_version(meta),
            "seconds": seconds,
            "triangles": meta.get("counts", {}).get("triangles"),
            "edge_mm": meta["params"]["edge_length_m"] * 1e3,
            "branches": m,
        }
        if args.validate:
            from cathsim_dmc.anatomy import validate_asset

            rep = validate_asset(folder)
            row["holes"], row["max_intrusion_mm"], row["ok"] = rep.holes, rep.max_intrusion_m * 1e3, rep.ok
        worst = min(m, key=lambda b: m[b]["branch"])
        print(
            f"{label:>14} {row['type'] or '-':>3} v{row['mesher_version']} "
            + (f"{seconds:5.1f}s " if seconds is not None else "   -   ")
            + f"tri {row['triangles']} | "
            + " | ".join(
                f"{b} r{m[b]['nominal_mm']:.2f} site {m[b]['to_site']:.2f} all {m[b]['branch']:.2f}"
                f" @{m[b]['at_mm']:.0f}mm meta {m[b]['meta']:.2f}"
                for b in BRANCHES
            )
            + f" | worst {worst} {m[worst]['branch']:.2f}"
            + (
                f" | holes {row['holes']} intr {max(row['max_intrusion_mm'], 0):.3f}mm ok {row['ok']}"
                if args.validate
                else ""
            ),
            flush=True,
        )
        rows.append(row)
    if args.json:
        pathlib.Path(args.json).write_text(json.dumps(rows, indent=1))
    times = [r["seconds"] for r in rows if r["seconds"] is not None]
    if times:
        print(
            f"build seconds: median {statistics.median(times):.2f}, mean {statistics.mean(times):.2f}, "
            f"max {max(times):.2f} over {len(times)}"
        )
    worst = sorted(rows, key=lambda r: min(x["branch"] for x in r["branches"].values()))
    print(
        "worst arches (min ratio over the branches): "
        + ", ".join(f"{r['arch']}:{min(x['branch'] for x in r['branches'].values()):.2f}" for r in worst[:12])
    )
    ratios = [min(x["branch"] for x in r["branches"].values()) for r in rows]
    print(
        f"per-arch min ratio over {len(rows)}: min {min(ratios):.2f}, median {statistics.median(ratios):.2f}, "
        f"max {max(ratios):.2f}; below 0.75: {sum(x < 0.75 for x in ratios)}, "
        f"below 0.85: {sum(x < 0.85 for x in ratios)}"
    )


if __name__ == "__main__":
    main()
