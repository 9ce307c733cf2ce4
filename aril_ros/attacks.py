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

import inspect

import numpy as np
import torch

from .adversary_net import DIFFERENCE, AdversaryNet, difference_moves, load_adversary, pushes
from .envs import ObsLayout
from .policy import in_blocks, load_policy
from .registry import ATTACKS, QUERY_ATTACKS, WHITE_BOX, adversary_path, check_name
from .step import disagreement


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

    @staticmethod
    def keep_better(delta, loss, best, best_loss):
        """The iterate of each row with the larger loss (the earlier one on a tie), and that loss: how the iterated
        attacks (FGSM^k, SPSA^k, fd_fgsm) keep their best."""
        better = loss > best_loss
        return np.where(better[:, None], delta, best), np.where(better, loss, best_loss)


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
        # each row the draws of its episode's generator, then scaled all at once: bit for bit
        # rng.uniform(-eps, eps) (-eps + 2 eps * u, the same two roundings), at a third of its cost per row
        for row, rng in zip(delta, rngs):
            rng.random(out=row[:n_pos])
        delta[:, :n_pos] = -self.eps + 2 * self.eps * delta[:, :n_pos]
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

    def propose(self, true_obs, rngs):
        label = self.expert.act(true_obs)
        delta = np.zeros_like(true_obs)
        best, best_loss = delta, np.full(len(true_obs), -np.inf)
        grad, _ = self.victim.loss_gradient(true_obs + delta, label)
        for step in range(1, self.steps + 1):
            delta = self.project(delta + (self.eps / self.steps) * np.sign(grad))
            if self.steps == 1:
                return delta
            if step < self.steps:  # the next step's gradient, and the actions at this iterate its forward pass gave
                grad, actions = self.victim.loss_gradient(true_obs + delta, label)
            else:
                actions = self.victim.act(true_obs + delta)
            best, best_loss = self.keep_better(delta, disagreement(actions, label), best, best_loss)
        return best


class FGSMk(FGSM):
    name = "fgsm_k"
    STEPS = 10
    """Its iterations unless told otherwise; FGSM by finite differences takes as many where it stands for it."""

    def __init__(self, layout: ObsLayout, eps: float, victim, expert, steps: int = STEPS):
        super().__init__(layout, eps, victim, expert, steps)


class TransferFGSM(FGSM):
    """FGSM^k on a surrogate, applied to the victim: a white-box attack on a copy of the policy learned from its
    answers (:mod:`aril_ros.surrogate`), black-box with respect to the victim itself, which it never asks."""

    name = "transfer"

    def __init__(self, layout: ObsLayout, eps: float, surrogate, expert, steps: int = 10):
        super().__init__(layout, eps, surrogate, expert, steps)


class QueryAttack(Attack):
    """Base of the black-box attacks: they ask the victim for actions (any object with ``act``), never
    for its weights, and the expert for its action on the true state (what the loss compares with).
    ``queries`` counts the observations put to the victim, ``attacked`` the observations perturbed."""

    asks_victim = True
    """Whether it queries the victim (and the expert) at all; a subclass may decide per instance."""

    def __init__(self, layout: ObsLayout, eps: float, victim, expert):
        super().__init__(layout, eps)
        self.victim, self.expert = victim, expert
        self.queries = self.attacked = 0

    def require_answers(self) -> None:
        if self.asks_victim and (self.victim is None or self.expert is None):
            raise ValueError(f"attack {self.name} queries the victim's actions and the expert's: it needs both")

    def ask(self, obs: np.ndarray) -> np.ndarray:
        self.queries += len(obs)
        return self.victim.act(obs)

    def losses(self, true_obs: np.ndarray, candidates: np.ndarray, label: np.ndarray) -> np.ndarray:
        """``||pi(s + delta) - pi_e(s)||^2`` of ``candidates[i, j]`` (deltas of observation i), in one query batch."""
        n, m = candidates.shape[:2]
        seen = (true_obs[:, None, :] + candidates).reshape(n * m, -1)
        return disagreement(self.ask(seen).reshape(n, m, -1), label[:, None, :])

    def perturb(self, true_obs, rngs):
        self.attacked += len(true_obs)
        return super().perturb(true_obs, rngs)

    @property
    def queries_per_step(self) -> float:
        return self.queries / max(self.attacked, 1)


class SPSA(QueryAttack):
    """Black-box FGSM^k: the gradient of the one-step disagreement estimated from action queries alone.

    ``k`` iterations; each draws ``samples`` Rademacher directions ``u`` on the zero-order entries from
    the episode's rng, queries the loss at ``delta ± c u`` (``c = eps / 2``) and steps
    ``delta <- clip(delta + alpha * sign(sum (L+ - L-) u))`` with ``alpha = 2.5 eps / k`` (so a consistent
    sign reaches the box's corner); the iterate with the largest queried loss is kept. Queries per
    step: ``1 + k (2 samples + 1)``, in ``k + 1`` batches: each iterate is asked together with the
    directions around it (through a graph a batch is one round trip to the policy node and back).
    """

    name = "spsa"

    def __init__(self, layout: ObsLayout, eps: float, victim, expert, steps: int = 5, samples: int = 8):
        super().__init__(layout, eps, victim, expert)
        self.require_answers()
        if steps < 1 or samples < 1:
            raise ValueError(f"spsa needs steps >= 1 and samples >= 1, got {steps} and {samples}")
        self.steps, self.samples = int(steps), int(samples)

    def propose(self, true_obs, rngs):
        n, n_pos, eps, s = len(true_obs), self.layout.n_position, self.eps, self.samples
        label = self.expert.act(true_obs)
        delta = np.zeros_like(true_obs)
        best, best_loss = delta, np.full(n, -np.inf)
        for _ in range(self.steps):
            u = np.zeros((n, s, true_obs.shape[1]))
            for row, rng in enumerate(rngs):
                u[row, :, :n_pos] = 2.0 * rng.integers(0, 2, (s, n_pos)) - 1.0
            loss = self.losses(true_obs, np.concatenate(
                [delta[:, None], delta[:, None] + 0.5 * eps * u, delta[:, None] - 0.5 * eps * u], axis=1), label)
            best, best_loss = self.keep_better(delta, loss[:, 0], best, best_loss)
            slope = ((loss[:, 1:s + 1] - loss[:, s + 1:])[:, :, None] * u).sum(1)
            delta = self.project(delta + 2.5 * eps / self.steps * np.sign(slope))
        return self.keep_better(delta, self.losses(true_obs, delta[:, None], label)[:, 0], best, best_loss)[0]


class FiniteDifferenceFGSM(QueryAttack):
    """Black-box FGSM (FGSM^k with ``k`` > 1): the loss gradient from central finite differences of the victim's
    answers, one zero-order entry at a time (ZOO's coordinate-wise estimate, Chen et al. 2017).

    The perturbed entries are few (HalfCheetah 8, Ant 13, Swimmer 3), so ``2 n`` questions, every entry moved by
    ``± h`` (``h = eps / 100``, :data:`~aril_ros.adversary_net.DIFFERENCE`), recover
    the gradient's sign that white-box FGSM takes from the weights. Each of the ``k`` iterations steps
    ``eps / k`` (one step of ``eps`` for ``k = 1``) along that sign and projects, as FGSM^k does; for ``k > 1``
    each iterate is asked too and the one with the largest loss kept. Queries per step: ``2 n`` in one batch for
    ``k = 1``, else ``k (2 n + 1) + 1`` in ``k + 1`` batches.
    """

    name = "fd_fgsm"

    def __init__(self, layout: ObsLayout, eps: float, victim, expert, steps: int = 1):
        super().__init__(layout, eps, victim, expert)
        self.require_answers()
        if steps < 1:
            raise ValueError(f"fd_fgsm steps must be >= 1, got {steps}")
        self.steps = int(steps)
        self.moves = difference_moves(layout.n_position, layout.obs_dim, DIFFERENCE * self.eps)

    def propose(self, true_obs, rngs):
        n_pos, iterated = self.layout.n_position, self.steps > 1
        label = self.expert.act(true_obs)
        delta = np.zeros_like(true_obs)
        best, best_loss = delta, np.full(len(true_obs), -np.inf)
        for _ in range(self.steps):
            asked = delta[:, None] + self.moves[None]
            if iterated:
                asked = np.concatenate([delta[:, None], asked], axis=1)
            loss = self.losses(true_obs, asked, label)
            if iterated:
                best, best_loss = self.keep_better(delta, loss[:, 0], best, best_loss)
                loss = loss[:, 1:]
            step = np.zeros_like(true_obs)
            step[:, :n_pos] = np.sign(loss[:, :n_pos] - loss[:, n_pos:])
            delta = self.project(delta + self.eps / self.steps * step)
        if not iterated:
            return delta
        return self.keep_better(delta, self.losses(true_obs, delta[:, None], label)[:, 0], best, best_loss)[0]


class LearnedAttack(QueryAttack):
    """ARIL-A at evaluation: a perturbation drawn from the adversary given the true observation (and,
    if it takes them, the victim's and the expert's actions on it), from the episode's rng
    (``stochastic``, as the paper samples it), or the one it ranks highest.

    With ``search = K > 0`` (query-time search) it draws K candidates, adds the one it ranks highest,
    asks the victim for its actions on all K + 1 in one batch and applies the one with the largest
    disagreement: the learned prior picks where to look, the queries pick the best. With ``eps`` other
    than the one it was trained with, every perturbation is scaled by ``eps / trained eps`` (eps sweeps:
    the same learned direction, a different budget). Queries per step: 1 if it takes actions, + K + 1."""

    name = "aril_a"

    def __init__(self, layout: ObsLayout, net: AdversaryNet, stochastic: bool = True, eps: float | None = None,
                 victim=None, expert=None, search: int = 0):
        super().__init__(layout, net.eps if eps is None else eps, victim, expert)
        if search < 0:
            raise ValueError(f"search must be >= 0 candidates, got {search}")
        self.net, self.stochastic, self.search = net, stochastic, int(search)
        self.require_answers()
        self.scale = self.eps / net.eps

    @property
    def asks_victim(self) -> bool:
        return queries_victim(self.name, self.net, self.search)

    @torch.inference_mode()
    def propose(self, true_obs, rngs):
        n_pos = self.layout.n_position
        label = self.expert.act(true_obs) if self.asks_victim else None
        clean = self.ask(true_obs) if self.net.takes_actions else None
        x = self.net.inputs(true_obs, clean, label)
        blocks, n = in_blocks(x)  # batch-invariant, like the policies
        dists = [self.net.distribution(b) for b in blocks]
        draws = self.search or int(self.stochastic)
        picks = np.zeros((n, draws + 1, self.net.sample_width))
        picks[:, 0] = torch.cat([self.net.most_likely(d) for d in dists])[:n].double().numpy()
        if draws:
            picks[:, 1:] = self.draws(dists, rngs, draws)
        if self.net.directed:  # directions: the actor turns each into its perturbation, asking the victim
            picks = pushes(self.ask, true_obs, picks, self.net.eps, n_pos)
        candidates = np.zeros((n, draws + 1, true_obs.shape[1]))
        candidates[:, :, :n_pos] = picks * self.scale
        if not self.search:
            return candidates[:, -1]
        best = self.losses(true_obs, candidates, label).argmax(1)
        return candidates[np.arange(n), best]

    def draws(self, dists, rngs, k: int) -> np.ndarray:
        """``k`` perturbations (directed: directions) per row from the adversary's distribution, drawn from the row's
        rng."""
        if self.net.categorical:
            cumulative = torch.cat([d.probs for d in dists]).double().numpy().cumsum(-1)
            out = np.empty((len(rngs), k, self.net.n_position))
            for row, rng in enumerate(rngs):
                choice = (rng.random((k, self.net.n_position))[..., None] >= cumulative[row, None, :, :2]).sum(-1)
                out[row] = self.net.eps * (choice - 1.0)
            return out
        mean = torch.cat([d.mean for d in dists]).double().numpy()
        std = self.net.log_std.detach().exp().double().numpy()
        bound = np.inf if self.net.directed else self.net.eps
        return np.stack([np.clip(mean[row] + std * rng.standard_normal((k, len(std))), -bound, bound)
                         for row, rng in enumerate(rngs)])


CLASSES: dict[str, type[Attack]] = {cls.name: cls for cls in (NoAttack, RandomAttack, FGSM, FGSMk, TransferFGSM, SPSA,
                                                                   FiniteDifferenceFGSM)}


def queries_victim(attack: str, adversary: AdversaryNet | None = None, search: int = 0) -> bool:
    """Whether ``attack`` puts questions to the victim: the zeroth-order ones always, aril_a when its
    ``adversary`` takes the victim's actions or directs them, or it searches (``search`` > 0) -- in a graph,
    whether the attacker's probe client listens on ``action`` too."""
    if attack == "aril_a":
        return adversary.takes_actions or adversary.directed or search > 0
    return attack in QUERY_ATTACKS


def make_attack(name: str, layout: ObsLayout, eps: float, victim=None, expert=None, steps: int | None = None,
                adversary: str | None = None, mode: str | None = None, rescale: bool = False,
                search: int = 0, samples: int | None = None) -> Attack:
    """An attack by name. The white-box ones (fgsm, fgsm_k) need the victim and the expert; transfer the expert
    and a surrogate file (``adversary``), on which it runs FGSM^k (``steps``), never asking the victim; spsa asks
    both for actions only (``steps``: its iterations, ``samples``: its directions per iteration); aril_a
    needs an adversary file (default: the bundled one against the bundled learner; its eps is the one it
    was trained with, unless ``rescale`` scales it to ``eps``) and, when it takes actions or searches
    (``search`` candidates), the victim and the expert to query."""
    check_name("attack", name, ATTACKS)
    if name == "transfer":
        if not adversary:
            raise ValueError("attack transfer runs FGSM^k on a surrogate of the victim: pass its file as attack_file:= "
                             "(aril fit-surrogate, or a scorecard's surrogate-<mode>.pt)")
        if expert is None:
            raise ValueError("attack transfer needs the expert, whose action its loss compares with")
        return TransferFGSM(layout, eps, load_policy(adversary, layout.env_id), expert,
                            **({} if steps is None else {"steps": steps}))
    if name == "aril_a":
        return _learned_attack(layout, eps, adversary, mode, rescale, victim, expert, search)
    if name in WHITE_BOX or name in QUERY_ATTACKS:
        kwargs = {} if steps is None else {"steps": steps}
        if name == "spsa" and samples is not None:
            kwargs["samples"] = samples
        return CLASSES[name](layout, eps, victim, expert, **kwargs)
    return CLASSES[name](layout, eps)


def _learned_attack(layout: ObsLayout, eps: float, adversary: str | None, mode: str | None, rescale: bool,
                    victim, expert, search: int) -> LearnedAttack:
    _, net = learned_adversary(layout.env_id, mode, adversary, eps, rescale)
    return LearnedAttack(layout, net, eps=learned_eps(net, eps, rescale), victim=victim, expert=expert,
                         search=search)


def learned_adversary(env_id: str, mode: str | None, adversary: str | None = None, eps: float = 0.0,
                      rescale: bool = False) -> tuple[str, AdversaryNet]:
    """The file aril_a runs (``adversary``; none: the bundled one against the bundled learner) and its network,
    checked against the env and mode; an ``eps`` other than the one it was trained with needs ``rescale``."""
    if not adversary:
        bundled = adversary_path(env_id, mode or "sensory")
        if not bundled.exists():
            raise ValueError(f"attack aril_a needs an adversary file: no bundled one for {env_id} "
                             f"{mode} (looked for {bundled}); pass attack_file:= (from aril train-adversary)")
        adversary = str(bundled)
    net = load_adversary(adversary, env_id, mode)
    if eps and abs(eps - net.eps) > 1e-12 and not rescale:
        raise ValueError(f"{adversary} was trained with eps={net.eps}, not eps={eps} (rescale:=true scales it)")
    return adversary, net


def learned_eps(net: AdversaryNet, eps: float, rescale: bool) -> float:
    """The eps aril_a runs at: ``eps`` when ``rescale`` scales its adversary to it, else the adversary's own."""
    return eps if eps and rescale else net.eps


def iteration_settings(name: str, k: int = 0, samples: int = 0) -> dict[str, int | None]:
    """``k`` (iterations) and ``samples`` (spsa's directions per iteration) as attack ``name`` runs them: the ones
    given, or for 0 the attack's own defaults; None for a setting the attack does not read."""
    params = inspect.signature(CLASSES[name].__init__).parameters if name in CLASSES else {}

    def setting(param: str, given: int) -> int | None:
        return (given or params[param].default) if param in params else None

    return {"k": setting("steps", k), "samples": setting("samples", samples)}
