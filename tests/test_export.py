"""aril export: run logs of real graph runs into Minari datasets, read back with minari's own reader, and into the
learners: a dataset gives exactly the pairs of its logs."""
from __future__ import annotations

import numpy as np
import pytest

from aril_ros.dataset import load_dagger_dataset
from aril_ros.export import ExportConfig, export
from aril_ros.runlog import RunLogError, read_run
from tests.conftest import policy_files, run_graph, summary_of


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    """A folder of two logs of one env: sensory with a random attack and a timing attack (drops), and clean."""
    folder = tmp_path_factory.mktemp("logs")
    policy, expert = policy_files(folder, "HalfCheetah-v5")
    common = ("env:=HalfCheetah-v5", f"policy:={policy}", f"expert:={expert}", "baseline:=false")
    summary_of(run_graph("mode:=sensory", "attack:=random", "eps:=0.1", "drop:=0.2", "episodes:=2", "horizon:=25",
                         "seed:=3", f"record:={folder / 'a.mcap'}", *common))
    summary_of(run_graph("mode:=clean", "episodes:=1", "horizon:=20", f"record:={folder / 'b.mcap'}", *common))
    return folder


@pytest.mark.slow
def test_a_minari_dataset_holds_every_step_of_its_logs_read_by_minari(logs, tmp_path, monkeypatch):
    import minari

    out = export(ExportConfig(file=str(logs), out=str(tmp_path)), log=lambda *a, **k: None)
    assert out == tmp_path / "aril_ros" / "HalfCheetah-v5-clean-sensory-v0" / "data"
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path))
    dataset = minari.load_dataset("aril_ros/HalfCheetah-v5-clean-sensory-v0")
    assert dataset.total_episodes == 3 and dataset.total_steps == 25 + 25 + 20
    runs = [read_run(logs / "a.mcap"), read_run(logs / "b.mcap")]
    episodes = list(dataset.iterate_episodes())
    where = list(dataset.storage.get_episode_metadata(range(3)))
    assert [(w["source"], w["run_episode"], w["seed"]) for w in where] == [
        (str(logs / "a.mcap"), 0, 3), (str(logs / "a.mcap"), 1, 4), (str(logs / "b.mcap"), 0, 0)]
    for episode, run, rows in zip(episodes, [runs[0], runs[0], runs[1]],
                                  [np.arange(25), np.arange(25, 50), np.arange(20)]):
        assert np.array_equal(episode.observations[:-1], run.obs[rows])
        assert np.array_equal(episode.observations[-1], run.obs[rows[-1]])  # once more: Minari's T + 1 rows
        assert np.array_equal(episode.actions, run.action[rows])
        assert np.array_equal(episode.rewards, run.reward[rows])
        assert np.array_equal(episode.terminations, run.terminated[rows])
        assert np.array_equal(episode.truncations, run.truncated[rows]) and episode.truncations[-1]
        infos = episode.infos
        assert np.array_equal(infos["true_observation"][:-1], run.true_obs[rows])
        assert np.array_equal(infos["perturbation"][:-1], run.delta[rows])
        assert np.array_equal(infos["expert_action"][:-1], run.expert_action[rows])
        assert infos["logged"].tolist() == [True] * len(rows) + [False]
        assert ("timing" in infos) == (run.timing is not None)
        if run.timing is not None:
            assert np.array_equal(infos["timing"][:-1], run.timing[rows]) and infos["timing"][:, 1].any()
    assert np.abs(episodes[0].infos["perturbation"]).max() > 0
    kept = dataset.storage.metadata["aril_ros"]["runs"]
    assert [(r["source"], r["mode"], r["attack"], r["eps"]) for r in kept] == [
        (str(logs / "a.mcap"), "sensory", "random", 0.1), (str(logs / "b.mcap"), "clean", "none", 0.0)]
    assert kept[0]["files"] == runs[0].metadata["files"] and kept[0]["timing"] == runs[0].metadata["timing"]


@pytest.mark.slow
def test_a_learner_trains_on_the_exported_dataset_as_on_its_logs(logs, tmp_path):
    from aril_ros.dagger import train_learner
    from aril_ros.learner_config import LearnerConfig
    from aril_ros.policy import load_policy

    folder = export(ExportConfig(file=str(logs), out=str(tmp_path / "minari"), name="mine/cheetah-v3"),
                    log=lambda *a, **k: None).parent
    from_logs = load_dagger_dataset([logs / "a.mcap", logs / "b.mcap"])
    from_minari = load_dagger_dataset(folder)
    for field in ("obs", "expert_action", "episode"):
        assert np.array_equal(getattr(from_minari, field), getattr(from_logs, field)), field
    assert len(from_minari) == 70

    def trained(data: str, name: str):
        cfg = LearnerConfig(env="HalfCheetah-v5", rounds=1, episodes=1, epochs=2, data=data,
                            run_dir=str(tmp_path / name), out=str(tmp_path / f"{name}.pt"))
        train_learner(cfg, log=lambda *a, **k: None)
        return load_policy(tmp_path / name / "pi-1.pt").net.state_dict()

    with_logs, with_minari = trained(f"{logs / 'a.mcap'},{logs / 'b.mcap'}", "logs"), trained(str(folder), "minari")
    assert all(np.array_equal(with_logs[k], with_minari[k]) for k in with_logs)
    without = trained("", "none")
    assert not all(np.array_equal(with_logs[k], without[k]) for k in with_logs)  # the given pairs count


def test_what_cannot_be_exported_is_named(tmp_path):
    with pytest.raises(RunLogError, match="holds no run log"):
        export(ExportConfig(file=str(tmp_path)))
    with pytest.raises(RunLogError, match="no run log .*missing.mcap"):
        export(ExportConfig(file=str(tmp_path / "missing.mcap")))
    with pytest.raises(ValueError, match="format:= is one of minari, got 'hdf5'"):
        export(ExportConfig(file=str(tmp_path), format="hdf5"))


@pytest.mark.slow
@pytest.mark.filterwarnings("ignore::UserWarning")  # minari's, for the metadata this dataset leaves unset
def test_a_minari_dataset_not_from_aril_ros_is_refused_as_dagger_data(tmp_path, monkeypatch):
    import gymnasium as gym
    import minari
    from minari.data_collector.episode_buffer import EpisodeBuffer

    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path))
    minari.create_dataset_from_buffers(
        "other/cheetah-v0", [EpisodeBuffer(id=0, observations=np.zeros((3, 17)), actions=np.zeros((2, 6)),
                                           rewards=np.zeros(2), terminations=np.array([False, True]),
                                           truncations=np.zeros(2, bool), infos={})],
        observation_space=gym.spaces.Box(-np.inf, np.inf, (17,)), action_space=gym.spaces.Box(-1, 1, (6,)),
        author="someone", description="not ours", algorithm_name="x", code_permalink="x", author_email="x")
    with pytest.raises(RunLogError, match="without aril_ros's run records .* no expert label"):
        load_dagger_dataset(tmp_path / "other" / "cheetah-v0")
