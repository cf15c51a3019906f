"""Import the close-ostia corpus class (cathsim_dmc/anatomy/corpus.py, `CLOSE_OSTIA_VARIANTS`) with
`cathsim-aorta import` and sites=auto, one command per mesh and option set, and print a Markdown
table: wall and CPU seconds, the answer (OK or the one line), the remedies that ran, the thinnest
septum the wall was thinned at, and how far the found BCA and LCCA sites lie from the generator's.

    python experiments/import_close_ostia.py --out /tmp/close            # defaults
    python experiments/import_close_ostia.py --options sdf_mm=0.4 --options "edge_mm=1.5 sdf_mm=0.4"
"""

from __future__ import annotations

import argparse
import json
import pathlib
import re
import resource
import subprocess
import sys
import time

import numpy as np

from cathsim_dmc.anatomy.corpus import CLOSE_OSTIA_VARIANTS, make_variant


def _child_cpu_s() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=pathlib.Path, default=pathlib.Path("/tmp/close_ostia"))
    ap.add_argument("--variants", nargs="+", default=list(CLOSE_OSTIA_VARIANTS), choices=CLOSE_OSTIA_VARIANTS)
    ap.add_argument("--options", action="append", default=None, help="an option set (repeatable); '' = defaults")
    args = ap.parse_args(argv)
    option_sets = args.options or [""]
    script = pathlib.Path(sys.executable).with_name("cathsim-aorta")
    rows = []
    for name in args.variants:
        path, _, sites = make_variant(name, args.out / "meshes")
        for options in option_sets:
            out = args.out / (name + ("_" + re.sub(r"\W+", "_", options) if options else ""))
            cpu0, t0 = _child_cpu_s(), time.perf_counter()
            proc = subprocess.run(
                [str(script), "import", f"mesh={path}", f"out={out}", "overwrite=true", *options.split()],
                capture_output=True,
                text=True,
            )
            wall, cpu = time.perf_counter() - t0, _child_cpu_s() - cpu0
            remedies = [
                line.split("survived local repair: ", 1)[1]
                for line in proc.stdout.splitlines()
                if line.startswith("note: a fold at ")
            ]
            septum = re.search(r"meet another lumen ([\d.]+)-", proc.stdout)
            answer = "OK" if proc.returncode == 0 else proc.stderr.strip().splitlines()[-1]
            off = ""
            if proc.returncode == 0:
                meta = json.loads((out / "meta.json").read_text())
                off = ", ".join(
                    f"{k} {np.linalg.norm(np.array(meta['sites'][k]) * 1e3 - sites[k]):.1f}" for k in ("bca", "lcca")
                )
            rows.append(
                f"| {name} | {options or 'defaults'} | {wall:.0f} | {cpu:.0f} | {answer} | "
                f"{'; '.join(remedies) or 'none'} | {septum.group(1) + ' mm' if septum else 'none'} | {off} |"
            )
            print(rows[-1], flush=True)
    print("\n| mesh | options | wall s | CPU s | answer | fold remedies | thinnest septum | found sites off (mm) |")
    print("|---|---|---|---|---|---|---|---|")
    print("\n".join(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
