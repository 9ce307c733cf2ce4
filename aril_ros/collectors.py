"""Where a round of ``aril train-learner`` is collected: a collector runs round ``r`` as its
:class:`RoundSpec` says and returns the (observation seen, expert action) pairs with the figures of the
round's learner. :func:`engine` runs it in process, :func:`graph` through the ROS 2 nodes (the same
seeds give the same pairs), and :func:`noisy_expert` is DART's: the expert collects with noise.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import plugins
from .attacks import make_attack
from .dataset import DaggerDataset, dataset_of_run
from .envs import HORIZON
from .learner_config import LearnerConfig
from .learner_run import LearnerRun
from .runlog import read_run
from .timing import TimingAttack


@dataclass
class RoundSpec:
    """One round's collection as a collector receives it; the graph's is the ROS side's ``aril_ros.collectors``
    entry point, which runs it through the nodes and records it (``aril scorecard`` runs its graph cells so)."""

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
    """where the collector writes the round's run log (MCAP, see :mod:`aril_ros.runlog`)"""
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
    search: int = 0
    """aril_a's query-time search: candidates a step the policy is asked about (0: none)"""
    delay: int = 0
    """a timing attack's observation delay, in steps (:mod:`aril_ros.timing`; 0: none)"""
    drop: float = 0.0
    """a timing attack's share of dropped observations (0: none)"""
    action_delay: int = 0
    """a timing attack's action delay, in steps (0: none)"""
    timing: str = "fixed"
    """who picks within the timing budget (:data:`aril_ros.timing.CHOOSERS`)"""
    timing_file: str = ""
    """``learned``'s timing adversary file"""


@dataclass
class Collected:
    """A round's pairs and how its learner fared."""

    data: DaggerDataset
    returns: np.ndarray
    """per episode, of the learner pi_r (under the round's attack)"""
    expert_loss: float
    """pi_r's mean squared disagreement with the expert per step"""
    figures: dict = field(default_factory=dict)
    """the collector's own figures for the round's record"""


Collector = Callable[[LearnerRun, int, object, RoundSpec], Collected]
"""A collector: ``(run, r, learner, spec) -> Collected``, round ``r`` of ``run`` with ``learner`` (pi_r, the expert in
round 0) as ``spec`` says."""


def collector_for(cfg: LearnerConfig) -> Collector:
    """The collector of ``cfg``'s rounds."""
    if cfg.source == "graph":
        return graph
    return noisy_expert if cfg.algorithm == "dart" else engine


def engine(run: LearnerRun, r: int, learner, spec: RoundSpec) -> Collected:
    """pi_r (``learner``) collects under the round's attack in process."""
    traj = _attacked_rollout(run, learner, learner, spec)
    return Collected(DaggerDataset.from_trajectories(traj), traj.returns, traj.mean_expert_loss)


def graph(run: LearnerRun, r: int, learner, spec: RoundSpec) -> Collected:
    """pi_r collects through the ROS 2 nodes, recorded to ``spec.record``; the pairs and figures read back from the
    run log."""
    spec.record.unlink(missing_ok=True)  # an earlier, killed attempt at this round: the run log is made anew
    log_path = plugins.load("aril_ros.collectors", "graph")(spec)
    logged = read_run(log_path)
    episodes = logged.episode_stats  # the recorder's figures, taken once as the run went
    expert_loss = sum(e.squared_loss for e in episodes) / sum(e.steps for e in episodes)
    return Collected(dataset_of_run(logged, log_path), np.array([e.reward for e in episodes]), expert_loss)


def noisy_expert(run: LearnerRun, r: int, learner, spec: RoundSpec) -> Collected:
    """DART (Laskey et al. 2017): after the expert's clean demonstrations, the expert collects with Gaussian action
    noise of the learner's error on the data so far, and pi_r is judged apart, clean, on the round's seeds."""
    if r == 0:
        return engine(run, r, learner, spec)
    cov = learner_error_covariance(learner, run.data)
    traj = _attacked_rollout(run, NoisyPolicy(run.expert, cov, np.random.default_rng([run.cfg.seed, r])), learner,
                             spec)
    judged = run.rollout(learner, None, "clean", spec.episodes, spec.seed)
    return Collected(DaggerDataset.from_trajectories(traj), judged.returns, judged.mean_expert_loss,
                     {"noise_trace": float(np.trace(cov)), "collected_return": float(traj.returns.mean())})


def _attacked_rollout(run: LearnerRun, collecting, learner, spec: RoundSpec):
    """``collecting`` plays the round's episodes under its attack, which targets the learner pi_r."""
    attack = make_attack(spec.attack, run.layout, spec.eps, victim=learner, expert=run.expert,
                         adversary=spec.attack_file, mode=spec.mode)
    return run.rollout(collecting, attack, spec.mode, spec.episodes, spec.seed, TimingAttack.of(spec))


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
