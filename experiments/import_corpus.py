"""Import the segmentation-style corpus (tests/segmentation_corpus.py) with `cathsim-aorta import`,
one command per mesh, and print a Markdown table: triangles in, what the importer did, seconds,
and the validation (holes, intrusion) with the anatomy against the type I arch it came from.

    python experiments/import_corpus.py --out /tmp/corpus        # all variants, 1 mm voxels (~260k triangles)
    python experiments/import_corpus.py --voxel-mm 0.9 --variants noisy   # ~320k triangles
"""

from __future__ import annotations

import argparse
import pathlib
import subprocess
import sys
import time

import numpy as np
import trimesh

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from segmentation_corpus import VARIANTS, make_variant  # noqa: E402

from cathsim_dmc.anatomy import load_asset  # noqa: E402
from cathsim_dmc.model_check import validate_and_compile  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=pathlib.Path, default=pathlib.Path("corpus_import"))
    ap.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    ap.add_argument("--voxel-mm", type=float, default=1.0)
    args = ap.parse_args(argv)
    src = load_asset(ROOT / "assets" / "type1")
    length = lambda a, k: float(np.linalg.norm(np.diff(a.centerlines[k].points, axis=0), axis=1).sum())
    volume = lambda a: trimesh.Trimesh(a.visual_vertices.astype(float), a.visual_faces, process=False).volume
    script = pathlib.Path(sys.executable).with_name("cathsim-aorta")
    vec = lambda p: "[" + ",".join(f"{x:.4f}" for x in p) + "]"
    print("| mesh | triangles in | what the importer did | import s (incl. validation) | holes | max intrusion mm "
          "| centerline length / source | lumen volume / source |")
    print("|---|---|---|---|---|---|---|---|")
    for name in args.variants:
        path, entry, sites = make_variant(name, args.out, voxel_m=args.voxel_mm * 1e-3)
        n_in = len(trimesh.load(path, process=False).faces)
        out = args.out / f"{name}_asset"
        cmd = [str(script), "import", f"mesh={path}", f"entry={vec(entry)}", f"out={out}", "overwrite=true",
               *[f"sites.{k}={vec(p)}" for k, p in sorted(sites.items())]]
        t0 = time.perf_counter()
        proc = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)
        seconds = time.perf_counter() - t0
        if proc.returncode != 0:
            print(f"| {path.name} | {n_in} | failed: {proc.stderr.strip()} | {seconds:.1f} | | | | |")
            continue
        did = [line.split(": ", 2)[-1] if line.startswith("repair:") else line[len("note: "):]
               for line in proc.stdout.splitlines() if line.startswith(("repair:", "note:"))
               and "assuming" not in line and "entry direction" not in line]
        asset = load_asset(out)
        report = validate_and_compile(asset)
        ratios = ", ".join(f"{k} {length(asset, k) / length(src, k):.3f}" for k in sorted(src.sites))
        print(f"| {path.name} | {n_in:,} | {'; '.join(did)} | {seconds:.1f} | {report.holes} | "
              f"{report.max_intrusion_m * 1e3:.3f} | {ratios} | {volume(asset) / volume(src):.3f} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
