"""Anatomy randomisation: one navigation environment whose aorta is redrawn from a pool.

    env = tasks.load("bca", "random", seed=0, aorta_params={"pool_size": 8, "resample_every": 1})
    env = tasks.load("bca", "random", aorta_params={"assets": ["type1", "type2", "path/to/asset"]})

The pool is a list of asset folders: generated arches drawn with
`cathsim_dmc.anatomy.sample_arch_params` (built once, then cached on disk like
`aorta=custom`), or the assets you list. Each anatomy gets its own composer environment,
built the first time it is drawn (its compiled model is cached too), so a swap costs a
dictionary look-up after the first episode in each anatomy. Every environment of the
pool shares one `numpy.random.RandomState`, which also draws the anatomies: seeding it
(`env.random_state.seed(s)`) makes the whole sequence repeat.
"""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

from cathsim_dmc.core.registry import RANDOM_AORTA

# The sampling distribution's fields (`sample_arch_params`) that `aorta_params` may set.
DISTRIBUTION_KEYS = (
    "distribution",
    "base",
    "arch_types",
    "type_weights",
    "size_scale",
    "diameter_scale",
    "obliquity_deg",
    "obliquity_range_deg",
)
# Draws of one pool arch before its fold is reported (`anatomy_pool`).
MESH_TRIES = 4
POOL_KEYS = ("pool_size", "pool_seed", "resample_every", "order", "assets", "prebuild")
ORDERS = ("random", "cycle")
# Named pool seeds of the "morphometry" distribution: the navigators train on "training",
# their recipe is tuned and the shipped seed chosen on "tuning", and "heldout" is never
# trained or tuned on (scripts/generalisation.py). The "fixed_branches" distribution's
# tables used seeds 0, 500 and 1000.
POOL_SEEDS = {"training": 3000, "tuning": 3500, "heldout": 4000}


def pool_seed_value(pool_seed) -> int:
    """`pool_seed` as an int: an integer, or one of the names in `POOL_SEEDS`."""
    if isinstance(pool_seed, str) and pool_seed in POOL_SEEDS:
        return POOL_SEEDS[pool_seed]
    try:
        if float(pool_seed) == int(float(pool_seed)):
            return int(float(pool_seed))
    except (TypeError, ValueError):
        pass
    raise ValueError(f"aorta pool_seed={pool_seed!r} is not valid; give an integer or one of {list(POOL_SEEDS)}")


def anatomy_pool(
    pool_size: int = 8, pool_seed: int | str = 0, assets: Sequence[str] | None = None, **distribution
) -> list:
    """The pool's asset folders: `assets` (names or folders) if given, else `pool_size`
    generated arches, the i-th drawn by `sample_arch_params(seed=(pool_seed, i), **distribution)`
    (so a larger pool keeps the smaller one's anatomies). `pool_seed` may be a name of
    `POOL_SEEDS`. An arch whose lumen folds at every edge length the mesher tries (a few in a
    hundred of the morphometry distribution, in the crease between two close branches) is
    drawn again from the same random stream, so the pool stays the same on every machine."""
    from cathsim_dmc.anatomy import generated_asset
    from cathsim_dmc.anatomy.generate import sample_arch_params
    from cathsim_dmc.core.shipped import resolve_asset

    if assets:
        return [resolve_asset(str(a)) for a in assets]
    if int(pool_size) < 1:
        raise ValueError(f"aorta pool_size={pool_size!r} must be at least 1")
    pool_seed = pool_seed_value(pool_seed)
    from cathsim_dmc.anatomy.lumen import FoldedSurfaceError

    options = {k: (tuple(v) if isinstance(v, list) else v) for k, v in distribution.items() if v is not None}

    def arch(i):
        rng = np.random.default_rng([pool_seed, i])
        for attempt in range(MESH_TRIES):
            try:
                return generated_asset(sample_arch_params(rng, name=f"random{pool_seed}-{i}", **options))
            except FoldedSurfaceError:
                if attempt == MESH_TRIES - 1:
                    raise

    return [arch(i) for i in range(int(pool_size))]


def random_anatomy_environment(params: dict | None, build, seed=None) -> "RandomAnatomyEnvironment":
    """The environment for `aorta_params` (`params`): POOL_KEYS and DISTRIBUTION_KEYS,
    each checked here, split between the pool (`anatomy_pool`) and the environment."""
    params = dict(params or {})
    unknown = sorted(set(params) - set(POOL_KEYS + DISTRIBUTION_KEYS))
    if unknown:
        raise ValueError(
            f"aorta_params {unknown} unknown for aorta='{RANDOM_AORTA}'; "
            f"choose from {list(POOL_KEYS + DISTRIBUTION_KEYS)}"
        )
    env_keys = ("resample_every", "prebuild", "order")
    if params.get("order", "random") not in ORDERS:  # before the pool, whose build takes tens of seconds
        raise ValueError(f"aorta order={params['order']!r}; choose one of {list(ORDERS)}")
    from cathsim_dmc.anatomy.generate import DISTRIBUTIONS

    pool_seed_value(params.get("pool_seed", 0))
    if params.get("distribution") not in (None, *DISTRIBUTIONS):
        raise ValueError(
            f"aorta distribution={params['distribution']!r} is not valid; choose one of {list(DISTRIBUTIONS)}"
        )
    pool = anatomy_pool(**{k: v for k, v in params.items() if k not in env_keys})
    return RandomAnatomyEnvironment(pool, build, seed=seed, **{k: params[k] for k in env_keys if k in params})


class RandomAnatomyEnvironment:
    """A dm_env environment that redraws its anatomy from `anatomies` (asset folders)
    every `resample_every` episodes; otherwise it is the composer environment of the
    current anatomy (attributes such as `task` and `physics` are that one's).

    `order="random"` draws each anatomy from the shared random state; `"cycle"` takes
    them in turn (the first, the second, ...), so that `len(anatomies)` episodes with
    `resample_every=1` visit each once (an evaluation over the whole pool).

    `build(asset, random_state)` makes the composer environment of one anatomy.
    """

    def __init__(
        self,
        anatomies: Sequence,
        build,
        resample_every: int = 1,
        seed=None,
        prebuild: bool = False,
        order: str = "random",
    ):
        if not anatomies:
            raise ValueError("the anatomy pool is empty")
        if order not in ORDERS:
            raise ValueError(f"aorta order={order!r}; choose one of {list(ORDERS)}")
        self.order = order
        if int(resample_every) < 1:
            raise ValueError(f"aorta resample_every={resample_every!r} must be at least 1 (episodes)")
        self.anatomies = [Path(a) for a in anatomies]
        self.anatomy_names = [_asset_name(a) for a in self.anatomies]
        self._build = build
        self.resample_every = int(resample_every)
        self._random_state = seed if isinstance(seed, np.random.RandomState) else np.random.RandomState(seed)
        self._envs: dict = {}
        self._episodes = 0
        self._index = 0
        if prebuild:
            for i in range(len(self.anatomies)):
                self._env_for(i)

    @property
    def random_state(self) -> np.random.RandomState:
        return self._random_state

    @property
    def anatomy_name(self) -> str:
        """The current anatomy's name (its asset's meta.json name)."""
        return self.anatomy_names[self._index]

    @property
    def current(self):
        """The composer environment of the current anatomy."""
        return self._env_for(self._index)

    def _env_for(self, index: int):
        if index not in self._envs:
            self._envs[index] = self._build(self.anatomies[index], self._random_state)
        return self._envs[index]

    def reset(self):
        if self._episodes % self.resample_every == 0:
            if self.order == "cycle":
                self._index = self._episodes // self.resample_every % len(self.anatomies)
            else:
                self._index = int(self._random_state.randint(len(self.anatomies)))
        self._episodes += 1
        return self.current.reset()

    def step(self, action):
        return self.current.step(action)

    def observation_spec(self):
        return self.current.observation_spec()

    def action_spec(self):
        return self.current.action_spec()

    def close(self):
        for env in self._envs.values():
            env.close()
        self._envs.clear()

    def __getattr__(self, name):
        # Everything else (task, physics, reward_spec, ...) is the current anatomy's.
        if name.startswith("_"):
            raise AttributeError(name)
        return getattr(self.current, name)


def _asset_name(folder: Path) -> str:
    import json

    return str(json.loads((Path(folder) / "meta.json").read_text()).get("name") or Path(folder).name)
