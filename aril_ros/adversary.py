"""ARIL-A, the learned adversary (paper §4.2), trained by PPO on vectorised in-process simulators.

The adversary f is a Gaussian over perturbations of the zero-order entries: mean
``eps * tanh(net(s))``, a state-independent std initialised to ``0.1 * eps``, samples clipped to
``±eps``. Its input is the *true* observation ``s``. Its reward at step h is the victim's
disagreement with the expert on the true state, ``||a_h - pi_e(s_h)||^2``, where ``a_h`` is the
victim's action on what the attack made it see (sensory) or on the moved state (physical); PPO
maximises the discounted sum. It never needs the victim's gradients: it only queries actions, so
any black-box policy can be attacked.

The critic is split in two: the victim's disagreement at the state *without* the attack, computed
exactly by querying the victim (``baseline``), plus a learned remainder. A perturbation moves the
disagreement by little next to how much it varies from state to state, more than a learned value
follows; the exact part removes that variance from the advantages without changing the objective
(it is a state-dependent baseline, and the rewards stay the raw disagreement).

Adversary files (``*.pt``) use the policy-file container (:func:`aril_ros.policy.save_weights`) with
format ``aril_ros.adversary`` and a JSON meta: env id, mode, eps, sizes, hidden width, observation
normalisation and provenance (victim, expert, training steps, seconds, seed, command).

The training loop reads top to bottom (cleanrl style): collect ``rollout`` steps on ``n_envs``
simulators, compute GAE advantages, run ``epochs`` of clipped PPO updates, repeat.
"""
from __future__ import annotations

import datetime
import json
import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import nn

from .args import arg, command_line
from .attacks import Attack
from .envs import MujocoSim, ObsLayout, layout_of
from .experts import DATA_DIR, git_revision, resolve_policy
from .policy import PolicyFileError, _blocks, load_weights, save_weights
from .rollout import MODES, apply_perturbation


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
        blocks, n = _blocks(true_obs)  # batch-invariant, like the policies
        mean = torch.cat([self.net.mean(b) for b in blocks])[:n].double().numpy()
        delta = np.zeros_like(true_obs)
        delta[:, : self.layout.n_position] = mean
        if self.stochastic:
            for row, rng in enumerate(rngs):
                delta[row, : self.layout.n_position] += self.std * rng.standard_normal(len(self.std))
        return delta * self.scale


class RunningStd:
    """Running standard deviation of a stream of batches (Chan et al.'s parallel update)."""

    def __init__(self):
        self.count, self.mean, self.m2 = 0, 0.0, 0.0

    def update(self, batch: np.ndarray) -> None:
        n, mean = len(batch), float(batch.mean())
        delta, total = mean - self.mean, self.count + n
        self.m2 += float(((batch - mean) ** 2).sum()) + delta**2 * self.count * n / total
        self.mean += delta * n / total
        self.count = total

    @property
    def std(self) -> float:
        return max(float(np.sqrt(self.m2 / max(self.count, 1))), 1e-8)


def bundled_adversary_path(env_id: str, mode: str) -> Path:
    """Where the bundled ARIL-A adversary against the bundled learner lives (``attack:=aril_a`` by name)."""
    return DATA_DIR / "adversary" / f"{env_id}-{mode}.pt"


def defense_adversary_path(env_id: str, mode: str, defense: str) -> Path:
    """Where the bundled ARIL-A trained against the bundled learner ``defense`` (``dagger``, ``aril``,
    ``dart``, ...) lives; the one against DAgger is the default adversary above."""
    if defense == "dagger":
        return bundled_adversary_path(env_id, mode)
    return DATA_DIR / "defense-adversary" / f"{env_id}-{mode}-{defense}.pt"


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


@dataclass
class AdversaryConfig:
    """Arguments of ``aril train-adversary`` (defaults: the paper's Table 3 and appendix)."""

    env: str = arg("HalfCheetah-v5", "gymnasium MuJoCo env id")
    mode: str = arg("sensory", "sensory or physical")
    eps: float = arg(0.05, "L-infinity budget on the zero-order entries")
    victim: str = arg("expert", "the attacked policy: a bundled name, a policy file, or ros (a running policy node "
                                "on observation -> action in this ROS_DOMAIN_ID); only its actions are used")
    expert: str = arg("expert", "the expert whose action on the true state defines the loss")
    steps: int = arg(1_000_000, "environment steps of training (the paper: 1e6 per attack stage)")
    n_envs: int = arg(16, "simulators run side by side")
    rollout: int = arg(256, "steps per simulator between PPO updates")
    epochs: int = arg(10, "PPO epochs per update")
    minibatch: int = arg(1024, "samples per PPO minibatch")
    lr: float = arg(1e-3, "Adam learning rate (the paper's appendix)")
    gamma: float = arg(0.99, "discount of the adversary's return")
    gae_lambda: float = arg(0.95, "GAE lambda")
    clip: float = arg(0.2, "PPO clip range (Table 3)")
    ent_coef: float = arg(0.01, "entropy bonus (Table 3)")
    vf_coef: float = arg(0.5, "value loss weight (Table 3)")
    max_grad_norm: float = arg(0.5, "gradient norm clip")
    hidden: int = arg(64, "width of the two hidden layers")
    warmup: int = arg(200, "steps per simulator of the unattacked victim that set the input normalisation")
    norm_reward: bool = arg(True, "divide rewards by the running std of the discounted return")
    baseline: bool = arg(True, "value = the victim's unperturbed disagreement at the state (computed exactly) + a "
                              "learned remainder, instead of all learned (a control variate: the objective is the same)")
    seed: int = arg(0, "seed of the initial weights, the sampling and the env resets")
    init: str = arg("", "start from this adversary file (same env, mode, eps and width; its input scaling is kept) "
                        "instead of fresh weights: ARIL's warm start from the previous round's adversary")
    out: str = arg("", "where to write the adversary (default: runs/adversary-<env>-<mode>.pt)")
    threads: int = arg(1, "torch threads")


def train_adversary(cfg: AdversaryConfig, log=print, victim=None) -> Path:
    """Train ARIL-A against ``cfg.victim`` (or ``victim``: any object with ``act(obs_batch)`` and
    ``meta.provenance``, e.g. a policy node over ROS); writes the adversary file, returns its path."""
    if cfg.mode not in MODES or cfg.mode == "clean":
        raise ValueError(f"mode:= must be sensory or physical, got {cfg.mode!r}")
    if not cfg.eps > 0:
        raise ValueError(f"eps:= must be > 0, got {cfg.eps}")
    torch.set_num_threads(cfg.threads)
    layout = layout_of(cfg.env)
    victim = victim if victim is not None else resolve_policy(cfg.victim, cfg.env)
    expert = resolve_policy(cfg.expert, cfg.env)
    out = Path(cfg.out or f"runs/adversary-{cfg.env}-{cfg.mode}.pt")
    command = command_line("aril train-adversary", cfg)
    gen = torch.Generator().manual_seed(cfg.seed)
    n, T, n_pos = cfg.n_envs, cfg.rollout, layout.n_position

    # --- simulators; the input scaling comes from the states the victim visits unattacked (reset
    # states alone have almost no spread, and would blow the normalised inputs up once it runs)
    sims = [MujocoSim(cfg.env) for _ in range(n)]
    next_seed = cfg.seed * 1_000_003
    obs = np.stack([sim.reset(next_seed + i) for i, sim in enumerate(sims)])
    visited = [obs.copy()]
    for _ in range(cfg.warmup):
        action = victim.act(obs)
        obs = np.stack([sim.step(a)[0] for sim, a in zip(sims, action)])
        visited.append(obs.copy())
    visited = np.concatenate(visited)
    obs_mean, obs_std = visited.mean(0), visited.std(0) + 1e-3
    next_seed += n
    obs = np.stack([sim.reset(next_seed + i) for i, sim in enumerate(sims)])
    next_seed += n
    meta = {"env_id": cfg.env, "mode": cfg.mode, "eps": cfg.eps, "obs_dim": layout.obs_dim, "n_position": n_pos,
            "hidden": cfg.hidden, "obs_mean": obs_mean.tolist(), "obs_std": obs_std.tolist(), "provenance": {}}
    if cfg.init:
        net = load_adversary(cfg.init, cfg.env, cfg.mode).train()
        if (net.eps, net.meta["hidden"]) != (cfg.eps, cfg.hidden):
            raise ValueError(f"init:={cfg.init} has eps {net.eps} and width {net.meta['hidden']}, "
                             f"not eps:={cfg.eps} hidden:={cfg.hidden}")
    else:
        with torch.random.fork_rng():  # seeded initial weights without touching the global generator
            torch.manual_seed(cfg.seed)
            net = AdversaryNet(meta)
    optimizer = torch.optim.Adam(net.parameters(), lr=cfg.lr, eps=1e-5)

    buf_obs = torch.zeros(T, n, layout.obs_dim)
    buf_sample, buf_logp = torch.zeros(T, n, n_pos), torch.zeros(T, n)
    buf_reward, buf_value, buf_done = torch.zeros(T, n), torch.zeros(T, n), torch.zeros(T, n)
    buf_base = torch.zeros(T, n)

    def unperturbed_loss(states: np.ndarray, label: np.ndarray | None = None) -> np.ndarray:
        """The disagreement the victim would have without the attack: the exact part of the value
        (``label``: the expert's actions on ``states`` when already known)."""
        if not cfg.baseline:
            return np.zeros(len(states))
        label = expert.act(states) if label is None else label
        return ((victim.act(states) - label) ** 2).sum(axis=1)

    episode_loss, episode_return, discounted = np.zeros(n), np.zeros(n), np.zeros(n)
    return_scale = RunningStd()
    finished_loss, finished_return = [], []
    started, steps = time.time(), 0
    while steps < cfg.steps:
        # --- collect: the adversary perturbs, the victim acts, the expert labels the true state
        for t in range(T):
            obs_t = torch.as_tensor(obs, dtype=torch.float32)
            with torch.no_grad():
                dist = net.distribution(obs_t)
                sample = dist.mean + dist.stddev * torch.randn(dist.mean.shape, generator=gen)
                buf_logp[t] = dist.log_prob(sample).sum(-1)
                remainder = net.value(obs_t)
            delta = np.zeros_like(obs)
            delta[:, :n_pos] = sample.clamp(-cfg.eps, cfg.eps).double().numpy()
            seen = apply_perturbation(cfg.mode, sims, obs, delta)
            action = victim.act(seen)
            label = expert.act(obs)
            loss = ((action - label) ** 2).sum(axis=1)
            # the perturbation moves the disagreement by little next to how much it varies from state to
            # state, more than a learned value can follow: the unperturbed disagreement, known exactly for
            # every visited state, carries that part of the value
            base = unperturbed_loss(obs, label)
            buf_obs[t], buf_sample[t] = obs_t, sample
            discounted = discounted * cfg.gamma + loss
            return_scale.update(discounted)
            # in units of the return's spread, so the value loss and the clip ranges keep their meaning
            # whether a step's disagreement is 0.001 or 10
            scale = return_scale.std if cfg.norm_reward else 1.0
            reward = torch.as_tensor(loss / scale, dtype=torch.float32)
            buf_base[t] = torch.as_tensor(base / scale, dtype=torch.float32)
            buf_value[t] = remainder + buf_base[t]
            for i, sim in enumerate(sims):
                obs[i], env_reward, terminated, truncated = sim.step(action[i])
                episode_loss[i] += loss[i]
                episode_return[i] += env_reward
                if truncated and not terminated:  # time limit: bootstrap from the state it stopped in
                    with torch.no_grad():
                        stopped = obs[i:i + 1]
                        value = net.value(torch.as_tensor(stopped, dtype=torch.float32))[0]
                        reward[i] += cfg.gamma * (value + float(unperturbed_loss(stopped)[0]) / scale)
                if terminated or truncated:
                    discounted[i] = 0.0
                    finished_loss.append(episode_loss[i])
                    finished_return.append(episode_return[i])
                    episode_loss[i] = episode_return[i] = 0.0
                    obs[i] = sim.reset(next_seed)
                    next_seed += 1
                buf_done[t, i] = float(terminated or truncated)
            buf_reward[t] = reward
        steps += T * n

        # --- generalised advantage estimation
        with torch.no_grad():
            next_value = net.value(torch.as_tensor(obs, dtype=torch.float32))
            next_value += torch.as_tensor(unperturbed_loss(obs) / scale, dtype=torch.float32)
        advantages = torch.zeros(T, n)
        last = torch.zeros(n)
        for t in reversed(range(T)):
            not_done = 1.0 - buf_done[t]
            value_after = next_value if t == T - 1 else buf_value[t + 1]
            td = buf_reward[t] + cfg.gamma * value_after * not_done - buf_value[t]
            last = td + cfg.gamma * cfg.gae_lambda * not_done * last
            advantages[t] = last
        remainder_target = advantages + buf_value - buf_base

        # --- clipped PPO updates
        flat = lambda x: x.reshape(T * n, *x.shape[2:])  # noqa: E731
        b_obs, b_sample, b_logp = flat(buf_obs), flat(buf_sample), flat(buf_logp)
        b_adv, b_ret = flat(advantages), flat(remainder_target)
        for _ in range(cfg.epochs):
            for idx in torch.randperm(T * n, generator=gen).split(cfg.minibatch):
                dist = net.distribution(b_obs[idx])
                ratio = (dist.log_prob(b_sample[idx]).sum(-1) - b_logp[idx]).exp()
                adv = (b_adv[idx] - b_adv[idx].mean()) / (b_adv[idx].std() + 1e-8)
                policy_loss = -torch.min(ratio * adv, ratio.clamp(1 - cfg.clip, 1 + cfg.clip) * adv).mean()
                value_loss = ((net.value(b_obs[idx]) - b_ret[idx]) ** 2).mean()
                entropy = dist.entropy().sum(-1).mean()
                loss = policy_loss + cfg.vf_coef * value_loss - cfg.ent_coef * entropy
                optimizer.zero_grad()
                loss.backward()
                # clipped apart: the value loss (in units of summed disagreement) would otherwise
                # dominate the joint norm and shrink every policy step along with it
                nn.utils.clip_grad_norm_([*net.mean_net.parameters(), net.log_std], cfg.max_grad_norm)
                nn.utils.clip_grad_norm_(net.value_net.parameters(), cfg.max_grad_norm)
                optimizer.step()

        seconds = time.time() - started
        recent = slice(-4 * n, None)
        log(f"[train-adversary {cfg.env} {cfg.mode} eps={cfg.eps}] step {steps:>8d}  {steps / seconds:6.0f} steps/s  "
            f"episode loss {np.mean(finished_loss[recent]) if finished_loss else float('nan'):9.1f}  "
            f"victim return {np.mean(finished_return[recent]) if finished_return else float('nan'):8.1f}  "
            f"std/eps {float(net.log_std.detach().exp().mean()) / cfg.eps:.3f}", flush=True)
    for sim in sims:
        sim.close()
    net.meta["provenance"] = {
        "command": command, "victim": cfg.victim, "victim_provenance": victim.meta.provenance,
        "expert": cfg.expert, "steps": steps, "train_seconds": round(time.time() - started, 1), "seed": cfg.seed,
        "final_episode_loss": float(np.mean(finished_loss[-4 * n:])) if finished_loss else None,
        "git_revision": git_revision(), "created": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
    }
    save_adversary(net, out)
    log(json.dumps({"out": str(out), "steps": steps, "steps_per_s": round(steps / (time.time() - started), 1)}))
    return out
