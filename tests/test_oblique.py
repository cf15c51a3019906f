"""Oblique arches and the LAO view: the arch-plane rotation (`ArchParams.arch_rotation_deg`),
its measured obliquity, the shipped `*_oblique` variants, the sampler's obliquity draw,
and the top camera turned into a left anterior oblique view (`lao_deg`)."""

import functools
import json
import math
import pathlib

import numpy as np
import pytest

from cathsim_dmc.anatomy import (
    ARCH_OBLIQUITY_DEG,
    PRESETS,
    build_arch,
    load_asset,
    ostia_obliquity_deg,
    params_hash,
    sample_arch_params,
)
from cathsim_dmc.sim.arena import lao_camera_axes

ROOT = pathlib.Path(__file__).resolve().parents[1]
OBLIQUE = ("type1_oblique", "type2_oblique", "type3_oblique")
SIZE = 80


def _turned(points, angle_deg, axis_x, axis_z):
    """`points` turned about the vertical line (axis_x, *, axis_z) by `angle_deg` (right hand, +y)."""
    a = math.radians(angle_deg)
    p = np.array(points, dtype=float) - [axis_x, 0.0, axis_z]
    x, z = p[..., 0] * math.cos(a) + p[..., 2] * math.sin(a), -p[..., 0] * math.sin(a) + p[..., 2] * math.cos(a)
    return np.stack([x + axis_x, p[..., 1], z + axis_z], axis=-1)


# ----------------------------------------------------------------------------
# The parameter


def test_rotation_keeps_the_entry_and_brings_the_ascending_aorta_anterior():
    base = PRESETS["type1"]
    flat, turned = build_arch(base), build_arch(base.replace(arch_rotation_deg=30.0))
    np.testing.assert_array_equal(turned.entry_position, flat.entry_position)
    np.testing.assert_array_equal(turned.entry_direction, flat.entry_direction)
    np.testing.assert_array_equal(turned.open_end_center, flat.open_end_center)
    assert turned.arch_top_y == flat.arch_top_y and turned.arch_type_distance_m == flat.arch_type_distance_m
    # The closed root of the ascending aorta: 60 mm across the arch from the descending
    # aorta and 10 mm anterior to it; turned 30 deg it comes 2a sin - 2hd (1 - cos) forward.
    a, hd = base.arch_width_m / 2, base.arch_depth_m / 2
    root_flat, root_turned = flat.aorta.points[-1], turned.aorta.points[-1]
    np.testing.assert_allclose(root_flat, [-a, -base.ascending_length_m, hd], atol=1e-12)
    expected = 2 * a * math.sin(math.radians(30)) - 2 * hd * (1 - math.cos(math.radians(30)))
    assert root_turned[2] - root_flat[2] == pytest.approx(expected, abs=1e-9)
    assert root_turned[2] - root_flat[2] > 0.028
    np.testing.assert_allclose(root_turned, _turned(root_flat, 30.0, a, -hd), atol=1e-12)
    # A rigid turn: every centreline point, ostium and site turned alike, radii unchanged.
    np.testing.assert_allclose(turned.aorta.points, _turned(flat.aorta.points, 30.0, a, -hd), atol=1e-12)
    np.testing.assert_array_equal(turned.aorta.radius, flat.aorta.radius)
    for b in ("bca", "lcca", "lsa"):
        np.testing.assert_allclose(turned.sites[b], _turned(flat.sites[b], 30.0, a, -hd), atol=1e-12)
        np.testing.assert_allclose(
            turned.branches[b].points, _turned(flat.branches[b].points, 30.0, a, -hd), atol=1e-12
        )
    assert turned.tortuosity() == pytest.approx(flat.tortuosity())
    # Negative turns it the other way: the ascending aorta posterior.
    assert build_arch(base.replace(arch_rotation_deg=-20.0)).aorta.points[-1][2] < root_flat[2] - 0.015


@pytest.mark.parametrize("angle", [-15.0, 0.0, 20.0, 33.5, 60.0])
def test_measured_obliquity_is_the_unturned_arch_plus_the_rotation(angle):
    flat = build_arch(PRESETS["type2"])
    ostia = flat.ostia
    d = ostia["lsa"] - ostia["bca"]
    # By hand: the BCA-LSA line seen from above, from the coronal (x-y) plane.
    assert flat.obliquity_deg == pytest.approx(math.degrees(math.atan2(-d[2], d[0])))
    assert 5.0 < flat.obliquity_deg < 8.0, "arch_depth_m alone gives a few degrees"
    model = build_arch(PRESETS["type2"].replace(arch_rotation_deg=angle))
    assert model.obliquity_deg == pytest.approx(flat.obliquity_deg + angle, abs=1e-9)


def test_the_default_is_unchanged_and_the_new_field_is_recorded_only_when_set(monkeypatch):
    from cathsim_dmc.anatomy import generate

    # Cache keys today: GENERATOR_VERSION 2 (the lumen mesher fix) changed every key on purpose.
    assert params_hash(PRESETS["type1"]) == "efc2bd260760fb94"
    assert params_hash(sample_arch_params(3, distribution="fixed_branches")) == "ee9f34fc487f534b"
    # At GENERATOR_VERSION 1 the keys of the arches made before the field existed (computed
    # with that code): the unset field leaves the hash as it was.
    monkeypatch.setattr(generate, "GENERATOR_VERSION", 1)
    assert params_hash(PRESETS["type1"]) == "e13b5e26badd5989"
    assert params_hash(sample_arch_params(3, distribution="fixed_branches")) == "ec38265df4033360"
    assert params_hash(PRESETS["type1"].replace(arch_rotation_deg=1.0)) != "e13b5e26badd5989"
    for name in ("type1", "type2", "type3"):
        meta = json.loads((ROOT / "assets" / name / "meta.json").read_text())
        assert "arch_rotation_deg" not in meta["params"] and "arch_obliquity_deg" not in meta
    with pytest.raises(ValueError, match="arch_rotation_deg"):
        PRESETS["type1"].replace(arch_rotation_deg=120.0).validate()


# ----------------------------------------------------------------------------
# The shipped variants


@pytest.mark.parametrize("name", OBLIQUE)
def test_shipped_oblique_arch_is_its_plain_arch_turned(name):
    plain_name = name.removesuffix("_oblique")
    asset, plain = load_asset(ROOT / "assets" / name), load_asset(ROOT / "assets" / plain_name)
    meta = asset.meta
    assert meta["params"]["arch_rotation_deg"] == 33.5
    assert PRESETS[name] == PRESETS[plain_name].replace(name=name, arch_rotation_deg=33.5)
    # The obliquity recorded, measured from the recorded ostia, is the published mean.
    assert meta["arch_obliquity_deg"] == pytest.approx(ostia_obliquity_deg(meta["ostia"]), abs=1e-3)
    assert meta["arch_obliquity_deg"] == pytest.approx(ARCH_OBLIQUITY_DEG[0], abs=0.5)
    # Same entry; the centerlines and sites are the plain arch's, turned about the descending aorta.
    p = PRESETS[plain_name]
    np.testing.assert_allclose(asset.entry_position, plain.entry_position, atol=1e-9)
    for b in ("bca", "lcca", "lsa"):
        pts, _ = asset.centerlines[b]
        ref, _ = plain.centerlines[b]
        np.testing.assert_allclose(pts, _turned(ref, 33.5, p.arch_width_m / 2, -p.arch_depth_m / 2), atol=2e-6)
        np.testing.assert_allclose(
            asset.sites[b], _turned(plain.sites[b], 33.5, p.arch_width_m / 2, -p.arch_depth_m / 2), atol=2e-6
        )
    # The ascending aorta now lies well anterior: the lumen reaches further forward.
    assert asset.visual_vertices[:, 2].max() > plain.visual_vertices[:, 2].max() + 0.02


# ----------------------------------------------------------------------------
# The sampler


def test_sampler_obliquity_is_off_by_default_with_fixed_branches_and_otherwise_drawn_and_reached():
    sample = functools.partial(sample_arch_params, distribution="fixed_branches")
    plain = sample(5)
    assert plain.arch_rotation_deg == 0.0
    # Exactly the published mean when the SD is 0; the other draws are unchanged.
    fixed = sample(5, obliquity_deg=(ARCH_OBLIQUITY_DEG[0], 0.0))
    assert fixed.replace(arch_rotation_deg=0.0) == plain
    assert build_arch(fixed).obliquity_deg == pytest.approx(ARCH_OBLIQUITY_DEG[0], abs=2e-3)
    # Drawn: clipped to the range, and the model's obliquity is the draw.
    for seed in range(4):
        p = sample(seed, obliquity_deg=ARCH_OBLIQUITY_DEG, obliquity_range_deg=(20.0, 50.0))
        assert 20.0 - 2e-3 <= build_arch(p).obliquity_deg <= 50.0 + 2e-3
    draws = {sample(s, obliquity_deg=ARCH_OBLIQUITY_DEG).arch_rotation_deg for s in range(4)}
    assert len(draws) == 4
    with pytest.raises(ValueError, match="obliquity"):
        sample(0, obliquity_deg=(40.0, -1.0))
    # The morphometry distribution always draws it, from the published distribution by default.
    exact = sample_arch_params(5, obliquity_deg=(ARCH_OBLIQUITY_DEG[0], 0.0))
    assert build_arch(exact).obliquity_deg == pytest.approx(ARCH_OBLIQUITY_DEG[0], abs=2e-3)
    assert sample_arch_params(5).arch_rotation_deg != 0.0


def test_random_aorta_config_passes_the_distribution_and_obliquity_to_the_sampler():
    import yaml

    from cathsim_dmc.tasks.randomized import DISTRIBUTION_KEYS

    conf = yaml.safe_load((ROOT / "conf" / "aorta" / "random.yaml").read_text())["params"]
    assert {"distribution", "obliquity_deg", "obliquity_range_deg"} <= set(DISTRIBUTION_KEYS) & set(conf)
    assert conf["distribution"] == "morphometry" and conf["obliquity_deg"] is None, "the sampler's defaults"


# ----------------------------------------------------------------------------
# The LAO view


def test_lao_camera_view_axis_and_framing():
    from cathsim_dmc import tasks

    env = tasks.load("bca", "type1_oblique", obs="pixels", seed=0, lao_deg=35.0)
    physics = env.physics
    cam = physics.model.name2id("top", "camera")
    xmat = physics.data.cam_xmat[cam].reshape(3, 3)
    a = math.radians(35.0)
    np.testing.assert_allclose(xmat[:, 2], [math.sin(a), 0, math.cos(a)], atol=1e-9)  # towards the camera
    np.testing.assert_allclose(xmat[:, 0], [math.cos(a), 0, -math.sin(a)], atol=1e-9)  # image right
    np.testing.assert_allclose(xmat[:, 1], [0, 1, 0], atol=1e-9)
    for axis, column in zip(lao_camera_axes(35.0), xmat.T):
        np.testing.assert_allclose(axis, column, atol=1e-9)
    # The camera sits anterior and to the patient's left of the anatomy, in front of all of it.
    lo, hi = env.task.aorta.bounds_m
    offset = physics.data.cam_xpos[cam] - (np.asarray(lo) + hi) / 2
    assert offset[0] > 0.1 and offset[2] > 0.1 and abs(offset[1]) < 1e-9
    # Every vertex of the lumen is in the image.
    from cathsim_dmc.sim.arena import top_camera_matrix

    vertices = env.task.aorta.asset.visual_vertices.astype(float)
    uv = (top_camera_matrix(physics, size=SIZE) @ np.c_[vertices, np.ones(len(vertices))].T)[:2]
    assert uv.min() >= 0 and uv.max() <= SIZE
    # AP (0, the default) is the camera it always was.
    ap_env = tasks.load("bca", "type1_oblique", obs="pixels", seed=0)
    np.testing.assert_array_equal(ap_env.physics.data.cam_xmat[cam], np.eye(3).ravel())
    with pytest.raises(ValueError, match="lao_deg"):
        tasks.load("bca", "type1", obs="pixels", lao_deg=100.0)


@pytest.mark.parametrize("renderer", ["raster", "gl"])
def test_lao_mask_is_where_the_wire_projects(renderer):
    from cathsim_dmc import tasks

    lao = 40.0
    env = tasks.load("bca", "type1_oblique", obs="pixels_mask", seed=0, lao_deg=lao, renderer=renderer)
    env.reset()
    for i in range(45):
        ts = env.step(np.array([1.0, 0.5 if i < 25 else -0.5]))
    physics, task = env.physics, env.task
    mask = ts.observation["guidewire_mask"][..., 0] > 0
    assert mask.sum() > 10
    # Project the wire's joints by hand, from the camera's place and the LAO axes alone.
    cam = physics.model.name2id("top", "camera")
    right, up, _ = lao_camera_axes(lao)
    scale = SIZE / physics.model.cam_fovy[cam]
    points = (
        np.concatenate([physics.bind(task.guidewire.segments).xpos, [task.tip_position_m(physics)]])
        - physics.data.cam_xpos[cam]
    )
    u, v = SIZE / 2 + scale * points @ right, SIZE / 2 - scale * points @ up
    inside = (u >= 0) & (u < SIZE) & (v >= 0) & (v < SIZE)
    assert inside.sum() > 10
    rows, cols = np.floor(v[inside]).astype(int), np.floor(u[inside]).astype(int)
    near = np.zeros_like(mask)
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            near |= np.roll(np.roll(mask, dr, axis=0), dc, axis=1)
    assert near[rows, cols].mean() >= 0.95, "the wire's joints fall on the mask"
    # ... and the mask lies along the projected wire (every pixel within 1.5 px of the polyline).
    pixels = np.argwhere(mask) + 0.5
    line = np.stack([v, u], axis=1)
    start, step = line[:-1], np.diff(line, axis=0)
    t = np.clip(((pixels[:, None] - start[None]) * step[None]).sum(-1) / np.maximum((step**2).sum(-1), 1e-12), 0, 1)
    gaps = np.linalg.norm(pixels[:, None] - (start[None] + t[..., None] * step[None]), axis=2).min(axis=1)
    assert gaps.max() <= 1.5
    # The AP view of the same state puts the wire elsewhere: the view really turned.
    ap_env = tasks.load("bca", "type1_oblique", obs="pixels_mask", seed=0, renderer=renderer)
    ap_env.reset()
    for i in range(45):
        ap_ts = ap_env.step(np.array([1.0, 0.5 if i < 25 else -0.5]))
    ap_mask = ap_ts.observation["guidewire_mask"][..., 0] > 0
    assert (mask & ap_mask).sum() < 0.8 * mask.sum()


def test_lao_reaches_the_environment_from_the_tools_config():
    from hydra import compose, initialize_config_dir

    from cathsim_dmc.app.cli._common import env_kwargs
    from cathsim_dmc.core.shipped import conf_root

    with initialize_config_dir(config_dir=str(conf_root()), version_base="1.3"):
        lao = env_kwargs(compose("eval", ["obs=pixels", "obs.lao_deg=40", "aorta=type2_oblique"]))
        ap = env_kwargs(compose("eval", ["obs=pixels"]))
    assert lao["lao_deg"] == 40 and lao["aorta"] == "type2_oblique"
    assert "lao_deg" not in ap, "the AP view is recorded as before the option existed"
