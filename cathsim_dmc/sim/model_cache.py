"""Compile a composer scene plus geoms added through `mujoco.MjSpec`, with an MJB cache.

An anatomy's wall is thousands of small meshes. As MJCF elements they take seconds to
create, serialise to XML and parse again; added to a spec of the scene they cost a
fraction of that, and the compiled model, saved as MJB, loads in milliseconds the next
time. The cache key covers the scene XML, what the extra geoms are made from and the
MuJoCo version, so any change to them compiles afresh. The cache lives next to the
generated aortas: ``$CATHSIM_DMC_CACHE/models`` or ``~/.cache/cathsim_dmc/models``, and
keeps the `MAX_CACHED_MODELS` most recently used models (about 15 MB each; the environment
variable CATHSIM_DMC_MAX_CACHED_MODELS sets another number). A random-anatomy pool
(`aorta=random`) compiles one model per arch, about 10 s each against under 1 s from the
cache, and a training run visits its pool from three environments (training, evaluation,
demonstrations): the cache holds a 64-arch training pool, the 100 held-out arches and the
shipped aortas at once.
"""

from __future__ import annotations

import hashlib
import os
import pathlib
import tempfile
from typing import Callable

import mujoco

from cathsim_dmc.anatomy import cache_root

MAX_CACHED_MODELS = int(os.environ.get("CATHSIM_DMC_MAX_CACHED_MODELS", 256))


def model_cache_dir() -> pathlib.Path:
    return cache_root().parent / "models"


def compile_model(
    mjcf_root, add_geoms: Callable[[mujoco.MjSpec], None], key: bytes, cache: bool = True
) -> mujoco.MjModel:
    """Compiles `mjcf_root` with `add_geoms(spec)` applied; `key` identifies what it adds."""
    xml = mjcf_root.to_xml_string()
    assets = mjcf_root.get_assets()
    digest = hashlib.sha256()
    for part in (mujoco.__version__.encode(), xml.encode(), key):
        digest.update(len(part).to_bytes(8, "little"))
        digest.update(part)
    for name in sorted(assets):
        digest.update(name.encode())
        digest.update(assets[name])
    path = model_cache_dir() / f"{digest.hexdigest()[:32]}.mjb"
    if cache and path.is_file():
        try:
            model = mujoco.MjModel.from_binary_path(str(path))
            os.utime(path)  # most recently used
            return model
        except Exception:  # a truncated or foreign file: compile again and replace it
            pass
    spec = mujoco.MjSpec.from_string(xml, assets=assets)
    add_geoms(spec)
    model = spec.compile()
    if cache:
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            # Atomic: concurrent builds of the same model never read a partial file.
            fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".tmp")
            os.close(fd)
            mujoco.mj_saveModel(model, tmp, None)
            os.replace(tmp, path)
            prune(path.parent)
        except OSError:
            pass  # a read-only cache only costs speed
    return model


def prune(folder: pathlib.Path, keep: int | None = None) -> None:
    """Deletes all but the `keep` (MAX_CACHED_MODELS) most recently used models in `folder`."""
    keep = MAX_CACHED_MODELS if keep is None else keep
    models = sorted(folder.glob("*.mjb"), key=lambda p: p.stat().st_mtime_ns, reverse=True)
    for old in models[keep:]:
        try:
            old.unlink()
        except OSError:
            pass  # another process got there first
