"""The black-box pipeline: the attacks a scorecard runs on a policy it may only ask for actions.

For one attacked mode, in five named steps (files in the scorecard's folder, which a rerun reuses):

1. **copy** the policy: a surrogate fitted to its answers (:mod:`aril_ros.surrogate`), ``surrogate-<mode>.pt``;
   FGSM^k on it is the ``transfer`` attack;
2. **screen the zoo**: every bundled ARIL-A of the env and mode (trained against DAgger, BC, DART, DR, GAIL and
   ARIL learners, three seeds each), *except any trained against this very policy* (leave-one-out, by the SHA-256
   of the policy file it was trained against), run against the surrogate on :data:`aril_ros.seeds.SCREENING`
   episodes; the one that takes the most return is the ``zoo`` attack;
3. **train** ARIL-A against the policy itself, from the zoo's best (a warm start): PPO that asks the policy for its
   action on the true state (an input of the adversary) and on the perturbed one, two questions a step, and nothing
   else: ``adversary-<mode>.pt``, which keeps a state every :data:`SNAPSHOT_EVERY` steps
   (``adversary-<mode>-at-<steps>.pt``); the one of them that takes the most return from the policy on the scored
   episodes is the ``aril_a`` attack (:func:`keep_strongest`). An external node answers the 16 simulators' rows of a
   question in one message (probe batches): the training ran at about half the engine's speed (3,994 against 7,549
   steps/s, HalfCheetah physical), where one probe a message had kept it at ~650;
4. **search** at run time: that adversary proposes, the policy is asked on :data:`SEARCH` candidates a step and
   the most damaging is applied (``aril_a_search``);
5. **direct** (:func:`directed_pipeline`, beside the others and needing none of their files): a directed ARIL-A
   (PA-AD's director, a direction in the policy's action space, and an actor that asks the policy for its action's
   slope along each perturbed entry, two questions an entry, and takes the corner of the box that moves the action
   furthest along it) trained against the policy itself, from the bundled directed ARIL-A that took the most return
   from the policy on screening episodes (none trained against this very policy): ``directed-<mode>.pt``, whose
   state that takes the most return from the policy on the scored episodes (as in step 3) is the ``aril_a_directed``
   attack.

The policy is asked for actions only: in step 1 (the surrogate's questions), steps 3 and 5 (the trainings', which
the adversary files count, and their states' screenings, which the records count), by the adversaries that take its
action as an input (one question a step), by the search and by the directed actor; never for its weights. For an
external node every question is a message to the node and back.
"""
from __future__ import annotations

import json
import os
from collections.abc import Callable
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import plugins, seeds
from .args import arg
from .adversary import AdversaryConfig, ready_adversaries, states_of
from .adversary_net import load_adversary
from .attacks import LearnedAttack
from .envs import HORIZON, layout_of
from .policy import Answers, load_policy, policy_file, resolve_policy
from .protocol import ros_domain
from .provenance import portable
from .registry import (ATTACKED_MODES, DATA_DIR, DEFAULT_ENV, DEFENSES, MAX_EPS, bundled_file, calibrated_eps, check_name,
                       for_task)
from .rollout import RolloutEngine
from .surrogate import SurrogateConfig, fit_answers, fit_surrogate, gather, summary
from .sweep import Produced, Shipped, digest_of, run_tasks, shipped

SEARCH = 8
"""Candidates a step of ``aril_a_search`` asks the policy about (and the adversary's own choice): on HalfCheetah
DAgger sensory 8 took 49% of the return where none took 39% (results/aril_a_tuning.md, issue 38)."""
PIPELINE = 6
"""The pipeline's version in its record: files a pipeline of another version made are made again (2: the zoo's best
may take the trained ARIL-A's place; 3: the surrogate fitted to the policy's variation inside the box too; 4: ARIL-A
trained against the policy itself, the surrogate fitted once; 5: the strongest of ARIL-A's states kept, on screening
episodes; 6: on the scored episodes)."""
SCREEN_EPISODES = 10
"""Episodes per zoo member in the screening (against the surrogate, so they cost no question to the policy): with 3,
HalfCheetah DAgger's screening picked a member that took 17% of its return where the one 10 pick took 39%
(results/aril_a_tuning.md)."""
ZOO_FOLDERS = (DATA_DIR / "adversary", DATA_DIR / "defense-adversary")
DIRECTED_ZOO = (DATA_DIR / "directed-adversary",)
"""The directed step's warm starts: the bundled directed ARIL-As, one against each of DAgger, BC, DR and ARIL. Screened
against the policy itself (a director's direction is in the policy's action space, which a copy's errors would
bend): on HalfCheetah DR and ARIL sensory, DAgger's directed ARIL-A trained 500k steps more against the learner took
-34.4% and -11.3% where 500k from fresh weights took -30.9% and -7.3% (results/aril_a_tuning.md, issue 38)."""
DIRECTED = 3
"""The directed step's version in its record (``directed-<mode>.json``): a file another version made is made again
(2: the strongest of the training's states kept, on screening episodes; 3: on the scored episodes)."""
SNAPSHOT_EVERY = 250_000
"""Steps between the states a pipeline training keeps before its end (the quick budget's 500k steps: one and the
end; the full budget's 2M: seven and the end): the row uses whichever of them took the most return from the policy on
the scored episodes (:func:`keep_strongest`). An adversary's objective, the policy's disagreement with the expert, is
not the return it takes: on Ant DAgger sensory the directed ARIL-A took -55.1% of the return after 254k of its 2M
steps, -42.2% at 504k (the quick budget's end) and -41.1% at its end (on env seeds 6600..6649; results/aril_a_tuning.md,
issue 38)."""


@dataclass(frozen=True)
class Trained:
    """A pipeline training against the policy, and the state of it that its row uses."""

    end: Path
    """the training's last state, whose provenance counts every step and question of the training"""
    kept: Path
    """the state (one kept every :data:`SNAPSHOT_EVERY` steps, or the end) that took the most return from the policy on
    the scored episodes"""
    screened: list[tuple[float, str]] = ()
    """every state's mean return against the policy, best first"""
    queries: int = 0
    """the questions the screening of the states put to the policy"""
    returns: dict[str, list[float]] = field(default_factory=dict)
    """every state's return in each scored episode, by file name: the row's figure is the best of them, so a verdict's
    interval resamples them all (:func:`aril_ros.benchmarks.verdict.ratio_interval`)"""
    scored_on: tuple[int, int] = (0, 0)
    """the env seed of the first scored episode and their count: the episodes the states were judged on"""


@dataclass(frozen=True)
class DirectedAttack:
    """What step 5 made for one mode: the directed ARIL-A and where it started."""

    trained: Trained
    zoo: Path | None = None
    """the bundled directed ARIL-A it was trained from (None: fresh weights)"""
    screened: list[tuple[float, str]] = ()
    """every directed zoo member's mean return against the policy, best first"""
    queries: int = 0
    """the questions the directed zoo's screening put to the policy"""


@dataclass(frozen=True)
class BlackBoxAttacks:
    """What the pipeline made for one mode: the surrogate (transfer), the zoo's best, the trained adversary and the
    directed one; None for what the scored rows did not need."""

    surrogate: Path | None = None
    zoo: Path | None = None
    """None also where the env has no bundled adversary (a new robot): no zoo row, ARIL-A from fresh weights"""
    adversary: Trained | None = None
    screened: list[tuple[float, str]] = ()
    """every zoo member's mean return against the surrogate, best first"""
    directed: DirectedAttack | None = None


@dataclass(frozen=True)
class Offline:
    """Work a pipeline asks for that puts no question to the policy (a surrogate's fit, the zoo's screening):
    ``fn(*call)`` as a sweep task (files in ``call`` marked as :func:`aril_ros.sweep.run_tasks` reads them); the
    pipeline is sent its result."""

    label: str
    fn: Callable
    call: tuple


def run_pipelines(pipelines: list, log=print, workers: int = 1, address: str = ""
                  ) -> list[BlackBoxAttacks | DirectedAttack]:
    """What each pipeline makes (a :func:`pipeline`'s :class:`BlackBoxAttacks`, a :func:`directed_pipeline`'s
    :class:`DirectedAttack`), the pipelines side by side: each runs until it asks for a job (an
    :class:`Offline` one, which puts no question to the policy, or an adversary's training, which asks it on its own
    connection), and the jobs all asked for run at once as sweep tasks (``workers`` CPUs of a local Ray, or the
    cluster at ``address``); the surrogates' questions stay one pipeline at a time. Two modes fit, screen and train on
    two CPUs in the time of one."""
    made: list[BlackBoxAttacks | DirectedAttack | None] = [None] * len(pipelines)
    asked: dict[int, AdversaryConfig | Offline] = {}

    def advance(index: int, answer=None) -> None:
        try:
            asked[index] = pipelines[index].send(answer)
        except StopIteration as done:
            made[index] = done.value
            asked.pop(index, None)

    for index in range(len(pipelines)):
        advance(index)
    while asked:
        jobs = {index: job for index, job in asked.items() if isinstance(job, Offline)}
        if jobs:
            label = " and ".join(dict.fromkeys(job.label for job in jobs.values()))
            order = list(jobs)
            for done, result in run_tasks(_offline, [(job.fn, job.call) for job in jobs.values()], workers, address,
                                          label=label, log=log):
                advance(order[done], result)
        else:
            ready_adversaries(list(asked.values()), True, log, workers, address)
            for index in list(asked):
                advance(index)
    return made


def _offline(fn: Callable, call: tuple):
    """An :class:`Offline` job, run where its sweep task runs."""
    return fn(*call)


def pipeline(victim_name: str, env_id: str, mode: str, eps: float, expert: str, steps: int, folder: Path,
             scored_on: tuple[int, int], domain: str = "", log=print, horizon: int = HORIZON, leave_out: str = ""):
    """The pipeline for the policy ``victim_name`` (a file, a bundled name, or ``ros``: an external node in
    ``domain``) in ``mode`` at ``eps``, on episodes of ``horizon`` steps (the scored ones'); ARIL-A trained ``steps``
    steps against it, its states judged on the scored episodes, ``scored_on`` (the first one's env seed, their count);
    the zoo leaves out the adversaries trained against ``victim_name``'s file, or for an external
    node against ``leave_out``'s (the file it serves, when it is one of ours: the verdict of a policy the testbed has
    never seen). Its record, ``pipeline-<mode>.json``, lets a rerun for the same policy, eps, horizon and steps find
    the files and make nothing (but judge the states again, on other scored episodes).

    A generator (run it with :func:`run_pipelines`): it yields each ARIL-A training it needs as an
    :class:`AdversaryConfig`, and each fit and screening as an :class:`Offline` job, and goes on once that is done
    (sent the job's result); it returns the :class:`BlackBoxAttacks`. The policy is connected while it is asked for
    the surrogate's answers, and by the training, which connects to it on its own."""
    surrogate, adversary = folder / f"surrogate-{mode}.pt", folder / f"adversary-{mode}.pt"
    record = folder / f"pipeline-{mode}.json"
    wanted = {"pipeline": PIPELINE, "victim": victim_name, "mode": mode, "eps": eps, "horizon": horizon,
              "adversary_steps": steps, "leave_out": leave_out}
    made = made_before(record, wanted)
    if made:
        log(f"[verdict] {mode}: reusing {surrogate} and {adversary}")
        trained = kept_on(adversary, made, record, victim_name, env_id, mode, eps, expert, domain, horizon, scored_on,
                          log)
        return BlackBoxAttacks(surrogate, made["zoo"] and Path(made["zoo"]), trained,
                               [tuple(s) for s in made["zoo_screened"]])
    cfg = SurrogateConfig()
    expert_file = shipped(for_task(expert, env_id))
    with answering(victim_name, env_id, mode, domain) as victim:
        questions, answers = gather(victim, env_id, mode, eps, cfg, horizon)
        queries = victim.asked
    yield from fitting(questions, answers, env_id, {**wanted, "queries": queries}, surrogate, log)
    left_out = victim_digest(leave_out or victim_name, env_id, mode)
    members = zoo_members(env_id, mode, left_out, ZOO_FOLDERS)
    returns = yield Offline("zoo screenings", screen_zoo, ([Shipped(member) for member in members], Shipped(surrogate),
                                                           env_id, mode, eps, expert_file, horizon))
    screened = sorted(zip(returns, map(relative, members)))
    zoo = Path(screened[0][1]) if screened else None
    log(f"[verdict] {mode}: " + (f"the zoo's strongest against the surrogate is {relative(zoo)} "
                                 f"({len(screened)} screened, mean return {screened[0][0]:.1f})" if zoo else
                                 f"no bundled adversary of {env_id} {mode} for the zoo: ARIL-A from fresh weights"))
    start = zoo if zoo and load_adversary(zoo).eps == eps else None
    # against the policy itself, through its answers: an adversary trained against the surrogate learns the copy's
    # errors too (HalfCheetah DR physical, 500k steps: -76.9% against -98.6% trained against the policy, issue 38)
    yield AdversaryConfig(env=env_id, mode=mode, eps=eps, victim=victim_name, domain=domain if victim_name == "ros"
                          else "", expert=expert, steps=steps, snapshot_every=SNAPSHOT_EVERY,
                          init=str(start) if start else "", out=str(adversary))
    trained = keep_strongest(adversary, victim_name, env_id, mode, eps, expert, domain, horizon, scored_on, log)
    record.write_text(json.dumps({**wanted, "zoo": zoo and relative(zoo), "zoo_screened": screened,
                                  **kept_record(trained), "files": files_record(surrogate, trained)}, indent=1) + "\n")
    return BlackBoxAttacks(surrogate, zoo, trained, screened)


def directed_pipeline(victim_name: str, env_id: str, mode: str, eps: float, expert: str, steps: int, folder: Path,
                      scored_on: tuple[int, int], domain: str = "", log=print, horizon: int = HORIZON,
                      leave_out: str = ""):
    """Step 5 for the policy ``victim_name`` (as :func:`pipeline` takes it, ``leave_out`` and ``scored_on`` too) in
    ``mode`` at ``eps``: the bundled directed ARIL-As screened against the policy itself on :data:`SCREEN_EPISODES`
    screening episodes of ``horizon`` steps (but any trained against it), and a directed ARIL-A trained ``steps`` steps
    against it from the one that took the most return, ``directed-<mode>.pt``. Its record, ``directed-<mode>.json``,
    lets a rerun for the same policy, eps, horizon and steps make nothing (but judge the states again, on other scored
    episodes). A generator like :func:`pipeline` (run them
    together with :func:`run_pipelines`): it yields the training, returns the :class:`DirectedAttack`."""
    out, record = folder / f"directed-{mode}.pt", folder / f"directed-{mode}.json"
    wanted = {"directed": DIRECTED, "victim": victim_name, "mode": mode, "eps": eps, "horizon": horizon,
              "adversary_steps": steps, "leave_out": leave_out}
    made = made_before(record, wanted)
    if made:
        log(f"[verdict] {mode}: reusing {out}")
        trained = kept_on(out, made, record, victim_name, env_id, mode, eps, expert, domain, horizon, scored_on, log)
        return DirectedAttack(trained, made["zoo"] and Path(made["zoo"]), [tuple(s) for s in made["zoo_screened"]],
                              made["queries"])
    members = zoo_members(env_id, mode, victim_digest(leave_out or victim_name, env_id, mode), DIRECTED_ZOO)
    returns, queries = (screen_against_policy(members, victim_name, env_id, mode, eps, expert, domain, horizon)
                        if members else ([], 0))
    screened = sorted(zip(returns, map(relative, members)))
    zoo = Path(screened[0][1]) if screened else None
    start = zoo if zoo and load_adversary(zoo).eps == eps else None
    log(f"[verdict] {mode}: " + (f"the strongest directed ARIL-A against the policy is {relative(zoo)} "
                                 f"({len(screened)} screened, mean return {screened[0][0]:.1f}, {queries:,} questions)"
                                 if zoo else f"no bundled directed ARIL-A of {env_id} {mode}: from fresh weights"))
    yield AdversaryConfig(env=env_id, mode=mode, eps=eps, victim=victim_name, domain=domain if victim_name == "ros"
                          else "", expert=expert, steps=steps, policy="directed", snapshot_every=SNAPSHOT_EVERY,
                          init=str(start) if start else "", out=str(out))
    trained = keep_strongest(out, victim_name, env_id, mode, eps, expert, domain, horizon, scored_on, log)
    record.write_text(json.dumps({**wanted, "zoo": zoo and relative(zoo), "zoo_screened": screened, "queries": queries,
                                  **kept_record(trained), "files": files_record(trained)}, indent=1) + "\n")
    return DirectedAttack(trained, zoo, screened, queries)


def keep_strongest(end: Path, victim_name: str, env_id: str, mode: str, eps: float, expert: str, domain: str,
                   horizon: int, scored_on: tuple[int, int], log=print) -> Trained:
    """The states of the training that wrote ``end`` (its snapshots and its end) run against the policy itself on
    the scored episodes, ``scored_on`` (the first one's env seed, their count): the one that took the most return is
    the row's. Judged by return, which the scorecard reports, where the training maximised the policy's disagreement
    with the expert; on the scored episodes, as the verdict judges its rows, because screening episodes could not
    choose: on Ant ARIL physical, after 100 screening episodes the quick ARIL-A's two states were -95 +- 312 of return
    apart, and on 100 fresh episodes one took -76.7% and the other -68.5% (results/aril_a_tuning.md, issue 38)."""
    states = states_of(end)
    with answering(victim_name, env_id, mode, domain) as victim:
        episodes = episode_returns(states, Stepped(victim.act), env_id, mode, eps, resolve_policy(expert, env_id),
                                   horizon, scored_on[1], scored_on[0])
        queries = victim.asked
    returns = [round(float(np.mean(r)), 3) for r in episodes]
    screened = sorted(zip(returns, map(relative, states)))
    kept = states[returns.index(screened[0][0])]
    log(f"[verdict] {mode}: of {end.name}'s {len(states)} states, {kept.name} took the most return from the policy "
        f"on the {scored_on[1]} scored episodes (mean return {screened[0][0]:.1f}, {queries:,} questions)")
    return Trained(end, kept, screened, queries, {state.name: [round(float(x), 3) for x in r]
                                                  for state, r in zip(states, episodes)}, tuple(scored_on))


def kept_on(end: Path, made: dict, record: Path, victim_name: str, env_id: str, mode: str, eps: float, expert: str,
            domain: str, horizon: int, scored_on: tuple[int, int], log=print) -> Trained:
    """The :class:`Trained` a pipeline's record ``made`` names for the training that wrote ``end``, its states judged
    again (:func:`keep_strongest`, the record rewritten) where they were judged on other episodes than
    ``scored_on``."""
    trained = kept_before(end, made)
    if trained.scored_on == tuple(scored_on):
        return trained
    trained = keep_strongest(end, victim_name, env_id, mode, eps, expert, domain, horizon, scored_on, log)
    record.write_text(json.dumps({**made, **kept_record(trained)}, indent=1) + "\n")
    return trained


def screen_against_policy(members: list[Path], victim_name: str, env_id: str, mode: str, eps: float, expert: str,
                          domain: str, horizon: int) -> tuple[list[float], int]:
    """:func:`screen_members` against the policy ``victim_name`` itself, connected for it (its answers alone), and
    the questions that put to it."""
    with answering(victim_name, env_id, mode, domain) as victim:
        returns = screen_members(members, Stepped(victim.act), env_id, mode, eps, resolve_policy(expert, env_id),
                                 horizon)
        return returns, victim.asked


def kept_record(trained: Trained) -> dict:
    """What a pipeline's record keeps of a training's states."""
    return {"kept": trained.kept.name, "states_screened": trained.screened, "states_queries": trained.queries,
            "states_returns": trained.returns, "states_scored_on": list(trained.scored_on)}


def kept_before(end: Path, made: dict) -> Trained:
    """The :class:`Trained` a pipeline's record ``made`` names for the training that wrote ``end``."""
    return Trained(end, end.parent / made["kept"], [tuple(s) for s in made["states_screened"]], made["states_queries"],
                   made["states_returns"], tuple(made["states_scored_on"]))


def files_record(*made: Path | Trained) -> dict:
    """The digests of a pipeline's files (a training's: every state), by name, which a rerun checks."""
    paths = [path for item in made for path in (states_of(item.end) if isinstance(item, Trained) else [item])]
    return {path.name: digest_of(path.read_bytes()) for path in paths}


@dataclass(frozen=True)
class Stepped:
    """A black box as the engine steps it: its answers alone. The engine checks a policy's env before it runs; a
    black box says nothing of its env but its answers, which the engine's steps take as they come."""

    act: Callable

    def check_env(self, env_id: str, obs_dim: int, act_dim: int) -> None:
        pass


def fitting(questions: np.ndarray, answers: np.ndarray, env_id: str, made: dict, out: Path, log=print):
    """Step 1's fit, as an :class:`Offline` job (a generator's part: ``yield from`` it): the surrogate fitted to the
    grouped answers at ``out``, reported in ``log`` once made."""
    path = yield Offline("surrogate fits", fit_answers, (questions, answers, env_id, SurrogateConfig(), made,
                                                         Produced(out), None))
    log(summary(path, load_policy(path, env_id).meta.provenance))


def made_before(record: Path, wanted: dict) -> dict | None:
    """The pipeline's record when it was made for ``wanted`` (the policy, mode, eps, horizon and steps) and
    the files it names are still those it made; else None."""
    if not record.exists():
        return None
    made = json.loads(record.read_text())
    if any(made.get(key) != value for key, value in wanted.items()):
        return None
    files = {name: record.parent / name for name in made["files"]}
    if not all(path.exists() and digest_of(path.read_bytes()) == made["files"][name] for name, path in files.items()):
        return None
    return made


@contextmanager
def answering(victim_name: str, env_id: str, mode: str, domain: str):
    """The policy as a black box (:class:`Answers`): a file's or bundled name's actions, or an external node's through
    ROS in ``domain``, connected for the pipeline and closed after."""
    if victim_name != "ros":
        yield Answers(resolve_policy(victim_name, env_id, mode))
        return
    with ros_domain(domain):
        remote = plugins.load("aril_ros.victims", "ros")(env_id)
        try:
            yield Answers(remote)
        finally:
            remote.close()


def victim_digest(victim_name: str, env_id: str, mode: str) -> str | None:
    """The SHA-256 of the policy file behind ``victim_name`` (None for an external node: no file to compare)."""
    if victim_name == "ros":
        return None
    return digest_of(policy_file(victim_name, env_id, mode).read_bytes())


def zoo_members(env_id: str, mode: str, exclude_sha256: str | None, folders: tuple[Path, ...]) -> list[Path]:
    """The bundled adversaries in ``folders`` (the zoo's, or the directed step's) of ``env_id`` and ``mode`` but any
    trained against the policy file of digest ``exclude_sha256`` (leave-one-out)."""
    members = []
    for folder in folders:
        for path in sorted(folder.glob(f"{env_id}-{mode}*.pt")):
            if exclude_sha256 is None or trained_against(path, env_id, mode) != exclude_sha256:
                members.append(path)
    return members


def trained_against(adversary: Path, env_id: str, mode: str) -> str | None:
    """The SHA-256 of the policy file ``adversary`` was trained against: its provenance's, or for files made before
    it recorded one, the digest of the bundled learner whose provenance it recorded (their victim is named by a path
    that was the learner's before it was bundled, and is gone: its provenance is what stayed with both)."""
    made = load_adversary(adversary).meta.get("provenance", {})
    if made.get("victim_sha256"):
        return made["victim_sha256"]
    for name in DEFENSES:
        try:
            learner = bundled_file(name, env_id, mode)
        except ValueError:  # no such learner for this env
            continue
        if load_policy(learner, env_id).meta.provenance == made.get("victim_provenance"):
            return digest_of(learner.read_bytes())
    return None


def screen_zoo(members: list[Path], surrogate: Path, env_id: str, mode: str, eps: float, expert: str,
               horizon: int = HORIZON) -> list[float]:
    """Step 2: each member's mean return against the surrogate (scaled to ``eps``) over episodes of ``horizon``
    steps, labelled by the policy ``expert`` (a file or bundled name), in the members' order."""
    return screen_members(members, load_policy(surrogate, env_id), env_id, mode, eps, resolve_policy(expert, env_id),
                          horizon)


def screen_members(members: list[Path], policy, env_id: str, mode: str, eps: float, expert_policy,
                   horizon: int = HORIZON, episodes: int = SCREEN_EPISODES) -> list[float]:
    """Each adversary's mean return against ``policy`` (a surrogate, or the policy's answers) on ``episodes``
    screening episodes, scaled to ``eps``, in the members' order."""
    return [round(float(np.mean(returns)), 3) for returns in
            episode_returns(members, policy, env_id, mode, eps, expert_policy, horizon, episodes, seeds.SCREENING)]


def episode_returns(members: list[Path], policy, env_id: str, mode: str, eps: float, expert_policy, horizon: int,
                    episodes: int, seed: int) -> list[np.ndarray]:
    """Each adversary's return against ``policy`` (scaled to ``eps``) in each of ``episodes`` episodes from env seed
    ``seed``, in the members' order."""
    made = []
    for member in members:
        attack = LearnedAttack(layout_of(env_id), load_adversary(member, env_id, mode), eps=eps,
                               victim=policy, expert=expert_policy)
        engine = RolloutEngine(env_id, policy, expert_policy, attack, mode, episodes, horizon)
        returns = np.zeros(episodes)
        for step in engine.iter_steps(episodes, seed):
            returns[step.episodes] += step.reward
        engine.close()
        made.append(returns)
    return made


def relative(path: Path) -> str:
    """``path`` relative to here when it lies below (what files and pages record), else as it is."""
    path = Path(path).resolve()
    return os.path.relpath(path) if path.is_relative_to(Path.cwd()) else str(path)


@dataclass
class FitSurrogateConfig:
    """Arguments of ``aril fit-surrogate``."""

    victim: str = arg("dagger", "the policy to copy from its answers: a bundled name, a policy file, or ros (a running "
                                "policy node in domain:=)")
    env: str = arg(DEFAULT_ENV, "gymnasium MuJoCo env id")
    mode: str = arg("sensory", "the attacked mode whose states it visits: sensory or physical")
    eps: float = arg(0.0, "the budget of the noise it visits under and of its probes (0: the calibrated one)",
                     low=0.0, high=MAX_EPS)
    domain: str = arg("", "victim:=ros: the ROS_DOMAIN_ID the node runs in")
    horizon: int = arg(HORIZON, "steps per visited episode", low=1, high=1_000_000)
    out: str = arg("", "where to write it (default runs/surrogate-<env>-<mode>.pt)")


def surrogate_fits(path: Path, victim_name: str, env_id: str, mode: str, eps: float, horizon: int) -> bool:
    """Whether ``path`` holds the pipeline's first surrogate of ``victim_name`` (a file inside the checkout by its
    relative path, as the surrogate records it) in ``mode`` at ``eps`` from episodes of ``horizon`` steps."""
    if not path.exists():
        return False
    made = load_policy(path, env_id).meta.provenance
    return ((made.get("victim"), made.get("mode"), made.get("eps"), made.get("horizon"))
            == (portable(victim_name), mode, eps, horizon))


def ready_surrogate(victim_name: str, env_id: str, mode: str, eps: float, out: Path, horizon: int = HORIZON,
                    log=print) -> Path:
    """``out``, the pipeline's first surrogate of ``victim_name`` (a file or bundled name) in ``mode`` at ``eps``:
    reused when it was fitted to that victim at that eps and horizon, else fitted now."""
    if surrogate_fits(out, victim_name, env_id, mode, eps, horizon):
        return out
    with answering(victim_name, env_id, mode, "") as victim:
        return fit_surrogate(victim, env_id, mode, eps, out, SurrogateConfig(), portable(victim_name), log, horizon)


def fit_surrogate_command(cfg: FitSurrogateConfig) -> Path:
    """``aril fit-surrogate``: the pipeline's first surrogate alone, for ``aril eval attack:=transfer
    attack_file:=<it>``."""
    check_name("mode", cfg.mode, ATTACKED_MODES)
    eps = cfg.eps or calibrated_eps(cfg.env, cfg.mode)
    out = Path(cfg.out or f"runs/surrogate-{cfg.env}-{cfg.mode}.pt")
    with answering(cfg.victim, cfg.env, cfg.mode, cfg.domain) as victim:
        return fit_surrogate(victim, cfg.env, cfg.mode, eps, out, SurrogateConfig(), cfg.victim, print, cfg.horizon)
