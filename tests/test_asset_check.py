"""`scripts/build_assets.py --check`'s comparison: byte-identical, or equal apart from
coordinates in their last float32 bits (which differ between machines), never more."""

import importlib.util
import pathlib
import shutil

import numpy as np
import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def build_assets():
    spec = importlib.util.spec_from_file_location("build_assets", ROOT / "scripts" / "build_assets.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _copy_with_vertex_moved(tmp_path, offset_m: float) -> pathlib.Path:
    copy = tmp_path / "type1"
    shutil.copytree(ROOT / "assets" / "type1", copy)
    with np.load(copy / "collision.npz") as z:
        arrays = {k: z[k] for k in z.files}
    arrays["vertices"] = arrays["vertices"].copy()
    arrays["vertices"][17, 1] += np.float32(offset_m)
    np.savez(copy / "collision.npz", **arrays)
    return copy


def test_an_identical_build_is_identical(build_assets):
    assert build_assets.compare(ROOT / "assets" / "type1", ROOT / "assets" / "type1") == (True, 0.0)


def test_float_rounding_passes_and_a_real_change_does_not(build_assets, tmp_path):
    shipped = ROOT / "assets" / "type1"
    same, largest = build_assets.compare(shipped, _copy_with_vertex_moved(tmp_path / "a", 1e-7))
    assert same and 0.0 < largest <= build_assets.ROUNDING_TOLERANCE_M
    same, largest = build_assets.compare(shipped, _copy_with_vertex_moved(tmp_path / "b", 1e-5))
    assert not same and largest == pytest.approx(1e-5, rel=0.1)


def test_another_asset_differs(build_assets):
    assert not build_assets.compare(ROOT / "assets" / "type1", ROOT / "assets" / "type2")[0]
