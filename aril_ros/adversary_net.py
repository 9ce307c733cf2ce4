"""The learned adversary's network and its file format (ARIL-A, paper §4.2; trained by :mod:`aril_ros.adversary`).

The adversary f is a Gaussian over perturbations of the zero-order entries: mean ``eps * tanh(net(s))``
of the *true* observation ``s``, a state-independent std initialised to ``0.1 * eps``. A value head
holds the learned remainder of the trainer's value (see :mod:`aril_ros.adversary`).

Adversary files (``*.pt``) use the policy-file container (:func:`aril_ros.policy.save_weights`) with
format ``aril_ros.adversary`` and a JSON meta: env id, mode, eps, sizes, hidden width, observation
normalisation and provenance (victim, expert, training steps, seconds, seed, command and settings).
"""
from __future__ import annotations

import math
from pathlib import Path

import torch
from torch import nn

from .policy import PolicyFileError, load_weights, save_weights


def _mlp(n_in: int, hidden: int, n_out: int) -> nn.Sequential:
    return nn.Sequential(nn.Linear(n_in, hidden), nn.Tanh(), nn.Linear(hidden, hidden), nn.Tanh(),
                         nn.Linear(hidden, n_out))


class AdversaryNet(nn.Module):
    """Mean ``eps * tanh(net(s))`` over the zero-order entries, learnable log-std, and a value head
    (the learned remainder of the value, see the module docstring)."""

    def __init__(self, meta: dict):
        super().__init__()
        self.meta = meta
        obs_dim, n_out, hidden = meta["obs_dim"], meta["n_position"], meta["hidden"]
        self.eps = float(meta["eps"])
        self.mean_net = _mlp(obs_dim, hidden, n_out)
        self.value_net = _mlp(obs_dim, hidden, 1)
        self.log_std = nn.Parameter(torch.full((n_out,), math.log(0.1 * self.eps)))
        self.register_buffer("obs_mean", torch.tensor(meta["obs_mean"], dtype=torch.float32))
        self.register_buffer("obs_std", torch.tensor(meta["obs_std"], dtype=torch.float32))

    def normalise(self, obs: torch.Tensor) -> torch.Tensor:
        return ((obs.float() - self.obs_mean) / self.obs_std).clamp(-10.0, 10.0)

    def mean(self, obs: torch.Tensor) -> torch.Tensor:
        return self.eps * torch.tanh(self.mean_net(self.normalise(obs)))

    def distribution(self, obs: torch.Tensor) -> torch.distributions.Normal:
        return torch.distributions.Normal(self.mean(obs), self.log_std.exp().expand(len(obs), -1))

    def value(self, obs: torch.Tensor) -> torch.Tensor:
        return self.value_net(self.normalise(obs)).squeeze(-1)


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
