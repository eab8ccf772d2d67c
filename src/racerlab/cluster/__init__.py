"""Beyond one machine: rollout workers and sweeps on a Ray cluster (`pip install racerlab[cluster]`).

Nothing here is imported by `racerlab train` without `--workers`, so Ray stays optional.
"""

from racerlab.cluster.collector import RayCollector, merge_rollouts, split_episodes
from racerlab.cluster.training import ClusterCollection, ClusterTraining, WorkerLogs, train_on_cluster
from racerlab.cluster.worker import RolloutWorker

__all__ = ["ClusterCollection", "ClusterTraining", "RayCollector", "RolloutWorker", "WorkerLogs", "merge_rollouts",
           "split_episodes", "train_on_cluster"]
