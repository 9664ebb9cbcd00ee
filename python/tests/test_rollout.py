"""Distributed rollouts: the same episodes whatever the number of MPI processes."""
import json
import os
import subprocess
import sys

import pytest

ENV = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1",
           OMPI_MCA_rmaps_base_oversubscribe="1")
ARGS = ["-m", "vcsim.rollout", "--env", "ArchNavigation", "--seeds", "0:4", "--policy",
        "random", "--max-steps", "15"]


def episodes(path):
    with open(path) as f:
        eps = json.load(f)["episodes"]
    for e in eps:
        e.pop("wall_s")
    return eps


def test_two_processes_give_the_episodes_of_one(tmp_path):
    one, two = tmp_path / "one.json", tmp_path / "two.json"
    subprocess.run([sys.executable, *ARGS, "--out", str(one)], check=True, env=ENV)
    subprocess.run(["mpirun", "-np", "2", sys.executable, *ARGS, "--out", str(two)],
                   check=True, env=ENV, timeout=600)
    e1, e2 = episodes(one), episodes(two)
    assert [e["seed"] for e in e1] == [0, 1, 2, 3]
    assert e1 == e2
    with open(two) as f:
        assert json.load(f)["summary"]["processes"] == 2


@pytest.mark.parametrize("args,message", [
    (["--seeds", "a:b"], "--seeds: expected"),
    (["--env", "Nowhere"], "--env: expected"),
    (["--policy", "clever"], "--policy: expected"),
    (["--option", "control_hz=0"], "control_hz"),
])
def test_bad_arguments_exit_2_with_a_message(args, message):
    r = subprocess.run([sys.executable, "-m", "vcsim.rollout", *args], capture_output=True,
                       text=True, env=ENV)
    assert r.returncode == 2 and message in r.stderr
