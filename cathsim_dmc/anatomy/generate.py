"""Generated anatomy on demand: cached asset folders and a parameter sampler.

    from cathsim_dmc.anatomy import generated_asset, sample_arch_params
    params = sample_arch_params(7)                  # a random arch (documented below)
    folder = generated_asset(params)                # built once (~4 s), then cached
    Aorta(asset=folder)

Cache: ``generated_asset`` writes each parameter set into
``<cache root>/<hash>``, where the hash covers every parameter, the asset
format version and `GENERATOR_VERSION`, and the cache root is, in order of
precedence, the `cache_dir` argument, ``$CATHSIM_DMC_CACHE/aortas``, or
``${XDG_CACHE_HOME:-~/.cache}/cathsim_dmc/aortas``. A build goes into a
temporary folder next to its final place and is renamed into place in one
step, so concurrent processes never see half an asset: the first rename wins
and the others drop their copy.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
import pathlib
import shutil
import tempfile
from typing import Mapping, Optional, Sequence, Tuple, Union

import numpy as np

from cathsim_dmc.anatomy.arch import build_arch
from cathsim_dmc.anatomy.asset import FORMAT_VERSION, META_FILE, params_record
from cathsim_dmc.anatomy.parameters import (
    ARCH_OBLIQUITY_DEG,
    ARCH_TYPE_ELONGATION,
    ARCH_TYPE_RATIO_RANGE,
    ARCH_TYPES,
    BRANCHES,
    ArchParams,
    normalize_arch_type,
)
from cathsim_dmc.anatomy.presets import PRESETS

# Bump when the pipeline's output for the same parameters changes (invalidates caches),
# e.g. with lumen.MESHER_VERSION, which generated arches are built at. 2: mesher version 2
# (narrow branches no longer pinched); the version-1 arches cached before stay unused.
GENERATOR_VERSION = 2
CACHE_ENV = "CATHSIM_DMC_CACHE"
# A parameter set whose lumen folds at every edge length is remembered in the cache as
# <hash><UNMESHABLE_SUFFIX>, so that the next request fails at once instead of meshing again.
UNMESHABLE_SUFFIX = ".unmeshable"

_DIAMETER_FIELDS = (
    "ascending_diameter_m",
    "proximal_arch_diameter_m",
    "distal_arch_diameter_m",
    "isthmus_diameter_m",
    "descending_diameter_m",
    "bca_diameter_m",
    "lcca_diameter_m",
    "lsa_diameter_m",
)


def arch_params(params: Union[ArchParams, Mapping, str]) -> ArchParams:
    """An `ArchParams` from itself, a preset name, or a mapping of field values.

    A mapping may hold any subset of the fields (the others keep their
    defaults) plus ``preset: <name>`` to start from a shipped preset. Unknown
    keys and badly typed values raise ValueError naming them.
    """
    if isinstance(params, ArchParams):
        params.validate()
        return params
    if isinstance(params, str):
        if params not in PRESETS:
            raise ValueError(f"preset={params!r} is not valid; choose one of {list(PRESETS)}")
        return PRESETS[params]
    if not isinstance(params, Mapping):
        raise ValueError(f"arch parameters must be ArchParams, a preset name or a mapping, got {type(params).__name__}")
    values = dict(params)
    base = arch_params(str(values.pop("preset"))) if "preset" in values else ArchParams()
    fields = {f.name: f for f in dataclasses.fields(ArchParams)}
    unknown = sorted(set(values) - set(fields))
    if unknown:
        raise ValueError(f"unknown arch parameter(s) {unknown}; valid ones: {sorted(fields)}")
    typed = {}
    for key, value in values.items():
        kind = type(getattr(base, key))
        if key == "arch_type":
            typed[key] = normalize_arch_type(value)
            continue
        try:
            if kind is bool:
                if isinstance(value, (bool, np.bool_)):
                    typed[key] = bool(value)
                elif str(value).lower() in ("true", "false"):
                    typed[key] = str(value).lower() == "true"
                else:
                    raise ValueError
            elif kind is int:
                if float(value) != int(float(value)):
                    raise ValueError
                typed[key] = int(float(value))
            elif kind is float:
                typed[key] = float(value)
                if not math.isfinite(typed[key]):
                    raise ValueError
            else:
                typed[key] = kind(value)
        except (TypeError, ValueError):
            raise ValueError(f"arch parameter {key}={value!r} is not a valid {kind.__name__}") from None
    out = base.replace(**typed)
    out.validate()
    return out


def params_hash(params: ArchParams) -> str:
    """Stable 16-hex-digit hash of every parameter (plus the format and generator versions)."""
    payload = json.dumps(
        {"params": params_record(params), "format_version": FORMAT_VERSION, "generator_version": GENERATOR_VERSION},
        sort_keys=True,
        allow_nan=False,
    )
    return hashlib.sha256(payload.encode()).hexdigest()[:16]


def cache_root(cache_dir=None) -> pathlib.Path:
    """Folder holding the cached generated assets (see the module docstring)."""
    if cache_dir is not None:
        return pathlib.Path(cache_dir).expanduser()
    env = os.environ.get(CACHE_ENV)
    if env:
        return pathlib.Path(env).expanduser() / "aortas"
    xdg = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return pathlib.Path(xdg) / "cathsim_dmc" / "aortas"


def generated_asset(params: Union[ArchParams, Mapping, str], cache_dir=None) -> pathlib.Path:
    """The asset folder for `params`: built on first use into the cache, returned from it afterwards.

    `params`: `ArchParams`, a mapping of fields (see `arch_params`) or a preset
    name. Returns the folder path; raise ValueError on bad parameters.
    """
    from cathsim_dmc.anatomy.asset import build_asset
    from cathsim_dmc.anatomy.lumen import FoldedSurfaceError

    p = arch_params(params)
    root = cache_root(cache_dir)
    final = root / params_hash(p)
    if (final / META_FILE).is_file():
        return final
    unmeshable = root / f"{final.name}{UNMESHABLE_SUFFIX}"
    if unmeshable.is_file():  # meshed before, and it folded at every edge length: fail fast
        raise FoldedSurfaceError(unmeshable.read_text())
    root.mkdir(parents=True, exist_ok=True)
    tmp = pathlib.Path(tempfile.mkdtemp(prefix=f".{final.name}.", suffix=".tmp", dir=root))
    try:
        try:
            build_asset(p, tmp)
        except FoldedSurfaceError as error:
            unmeshable.write_text(str(error))
            raise
        os.chmod(tmp, 0o755)
        try:
            os.rename(tmp, final)
        except OSError:
            # Another process finished first (the target exists and is not empty): use its copy.
            if not (final / META_FILE).is_file():
                raise
            shutil.rmtree(tmp, ignore_errors=True)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return final


# ----------------------------------------------------------------------------
# Sampling


def _rng_uniform(rng, lo, hi):
    return float(rng.uniform(lo, hi))


def _rng_int(rng, hi):
    return int(rng.integers(0, hi)) if isinstance(rng, np.random.Generator) else int(rng.randint(0, hi))


# The sampler's distributions: "morphometry" varies the arch as published morphometry of
# patients' arches reports (`MORPHOMETRY`); "fixed_branches" is the distribution before
# 2026-12-02, whose branches always leave the arch the same way (its pools are unchanged).
DISTRIBUTIONS = ("morphometry", "fixed_branches")


@dataclasses.dataclass(frozen=True)
class Morphometry:
    """The "morphometry" distribution's figures (docs/anatomy.md#random-arches gives the sources).

    Normal draws are (mean, sd) clipped to mean +- `clip_sd` sd unless a range is given.
    """

    # Branching variant: the BCA and LCCA from a common origin or the LCCA from the BCA
    # (the "bovine" arch, 13.6% of 23,882 arches in a meta-analysis, 15% and 15.5% in two
    # large angiographic series; about half each of common origin and origin from the
    # BCA). A common origin is a trunk shorter than `short_trunk_m`, an LCCA from the BCA
    # one of `long_trunk_m` (a modelling choice: no series reports the trunk's length).
    bovine_fraction: float = 0.15
    short_trunk_m: Tuple[float, float] = (0.0, 0.003)
    long_trunk_m: Tuple[float, float] = (0.005, 0.010)
    # Wall-to-wall gaps between the ostia on CTA of 217 normal arches (Yan et al.), m;
    # clipped at 0 (touching ostia).
    bca_lcca_gap_m: Tuple[float, float] = (0.00439, 0.00249)
    lcca_lsa_gap_m: Tuple[float, float] = (0.00643, 0.00398)
    # Ostium diameters on the same CTA series, relative spread (sd / mean): BCA 12.50 +- 1.95,
    # LCCA 8.28 +- 1.51, LSA 10.41 +- 2.20 mm; ascending aorta 34.56 +- 4.72 mm.
    branch_diameter_cv: Tuple[float, float, float] = (0.156, 0.182, 0.211)
    ascending_diameter_cv: float = 0.137
    # Take-off: the branch's lean from the wall normal, sd of the branch angles on CT of 118
    # arches (BCA 15.9, LCCA 15.5, LSA 14.5 degrees), centred on the normal.
    takeoff_sd_deg: Tuple[float, float, float] = (15.9, 15.5, 14.5)
    # Ostia off the top of the outer curvature (modelling choice), degrees.
    roll_sd_deg: float = 10.0
    # Final headings: the base's, +- this sd (modelling choice), degrees.
    heading_sd_deg: float = 10.0
    # Bend from take-off to heading, m (modelling choice).
    bend_length_m: Tuple[float, float] = (0.012, 0.030)
    # Branch tortuosity: the distance metric of the common carotid is 1.1 +- 0.1 below 60
    # years and 1.2 +- 0.2 above; a sinusoid of amplitude A and wavelength L adds about
    # (pi A / L)^2, so these give 1.0-1.2.
    branch_tortuosity_amplitude_m: Tuple[float, float] = (0.0, 0.003)
    branch_tortuosity_wavelength_m: Tuple[float, float] = (0.020, 0.040)
    # Ascending aorta below the arch, m (modelling choice around the base's 40 mm; it ends
    # closed and holds no target).
    ascending_length_m: Tuple[float, float] = (0.030, 0.060)
    clip_sd: float = 2.0


MORPHOMETRY = Morphometry()
# Tries to draw a branch layout that fits on the arch (`build_arch` raises when the gaps
# leave no room) before the sampler gives up.
_LAYOUT_TRIES = 20


# Neighbouring branches must have parted by the lumen's blend width (`blend_radius_m`,
# wall to wall) from `_PARTED_BY_M` past their ostia (past the trunk of a bovine pair) on:
# closer, the smooth union webs them together, and the crease of the web folded the mesh
# at every edge length tried (2 of the first 22 held-out arches, with 2.0 and 3.5 mm); real
# neighbouring branches part at the carina.
_PARTED_BY_M = 0.012


def branch_clearance_m(model) -> float:
    """The smallest wall-to-wall distance, m, between neighbouring branches (BCA-LCCA,
    LCCA-LSA) from `_PARTED_BY_M` past their ostia on (past the common trunk of a bovine
    BCA and LCCA)."""
    p = model.params
    out = math.inf
    for a, b in (("bca", "lcca"), ("lcca", "lsa")):
        trunk = p.bovine_trunk_length_m + p.branch_bend_length_m if p.bovine and a == "bca" else 0.0
        keep = {}
        for name in (a, b):
            v = model.branches[name]
            start = float(np.linalg.norm(model.ostia[name] - v.points[0])) + _PARTED_BY_M + trunk
            mask = v.arclength >= start
            keep[name] = (v.points[mask], v.radius[mask])
        (pa, ra), (pb, rb) = keep[a], keep[b]
        if len(pa) and len(pb):
            gap = np.linalg.norm(pa[:, None] - pb[None], axis=-1) - ra[:, None] - rb[None]
            out = min(out, float(gap.min()))
    return out


def _clipped_normal(rng, mean, sd, clip_sd, lo=-math.inf):
    """A normal draw clipped to clip_sd standard deviations, and to at least `lo`."""
    value = float(np.clip(rng.normal(mean, sd), mean - clip_sd * sd, mean + clip_sd * sd))
    return max(value, lo)


def _morphometry_sizes(rng, params: ArchParams, m: Morphometry = MORPHOMETRY) -> dict:
    """The "morphometry" fields drawn once per arch (see `sample_arch_params`): the branching
    variant, the gaps between the ostia, the diameters and the ascending aorta."""
    um = lambda x: round(float(x), 7)
    c = m.clip_sd
    drop_ratio = params.bca_origin_drop_m / params.lcca_diameter_m  # the arch type's measure
    # A bovine base (base=bovine) keeps its variant: every arch drawn is bovine.
    bovine = bool(rng.uniform() < m.bovine_fraction) or params.bovine
    trunk = m.short_trunk_m if rng.uniform() < 0.5 else m.long_trunk_m
    out = {"bovine": bovine}
    if bovine:
        out["bovine_trunk_length_m"] = um(rng.uniform(*trunk))
    out["bca_lcca_gap_m"] = um(_clipped_normal(rng, *m.bca_lcca_gap_m, c, lo=0.0))
    out["lcca_lsa_gap_m"] = um(_clipped_normal(rng, *m.lcca_lsa_gap_m, c, lo=0.0))
    for b, cv in zip(BRANCHES, m.branch_diameter_cv):
        out[f"{b}_diameter_m"] = um(params.branch_diameter_m(b) * _clipped_normal(rng, 1.0, cv, c, lo=0.6))
    ascending_scale = _clipped_normal(rng, 1.0, m.ascending_diameter_cv, c)
    out["ascending_diameter_m"] = um(params.ascending_diameter_m * ascending_scale)
    out["ascending_length_m"] = um(rng.uniform(*m.ascending_length_m))
    out["bca_origin_drop_m"] = um(drop_ratio * out["lcca_diameter_m"])
    # The mesher's base edge must stay below the narrowest branch (ArchParams.validate).
    narrowest = min(out[f"{b}_diameter_m"] for b in BRANCHES)
    if params.edge_length_m > narrowest:
        out["edge_length_m"] = math.floor(narrowest * 1e4) / 1e4
    return out


def _morphometry_directions(rng, params: ArchParams, m: Morphometry = MORPHOMETRY) -> dict:
    """The "morphometry" fields redrawn until neighbouring branches part (see
    `sample_arch_params`): each branch's take-off, origin roll and heading, the bend and the
    branch tortuosity."""
    um = lambda x: round(float(x), 7)
    c = m.clip_sd
    out = {}
    for b, sd in zip(BRANCHES, m.takeoff_sd_deg):
        out[f"{b}_takeoff_deg"] = round(_clipped_normal(rng, 0.0, sd, c), 3)
        out[f"{b}_roll_deg"] = round(_clipped_normal(rng, 0.0, m.roll_sd_deg, c), 3)
        heading = params.branch_angle_deg(b)
        if params.bovine:
            # The two carotid lumens of a bovine trunk part as the shipped bovine arch's do.
            heading = {"bca": -40.0, "lcca": 20.0}.get(b, heading)
        out[f"{b}_angle_deg"] = round(_clipped_normal(rng, heading, m.heading_sd_deg, c), 3)
    out["branch_bend_length_m"] = um(rng.uniform(*m.bend_length_m))
    out["branch_tortuosity_amplitude_m"] = um(rng.uniform(*m.branch_tortuosity_amplitude_m))
    out["branch_tortuosity_wavelength_m"] = um(rng.uniform(*m.branch_tortuosity_wavelength_m))
    return out


def _morphometry_draw(rng, params: ArchParams, name: str) -> ArchParams:
    """`params` with the "morphometry" fields drawn: the sizes once, the directions until
    the branches part by the blend width (`branch_clearance_m`); sizes that leave no room on
    the arch are drawn again."""
    for _ in range(_LAYOUT_TRIES):
        sized = params.replace(**_morphometry_sizes(rng, params))
        for _ in range(_LAYOUT_TRIES):
            drawn = sized.replace(**_morphometry_directions(rng, sized))
            try:
                drawn.validate()
                model = build_arch(drawn)
            except ValueError:
                break  # no room on the arch for these sizes
            if branch_clearance_m(model) >= drawn.blend_radius_m:
                return drawn
    raise ValueError(f"no branch layout of the morphometry distribution fits the arch of {name!r}")


def sample_arch_params(
    random_state=None,
    base: Union[ArchParams, Mapping, str] = "type1",
    *,
    distribution: str = "morphometry",
    arch_types: Sequence[str] = ARCH_TYPES,
    type_weights: Optional[Sequence[float]] = None,
    size_scale: Tuple[float, float] = (0.85, 1.15),
    diameter_scale: Tuple[float, float] = (0.85, 1.15),
    obliquity_deg: Optional[Tuple[float, float]] = None,
    obliquity_range_deg: Tuple[float, float] = (12.0, 68.0),
    name: str = "sampled",
) -> ArchParams:
    """Draw a random arch around `base` (default: the type1 preset).

    `distribution` is "morphometry" (the default) or "fixed_branches". Both draw, in this
    order from `random_state` (an int seed, a `numpy.random.Generator` or a
    `numpy.random.RandomState`):

    1. arch type: one of `arch_types` ("I"/"II"/"III" or 1/2/3) with
       probabilities `type_weights` (default: equal; a modelling choice, not
       population frequencies);
    2. BCA-origin distance below the arch top, in CCA diameters: uniform in
       the type's `ARCH_TYPE_RATIO_RANGE` (I 0.15-0.85, II 1.15-1.85,
       III 2.15-2.85), i.e. well inside the class;
    3. arch width and arch height scale factors: independent, uniform in
       `size_scale` (the height is then also elongated by
       `ARCH_TYPE_ELONGATION` for the drawn type, relative to the base's type);
    4. one diameter scale factor, uniform in `diameter_scale`, applied to every
       aortic and branch lumen diameter (so the branch/aorta proportions keep
       the base's; the CCA diameter that defines the arch type scales too);
    5. `seed` (for the generator's own random choices): a uniform integer;
    6. only with `obliquity_deg=(mean, sd)`: the arch's obliquity (the BCA-LSA ostia
       line's angle with the coronal plane, `ArchModel.obliquity_deg`) from a normal
       with that mean and SD clipped to `obliquity_range_deg`, reached by setting
       `arch_rotation_deg` (the drawn angle minus the unturned arch's own). The
       published distribution of normal arches is `ARCH_OBLIQUITY_DEG` (39.7 +- 13.8
       deg); the default range, 12-68 deg, is its mean +- 2 SD. Off by default (the
       base's `arch_rotation_deg` is kept), and drawn last, so the first five draws
       are the same either way.

    "fixed_branches" stops there: every other field (the branches' gaps, take-off and
    headings, aneurysm, bovine, tortuosity, meshing) is the base's. "morphometry" draws,
    between steps 5 and 6, how the branches leave the arch (`Morphometry`, with the sources
    in docs/anatomy.md): the bovine variant and its trunk, the gaps between the ostia down
    to touching, each branch's and the ascending aorta's diameter, the ascending aorta's
    length, each branch's take-off lean, origin roll and heading, the bend and the branch
    tortuosity; a layout that leaves no room on the arch is drawn again. Its obliquity
    (step 6) is always drawn: from `obliquity_deg`, or `ARCH_OBLIQUITY_DEG` when None.
    """
    if distribution not in DISTRIBUTIONS:
        raise ValueError(f"distribution={distribution!r} is not valid; choose one of {list(DISTRIBUTIONS)}")
    rng = (
        random_state
        if isinstance(random_state, (np.random.Generator, np.random.RandomState))
        else np.random.default_rng(random_state)
    )
    b = arch_params(base)
    types = [normalize_arch_type(t) for t in arch_types]
    if not types:
        raise ValueError("arch_types is empty")
    w = np.ones(len(types)) if type_weights is None else np.asarray(type_weights, dtype=float)
    if w.shape != (len(types),) or np.any(w < 0) or w.sum() <= 0:
        raise ValueError(f"type_weights={type_weights!r} must be {len(types)} non-negative numbers, not all 0")
    for lo_hi, what in ((size_scale, "size_scale"), (diameter_scale, "diameter_scale")):
        if len(lo_hi) != 2 or not 0 < lo_hi[0] <= lo_hi[1]:
            raise ValueError(f"{what}={lo_hi!r} must be (low, high) with 0 < low <= high")
    arch_type = types[int(rng.choice(len(types), p=w / w.sum()))]
    ratio = _rng_uniform(rng, *ARCH_TYPE_RATIO_RANGE[arch_type])
    width_scale = _rng_uniform(rng, *size_scale)
    height_scale = _rng_uniform(rng, *size_scale)
    d_scale = _rng_uniform(rng, *diameter_scale)
    seed = _rng_int(rng, 2**31 - 1)
    # Lengths are rounded to 0.1 um so that they survive the asset's JSON exactly.
    um = lambda x: round(float(x), 7)
    changes = {f: um(getattr(b, f) * d_scale) for f in _DIAMETER_FIELDS}
    if b.aneurysm_diameter_m > 0:
        changes["aneurysm_diameter_m"] = um(b.aneurysm_diameter_m * d_scale)
    elongation = ARCH_TYPE_ELONGATION[arch_type] / ARCH_TYPE_ELONGATION[b.arch_type]
    out = b.replace(
        name=name,
        arch_type=arch_type,
        seed=seed,
        bca_origin_drop_m=um(ratio * changes["lcca_diameter_m"]),
        arch_width_m=um(b.arch_width_m * width_scale),
        arch_height_m=um(b.arch_height_m * height_scale * elongation),
        **changes,
    )
    if distribution == "morphometry":
        out = _morphometry_draw(rng, out, name)
        if obliquity_deg is None:
            obliquity_deg = ARCH_OBLIQUITY_DEG
    if obliquity_deg is not None:
        mean, sd = (float(v) for v in obliquity_deg)
        lo, hi = (float(v) for v in obliquity_range_deg)
        if not (sd >= 0 and -90 < lo <= hi < 90):
            raise ValueError(
                f"obliquity_deg={obliquity_deg!r} needs sd >= 0 and obliquity_range_deg="
                f"{obliquity_range_deg!r} a (low, high) range within (-90, 90)"
            )
        target = float(np.clip(rng.normal(mean, sd), lo, hi))
        unturned = build_arch(out.replace(arch_rotation_deg=0.0)).obliquity_deg
        out = out.replace(arch_rotation_deg=round(target - unturned, 3))
    out.validate()
    return out
