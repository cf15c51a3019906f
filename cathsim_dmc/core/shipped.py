"""Where the shipped assets and configs live (inside the installed package)."""

from __future__ import annotations

import importlib.resources
from pathlib import Path


def assets_root() -> Path:
    """Folder of the shipped anatomy assets."""
    return Path(str(importlib.resources.files("cathsim_dmc.assets")))


def conf_root() -> Path:
    """Folder of the shipped Hydra configs."""
    return Path(str(importlib.resources.files("cathsim_dmc.conf")))


def available_aortas() -> tuple:
    """Names of the shipped aorta assets."""
    return tuple(sorted(p.name for p in assets_root().iterdir() if (p / "meta.json").is_file()))


def resolve_asset(asset) -> Path:
    """A shipped asset name or a path to an asset folder -> the folder."""
    path = Path(asset)
    if (path / "meta.json").is_file():
        return path
    if str(asset) in available_aortas():
        return assets_root() / str(asset)
    raise ValueError(f"aorta={str(asset)!r} is neither a shipped aorta {list(available_aortas())} nor an asset folder")


def aorta_label(aorta) -> str:
    """How tables and run folders name an aorta: a shipped name as it is, an asset folder
    by its own name (not its path)."""
    text = str(aorta)
    return Path(text).name if ("/" in text or "\\" in text) else text
