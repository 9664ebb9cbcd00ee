"""Several environments stepped side by side in threads (the engine releases the GIL while it
steps), in the conventions of gymnasium's vector environments: batched observations (a dict of
stacked arrays), rewards, terminations and truncations as arrays, and automatic reset of an
environment whose episode ended (its last observation and info in infos["final_observation"]
and infos["final_info"])."""
from __future__ import annotations

import concurrent.futures

import numpy as np

from .. import _vcsim
from ._spaces import Box, Dict

__all__ = ["ThreadVectorEnv"]


def _stack(items):
    if isinstance(items[0], dict):
        return {k: np.stack([it[k] for it in items]) for k in items[0]}
    return np.stack(items)


def _batched(space, n):
    if isinstance(space, Dict):
        return Dict({k: _batched(s, n) for k, s in space.spaces.items()})
    return Box(np.stack([space.low] * n), np.stack([space.high] * n), dtype=space.dtype)


class ThreadVectorEnv:
    """num_envs copies of an environment, stepped in parallel threads in one call.

    ``ThreadVectorEnv(vcsim.envs.ArchNavigation, 2, observation="tracking3d")`` makes two
    ArchNavigation(observation="tracking3d"); ``ThreadVectorEnv([make_a, make_b])`` takes
    factories. reset(seed=s) seeds environment i with s + i, so a vector run gives the same
    episodes as stepping the environments one by one with those seeds.

    Each environment's physics steps on a thread of its own and on that thread only
    (``threads=1`` of the environment, Simulator.threads), so that N environments keep N cores
    busy rather than each one's parallel collision queries competing for the same cores;
    ``sim_threads=0`` leaves the environments' own setting. The results are the same either way.

    step() waits for every environment (gymnasium's synchronous convention), so it goes at the
    pace of the slowest physics of each step. ``send(actions, env_ids)`` and ``recv()`` (as
    EnvPool's asynchronous mode) let each environment step on as soon as it has its action:
    recv() returns the environments that have finished, ``infos["env_id"]`` saying which.
    """

    def __init__(self, env_fns, num_envs=None, threads=None, sim_threads=1, **kwargs):
        if callable(env_fns) and num_envs is not None:
            if int(num_envs) < 1:
                raise ValueError(f"num_envs: expected at least 1, got {num_envs}")
            self.envs = [env_fns(**kwargs) for _ in range(int(num_envs))]
        elif isinstance(env_fns, (list, tuple)) and env_fns and num_envs is None:
            self.envs = [f() for f in env_fns]
        else:
            raise ValueError("env_fns: expected an environment class or factory with num_envs, "
                             "or a non-empty list of factories")
        self.num_envs = len(self.envs)
        if int(sim_threads) < 0:
            raise ValueError(f"sim_threads: expected 0 or more, got {sim_threads!r}")
        if int(sim_threads) > 0:
            for e in self.envs:
                if hasattr(e, "threads"):
                    e.threads = int(sim_threads)
        self.single_observation_space = self.envs[0].observation_space
        self.single_action_space = self.envs[0].action_space
        self.observation_space = _batched(self.single_observation_space, self.num_envs)
        self.action_space = _batched(self.single_action_space, self.num_envs)
        self._pool = concurrent.futures.ThreadPoolExecutor(max_workers=threads or self.num_envs)
        # vcsim's own environments step their physics on a Stepper's threads; others in the pool.
        self._together = all(hasattr(e, "_begin_step") and hasattr(e, "_end_step")
                             for e in self.envs)
        self._stepper = _vcsim.Stepper(self.num_envs) if self._together else None
        self._sent = set()  # environments sent a step with send() and not yet recv()-ed

    def reset(self, *, seed=None, options=None):
        seeds = [None if seed is None else int(seed) + i for i in range(self.num_envs)]
        out = list(self._pool.map(lambda ie: ie[1].reset(seed=seeds[ie[0]], options=options),
                                  enumerate(self.envs)))
        return _stack([o for o, _ in out]), {"envs": [i for _, i in out]}

    def step(self, actions):
        actions = np.asarray(actions)
        want = (self.num_envs,) + tuple(self.single_action_space.shape)
        if actions.shape != want:
            raise ValueError(f"actions: expected shape {want}, got {actions.shape}")

        one = self._finish
        if self._together:
            if self._stepper.running:
                raise RuntimeError("step() while environments sent with send() are still "
                                   "stepping: recv() them first")
            # Every environment's physics started on the stepper's threads (every action
            # checked first), then each one's reward, observation and reset in this thread as
            # its physics comes back, while the others' still runs.
            full = [e._begin_step(a) for e, a in zip(self.envs, actions)]
            for i, e in enumerate(self.envs):
                self._stepper.start(i, e.sim, full[i], e.control_steps)
            out = [None] * self.num_envs
            try:
                for _ in range(self.num_envs):
                    i = self._stepper.wait()
                    out[i] = one(i, self.envs[i]._end_step())
            finally:
                while self._stepper.running:  # after an exception: the others' steps finish
                    try:
                        self._stepper.wait()
                    except Exception:
                        pass
        else:
            out = list(self._pool.map(lambda i: one(i, self.envs[i].step(actions[i])),
                                      range(self.num_envs)))
        return self._batch(out)

    # ---- asynchronous stepping, as EnvPool's send / recv: each environment steps on as soon as
    # it is given its action, and recv() returns the environments whose steps have finished.
    def send(self, actions, env_ids=None):
        """Starts a step of each environment in env_ids (all by default) with actions[k] for
        env_ids[k]; returns at once. Every action is checked before any environment moves."""
        if not self._together:
            raise TypeError("send/recv: only for vcsim's own environments")
        ids = np.arange(self.num_envs) if env_ids is None else np.asarray(env_ids, dtype=int)
        actions = np.asarray(actions)
        want = (len(ids),) + tuple(self.single_action_space.shape)
        if ids.ndim != 1 or actions.shape != want:
            raise ValueError(f"actions: expected shape {want} for env_ids {ids.tolist()}, got "
                             f"{actions.shape}")
        if len(set(ids.tolist())) != len(ids) or any(not 0 <= i < self.num_envs for i in ids):
            raise ValueError(f"env_ids: expected distinct indices in [0, {self.num_envs}), got "
                             f"{ids.tolist()}")
        busy = sorted(self._sent.intersection(ids.tolist()))
        if busy:
            raise ValueError(f"env_ids: {busy} still stepping (recv() them first)")
        full = [self.envs[i]._begin_step(a) for i, a in zip(ids, actions)]
        for i, f in zip(ids, full):
            self._stepper.start(int(i), self.envs[i].sim, f, self.envs[i].control_steps)
            self._sent.add(int(i))

    def recv(self, batch_size=1):
        """(obs, rewards, terminated, truncated, infos) of the next batch_size environments to
        finish the steps sent, in the order they finished; infos["env_id"] says which (an
        environment whose episode ended is reset, as step() does)."""
        if not self._together:
            raise TypeError("send/recv: only for vcsim's own environments")
        if not 1 <= int(batch_size) <= self._stepper.running:
            raise ValueError(f"batch_size: expected 1 to the {self._stepper.running} "
                             f"environments stepping, got {batch_size}")
        ids = []
        for _ in range(int(batch_size)):
            i = self._stepper.wait()
            self._sent.discard(i)
            ids.append(i)
        obs, r, term, trunc, infos = self._batch(
            [self._finish(i, self.envs[i]._end_step()) for i in ids])
        infos["env_id"] = np.array(ids, dtype=np.int64)
        return obs, r, term, trunc, infos

    def _finish(self, i, end):
        """Environment i's step result, reset if its episode ended."""
        env = self.envs[i]
        obs, r, term, trunc, info = end
        if term or trunc:
            info = dict(info)
            final_obs, final_info = obs, info
            obs, _ = env.reset()
            return obs, r, term, trunc, {"final_observation": final_obs,
                                         "final_info": final_info}
        return obs, r, term, trunc, info

    @staticmethod
    def _batch(out):
        obs = _stack([o[0] for o in out])
        return (obs, np.array([o[1] for o in out], dtype=np.float64),
                np.array([o[2] for o in out], dtype=bool),
                np.array([o[3] for o in out], dtype=bool), {"envs": [o[4] for o in out]})

    def close(self):
        self._pool.shutdown(wait=True)
        self._stepper = None  # steps still under way finish first
        for e in self.envs:
            e.close()

    def __enter__(self):
        return self

    def __exit__(self, *args):
        self.close()
        return False
