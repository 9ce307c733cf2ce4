"""The vocabulary and the seed ranges: defined once, and the ranges never overlap."""
from __future__ import annotations

import itertools
import json

import pytest

from aril_ros import registry, seeds

EVALUATIONS = {"calibration": seeds.CALIBRATION, "attack table": seeds.ATTACK_TABLE,
               "defense table": seeds.DEFENSE_TABLE, "selection": seeds.SELECTION, "gail demos": seeds.GAIL_DEMOS,
               "learner eval": seeds.LEARNER_EVAL, "validation": seeds.VALIDATION}
RANGE = 1000  # episodes an evaluation may take from its first seed


def test_evaluation_ranges_are_disjoint_and_below_every_training():
    spans = sorted((first, first + RANGE, name) for name, first in EVALUATIONS.items())
    for (_, end, a), (start, _, b) in itertools.pairwise(spans):
        assert end <= start, f"{a} overlaps {b}"
    assert spans[-1][1] <= seeds.TRAINING


@pytest.mark.parametrize("seed", [0, 1, 2, 3, 10])
def test_a_training_seed_collects_in_its_own_block_above_the_evaluations(seed):
    rounds = [seeds.collection(seed, r) for r in range(50)]
    adversary = seeds.adversary_training(seed)
    block = seeds.training_block(seed)
    assert all(block <= first < block + seeds.SEED_BLOCK for first in [*rounds, adversary])
    assert min(rounds) >= seeds.TRAINING  # BC with seed:=1 no longer takes the calibration's episodes
    assert rounds[-1] + seeds.ROUND_BLOCK <= adversary  # rounds (1000 episodes each at most) before the adversary
    assert seeds.training_block(seed + 1) == block + seeds.SEED_BLOCK
    with pytest.raises(ValueError, match="training seeds are >= 0"):
        seeds.training_block(-1)


def test_names_are_defined_once_and_consistently():
    assert set(registry.WHITE_BOX) | set(registry.QUERY_ATTACKS) <= set(registry.ATTACKS) and set(registry.THREATS) <= set(registry.ATTACKS)
    assert set(registry.PAPER_DEFENSES) <= set(registry.DEFENSES)
    assert set(registry.PER_MODE_POLICIES) <= set(registry.DEFENSES)
    assert registry.attack_for_mode("clean") == "none" and registry.attack_for_mode("sensory") == "random"
    with pytest.raises(ValueError, match="unknown attack 'pgd'; choose one of none, random, fgsm, fgsm_k, spsa, fd_fgsm, aril_a"):
        registry.attack_for_mode("sensory", "pgd")
    with pytest.raises(ValueError, match="mode:=clean runs no attack"):
        registry.attack_for_mode("clean", "fgsm")


def test_bundled_files_and_the_calibration_are_package_data():
    assert registry.CALIBRATION.is_relative_to(registry.DATA_DIR)
    for env in registry.PAPER_ENVS:
        for mode in registry.ATTACKED_MODES:
            assert registry.calibrated_eps(env, mode) > 0
            assert registry.adversary_path(env, mode).is_file()
            assert registry.bundled_file("aril", env, mode).is_file()
        assert registry.bundled_file("bundled", env) == registry.bundled_path("dagger", env)
    with pytest.raises(registry.BundledFileError, match=r"no dagger for Hopper-v5 .*there are: Ant-v5.*"
                       r"`aril train-learner algorithm:=dagger env:=Hopper-v5 out:=.*/dagger/Hopper-v5.pt`"):
        registry.bundled_file("dagger", "Hopper-v5")
    with pytest.raises(registry.BundledFileError, match="trained per attack mode"):
        registry.bundled_path("dr", "Swimmer-v5", "clean")


def test_settings_travel_as_json_in_provenance():
    from aril_ros.learner_config import LearnerConfig
    from aril_ros.policy import load_weights
    from aril_ros.provenance import settings_of, stamp

    provenance = load_weights(registry.bundled_file("aril", "Swimmer-v5", "physical"))[0]["provenance"]
    cfg = settings_of(provenance, LearnerConfig, seed=2)
    assert (cfg.algorithm, cfg.env, cfg.mode, cfg.adversary_seeds, cfg.warm_start, cfg.seed) == (
        "aril", "Swimmer-v5", "physical", 3, False, 2)  # the bundled one: each round's f_t the strongest of three
    made = stamp("aril train-learner", cfg)
    assert settings_of(made, LearnerConfig) == cfg and made["command"].startswith("aril train-learner algorithm:=aril")
    with pytest.raises(ValueError, match="records no settings"):
        settings_of({"command": "aril train-bc"}, LearnerConfig)


def test_provenance_records_paths_inside_the_checkout_relative_to_it(tmp_path):
    """What ``aril defense-table`` trains from the bundled files' absolute paths is committed: it must name them from
    the checkout's root, not from this machine's folder; a path elsewhere (the user's) stays as given."""
    from aril_ros.adversary import AdversaryConfig
    from aril_ros.provenance import CHECKOUT, stamp

    victim = CHECKOUT / "aril_ros" / "data" / "aril" / "Swimmer-v5-physical.pt"
    made = stamp("aril train-adversary", AdversaryConfig(victim=str(victim), out=str(tmp_path / "adversary.pt")))
    assert made["settings"]["victim"] == "aril_ros/data/aril/Swimmer-v5-physical.pt"
    assert " victim:=aril_ros/data/aril/Swimmer-v5-physical.pt " in made["command"]
    assert made["settings"]["out"] == str(tmp_path / "adversary.pt")


def test_no_bundled_file_or_committed_figure_names_a_machines_path():
    """Bundled files and the committed figures are read on other machines: a path they record (a trained file's
    out:=, a table's adversary) is relative to the checkout, never this machine's folder or a worker's scratch."""
    import re

    import torch

    from aril_ros.provenance import CHECKOUT

    absolute = re.compile(r"""(?:^|[\s="'])(/\w[^\s"']*)""")
    for path in sorted([*registry.DATA_DIR.glob("*/*.pt"), *CHECKOUT.glob("results/**/*.pt")]):
        meta = torch.load(path, map_location="cpu", weights_only=True)["meta"]  # policies and adversaries alike
        assert not absolute.findall(meta), path.relative_to(CHECKOUT)
    for path in [*CHECKOUT.glob("results/**/*.json"), *CHECKOUT.glob("docs/results/*.json")]:
        assert not absolute.findall(path.read_text()), path.relative_to(CHECKOUT)


def test_provenance_names_the_cpu_whose_kernels_made_the_figures():
    """The same files give other episodes on a CPU with another instruction set (torch's kernels round
    differently), so a record must say which CPU made it."""
    import torch

    from aril_ros.provenance import versions

    recorded = versions()
    assert set(recorded) == {"mujoco", "gymnasium", "numpy", "torch", "cpu"}
    assert recorded["cpu"].endswith(f"({torch.backends.cpu.get_cpu_capability()})")
