import itertools
from pathlib import Path

import numpy as np
import pytest
import torch

import aril_ros
from aril_ros.policy import (
    BLOCK_ROWS,
    MLPPolicy,
    PolicyFileError,
    in_blocks,
    load_policy,
    meta_for_env,
    save_policy,
)


def test_round_trip_keeps_actions_and_meta(tmp_path, make_policy):
    policy = make_policy("HalfCheetah-v5", seed=1)
    policy.meta.obs_mean = list(np.linspace(-1, 1, 17))
    policy.meta.obs_std = list(np.linspace(0.5, 2, 17))
    policy.meta.obs_clip = 5.0
    policy = type(policy)(policy.meta)  # rebuild so the normalisation buffers are set
    path = save_policy(policy, tmp_path / "p.pt")
    loaded = load_policy(path, "HalfCheetah-v5")
    obs = np.random.default_rng(0).normal(size=(10, 17))
    np.testing.assert_array_equal(policy.act(obs), loaded.act(obs))
    assert loaded.meta == policy.meta


def test_actions_respect_bounds_and_single_observation(make_policy):
    policy = make_policy("Swimmer-v5")
    obs = np.random.default_rng(0).normal(scale=100, size=(5, 8))
    actions = policy.act(obs)
    assert actions.shape == (5, 2) and np.all(np.abs(actions) <= 1)
    np.testing.assert_array_equal(policy.act(obs[2]), actions[2])


@pytest.mark.parametrize("env_id, hidden, activation", [("Ant-v5", (256, 256), "relu"),
                                                      ("HalfCheetah-v5", (64, 64), "tanh"),
                                                      ("Hopper-v5", (5, 7), "tanh"), ("Swimmer-v5", (33, 47), "tanh")])
def test_actions_do_not_depend_on_batch_composition(env_id, hidden, activation):
    """The widths this project trains (64, 256), bit for bit on every CPU: the blocks share one matrix-product call
    and every elementwise step. Odd widths, to the last bits: on AVX512 and on an AMD EPYC's AVX2 kernels MKL rounds a
    row of a layer whose width is no multiple of 16 by its place in the block (see BLOCK_ROWS); on other CPUs they
    held bit for bit."""
    torch.manual_seed(0)
    policy = MLPPolicy(meta_for_env(env_id, hidden=list(hidden), activation=activation)).eval()
    obs = np.random.default_rng(0).normal(scale=3.0, size=(3 * BLOCK_ROWS + 5, policy.meta.obs_dim))
    whole = policy.act(obs)
    one_by_one = np.stack([policy.act(o) for o in obs])
    if hidden[0] % 16:
        np.testing.assert_allclose(whole, one_by_one, rtol=0, atol=1e-6)
    else:
        np.testing.assert_array_equal(whole, one_by_one)


BUNDLED_POLICY_FILES = sorted(p for p in (Path(aril_ros.__file__).parent / "data").glob("*/*.pt")
                              if "adversary" not in p.parent.name)


@pytest.mark.parametrize("path", BUNDLED_POLICY_FILES, ids=lambda p: f"{p.parent.name}/{p.stem}")
def test_act_is_each_blocks_own_forward_bit_for_bit(path):
    """act() multiplies all blocks in one call; each block's rows must be what the block alone gives (the
    promise of BLOCK_ROWS, and what the trajectories already recorded were made with), and so what the forward
    pass of loss_gradient gives (FGSM^k takes its iterates' actions from there)."""
    policy = load_policy(path)
    obs = np.random.default_rng(0).normal(scale=2.0, size=(3 * BLOCK_ROWS + 5, policy.meta.obs_dim))
    blocks, n = in_blocks(obs)
    with torch.no_grad():
        block_by_block = torch.cat([policy(block) for block in blocks])[:n].double().numpy()
    np.testing.assert_array_equal(policy.act(obs), block_by_block)
    np.testing.assert_array_equal(policy.loss_gradient(obs, np.zeros((len(obs), policy.meta.act_dim)))[1],
                                  block_by_block)


def autograd_gradient(policy: MLPPolicy, obs: np.ndarray, target: np.ndarray) -> np.ndarray:
    """``d/d obs ||policy(obs) - target||^2`` block by block, as autograd gives it: what loss_gradient writes out."""
    grads = []
    for block, target_block in zip(in_blocks(obs)[0], in_blocks(target)[0]):
        block = block.clone().requires_grad_(True)
        grads.append(torch.autograd.grad(((policy(block) - target_block) ** 2).sum(), block)[0])
    return torch.cat(grads)[: len(obs)].double().numpy()


def variants() -> list[MLPPolicy]:
    """Every kind of net a policy file can hold (activation, squash, observation clip), small, random, its outputs
    scaled so that many leave the action bounds (where the clip squash's gradient is cut)."""
    made = []
    for activation, squash, obs_clip in itertools.product(("relu", "tanh"), ("tanh", "clip"), (None, 1.5)):
        torch.manual_seed(len(made))  # test-only: the nets' weights
        policy = MLPPolicy(meta_for_env("HalfCheetah-v5", hidden=[64, 64], activation=activation, squash=squash,
                                        obs_clip=obs_clip)).eval()
        with torch.no_grad():
            policy.net[-1].weight.mul_(8.0)
        made.append(policy)
    return made


@pytest.mark.parametrize("policy", [*BUNDLED_POLICY_FILES, *variants()],
                         ids=lambda p: f"{p.parent.name}/{p.stem}" if isinstance(p, Path) else
                         f"{p.meta.activation}-{p.meta.squash}-clip{p.meta.obs_clip}")
def test_loss_gradient_is_autograds_bit_for_bit(policy):
    """loss_gradient writes the chain rule out (FGSM^k's cost): it must give autograd's gradient to the last bit, on
    observations wide enough to reach the clip of the observations and the bounds of the actions."""
    policy = load_policy(policy) if isinstance(policy, Path) else policy
    rng = np.random.default_rng(0)
    obs = rng.normal(scale=4.0, size=(2 * BLOCK_ROWS + 3, policy.meta.obs_dim))
    target = rng.uniform(policy.meta.action_low, policy.meta.action_high, size=(len(obs), policy.meta.act_dim))
    grad, actions = policy.loss_gradient(obs, target)
    np.testing.assert_array_equal(grad, autograd_gradient(policy, obs, target))
    np.testing.assert_array_equal(actions, policy.act(obs))


def test_mismatched_env_is_named(tmp_path, make_policy):
    path = save_policy(make_policy("Swimmer-v5"), tmp_path / "swim.pt")
    with pytest.raises(PolicyFileError, match=r"policy is for Swimmer-v5 \(obs 8, act 2\) but the env is "
                                               r"HalfCheetah-v5 \(obs 17, act 6\)"):
        load_policy(path, "HalfCheetah-v5")


def test_corrupt_and_foreign_files_are_rejected(tmp_path, make_policy):
    good = save_policy(make_policy("Swimmer-v5"), tmp_path / "good.pt").read_bytes()
    truncated = tmp_path / "truncated.pt"
    truncated.write_bytes(good[: len(good) // 2])
    with pytest.raises(PolicyFileError, match="not a readable policy file"):
        load_policy(truncated)
    foreign = tmp_path / "foreign.pt"
    torch.save({"weights": torch.zeros(3)}, foreign)
    with pytest.raises(PolicyFileError, match="not an aril_ros policy file"):
        load_policy(foreign)
    with pytest.raises(PolicyFileError, match="no such policy file"):
        load_policy(tmp_path / "missing.pt")
    blob = torch.load(tmp_path / "good.pt", weights_only=True)
    blob["state_dict"].pop("net.2.weight")
    torch.save(blob, tmp_path / "missing_key.pt")
    with pytest.raises(PolicyFileError, match="corrupt policy file"):
        load_policy(tmp_path / "missing_key.pt")
    blob = torch.load(tmp_path / "good.pt", weights_only=True)
    blob["version"] = 99
    torch.save(blob, tmp_path / "future.pt")
    with pytest.raises(PolicyFileError, match="version 99"):
        load_policy(tmp_path / "future.pt")


def test_random_bytes_are_not_a_policy_file_and_not_called_pickled_code(tmp_path):
    path = tmp_path / "x.pt"
    path.write_bytes(np.random.default_rng(0).integers(0, 256, 4096, dtype=np.uint8).tobytes())
    with pytest.raises(PolicyFileError) as refused:
        load_policy(path)
    assert str(refused.value) == f"{path}: not an aril_ros policy file: not a torch archive"


class Payload:
    """Pickled code: loading it would call ``print``."""

    def __reduce__(self):
        return (print, ("ran",))


@pytest.mark.parametrize("content, message", [
    (lambda path: path.write_bytes(b"\x00" * 64), "x.pt: not an aril_ros policy file: not a torch archive"),
    (lambda path: torch.save({"format": "aril_ros.policy", "payload": Payload()}, path),
     "x.pt: refused for safety: the file holds pickled code or objects beyond plain weights"),
])
def test_aril_eval_refuses_a_file_that_is_no_policy_in_one_line(content, message, tmp_path, monkeypatch, capsys):
    from aril_ros.cli import main

    monkeypatch.chdir(tmp_path)
    content(Path("x.pt"))
    assert main(["eval", "env:=Swimmer-v5", "policy:=x.pt"]) == 2
    out, err = capsys.readouterr()
    assert out == "" and err.startswith(f"aril eval: error: {message}") and err.count("\n") == 1, err
