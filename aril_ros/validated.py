"""``aril validate-defense``: of a few learners trained for the same env and mode, the one that keeps the most return
under its worst attack on validation episodes no table shares: the defense ARIL-V, beyond the paper.

Why. Over training seeds neither of the two strongest defenses keeps the most in every cell (``docs/results.md``,
"Which defense leads"): ARIL (Algorithm 1, its rounds under a learned adversary) holds where DR (its rounds under
uniform +-eps noise) does not, and the other way round, seed by seed. HalfCheetah physical's ARIL seeds keep -159 to
2514 under their ARIL-A, DR's 163 to 511. Algorithm 1 returns the round learner whose return under its own round's
adversary is best, a judge the learner was just trained against. ARIL-V (``candidates:=aril,dr``) runs Algorithm 1
with both families of round adversaries and keeps the learner a fresh judge finds strongest: the worst of every attack
the defense tables use, an ARIL-A among them trained against that very candidate with a seed no table's ARIL-A has
(:data:`~aril_ros.seeds.VALIDATION_ADVERSARY`), on env seeds :data:`~aril_ros.seeds.VALIDATION` onwards.

On disk::

    <out>                 the chosen candidate, a byte copy: the tables evaluate the same bytes as that candidate's
                          row (its cached evaluations, the ARIL-A trained against it) and the file's own provenance
                          says how it was trained
    <out without .pt>.json the choice: per candidate its file and digest, its validation adversary, its mean
                          return clean and under each attack, its worst; which was chosen; the command, the CPU
                          and the CPU seconds of the adversaries' trainings and of the evaluations
    <work_dir>/<env>-<mode>-<candidate>-validation.pt   each candidate's validation ARIL-A (kept: a rerun resumes)
"""
from __future__ import annotations

import dataclasses
import json
import shutil
import time
from dataclasses import dataclass
from pathlib import Path

from . import seeds
from .adversary import AdversaryConfig, ready_adversaries
from .adversary_net import load_adversary
from .args import arg, comma_list
from .envs import HORIZON
from .evaluation import evaluate_all
from .files import write_atomically
from .policy import policy_file
from .provenance import cpu, portable, stamp
from .registry import ATTACKED_MODES, DEFAULT_ENV, MAX_EPS, THREATS, calibrated_eps
from .sweep import digest_of, session


@dataclass
class ValidateConfig:
    """Arguments of ``aril validate-defense``."""

    env: str = arg(DEFAULT_ENV, "gymnasium MuJoCo env id")
    mode: str = arg("sensory", "the attack mode the candidates are judged under: sensory or physical")
    candidates: str = arg("aril,dr", "comma-separated learners (bundled names, aril and dr the ones of mode:=, or "
                                     "policy files), at least two; on a tie the first is kept")
    eps: float = arg(0.0, "the budget (0: the calibrated eps for env and mode, as the tables)", low=0.0, high=MAX_EPS)
    expert: str = arg("expert", "the expert whose action on the true state the ARIL-As' loss compares with")
    episodes: int = arg(50, f"validation episodes per candidate and attack (env seeds {seeds.VALIDATION}...), the same "
                            f"for every candidate", low=1, high=1000)
    adversary_steps: int = arg(1_000_000, "PPO steps of each candidate's validation ARIL-A (the tables': 1M)",
                               low=0, high=10**9)
    horizon: int = arg(HORIZON, "steps per episode (fewer only for a smoke test)", low=1, high=1_000_000)
    workers: int = arg(1, "CPUs of a local Ray the adversaries and evaluations run on as tasks (1: in this process)",
                       low=1, high=1024)
    address: str = arg("", "run the tasks on this Ray cluster instead (<head ip>:6379, or auto)")
    work_dir: str = arg("runs/validate", "where the validation ARIL-As are kept")
    out: str = arg("", "the chosen learner's copy (default runs/aril_v-<env>-<mode>.pt); its record beside it, .json")


def checked(cfg: ValidateConfig) -> tuple[ValidateConfig, dict[str, Path]]:
    """``cfg`` with eps and out filled in, and each candidate's file by its name; a ValueError naming what is wrong."""
    if cfg.mode not in ATTACKED_MODES:
        raise ValueError(f"validate-defense judges under attack: mode:= sensory or physical, got {cfg.mode!r}")
    names = comma_list(cfg.candidates)
    if len(names) < 2 or len(set(names)) < len(names):
        raise ValueError(f"candidates:= takes at least two different learners, got {cfg.candidates!r}")
    files = {}
    for name in names:
        file = policy_file(name, cfg.env, cfg.mode)
        if not file.is_file():
            raise ValueError(f"candidate {name!r}: no policy file at {file}")
        # keyed as the record names them: a file inside the checkout by its relative path, as every record does
        files[portable(str(file.resolve())) if Path(name).suffix else name] = file
    eps = cfg.eps or calibrated_eps(cfg.env, cfg.mode)
    out = cfg.out or f"runs/aril_v-{cfg.env}-{cfg.mode}.pt"
    return dataclasses.replace(cfg, eps=eps, out=out), files


def label(name: str) -> str:
    """A candidate's name in file names: a bundled name as it is, a file by its stem."""
    return Path(name).stem


def validation_adversaries(cfg: ValidateConfig, files: dict[str, Path], log) -> dict[str, Path]:
    """Each candidate's validation ARIL-A, trained against it (kept and reused when already so trained)."""
    wanted = {name: AdversaryConfig(env=cfg.env, mode=cfg.mode, eps=cfg.eps, victim=str(file), expert=cfg.expert,
                                    steps=cfg.adversary_steps, seed=seeds.VALIDATION_ADVERSARY,
                                    out=str(Path(cfg.work_dir) / f"{cfg.env}-{cfg.mode}-{label(name)}-validation.pt"))
              for name, file in files.items()}
    return dict(zip(wanted, ready_adversaries(list(wanted.values()), False, log, cfg.workers, cfg.address)))


def judged(cfg: ValidateConfig, files: dict[str, Path], adversaries: dict[str, Path], log
           ) -> tuple[dict[str, dict], float]:
    """Each candidate's mean return clean and under each of the tables' attacks (:data:`~aril_ros.registry.THREATS`),
    every one on the same validation episodes, and its worst attack; and the seconds the evaluations took."""
    points = [(name, attack) for name in files for attack in ("none", *THREATS)]
    jobs = [{"env": cfg.env, "policy": str(files[name]), "expert": cfg.expert,
             "mode": "clean" if attack == "none" else cfg.mode, "attack": attack, "eps": cfg.eps,
             "attack_file": str(adversaries[name]) if attack == "aril_a" else "", "episodes": cfg.episodes,
             "seed": seeds.VALIDATION, "horizon": cfg.horizon} for name, attack in points]
    results = evaluate_all(jobs, cfg.workers, cfg.address, log, label="validation evaluations")
    seconds = sum(result["steps"] / result["steps_per_s"] for result in results)
    records = {name: {"file": portable(str(files[name])), "sha256": digest_of(files[name].read_bytes()),
                      "adversary": portable(str(adversaries[name])),
                      "adversary_sha256": digest_of(Path(adversaries[name]).read_bytes()), "returns": {}}
               for name in files}
    for (name, attack), result in zip(points, results):
        records[name]["returns"][attack] = round(float(result["mean_return"]), 3)
    for record in records.values():
        attacked = {a: r for a, r in record["returns"].items() if a != "none"}
        worst = min(attacked, key=attacked.get)
        record["worst"] = {"attack": worst, "mean_return": attacked[worst]}
    return records, seconds


def validate_defense(cfg: ValidateConfig, log=print) -> Path:
    """The candidate that keeps the most under its worst attack on the validation episodes, copied to ``out``, and
    the record of the choice beside it."""
    started = time.time()
    cfg, files = checked(cfg)
    made = stamp("aril validate-defense", cfg)
    with session(cfg.workers, cfg.address):
        adversaries = validation_adversaries(cfg, files, log)
        candidates, evaluation_seconds = judged(cfg, files, adversaries, log)
    training_seconds = sum(load_adversary(file).meta["provenance"]["train_seconds"] for file in adversaries.values())
    chosen = max(candidates, key=lambda name: candidates[name]["worst"]["mean_return"])  # the first on a tie
    out = Path(cfg.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    record = {**made, "cpu": cpu(), "seconds": round(time.time() - started, 1),
              "cpu_seconds": {"adversaries": round(training_seconds, 1), "evaluations": round(evaluation_seconds, 1)},
              "env": cfg.env, "mode": cfg.mode,
              "eps": cfg.eps, "episode_seeds": f"{seeds.VALIDATION}..{seeds.VALIDATION + cfg.episodes - 1}",
              "chosen": chosen, "candidates": candidates}
    write_atomically(out, lambda partial: shutil.copyfile(files[chosen], partial))
    write_atomically(out.with_suffix(".json"), lambda partial: partial.write_text(json.dumps(record, indent=1) + "\n"))
    log(f"[validate-defense] {cfg.env} {cfg.mode}: " + ", ".join(
        f"{name} worst {c['worst']['mean_return']:.1f} ({c['worst']['attack']})" for name, c in candidates.items())
        + f"; kept {chosen} as {out}", flush=True)
    return out
