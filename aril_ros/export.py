"""``aril export``: run logs into the dataset formats other tools read, and those datasets back into a DAgger data
set.

Minari (gymnasium's offline-data standard; the ``minari`` package itself, the ``export`` extra, installed on first
use). One dataset from one log or a folder of them (every ``*.mcap`` in it, in name order; all of one env), written at
``<out>/<name>/data`` where ``minari.load_dataset(name)`` finds it with ``MINARI_DATASETS_PATH=<out>``. Per episode of a
log (its completed episodes, in order):

- ``observations``: what the policy saw at each step (the attacked observation under a sensory attack), then once more
  the last one: Minari keeps one observation more than steps, and a log holds none after its last step (the
  ``logged`` info says which rows are the log's);
- ``actions``: the policy's action at each step; ``rewards``, ``terminations``, ``truncations``;
- ``infos`` (rows like ``observations``): ``true_observation`` (the state the expert labels), ``perturbation``,
  ``expert_action`` (the DAgger label), ``logged`` and, under a timing attack, ``timing`` (the age of the observation
  seen, whether it was dropped, the age of the action applied; :data:`aril_ros.protocol.TIMING_NAMES`);
- episode metadata: ``source`` (the log), ``run_episode`` (its episode there) and ``seed`` (its env seed).

The dataset's metadata keeps, under ``aril_ros``, each log's run record as the log has it (env, mode, attack, eps,
attack settings, the files that acted with their digests, the policy's and expert's provenance) and its path.
:func:`minari_pairs` reads such a dataset back into the pairs of its logs, exactly
(:func:`aril_ros.dataset.load_dagger_dataset` takes either).
"""
from __future__ import annotations

import contextlib
import os
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .args import arg
from .extras import MINARI, ensure
from .envs import layout_of
from .runlog import RunLog, RunLogError, read_run
from .step import episode_seed

FORMATS = ("minari",)
"""What ``aril export`` writes."""
KEY = "aril_ros"
"""The dataset metadata key holding the runs' records."""


@dataclass
class ExportConfig:
    """Arguments of ``aril export``."""

    file: str = arg("", "a run log (.mcap) or a folder of them (every *.mcap in it, in name order; one env)")
    format: str = arg("minari", f"one of {', '.join(FORMATS)}")
    out: str = arg("exports", "the datasets' root folder: minari writes <out>/<name>/data (MINARI_DATASETS_PATH=<out> "
                              "makes minari.load_dataset(name) find it)")
    name: str = arg("", "the dataset's id: [namespace/]name-v<N> (default: aril_ros/<env>-<mode>-v0)")
    allow_interrupted: bool = arg(False, "take a log cut short or interrupted (its completed episodes)")


def export(cfg: ExportConfig, log=print) -> Path:
    """Write the dataset ``cfg`` asks for; returns its folder."""
    if cfg.format not in FORMATS:
        raise ValueError(f"format:= is one of {', '.join(FORMATS)}, got {cfg.format!r}")
    paths = log_files(cfg.file)
    runs = [read_run(path, cfg.allow_interrupted) for path in paths]
    envs = sorted({run.metadata["env"] for run in runs})
    if len(envs) > 1:
        raise RunLogError(f"run logs of different envs cannot make one dataset: {envs} (export them apart)")
    modes = sorted({run.metadata["mode"] for run in runs})
    name = cfg.name or f"aril_ros/{envs[0]}-{'-'.join(modes)}-v0"
    folder = write_minari(runs, paths, name, Path(cfg.out))
    steps = sum(len(run.tags) for run in runs)
    log(f"[export] {len(paths)} log(s), {steps} steps -> Minari dataset {name} at {folder} (read it with "
        f"MINARI_DATASETS_PATH={cfg.out} and minari.load_dataset({name!r}))", flush=True)
    return folder


def log_files(file: str) -> list[Path]:
    """The logs ``file`` names: itself, or every ``*.mcap`` of a folder in name order."""
    if not file:
        raise ValueError("file:= names a run log or a folder of them")
    path = Path(file)
    if path.is_dir():
        found = sorted(path.glob("*.mcap"))
        if not found:
            raise RunLogError(f"{path} holds no run log (*.mcap)")
        return found
    if not path.is_file():
        raise RunLogError(f"no run log {path}")
    return [path]


def episodes_of(run: RunLog) -> list[np.ndarray]:
    """The row indices of each completed episode of ``run``, in order (a cut-short run's last may be incomplete)."""
    episodes = run.episodes
    done = run.terminated | run.truncated
    found = []
    for episode in dict.fromkeys(episodes.tolist()):
        rows = np.flatnonzero(episodes == episode)
        if done[rows[-1]]:
            found.append(rows)
    return found


def once_more(rows: np.ndarray) -> np.ndarray:
    """``rows`` with its last row repeated: Minari keeps one observation (and info) more than steps."""
    return np.concatenate([rows, rows[-1:]])


def write_minari(runs: list[RunLog], paths: list[Path], name: str, out: Path) -> Path:
    """The Minari dataset ``name`` under ``out`` from ``runs`` (read from ``paths``); returns its data folder."""
    minari = ensure("minari", MINARI, "the export extra, for Minari datasets")
    from gymnasium.spaces import Box
    from minari.data_collector.episode_buffer import EpisodeBuffer

    layout = layout_of(runs[0].metadata["env"])
    buffers, episode_metadata = [], []
    for path, run in zip(paths, runs):
        for rows in episodes_of(run):
            infos = {"true_observation": once_more(run.true_obs[rows]), "perturbation": once_more(run.delta[rows]),
                     "expert_action": once_more(run.expert_action[rows]),
                     "logged": np.r_[np.ones(len(rows), bool), False]}
            if run.timing is not None:
                infos["timing"] = once_more(run.timing[rows])
            episode = int(run.episodes[rows[0]])
            buffers.append(EpisodeBuffer(
                id=len(buffers), seed=episode_seed(run.metadata["seed"], episode),
                observations=once_more(run.obs[rows]), actions=run.action[rows], rewards=run.reward[rows],
                terminations=run.terminated[rows], truncations=run.truncated[rows], infos=infos))
            episode_metadata.append({"source": str(path), "run_episode": episode})
    if not buffers:
        raise RunLogError(f"no completed episode in {', '.join(map(str, paths))}")
    with _datasets_root(out), warnings.catch_warnings():
        warnings.simplefilter("ignore")  # minari warns for each metadata field left unset (a code permalink, ...)
        try:
            dataset = minari.create_dataset_from_buffers(
                name, buffers, observation_space=Box(-np.inf, np.inf, (layout.obs_dim,), np.float64),
                action_space=Box(np.array(layout.action_low), np.array(layout.action_high), dtype=np.float64),
                algorithm_name=f"aril_ros run logs ({', '.join(sorted({r.metadata['mode'] for r in runs}))})",
                author="aril_ros", description="Episodes of aril_ros graph runs (run_graph.py), exported from their "
                                               "logs by aril export: the observation the policy saw, its action, and "
                                               "as infos the true state, the perturbation and the expert's label.",
                data_format="hdf5")
        except ValueError as err:  # an id that exists already, or one not of the form [namespace/]name-vN
            raise ValueError(f"name:={name}: {err}") from None
    dataset.storage.update_metadata({KEY: {"runs": [{"source": str(path), **run.metadata}
                                                    for path, run in zip(paths, runs)]}})
    dataset.storage.update_episode_metadata(episode_metadata, episode_indices=range(len(buffers)))
    return Path(dataset.storage.data_path)


@contextlib.contextmanager
def _datasets_root(out: Path):
    """Minari finds its datasets under ``MINARI_DATASETS_PATH``, read at each call: ``out`` for the block."""
    before = os.environ.get("MINARI_DATASETS_PATH")
    os.environ["MINARI_DATASETS_PATH"] = str(out.resolve())
    try:
        yield
    finally:
        if before is None:
            del os.environ["MINARI_DATASETS_PATH"]
        else:
            os.environ["MINARI_DATASETS_PATH"] = before


def minari_data(path: str | Path) -> Path | None:
    """The ``data`` folder of the Minari dataset ``path`` names (its folder, holding ``data/``, or that ``data``
    folder itself); None when ``path`` is no Minari dataset."""
    path = Path(path)
    return next((data for data in (path / "data", path) if (data / "metadata.json").is_file()), None)


def minari_pairs(path: str | Path) -> tuple[dict[str, np.ndarray | list], str]:
    """The (observation seen, expert action) pairs of a Minari dataset ``aril export`` wrote, as the fields of
    :class:`aril_ros.dataset.DaggerDataset` (``obs``, ``expert_action``, ``episode``: each pair's episode in its
    log, ``source``: the dataset and that log), and the dataset's env."""
    minari = ensure("minari", MINARI, "the export extra, for Minari datasets")
    path = Path(path)
    data = minari_data(path)
    if data is None:
        raise RunLogError(f"{path} is no Minari dataset (no metadata.json in it or in its data folder)")
    dataset = minari.MinariDataset(str(data))
    runs = dataset.storage.metadata.get(KEY, {}).get("runs")
    if not runs:
        raise RunLogError(f"{path} is a Minari dataset without aril_ros's run records (written by aril export): its "
                          "episodes have no expert label to learn from")
    metadata = list(dataset.storage.get_episode_metadata(range(dataset.total_episodes)))
    obs, expert_action, episodes, source = [], [], [], []
    for episode, where in zip(dataset.iterate_episodes(), metadata):
        logged = episode.infos["logged"].astype(bool)
        steps = int(logged.sum())
        obs.append(episode.observations[logged])
        expert_action.append(episode.infos["expert_action"][logged])
        episodes.append(np.full(steps, int(where["run_episode"])))
        source += [f"{path}:{where['source']}"] * steps
    return {"obs": np.concatenate(obs), "expert_action": np.concatenate(expert_action),
            "episode": np.concatenate(episodes), "source": source}, runs[0]["env"]
