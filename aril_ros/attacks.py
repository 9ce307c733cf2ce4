"""Attacks: perturbations of the zero-order observation within an L-infinity budget ``eps``.

An attack maps a batch of *true* observations to perturbations ``delta`` (same shape). The rollout
engine decides what the perturbation touches: in ``sensory`` mode only what the policy sees, in
``physical`` mode the simulator's real state. Every perturbation passes through
:meth:`Attack.project`, so whatever an attack proposes, ``|delta| <= eps`` on the zero-order entries
and ``delta == 0`` elsewhere.

Randomness comes from one ``np.random.Generator`` per episode, handed in by the engine, so an
episode's perturbations do not depend on how many episodes run side by side.
"""
from __future__ import annotations

import numpy as np

from .envs import ObsLayout


class Attack:
    """Base class. Subclasses implement :meth:`propose`; the engine calls :meth:`perturb`."""

    name = "none"

    def __init__(self, layout: ObsLayout, eps: float):
        if not np.isfinite(eps) or eps < 0:
            raise ValueError(f"eps must be a finite number >= 0, got {eps}")
        self.layout = layout
        self.eps = float(eps)
        self.mask = layout.zero_order_mask

    def propose(self, true_obs: np.ndarray, rngs: list[np.random.Generator]) -> np.ndarray:
        raise NotImplementedError

    def project(self, delta: np.ndarray) -> np.ndarray:
        """Onto the allowed set: the ±eps box on zero-order entries, zero elsewhere."""
        return np.where(self.mask, np.clip(delta, -self.eps, self.eps), 0.0)

    def perturb(self, true_obs: np.ndarray, rngs: list[np.random.Generator]) -> np.ndarray:
        return self.project(self.propose(true_obs, rngs))


class NoAttack(Attack):
    name = "none"

    def propose(self, true_obs, rngs):
        return np.zeros_like(true_obs)


class RandomAttack(Attack):
    """Uniform noise in ``[-eps, eps]`` on every zero-order entry."""

    name = "random"

    def propose(self, true_obs, rngs):
        n_pos = self.layout.n_position
        delta = np.zeros_like(true_obs)
        for i, rng in enumerate(rngs):
            delta[i, :n_pos] = rng.uniform(-self.eps, self.eps, n_pos)
        return delta


ATTACKS: dict[str, type[Attack]] = {cls.name: cls for cls in (NoAttack, RandomAttack)}


def make_attack(name: str, layout: ObsLayout, eps: float) -> Attack:
    if name not in ATTACKS:
        raise ValueError(f"unknown attack {name!r}; choose one of {', '.join(ATTACKS)}")
    return ATTACKS[name](layout, eps)
