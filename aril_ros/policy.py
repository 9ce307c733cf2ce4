"""MLP policies and the single-file policy format.

A policy file (``*.pt``) is one ``torch.save`` dict that ``torch.load(weights_only=True)`` reads, so
loading never runs pickled code and needs none of the training code::

    {
      "format": "aril_ros.policy",
      "version": 1,
      "meta": "<JSON string>",          # see PolicyMeta: env id, sizes, architecture, action bounds,
                                        # observation normalisation, provenance
      "state_dict": {name: tensor},    # net.{0,2,4}.weight/bias and log_std
    }

The network is the paper's: two hidden layers. Its output is the action mean, squashed by ``tanh``
into the action bounds (``squash="tanh"``, SAC-style) or clipped to them (``squash="clip"``). The
deterministic mean action is what every rollout, node and attack uses.

:func:`resolve_policy` turns what a user types (a bundled name or a file path) into a policy.
"""
from __future__ import annotations

import json
import pickle
import re
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch
from torch import nn

from .files import write_atomically
from .registry import BUNDLED_NAMES, BundledFileError, bundled_file

VERSION = 1
_ACTIVATIONS = {"relu": nn.ReLU, "tanh": nn.Tanh}
_SQUASHES = ("tanh", "clip")
# BLAS picks its kernels by batch size and they round differently, so one observation's action
# would depend on how many others share its forward pass. Evaluating in fixed blocks of this many
# rows makes each action a function of its own observation only: the same in a batch of 16 envs
# as in a ROS node that sees one observation at a time. A node pays a whole block for its one observation, so the
# block is the smallest whose rounding here is that of larger ones: 16 and 64 rows give every bundled policy's and
# adversary's outputs and gradients bit for bit, 8 do not; 16 costs the expert node 0.5 ms a step, 64 0.9 ms.
# Not for every width on every CPU: on AVX512, and on an AMD EPYC's AVX2 kernels, MKL rounds a row of a layer whose
# width is no multiple of 16 (5, 7, 33, 47 were tried) by its place in the block, so such a policy acts on one
# observation (a node) and on a batch (the engine) alike only to the last bits. The widths trained here (64, 256)
# and every bundled file hold on both (tests/test_policy.py); padding the widths would fix it but change every
# bundled file's figures.
BLOCK_ROWS = 16


class PolicyFileError(ValueError):
    """A policy file is missing, corrupt, of another format, or made for another env."""


@dataclass
class PolicyMeta:
    """Everything about a policy but its weights."""

    env_id: str
    obs_dim: int
    act_dim: int
    action_low: list[float]
    action_high: list[float]
    hidden: list[int] = field(default_factory=lambda: [256, 256])
    activation: str = "relu"
    squash: str = "tanh"
    obs_mean: list[float] | None = None
    """Observation normalisation: the net sees clip((obs - obs_mean) / obs_std, -obs_clip, obs_clip)."""
    obs_std: list[float] | None = None
    obs_clip: float | None = None
    provenance: dict = field(default_factory=dict)
    """How the weights were made: command, algorithm, steps, seconds, seed, git revision, evaluation."""

    def __post_init__(self):
        if len(self.hidden) != 2:
            raise PolicyFileError(f"the policy MLP has two hidden layers, got hidden={self.hidden}")
        if self.activation not in _ACTIVATIONS:
            raise PolicyFileError(f"activation must be one of {sorted(_ACTIVATIONS)}, got {self.activation!r}")
        if self.squash not in _SQUASHES:
            raise PolicyFileError(f"squash must be one of {_SQUASHES}, got {self.squash!r}")
        if len(self.action_low) != self.act_dim or len(self.action_high) != self.act_dim:
            raise PolicyFileError("action bounds do not match act_dim")


def stacked_blocks(rows: np.ndarray) -> tuple[torch.Tensor, int]:
    """``rows`` as one float32 tensor ``[blocks, BLOCK_ROWS, width]`` (zero-padded), and the number of real rows."""
    n, width = rows.shape
    padded = np.zeros((-(-n // BLOCK_ROWS), BLOCK_ROWS, width), dtype=np.float32)
    padded.reshape(-1, width)[:n] = rows
    return torch.from_numpy(padded), n


def in_blocks(rows: np.ndarray) -> tuple[tuple[torch.Tensor, ...], int]:
    """``rows`` as float32 blocks of BLOCK_ROWS rows (zero-padded), and the number of real rows."""
    blocks, n = stacked_blocks(rows)
    return blocks.unbind(), n


def blockwise_linear(blocks: torch.Tensor, layer: nn.Linear) -> torch.Tensor:
    """``layer`` applied to each block of ``[blocks, BLOCK_ROWS, width]`` in one call: one matrix product per
    block, bit for bit the block's own ``layer(block)`` (tests/test_policy.py checks it on every bundled policy),
    without a Python round per block."""
    return torch.baddbmm(layer.bias, blocks, layer.weight.t().expand(len(blocks), -1, -1))


def meta_for_env(env_id: str, **fields) -> PolicyMeta:
    """A :class:`PolicyMeta` with the env's sizes and action bounds filled in."""
    from .envs import layout_of

    layout = layout_of(env_id)
    return PolicyMeta(env_id=env_id, obs_dim=layout.obs_dim, act_dim=layout.act_dim,
                      action_low=list(layout.action_low), action_high=list(layout.action_high), **fields)


class MLPPolicy(nn.Module):
    """obs -> normalise -> Linear-act-Linear-act-Linear -> squash into the action bounds."""

    def __init__(self, meta: PolicyMeta):
        super().__init__()
        self.meta = meta
        act = _ACTIVATIONS[meta.activation]
        h1, h2 = meta.hidden
        self.net = nn.Sequential(
            nn.Linear(meta.obs_dim, h1), act(), nn.Linear(h1, h2), act(), nn.Linear(h2, meta.act_dim)
        )
        # part of the file format (every policy file carries it); no rollout samples from it
        self.log_std = nn.Parameter(torch.full((meta.act_dim,), -0.5))
        low = torch.tensor(meta.action_low, dtype=torch.float32)
        high = torch.tensor(meta.action_high, dtype=torch.float32)
        self.register_buffer("action_low", low, persistent=False)
        self.register_buffer("action_high", high, persistent=False)
        self.register_buffer("action_range", high - low, persistent=False)
        mean = torch.zeros(meta.obs_dim) if meta.obs_mean is None else torch.tensor(meta.obs_mean)
        std = torch.ones(meta.obs_dim) if meta.obs_std is None else torch.tensor(meta.obs_std)
        self.register_buffer("obs_mean", mean.float(), persistent=False)
        self.register_buffer("obs_std", std.float(), persistent=False)

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        """Deterministic (mean) action in env units for a batch of observations."""
        return self.squash(self.net(self.normalise(obs)))

    def normalise(self, obs: torch.Tensor) -> torch.Tensor:
        """What the net sees of ``obs`` (elementwise, so any shape)."""
        x = self.standardise(obs)
        if self.meta.obs_clip is not None:
            x = x.clamp(-self.meta.obs_clip, self.meta.obs_clip)
        return x

    def standardise(self, obs: torch.Tensor) -> torch.Tensor:
        """``obs`` in units of the observations' spread, before the clip of :meth:`normalise`."""
        return (obs.float() - self.obs_mean) / self.obs_std

    def squash(self, out: torch.Tensor) -> torch.Tensor:
        """The net's output into the action bounds (elementwise, so any shape)."""
        if self.meta.squash == "tanh":
            return self.action_low + (torch.tanh(out) + 1.0) * 0.5 * self.action_range
        return torch.maximum(torch.minimum(out, self.action_high), self.action_low)

    @torch.inference_mode()
    def act(self, obs: np.ndarray) -> np.ndarray:
        """Deterministic actions (float64) for a batch ``[n, obs_dim]`` or a single observation.

        Batch-invariant: row i of the result does not depend on the other rows (see BLOCK_ROWS). The products
        run for all blocks in one call (:func:`blockwise_linear`); the elementwise steps on all rows at once.
        """
        obs = np.asarray(obs)
        blocks, n = stacked_blocks(np.atleast_2d(obs))
        x = self.normalise(blocks)
        for layer in self.net:
            x = blockwise_linear(x, layer) if isinstance(layer, nn.Linear) else layer(x)
        x = self.squash(x)
        actions = x.reshape(-1, x.shape[-1])[:n].numpy().astype(np.float64)
        return actions[0] if obs.ndim == 1 else actions

    def loss_gradient(self, obs: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``d/d obs ||pi(obs) - target||^2`` per row (float64), batch-invariant like :meth:`act`, and the actions
        its forward pass computed: bit for bit ``act(obs)`` (a block's layers give the bits of :func:`blockwise_linear`),
        so an iterative attack need not ask for them again."""
        blocks, n = in_blocks(np.atleast_2d(obs))
        targets, _ = in_blocks(np.atleast_2d(target))
        grads, actions = zip(*(self.block_gradient(block, target_block) for block, target_block in zip(blocks, targets)))
        return torch.cat(grads)[:n].double().numpy(), torch.cat(actions)[:n].numpy().astype(np.float64)

    @torch.no_grad()
    def block_gradient(self, block: torch.Tensor, target: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """One block's ``d/d obs ||forward(obs) - target||^2`` and actions, by the chain rule written out: the very
        operations autograd runs for it, in its order (bit for bit its gradient, tests/test_policy.py), without the
        cost of recording a graph: on one observation 0.19 ms where autograd took 0.34, and FGSM^k asks 10 a step."""
        layers, outputs = list(self.net), [self.normalise(block)]
        for layer in layers:
            outputs.append(layer(outputs[-1]))
        action = self.squash(outputs[-1])
        grad = 2.0 * (action - target)  # autograd's pow backward: 1 * (2 * difference^1)
        out = outputs[-1]
        if self.meta.squash == "tanh":
            grad = torch.ops.aten.tanh_backward(grad * self.action_range * 0.5, torch.tanh(out))
        else:  # max(min(out, high), low): on a tie autograd gives each side half
            inner = torch.minimum(out, self.action_high)
            grad = torch.where(inner == self.action_low, grad / 2, grad).masked_fill_(inner < self.action_low, 0)
            grad = torch.where(out == self.action_high, grad / 2, grad).masked_fill_(out > self.action_high, 0)
        for layer, output in zip(reversed(layers), reversed(outputs[1:])):
            if isinstance(layer, nn.Linear):
                grad = grad.mm(layer.weight)
            elif isinstance(layer, nn.ReLU):
                grad = torch.ops.aten.threshold_backward(grad, output, 0)
            else:
                grad = torch.ops.aten.tanh_backward(grad, output)
        if self.meta.obs_clip is not None:  # the clip passes the gradient where the standardised input lies inside it
            clip, standard = self.meta.obs_clip, self.standardise(block)
            grad = torch.where((standard >= -clip) & (standard <= clip), grad, torch.zeros((), dtype=grad.dtype))
        return grad / self.obs_std, action

    def check_env(self, env_id: str, obs_dim: int, act_dim: int) -> None:
        """Raise :class:`PolicyFileError` if this policy was not made for that env."""
        m = self.meta
        if (m.env_id, m.obs_dim, m.act_dim) != (env_id, obs_dim, act_dim):
            raise PolicyFileError(
                f"policy is for {m.env_id} (obs {m.obs_dim}, act {m.act_dim}) but the env is "
                f"{env_id} (obs {obs_dim}, act {act_dim})"
            )


def save_weights(module: nn.Module, meta: dict, path: str | Path, kind: str = "policy") -> Path:
    """Write ``{format: aril_ros.<kind>, version, meta: JSON, state_dict}`` atomically."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    blob = {
        "format": f"aril_ros.{kind}",
        "version": VERSION,
        "meta": json.dumps(meta, sort_keys=True),
        "state_dict": {k: v.detach().clone() for k, v in module.state_dict().items()},
    }
    return write_atomically(path, lambda partial: torch.save(blob, partial))


ZIP_MAGIC = b"PK\x03\x04"
"""The first bytes of a zip archive, which every ``torch.save`` file is (a cut-short one too)."""


def load_weights(path: str | Path, kind: str = "policy") -> tuple[dict, dict]:
    """``(meta, state_dict)`` of a file written by :func:`save_weights`, or a clear PolicyFileError."""
    path = Path(path)
    if not path.is_file():
        raise PolicyFileError(f"{path}: no such {kind} file")
    with path.open("rb") as head:
        archive = head.read(len(ZIP_MAGIC)) == ZIP_MAGIC
    if not archive:  # torch.save writes a zip: other bytes would reach torch's legacy unpickler, whose refusal reads
        # as pickled code "refused for safety", a verdict on a file that may hold no pickle at all
        raise PolicyFileError(f"{path}: not an aril_ros {kind} file: not a torch archive")
    try:
        blob = torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as err:
        # torch's own text advises retrying with weights_only=False, which would run the file's code: never shown
        refused = re.search(r"GLOBAL ([\w.]+)", str(err))
        raise PolicyFileError(
            f"{path}: refused for safety: the file holds pickled code or objects beyond plain weights"
            + (f" (it asks for {refused[1]})" if refused else "")
            + f"; an aril_ros {kind} file holds tensors and plain values only, and is never loaded otherwise"
        ) from None
    except Exception as err:  # torch raises many types for a damaged zip
        raise PolicyFileError(f"{path}: not a readable {kind} file ({type(err).__name__}: {err})") from None
    if not isinstance(blob, dict) or blob.get("format") != f"aril_ros.{kind}":
        found = blob.get("format") if isinstance(blob, dict) else None
        raise PolicyFileError(f"{path}: not an aril_ros {kind} file (format tag {found!r})")
    if blob.get("version") != VERSION:
        raise PolicyFileError(f"{path}: {kind} format version {blob.get('version')}, this aril_ros reads {VERSION}")
    try:
        return json.loads(blob["meta"]), blob["state_dict"]
    except (KeyError, TypeError, ValueError) as err:
        raise PolicyFileError(f"{path}: corrupt {kind} file ({type(err).__name__}: {err})") from None


def save_policy(policy: MLPPolicy, path: str | Path) -> Path:
    return save_weights(policy, asdict(policy.meta), path, "policy")


def load_policy(path: str | Path, env_id: str | None = None) -> MLPPolicy:
    """Load a policy file; with ``env_id``, also check it was made for that env."""
    meta, state_dict = load_weights(path, "policy")
    try:
        policy = MLPPolicy(PolicyMeta(**meta))
        policy.load_state_dict(state_dict)
    except PolicyFileError as err:
        raise PolicyFileError(f"{path}: {err}") from None
    except (TypeError, ValueError, RuntimeError) as err:
        raise PolicyFileError(f"{path}: corrupt policy file ({type(err).__name__}: {err})") from None
    policy.eval()
    if env_id is not None:
        from .envs import layout_of

        layout = layout_of(env_id)
        try:
            policy.check_env(env_id, layout.obs_dim, layout.act_dim)
        except PolicyFileError as err:
            raise PolicyFileError(f"{path}: {err}") from None
    return policy


def policy_file(name_or_path: str, env_id: str, mode: str | None = None) -> Path:
    """The file behind a bundled name (``expert``, ``dagger``, ``aril``, ...; ``mode`` picks the ``dr``/``aril``
    one) or a policy file path."""
    if name_or_path in BUNDLED_NAMES:
        try:
            return bundled_file(name_or_path, env_id, mode)
        except BundledFileError as err:
            raise PolicyFileError(str(err)) from None
    if not Path(name_or_path).suffix:
        raise PolicyFileError(
            f"{name_or_path!r} is neither a bundled policy name ({', '.join(BUNDLED_NAMES)}) nor a file path"
        )
    return Path(name_or_path)


def resolve_policy(name_or_path: str, env_id: str, mode: str | None = None) -> MLPPolicy:
    """The policy of a bundled name or a policy file path (:func:`policy_file`), checked against ``env_id``."""
    return load_policy(policy_file(name_or_path, env_id, mode), env_id)


class Answers:
    """A policy as a black box: its actions, nothing else (what a black-box attack may see of a file or a node), and
    how many rows it was asked (``asked``)."""

    def __init__(self, policy):
        self._act = policy.act
        self.asked = 0

    def act(self, obs: np.ndarray) -> np.ndarray:
        self.asked += len(np.atleast_2d(obs))
        return self._act(obs)
