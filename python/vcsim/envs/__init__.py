"""Learning environments in Gymnasium's conventions (docs/python.md): reset(seed, options) ->
(obs, info), step(action) -> (obs, reward, terminated, truncated, info), observation_space,
action_space, render(). They are gymnasium.Env subclasses when gymnasium is installed and work
without it."""
from ._spaces import HAVE_GYMNASIUM, Box, Dict, Env  # noqa: F401
from .navigation import (ArchNavigation, CoronaryNavigation, Episode,  # noqa: F401
                         StartFailed)
from .vector import ThreadVectorEnv  # noqa: F401

__all__ = ["ArchNavigation", "CoronaryNavigation", "Episode", "StartFailed", "ThreadVectorEnv",
           "Box", "Dict", "Env", "HAVE_GYMNASIUM"]
