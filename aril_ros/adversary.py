"""ARIL-A, the learned adversary (paper §4.2), trained by PPO on vectorised in-process simulators; and the learned
timing adversary (:mod:`aril_ros.timing_adversary`), the same training with time for values.

The adversary (:class:`aril_ros.adversary_net.AdversaryNet`) is a distribution over perturbations of the
zero-order entries within ``±eps`` (by default a categorical over ``{-eps, 0, +eps}`` per entry), given the
*true* observation ``s`` (and, with ``inputs:=state+actions``, the victim's and the expert's actions on
``s``, which the trainer queries anyway for the critic). Its reward at step h
is the victim's disagreement with the expert on the true state, ``||a_h - pi_e(s_h)||^2``, where
``a_h`` is the victim's action on what the attack made it see (sensory) or on the moved state
(physical), by the step rules of :mod:`aril_ros.step`; PPO maximises the discounted sum. It never
needs the victim's gradients: it only queries actions, so any black-box policy can be attacked. Two settings change
the objective, both off by default: ``objective:=return`` rewards minus the victim's env reward instead, and
``terminal:=`` gives an episode the victim ended early (a fallen Ant) a value after its end, which by default it
has not.
How a sample acts on a step is a :class:`ValuePlay`'s (a perturbation) or, in mode ``clean`` with a timing budget
(``delay:=``, ``drop:=``, ``action_delay:=``), a :class:`TimingPlay`'s (when the observation is late or dropped and
the action applied late; ``a_h`` is then the action applied).

The critic is split in two: the victim's disagreement at the state *without* the attack, computed
exactly by querying the victim (``baseline``), plus a learned remainder. A perturbation moves the
disagreement by little next to how much it varies from state to state, more than a learned value
follows; the exact part removes that variance from the advantages without changing the objective
(it is a state-dependent baseline, and the rewards stay the raw disagreement).

:func:`train_adversary` reads top to bottom (cleanrl style): scale the inputs on the states the
victim visits, then repeat: collect ``rollout`` steps on ``n_envs`` simulators, compute GAE
advantages, run ``epochs`` of clipped PPO updates.
"""
from __future__ import annotations

import json
import time
from contextlib import nullcontext
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
from torch import nn

from . import plugins, seeds
from .adversary_net import INPUTS, POLICIES, AdversaryNet, input_rows, load_adversary, pushes, save_adversary
from .args import arg
from .envs import layout_of
from .policy import Answers, load_policy, policy_file, resolve_policy
from .protocol import ros_domain
from .provenance import stamp
from .registry import ATTACKED_MODES, DEFAULT_ENV, MAX_EPS, check_name, for_task
from .rollout import SimBatch
from .step import disagreement
from .sweep import Produced, digest_of, run_tasks, shipped
from .timing import Timeline, TimingBudget, TimingChoice, timing_arg
from .timing_adversary import TimingNet, load_timing_adversary, save_timing_adversary


OBJECTIVES = ("disagreement", "return")
"""The values of ``objective:=`` (:class:`AdversaryConfig`)."""
TERMINAL = ("nothing", "bootstrap", "held")
"""The values of ``terminal:=`` (:class:`AdversaryConfig`)."""


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


@dataclass
class AdversaryConfig:
    """Arguments of ``aril train-adversary`` (defaults: the paper's Table 3 and appendix)."""

    env: str = arg(DEFAULT_ENV, "gymnasium MuJoCo env id")
    mode: str = arg("sensory", "sensory or physical: a value adversary (ARIL-A); clean with a timing budget "
                               "(delay:=, drop:=, action_delay:=): a timing adversary (aril_ros.timing_adversary)")
    eps: float = arg(0.05, "L-infinity budget on the zero-order entries (a value adversary)", low=0.0, high=MAX_EPS)
    delay: int = timing_arg("delay", "a timing adversary's budget, mode:=clean")
    drop: float = timing_arg("drop", "a timing adversary's budget, mode:=clean")
    action_delay: int = timing_arg("action_delay", "a timing adversary's budget, mode:=clean")
    victim: str = arg("expert", "the attacked policy: a bundled name, a policy file, or ros (a running policy node "
                                "on observation -> action in this ROS_DOMAIN_ID, through the installed ROS side); "
                                "only its actions are used")
    domain: str = arg("", "victim:=ros: the ROS_DOMAIN_ID the policy node runs in (default: this process's)")
    expert: str = arg("expert", "the expert whose action on the true state defines the loss")
    steps: int = arg(1_000_000, "environment steps of training (the paper: 1e6 per attack stage)", low=0, high=10**9)
    n_envs: int = arg(16, "simulators run side by side", low=1, high=1024)
    rollout: int = arg(256, "steps per simulator between PPO updates", low=1, high=1_000_000)
    epochs: int = arg(10, "PPO epochs per update", low=0, high=10_000)
    minibatch: int = arg(1024, "samples per PPO minibatch", low=1, high=10**7)
    lr: float = arg(1e-3, "Adam learning rate (the paper's appendix)", low=0.0, high=1.0)
    gamma: float = arg(0.99, "discount of the adversary's return", low=0.0, high=1.0)
    gae_lambda: float = arg(0.95, "GAE lambda", low=0.0, high=1.0)
    clip: float = arg(0.2, "PPO clip range (Table 3)", low=0.0, high=1.0)
    ent_coef: float = arg(0.01, "entropy bonus (Table 3)", low=0.0, high=10.0)
    vf_coef: float = arg(0.5, "value loss weight (Table 3)", low=0.0, high=10.0)
    max_grad_norm: float = arg(0.5, "gradient norm clip", low=0.0, high=1000.0)
    hidden: int = arg(64, "width of the two hidden layers", low=1, high=4096)
    policy: str = arg("categorical", "a value adversary's: categorical: one of {-eps, 0, +eps} per zero-order entry (the corners of the "
                                     "L-infinity box, where a one-step attack's optimum lies); gaussian: a Normal "
                                     "around eps*tanh(net), clipped to the box (the adversaries made before); "
                                     "directed: a Normal over a direction in the victim's action space, turned into "
                                     "the corner that moves the action furthest along it by finite differences of the "
                                     "victim's answers (PA-AD's director and actor, black-box; 2 questions per "
                                     "zero-order entry a step)")
    inputs: str = arg("state+actions", "a value adversary's: state: the true observation alone; state+actions: also the victim's action "
                                       "on it unperturbed and the expert's (queried answers, never weights)")
    warmup: int = arg(200, "steps per simulator of the unattacked victim that set the input normalisation",
                      low=1, high=1_000_000)
    norm_reward: bool = arg(True, "divide rewards by the running std of the discounted return")
    baseline: bool = arg(True, "value = the victim's unperturbed disagreement at the state (computed exactly) + a "
                              "learned remainder, instead of all learned (a control variate: the objective is the same)")
    objective: str = arg("disagreement", "what the adversary maximises, summed over the episode with gamma: "
                                        "disagreement: the victim's with the expert on the true state (the paper's "
                                        "ARIL-A); return: minus the victim's reward from the env (the optimal attack "
                                        "of Zhang et al. 2021; no exact part in the value, whatever baseline:= says)")
    terminal: str = arg("nothing", "what an episode the victim ended early (Ant fallen over: the env's termination) is "
                                   "worth to the adversary after its last step: nothing (an early end stops the "
                                   "disagreement it collects, so toppling the victim costs it reward); bootstrap: the "
                                   "value of the state it ended in, as at the time limit; held: that state's "
                                   "disagreement at every step after, gamma / (1 - gamma) times it")
    seed: int = arg(0, "seed of the initial weights and the sampling; the env resets take the seed's training block "
                       "(aril_ros.seeds.adversary_training)", low=0, high=2**31 - 1)
    init: str = arg("", "start from this adversary file (same env, mode, eps and width; its input scaling is kept) "
                        "instead of fresh weights: ARIL's warm start from the previous round's adversary")
    out: str = arg("", "where to write the adversary (default: runs/adversary-<env>-<mode>.pt, a timing one "
                       "runs/timing-adversary-<env>.pt)")
    snapshot_every: int = arg(0, "also write the adversary every this many steps before the end (0: never), beside "
                                 "out:= as <its stem>-at-<steps>.pt: what the verdict's pipeline screens to keep the "
                                 "strongest, since the last state is not always the one that takes the most return",
                              low=0, high=10**9)
    threads: int = arg(1, "torch threads", low=1, high=256)


def train_adversary(cfg: AdversaryConfig, log=print, victim=None) -> Path:
    """Train ARIL-A against ``cfg.victim`` (or ``victim``: any object with ``act(obs_batch)`` and
    ``meta.provenance``); writes the adversary file, returns its path. A victim name registered by an
    installed package (``ros``: a live policy node) is connected for the training and closed after."""
    check_config(cfg)
    if victim is not None:
        return train_against(cfg, victim, log)
    if cfg.victim in plugins.names("aril_ros.victims"):
        with ros_domain(cfg.domain) if cfg.domain else nullcontext():
            remote = plugins.load("aril_ros.victims", cfg.victim)(cfg.env)
            try:
                return train_against(cfg, remote, log)
            finally:
                remote.close()
    file = policy_file(cfg.victim, cfg.env, cfg.mode)
    return train_against(cfg, load_policy(file, cfg.env), log, victim_digest=digest_of(file.read_bytes()))


def train_against(cfg: AdversaryConfig, victim, log, victim_digest: str = "") -> Path:
    """The training: scale the inputs, then collect, estimate advantages and update until ``cfg.steps``;
    ``victim_digest``, the victim file's sha256, goes into the provenance (what :func:`trained_for` checks)."""
    torch.set_num_threads(cfg.threads)
    expert = resolve_policy(cfg.expert, cfg.env)
    made_by = stamp("aril train-adversary", cfg)
    victim_provenance, victim = victim.meta.provenance, Answers(victim)  # from here on its answers alone
    sims, resets = SimBatch(cfg.env, cfg.n_envs), EnvSeeds(seeds.adversary_training(cfg.seed))
    net = initial_adversary(cfg, *input_scaling(cfg, sims, victim, expert, resets))
    play = TimingPlay(cfg, net, victim) if timed(cfg) else ValuePlay(cfg, sims, net, victim)
    # foreach: one kernel per step for all the parameters, the same update as the per-tensor loop
    optimizer = torch.optim.Adam(net.parameters(), lr=cfg.lr, eps=1e-5, foreach=True)
    gen = torch.Generator().manual_seed(cfg.seed)
    collector = Collector(cfg, sims, resets, net, play, victim, expert, gen)
    started, steps = time.time(), 0
    out = Path(cfg.out or (f"runs/timing-adversary-{cfg.env}.pt" if timed(cfg) else
                           f"runs/adversary-{cfg.env}-{cfg.mode}.pt"))
    marks = snapshot_steps(cfg)
    for stale in snapshots_of(out):  # another training's, which a screening would take for this one's
        stale.unlink()

    def save(path: Path) -> Path:
        net.meta["provenance"] = {
            **made_by, "victim": cfg.victim, "victim_provenance": victim_provenance,
            **({"victim_sha256": victim_digest} if victim_digest else {}), "expert": cfg.expert,
            "steps": steps, "queries": victim.asked, "train_seconds": round(time.time() - started, 1),
            "seed": cfg.seed, "final_episode_loss": collector.recent_loss()}
        return save_timing_adversary(net, path) if timed(cfg) else save_adversary(net, path)

    while steps < cfg.steps:
        batch = collector.collect()
        advantages, remainder_target = advantages_gae(batch, cfg)
        ppo_update(net, optimizer, batch, advantages, remainder_target, cfg, gen)
        steps += cfg.rollout * cfg.n_envs
        log(collector.progress_line(steps, time.time() - started), flush=True)
        if steps in marks:
            save(snapshot_path(out, steps))
    sims.close()
    out = save(out)
    log(json.dumps({"out": str(out), "steps": steps, "steps_per_s": round(steps / (time.time() - started), 1)}))
    return out


def snapshot_steps(cfg: AdversaryConfig) -> list[int]:
    """The steps after which a training keeps its state (``snapshot_every:=``): the first update at or past each
    multiple of it, but the end, which is ``out:=`` itself."""
    update = cfg.rollout * cfg.n_envs
    end = -(-cfg.steps // update) * update
    marks = range(cfg.snapshot_every, cfg.steps, cfg.snapshot_every) if cfg.snapshot_every else ()
    return sorted({-(-mark // update) * update for mark in marks} - {end})


def snapshot_path(out: Path, steps: int) -> Path:
    """Where a training writing ``out`` keeps its state after ``steps`` steps (``snapshot_every:=``)."""
    return out.with_name(f"{out.stem}-at-{steps}{out.suffix}")


def snapshots_of(out: Path) -> list[Path]:
    """The snapshots a training writing ``out`` kept, first first."""
    return sorted(out.parent.glob(f"{out.stem}-at-*{out.suffix}"), key=lambda path: int(path.stem.rsplit("-", 1)[1]))


def states_of(out: Path) -> list[Path]:
    """Every state a training writing ``out`` left: its snapshots, then its end (``out`` itself)."""
    return [*snapshots_of(out), out]


def trained_for(adversary: Path, eps: float, victim: str = "", env: str = "", mode: str | None = None) -> bool:
    """Whether ``adversary`` exists, was trained for ``eps`` and, given a ``victim`` policy (a bundled name or a
    file), against that very policy. The victim file's sha256 at training time is kept in the adversary, so a
    policy file replaced since (a bundled learner retrained) makes its adversary stale rather than silently
    judging the new learner by an attack on the old one. A live victim (``aril_ros.victims``) cannot be compared."""
    if not adversary.exists():
        return False
    made = load_adversary(adversary)
    return made.eps == eps and made_against(made.meta["provenance"], victim, env, mode)


def timing_trained_for(adversary: Path, budget: dict, victim: str, env: str) -> bool:
    """Whether the timing adversary ``adversary`` exists, was trained for ``budget`` (a TimingBudget's fields) and
    against ``victim`` as it is now (as :func:`trained_for`)."""
    if not adversary.exists():
        return False
    made = load_timing_adversary(adversary)
    return made.budget == budget and made_against(made.meta["provenance"], victim, env, "clean")


def made_against(provenance: dict, victim: str, env: str, mode: str | None) -> bool:
    """Whether an adversary of ``provenance`` was trained against ``victim`` (a bundled name or a file) as it is now:
    the victim file's sha256 at training time is kept; no ``victim`` or a live one: nothing to compare."""
    if not victim or victim in plugins.names("aril_ros.victims"):
        return True
    file = policy_file(victim, env, mode)
    if "victim_sha256" in provenance:
        return provenance["victim_sha256"] == digest_of(file.read_bytes())
    # adversaries made before the digest was kept: the victim's provenance (its command and creation time)
    return provenance.get("victim_provenance") == load_policy(file, env).meta.provenance


def ready_adversary(adversary: Path, victim: str, env: str, mode: str, eps: float, expert: str, steps: int,
                    retrain: bool, log, seed: int = 0, init: str = "", policy: str = "categorical") -> Path:
    """``adversary``, trained (with training seed ``seed``, from the adversary file ``init`` if given, of adversary
    ``policy``) against ``victim`` first when it is missing, of another eps, trained against another policy than
    ``victim`` is now, or ``retrain``."""
    wanted = AdversaryConfig(env=env, mode=mode, eps=eps, victim=victim, expert=expert, steps=steps, seed=seed,
                             init=init, policy=policy, out=str(adversary))
    return ready_adversaries([wanted], retrain, log)[0]


def ready_adversaries(wanted: list[AdversaryConfig], retrain: bool, log, workers: int = 1, address: str = ""
                      ) -> list[Path]:
    """Each ``wanted`` adversary's file (its ``out``), trained first as :func:`ready_adversary` says; those to train
    run as sweep tasks, ``workers`` CPUs of a local Ray or the cluster at ``address`` (one worker: one after the
    other in this process, logging to ``log``). Their victim, expert and init files travel with them, and a task
    records a file by the path it saw: a relative path or a bundled name reads the same on every node, and a file
    inside the checkout is shown to it by its checkout-relative path (:func:`sweep.run_tasks`)."""
    todo = [cfg for cfg in wanted if retrain or not ready(cfg)]
    here = workers == 1 and not address
    calls = [(*_with_files_marked(cfg), log if here else None) for cfg in todo]
    for _ in run_tasks(training_task, calls, workers, address, label="adversary trainings", log=log):
        pass
    return [Path(cfg.out) for cfg in wanted]


def ready(cfg: AdversaryConfig) -> bool:
    """Whether ``cfg``'s adversary file is there, trained as ``cfg`` asks (:func:`trained_for`,
    :func:`timing_trained_for`)."""
    if timed(cfg):
        return timing_trained_for(Path(cfg.out), asdict(timing_budget(cfg)), cfg.victim, cfg.env)
    return trained_for(Path(cfg.out), cfg.eps, cfg.victim, cfg.env, cfg.mode)


def _with_files_marked(cfg: AdversaryConfig) -> tuple[dict, list]:
    """``cfg``'s fields for a task: the files it reads marked to travel with it, the ones it writes (the adversary
    and the states it keeps) to come back."""
    out = Path(cfg.out)
    return ({**asdict(cfg), "victim": shipped(for_task(cfg.victim, cfg.env, cfg.mode)),
             "expert": shipped(for_task(cfg.expert, cfg.env)), "init": shipped(cfg.init), "out": Produced(out)},
            [Produced(snapshot_path(out, steps)) for steps in snapshot_steps(cfg)])


def training_task(settings: dict, states: list, log=None) -> Path:
    """One adversary's training (a sweep task): AdversaryConfig's fields, a file given as a path, and where the
    states it keeps go (their paths, which the training makes beside its ``out``: marked in the call so that they
    come back too); ``log`` only in the calling process (a Ray worker's output is not the driver's)."""
    cfg = AdversaryConfig(**{k: str(v) if isinstance(v, Path) else v for k, v in settings.items()})
    made = train_adversary(cfg, log=log or print)
    kept = snapshots_of(made)
    if [str(path) for path in kept] != [str(path) for path in states]:
        raise RuntimeError(f"{made}: kept the states {[p.name for p in kept]}, not {[Path(p).name for p in states]}")
    return made


def timing_budget(cfg: AdversaryConfig) -> TimingBudget:
    return TimingBudget(cfg.delay, cfg.drop, cfg.action_delay)


def timed(cfg: AdversaryConfig) -> bool:
    """Whether ``cfg`` trains a timing adversary (mode clean, a timing budget) rather than a value one."""
    return cfg.mode == "clean"


def check_config(cfg: AdversaryConfig) -> None:
    if timed(cfg):
        if not timing_budget(cfg).any:
            raise ValueError("mode:=clean trains a timing adversary: give its budget, delay:=, drop:= or "
                             "action_delay:= (a value adversary: mode:=sensory or physical)")
        return
    if cfg.mode not in ATTACKED_MODES:
        raise ValueError(f"mode:= must be sensory or physical (a value adversary) or clean (a timing one), "
                         f"got {cfg.mode!r}")
    if timing_budget(cfg).any:
        raise ValueError(f"a timing budget (delay:=, drop:=, action_delay:=) trains a timing adversary, in "
                         f"mode:=clean; mode:={cfg.mode} trains a value adversary, and one of both is not built")
    if not cfg.eps > 0:
        raise ValueError(f"eps:= must be > 0, got {cfg.eps}")
    check_name("adversary policy", cfg.policy, POLICIES)
    check_name("adversary inputs", cfg.inputs, INPUTS)
    check_name("adversary objective", cfg.objective, OBJECTIVES)
    check_name("adversary terminal", cfg.terminal, TERMINAL)
    if cfg.terminal == "held" and cfg.gamma >= 1.0:
        raise ValueError("terminal:=held values the state an episode ended in as held forever, gamma / (1 - gamma) "
                         f"times its disagreement: it needs gamma:= < 1, got {cfg.gamma}")


class EnvSeeds:
    """The env seeds of the trainer's episodes, handed out one by one from the first."""

    def __init__(self, first: int):
        self.next = first

    def take(self, n: int) -> list[int]:
        taken = list(range(self.next, self.next + n))
        self.next += n
        return taken


def input_scaling(cfg: AdversaryConfig, sims: SimBatch, victim, expert, resets: EnvSeeds
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Mean and std of the adversary's inputs (a timing adversary's: of the observation) on the states the victim
    visits unattacked over ``warmup`` steps: reset states alone have almost no spread, and would blow the normalised
    inputs up once it runs."""
    rows = range(len(sims))
    obs = sims.reset(resets.take(len(sims)))
    visited = []
    for _ in range(cfg.warmup + 1):
        action = victim.act(obs)
        visited.append(obs.copy() if timed(cfg) else input_rows(cfg.inputs, obs.copy(), action, expert.act(obs)))
        obs = sims.step(action, rows)[0]
    visited = np.concatenate(visited)
    return visited.mean(0), visited.std(0) + 1e-3


def initial_adversary(cfg: AdversaryConfig, obs_mean: np.ndarray, obs_std: np.ndarray) -> AdversaryNet | TimingNet:
    """Fresh seeded weights, or (``init:=``) the previous round's adversary with its input scaling."""
    if timed(cfg):
        return initial_timing_adversary(cfg, obs_mean, obs_std)
    if cfg.init:
        net = load_adversary(cfg.init, cfg.env, cfg.mode).train()
        have = (net.eps, net.meta["hidden"], net.meta["policy"], net.meta["inputs"])
        if have != (cfg.eps, cfg.hidden, cfg.policy, cfg.inputs):
            raise ValueError(f"init:={cfg.init} has eps {have[0]}, width {have[1]}, policy {have[2]} and inputs "
                             f"{have[3]}, not eps:={cfg.eps} hidden:={cfg.hidden} policy:={cfg.policy} "
                             f"inputs:={cfg.inputs}")
        return net
    layout = layout_of(cfg.env)
    meta = {"env_id": cfg.env, "mode": cfg.mode, "eps": cfg.eps, "obs_dim": layout.obs_dim, "act_dim": layout.act_dim,
            "n_position": layout.n_position, "policy": cfg.policy, "inputs": cfg.inputs, "hidden": cfg.hidden,
            "obs_mean": obs_mean.tolist(), "obs_std": obs_std.tolist(), "provenance": {}}
    with torch.random.fork_rng():  # seeded initial weights without touching the global generator
        torch.manual_seed(cfg.seed)
        return AdversaryNet(meta)


def initial_timing_adversary(cfg: AdversaryConfig, obs_mean: np.ndarray, obs_std: np.ndarray) -> TimingNet:
    """A timing adversary's fresh seeded weights, or (``init:=``) a timing adversary of the same budget."""
    if cfg.init:
        net = load_timing_adversary(cfg.init, asdict(timing_budget(cfg)), cfg.env).train()
        if net.meta["hidden"] != cfg.hidden:
            raise ValueError(f"init:={cfg.init} has width {net.meta['hidden']}, not hidden:={cfg.hidden}")
        return net
    layout = layout_of(cfg.env)
    meta = {"env_id": cfg.env, "mode": "clean", "budget": asdict(timing_budget(cfg)), "obs_dim": layout.obs_dim,
            "act_dim": layout.act_dim, "hidden": cfg.hidden, "obs_mean": obs_mean.tolist(),
            "obs_std": obs_std.tolist(), "provenance": {}}
    with torch.random.fork_rng():
        torch.manual_seed(cfg.seed)
        return TimingNet(meta)


class ValuePlay:
    """How a value adversary's sample acts on a step: the perturbation it stands for, by the mode's rule."""

    def __init__(self, cfg: AdversaryConfig, sims: SimBatch, net: AdversaryNet, victim):
        self.mode, self.sims, self.net, self.victim = cfg.mode, sims, net, victim

    def inputs(self, obs: np.ndarray, clean, label, rows) -> np.ndarray:
        return self.net.inputs(obs, clean, label)

    def act(self, sample: torch.Tensor, obs: np.ndarray, rows) -> np.ndarray:
        """The action applied: the victim's on what the perturbation made it see."""
        n_pos, delta = self.net.n_position, np.zeros_like(obs)
        if self.net.directed:
            delta[:, :n_pos] = pushes(self.victim.act, obs, sample.double().numpy()[:, None], self.net.eps, n_pos)[:, 0]
        else:
            delta[:, :n_pos] = self.net.delta(sample).double().numpy()
        return self.victim.act(self.sims.seen(self.mode, obs, delta, rows))

    def restart(self, row: int) -> None:
        pass


class TimingPlay:
    """How a timing adversary's sample acts on a step: the ages and the drop it asks for, within the budget's rules
    (:class:`~aril_ros.timing.Timeline`, one step per simulator: each begins its next episode where one ends)."""

    def __init__(self, cfg: AdversaryConfig, net: TimingNet, victim):
        layout = layout_of(cfg.env)
        self.net, self.victim = net, victim
        self.timeline = Timeline(timing_budget(cfg), None, cfg.n_envs, layout.obs_dim, layout.act_dim, [])
        self.t = np.zeros(cfg.n_envs, dtype=np.int64)

    def inputs(self, obs: np.ndarray, clean, label, rows) -> np.ndarray:
        rows = np.asarray(rows)
        return self.net.inputs(obs, self.timeline.may_drop_now(self.t[rows], rows))

    def act(self, sample: torch.Tensor, obs: np.ndarray, rows) -> np.ndarray:
        """The action applied: the victim's on the observation delivered, as late as asked, applied as late."""
        rows, asked = np.asarray(rows), sample.long().numpy()
        choice = TimingChoice(asked[:, 0], asked[:, 1].astype(bool), asked[:, 2])
        seen = self.timeline.deliver(self.t[rows], obs, rows, choice)[0]
        applied = self.timeline.apply(self.t[rows], self.victim.act(seen), rows)[0]
        self.t[rows] += 1
        return applied

    def restart(self, row: int) -> None:
        self.t[row] = 0
        self.timeline.restart([row])


@dataclass
class Rollout:
    """``T`` steps of ``n`` simulators, as PPO needs them (rewards and values in units of the return's spread)."""

    obs: torch.Tensor
    """the adversary's input rows"""
    sample: torch.Tensor
    logp: torch.Tensor
    reward: torch.Tensor
    value: torch.Tensor
    """the full value: learned remainder + ``base``"""
    base: torch.Tensor
    """the exact part of the value: the victim's unperturbed disagreement"""
    done: torch.Tensor
    next_value: torch.Tensor
    """the value of the states the rollout stopped in"""


class Collector:
    """Runs the adversary against the victim on the simulators, step by step, resetting finished episodes."""

    def __init__(self, cfg: AdversaryConfig, sims: SimBatch, resets: EnvSeeds, net: AdversaryNet | TimingNet,
                 play: ValuePlay | TimingPlay, victim, expert, gen: torch.Generator):
        self.cfg, self.sims, self.resets, self.net, self.play = cfg, sims, resets, net, play
        self.victim, self.expert, self.gen = victim, expert, gen
        self.obs = sims.reset(resets.take(len(sims)))
        n = len(sims)
        self.episode_loss, self.episode_return, self.discounted = np.zeros(n), np.zeros(n), np.zeros(n)
        self.return_scale = RunningStd()
        self.finished_loss: list[float] = []
        self.finished_return: list[float] = []
        self.entropy = float("nan")

    def answers(self, states: np.ndarray) -> tuple[np.ndarray | None, np.ndarray]:
        """The victim's action on ``states`` unperturbed (when the critic or the inputs need it) and the
        expert's: one query of each per state."""
        needed = self.cfg.baseline or self.net.takes_actions
        return (self.victim.act(states) if needed else None), self.expert.act(states)

    def unperturbed_loss(self, clean: np.ndarray | None, label: np.ndarray) -> np.ndarray:
        """The disagreement the victim would have without the attack: the exact part of the value."""
        exact = self.cfg.baseline and self.cfg.objective == "disagreement"
        return disagreement(clean, label) if exact else np.zeros(len(label))

    def collect(self) -> Rollout:
        cfg, n, T = self.cfg, len(self.sims), self.cfg.rollout
        rows = range(n)
        buf = Rollout(obs=torch.zeros(T, n, self.net.input_width),
                      sample=torch.zeros(T, n, self.net.sample_width), logp=torch.zeros(T, n), reward=torch.zeros(T, n),
                      value=torch.zeros(T, n), base=torch.zeros(T, n), done=torch.zeros(T, n),
                      next_value=torch.zeros(n))
        for t in range(T):
            # the adversary perturbs (or times), the victim acts, the expert labels the true state
            clean, label = self.answers(self.obs)
            x = torch.as_tensor(self.play.inputs(self.obs, clean, label, rows), dtype=torch.float32)
            with torch.no_grad():
                # the entropy for the progress line only: once a rollout, not every step
                sample, buf.logp[t], entropy = self.net.sample(x, self.gen, entropy=t == T - 1)
                remainder = self.net.value(x)
            self.entropy = self.entropy if entropy is None else entropy
            action = self.play.act(sample, self.obs, rows)
            loss = disagreement(action, label)
            # the perturbation moves the disagreement by little next to how much it varies from state to
            # state, more than a learned value can follow: the unperturbed disagreement, known exactly for
            # every visited state, carries that part of the value
            base = self.unperturbed_loss(clean, label)
            buf.obs[t], buf.sample[t] = x, sample
            self.obs, env_reward, terminated, truncated = self.sims.step(action, rows)
            gain = loss if cfg.objective == "disagreement" else -env_reward
            self.discounted = self.discounted * cfg.gamma + gain
            self.return_scale.update(self.discounted)
            # in units of the return's spread, so the value loss and the clip ranges keep their meaning
            # whether a step's disagreement is 0.001 or 10
            scale = self.return_scale.std if cfg.norm_reward else 1.0
            reward = torch.as_tensor(gain / scale, dtype=torch.float32)
            buf.base[t] = torch.as_tensor(base / scale, dtype=torch.float32)
            buf.value[t] = remainder + buf.base[t]
            self.episode_loss += loss
            self.episode_return += env_reward
            stopped = np.flatnonzero(truncated & ~terminated)  # time limit: bootstrap from the state it stopped in
            if stopped.size:  # all at once: every simulator reaches the horizon at the same step
                reward[torch.as_tensor(stopped)] += cfg.gamma * self.value_of(self.obs[stopped], scale, stopped)
            ended = np.flatnonzero(terminated)
            if ended.size and cfg.terminal != "nothing":
                reward[torch.as_tensor(ended)] += self.after_end(self.obs[ended], scale, ended)
            for i in np.flatnonzero(terminated | truncated):
                self.discounted[i] = 0.0
                self.finished_loss.append(self.episode_loss[i])
                self.finished_return.append(self.episode_return[i])
                self.episode_loss[i] = self.episode_return[i] = 0.0
                self.obs[i] = self.sims.reset(self.resets.take(1), rows=[i])[0]
                self.play.restart(i)
            buf.done[t] = torch.as_tensor(terminated | truncated, dtype=torch.float32)
            buf.reward[t] = reward
        buf.next_value = self.value_of(self.obs, scale, rows)
        return buf

    def value_of(self, states: np.ndarray, scale: float, rows) -> torch.Tensor:
        """The full value of ``states`` (the simulators ``rows``'): the learned remainder plus their unperturbed
        disagreement."""
        clean, label = self.answers(states)
        with torch.no_grad():
            remainder = self.net.value(torch.as_tensor(self.play.inputs(states, clean, label, rows),
                                                       dtype=torch.float32))
        return remainder + torch.as_tensor(self.unperturbed_loss(clean, label) / scale, dtype=torch.float32)

    def after_end(self, states: np.ndarray, scale: float, rows) -> torch.Tensor:
        """What ``terminal`` makes the rest of an episode ended early in ``states`` worth (see its help)."""
        if self.cfg.terminal == "bootstrap":
            return self.cfg.gamma * self.value_of(states, scale, rows)
        clean, label = self.victim.act(states), self.expert.act(states)
        held = self.cfg.gamma / (1.0 - self.cfg.gamma)
        return torch.as_tensor(held * disagreement(clean, label) / scale, dtype=torch.float32)

    def recent_loss(self) -> float | None:
        recent = self.finished_loss[-4 * len(self.sims):]
        return float(np.mean(recent)) if recent else None

    def progress_line(self, steps: int, seconds: float) -> str:
        recent = self.finished_return[-4 * len(self.sims):]
        loss = self.recent_loss()
        what = timing_budget(self.cfg).described() if timed(self.cfg) else f"{self.cfg.mode} eps={self.cfg.eps}"
        return (f"[train-adversary {self.cfg.env} {what}] step {steps:>8d}  "
                f"{steps / seconds:6.0f} steps/s  episode loss {float('nan') if loss is None else loss:9.1f}  "
                f"victim return {np.mean(recent) if recent else float('nan'):8.1f}  "
                f"entropy/{'choice' if timed(self.cfg) else 'entry'} {self.entropy:.3f}")


def advantages_gae(batch: Rollout, cfg: AdversaryConfig) -> tuple[torch.Tensor, torch.Tensor]:
    """Generalised advantage estimation; the value target of the learned remainder."""
    T = len(batch.reward)
    advantages = torch.zeros_like(batch.reward)
    last = torch.zeros(batch.reward.shape[1])
    for t in reversed(range(T)):
        not_done = 1.0 - batch.done[t]
        value_after = batch.next_value if t == T - 1 else batch.value[t + 1]
        td = batch.reward[t] + cfg.gamma * value_after * not_done - batch.value[t]
        last = td + cfg.gamma * cfg.gae_lambda * not_done * last
        advantages[t] = last
    return advantages, advantages + batch.value - batch.base


def ppo_update(net: AdversaryNet, optimizer, batch: Rollout, advantages: torch.Tensor, remainder_target: torch.Tensor,
               cfg: AdversaryConfig, gen: torch.Generator) -> None:
    """``epochs`` passes of clipped PPO over the rollout's samples in minibatches."""
    size = batch.reward.numel()
    flat = lambda x: x.reshape(size, *x.shape[2:])  # noqa: E731
    b_obs, b_sample, b_logp = flat(batch.obs), flat(batch.sample), flat(batch.logp)
    b_adv, b_ret = flat(advantages), flat(remainder_target)
    # clipped apart: the value loss (in units of summed disagreement) would otherwise dominate the joint norm and
    # shrink every policy step along with it
    policy_params = [p for name, p in net.named_parameters() if not name.startswith("value_net")]
    value_params = list(net.value_net.parameters())
    for _ in range(cfg.epochs):
        for idx in torch.randperm(size, generator=gen).split(cfg.minibatch):
            log_prob, entropy = net.log_prob_and_entropy(b_obs[idx], b_sample[idx])
            ratio = (log_prob - b_logp[idx]).exp()
            mb_adv = b_adv[idx]
            adv = (mb_adv - mb_adv.mean()) / (mb_adv.std() + 1e-8)
            policy_loss = -torch.min(ratio * adv, ratio.clamp(1 - cfg.clip, 1 + cfg.clip) * adv).mean()
            value_loss = ((net.value(b_obs[idx]) - b_ret[idx]) ** 2).mean()
            entropy = entropy.mean()
            loss = policy_loss + cfg.vf_coef * value_loss - cfg.ent_coef * entropy
            optimizer.zero_grad()
            loss.backward()
            nn.utils.clip_grad_norm_(policy_params, cfg.max_grad_norm)
            nn.utils.clip_grad_norm_(value_params, cfg.max_grad_norm)
            optimizer.step()
