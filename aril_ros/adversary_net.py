"""The learned adversary's network and its file format (ARIL-A, paper §4.2; trained by :mod:`aril_ros.adversary`).

The adversary f maps what it knows of a step to a distribution over perturbations of the zero-order
entries, within ``±eps``. Two choices, recorded in the file's meta:

- ``policy``: ``categorical`` (default for new files) — per zero-order entry, one of ``{-eps, 0, +eps}``.
  A one-step attack's optimum lies on the corners of the L-infinity box, which this policy reaches by
  one choice per entry; ``gaussian`` (files made before it) — mean ``eps * tanh(net(x))`` and a
  state-independent std initialised to ``0.1 * eps``, samples clipped to the box; ``directed`` — PA-AD's split
  (Sun et al. 2022) made black-box: the network is a director, a Normal over a direction in the victim's
  *action* space, and :func:`pushes` the actor, the corner of the box that moves the victim's action furthest
  along it to first order, from the victim's answers alone (finite differences, no gradients). The director
  learns where the victim's action should go; the actor finds, state by state, how to send it there, which a
  map from states to perturbations would have to learn for every state.
- ``inputs``: ``state`` — the *true* observation ``s`` alone; ``state+actions`` — ``s``, the victim's
  action on ``s`` unperturbed and the expert's action on ``s``. Both actions are answers to queries the
  attack may make of a black box (never its weights): the map need not rediscover the victim from the
  state alone.

A value head holds the learned remainder of the trainer's value (see :mod:`aril_ros.adversary`).

Adversary files (``*.pt``) use the policy-file container (:func:`aril_ros.policy.save_weights`) with
format ``aril_ros.adversary`` and a JSON meta: env id, mode, eps, sizes, policy, inputs, hidden width,
input normalisation (over the inputs) and provenance (victim, expert, training steps, seconds, seed,
command and settings).
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import torch
from torch import nn

from .policy import PolicyFileError, load_weights, save_weights

POLICIES = ("categorical", "gaussian", "directed")
INPUTS = ("state", "state+actions")
CHOICES = 3
"""A categorical adversary's choices per entry, in order: -eps, 0, +eps."""
DIFFERENCE = 0.01
"""The finite differences' step as a share of eps (the directed actor's, FGSM by finite differences'): small enough
for the local slope, large enough above float32's rounding."""


def difference_moves(n_position: int, obs_dim: int, step: float) -> np.ndarray:
    """``2 n_position`` observation offsets: ``+step`` on each zero-order entry in turn, then ``-step`` on each."""
    moves = np.zeros((2 * n_position, obs_dim))
    moves[np.arange(n_position), np.arange(n_position)] = step
    moves[n_position + np.arange(n_position), np.arange(n_position)] = -step
    return moves


def pushes(ask, obs: np.ndarray, directions: np.ndarray, eps: float, n_position: int) -> np.ndarray:
    """The directed adversary's actor: for each row of ``obs`` and each of its ``directions`` (``n × k × act_dim``),
    the perturbation of the zero-order entries (``n × k × n_position``) that moves the victim's action furthest
    along the direction to first order, ``eps * sign(J^T d)``. ``J``, the victim's action's slope along each
    zero-order entry, comes from central differences: ``2 n_position`` questions a row, one ``ask`` for all."""
    n, obs_dim = obs.shape
    moves = difference_moves(n_position, obs_dim, DIFFERENCE * eps)
    answers = ask((obs[:, None, :] + moves[None]).reshape(n * len(moves), obs_dim)).reshape(n, len(moves), -1)
    slope = answers[:, :n_position] - answers[:, n_position:]  # n × n_position × act_dim, times 2 step
    return eps * np.sign(np.einsum("npa,nka->nkp", slope, directions))


def mlp(n_in: int, hidden: int, n_out: int) -> nn.Sequential:
    return nn.Sequential(nn.Linear(n_in, hidden), nn.Tanh(), nn.Linear(hidden, hidden), nn.Tanh(),
                         nn.Linear(hidden, n_out))


def input_size(meta: dict) -> int:
    """Length of the adversary's input row: the observation, and the two actions if it takes them."""
    return meta["obs_dim"] + (2 * meta["act_dim"] if meta.get("inputs", "state") == "state+actions" else 0)


def input_rows(inputs: str, obs: np.ndarray, victim_action: np.ndarray | None,
               expert_action: np.ndarray | None) -> np.ndarray:
    """The adversary's input rows for its ``inputs``: ``obs``, followed by both actions for ``state+actions``."""
    if inputs == "state":
        return obs
    if victim_action is None or expert_action is None:
        raise ValueError("this adversary takes the victim's and the expert's actions on the true state")
    return np.concatenate([obs, victim_action, expert_action], axis=1)


class AdversaryNet(nn.Module):
    """The adversary's policy head (categorical logits or a Gaussian mean with a learnable log-std)
    and its value head, both on the normalised input row (see the module docstring)."""

    def __init__(self, meta: dict):
        super().__init__()
        meta.setdefault("policy", "gaussian")  # files made before the categorical policy say nothing
        meta.setdefault("inputs", "state")
        for key, allowed in (("policy", POLICIES), ("inputs", INPUTS)):
            if meta[key] not in allowed:
                raise ValueError(f"adversary {key} must be one of {', '.join(allowed)}, got {meta[key]!r}")
        self.meta = meta
        n_in, n_out, hidden = input_size(meta), meta["n_position"], meta["hidden"]
        self.eps, self.n_position = float(meta["eps"]), n_out
        self.categorical = meta["policy"] == "categorical"
        self.directed = meta["policy"] == "directed"
        self.takes_actions = meta["inputs"] == "state+actions"
        # a sample's columns: a choice or a perturbation per zero-order entry, or a direction in action space
        self.sample_width = meta["act_dim"] if self.directed else n_out
        self.mean_net = mlp(n_in, hidden, n_out * CHOICES if self.categorical else self.sample_width)
        self.value_net = mlp(n_in, hidden, 1)
        if not self.categorical:  # a direction's scale does not matter: unit spread to start with
            self.log_std = nn.Parameter(torch.full((self.sample_width,), 0.0 if self.directed else
                                                   math.log(0.1 * self.eps)))
        self.register_buffer("obs_mean", torch.tensor(meta["obs_mean"], dtype=torch.float32))
        self.register_buffer("obs_std", torch.tensor(meta["obs_std"], dtype=torch.float32))

    def inputs(self, obs: np.ndarray, victim_action: np.ndarray | None, expert_action: np.ndarray | None) -> np.ndarray:
        return input_rows(self.meta["inputs"], obs, victim_action, expert_action)

    def normalise(self, x: torch.Tensor) -> torch.Tensor:
        return ((x.float() - self.obs_mean) / self.obs_std).clamp(-10.0, 10.0)

    def distribution(self, x: torch.Tensor) -> torch.distributions.Distribution:
        """Per zero-order entry: a categorical over the choice index, or a Normal over the perturbation; directed: a
        Normal over the direction."""
        out = self.mean_net(self.normalise(x))
        if self.categorical:
            # unvalidated: the samples are the distribution's own, and the checks cost more than the net
            return torch.distributions.Categorical(logits=out.reshape(len(x), self.n_position, CHOICES),
                                                   validate_args=False)
        mean = out if self.directed else self.eps * torch.tanh(out)
        return torch.distributions.Normal(mean, self.log_std.exp().expand(len(x), -1), validate_args=False)

    def log_prob_and_entropy(self, x: torch.Tensor, sample: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Per row, summed over the entries: the log-probability of ``sample`` and the entropy, PPO's two
        terms. The categorical's are written out on its normalised logits: the same log-probabilities as
        ``distribution(x).log_prob``, without torch.distributions' bookkeeping, which in a PPO minibatch
        costs more than both networks forward and backward."""
        if not self.categorical:
            dist = self.distribution(x)
            return dist.log_prob(sample).sum(-1), dist.entropy().sum(-1)
        logits = self.mean_net(self.normalise(x)).reshape(len(x), self.n_position, CHOICES)
        log_p = logits - logits.logsumexp(-1, keepdim=True)
        chosen = log_p.gather(-1, sample.long().unsqueeze(-1)).squeeze(-1)
        return chosen.sum(-1), -(log_p.exp() * log_p).sum((-2, -1))

    @property
    def input_width(self) -> int:
        return input_size(self.meta)

    def sample(self, x: torch.Tensor, gen: torch.Generator, entropy: bool = False
               ) -> tuple[torch.Tensor, torch.Tensor, float | None]:
        """A training sample per row (:meth:`draw`), its log-probability and (``entropy``) the mean entropy per entry."""
        dist = self.distribution(x)
        sample = self.draw(dist, gen)
        return sample, dist.log_prob(sample).sum(-1), (float(dist.entropy().mean()) if entropy else None)

    def draw(self, dist: torch.distributions.Distribution, gen: torch.Generator) -> torch.Tensor:
        """A sample of ``dist`` from ``gen`` (choice indices, perturbations before clipping, or directions)."""
        if self.categorical:
            flat = torch.multinomial(dist.probs.reshape(-1, CHOICES), 1, generator=gen)
            return flat.reshape(dist.probs.shape[:-1]).float()
        return dist.mean + dist.stddev * torch.randn(dist.mean.shape, generator=gen)

    def delta(self, sample: torch.Tensor) -> torch.Tensor:
        """The perturbation of the zero-order entries a sample stands for, within ±eps (a direction's: :func:`pushes`,
        which asks the victim)."""
        if self.directed:
            raise ValueError("a directed adversary's sample is a direction: pushes() turns it into a perturbation")
        if self.categorical:  # in float64, so the corners are exactly ±eps
            return self.eps * (sample.double() - 1.0)
        return sample.clamp(-self.eps, self.eps)

    def most_likely(self, dist: torch.distributions.Distribution) -> torch.Tensor:
        """The perturbation ``dist`` ranks highest: each entry's likeliest choice, or the mean (directed: the
        direction)."""
        return self.delta(dist.probs.argmax(-1).float()) if self.categorical else dist.mean

    def value(self, x: torch.Tensor) -> torch.Tensor:
        return self.value_net(self.normalise(x)).squeeze(-1)


def save_adversary(net: AdversaryNet, path: str | Path) -> Path:
    return save_weights(net, net.meta, path, "adversary")


def load_adversary(path: str | Path, env_id: str | None = None, mode: str | None = None) -> AdversaryNet:
    """Load an adversary file; with ``env_id``/``mode``, check it was trained for them."""
    meta, state_dict = load_weights(path, "adversary")
    try:
        net = AdversaryNet(meta)
        net.load_state_dict(state_dict)
    except (KeyError, TypeError, ValueError, RuntimeError) as err:
        raise PolicyFileError(f"{path}: corrupt adversary file ({type(err).__name__}: {err})") from None
    for name, wanted in (("env_id", env_id), ("mode", mode)):
        if wanted is not None and meta[name] != wanted:
            raise PolicyFileError(f"{path}: adversary trained for {meta['env_id']} ({meta['mode']}), "
                                  f"not {env_id or meta['env_id']} ({mode or meta['mode']})")
    return net.eval()
