"""Interactive imitation by rounds: DAgger (Ross et al., 2011), and with an attack in the loop,
domain randomisation (``attack:=random``) and ARIL (``attack:=aril_a``, the paper's Algorithm 1).

Round 0 collects expert demonstrations (DAgger's beta_0 = 1). Round r >= 1 runs the current learner
pi_r (through the attack f_r in ``mode``, where f_r is retrained against pi_r for ARIL-A), labels
every visited *true* state with the expert, adds the pairs (observation pi_r saw, expert action) to
the aggregated data set (follow the leader: nothing is ever dropped) and fits pi_{r+1} on all of it
from scratch. Round ``rounds`` only runs pi_rounds. A round's run is also its learner's evaluation
(under that round's attack): the returned policy is the pi_r with the best return in its own round,
because the analysis of DAgger and the paper's theorem bound the *best* pi_i, not the last.

A run directory holds everything needed to resume after an interruption from the last finished
round::

    <run_dir>/state.json        config and one record per finished round (returns, losses, seconds)
    <run_dir>/data.npz          the aggregated data set (obs, expert_action, episode, round, source)
    <run_dir>/pi-<r>.pt         pi_r, the learner fitted after round r - 1 (a policy file)
    <run_dir>/adversary-<r>.pt  ARIL only: f_r, the adversary trained against pi_r
"""
from __future__ import annotations

import dataclasses
import datetime
import json
import os
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from .adversary import AdversaryConfig, train_adversary
from .args import arg, command_line
from .attacks import calibrated_eps, make_attack
from .dataset import DaggerDataset
from .envs import layout_of
from .experts import git_revision, resolve_policy
from .learners import fit_policy
from .mcap_log import dataset_of_run, read_run
from .policy import load_policy, save_policy
from .rollout import RolloutEngine


ALGORITHMS = {"dagger": "none", "dart": "none", "dr": "random", "aril": "aril_a"}  # and the attack in the loop


@dataclass
class LearnerConfig:
    """Arguments of ``aril train-learner``."""

    algorithm: str = arg("dagger", "dagger: the learner collects | dart: the expert collects with Gaussian action noise "
                                   "sized by the learner's error (Laskey et al. 2017) | dr: dagger under random +-eps "
                                   "perturbations (domain randomisation) | aril: dagger under ARIL-A, retrained against "
                                   "each learner (the paper's Algorithm 1)")
    env: str = arg("HalfCheetah-v5", "gymnasium MuJoCo env id")
    expert: str = arg("expert", "the expert that labels the true states: a bundled name or a policy file")
    mode: str = arg("sensory", "dr and aril: sensory or physical perturbations (dagger and dart collect clean)")
    eps: float = arg(0.0, "dr and aril: the budget (0: the calibrated eps for env and mode, results/eps_calibration.json)")
    rounds: int = arg(10, "rounds of collecting and refitting after round 0 (expert demonstrations)")
    episodes: int = arg(5, "episodes collected per round (1000 steps each)")
    hidden: int = arg(64, "width of the learner's two hidden layers")
    epochs: int = arg(20, "passes over the aggregated data per fit")
    lr: float = arg(1e-3, "Adam learning rate (the paper's appendix)")
    batch: int = arg(256, "minibatch size")
    adversary_steps: int = arg(300_000, "aril: PPO steps of each round's adversary")
    warm_start: bool = arg(False, "aril: each round's adversary starts from the previous round's (f_{t-1}) instead of "
                                  "fresh weights, so it keeps up with a learner that changes a little per round")
    eval_episodes: int = arg(5, "dr and aril: episodes of each learner's clean evaluation (env seeds 500000...)")
    seed: int = arg(0, "seed of the collection (env seeds seed*100000 + round*1000 + i), fits, noise and adversaries")
    run_dir: str = arg("", "the run directory (default runs/<algorithm>-<env>[-<mode>]); an existing one is resumed")
    out: str = arg("", "where to write the selected policy (default runs/<algorithm>-<env>[-<mode>].pt)")
    threads: int = arg(1, "torch threads")
    source: str = arg("inprocess", "where rounds are collected: inprocess (the engine, fast) or graph (run_graph.py "
                                   "through the ROS 2 nodes, recorded to <run_dir>/round-<r>.mcap and loaded back); "
                                   "the same seeds give the same data set")


@dataclass
class RoundSpec:
    """One round's collection, as a collector other than the engine receives it (``source:=graph``:
    the ROS side's ``aril_ros.collectors`` entry point runs it through the nodes and records it)."""

    env: str
    mode: str
    """clean, sensory or physical"""
    attack: str
    eps: float
    policy: str
    """the collecting policy: a bundled name or a policy file"""
    expert: str
    attack_file: str
    """aril_a: the round's adversary file, else empty"""
    episodes: int
    seed: int
    """env seed of the first episode (and of the attack noise)"""
    record: Path
    """where the collector writes the round's run log (MCAP, see :mod:`aril_ros.mcap_log`)"""


class NoisyPolicy:
    """DART's collector: ``policy``'s action plus Gaussian noise ``N(0, cov)``, clipped to the action bounds."""

    def __init__(self, policy, cov: np.ndarray, rng: np.random.Generator):
        self.policy, self.meta, self.rng = policy, policy.meta, rng
        self.chol = np.linalg.cholesky(cov + 1e-9 * np.eye(len(cov)))
        self.low, self.high = np.asarray(policy.meta.action_low), np.asarray(policy.meta.action_high)

    def check_env(self, *args) -> None:
        self.policy.check_env(*args)

    def act(self, obs: np.ndarray) -> np.ndarray:
        action = self.policy.act(obs)
        return np.clip(action + self.rng.standard_normal(action.shape) @ self.chol.T, self.low, self.high)


def learner_error_covariance(policy, data: DaggerDataset) -> np.ndarray:
    """DART's noise: the second moment of the learner's error on the expert's states, E[(pi(s) - pi_e(s))(...)^T]."""
    error = policy.act(data.obs) - data.expert_action
    return error.T @ error / len(error)


EVAL_SEED = 500_000
ROOT = Path(__file__).resolve().parents[1]


def _save_atomic(path: Path, write) -> None:
    tmp = path.with_name(path.name + ".tmp")
    write(tmp)
    os.replace(tmp, path)


def _load_data(path: Path) -> tuple[DaggerDataset, np.ndarray]:
    with np.load(path) as f:
        return (DaggerDataset(obs=f["obs"], expert_action=f["expert_action"], episode=f["episode"],
                              source=[str(s) for s in f["source"]]), f["round"])


def _save_data(path: Path, data: DaggerDataset, rounds: np.ndarray) -> None:
    def write(tmp):
        with open(tmp, "wb") as fh:
            np.savez(fh, obs=data.obs, expert_action=data.expert_action, episode=data.episode,
                     source=np.array(data.source), round=rounds)

    _save_atomic(path, write)


def train_learner(cfg: LearnerConfig, log=print) -> Path:
    """Run (or resume) the rounds; write the selected policy to ``cfg.out`` and return its path."""
    if cfg.algorithm not in ALGORITHMS:
        raise ValueError(f"unknown algorithm {cfg.algorithm!r}; choose one of {', '.join(ALGORITHMS)}")
    attack_name = ALGORITHMS[cfg.algorithm]
    if attack_name != "none":
        if cfg.mode not in ("sensory", "physical"):
            raise ValueError(f"{cfg.algorithm} needs mode:=sensory or mode:=physical, got {cfg.mode!r}")
        if cfg.eps == 0:
            cfg = dataclasses.replace(cfg, eps=calibrated_eps(cfg.env, cfg.mode))
        if not cfg.eps > 0:
            raise ValueError(f"eps:= must be > 0, got {cfg.eps}")
    if cfg.rounds < 1:
        raise ValueError("rounds:= must be >= 1")
    if cfg.source not in ("inprocess", "graph"):
        raise ValueError(f"source:= must be inprocess or graph, got {cfg.source!r}")
    if cfg.source == "graph" and cfg.algorithm == "dart":
        raise ValueError("dart collects with a noisy expert, which has no policy node: use source:=inprocess")
    torch.set_num_threads(cfg.threads)
    layout = layout_of(cfg.env)
    expert = resolve_policy(cfg.expert, cfg.env)
    name = f"{cfg.algorithm}-{cfg.env}" + (f"-{cfg.mode}" if attack_name != "none" else "")
    mode = cfg.mode if attack_name != "none" else "clean"
    run_dir = Path(cfg.run_dir or f"runs/{name}")
    run_dir.mkdir(parents=True, exist_ok=True)
    state_path, data_path = run_dir / "state.json", run_dir / "data.npz"
    config = {k: v for k, v in dataclasses.asdict(cfg).items()
              if k not in ("run_dir", "out", "threads", "rounds", "eval_episodes", "source")}
    state = {"config": config, "rounds": []}
    if state_path.exists():
        state = json.loads(state_path.read_text())
        defaults = dataclasses.asdict(LearnerConfig())  # a setting added since the run was made had its default
        stored = {**{k: defaults[k] for k in config}, **state["config"]}
        if stored != config:
            changed = sorted(k for k in config if stored.get(k) != config[k])
            raise ValueError(f"{run_dir} holds a run with other settings ({', '.join(changed)}); "
                             f"pick another run_dir:= or repeat its settings")
        log(f"[train-learner {name}] resuming after round {len(state['rounds']) - 1}", flush=True)
    if state["rounds"] and "samples" not in state["rounds"][-1] and len(state["rounds"]) <= cfg.rounds:
        state["rounds"].pop()  # the evaluation-only last round of a shorter run: now it collects and fits too
    data, data_round = None, np.zeros(0, dtype=np.int64)
    if data_path.exists() and state["rounds"]:
        data, data_round = _load_data(data_path)
        keep = data_round < len(state["rounds"])  # drop a round whose record was not written (killed between)
        data = DaggerDataset(obs=data.obs[keep], expert_action=data.expert_action[keep], episode=data.episode[keep],
                             source=[src for src, k in zip(data.source, keep) if k])
        data_round = data_round[keep]
    started = time.time() - sum(r["seconds"] for r in state["rounds"])

    def rollout(policy, attack, mode, episodes, seed):
        engine = RolloutEngine(cfg.env, policy, expert, attack, mode, n_envs=min(episodes, 16))
        try:
            return engine.rollout(episodes, seed)
        finally:
            engine.close()

    # round r (>= 1) first runs pi_r, which is also pi_r's evaluation (DART: the noisy expert collects
    # and pi_r is evaluated apart); the last round only evaluates
    for r in range(len(state["rounds"]), cfg.rounds + 1):
        round_started = time.time()
        learner = expert if r == 0 else load_policy(run_dir / f"pi-{r}.pt", cfg.env)
        adversary_file = ""
        if r > 0 and attack_name == "aril_a":
            adversary_file = str(run_dir / f"adversary-{r}.pt")
            train_adversary(AdversaryConfig(env=cfg.env, mode=mode, eps=cfg.eps, victim=str(run_dir / f"pi-{r}.pt"),
                                            expert=cfg.expert, steps=cfg.adversary_steps, seed=cfg.seed * 1000 + r,
                                            init=str(run_dir / f"adversary-{r - 1}.pt") if cfg.warm_start and r > 1
                                            else "", out=adversary_file), log=log)
        attack = make_attack(attack_name if r > 0 else "none", layout, cfg.eps if r > 0 else 0.0, victim=learner,
                             expert=expert, adversary=adversary_file, mode=mode)
        collector, record = learner, {"round": r}
        if r > 0 and cfg.algorithm == "dart":
            cov = learner_error_covariance(learner, data)
            collector = NoisyPolicy(expert, cov, np.random.default_rng([cfg.seed, r]))
            record["noise_trace"] = float(np.trace(cov))
        seed = cfg.seed * 100_000 + r * 1000
        if cfg.source == "graph":
            part, returns, expert_loss = collect_through_graph(
                run_dir / f"round-{r}.mcap", cfg, cfg.expert if r == 0 else str(run_dir / f"pi-{r}.pt"),
                mode if r > 0 else "clean", attack_name if r > 0 else "none", adversary_file, seed)
        else:
            traj = rollout(collector, attack, mode if r > 0 else "clean", cfg.episodes, seed)
            part, returns, expert_loss = DaggerDataset.from_trajectories(traj), traj.returns, traj.mean_expert_loss
        if collector is not learner:
            record["collected_return"] = float(returns.mean())
            judged = rollout(learner, None, "clean", cfg.episodes, seed)
            returns, expert_loss = judged.returns, judged.mean_expert_loss
        record.update({"return": float(returns.mean()), "return_std": float(returns.std()), "expert_loss": expert_loss})
        if r > 0 and attack_name != "none":
            record["clean_return"] = float(rollout(learner, None, "clean", cfg.eval_episodes, EVAL_SEED).returns.mean())
        if r < cfg.rounds:
            data = part if data is None else DaggerDataset.concatenate([data, part])
            data_round = np.concatenate([data_round, np.full(len(part), r)])
            provenance = {"algorithm": cfg.algorithm, "round": r + 1, "samples": len(data),
                          "command": command_line("aril train-learner", cfg), "expert": cfg.expert,
                          "expert_provenance": expert.meta.provenance, "mode": mode, "attack": attack_name,
                          "eps": cfg.eps if attack_name != "none" else 0.0, "seed": cfg.seed,
                          "git_revision": git_revision()}
            policy = fit_policy(data, cfg.env, cfg.hidden, cfg.epochs, cfg.lr, cfg.batch, cfg.seed * 1000 + r,
                                provenance)
            save_policy(policy, run_dir / f"pi-{r + 1}.pt")
            _save_data(data_path, data, data_round)
            record.update(samples=len(data), train_loss=policy.meta.provenance["final_train_loss"])
        record["seconds"] = round(time.time() - round_started, 1)
        state["rounds"].append(record)
        _save_atomic(state_path, lambda tmp: tmp.write_text(json.dumps(state, indent=1)))
        who = "expert" if r == 0 else f"pi_{r}" + (f" {mode}/{attack_name}" if attack_name != "none" else "")
        log(f"[train-learner {name}] round {r}: {who} return {record['return']:8.1f} ± {record['return_std']:6.1f}"
            + (f" (clean {record['clean_return']:.1f})" if "clean_return" in record else "")
            + (f" (noisy expert {record['collected_return']:.1f}, noise trace {record['noise_trace']:.4f})"
               if "noise_trace" in record else "")
            + f"  expert loss {record['expert_loss']:.4f}"
            + (f"  samples {record['samples']:7d}  train loss {record['train_loss']:.4f}" if "samples" in record else "")
            + f"  {record['seconds']:.0f}s", flush=True)

    # the theorem (like DAgger's) bounds the best of the learners pi_1..pi_R, each judged here by its
    # own round: its return under the attack of that round (for ARIL, the adversary trained against it)
    best = max(state["rounds"][1:], key=lambda rec: rec["return"])
    policy = load_policy(run_dir / f"pi-{best['round']}.pt", cfg.env)
    policy.meta.provenance.update({
        "selected": f"pi_{best['round']}", "rounds": cfg.rounds, "train_seconds": round(time.time() - started, 1),
        "selection": "the learner with the best return in its own round"
                     + (f" ({mode}, {attack_name} eps {cfg.eps})" if attack_name != "none" else " (clean)"),
        "rounds_log": state["rounds"],
        "created": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
    })
    out = save_policy(policy, cfg.out or f"runs/{name}.pt")
    log(json.dumps({"out": str(out), "selected": f"pi_{best['round']}", "return": round(best["return"], 1)}))
    return out


def collect_through_graph(record: Path, cfg: LearnerConfig, policy: str, mode: str, attack: str, adversary_file: str,
                          seed: int) -> tuple[DaggerDataset, np.ndarray, float]:
    """Run the round through the ROS 2 graph (``run_graph.py`` in a process of its own, so this module
    never imports rclpy), then read its run log back: the data set, per-episode returns, expert loss."""
    command = [sys.executable, str(ROOT / "run_graph.py"), f"env:={cfg.env}", f"mode:={mode}", f"attack:={attack}",
               f"eps:={cfg.eps if attack != 'none' else 0.0}", f"policy:={policy}", f"expert:={cfg.expert}",
               f"episodes:={cfg.episodes}", f"seed:={seed}", f"record:={record}"]
    if adversary_file:
        command.append(f"attack_file:={adversary_file}")
    done = subprocess.run(command, capture_output=True, text=True, cwd=ROOT)
    if done.returncode != 0:
        raise RuntimeError(f"the graph run for {record.name} failed ({done.returncode}): "
                           + (done.stderr.strip().splitlines() or ["no output"])[-1])
    run = read_run(record)
    returns = np.bincount(run.episodes, weights=run.reward)
    expert_loss = float(((run.action - run.expert_action) ** 2).sum(axis=1).mean())
    return dataset_of_run(run, record), returns, expert_loss
