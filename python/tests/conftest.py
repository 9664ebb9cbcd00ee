import os
import sys

import pytest

# The build tree's package (ctest sets PYTHONPATH; this covers a direct pytest run from the
# source tree after `make build`).
_build = os.path.join(os.path.dirname(__file__), "..", "..", "build", "python")
if "vcsim" not in sys.modules and os.path.isdir(_build) and _build not in sys.path:
    sys.path.insert(0, os.path.abspath(_build))

import vcsim  # noqa: E402


def arch_scenario(nodes=64, dt_ms=1.0):
    return {
        "format": "vcsim-scenario", "version": 1, "name": "arch-test", "anatomy": "default",
        "motion": {"beating": False}, "dt_ms": dt_ms, "time_limit_s": 600,
        "instruments": [{"name": "wire", "catalogue": "wire-035-angled-hydrophilic",
                         "max_nodes": nodes, "tip_segment_mm": 2}],
        "input": {"type": "autopilot"},
        "autopilot": [{"action": "navigate", "instrument": "wire",
                       "goal": {"segment": "left_common_carotid", "distance_mm": 30},
                       "speed_mm_s": 50}],
    }


@pytest.fixture(scope="session")
def arch_tree():
    return vcsim.Anatomy.builtin("arch")


@pytest.fixture()
def arch_sim(arch_tree):
    return vcsim.Simulator(arch_scenario(), anatomy=arch_tree)
