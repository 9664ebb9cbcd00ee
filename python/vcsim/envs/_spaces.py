"""Gymnasium's Env and spaces when gymnasium is installed, else small stand-ins with the same
attributes and behaviour for what vcsim's environments use (Box, Dict, Env.reset seeding).
gymnasium is not a Debian package; with it installed, vcsim's environments are gymnasium.Env
subclasses and pass gymnasium.utils.env_checker.check_env."""
from __future__ import annotations

import numpy as np

try:  # pragma: no cover - depends on the machine
    import gymnasium as _gym
    from gymnasium import spaces as _gym_spaces

    HAVE_GYMNASIUM = True
except ImportError:  # the Debian machine
    _gym = None
    _gym_spaces = None
    HAVE_GYMNASIUM = False


class _Box:
    """A box of real (or integer) values: low <= x <= high, of a shape and dtype."""

    def __init__(self, low, high, shape=None, dtype=np.float32, seed=None):
        self.dtype = np.dtype(dtype)
        if shape is None:
            shape = np.broadcast(np.asarray(low), np.asarray(high)).shape
        self.shape = tuple(int(s) for s in shape)
        self.low = np.broadcast_to(np.asarray(low, dtype=self.dtype), self.shape).copy()
        self.high = np.broadcast_to(np.asarray(high, dtype=self.dtype), self.shape).copy()
        self._rng = np.random.default_rng(seed)

    def seed(self, seed=None):
        self._rng = np.random.default_rng(seed)
        return [seed]

    def sample(self):
        if np.issubdtype(self.dtype, np.integer):
            return self._rng.integers(self.low, self.high.astype(np.int64) + 1,
                                      size=self.shape).astype(self.dtype)
        return self._rng.uniform(self.low, self.high, size=self.shape).astype(self.dtype)

    def contains(self, x) -> bool:
        x = np.asarray(x)
        if x.shape != self.shape:
            return False
        if not np.can_cast(x.dtype, self.dtype, casting="same_kind"):
            return False
        return bool(np.all(x >= self.low) and np.all(x <= self.high))

    __contains__ = contains

    def __repr__(self):
        return f"Box({self.low.min()}, {self.high.max()}, {self.shape}, {self.dtype})"


class _Dict:
    """A dictionary of spaces; samples and observations are dicts with the same keys."""

    def __init__(self, spaces: dict, seed=None):
        self.spaces = dict(spaces)
        self.shape = None
        self.dtype = None
        if seed is not None:
            self.seed(seed)

    def seed(self, seed=None):
        rng = np.random.default_rng(seed)
        for s in self.spaces.values():
            s.seed(int(rng.integers(2**31)))
        return [seed]

    def sample(self):
        return {k: s.sample() for k, s in self.spaces.items()}

    def contains(self, x) -> bool:
        return (isinstance(x, dict) and set(x) == set(self.spaces)
                and all(self.spaces[k].contains(v) for k, v in x.items()))

    __contains__ = contains

    def __getitem__(self, key):
        return self.spaces[key]

    def keys(self):
        return self.spaces.keys()

    def __repr__(self):
        return "Dict(" + ", ".join(f"{k}: {v}" for k, v in self.spaces.items()) + ")"


class _Env:
    """What gymnasium.Env provides that vcsim's environments use."""

    metadata: dict = {"render_modes": []}
    render_mode = None
    observation_space = None
    action_space = None
    _np_random = None

    @property
    def np_random(self) -> np.random.Generator:
        if self._np_random is None:
            self._np_random = np.random.default_rng()
        return self._np_random

    def reset(self, *, seed=None, options=None):
        if seed is not None:
            self._np_random = np.random.default_rng(seed)

    def close(self):
        pass

    @property
    def unwrapped(self):
        return self

    def __enter__(self):
        return self

    def __exit__(self, *args):
        self.close()
        return False


if HAVE_GYMNASIUM:  # pragma: no cover
    Box = _gym_spaces.Box
    Dict = _gym_spaces.Dict
    Env = _gym.Env
else:
    Box = _Box
    Dict = _Dict
    Env = _Env
