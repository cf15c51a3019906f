"""Arches that vary as patients' do: the branch layout fields of `ArchParams` (gaps down to
touching, take-off, origin roll, branch tortuosity), the "morphometry" distribution of
`sample_arch_params` and the named pools of aorta=random."""

import math

import numpy as np
import pytest

from cathsim_dmc.anatomy import (
    MORPHOMETRY,
    PRESETS,
    branch_clearance_m,
    build_arch,
    params_hash,
    sample_arch_params,
)
from cathsim_dmc.anatomy.asset import LATER_FIELD_DEFAULTS, params_record

TYPE1 = PRESETS["type1"]


def _gap(model, a, b):
    """Wall-to-wall distance between two ostia, m."""
    return float(
        np.linalg.norm(model.ostia[a] - model.ostia[b])
        - model.params.branch_diameter_m(a) / 2
        - model.params.branch_diameter_m(b) / 2
    )


def _first_direction(model, branch):
    v = model.branches[branch].points
    d = v[4] - v[0]  # 2 mm: inside the aorta, before any bend
    return d / np.linalg.norm(d)


def test_the_layout_fields_are_off_by_default_and_recorded_only_when_set():
    for key, default in LATER_FIELD_DEFAULTS.items():
        assert getattr(TYPE1, key) == default
        assert key not in params_record(TYPE1)
    turned = TYPE1.replace(lcca_takeoff_deg=10.0)
    assert params_record(turned)["lcca_takeoff_deg"] == 10.0
    assert params_hash(turned) != params_hash(TYPE1)


@pytest.mark.parametrize("gap_mm", [0.0, 1.0, 8.0])
def test_the_gap_is_the_wall_to_wall_distance_of_the_ostia_also_for_slanted_rolled_branches(gap_mm):
    p = TYPE1.replace(bca_lcca_gap_m=gap_mm / 1e3, bca_takeoff_deg=-20.0, lcca_takeoff_deg=15.0, lcca_roll_deg=12.0)
    model = build_arch(p)
    assert _gap(model, "bca", "lcca") == pytest.approx(gap_mm / 1e3, abs=2e-4)
    assert _gap(model, "lcca", "lsa") == pytest.approx(p.lcca_lsa_gap_m, abs=2e-4)
    assert model.arch_type_measured == "I"


def test_take_off_leans_the_first_direction_towards_the_descending_side():
    for angle in (-25.0, 0.0, 25.0):
        model = build_arch(TYPE1.replace(lcca_takeoff_deg=angle))
        d = _first_direction(model, "lcca")
        # The aorta's tangent at the origin runs from the descending towards the ascending
        # side: the wall normal is square to it, and a positive lean points against it.
        s, points = model.aorta.arclength, model.aorta.points
        at = lambda q: np.array([np.interp(q, s, points[:, k]) for k in range(3)])  # noqa: E731
        origin = model.branch_origin_s["lcca"]
        tangent = at(origin + 1e-3) - at(origin - 1e-3)
        tangent /= np.linalg.norm(tangent)
        assert math.degrees(math.acos(np.dot(d, tangent))) - 90.0 == pytest.approx(angle, abs=0.5)
        # The site stays site_depth_m along the branch past its (moved) ostium.
        u = model.branches["lcca"].arclength
        wall = float(np.linalg.norm(model.ostia["lcca"] - model.branches["lcca"].points[0]))
        k = int(np.argmin(np.linalg.norm(model.branches["lcca"].points - model.sites["lcca"], axis=1)))
        assert u[k] - wall == pytest.approx(TYPE1.site_depth_m, abs=1e-3)


def test_roll_moves_the_ostium_off_the_top_of_the_curvature_anteriorly():
    flat = build_arch(TYPE1)
    rolled = build_arch(TYPE1.replace(lcca_roll_deg=20.0))
    lift = rolled.ostia["lcca"][2] - flat.ostia["lcca"][2]
    radius = float(np.interp(flat.branch_origin_s["lcca"], flat.aorta.arclength, flat.aorta.radius))
    assert lift == pytest.approx(radius * math.sin(math.radians(20.0)), rel=0.15)
    assert rolled.ostia["lcca"][1] < flat.ostia["lcca"][1]


def test_branch_tortuosity_raises_the_distance_metric_and_leaves_the_ostium():
    plain = build_arch(TYPE1)
    wavy = build_arch(TYPE1.replace(branch_tortuosity_amplitude_m=0.003, branch_tortuosity_wavelength_m=0.025))
    for b in ("bca", "lcca", "lsa"):
        assert np.allclose(wavy.ostia[b], plain.ostia[b])
        gain = wavy.tortuosity()[b] - plain.tortuosity()[b]
        assert 0.02 < gain < 0.4, (b, gain)
    # Its own random stream: the aortic tortuosity's phase is what it was.
    seeded = TYPE1.replace(tortuosity_amplitude_m=0.004, seed=3)
    assert np.array_equal(
        build_arch(seeded).aorta.points,
        build_arch(seeded.replace(branch_tortuosity_amplitude_m=0.002)).aorta.points,
    )


@pytest.fixture(scope="module")
def draws():
    return [sample_arch_params(np.random.default_rng([77, i])) for i in range(40)]


def test_the_morphometry_draws_vary_the_branches_within_their_sources(draws):
    assert sample_arch_params(np.random.default_rng([77, 3])) == draws[3]
    m = MORPHOMETRY
    gaps = np.array([p.bca_lcca_gap_m for p in draws])
    assert gaps.min() >= 0.0 and (gaps < 0.002).any() and (gaps > 0.006).any()
    assert 0.002 < np.median(gaps) < 0.007  # Yan et al.: 4.39 +- 2.49 mm
    assert any(p.bovine for p in draws) and sum(p.bovine for p in draws) < 0.4 * len(draws)
    for p in draws:
        model = build_arch(p)
        assert model.arch_type_measured == p.arch_type
        assert branch_clearance_m(model) >= p.blend_radius_m
        assert p.edge_length_m <= min(p.branch_diameter_m(b) for b in ("bca", "lcca", "lsa"))
        for b, sd in zip(("bca", "lcca", "lsa"), m.takeoff_sd_deg):
            assert abs(getattr(p, f"{b}_takeoff_deg")) <= m.clip_sd * sd + 1e-9
    assert all(sample_arch_params(s, base="bovine").bovine for s in range(5)), "a bovine base stays bovine"
    # Obliquity is drawn from the published distribution.
    assert len({p.arch_rotation_deg for p in draws}) == len(draws)
    assert len({p.lcca_takeoff_deg for p in draws}) > 0.8 * len(draws)  # some clipped at 2 sd


def test_fixed_branches_keeps_the_distribution_before_morphometry():
    old = sample_arch_params(3, distribution="fixed_branches")
    # The cache key of this draw before the morphometry fields existed (GENERATOR_VERSION 2).
    assert params_hash(old) == "ee9f34fc487f534b"
    for key, default in LATER_FIELD_DEFAULTS.items():
        if key != "arch_rotation_deg":
            assert getattr(old, key) == default
    with pytest.raises(ValueError, match=r"distribution='patients' is not valid; choose one of \['morphometry'"):
        sample_arch_params(3, distribution="patients")


def test_named_pool_seeds_and_bad_ones():
    from cathsim_dmc.tasks.randomized import POOL_SEEDS, pool_seed_value, random_anatomy_environment

    assert pool_seed_value("heldout") == POOL_SEEDS["heldout"] and pool_seed_value(7) == pool_seed_value("7") == 7
    assert len(set(POOL_SEEDS.values())) == len(POOL_SEEDS)
    with pytest.raises(ValueError, match=r"pool_seed='held_out' is not valid; give an integer or one of \['training'"):
        random_anatomy_environment({"pool_seed": "held_out"}, build=None)
    with pytest.raises(ValueError, match=r"distribution='wide' is not valid; choose one of"):
        random_anatomy_environment({"distribution": "wide"}, build=None)


@pytest.mark.slow
def test_an_arch_that_folds_at_every_edge_length_fails_fast_the_second_time(tmp_path):
    """Held-out arch 15's first draw: the crease between its close LCCA and LSA (0.8 mm
    apart at the ostia) folds the lumen at every edge length; the pool draws it again."""
    import time

    from cathsim_dmc.anatomy import generated_asset
    from cathsim_dmc.anatomy.lumen import FoldedSurfaceError
    from cathsim_dmc.tasks.randomized import POOL_SEEDS

    params = sample_arch_params(np.random.default_rng([POOL_SEEDS["heldout"], 15]), name="folds")
    with pytest.raises(FoldedSurfaceError) as first:
        generated_asset(params, cache_dir=tmp_path)
    start = time.perf_counter()
    with pytest.raises(FoldedSurfaceError) as second:
        generated_asset(params, cache_dir=tmp_path)
    assert time.perf_counter() - start < 1.0 and str(second.value) == str(first.value)
    assert not [p for p in tmp_path.iterdir() if p.is_dir()], "no asset folder is left behind"
