"""vcsim: a simulator for training cardiovascular interventions, from Python.

The compiled core (``vcsim._vcsim``) holds the engine: ``Simulator`` (step, snapshot, restore,
state as numpy arrays), ``Anatomy`` (built-in and varied patients, centrelines), ``CArm``
(poses and projection), ``Fluoroscopy`` (images), ``AutopilotPolicy``, ``step_many`` (several
simulators stepped in parallel in one call) and ``Stepper`` (simulators stepped on threads of
its own, each handed back as it finishes). Units are SI
(m, rad, N, s). ``vcsim.envs`` holds learning environments in Gymnasium's conventions.
See docs/python.md.
"""
from ._vcsim import (  # noqa: F401
    Anatomy,
    Autopilot,
    AutopilotPolicy,
    CArm,
    Fluoroscopy,
    InputError,
    Simulator,
    Snapshot,
    Stepper,
    step_many,
)

__all__ = ["Anatomy", "Autopilot", "AutopilotPolicy", "CArm", "Fluoroscopy", "InputError", "Simulator",
           "Snapshot", "Stepper", "step_many"]
