"""Gymnasium MuJoCo environments with a known observation layout, stepped many at a time.

- :mod:`.layout`: where each observation entry comes from (:func:`layout_of`), and ``gym.make`` with clear errors.
- :mod:`.rules`: gymnasium v5's rewards and terminations over a batch of rows, bit for bit (:data:`BATCHED_RULES`).
- :mod:`.pool`: the threads that step many simulators' physics side by side, owned by whoever steps them.
- :mod:`.sim`: :class:`MujocoSim` (one env with full-state access) and the step of many (:func:`step_sims`).
"""
from .layout import (HORIZON, OTHER, POSITION, VELOCITY, EnvLayoutError, ObsLayout, layout_of, make_gym_env,
                     qpos_names, qvel_names)
from .pool import PhysicsPool, physics_threads
from .rules import BATCHED_RULES, Frame
from .sim import MujocoSim, observe_sims, perturb_sims, step_sims

__all__ = ["BATCHED_RULES", "HORIZON", "OTHER", "POSITION", "VELOCITY", "EnvLayoutError", "Frame", "MujocoSim",
           "ObsLayout", "PhysicsPool", "layout_of", "make_gym_env", "observe_sims", "perturb_sims",
           "physics_threads", "qpos_names", "qvel_names", "step_sims"]
