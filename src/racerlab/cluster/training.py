"""`racerlab train MODEL --workers N`: the trainer with its collection spread over Ray actors.

The learner (PPO or SAC update, in-training evaluation, checkpoints, racerlab's metrics.jsonl) stays
on the driver, exactly as on one machine; only collection moves to the workers. The logs follow
DRfC's multi-worker layout, which deepracer-utils reads: worker k's simtrace goes to
`<model>/<k>/training-simtrace/<n>-iteration.csv` and its episodes to `metrics/TrainingMetrics_<k>.json`
(`TrainingMetrics.json` for worker 0, which also holds the evaluation episodes), each worker counting
its own episodes from 0.
"""

from __future__ import annotations

from pathlib import Path

from racerlab import logs
from racerlab.cluster.collector import RayCollector
from racerlab.train.loop import Trainer
from racerlab.train.records import TrainingLogs


class WorkerLogs(TrainingLogs):
    """`TrainingLogs` with one simtrace folder and one TrainingMetrics file per worker."""

    def __init__(self, model_dir: Path, cfg, workers: int):
        super().__init__(model_dir, cfg)
        self.workers = workers
        self.worker_metrics = [self.metrics] + [
            logs.TrainingMetrics(logs.training_metrics_path(self.model_dir, k),
                                 best_model_metric=cfg.evaluation.best_model_metric) for k in range(1, workers)]
        self.resume_counts: list[int] = []

    def write_iteration(self, iteration: int, ro, evals, first_episode: int) -> None:
        for k, part, first in ro.parts:
            self._simtrace(iteration, part, base=self.model_dir / str(k))
            entries = [self._train_entry(ep, first + n, n) for n, ep in enumerate(part.episodes)]
            if k == 0:
                entries += [self._eval_entry(e, first + len(part.episodes), n) for n, e in enumerate(evals)]
            self.worker_metrics[k].add(entries)
        for m in self.worker_metrics:
            m.save()

    def truncate(self, iteration: int, episodes: int) -> None:
        super().truncate(iteration, episodes)
        for k in range(self.workers):
            logs.remove_training_simtrace_after(self.model_dir / str(k), iteration - 1)
            done = self.resume_counts[k] if k < len(self.resume_counts) else 0
            self.worker_metrics[k].truncate(done)
            self.worker_metrics[k].save()

    def disk_bytes(self) -> int:
        return super().disk_bytes() + sum(logs.disk_bytes(logs.training_simtrace_dir(self.model_dir / str(k)))
                                          for k in range(self.workers))


class ClusterTrainer(Trainer):
    """A `Trainer` whose episodes come from `workers` Ray actors (a local Ray, or the cluster at `address`)."""

    def __init__(self, model_dir, workers: int, address: str | None = None, progress: bool = True,
                 stop_at_first_lap: bool = False, **overrides):
        super().__init__(model_dir, progress=progress, stop_at_first_lap=stop_at_first_lap, **overrides)
        self.collector = RayCollector(self.folder.path, workers, overrides, address, note=self.progress.note)
        self.logs = WorkerLogs(self.folder.path, self.cfg, workers)
        self.failures: list[dict] = []

    def _newest_readable(self, cps):
        info, ck = super()._newest_readable(cps)
        counts = ck.get("worker_episodes") or []
        self.logs.resume_counts = counts
        self.collector.episodes[: len(counts)] = counts[: self.collector.n]
        for k, starts in enumerate((ck.get("worker_starts") or [])[: self.collector.n]):
            self.collector.starts[k] = starts
            self.collector.actors[k].set_starts.remote(starts)
        return info, ck

    def _redraw_if_due(self):
        """Generated tracks are drawn once per worker (its own seed); they are not redrawn during the run."""

    def _checkpoint_state(self) -> dict:
        state = super()._checkpoint_state()
        state["worker_episodes"] = list(self.collector.episodes)
        state["worker_starts"] = [list(s) for s in self.collector.starts]
        return state

    def _summary(self, ro, evals, metrics, learn_s, value) -> dict:
        entry = super()._summary(ro, evals, metrics, learn_s, value)
        rep = self.collector.report
        if rep.failed:
            self.failures.append({"iteration": self.state.iteration, "workers": sorted(rep.failed)})
        entry.update({"cluster/workers": len(rep.finished), "cluster/failed_workers": len(rep.failed),
                      "cluster/weights_bytes": rep.weights_bytes,
                      "cluster/rollout_bytes": sum(rep.rollout_bytes.values())})
        return entry

    def run(self):
        try:
            return super().run()
        finally:
            self.collector.close()


def train_on_cluster(model_dir, workers: int, address: str | None = None, *, progress: bool = True,
                     **overrides):
    """Train `model_dir` with `workers` Ray rollout workers (resuming as `racerlab.train.train` does)."""
    return ClusterTrainer(model_dir, workers, address, progress=progress, **overrides).run()
