"""cathsim-forcecheck: are simulated contact forces distributed like measured ones?

    cathsim-forcecheck trajectories=[outputs/eval/bca-type1/<run>/trajectories.npz] reference=measured.csv out=check
    cathsim-forcecheck trajectories=[run1/trajectories.npz,run2/trajectories.npz] mean_n=0.3 std_n=0.1 out=check

The simulated samples are the wall forces of the trajectory files' rows, one per control
step: the total averaged over the step's physics steps (`mean_contact_force_n`; files
written before it existed give their end-of-step `contact_force_n`; see
`cathsim_dmc.evaluation.trajectory.wall_forces_n`). `contact_only=true` keeps the steps with a
contact. The reference is either a CSV of measured forces in newtons (`column` by header
name or 0-based index, else the first column) or a normal distribution the user states
with `mean_n` and `std_n`, sampled with `seed` (`samples` draws, default as many as
simulated). No reference values live in this code: they are the user's measurement.
Options: conf/forcecheck.yaml.

Runs the two-sided Mann-Whitney U test (`scipy.stats.mannwhitneyu`) and writes
forcecheck.json, forcecheck.md and force_cdf.png (empirical CDFs of both) into `out`.
Exit status 0 on success, 2 with one `error:` line on bad input.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np

RESULT_JSON = "forcecheck.json"
RESULT_MD = "forcecheck.md"
CDF_PLOT = "force_cdf.png"


def simulated_forces(paths, contact_only: bool = False) -> np.ndarray:
    """All wall-force samples (`trajectory.wall_forces_n`: step means) of the trajectory files at `paths`."""
    from cathsim_dmc.evaluation.trajectory import load_trajectories, wall_forces_n

    if not paths:
        raise ValueError("no trajectory file given")
    samples = np.concatenate([wall_forces_n(load_trajectories(p)).ravel() for p in paths])
    if contact_only:
        samples = samples[samples > 0.0]
    if samples.size == 0:
        raise ValueError("the trajectory files hold no force samples" + (" with contact" if contact_only else ""))
    return _finite(samples, "simulated forces")


def measured_forces(csv_path, column: str | None = None) -> np.ndarray:
    """One column of a CSV of measured forces (newtons); a non-numeric first row is a header."""
    path = Path(csv_path)
    if not path.is_file():
        raise FileNotFoundError(f"no reference CSV at {path}")
    rows = [row for row in csv.reader(path.read_text().splitlines()) if any(cell.strip() for cell in row)]
    if not rows:
        raise ValueError(f"{path} is empty")
    header = None
    try:
        [float(cell) for cell in rows[0] if cell.strip()]
    except ValueError:
        header, rows = [cell.strip() for cell in rows[0]], rows[1:]
    index = 0
    if column is not None:
        if header is not None and column in header:
            index = header.index(column)
        elif column.isdigit():
            index = int(column)
        else:
            raise ValueError(f"{path} has no column {column!r}" + (f"; columns: {header}" if header else ""))
    try:
        values = np.asarray([float(row[index]) for row in rows if len(row) > index and row[index].strip()])
    except ValueError as error:
        raise ValueError(f"{path} column {index}: {error}") from None
    if values.size == 0:
        raise ValueError(f"{path} holds no force values in column {index}")
    return _finite(values, str(path))


def normal_reference(mean_n: float, std_n: float, count: int, seed: int) -> np.ndarray:
    """`count` draws from Normal(mean_n, std_n), the user's summary of a measurement."""
    if not np.isfinite(mean_n) or not np.isfinite(std_n) or std_n <= 0:
        raise ValueError(f"std_n={std_n!r} must be positive, and mean_n={mean_n!r} and std_n finite")
    if count < 1:
        raise ValueError(f"samples={count!r} must be at least 1")
    return np.random.default_rng(seed).normal(mean_n, std_n, size=count)


def _finite(values, what):
    if not np.isfinite(values).all():
        raise ValueError(f"{what} contain non-finite values")
    return values


def mann_whitney(simulated, reference) -> dict:
    """Two-sided Mann-Whitney U test with the summaries the report shows."""
    from scipy.stats import mannwhitneyu

    result = mannwhitneyu(simulated, reference, alternative="two-sided")
    summary = lambda x: {
        "n": int(x.size),
        "mean_n": float(np.mean(x)),
        "median_n": float(np.median(x)),
        "std_n": float(np.std(x, ddof=1)) if x.size > 1 else 0.0,
    }
    return {
        "test": "Mann-Whitney U, two-sided",
        "u_statistic": float(result.statistic),
        "p_value": float(result.pvalue),
        # P(simulated > reference) + P(equal)/2: 0.5 when neither tends to be larger.
        "common_language_effect": float(result.statistic) / (simulated.size * reference.size),
        "simulated": summary(simulated),
        "reference": summary(reference),
    }


def markdown(result: dict, alpha: float) -> str:
    s, r = result["simulated"], result["reference"]
    verdict = ("not distinguishable" if result["p_value"] >= alpha else "different") + f" at alpha = {alpha:g}"
    lines = [
        f"{result['test']}: U = {result['u_statistic']:.6g}, p = {result['p_value']:.4g} ({verdict}); "
        f"P(sim > ref) = {result['common_language_effect']:.3f}",
        f"Reference: {result['reference_source']}",
        "",
        "| Samples | n | mean (N) | median (N) | std (N) |",
        "|---|---|---|---|---|",
        f"| Simulated | {s['n']} | {s['mean_n']:.4f} | {s['median_n']:.4f} | {s['std_n']:.4f} |",
        f"| Reference | {r['n']} | {r['mean_n']:.4f} | {r['median_n']:.4f} | {r['std_n']:.4f} |",
    ]
    return "\n".join(lines) + "\n"


def cdf_plot(simulated, reference, out_path, title: str = "") -> Path:
    from cathsim_dmc.evaluation.plots import _pyplot

    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(5, 3.5))
    for values, label, colour in ((simulated, "simulated", "tab:blue"), (reference, "reference", "tab:orange")):
        x = np.sort(values)
        ax.step(x, np.arange(1, x.size + 1) / x.size, where="post", label=f"{label} (n={x.size})", color=colour)
    ax.set_xlabel("contact force (N)")
    ax.set_ylabel("cumulative probability")
    ax.set_ylim(0, 1.02)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="lower right")
    ax.set_title(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(out_path, dpi=110)
    plt.close(fig)
    return Path(out_path)


def force_check(
    trajectories,
    out_dir,
    reference_csv=None,
    column=None,
    mean_n=None,
    std_n=None,
    samples=None,
    seed: int = 0,
    contact_only: bool = False,
    alpha: float = 0.05,
) -> dict:
    """Compare the trajectories' forces with the reference; write the report into `out_dir`."""
    if (reference_csv is None) == (mean_n is None and std_n is None):
        raise ValueError("give the reference as reference=<CSV> or as mean_n= and std_n= (one of the two)")
    simulated = simulated_forces(trajectories, contact_only)
    if reference_csv is not None:
        reference = measured_forces(reference_csv, column)
        source = f"measured, {reference_csv}" + (f" column {column}" if column is not None else "")
    else:
        if mean_n is None or std_n is None:
            raise ValueError("a normal reference needs both mean_n= and std_n=")
        count = simulated.size if samples is None else int(samples)
        reference = normal_reference(float(mean_n), float(std_n), count, seed)
        source = f"normal, mean {mean_n:g} N, std {std_n:g} N, {count} draws, seed {seed}"
    result = mann_whitney(simulated, reference)
    result.update(
        reference_source=source, alpha=alpha, contact_only=contact_only, trajectories=[str(p) for p in trajectories]
    )
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / RESULT_JSON).write_text(json.dumps(result, indent=2))
    (out_dir / RESULT_MD).write_text(markdown(result, alpha))
    cdf_plot(
        simulated,
        reference,
        out_dir / CDF_PLOT,
        f"Mann-Whitney U = {result['u_statistic']:.4g}, p = {result['p_value']:.3g}",
    )
    return result


def run(cfg) -> dict:
    from omegaconf import OmegaConf

    from cathsim_dmc.core.checks import check_number

    if OmegaConf.is_missing(cfg, "trajectories"):
        raise ValueError("trajectories= is required: one trajectories.npz or a [list] of them")
    files = cfg.trajectories if OmegaConf.is_list(cfg.trajectories) else [cfg.trajectories]
    numbers = {
        key: None if cfg[key] is None else check_number(key, cfg[key], 0.0) for key in ("mean_n", "std_n", "alpha")
    }
    samples = None if cfg.samples is None else check_number("samples", cfg.samples, 1, whole=True)
    seed = check_number("seed", cfg.seed, 0, whole=True)
    out = Path(str(cfg.out))
    try:
        result = force_check(
            [Path(str(f)) for f in files],
            out,
            None if cfg.reference is None else Path(cfg.reference),
            cfg.column,
            numbers["mean_n"],
            numbers["std_n"],
            samples,
            seed,
            bool(cfg.contact_only),
            numbers["alpha"],
        )
    except KeyError as error:  # a CSV column that is not there
        raise ValueError(str(error).strip("'\"")) from None
    print((out / RESULT_MD).read_text(), end="")
    print(f"results in {out}")
    return result


def main():
    from cathsim_dmc.app.cli._common import run_hydra

    run_hydra(run, "forcecheck")


if __name__ == "__main__":
    main()
