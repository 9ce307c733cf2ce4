"""The ``aril`` command (also ``python -m aril_ros``): subcommands with ``key:=value`` arguments.

    aril eval env:=HalfCheetah-v5 policy:=expert mode:=sensory attack:=random eps:=0.05
    aril train-expert env:=Ant-v5 steps:=300000

Progress goes to stderr; results to stdout, ending with one JSON line.
"""
from __future__ import annotations

import json
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from .args import ArgumentError, arg, parse_args, usage
from .adversary import AdversaryConfig, train_adversary
from .attacks import ATTACK_NAMES, make_attack
from .envs import EnvLayoutError, layout_of
from .experts import ExpertConfig, resolve_policy, train_expert
from .learners import BCConfig, train_bc
from .mcap_log import RunLogError, recover
from .policy import PolicyFileError
from .rollout import MODES, RolloutEngine


@dataclass
class EvalConfig:
    """Arguments of ``aril eval``."""

    env: str = arg("HalfCheetah-v5", "gymnasium MuJoCo env id")
    policy: str = arg("expert", "policy to evaluate: a bundled name (expert) or a policy file path")
    expert: str = arg("expert", "expert that labels the true states: a bundled name or a file path")
    mode: str = arg("clean", f"one of {', '.join(MODES)}")
    attack: str = arg("", f"one of {', '.join(ATTACK_NAMES)} (default: none when clean, random otherwise)")
    eps: float = arg(0.05, "L-infinity bound of the perturbation on the zero-order entries")
    k: int = arg(10, "steps of fgsm_k")
    attack_file: str = arg("", "aril_a: the adversary file (from aril train-adversary)")
    episodes: int = arg(5, "number of episodes (env seeds seed, seed+1, ...)")
    seed: int = arg(0, "seed of the first episode and of the attack noise")
    n_envs: int = arg(32, "simulators run side by side (does not change the results)")
    horizon: int = arg(1000, "steps per episode")
    threads: int = arg(1, "torch threads (more only slows these small networks down)")


def run_eval(cfg: EvalConfig) -> dict:
    torch.set_num_threads(cfg.threads)
    attack_name = cfg.attack or ("none" if cfg.mode == "clean" else "random")
    layout = layout_of(cfg.env)  # an unknown or non-MuJoCo id is the first thing to report
    policy = resolve_policy(cfg.policy, cfg.env)
    expert = resolve_policy(cfg.expert, cfg.env)
    if cfg.mode == "clean" and attack_name != "none":
        raise ArgumentError(f"mode:=clean runs no attack, got attack:={attack_name}")
    attack = make_attack(attack_name, layout, cfg.eps if attack_name != "none" else 0.0, victim=policy,
                         expert=expert, steps=cfg.k if attack_name == "fgsm_k" else None,
                         adversary=cfg.attack_file, mode=cfg.mode)
    engine = RolloutEngine(cfg.env, policy, expert, attack, cfg.mode, min(cfg.n_envs, cfg.episodes), cfg.horizon)
    started = time.time()
    returns = np.zeros(cfg.episodes)
    sq_loss = np.zeros(cfg.episodes)
    length = np.zeros(cfg.episodes, dtype=int)
    max_delta = np.zeros(cfg.episodes)
    steps = 0
    for step in engine.iter_steps(cfg.episodes, cfg.seed):
        e = step.episodes
        returns[e] += step.reward
        sq_loss[e] += ((step.action - step.expert_action) ** 2).sum(axis=1)
        length[e] += 1
        max_delta[e] = np.maximum(max_delta[e], np.abs(step.delta).max(axis=1))
        steps += len(e)
        for k in e[step.done]:
            print(f"episode {k:3d}  return {returns[k]:9.1f}  expert loss {sq_loss[k] / length[k]:.4f}  "
                  f"steps {length[k]:4d}  max|delta| {max_delta[k]:.4f}", file=sys.stderr, flush=True)
    engine.close()
    seconds = time.time() - started
    summary = {
        "env": cfg.env, "policy": cfg.policy, "expert": cfg.expert, "mode": cfg.mode, "attack": attack_name,
        "eps": engine.attack.eps, "episodes": cfg.episodes, "seed": cfg.seed,
        "mean_return": round(float(returns.mean()), 3), "std_return": round(float(returns.std()), 3),
        "mean_expert_loss": round(float(sq_loss.sum() / length.sum()), 6),
        "steps": int(steps), "steps_per_s": round(steps / seconds, 1),
    }
    print(f"{cfg.env} {cfg.mode}/{attack_name} eps={summary['eps']}: return "
          f"{summary['mean_return']:.1f} ± {summary['std_return']:.1f} over {cfg.episodes} episodes, "
          f"mean expert loss {summary['mean_expert_loss']:.4f}, {summary['steps_per_s']:.0f} steps/s")
    print(json.dumps(summary))
    return summary


@dataclass
class RecoverConfig:
    """Arguments of ``aril log-recover``."""

    input: str = arg("", "a run log that was cut short (the run was killed)")
    out: str = arg("", "where to write the recovered log (default: <input>.recovered.mcap)")


def run_recover(cfg: RecoverConfig) -> int:
    out = cfg.out or str(Path(cfg.input).with_suffix("")) + ".recovered.mcap"
    steps = recover(cfg.input, out)
    print(f"recovered {steps} complete steps into {out}")
    return steps


def run_replay(cfg) -> int:
    from nodes.replay import replay  # the only subcommand that needs ROS

    return replay(cfg)


def _replay_config():
    from nodes.replay import ReplayConfig

    return ReplayConfig


COMMANDS = {
    "eval": (EvalConfig, run_eval, "Evaluate a policy under a mode, attack and eps, labelled by the expert."),
    "train-expert": (ExpertConfig, train_expert, "Train an expert with stable-baselines3 SAC and export it."),
    "train-bc": (BCConfig, train_bc, "Behaviour-clone a learner from clean expert demonstrations."),
    "train-adversary": (AdversaryConfig, train_adversary,
                        "Train the learned ARIL-A adversary against a policy (PPO on the in-process engine)."),
    "replay": (_replay_config, run_replay, "Republish a run log's topics paced by sim time (like ros2 bag play)."),
    "log-recover": (RecoverConfig, run_recover, "Rewrite the complete steps of a cut-short run log."),
}


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if not argv or argv[0] in ("-h", "--help") or argv[0] not in COMMANDS:
        print("usage: aril <command> [key:=value ...] [--help]\n\ncommands:")
        for name, (_, _, summary) in COMMANDS.items():
            print(f"  {name:<14} {summary}")
        return 0 if not argv or argv[0] in ("-h", "--help") else 2
    cls, run, summary = COMMANDS[argv[0]]
    cls = cls if isinstance(cls, type) else cls()
    if "-h" in argv[1:] or "--help" in argv[1:]:
        print(usage(cls, f"aril {argv[0]}", summary))
        return 0
    try:
        run(parse_args(cls, argv[1:]))
    except (ArgumentError, EnvLayoutError, PolicyFileError, RunLogError, ValueError) as err:
        print(f"aril {argv[0]}: error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"aril {argv[0]}: interrupted", file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
