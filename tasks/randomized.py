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
    "base",
    "arch_types",
    "type_weights",
    "size_scale",
    "diameter_scale",
    "obliquity_deg",
    "obliquity_range_deg",
)
POOL_KEYS = ("pool_size", "pool_seed", "resample_every", "order", "assets", "prebuild")
ORDERS = ("random", "cycle")


def anatomy_pool(pool_size: int = 8, pool_seed: int = 0, assets: Sequence[str] | None = None, **distribution) -> list:
    """The pool's asset folders: `assets` (names or folders) if given, else `pool_size`
    generated arches, the i-th drawn by `sample_arch_params(seed=(pool_seed, i), **distribution)`
    (so a larger pool keeps the smaller one's anatomies)."""
    from cathsim_dmc.anatomy import generated_asset
    from cathsim_dmc.anatomy.generate import sample_arch_params
    from cathsim_dmc.core.shipped import resolve_asset

    if assets:
        return [resolve_asset(str(a)) for a in assets]
    if int(pool_size) < 1:
        raise ValueError(f"aorta pool_size={pool_size!r} must be at least 1")
    options = {k: (tuple(v) if isinstance(v, list) else v) for k, v in distribution.items() if v is not None}
    return [
        generated_asset(
            sample_arch_params(np.random.default_rng([int(pool_seed), i]), name=f"random{pool_seed}-{i}", **options)
        )
        for i in range(int(pool_size))
    ]


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
