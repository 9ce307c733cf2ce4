"""The DAgger dataset: (observation the policy saw, expert action on the true state) pairs.

One format whatever the source: in-process rollouts (:meth:`DaggerDataset.from_trajectories`), run logs recorded
through the ROS graph, or Minari datasets exported from them (:func:`load_dagger_dataset`).
Aggregation (DAgger's data set union) is :meth:`DaggerDataset.concatenate`, in the order given.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .export import minari_data, minari_pairs
from .runlog import RunLog, RunLogError, read_run


@dataclass
class DaggerDataset:
    obs: np.ndarray
    """[n, obs_dim] what the policy saw (the attacked observation under a sensory attack)"""
    expert_action: np.ndarray
    """[n, act_dim] the expert's action on the true state"""
    episode: np.ndarray
    """[n] the episode each pair came from"""
    source: list[str]
    """[n] where each pair came from: a run log's path, or ``inprocess:seed=<seed>``"""

    def __len__(self) -> int:
        return len(self.obs)

    @classmethod
    def from_trajectories(cls, traj) -> "DaggerDataset":
        """The steps of an engine rollout (:class:`aril_ros.rollout.Trajectories`), episode by episode."""
        steps = traj.step_mask
        episode = np.broadcast_to(np.arange(len(traj.length))[:, None], steps.shape)[steps]
        return cls(obs=traj.obs[steps], expert_action=traj.expert_action[steps], episode=episode,
                   source=[f"inprocess:seed={traj.seed}"] * int(steps.sum()))

    @classmethod
    def concatenate(cls, parts: list["DaggerDataset"]) -> "DaggerDataset":
        return cls(obs=np.concatenate([p.obs for p in parts]),
                   expert_action=np.concatenate([p.expert_action for p in parts]),
                   episode=np.concatenate([p.episode for p in parts]),
                   source=[s for p in parts for s in p.source])


def load_dagger_dataset(paths, env_id: str | None = None, allow_interrupted: bool = False) -> DaggerDataset:
    """Aggregate one or many run logs or Minari datasets ``aril export`` made of them (:func:`aril_ros.export.
    minari_pairs`; a dataset gives exactly the pairs of its logs), in the order given; all must be of the same env."""
    paths = [paths] if isinstance(paths, (str, Path)) else list(paths)
    if not paths:
        raise RunLogError("no run logs given")
    parts, envs = [], set()
    for path in paths:
        if minari_data(path) is not None:
            fields, env = minari_pairs(path)
            part = DaggerDataset(**fields)
        else:
            run = read_run(path, allow_interrupted)
            part, env = dataset_of_run(run, path), run.metadata["env"]
        parts.append(part)
        envs.add(env)
    if env_id is not None:
        envs.add(env_id)
    if len(envs) > 1:
        raise RunLogError(f"run logs of different envs cannot make one dataset: {sorted(envs)}")
    return DaggerDataset.concatenate(parts)


def dataset_of_run(run: RunLog, path) -> DaggerDataset:
    """The (observation seen, expert action) pairs of one run log already read from ``path``."""
    return DaggerDataset(obs=run.obs, expert_action=run.expert_action, episode=run.episodes,
                         source=[str(path)] * len(run.tags))
