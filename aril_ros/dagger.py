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

    <run_dir>/state.json        config and one record per finished round (returns, losses, seconds; ARIL:
                                its adversaries' seconds on the clock and their trainings' own, summed)
    <run_dir>/data.npz          the aggregated data set (obs, expert_action, episode, round, source)
    <run_dir>/pi-<r>.pt         pi_r, the learner fitted after round r - 1 (a policy file)
    <run_dir>/adversary-<r>.pt  ARIL only: f_r, the adversary trained against pi_r (none when round_attacks:=
                                made a query attack f_r: the round's record in state.json names it, "attack")
    <run_dir>/adversary-<r>-seed<k>.pt  ARIL with adversary_seeds:=N > 1 or round_attacks:=: the trained
                                candidates f_r was chosen from
    <run_dir>/round-<r>.mcap    source:=graph only: the round's run log

:func:`train_learner` reads top to bottom: check the settings, open (or resume) the run directory,
then per round train its adversary, collect, fit the next learner, and record; finally select.
"""
from __future__ import annotations

import dataclasses
import json
import shutil
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from . import plugins, seeds
from .adversary import AdversaryConfig, ready_adversaries
from .adversary_net import load_adversary
from .args import arg, comma_list
from .attacks import make_attack
from .dataset import DaggerDataset
from .envs import HORIZON, layout_of
from .files import write_atomically
from .learners import fit_policy
from .mcap_log import dataset_of_run, read_run
from .policy import load_policy, resolve_policy, save_policy
from .provenance import now, stamp
from .registry import ATTACKED_MODES, DEFAULT_ENV, MAX_EPS, calibrated_eps
from .rollout import RolloutEngine
from .step import disagreement, episode_stats

ALGORITHMS = {"dagger": "none", "dart": "none", "dr": "random", "aril": "aril_a"}  # and the attack in the loop
ROUND_ATTACKS = ("spsa", "random")
"""Attacks that may be ARIL's f_t beside the trained adversaries (round_attacks:=): black-box, as ARIL-A is."""
SOURCES = ("inprocess", "graph")


@dataclass
class LearnerConfig:
    """Arguments of ``aril train-learner``."""

    algorithm: str = arg("dagger", "dagger: the learner collects | dart: the expert collects with Gaussian action noise "
                                   "sized by the learner's error (Laskey et al. 2017) | dr: dagger under random +-eps "
                                   "perturbations (domain randomisation) | aril: dagger under ARIL-A, retrained against "
                                   "each learner (the paper's Algorithm 1)")
    env: str = arg(DEFAULT_ENV, "gymnasium MuJoCo env id")
    expert: str = arg("expert", "the expert that labels the true states: a bundled name or a policy file")
    mode: str = arg("sensory", "dr and aril: sensory or physical perturbations (dagger and dart collect clean)")
    eps: float = arg(0.0, "dr and aril: the budget (0: the calibrated eps for env and mode, bundled with aril_ros)",
                     low=0.0, high=MAX_EPS)
    rounds: int = arg(10, "rounds of collecting and refitting after round 0 (expert demonstrations)", low=0, high=1000)
    episodes: int = arg(5, "episodes collected per round (1000 steps each)", low=1, high=100_000)
    hidden: int = arg(64, "width of the learner's two hidden layers", low=1, high=4096)
    epochs: int = arg(20, "passes over the aggregated data per fit", low=0, high=100_000)
    lr: float = arg(1e-3, "Adam learning rate (the paper's appendix)", low=0.0, high=1.0)
    batch: int = arg(256, "minibatch size", low=1, high=10**7)
    adversary_steps: int = arg(300_000, "aril: PPO steps of each round's adversary", low=0, high=10**9)
    warm_start: bool = arg(False, "aril: each round's adversary starts from the previous round's (f_{t-1}) instead of "
                                  "fresh weights, so it keeps up with a learner that changes a little per round")
    adversary_seeds: int = arg(1, "aril: f_t is the strongest of this many adversaries trained against pi_t with "
                                  "different seeds (the largest objective at the end of its training): a closer "
                                  "argmax over adversaries, since one PPO run may miss the exploit another finds",
                               low=1, high=100)
    workers: int = arg(1, "aril with adversary_seeds:=N: the candidates trained side by side on this many CPUs of a "
                          "local Ray (1: one after the other in this process); the files are the same either way",
                       low=1, high=1024)
    address: str = arg("", "aril: train the candidates on this Ray cluster instead (<head ip>:6379, or auto)")
    round_attacks: str = arg("", "aril: black-box attacks (comma-separated: spsa, random) that compete with the "
                                 "trained adversaries for f_t; then every candidate is judged by pi_t's mean episode "
                                 "disagreement with the expert under it (the paper's objective) on eval_episodes "
                                 "episodes, and the largest is f_t")
    eval_episodes: int = arg(5, f"dr and aril: episodes of each learner's clean evaluation (env seeds {seeds.LEARNER_EVAL}...)",
                             low=1, high=100_000)
    seed: int = arg(0, "seed of the fits, noise and adversaries; the rounds collect in the seed's training block "
                       "(aril_ros.seeds.collection(seed, round))", low=0, high=999)
    run_dir: str = arg("", "the run directory (default runs/<algorithm>-<env>[-<mode>]); an existing one is resumed")
    out: str = arg("", "where to write the selected policy (default runs/<algorithm>-<env>[-<mode>].pt)")
    threads: int = arg(1, "torch threads", low=1, high=256)
    source: str = arg("inprocess", "where rounds are collected: inprocess (the engine, fast) or graph (through the "
                                   "ROS 2 nodes of the installed ROS side, recorded to <run_dir>/round-<r>.mcap and "
                                   "loaded back); the same seeds give the same data set")


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
    horizon: int = HORIZON
    """steps per episode"""
    domain: str = "auto"
    """the ROS domain of the run (a number when a node started apart, an external policy, must join it)"""
    rescale: bool = False
    """aril_a at an eps other than its file's: its perturbation scaled to eps"""
    k: int = 0
    """iterations of fgsm_k and spsa (0: the attack's default)"""
    samples: int = 0
    """spsa's directions per iteration (0: its default)"""


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


def train_learner(cfg: LearnerConfig, log=print) -> Path:
    """Run (or resume) the rounds; write the selected policy to ``cfg.out`` and return its path."""
    cfg = checked(cfg)
    torch.set_num_threads(cfg.threads)
    run = LearnerRun(cfg, log)
    for r in range(len(run.rounds), cfg.rounds + 1):
        started = time.time()
        adversary = train_round_adversary(cfg, run, r, log)
        adversary_seconds = time.time() - started
        record, part = collect(cfg, run, r, adversary.attack, adversary.file)
        if r < cfg.rounds:
            record.update(run.fit_next(r, part))
        record["seconds"] = round(time.time() - started, 1)
        if r > 0 and run.attack == "aril_a":
            record.update(adversary_seconds=round(adversary_seconds, 1), adversary_cpu_seconds=adversary.cpu_seconds)
        run.finish_round(record)
        log(round_line(cfg, run, record), flush=True)
    return select_best(cfg, run, log)


def checked(cfg: LearnerConfig) -> LearnerConfig:
    """``cfg`` with its eps filled in from the calibration when unset; a ValueError for what cannot run."""
    if cfg.algorithm not in ALGORITHMS:
        raise ValueError(f"unknown algorithm {cfg.algorithm!r}; choose one of {', '.join(ALGORITHMS)}")
    if ALGORITHMS[cfg.algorithm] != "none":
        if cfg.mode not in ATTACKED_MODES:
            raise ValueError(f"{cfg.algorithm} needs mode:=sensory or mode:=physical, got {cfg.mode!r}")
        if cfg.eps == 0:
            cfg = dataclasses.replace(cfg, eps=calibrated_eps(cfg.env, cfg.mode))
        if not cfg.eps > 0:
            raise ValueError(f"eps:= must be > 0, got {cfg.eps}")
    if cfg.rounds < 1:
        raise ValueError("rounds:= must be >= 1")
    if cfg.adversary_seeds < 1:
        raise ValueError(f"adversary_seeds:= must be >= 1, got {cfg.adversary_seeds}")
    for name in comma_list(cfg.round_attacks):
        if name not in ROUND_ATTACKS:
            raise ValueError(f"round_attacks:= takes black-box attacks ({', '.join(ROUND_ATTACKS)}), got {name!r}")
    if cfg.round_attacks and (cfg.algorithm != "aril" or cfg.warm_start):
        raise ValueError("round_attacks:= is for algorithm:=aril without warm_start (which needs a learned f_{t-1})")
    if cfg.source not in SOURCES:
        raise ValueError(f"source:= must be one of {', '.join(SOURCES)}, got {cfg.source!r}")
    if cfg.source == "graph" and cfg.algorithm == "dart":
        raise ValueError("dart collects with a noisy expert, which has no policy node: use source:=inprocess")
    return cfg


class LearnerRun:
    """The run directory: its settings, one record per finished round, the aggregated data set and the
    learners; opening an existing one resumes it after its last finished round."""

    def __init__(self, cfg: LearnerConfig, log):
        self.cfg = cfg
        self.attack = ALGORITHMS[cfg.algorithm]
        self.mode = cfg.mode if self.attack != "none" else "clean"
        self.name = f"{cfg.algorithm}-{cfg.env}" + (f"-{cfg.mode}" if self.attack != "none" else "")
        self.dir = Path(cfg.run_dir or f"runs/{self.name}")
        self.dir.mkdir(parents=True, exist_ok=True)
        self.state_path, self.data_path = self.dir / "state.json", self.dir / "data.npz"
        self.expert = resolve_policy(cfg.expert, cfg.env)
        self.layout = layout_of(cfg.env)
        config = {k: v for k, v in dataclasses.asdict(cfg).items()
                  if k not in ("run_dir", "out", "threads", "workers", "address", "rounds", "eval_episodes",
                              "source")}
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
                      "eps": cfg.eps if self.attack != "none" else 0.0, "seed": cfg.seed}
        policy = fit_policy(self.data, cfg.env, cfg.hidden, cfg.epochs, cfg.lr, cfg.batch,
                            seeds.round_weights(cfg.seed, r), provenance)
        save_policy(policy, self.policy_file(r + 1))
        write_atomically(self.data_path, lambda partial: _write_data(partial, self.data, self.data_round))
        return {"samples": len(self.data), "train_loss": policy.meta.provenance["final_train_loss"]}

    def finish_round(self, record: dict) -> None:
        self.rounds.append(record)
        write_atomically(self.state_path, lambda partial: partial.write_text(json.dumps(self.state, indent=1)))

    def rollout(self, policy, attack, mode: str, episodes: int, seed: int):
        engine = RolloutEngine(self.cfg.env, policy, self.expert, attack, mode, n_envs=min(episodes, 16))
        try:
            return engine.rollout(episodes, seed)
        finally:
            engine.close()


@dataclass
class RoundAdversary:
    """A round's f_t as the round collects under it."""

    attack: str
    """the attack's name (``aril_a`` for a trained adversary)"""
    file: str = ""
    """the adversary file, for ``aril_a``"""
    cpu_seconds: float = 0.0
    """the training time of every candidate it was chosen from (the round's compute, not its wall time)"""


def train_round_adversary(cfg: LearnerConfig, run: LearnerRun, r: int, log) -> RoundAdversary:
    """Round ``r``'s attack and adversary file: for ARIL, f_r trained against pi_r (warm-started from f_{r-1} if
    asked); with ``adversary_seeds`` > 1 the candidate whose objective (the mean episode loss of its last updates;
    0 when no episode finished) is largest, copied from ``adversary-<r>-seed<k>.pt``; with ``round_attacks`` the
    strongest on pi_r of the candidates and those attacks (:func:`strongest_on`). Else the run's attack, no file."""
    if r == 0 or run.attack != "aril_a":
        return RoundAdversary(run.attack)
    out, candidates = run.dir / f"adversary-{r}.pt", round_candidates(cfg, run, r)
    init = str(run.dir / f"adversary-{r - 1}.pt") if cfg.warm_start and r > 1 else ""
    wanted = [AdversaryConfig(env=cfg.env, mode=run.mode, eps=cfg.eps, victim=str(run.policy_file(r)),
                              expert=cfg.expert, steps=cfg.adversary_steps, seed=seeds.round_adversary(cfg.seed, r, k),
                              init=init, out=str(file)) for k, file in enumerate(candidates)]
    # one finished before an interruption is kept: the same seed against the same pi_r gives the same file
    ready_adversaries(wanted, False, log, cfg.workers, cfg.address)
    made = {file: load_adversary(file).meta["provenance"] for file in candidates}
    cpu_seconds = sum(provenance["train_seconds"] for provenance in made.values())
    if cfg.round_attacks:
        attack, file = strongest_on(cfg, run, r, [("aril_a", str(f)) for f in candidates]
                                    + [(name, "") for name in comma_list(cfg.round_attacks)], log)
        if not file:
            return RoundAdversary(attack, "", cpu_seconds)
        candidates = [Path(file)]
    if len(candidates) > 1:
        objectives = [made[file]["final_episode_loss"] or 0.0 for file in candidates]
        best = int(np.argmax(objectives))
        log(f"[train-learner {run.name}] round {r}: f_{r} is candidate {best} of {len(candidates)} (objectives "
            + ", ".join(f"{o:.1f}" for o in objectives) + ")", flush=True)
        candidates = [candidates[best]]
    if candidates[0] != out:
        shutil.copyfile(candidates[0], out)
    return RoundAdversary("aril_a", str(out), cpu_seconds)


def strongest_on(cfg: LearnerConfig, run: LearnerRun, r: int, options: list[tuple[str, str]], log
                 ) -> tuple[str, str]:
    """The (attack, adversary file) of ``options`` under which pi_r disagrees most with the expert: the paper's
    objective, the summed squared disagreement per episode, averaged over ``eval_episodes`` episodes that every
    option plays alike (:func:`seeds.round_judging`)."""
    learner, objectives = run.learner(r), []
    for name, file in options:
        attack = make_attack(name, run.layout, cfg.eps, victim=learner, expert=run.expert, adversary=file or None,
                             mode=run.mode)
        traj = run.rollout(learner, attack, run.mode, cfg.eval_episodes, seeds.round_judging(cfg.seed, r))
        objectives.append(float(disagreement(traj.action, traj.expert_action).sum()) / len(traj.length))
    best = int(np.argmax(objectives))
    labels = [name + (f" {Path(file).name}" if file else "") for name, file in options]
    log(f"[train-learner {run.name}] round {r}: f_{r} is {labels[best]} (objectives on pi_{r}: "
        + ", ".join(f"{label} {o:.1f}" for label, o in zip(labels, objectives)) + ")", flush=True)
    return options[best]


def round_candidates(cfg: LearnerConfig, run: LearnerRun, r: int) -> list[Path]:
    """The files of round ``r``'s trained adversaries: f_r itself, or the candidates it is chosen from."""
    if cfg.adversary_seeds == 1 and not cfg.round_attacks:
        return [run.dir / f"adversary-{r}.pt"]
    return [run.dir / f"adversary-{r}-seed{k}.pt" for k in range(cfg.adversary_seeds)]


def collect(cfg: LearnerConfig, run: LearnerRun, r: int, attack: str, adversary_file: str
            ) -> tuple[dict, DaggerDataset]:
    """Run round ``r``: pi_r under the round's attack (its run is also its evaluation), or DART's noisy
    expert (pi_r then judged apart); the round's record and its (observation seen, expert action) pairs."""
    learner = run.learner(r)
    mode, attack_name = (run.mode, attack) if r > 0 else ("clean", "none")
    eps = cfg.eps if attack_name != "none" else 0.0
    seed = seeds.collection(cfg.seed, r)
    record = {"round": r, **({"attack": attack_name} if attack_name != run.attack and r > 0 else {})}
    if cfg.source == "graph":
        policy = cfg.expert if r == 0 else str(run.policy_file(r))
        spec = RoundSpec(env=cfg.env, mode=mode, attack=attack_name, eps=eps, policy=policy, expert=cfg.expert,
                         attack_file=adversary_file, episodes=cfg.episodes, seed=seed,
                         record=run.dir / f"round-{r}.mcap")
        spec.record.unlink(missing_ok=True)  # an earlier, killed attempt at this round: the run log is made anew
        log_path = plugins.load("aril_ros.collectors", "graph")(spec)
        logged = read_run(log_path)
        episodes = episode_stats(logged.episodes, logged.reward, logged.action, logged.expert_action, logged.delta)
        part = dataset_of_run(logged, log_path)
        returns = np.array([e.reward for e in episodes])
        expert_loss = sum(e.squared_loss for e in episodes) / sum(e.steps for e in episodes)
    else:
        collector = learner
        if r > 0 and cfg.algorithm == "dart":
            cov = learner_error_covariance(learner, run.data)
            collector = NoisyPolicy(run.expert, cov, np.random.default_rng([cfg.seed, r]))
            record["noise_trace"] = float(np.trace(cov))
        attack = make_attack(attack_name, run.layout, eps, victim=learner, expert=run.expert,
                             adversary=adversary_file, mode=mode)
        traj = run.rollout(collector, attack, mode, cfg.episodes, seed)
        part, returns, expert_loss = DaggerDataset.from_trajectories(traj), traj.returns, traj.mean_expert_loss
        if collector is not learner:
            record["collected_return"] = float(returns.mean())
            judged = run.rollout(learner, None, "clean", cfg.episodes, seed)
            returns, expert_loss = judged.returns, judged.mean_expert_loss
    record.update({"return": float(returns.mean()), "return_std": float(returns.std()), "expert_loss": expert_loss})
    if r > 0 and attack_name != "none":
        clean = run.rollout(learner, None, "clean", cfg.eval_episodes, seeds.LEARNER_EVAL)
        record["clean_return"] = float(clean.returns.mean())
    return record, part


def round_line(cfg: LearnerConfig, run: LearnerRun, record: dict) -> str:
    r = record["round"]
    attack = record.get("attack", run.attack)
    who = "expert" if r == 0 else f"pi_{r}" + (f" {run.mode}/{attack}" if attack != "none" else "")
    return (f"[train-learner {run.name}] round {r}: {who} return {record['return']:8.1f} ± {record['return_std']:6.1f}"
            + (f" (clean {record['clean_return']:.1f})" if "clean_return" in record else "")
            + (f" (noisy expert {record['collected_return']:.1f}, noise trace {record['noise_trace']:.4f})"
               if "noise_trace" in record else "")
            + f"  expert loss {record['expert_loss']:.4f}"
            + (f"  samples {record['samples']:7d}  train loss {record['train_loss']:.4f}" if "samples" in record else "")
            + f"  {record['seconds']:.0f}s")


def select_best(cfg: LearnerConfig, run: LearnerRun, log) -> Path:
    """The theorem (like DAgger's) bounds the best of the learners pi_1..pi_R, each judged here by its
    own round: its return under the attack of that round (for ARIL, the adversary trained against it)."""
    best = max(run.rounds[1:], key=lambda rec: rec["return"])
    out = save_selected(cfg, run, best["round"], "the learner with the best return in its own round"
                        + (f" ({run.mode}, {run.attack} eps {cfg.eps})" if run.attack != "none" else " (clean)"))
    log(json.dumps({"out": str(out), "selected": f"pi_{best['round']}", "return": round(best["return"], 1)}))
    return out


def save_selected(cfg: LearnerConfig, run: LearnerRun, r: int, selection: str, **provenance) -> Path:
    """pi_r written to ``cfg.out`` (default ``runs/<run name>.pt``), its provenance saying how it was chosen
    (``selection``, and any further ``provenance`` fields) beside the run's round records."""
    policy = load_policy(run.policy_file(r), cfg.env)
    seconds = time.time() - run.started
    # CPU time: the round adversaries' trainings count at their own times (side by side they overlap on the clock)
    cpu_seconds = seconds + sum(rec.get("adversary_cpu_seconds", 0) - rec.get("adversary_seconds", 0)
                                for rec in run.rounds)
    policy.meta.provenance.update({
        "selected": f"pi_{r}", "rounds": cfg.rounds, "train_seconds": round(seconds, 1),
        "cpu_seconds": round(cpu_seconds, 1), "selection": selection, "rounds_log": run.rounds, "created": now(),
        **provenance,
    })
    return save_policy(policy, cfg.out or f"runs/{run.name}.pt")


def _write_data(path: Path, data: DaggerDataset, rounds: np.ndarray) -> None:
    with open(path, "wb") as fh:
        np.savez(fh, obs=data.obs, expert_action=data.expert_action, episode=data.episode,
                 source=np.array(data.source), round=rounds)
