"""``aril validate-defense`` (the defense ARIL-V): the kept learner is the candidate with the best worst case, judged on
the validation episodes by every table attack and an ARIL-A trained against each candidate; a byte copy of it."""
import json
import shutil
from pathlib import Path

import pytest

from aril_ros import seeds
from aril_ros.adversary import trained_for
from aril_ros.adversary_net import load_adversary
from aril_ros.cli import main
from aril_ros.evaluation import EvalConfig, evaluate
from aril_ros.policy import PolicyFileError
from aril_ros.registry import THREATS, bundled_file, calibrated_eps
from aril_ros.sweep import digest_of
from aril_ros.validated import ValidateConfig, validate_defense

ENV, MODE = "Swimmer-v5", "sensory"
SMALL = dict(env=ENV, mode=MODE, episodes=2, horizon=20, adversary_steps=0)  # an untrained ARIL-A: seconds


def quiet(*args, **kwargs):
    pass


@pytest.fixture(scope="module")
def validated(tmp_path_factory):
    folder = tmp_path_factory.mktemp("validate")
    cfg = ValidateConfig(**SMALL, work_dir=str(folder / "work"), out=str(folder / "aril_v.pt"))
    return cfg, validate_defense(cfg, log=quiet)


def test_the_kept_learner_is_a_byte_copy_of_the_candidate_with_the_best_worst_case(validated):
    _, out = validated
    record = json.loads(out.with_suffix(".json").read_text())
    assert set(record["candidates"]) == {"aril", "dr"}
    for name, candidate in record["candidates"].items():
        assert set(candidate["returns"]) == {"none", *THREATS}
        attacked = {a: r for a, r in candidate["returns"].items() if a != "none"}
        assert candidate["worst"] == {"attack": min(attacked, key=attacked.get), "mean_return": min(attacked.values())}
        assert candidate["file"] == f"aril_ros/data/{name}/{ENV}-{MODE}.pt"  # the checkout's, not this machine's path
    chosen = record["chosen"]
    assert record["candidates"][chosen]["worst"]["mean_return"] == max(
        c["worst"]["mean_return"] for c in record["candidates"].values())
    assert out.read_bytes() == bundled_file(chosen, ENV, MODE).read_bytes()
    assert record["episode_seeds"] == f"{seeds.VALIDATION}..{seeds.VALIDATION + 1}"
    # the compute the choice took, which the report adds to the defense's
    assert set(record["cpu_seconds"]) == {"adversaries", "evaluations"}
    assert record["cpu_seconds"]["evaluations"] > 0 and record["cpu_seconds"]["adversaries"] >= 0


def test_each_candidate_is_judged_by_an_aril_a_trained_against_it_with_the_validation_seed(validated):
    cfg, out = validated
    record = json.loads(out.with_suffix(".json").read_text())
    eps = calibrated_eps(ENV, MODE)
    for name, candidate in record["candidates"].items():
        adversary = Path(cfg.work_dir) / f"{ENV}-{MODE}-{name}-validation.pt"
        assert trained_for(adversary, eps, str(bundled_file(name, ENV, MODE)), ENV, MODE)
        assert load_adversary(adversary).meta["provenance"]["settings"]["seed"] == seeds.VALIDATION_ADVERSARY
        assert candidate["adversary_sha256"] == digest_of(adversary.read_bytes())  # the judge, though not kept
        # the figures are those of the validation episodes, which no table shares
        again = evaluate(EvalConfig(env=ENV, policy=name, mode=MODE, attack="aril_a", attack_file=str(adversary),
                                    eps=eps, episodes=2, seed=seeds.VALIDATION, horizon=20))
        assert candidate["returns"]["aril_a"] == round(again["mean_return"], 3)


def test_a_rerun_keeps_the_trained_adversaries_and_the_choice(validated, tmp_path):
    cfg, out = validated
    adversaries = sorted(p for p in (out.parent / "work").glob("*.pt"))
    before = {p: p.stat().st_mtime_ns for p in adversaries}
    again = validate_defense(ValidateConfig(**SMALL, work_dir=cfg.work_dir, out=str(tmp_path / "again.pt")), log=quiet)
    assert {p: p.stat().st_mtime_ns for p in adversaries} == before
    assert again.read_bytes() == out.read_bytes()


def test_on_a_tie_the_first_candidate_is_kept(tmp_path):
    twin = tmp_path / "twin.pt"
    shutil.copyfile(bundled_file("dagger", ENV), twin)
    out = validate_defense(ValidateConfig(**SMALL, candidates=f"{twin},dagger", work_dir=str(tmp_path / "work"),
                                          out=str(tmp_path / "kept.pt")), log=quiet)
    record = json.loads(out.with_suffix(".json").read_text())
    assert record["candidates"][str(twin)]["returns"] == record["candidates"]["dagger"]["returns"]
    assert record["chosen"] == str(twin)


@pytest.mark.parametrize("candidates, mode, says", [
    ("aril", MODE, "at least two different learners"),
    ("aril,aril", MODE, "at least two different learners"),
    ("aril,dr", "clean", "mode:= sensory or physical"),
    ("aril,missing.pt", MODE, "candidate 'missing.pt': no policy file"),
])
def test_what_cannot_be_validated_is_refused_naming_it(tmp_path, candidates, mode, says):
    with pytest.raises(ValueError, match=says):
        validate_defense(ValidateConfig(**{**SMALL, "mode": mode}, candidates=candidates, out=str(tmp_path / "o.pt")),
                         log=quiet)


def test_a_candidate_neither_bundled_nor_a_file_is_named(tmp_path):
    with pytest.raises(PolicyFileError, match="'nonsense' is neither a bundled policy name"):
        validate_defense(ValidateConfig(**SMALL, candidates="aril,nonsense", out=str(tmp_path / "o.pt")), log=quiet)


def test_the_command_refuses_in_one_line(capsys):
    assert main(["validate-defense", "candidates:=aril", f"env:={ENV}"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["aril validate-defense: error: candidates:= takes at least two different learners, got 'aril'"]
