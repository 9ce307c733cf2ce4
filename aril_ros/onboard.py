"""``aril onboard``: a new robot in one command. An expert, a DAgger learner and the eps of each attacked mode
for a gymnasium MuJoCo env that aril_ros bundles nothing for, written to the user data folder.

    aril onboard env:=Hopper-v5

Three stages, each skipped when its result is there, so an interrupted onboarding picks up where it stopped:

1. the expert: stable-baselines3 SAC (rl-baselines3-zoo's settings), the best exported actor kept, the training
   state checkpointed at every evaluation (with its replay buffer: the resume is on this machine) and resumed;
2. the DAgger learner (the paper's learner: two hidden layers of 64), its run directory resumed by round;
3. eps per attacked mode by the paper's rule (the largest eps before FGSM costs the learner more than 40%).

Then the expert is evaluated on 50 deterministic episodes. Where everything goes (``$ARIL_DATA``, default
``~/.local/share/aril_ros``; names resolve there, so ``policy:=dagger env:=Hopper-v5`` works afterwards)::

    expert/<env>.pt, dagger/<env>.pt, eps_calibration.{json,md}     what the names and eps:=0 resolve to
    onboard/<env>/expert/     the expert's checkpoint (state.json, model.zip, replay_buffer.pkl)
    onboard/<env>/dagger/     the learner's run directory (state.json, data.npz, pi-<r>.pt)
    onboard/<env>/onboard.json   the summary: files, returns, eps, seconds per stage of this run and the
                                 trainings' own seconds over every run (a resumed stage's whole time)
"""
from __future__ import annotations

import json
import shutil
import time
from dataclasses import dataclass
from pathlib import Path

from . import seeds
from .args import arg
from .dagger import train_learner
from .envs import layout_of
from .evaluation import EvalConfig, evaluate
from .experiments import CalibrationConfig, calibrate_eps
from .experts import ExpertConfig, train_expert
from .learner_config import LearnerConfig
from .policy import load_policy
from .registry import ATTACKED_MODES, DEFAULT_ENV, calibrated_eps, user_data_dir, user_path


@dataclass
class OnboardConfig:
    """Arguments of ``aril onboard``."""

    env: str = arg(DEFAULT_ENV, "the gymnasium MuJoCo env id to onboard")
    expert_steps: int = arg(1_000_000, "SAC steps of the expert (rl-baselines3-zoo trains Hopper and Walker2d 1M)",
                            low=1, high=10**9)
    eval_every: int = arg(25_000, "evaluate the expert's actor every this many steps (the best is kept, the training "
                                  "state saved)", low=1, high=10**9)
    rounds: int = arg(10, "DAgger rounds after the expert's demonstrations", low=1, high=1000)
    episodes: int = arg(5, "episodes collected per DAgger round", low=1, high=100_000)
    calibration_episodes: int = arg(10, "episodes per eps tried in the calibration", low=1, high=100_000)
    final_episodes: int = arg(50, "deterministic episodes of the expert's final evaluation", low=1, high=100_000)
    seed: int = arg(0, "seed of the expert's and the learner's training", low=0, high=999)


def onboard(cfg: OnboardConfig, log=print) -> dict:
    """Expert, learner, eps; then the expert's evaluation. Returns (and writes) the summary."""
    layout_of(cfg.env)  # an id that is not a MuJoCo env is the first thing to report
    home = user_data_dir() / "onboard" / cfg.env
    timings = {}
    expert = stage("expert", timings, log, lambda: ready_expert(cfg, home / "expert", log))
    learner = user_path("dagger", cfg.env)
    stale = learner.is_file() and expert.stat().st_mtime_ns > learner.stat().st_mtime_ns
    if stale:  # the expert trained on: its labels changed, so the learner and its eps are made anew
        log(f"[onboard] the expert is newer than {learner}: the learner and the eps are made anew")
        learner.unlink()
        shutil.rmtree(home / "dagger", ignore_errors=True)
    learner = stage("dagger learner", timings, log, lambda: ready_learner(cfg, expert, home / "dagger", log))
    eps = stage("eps calibration", timings, log, lambda: ready_eps(cfg, expert, learner, stale, log))
    final = evaluate(EvalConfig(env=cfg.env, policy=str(expert), expert=str(expert), episodes=cfg.final_episodes,
                                seed=seeds.USER))
    summary = {"env": cfg.env, "expert": str(expert), "dagger": str(learner), "eps": eps,
               "expert_return": {"mean": final["mean_return"], "std": final["std_return"],
                                 "episodes": cfg.final_episodes, "seeds": f"{seeds.USER}..{seeds.USER + cfg.final_episodes - 1}"},
               "seconds": timings,
               # a resumed or skipped stage took seconds here: what its file's training took in all, over every run
               "trained_seconds": {name: load_policy(path, cfg.env).meta.provenance.get("train_seconds")
                                   for name, path in (("expert", expert), ("dagger learner", learner))}}
    (home / "onboard.json").write_text(json.dumps(summary, indent=1) + "\n")
    log(f"[onboard {cfg.env}] done: expert {final['mean_return']:.1f} ± {final['std_return']:.1f} over "
        f"{cfg.final_episodes} episodes; eps {eps}; policy:=dagger, expert:=expert and eps:=0 now resolve for {cfg.env} "
        f"(files in {user_data_dir()})")
    log(json.dumps(summary))
    return summary


def stage(name: str, timings: dict, log, run):
    """Run one stage, timing it and saying when it starts and ends."""
    log(f"[onboard] {name}: starting", flush=True)
    started = time.monotonic()
    result = run()
    timings[name] = round(time.monotonic() - started, 1)
    log(f"[onboard] {name}: done in {timings[name]:.0f} s -> {result}", flush=True)
    return result


def ready_expert(cfg: OnboardConfig, checkpoint: Path, log) -> Path:
    """The expert file, trained (or its training resumed from ``checkpoint``) until ``expert_steps``."""
    out = user_path("expert", cfg.env)
    state = checkpoint / "state.json"
    done = json.loads(state.read_text())["steps"] if state.is_file() else 0
    if out.is_file() and done >= cfg.expert_steps:
        return out
    if done:
        log(f"[onboard] expert: resuming from {checkpoint} at step {done}")
    train_expert(ExpertConfig(env=cfg.env, algo="sac", steps=cfg.expert_steps, seed=cfg.seed, eval_every=cfg.eval_every,
                              out=str(out), checkpoint=str(checkpoint), keep_buffer=True,
                              resume=str(checkpoint) if done else ""), log=log)
    return out


def ready_learner(cfg: OnboardConfig, expert: Path, run_dir: Path, log) -> Path:
    """The DAgger learner file; its run directory resumes a training cut short."""
    out = user_path("dagger", cfg.env)
    if out.is_file():
        return out
    train_learner(LearnerConfig(algorithm="dagger", env=cfg.env, expert=str(expert), rounds=cfg.rounds,
                                episodes=cfg.episodes, seed=cfg.seed, run_dir=str(run_dir), out=str(out)), log=log)
    return out


def ready_eps(cfg: OnboardConfig, expert: Path, learner: Path, anew: bool, log) -> dict[str, float]:
    """eps per attacked mode: the calibration's, made now against the learner where it has none (every mode when
    ``anew``: the learner was trained again)."""
    missing = list(ATTACKED_MODES) if anew else []
    for mode in ATTACKED_MODES:
        try:
            calibrated_eps(cfg.env, mode)
        except ValueError:
            missing.append(mode)
    missing = sorted(set(missing), key=ATTACKED_MODES.index)
    if missing:
        calibrate_eps(CalibrationConfig(envs=cfg.env, modes=",".join(missing), policy=str(learner), expert=str(expert),
                                        episodes=cfg.calibration_episodes), log=log)
    return {mode: calibrated_eps(cfg.env, mode) for mode in ATTACKED_MODES}
