"""The fast environment build (wall added through MjSpec, MJB cache, one compile) builds
the same model as the plain MJCF path, and reset never recompiles."""

import numpy as np
import pytest
from dm_control import composer

from cathsim_dmc import tasks
from cathsim_dmc.entities import Aorta
from cathsim_dmc.sim import model_cache
from cathsim_dmc.sim.arena import OperatingArena


@pytest.fixture
def models_dir(tmp_path, monkeypatch):
    monkeypatch.setenv("CATHSIM_DMC_CACHE", str(tmp_path))
    return tmp_path / "models"


def rollout(env, n_steps=30):
    env.reset()
    rng = np.random.default_rng(1)
    for _ in range(n_steps):
        env.step(np.array([0.7, 0.0]) + rng.uniform(-1, 1, 2) * [0.3, 1.0])
    return env.task.tip_position_m(env.physics)


def test_fast_build_matches_the_mjcf_build_and_caches(models_dir):
    stock = tasks.load("bca", "type1", seed=0, aorta_options=dict(hulls_in_mjcf=True))
    fast = tasks.load("bca", "type1", seed=0)  # compiles and fills the cache
    assert stock.task.aorta.hulls_in_mjcf and not fast.task.aorta.hulls_in_mjcf
    cached = tasks.load("bca", "type1", seed=0)  # loads the MJB
    assert len(list(models_dir.glob("*.mjb"))) == 1
    for env in (fast, cached):
        m, s = env.physics.model, stock.physics.model
        assert (m.ngeom, m.nmesh, m.nbody, m.nv) == (s.ngeom, s.nmesh, s.nbody, s.nv)
        assert [m.geom(i).name for i in range(m.ngeom)] == [s.geom(i).name for i in range(s.ngeom)]
        np.testing.assert_array_equal(m.geom_solref, s.geom_solref)
        np.testing.assert_array_equal(m.mesh_vert, s.mesh_vert)
    tip = rollout(stock)
    np.testing.assert_array_equal(rollout(fast), tip)
    np.testing.assert_array_equal(rollout(cached), tip)


def test_the_field_wall_is_cached_and_refused_in_the_mjcf(models_dir):
    fast = tasks.load("bca", "type1", seed=0, physics="fast_field")  # compiles and fills the cache
    cached = tasks.load("bca", "type1", seed=0, physics="fast_field")
    assert len(list(models_dir.glob("*.mjb"))) == 1
    np.testing.assert_array_equal(cached.physics.model.numeric_data, fast.physics.model.numeric_data)
    np.testing.assert_array_equal(rollout(cached), rollout(fast))
    with pytest.raises(ValueError, match="use wall='prisms'"):
        tasks.load("bca", "type1", physics="fast_field", aorta_options=dict(hulls_in_mjcf=True))


def test_reset_does_not_recompile(models_dir):
    env = tasks.load("bca", "type1", seed=0)
    physics = env.physics
    for _ in range(3):
        env.reset()
        env.step([1.0, 0.0])
    assert env.physics is physics


def test_light_aorta_in_a_plain_environment_fails_loudly():
    arena = OperatingArena()
    arena.attach(Aorta(hulls_in_mjcf=False))
    env = composer.Environment(composer.NullTask(arena))
    with pytest.raises(RuntimeError, match="no wall"):
        env.reset()


def test_model_cache_keeps_the_most_recently_used(tmp_path):
    import os

    for i in range(5):
        (tmp_path / f"{i}.mjb").write_bytes(b"x")
        os.utime(tmp_path / f"{i}.mjb", ns=(i * 10**9, i * 10**9))
    model_cache.prune(tmp_path, keep=2)
    assert sorted(p.name for p in tmp_path.glob("*.mjb")) == ["3.mjb", "4.mjb"]
