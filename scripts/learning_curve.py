"""Plot a cathsim-train run's learning curve from its TensorBoard logs.

    python scripts/learning_curve.py RUN_DIR [RUN_DIR ...] --out curve.png

One line per run: success rate and mean episode return of the last 20 training
episodes, against environment steps.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def scalars(run_dir: Path, tag: str):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    steps, values = [], []
    for events in sorted((run_dir / "tensorboard").glob("*/events.out.tfevents.*")):
        accumulator = EventAccumulator(str(events))
        accumulator.Reload()
        if tag in accumulator.Tags()["scalars"]:
            for event in accumulator.Scalars(tag):
                steps.append(event.step)
                values.append(event.value)
    return steps, values


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", type=Path)
    parser.add_argument("--out", type=Path, default=Path("learning_curve.png"))
    args = parser.parse_args(argv)
    missing = [str(r) for r in args.runs if not list(r.glob("tensorboard/*/events.out.tfevents.*"))]
    if missing:
        print(f"error: no TensorBoard logs in {missing}; pass cathsim-train run folders", file=sys.stderr)
        return 2
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax_s, ax_r) = plt.subplots(1, 2, figsize=(9, 3.2))
    for run in args.runs:
        label = run.name
        ax_s.plot(*scalars(run, "rollout/success_rate"), label=label)
        ax_r.plot(*scalars(run, "rollout/ep_rew_mean"), label=label)
    ax_s.set_ylabel("success rate (last 20 episodes)")
    ax_r.set_ylabel("mean episode return")
    for ax in (ax_s, ax_r):
        ax.set_xlabel("environment steps")
        ax.grid(alpha=0.3)
    ax_s.set_ylim(-0.02, 1.02)
    ax_s.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(args.out, dpi=110)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
