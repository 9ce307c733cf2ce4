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
import torch

from .adversary_net import AdversaryNet, load_adversary
from .envs import ObsLayout
from .policy import in_blocks
from .registry import ATTACKS, WHITE_BOX, adversary_path, check_name


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


class FGSM(Attack):
    """White-box fast gradient sign attack on the one-step disagreement with the expert (paper §5).

    ``delta = eps * sign(grad_s ||pi(s) - pi_e(s_true)||^2)`` at ``s = s_true``, on the zero-order
    entries. With ``steps = k > 1`` it is FGSM^k (iterative FGSM): k steps of ``eps / k``, each
    projected back onto the ±eps box, keeping per observation the iterate with the largest loss.
    """

    name = "fgsm"

    def __init__(self, layout: ObsLayout, eps: float, victim, expert, steps: int = 1):
        super().__init__(layout, eps)
        if victim is None or expert is None:
            raise ValueError(f"attack {self.name} is white-box: it needs the victim policy and the expert")
        if steps < 1:
            raise ValueError(f"FGSM steps must be >= 1, got {steps}")
        self.victim, self.expert, self.steps = victim, expert, int(steps)

    def loss(self, true_obs: np.ndarray, delta: np.ndarray, label: np.ndarray) -> np.ndarray:
        return ((self.victim.act(true_obs + delta) - label) ** 2).sum(axis=1)

    def propose(self, true_obs, rngs):
        label = self.expert.act(true_obs)
        delta = np.zeros_like(true_obs)
        best, best_loss = delta, np.full(len(true_obs), -np.inf)
        for _ in range(self.steps):
            grad = self.victim.loss_gradient(true_obs + delta, label)
            delta = self.project(delta + (self.eps / self.steps) * np.sign(grad))
            if self.steps == 1:
                return delta
            loss = self.loss(true_obs, delta, label)
            better = loss > best_loss
            best = np.where(better[:, None], delta, best)
            best_loss = np.where(better, loss, best_loss)
        return best


class FGSMk(FGSM):
    name = "fgsm_k"

    def __init__(self, layout: ObsLayout, eps: float, victim, expert, steps: int = 10):
        super().__init__(layout, eps, victim, expert, steps)


class LearnedAttack(Attack):
    """ARIL-A at evaluation: ``delta ~ N(f(s), std)`` clipped to ±eps, drawn from the episode's rng
    (``stochastic``, as the paper samples it), or the mean ``f(s)``. With ``eps`` other than the one it
    was trained with, the whole perturbation is scaled by ``eps / trained eps`` (eps sweeps: the same
    learned direction, a different budget)."""

    name = "aril_a"

    def __init__(self, layout: ObsLayout, net: AdversaryNet, stochastic: bool = True, eps: float | None = None):
        super().__init__(layout, net.eps if eps is None else eps)
        self.net, self.stochastic = net, stochastic
        self.scale = self.eps / net.eps
        self.std = net.log_std.detach().exp().double().numpy()

    @torch.inference_mode()
    def propose(self, true_obs, rngs):
        blocks, n = in_blocks(true_obs)  # batch-invariant, like the policies
        mean = torch.cat([self.net.mean(b) for b in blocks])[:n].double().numpy()
        delta = np.zeros_like(true_obs)
        delta[:, : self.layout.n_position] = mean
        if self.stochastic:
            for row, rng in enumerate(rngs):
                delta[row, : self.layout.n_position] += self.std * rng.standard_normal(len(self.std))
        return delta * self.scale


CLASSES: dict[str, type[Attack]] = {cls.name: cls for cls in (NoAttack, RandomAttack, FGSM, FGSMk)}


def make_attack(name: str, layout: ObsLayout, eps: float, victim=None, expert=None, steps: int | None = None,
                adversary: str | None = None, mode: str | None = None, rescale: bool = False) -> Attack:
    """An attack by name. The white-box ones (fgsm, fgsm_k) need the victim and the expert; aril_a
    needs an adversary file (default: the bundled one against the bundled learner; its eps is the one
    it was trained with, unless ``rescale`` scales it to ``eps``)."""
    check_name("attack", name, ATTACKS)
    if name == "aril_a":
        return _learned_attack(layout, eps, adversary, mode, rescale)
    if name in WHITE_BOX:
        kwargs = {} if steps is None else {"steps": steps}
        return CLASSES[name](layout, eps, victim, expert, **kwargs)
    return CLASSES[name](layout, eps)


def _learned_attack(layout: ObsLayout, eps: float, adversary: str | None, mode: str | None,
                    rescale: bool) -> LearnedAttack:
    if not adversary:
        bundled = adversary_path(layout.env_id, mode or "sensory")
        if not bundled.exists():
            raise ValueError(f"attack aril_a needs an adversary file: no bundled one for {layout.env_id} "
                             f"{mode} (looked for {bundled}); pass attack_file:= (from aril train-adversary)")
        adversary = str(bundled)
    net = load_adversary(adversary, layout.env_id, mode)
    if eps and abs(eps - net.eps) > 1e-12 and not rescale:
        raise ValueError(f"{adversary} was trained with eps={net.eps}, not eps={eps} (rescale:=true scales it)")
    return LearnedAttack(layout, net, eps=eps if eps and rescale else None)
