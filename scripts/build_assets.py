#!/usr/bin/env python
"""Rebuild the shipped aorta assets deterministically.

    python scripts/build_assets.py            # every preset
    python scripts/build_assets.py type1      # only these

Writes assets/<name>/{meta.json, visual.stl, collision.npz} and prints, per
asset, its triangle and hull counts, build time, arch-type distance and the
centerline length from the entry to each site.
"""

import argparse
import pathlib
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from cathsim_dmc.anatomy import BRANCHES, PRESETS, build_asset  # noqa: E402


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("names", nargs="*", help=f"presets to build (default: all of {sorted(PRESETS)})")
    parser.add_argument("--out", type=pathlib.Path, default=ROOT / "assets", help="output root folder")
    args = parser.parse_args(argv)
    names = args.names or sorted(PRESETS)
    unknown = [n for n in names if n not in PRESETS]
    if unknown:
        print(f"error: unknown asset {', '.join(unknown)}; valid choices: {', '.join(sorted(PRESETS))}",
              file=sys.stderr)
        return 2
    for name in names:
        r = build_asset(PRESETS[name], args.out / name)
        ratio = r.arch_type_distance_m / r.cca_diameter_m
        paths = ", ".join(f"{b} {r.path_length_m[b] * 100:.1f} cm" for b in BRANCHES)
        print(f"{name}: {r.triangles} triangles, {r.hulls} hulls, built in {r.seconds:.1f} s; "
              f"arch-type distance {r.arch_type_distance_m * 1e3:.1f} mm = {ratio:.2f} CCA diameters "
              f"(type {r.arch_type}); entry->site {paths}; -> {r.path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
