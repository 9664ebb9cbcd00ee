"""Episodes of a policy over a list of seeds, across processes and machines with MPI.

    mpirun -np 4 python3 -m vcsim.rollout --env ArchNavigation --seeds 0:100 \\
        --policy autopilot --out episodes.json

Seeds are dealt to the ranks round robin; each episode depends only on its seed (the
environment's draw and, for the random policy, its actions), so the episodes written by rank 0,
sorted by seed, are the same whatever the number of processes. Without mpi4py, or run without
mpirun, it runs every seed in this process. docs/python.md.
"""
from __future__ import annotations

import argparse
import importlib
import json
import sys
import time

import numpy as np

from . import envs as _envs


def parse_seeds(text: str) -> list[int]:
    """'0:100' (a range), '3,5,9' (a list) or '7' (one seed)."""
    try:
        if ":" in text:
            a, b = text.split(":", 1)
            seeds = list(range(int(a), int(b)))
        else:
            seeds = [int(s) for s in text.split(",") if s.strip()]
    except ValueError:
        raise ValueError(f"--seeds: expected 'A:B', 'a,b,c' or 'a', got {text!r}") from None
    if not seeds:
        raise ValueError(f"--seeds: expected at least one seed, got {text!r}")
    return seeds


def make_policy(name: str, env, seed: int):
    """'autopilot', 'random', 'zero' or 'module:factory' (factory(env, seed) -> policy(obs))."""
    if name == "autopilot":
        return env.autopilot()
    if name == "random":
        space = env.action_space
        rng = np.random.default_rng(seed)
        return lambda obs: rng.uniform(space.low, space.high).astype(np.float32)
    if name == "zero":
        return lambda obs: np.zeros(env.action_space.shape, dtype=np.float32)
    if ":" in name:
        mod, fn = name.split(":", 1)
        return getattr(importlib.import_module(mod), fn)(env, seed)
    raise ValueError(f"--policy: expected 'autopilot', 'random', 'zero' or 'module:factory', "
                     f"got {name!r}")


def run_episode(env, policy_name: str, seed: int, max_steps: int | None = None) -> dict:
    obs, info = env.reset(seed=seed)
    redraws = int(info["redraws"])
    policy = make_policy(policy_name, env, seed)
    total, steps, done = 0.0, 0, False
    t0 = time.perf_counter()
    gave_up = False
    while not done:
        obs, r, term, trunc, info = env.step(policy(obs))
        total += r
        steps += 1
        # The autopilot that gave up only holds still: the episode is lost, end it.
        gave_up = bool(getattr(policy, "failed", False)) and not term
        done = term or trunc or gave_up or (max_steps is not None and steps >= max_steps)
    ep = info["episode"]
    return {"seed": seed, "success": bool(info["success"]), "steps": steps,
            "time_s": round(float(info["time"]), 6), "return": total,
            "path_length_mm": round(info["path_length"] * 1e3, 3),
            "target": ep.target_segment, "anatomy": ep.anatomy,
            "instruments": list(ep.instruments), "gave_up": gave_up,
            "redraws": redraws,
            "state_hash": env.sim.state_hash,
            "wall_s": time.perf_counter() - t0}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python3 -m vcsim.rollout", description=__doc__.split("\n")[0])
    p.add_argument("--env", default="ArchNavigation",
                   help="an environment of vcsim.envs (ArchNavigation, CoronaryNavigation)")
    p.add_argument("--seeds", default="0:10", help="'A:B', 'a,b,c' or 'a'")
    p.add_argument("--policy", default="autopilot")
    p.add_argument("--max-steps", type=int, default=None,
                   help="end each episode after this many steps (default: the environment's)")
    p.add_argument("--option", action="append", default=[], metavar="KEY=JSON",
                   help="an environment keyword, e.g. --option observation='\"tracking3d\"'")
    p.add_argument("--out", default=None, help="episodes as JSON (rank 0); default: stdout")
    a = p.parse_args(argv)
    try:
        seeds = parse_seeds(a.seeds)
        if not hasattr(_envs, a.env) or a.env in ("Box", "Dict", "Env", "Episode"):
            raise ValueError(f"--env: expected ArchNavigation or CoronaryNavigation, got {a.env!r}")
        kw = {}
        for o in a.option:
            k, _, v = o.partition("=")
            try:
                kw[k] = json.loads(v)
            except json.JSONDecodeError:
                raise ValueError(f"--option {k}: expected a JSON value, got {v!r}") from None
        if a.max_steps is not None and a.max_steps < 1:
            raise ValueError("--max-steps: expected at least 1")
        env = getattr(_envs, a.env)(**kw)
        make_policy(a.policy, env, 0) if a.policy != "autopilot" else None
    except (ValueError, TypeError) as e:
        print(f"vcsim.rollout: {e}", file=sys.stderr)
        return 2
    try:
        from mpi4py import MPI
        comm = MPI.COMM_WORLD
    except ImportError:
        comm = None
    rank = comm.Get_rank() if comm else 0
    size = comm.Get_size() if comm else 1
    mine = []
    for s in seeds[rank::size]:
        try:
            mine.append(run_episode(env, a.policy, s, a.max_steps))
        except Exception as e:  # an episode that could not run counts as a failure
            mine.append({"seed": s, "success": False, "error": f"{type(e).__name__}: {e}"})
    env.close()
    gathered = comm.gather(mine, root=0) if comm else [mine]
    if rank != 0:
        return 0
    episodes = sorted((e for part in gathered for e in part), key=lambda e: e["seed"])
    n = len(episodes)
    ok = [e for e in episodes if e["success"]]
    summary = {"env": a.env, "policy": a.policy, "processes": size, "episodes": n,
               "success_rate": len(ok) / n,
               "mean_time_to_target_s": (sum(e["time_s"] for e in ok) / len(ok)) if ok else None,
               "mean_steps": sum(e.get("steps", 0) for e in episodes) / n,
               "errors": sum(1 for e in episodes if "error" in e)}
    text = json.dumps({"summary": summary, "episodes": episodes}, indent=1)
    if a.out:
        with open(a.out, "w") as f:
            f.write(text + "\n")
    else:
        print(text)
    print(json.dumps(summary), file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
