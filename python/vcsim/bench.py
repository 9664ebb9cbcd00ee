"""Speed of the learning environments, as JSON (docs/python.md, "Speed"):

    python3 -m vcsim.bench [--seconds 20] [--out bench.json]

- env_steps_per_s: ArchNavigation control steps (7.5 Hz) per second of one environment as built
  by default (its physics may spread collision queries over the cores), the same anatomy every
  episode (random actions that mostly push; episodes that end are reset).
- env_steps_per_s_one_core: the same with the physics on one thread (threads=1): the rate per
  core.
- vector2_steps_per_s and vector2_speedup: the same with ThreadVectorEnv of 2 environments
  (environment steps, both counted), and its ratio to one environment as built by default;
  vector2_per_core_ratio its ratio to env_steps_per_s_one_core.
- vector2_async_steps_per_s and vector2_async_speedup: the same stepped asynchronously
  (ThreadVectorEnv.send / recv, each environment given its next action as soon as its step
  comes back), and its ratio to one environment as built by default.
- reset_ms: median reset to a cached start (a snapshot restore and the first observation).
- first_reset_s: a reset to a new anatomy (the scene built and its start made).
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import time

import numpy as np

from . import envs


def _run(env_or_vec, seconds, vector):
    """Steps with random actions that mostly push (translation -20..100 % of the limit, rotation
    -100..100 %), so the wire travels up into the arch and its branches as a learner's does."""
    rng = np.random.default_rng(0)
    space = env_or_vec.action_space
    env_or_vec.reset(seed=0)
    lo = space.low.copy()
    lo[..., 0] *= 0.2
    n, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        a = rng.uniform(lo, space.high).astype(np.float32)
        out = env_or_vec.step(a)
        if vector:
            n += env_or_vec.num_envs
        else:
            n += 1
            if out[2] or out[3]:
                env_or_vec.reset()
    return n / (time.perf_counter() - t0)


def _run_async(vec, seconds):
    """_run's actions and count, each environment sent its next action when it comes back."""
    rng = np.random.default_rng(0)
    space = vec.single_action_space
    vec.reset(seed=0)
    lo = space.low.copy()
    lo[..., 0] *= 0.2

    def act():
        return rng.uniform(lo, space.high).astype(np.float32)[None]

    for i in range(vec.num_envs):
        vec.send(act(), env_ids=[i])
    n, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        *_, infos = vec.recv()
        n += 1
        vec.send(act(), env_ids=infos["env_id"])
    rate = n / (time.perf_counter() - t0)
    while vec._stepper.running:
        vec.recv()
    return rate


def main(argv=None):
    p = argparse.ArgumentParser(prog="python3 -m vcsim.bench")
    p.add_argument("--seconds", type=float, default=20.0)
    p.add_argument("--out", default=None)
    a = p.parse_args(argv)
    kw = dict(randomize=False)
    t0 = time.perf_counter()
    env = envs.ArchNavigation(**kw)
    env.reset(seed=0)
    first_reset = time.perf_counter() - t0
    resets = []
    for s in range(50):
        t = time.perf_counter()
        env.reset(seed=s)
        resets.append(time.perf_counter() - t)
    one = _run(env, a.seconds, False)
    env.threads = 1
    one_core = _run(env, a.seconds, False)
    vec = envs.ThreadVectorEnv(envs.ArchNavigation, 2, **kw)
    two = _run(vec, a.seconds, True)
    two_async = _run_async(vec, a.seconds)
    vec.close()
    res = {"env": "ArchNavigation", "control_hz": env.control_hz, "dt_s": env.sim.dt,
           "physics_steps_per_env_step": env.control_steps,
           "wire_nodes": env.wire_nodes,
           "env_steps_per_s": round(one, 1), "env_steps_per_s_one_core": round(one_core, 1),
           "vector2_steps_per_s": round(two, 1), "vector2_speedup": round(two / one, 3),
           "vector2_per_core_ratio": round(two / one_core, 3),
           "vector2_async_steps_per_s": round(two_async, 1),
           "vector2_async_speedup": round(two_async / one, 3),
           "reset_ms": round(1e3 * float(np.median(resets)), 4),
           "first_reset_s": round(first_reset, 3), "cores": os.cpu_count(),
           "machine": platform.processor() or platform.machine()}
    env.close()
    text = json.dumps(res, indent=1)
    if a.out:
        with open(a.out, "w") as f:
            f.write(text + "\n")
    print(text)


if __name__ == "__main__":
    main()
