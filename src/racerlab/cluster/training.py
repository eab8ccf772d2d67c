"""`racerlab train MODEL --workers N`: the trainer with its collection spread over Ray actors.

The learner (PPO or SAC update, in-training evaluation, checkpoints, racerlab's metrics.jsonl) stays
on the driver, exactly as on one machine; only collection moves to the workers. `Trainer` is given the
Ray collection and the per-worker logs; the driver builds no training worlds of its own. The logs follow
DRfC's multi-worker layout, which deepracer-utils reads: worker k's simtrace goes to
`<model>/<k>/training-simtrace/<n>-iteration.csv` and its episodes to `metrics/TrainingMetrics_<k>.json`
(`TrainingMetrics.json` for worker 0, which also holds the evaluation episodes), each worker counting
its own episodes from 0.
"""

from __future__ import annotations

from pathlib import Path

from racerlab import logs
from racerlab.cluster.collector import RayCollector
from racerlab.model import ModelFolder
from racerlab.train import Trainer, TrainingLogs, WorldBuilder, apply_overrides, metric_entries


class ClusterCollection(RayCollector):
    """The Ray collector with what `Trainer` asks of a collection: the workers' episode counts and round-robin
    starts in the checkpoint (`worker_episodes`, `worker_starts`), and the cluster's metrics.jsonl keys."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.failures: list[dict] = []  # {"iteration", "workers"} of each iteration a worker died in

    def before_iteration(self, iteration: int) -> None:
        """Generated tracks are drawn once per worker (its own seed); they are not redrawn during the run."""

    def state(self) -> dict:
        return {"worker_episodes": list(self.episodes), "worker_starts": [list(s) for s in self.starts]}

    def restore(self, saved: dict) -> None:
        counts = saved.get("worker_episodes") or []
        self.episodes[: len(counts)] = counts[: self.n]
        for k, starts in enumerate((saved.get("worker_starts") or [])[: self.n]):
            self.starts[k] = starts
            self.actors[k].set_starts.remote(starts)

    def metrics(self, iteration: int) -> dict:
        rep = self.report
        if rep.failed:
            self.failures.append({"iteration": iteration, "workers": sorted(rep.failed)})
        return {"cluster/workers": len(rep.finished), "cluster/failed_workers": len(rep.failed),
                "cluster/weights_bytes": rep.weights_bytes, "cluster/rollout_bytes": sum(rep.rollout_bytes.values())}


class WorkerLogs:
    """The training logs with one simtrace folder and one TrainingMetrics file per worker (worker 0's are the
    model folder's own `TrainingLogs`, which also keeps metrics.jsonl)."""

    def __init__(self, model_dir: Path, cfg, collection: ClusterCollection):
        self.main = TrainingLogs(model_dir, cfg)
        self.model_dir = Path(model_dir)
        self.collection = collection
        self.workers = collection.n
        self.worker_metrics = [self.main.metrics] + [
            logs.TrainingMetrics(logs.training_metrics_path(self.model_dir, k),
                                 best_model_metric=cfg.evaluation.best_model_metric) for k in range(1, self.workers)]

    def write_iteration(self, iteration: int, ro, evals, first_episode: int) -> None:
        for k, part, first in ro.parts:
            self.main.write_simtrace(iteration, part, base=self.model_dir / str(k))
            self.worker_metrics[k].add(metric_entries(part.episodes, evals if k == 0 else [], first))
        for m in self.worker_metrics:
            m.save()

    def append_metrics(self, entry: dict) -> None:
        self.main.append_metrics(entry)

    def truncate(self, iteration: int, episodes: int) -> None:
        """After the collection is restored: each worker's metrics keep the episodes the checkpoint counted."""
        self.main.truncate(iteration, episodes)
        for k in range(self.workers):
            logs.remove_training_simtrace_after(self.model_dir / str(k), iteration - 1)
            self.worker_metrics[k].truncate(self.collection.episodes[k])
            self.worker_metrics[k].save()

    def disk_bytes(self) -> int:
        return self.main.disk_bytes() + sum(logs.disk_bytes(logs.training_simtrace_dir(self.model_dir / str(k)))
                                            for k in range(self.workers))

    def close(self) -> None:
        self.main.close()


class ClusterTraining:
    """A `Trainer` whose episodes come from `workers` Ray actors (a local Ray, or the cluster at `address`)."""

    def __init__(self, model_dir, workers: int, address: str | None = None, progress: bool = True,
                 stop_at_first_lap: bool = False, **overrides):
        folder = ModelFolder(model_dir)
        folder.require()
        cfg = apply_overrides(folder.config(), **overrides)
        WorldBuilder(cfg, None, None, track_flag=bool(overrides.get("tracks"))).check_tracks()  # before Ray starts
        self.trainer: Trainer | None = None
        self.collector = ClusterCollection(folder.path, workers, overrides, address, note=self._note)
        try:
            self.logs = WorkerLogs(folder.path, cfg, self.collector)
            self.trainer = Trainer(model_dir, progress=progress, stop_at_first_lap=stop_at_first_lap,
                                   collector=self.collector, logs=self.logs, **overrides)
        except BaseException:
            self.collector.close()
            raise

    def _note(self, text: str) -> None:
        if self.trainer is not None:
            self.trainer.note(text)
        else:
            print(text, flush=True)

    @property
    def failures(self) -> list[dict]:
        return self.collector.failures

    def run(self):
        return self.trainer.run()  # closes the collection when it ends


def train_on_cluster(model_dir, workers: int, address: str | None = None, *, progress: bool = True,
                     **overrides):
    """Train `model_dir` with `workers` Ray rollout workers (resuming as `racerlab.train.train` does)."""
    return ClusterTraining(model_dir, workers, address, progress=progress, **overrides).run()
