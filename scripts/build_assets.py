#!/usr/bin/env python
"""Rebuild the shipped aorta assets deterministically.

    python scripts/build_assets.py                 # every preset
    python scripts/build_assets.py type1 bovine    # only these
    python scripts/build_assets.py --check         # rebuild into a temp dir and compare
    python scripts/build_assets.py --validate      # also run the geometric validation and the MuJoCo compile

Writes assets/<name>/{meta.json, visual.stl, collision.npz} and prints, per
asset, its arch-type distance (mm and CCA diameters, with the clinical class),
tortuosity (path/chord of the arch and mean of the branches), triangle and hull
counts, build time, folder size, the centerline length from the entry to
each site and the arch's obliquity (the BCA-LSA ostia line's angle with the
coronal plane, with the `arch_rotation_deg` that turned it).

Each preset is meshed at its pinned lumen mesher version (`SHIPPED_MESHER_VERSIONS` in
cathsim_dmc/anatomy/asset.py, which says why), any other at the current one.
"""

import argparse
import pathlib
import sys
import tempfile

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from cathsim_dmc.anatomy import BRANCHES, PRESETS, build_asset  # noqa: E402
from cathsim_dmc.anatomy.asset import SHIPPED_MESHER_VERSIONS  # noqa: E402

FILES = ("meta.json", "visual.stl", "collision.npz")
# Coordinates may differ in their last float32 bits between machines (the CPU's vectorised
# paths or library versions; assets/bovine rebuilds 0.07 micrometres off on the 2026-11-25
# machines, type1 exactly), so --check accepts coordinates this close; everything else
# must match exactly.
ROUNDING_TOLERANCE_M = 1e-6
NORMAL_TOLERANCE = 1e-4  # a tiny facet's normal carries its vertices' rounding, magnified


def _stl_triangles(path: pathlib.Path):
    """(normals and vertices as float32 (N, 12), attributes) of a binary STL."""
    import numpy as np

    raw = path.read_bytes()
    count = int(np.frombuffer(raw, np.uint32, 1, 80)[0])
    records = np.frombuffer(raw, np.dtype([("xyz", "<f4", 12), ("attr", "<u2")]), count, 84)
    return records["xyz"], records["attr"]


def compare(shipped: pathlib.Path, rebuilt: pathlib.Path) -> tuple[bool, float]:
    """(same, largest coordinate difference in metres): byte-identical, or equal apart from
    coordinates within ROUNDING_TOLERANCE_M."""
    import numpy as np

    largest = 0.0
    for name in FILES:
        a, b = shipped / name, rebuilt / name
        if not a.is_file():
            return False, float("inf")
        if a.read_bytes() == b.read_bytes():
            continue
        if name == "visual.stl":
            (xa, attr_a), (xb, attr_b) = _stl_triangles(a), _stl_triangles(b)
            if xa.shape != xb.shape or np.abs(xa[:, :3] - xb[:, :3]).max(initial=0.0) > NORMAL_TOLERANCE:
                return False, float("inf")  # facet normals: unit vectors, not metres
            pairs, exact = [(xa[:, 3:], xb[:, 3:])], [(attr_a, attr_b)]
        elif name == "collision.npz":
            with np.load(a) as za, np.load(b) as zb:
                if sorted(za.files) != sorted(zb.files):
                    return False, float("inf")
                arrays = [(za[k], zb[k]) for k in za.files]
            pairs = [(x, y) for x, y in arrays if x.dtype.kind == "f"]
            exact = [(x, y) for x, y in arrays if x.dtype.kind != "f"]
        else:
            return False, float("inf")
        if any(x.shape != y.shape or not np.array_equal(x, y) for x, y in exact):
            return False, float("inf")
        for x, y in pairs:
            if x.shape != y.shape:
                return False, float("inf")
            largest = max(largest, float(np.abs(x.astype(np.float64) - y).max(initial=0.0)))
    return largest <= ROUNDING_TOLERANCE_M, largest


def folder_size(path: pathlib.Path) -> int:
    return sum((path / f).stat().st_size for f in FILES)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("names", nargs="*", help=f"presets to build (default: all of {list(PRESETS)})")
    parser.add_argument("--out", type=pathlib.Path, default=ROOT / "assets", help="output root folder")
    parser.add_argument(
        "--check", action="store_true", help="build into a temporary folder and compare with the assets under --out"
    )
    parser.add_argument(
        "--validate", action="store_true", help="run cathsim_dmc.sim.model_check.validate_and_compile on each build"
    )
    args = parser.parse_args(argv)
    names = args.names or list(PRESETS)
    unknown = [n for n in names if n not in PRESETS]
    if unknown:
        print(f"error: unknown asset {', '.join(unknown)}; valid choices: {', '.join(PRESETS)}", file=sys.stderr)
        return 2
    tmp = tempfile.TemporaryDirectory() if args.check else None
    root = pathlib.Path(tmp.name) if tmp else args.out
    status = 0
    print(
        f"{'name':<15} {'arch-type distance':<27} {'tort. arch/branch':<18} {'triangles':>9} {'hulls':>6} "
        f"{'build':>6} {'size':>8}"
    )
    for name in names:
        r = build_asset(PRESETS[name], root / name, mesher_version=SHIPPED_MESHER_VERSIONS.get(name))
        t = r.tortuosity
        dist = f"{r.arch_type_distance_m * 1e3:4.1f} mm = {r.arch_type_ratio:.2f} CCA (type {r.arch_type})"
        print(
            f"{name:<15} {dist:<27} {t['arch']:.3f} / {t['branches']:.4f}   {r.triangles:>9} {r.hulls:>6} "
            f"{r.seconds:5.1f}s {folder_size(r.path) / 1e6:6.2f}MB"
        )
        paths = ", ".join(f"{b} {r.path_length_m[b] * 100:.1f} cm" for b in BRANCHES)
        extra = (
            f"; max aortic diameter {r.max_aortic_diameter_m * 1e3:.1f} mm" if PRESETS[name].aneurysm_diameter_m else ""
        )
        extra += (
            f"; obliquity (BCA-LSA ostia line from the coronal plane) {r.obliquity_deg:.1f} deg"
            f" (arch_rotation_deg {PRESETS[name].arch_rotation_deg:g})"
        )
        print(f"{'':<15} entry->site {paths}{extra}; mesher version {r.mesher_version}; -> {r.path}")
        if args.check:
            same, largest = compare(args.out / name, r.path)
            if not same:
                verdict = "DIFFERS from"
            elif largest == 0.0:
                verdict = "identical to"
            else:
                verdict = f"equal (coordinates within {largest * 1e6:.2f} micrometres: float rounding) to"
            print(f"{'':<15} {verdict} {args.out / name}")
            status |= 0 if same else 1
        if args.validate:
            from cathsim_dmc.sim.model_check import validate_and_compile

            report = validate_and_compile(r.path)
            print(f"{'':<15} {report.summary()}")
            for problem in report.problems:
                print(f"{'':<17}- {problem}")
            status |= 0 if report.ok else 1
    if tmp:
        tmp.cleanup()
    return status


if __name__ == "__main__":
    sys.exit(main())
