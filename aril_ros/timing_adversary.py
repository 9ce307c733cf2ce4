"""The learned timing adversary's network and its file format: ARIL-A's method (paper §4.2) turned from values to time.

At each step the adversary chooses, within a :class:`~aril_ros.timing.TimingBudget`, how old the observation the policy
is shown is (``0..delay``), whether it is dropped (the last one shown, again; only where the budget has a share of
drops) and how old the action the simulator applies is (``0..action_delay``): three categorical choices, given the
observation due at the step (the true one: a timing adversary runs in mode ``clean``) and whether the drop share
allows a drop now. The budget's rules (:class:`~aril_ros.timing.Timeline`) bound what is played whatever it asks. It is
trained by :mod:`aril_ros.adversary`'s PPO on the paper's objective, the applied action's disagreement with the
expert on the true state, querying the victim's actions only (``aril train-adversary mode:=clean delay:=2``), and
played by ``timing:=learned timing_file:=<file>`` (:class:`~aril_ros.timing.LearnedChooser`) on the engine and in
the graph alike.

Timing adversary files (``*.pt``) use the policy-file container (:func:`aril_ros.policy.save_weights`) with format
``aril_ros.timing-adversary`` and a JSON meta: env id, the budget (``delay``, ``drop``, ``action_delay``), sizes,
hidden width, the observation's normalisation and provenance (victim, its sha256, expert, training steps, seconds,
seed, command and settings).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from torch import nn

from .adversary_net import mlp
from .policy import PolicyFileError, in_blocks, load_weights, save_weights

KIND = "timing-adversary"
CHOICES = ("obs_age", "drop", "action_age")
"""The choices of a step, in the order of a sample's columns (and of the uniform draws that pick them when played)."""


def choice_sizes(budget: dict) -> tuple[int, int, int]:
    """How many options each of :data:`CHOICES` has under ``budget`` (a :class:`~aril_ros.timing.TimingBudget`'s
    fields; one option: nothing to choose)."""
    return budget["delay"] + 1, 2 if budget["drop"] else 1, budget["action_delay"] + 1


class TimingNet(nn.Module):
    """Per step, three categorical distributions (:data:`CHOICES`) over the budget's options, and a value head, on the
    normalised observation and the may-drop-now flag (see the module docstring). Its PPO interface is
    :class:`~aril_ros.adversary_net.AdversaryNet`'s: :meth:`sample`, :meth:`log_prob_and_entropy`, :meth:`value`."""

    takes_actions = False
    sample_width = len(CHOICES)

    def __init__(self, meta: dict):
        super().__init__()
        self.meta = meta
        self.budget = meta["budget"]
        self.sizes = choice_sizes(self.budget)
        n_in, hidden = meta["obs_dim"] + 1, meta["hidden"]
        self.mean_net = mlp(n_in, hidden, sum(self.sizes))
        self.value_net = mlp(n_in, hidden, 1)
        self.register_buffer("obs_mean", torch.tensor(meta["obs_mean"], dtype=torch.float32))
        self.register_buffer("obs_std", torch.tensor(meta["obs_std"], dtype=torch.float32))

    @property
    def input_width(self) -> int:
        return self.meta["obs_dim"] + 1

    @staticmethod
    def inputs(observation: np.ndarray, may_drop_now: np.ndarray) -> np.ndarray:
        """The input rows: the observation due at the step, then 1.0 where a drop is allowed now."""
        return np.concatenate([observation, np.asarray(may_drop_now, dtype=np.float64)[:, None]], axis=1)

    def normalise(self, x: torch.Tensor) -> torch.Tensor:
        """The observation scaled by the victim's visited states (as ARIL-A's), the flag as it is (0 or 1)."""
        x = x.float()
        return torch.cat([((x[:, :-1] - self.obs_mean) / self.obs_std).clamp(-10.0, 10.0), x[:, -1:]], dim=1)

    def log_probabilities(self, x: torch.Tensor) -> list[torch.Tensor]:
        """Per choice, ``[rows, options]`` log-probabilities."""
        return [part - part.logsumexp(-1, keepdim=True) for part in self.mean_net(self.normalise(x)).split(self.sizes, 1)]

    def sample(self, x: torch.Tensor, gen: torch.Generator, entropy: bool = False
               ) -> tuple[torch.Tensor, torch.Tensor, float | None]:
        """A training sample per row (option indices, ``[rows, 3]``), its log-probability and (``entropy``) the mean
        entropy per choice."""
        log_p = self.log_probabilities(x)
        picked = torch.stack([torch.multinomial(lp.exp(), 1, generator=gen).squeeze(-1) for lp in log_p], 1).float()
        return picked, self._log_prob(log_p, picked), (self._entropy(log_p).mean().item() / 3 if entropy else None)

    def log_prob_and_entropy(self, x: torch.Tensor, sample: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Per row, summed over the choices: the log-probability of ``sample`` and the entropy, PPO's two terms."""
        log_p = self.log_probabilities(x)
        return self._log_prob(log_p, sample), self._entropy(log_p)

    @staticmethod
    def _log_prob(log_p: list[torch.Tensor], sample: torch.Tensor) -> torch.Tensor:
        return sum(lp.gather(-1, sample[:, [k]].long()).squeeze(-1) for k, lp in enumerate(log_p))

    @staticmethod
    def _entropy(log_p: list[torch.Tensor]) -> torch.Tensor:
        return sum(-(lp.exp() * lp).sum(-1) for lp in log_p)

    def value(self, x: torch.Tensor) -> torch.Tensor:
        return self.value_net(self.normalise(x)).squeeze(-1)

    @torch.inference_mode()
    def probabilities(self, observation: np.ndarray, may_drop_now: np.ndarray) -> list[np.ndarray]:
        """Per choice, ``[rows, options]`` probabilities (float64) at play, computed in the policies' fixed blocks of
        rows so that a row's choice does not depend on the rows beside it (the graph plays one at a time)."""
        blocks, n = in_blocks(self.inputs(observation, may_drop_now))
        per_block = [self.log_probabilities(block) for block in blocks]
        return [torch.cat([lp[k] for lp in per_block])[:n].double().exp().numpy() for k in range(len(CHOICES))]


def save_timing_adversary(net: TimingNet, path: str | Path) -> Path:
    return save_weights(net, net.meta, path, KIND)


def load_timing_adversary(path: str | Path, budget: dict | None = None, env_id: str | None = None) -> TimingNet:
    """Load a timing adversary file; with ``budget`` (a :class:`~aril_ros.timing.TimingBudget`'s fields) and
    ``env_id``, check it was trained for them (a network's options are its budget's)."""
    meta, state_dict = load_weights(path, KIND)
    try:
        net = TimingNet(meta)
        net.load_state_dict(state_dict)
    except (KeyError, TypeError, ValueError, RuntimeError) as err:
        raise PolicyFileError(f"{path}: corrupt timing adversary file ({type(err).__name__}: {err})") from None
    if budget is not None and net.budget != budget:
        said = lambda b: ", ".join(f"{k.replace('_', ' ')} {b[k]:g}" for k in ("delay", "drop", "action_delay"))  # noqa: E731
        raise PolicyFileError(f"{path}: timing adversary trained for {said(net.budget)}; played with {said(budget)}: "
                              "give the budget it was trained for")
    if env_id is not None and meta["env_id"] != env_id:
        raise PolicyFileError(f"{path}: timing adversary trained for {meta['env_id']}, not {env_id}")
    return net.eval()
