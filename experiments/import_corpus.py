"""Import the segmentation-style corpus (cathsim_dmc/anatomy/corpus.py) with `cathsim-aorta import`,
one command per mesh with the default options and the BCA and LCCA as sites (a CFD wall's cap
files too), and print a Markdown table: triangles in, what the importer did, seconds, and the
validation (holes, intrusion) with the anatomy against the type I arch it came from: the
paths' lengths, and the lumen's narrowest depth along them as a share of the source's radius.

    python experiments/import_corpus.py --out /tmp/corpus        # all variants, 1 mm voxels (~260k triangles)
    python experiments/import_corpus.py --voxel-mm 0.9 --variants noisy   # ~320k triangles
    python experiments/import_corpus.py --variants jagged_cap --options crop=none   # the final refusal
"""

from __future__ import annotations

import argparse
import pathlib
import resource
import subprocess
import sys
import time

import numpy as np
import trimesh

from cathsim_dmc.anatomy.corpus import VARIANTS, cap_files, make_variant

ROOT = pathlib.Path(__file__).resolve().parents[1]

from cathsim_dmc.anatomy import load_asset  # noqa: E402
from cathsim_dmc.anatomy.sdf import signed_distance  # noqa: E402
from cathsim_dmc.sim.model_check import validate_and_compile  # noqa: E402

TARGETS = ("bca", "lcca")


def _child_cpu_s() -> float:
    """User + system CPU seconds of the finished child processes: the import's own time, whatever
    else shares the machine (it runs on one core)."""
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=pathlib.Path, default=pathlib.Path("corpus_import"))
    ap.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    ap.add_argument("--voxel-mm", type=float, default=1.0)
    ap.add_argument("--options", nargs="*", default=[], help="more import options, e.g. crop=none")
    args = ap.parse_args(argv)
    src = load_asset(ROOT / "assets" / "type1")
    length = lambda a, k: float(np.linalg.norm(np.diff(a.centerlines[k].points, axis=0), axis=1).sum())

    def kept(a, k):  # the narrowest lumen depth along the source's path / its radius (past the entry's open end)
        points, radius = src.centerlines[k].points, src.centerlines[k].radius
        away = np.linalg.norm(points - points[0], axis=1) > 0.015
        depth = signed_distance(a.visual_vertices.astype(float), a.visual_faces, points[away])
        return float(np.min(depth / radius[away]))

    script = pathlib.Path(sys.executable).with_name("cathsim-aorta")
    vec = lambda p: "[" + ",".join(f"{x:.4f}" for x in p) + "]"
    print(
        "| mesh | triangles in | what the importer did | CPU s (wall s) of the import with validation | holes "
        "| max intrusion mm "
        "| path length / source (bca, lcca) | lumen depth / source radius, narrowest |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for name in args.variants:
        path, entry, sites = make_variant(name, args.out, voxel_m=args.voxel_mm * 1e-3)
        n_in = len(trimesh.load(path, process=False).faces)
        out = args.out / f"{name}_asset"
        cmd = [
            str(script),
            "import",
            f"mesh={path}",
            f"entry={vec(entry)}",
            f"out={out}",
            "overwrite=true",
            *[f"sites.{k}={vec(sites[k])}" for k in TARGETS],
        ]
        cmd += args.options
        caps = cap_files(path)
        if caps:
            cmd.append("caps=[" + ",".join(str(c) for c in caps) + "]")
        t0, cpu0 = time.perf_counter(), _child_cpu_s()
        proc = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)
        seconds, cpu = time.perf_counter() - t0, _child_cpu_s() - cpu0
        if proc.returncode != 0:
            print(f"| {path.name} | {n_in} | failed: {proc.stderr.strip()} | {cpu:.0f} ({seconds:.0f}) | | | | |")
            continue
        did = [
            line.split(": ", 2)[-1] if line.startswith("repair:") else line[len("note: ") :]
            for line in proc.stdout.splitlines()
            if line.startswith(("repair:", "note:")) and "assuming" not in line and "entry direction" not in line
        ]
        asset = load_asset(out)
        report = validate_and_compile(asset)
        ratios = ", ".join(f"{length(asset, k) / length(src, k):.3f}" for k in TARGETS)
        print(
            f"| {path.name} | {n_in:,} | {'; '.join(did)} | {cpu:.0f} ({seconds:.0f}) | {report.holes} | "
            f"{report.max_intrusion_m * 1e3:.3f} | {ratios} | {min(kept(asset, k) for k in TARGETS):.2f} |",
            flush=True,
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
