"""The run directory of ``aril train-learner``: everything needed to resume after an interruption from
the last finished round::

    <run_dir>/state.json        config and one record per finished round (returns, losses, seconds; ARIL:
                                its adversaries' seconds on the clock and their trainings' own, summed)
    <run_dir>/data.npz          the aggregated data set (obs, expert_action, episode, round, source)
    <run_dir>/pi-<r>.pt         pi_r, the learner fitted after round r - 1 (a policy file)
    <run_dir>/adversary-<r>.pt  ARIL only: f_r, the adversary trained against pi_r (none when round_attacks:=
                                made a query attack f_r: the round's record in state.json names it, "attack")
    <run_dir>/adversary-<r>-seed<k>.pt  ARIL with adversary_seeds:=N > 1 or round_attacks:=: the trained
                                candidates f_r was chosen from
    <run_dir>/timing-adversary-<r>.pt  ARIL with a timing budget: the timing adversary trained against pi_r
                                (-seed<k>: its candidates, as the value adversary's)
    <run_dir>/round-<r>.mcap    source:=graph only: the round's run log
"""
from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path

import numpy as np

from . import seeds
from .dataset import DaggerDataset
from .envs import layout_of
from .files import write_atomically
from .learner_config import ALGORITHMS, LearnerConfig, timing_in_loop
from .learners import fit_policy
from .policy import load_policy, resolve_policy, save_policy
from .provenance import now, stamp
from .rollout import RolloutEngine
from .timing import TimingAttack

NOT_RECORDED = ("run_dir", "out", "threads", "workers", "address", "rounds", "eval_episodes", "source", "select")
"""Settings a run may be resumed with changed: where and how fast it runs, how long it goes on, what only
its log reports (the clean evaluations) and which learner it returns; the data set and the learners do not depend
on them."""


class LearnerRun:
    """The run directory: its settings, one record per finished round, the aggregated data set and the
    learners; opening an existing one resumes it after its last finished round."""

    def __init__(self, cfg: LearnerConfig, log):
        self.cfg = cfg
        self.timing = timing_in_loop(cfg)
        self.attack = ALGORITHMS[cfg.algorithm] if cfg.mode != "clean" else "none"
        self.mode = cfg.mode if self.attack != "none" else "clean"
        self.name = (f"{cfg.algorithm}-{cfg.env}" + (f"-{cfg.mode}" if self.attack != "none" else "")
                     + "".join(f"-{k.replace('_', '')}{v:g}" for k, v in dataclasses.asdict(self.timing).items() if v))
        self.timing_chooser = "learned" if cfg.algorithm == "aril" else "random"
        """who times the rounds under a timing budget: dr at random, aril a timing adversary trained against pi_r"""
        self.dir = Path(cfg.run_dir or f"runs/{self.name}")
        self.dir.mkdir(parents=True, exist_ok=True)
        self.state_path, self.data_path = self.dir / "state.json", self.dir / "data.npz"
        self.expert = resolve_policy(cfg.expert, cfg.env)
        self.layout = layout_of(cfg.env)
        config = {k: v for k, v in dataclasses.asdict(cfg).items() if k not in NOT_RECORDED}
        state = {"config": config, "rounds": []}
        if self.state_path.exists():
            state = json.loads(self.state_path.read_text())
            defaults = dataclasses.asdict(LearnerConfig())  # a setting added since the run was made had its default
            stored = {**{k: defaults[k] for k in config}, **state["config"]}
            if stored != config:
                changed = sorted(k for k in config if stored.get(k) != config[k])
                raise ValueError(f"{self.dir} holds a run with other settings ({', '.join(changed)}); "
                                 f"pick another run_dir:= or repeat its settings")
            log(f"[train-learner {self.name}] resuming after round {len(state['rounds']) - 1}", flush=True)
        self.state = state
        self.rounds: list[dict] = state["rounds"]
        if self.rounds and "samples" not in self.rounds[-1] and len(self.rounds) <= cfg.rounds:
            self.rounds.pop()  # the evaluation-only last round of a shorter run: now it collects and fits too
        self.data, self.data_round = self._load_data()
        self.started = time.time() - sum(r["seconds"] for r in self.rounds)

    def _load_data(self) -> tuple[DaggerDataset | None, np.ndarray]:
        if not (self.data_path.exists() and self.rounds):
            return None, np.zeros(0, dtype=np.int64)
        with np.load(self.data_path) as f:
            keep = f["round"] < len(self.rounds)  # drop a round whose record was not written (killed between)
            data = DaggerDataset(obs=f["obs"][keep], expert_action=f["expert_action"][keep],
                                 episode=f["episode"][keep], source=[str(s) for s, k in zip(f["source"], keep) if k])
            return data, f["round"][keep]

    def policy_file(self, r: int) -> Path:
        return self.dir / f"pi-{r}.pt"

    def learner(self, r: int):
        """pi_r: the expert for round 0 (its demonstrations), else the learner fitted after round r - 1."""
        return self.expert if r == 0 else load_policy(self.policy_file(r), self.cfg.env)

    def fit_next(self, r: int, part: DaggerDataset) -> dict:
        """Aggregate round ``r``'s pairs and fit pi_{r+1} on all of them from scratch."""
        cfg = self.cfg
        self.data = part if self.data is None else DaggerDataset.concatenate([self.data, part])
        self.data_round = np.concatenate([self.data_round, np.full(len(part), r)])
        provenance = {"algorithm": cfg.algorithm, "round": r + 1, "samples": len(self.data),
                      **stamp("aril train-learner", cfg), "expert": cfg.expert,
                      "expert_provenance": self.expert.meta.provenance, "mode": self.mode, "attack": self.attack,
                      "eps": cfg.eps if self.attack != "none" else 0.0, "seed": cfg.seed,
                      **({"timing": {**dataclasses.asdict(self.timing), "chooser": self.timing_chooser}}
                         if self.timing.any else {})}
        policy = fit_policy(self.data, cfg.env, cfg.hidden, cfg.epochs, cfg.lr, cfg.batch,
                            seeds.round_weights(cfg.seed, r), provenance)
        save_policy(policy, self.policy_file(r + 1))
        write_atomically(self.data_path, lambda partial: _write_data(partial, self.data, self.data_round))
        return {"samples": len(self.data), "train_loss": policy.meta.provenance["final_train_loss"]}

    def finish_round(self, record: dict) -> None:
        self.rounds.append(record)
        write_atomically(self.state_path, lambda partial: partial.write_text(json.dumps(self.state, indent=1)))

    def rollout(self, policy, attack, mode: str, episodes: int, seed: int, timing: TimingAttack | None = None):
        engine = RolloutEngine(self.cfg.env, policy, self.expert, attack, mode, n_envs=min(episodes, 16), timing=timing)
        try:
            return engine.rollout(episodes, seed)
        finally:
            engine.close()

    def round_line(self, record: dict) -> str:
        """A finished round as the log shows it."""
        r = record["round"]
        attack = record.get("attack", self.attack)
        who = "expert" if r == 0 else (f"pi_{r}" + (f" {self.mode}/{attack}" if attack != "none" else "")
                                       + (f" timed ({self.timing_chooser})" if self.timing.any else ""))
        return (f"[train-learner {self.name}] round {r}: {who} return {record['return']:8.1f} ± "
                f"{record['return_std']:6.1f}"
                + (f" (clean {record['clean_return']:.1f})" if "clean_return" in record else "")
                + (" (mix: " + ", ".join(f"{name} {value:.1f}" for name, value in record["mix"].items()) + ")"
                   if "mix" in record else "")
                + (f" (noisy expert {record['collected_return']:.1f}, noise trace {record['noise_trace']:.4f})"
                   if "noise_trace" in record else "")
                + f"  expert loss {record['expert_loss']:.4f}"
                + (f"  samples {record['samples']:7d}  train loss {record['train_loss']:.4f}"
                   if "samples" in record else "")
                + f"  {record['seconds']:.0f}s")

    def save_selected(self, r: int, selection: str) -> Path:
        """pi_r written to ``cfg.out`` (default ``runs/<run name>.pt``), its provenance saying how it was chosen
        (``selection``) beside the run's round records."""
        policy = load_policy(self.policy_file(r), self.cfg.env)
        seconds = time.time() - self.started
        # CPU time: the round adversaries' trainings count at their own times (side by side they overlap on the clock)
        cpu_seconds = seconds + sum(rec.get("adversary_cpu_seconds", 0) - rec.get("adversary_seconds", 0)
                                    for rec in self.rounds)
        policy.meta.provenance.update({
            "selected": f"pi_{r}", "rounds": self.cfg.rounds, "train_seconds": round(seconds, 1),
            "cpu_seconds": round(cpu_seconds, 1), "selection": selection, "rounds_log": self.rounds,
            "created": now(),
        })
        return save_policy(policy, self.cfg.out or f"runs/{self.name}.pt")


def _write_data(path: Path, data: DaggerDataset, rounds: np.ndarray) -> None:
    with open(path, "wb") as fh:
        np.savez(fh, obs=data.obs, expert_action=data.expert_action, episode=data.episode,
                 source=np.array(data.source), round=rounds)
