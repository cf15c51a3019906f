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
    ARCH_TYPE_ELONGATION,
    ARCH_TYPE_RATIO_RANGE,
    ARCH_TYPES,
    ArchParams,
    normalize_arch_type,
)
from cathsim_dmc.anatomy.presets import PRESETS

# Bump when the pipeline's output for the same parameters changes (invalidates caches),
# e.g. with lumen.MESHER_VERSION, which generated arches are built at. 2: mesher version 2
# (narrow branches no longer pinched); the version-1 arches cached before stay unused.
GENERATOR_VERSION = 2
CACHE_ENV = "CATHSIM_DMC_CACHE"

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

    p = arch_params(params)
    root = cache_root(cache_dir)
    final = root / params_hash(p)
    if (final / META_FILE).is_file():
        return final
    root.mkdir(parents=True, exist_ok=True)
    tmp = pathlib.Path(tempfile.mkdtemp(prefix=f".{final.name}.", suffix=".tmp", dir=root))
    try:
        build_asset(p, tmp)
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


def sample_arch_params(
    random_state=None,
    base: Union[ArchParams, Mapping, str] = "type1",
    *,
    arch_types: Sequence[str] = ARCH_TYPES,
    type_weights: Optional[Sequence[float]] = None,
    size_scale: Tuple[float, float] = (0.85, 1.15),
    diameter_scale: Tuple[float, float] = (0.85, 1.15),
    obliquity_deg: Optional[Tuple[float, float]] = None,
    obliquity_range_deg: Tuple[float, float] = (12.0, 68.0),
    name: str = "sampled",
) -> ArchParams:
    """Draw a random arch around `base` (default: the type1 preset).

    The distribution, drawn in this order from `random_state` (an int seed, a
    `numpy.random.Generator` or a `numpy.random.RandomState`):

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

    Every other field (aneurysm, bovine, tortuosity, meshing) is the base's.
    """
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
