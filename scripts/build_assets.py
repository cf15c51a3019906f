#!/usr/bin/env python
"""Rebuild the shipped aorta assets deterministically.

    python scripts/build_assets.py                 # every preset
    python scripts/build_assets.py type1 bovine    # only these
    python scripts/build_assets.py --check         # rebuild into a temp dir, compare byte for byte
    python scripts/build_assets.py --validate      # also run the geometric validation and the MuJoCo compile

Writes assets/<name>/{meta.json, visual.stl, collision.npz} and prints, per
asset, its arch-type distance (mm and CCA diameters, with the clinical class),
tortuosity (path/chord of the arch and mean of the branches), triangle and hull
counts, build time, folder size, the centerline length from the entry to
each site and the arch's obliquity (the BCA-LSA ostia line's angle with the
coronal plane, with the `arch_rotation_deg` that turned it).
"""

import argparse
import pathlib
import sys
import tempfile

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from cathsim_dmc.anatomy import BRANCHES, PRESETS, build_asset  # noqa: E402

FILES = ("meta.json", "visual.stl", "collision.npz")


def folder_size(path: pathlib.Path) -> int:
    return sum((path / f).stat().st_size for f in FILES)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("names", nargs="*", help=f"presets to build (default: all of {list(PRESETS)})")
    parser.add_argument("--out", type=pathlib.Path, default=ROOT / "assets", help="output root folder")
    parser.add_argument("--check", action="store_true",
                        help="build into a temporary folder and compare with the assets under --out")
    parser.add_argument("--validate", action="store_true",
                        help="run cathsim_dmc.model_check.validate_and_compile on each build")
    args = parser.parse_args(argv)
    names = args.names or list(PRESETS)
    unknown = [n for n in names if n not in PRESETS]
    if unknown:
        print(f"error: unknown asset {', '.join(unknown)}; valid choices: {', '.join(PRESETS)}", file=sys.stderr)
        return 2
    tmp = tempfile.TemporaryDirectory() if args.check else None
    root = pathlib.Path(tmp.name) if tmp else args.out
    status = 0
    print(f"{'name':<15} {'arch-type distance':<27} {'tort. arch/branch':<18} {'triangles':>9} {'hulls':>6} "
          f"{'build':>6} {'size':>8}")
    for name in names:
        r = build_asset(PRESETS[name], root / name)
        t = r.tortuosity
        dist = f"{r.arch_type_distance_m * 1e3:4.1f} mm = {r.arch_type_ratio:.2f} CCA (type {r.arch_type})"
        print(f"{name:<15} {dist:<27} {t['arch']:.3f} / {t['branches']:.4f}   {r.triangles:>9} {r.hulls:>6} "
              f"{r.seconds:5.1f}s {folder_size(r.path) / 1e6:6.2f}MB")
        paths = ", ".join(f"{b} {r.path_length_m[b] * 100:.1f} cm" for b in BRANCHES)
        extra = f"; max aortic diameter {r.max_aortic_diameter_m * 1e3:.1f} mm" if PRESETS[name].aneurysm_diameter_m else ""
        extra += (f"; obliquity (BCA-LSA ostia line from the coronal plane) {r.obliquity_deg:.1f} deg"
                  f" (arch_rotation_deg {PRESETS[name].arch_rotation_deg:g})")
        print(f"{'':<15} entry->site {paths}{extra}; -> {r.path}")
        if args.check:
            same = [(args.out / name / f).is_file() and (args.out / name / f).read_bytes() == (r.path / f).read_bytes()
                    for f in FILES]
            print(f"{'':<15} {'identical to ' + str(args.out / name) if all(same) else 'DIFFERS from ' + str(args.out / name)}")
            status |= 0 if all(same) else 1
        if args.validate:
            from cathsim_dmc.model_check import validate_and_compile

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
