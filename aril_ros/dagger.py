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
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from .adversary import AdversaryConfig, train_adversary
from .args import arg, command_line
from .attacks import ATTACK_NAMES, attack_for_mode, make_attack
from .dataset import DaggerDataset
from .envs import layout_of
from .experts import git_revision, resolve_policy
from .learners import fit_policy
from .policy import load_policy, save_policy
from .rollout import MODES, RolloutEngine


@dataclass
class DaggerConfig:
    """Arguments of ``aril train-dagger``."""

    env: str = arg("HalfCheetah-v5", "gymnasium MuJoCo env id")
    expert: str = arg("expert", "the expert that labels the true states: a bundled name or a policy file")
    mode: str = arg("clean", f"how the learner runs while collecting: {', '.join(MODES)}")
    attack: str = arg("", f"attack in the loop ({', '.join(ATTACK_NAMES)}; default none when clean, else random): "
                          "random is domain randomisation, aril_a is ARIL")
    eps: float = arg(0.0, "the attack's budget (0 when clean)")
    rounds: int = arg(10, "rounds, including round 0 (expert demonstrations)")
    episodes: int = arg(5, "episodes collected per round (1000 steps each)")
    hidden: int = arg(64, "width of the learner's two hidden layers")
    epochs: int = arg(20, "passes over the aggregated data per fit")
    lr: float = arg(1e-3, "Adam learning rate (the paper's appendix)")
    batch: int = arg(256, "minibatch size")
    adversary_steps: int = arg(300_000, "ARIL: PPO steps of each round's adversary")
    eval_episodes: int = arg(5, "episodes of each round's evaluation (env seeds 500000...)")
    seed: int = arg(0, "seed of the collection (env seeds seed*100000 + round*1000 + i), fits and adversaries")
    run_dir: str = arg("", "the run directory (default runs/<algorithm>-<env>-<mode>); an existing one is resumed")
    out: str = arg("", "where to write the selected policy (default runs/<algorithm>-<env>-<mode>.pt)")
    threads: int = arg(1, "torch threads")

    @property
    def algorithm(self) -> str:
        return {"none": "dagger", "random": "dr", "aril_a": "aril"}.get(attack_for_mode(self.mode, self.attack),
                                                                     f"dagger-{self.attack}")


EVAL_SEED = 500_000


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


def train_dagger(cfg: DaggerConfig, log=print) -> Path:
    """Run (or resume) the rounds; write the selected policy to ``cfg.out`` and return its path."""
    attack_name = attack_for_mode(cfg.mode, cfg.attack)
    if attack_name != "none" and not cfg.eps > 0:
        raise ValueError(f"attack {attack_name} needs eps:= > 0")
    if cfg.rounds < 2:
        raise ValueError("rounds:= must be >= 2 (round 0 is the expert's demonstrations)")
    torch.set_num_threads(cfg.threads)
    layout = layout_of(cfg.env)
    expert = resolve_policy(cfg.expert, cfg.env)
    name = f"{cfg.algorithm}-{cfg.env}-{cfg.mode}"
    run_dir = Path(cfg.run_dir or f"runs/{name}")
    run_dir.mkdir(parents=True, exist_ok=True)
    state_path, data_path = run_dir / "state.json", run_dir / "data.npz"
    config = {k: v for k, v in dataclasses.asdict(cfg).items() if k not in ("run_dir", "out", "threads", "rounds")}
    state = {"config": config, "rounds": []}
    if state_path.exists():
        state = json.loads(state_path.read_text())
        if state["config"] != config:
            changed = sorted(k for k in config if state["config"].get(k) != config[k])
            raise ValueError(f"{run_dir} holds a run with other settings ({', '.join(changed)}); "
                             f"pick another run_dir:= or repeat its settings")
        log(f"[train-dagger {name}] resuming after round {len(state['rounds']) - 1}", flush=True)
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

    # round r (>= 1) first runs pi_r, which is also pi_r's evaluation; the last round only evaluates
    for r in range(len(state["rounds"]), cfg.rounds + 1):
        round_started = time.time()
        learner = expert if r == 0 else load_policy(run_dir / f"pi-{r}.pt", cfg.env)
        adversary_file = ""
        if r > 0 and attack_name == "aril_a":
            adversary_file = str(run_dir / f"adversary-{r}.pt")
            train_adversary(AdversaryConfig(env=cfg.env, mode=cfg.mode, eps=cfg.eps, victim=str(run_dir / f"pi-{r}.pt"),
                                            expert=cfg.expert, steps=cfg.adversary_steps, seed=cfg.seed * 1000 + r,
                                            out=adversary_file), log=log)
        attack = make_attack(attack_name if r > 0 else "none", layout, cfg.eps if r > 0 else 0.0, victim=learner,
                             expert=expert, adversary=adversary_file, mode=cfg.mode)
        traj = rollout(learner, attack, cfg.mode if r > 0 else "clean", cfg.episodes, cfg.seed * 100_000 + r * 1000)
        record = {"round": r, "return": float(traj.returns.mean()), "return_std": float(traj.returns.std()),
                  "expert_loss": traj.mean_expert_loss}
        if r > 0 and attack_name != "none":
            record["clean_return"] = float(rollout(learner, None, "clean", cfg.eval_episodes, EVAL_SEED).returns.mean())
        if r < cfg.rounds:
            part = DaggerDataset.from_trajectories(traj)
            data = part if data is None else DaggerDataset.concatenate([data, part])
            data_round = np.concatenate([data_round, np.full(len(part), r)])
            provenance = {"algorithm": cfg.algorithm, "round": r + 1, "samples": len(data),
                          "command": command_line("aril train-dagger", cfg), "expert": cfg.expert,
                          "expert_provenance": expert.meta.provenance, "mode": cfg.mode, "attack": attack_name,
                          "eps": cfg.eps, "seed": cfg.seed, "git_revision": git_revision()}
            policy = fit_policy(data, cfg.env, cfg.hidden, cfg.epochs, cfg.lr, cfg.batch, cfg.seed * 1000 + r,
                                provenance)
            save_policy(policy, run_dir / f"pi-{r + 1}.pt")
            _save_data(data_path, data, data_round)
            record.update(samples=len(data), train_loss=policy.meta.provenance["final_train_loss"])
        record["seconds"] = round(time.time() - round_started, 1)
        state["rounds"].append(record)
        _save_atomic(state_path, lambda tmp: tmp.write_text(json.dumps(state, indent=1)))
        who = "expert" if r == 0 else f"pi_{r}" + (f" {cfg.mode}/{attack_name}" if attack_name != "none" else "")
        log(f"[train-dagger {name}] round {r}: {who} return {record['return']:8.1f} ± {record['return_std']:6.1f}"
            + (f" (clean {record['clean_return']:.1f})" if "clean_return" in record else "")
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
                     + (f" ({cfg.mode}, {attack_name} eps {cfg.eps})" if attack_name != "none" else " (clean)"),
        "rounds_log": state["rounds"],
        "created": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
    })
    out = save_policy(policy, cfg.out or f"runs/{name}.pt")
    log(json.dumps({"out": str(out), "selected": f"pi_{best['round']}", "return": round(best["return"], 1)}))
    return out
