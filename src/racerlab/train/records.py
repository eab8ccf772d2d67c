"""What a training writes each iteration: the AWS simtrace and TrainingMetrics.json, and metrics.jsonl.

Formats and the folder layout (the one deepracer-utils reads) belong to `racerlab.logs`; this
module turns a rollout and its evaluation episodes into those records and keeps them consistent
with the checkpoints when a training resumes.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from racerlab import logs
from racerlab.sim import STATUS_NAMES
from racerlab.spec import STATUS_LABELS

_STATUS = np.array(STATUS_NAMES, dtype=object)
METRICS_KEEP = 10_000  # TrainingMetrics.json entries kept in the file (rewritten each iteration); older: archive


class TrainingLogs:
    """The logs writer `Trainer` uses by default; the cluster's per-worker logs offer the same methods:
    `write_iteration`, `append_metrics`, `truncate`, `disk_bytes` and `close`."""

    def __init__(self, model_dir: Path, cfg):
        self.model_dir = Path(model_dir)
        self.cfg = cfg
        self.metrics = logs.TrainingMetrics(logs.training_metrics_path(self.model_dir),
                                            best_model_metric=cfg.evaluation.best_model_metric, keep=METRICS_KEEP)
        self.jsonl = logs.MetricsLog(logs.metrics_jsonl_path(self.model_dir))
        logs.export_drfc_metadata(self.model_dir)  # model/ and ip/ copies where deepracer-utils looks
        self.retention = logs.SimtraceRetention(logs.training_simtrace_dir(self.model_dir), cfg.logs.plain_iterations,
                                                int(cfg.logs.max_mb * 1e6))

    # ---- per iteration ---------------------------------------------------------------------------
    def write_iteration(self, iteration: int, ro, evals, first_episode: int) -> None:
        self.metrics.add(metric_entries(ro.episodes, evals, first_episode))
        self.metrics.save()
        self.write_simtrace(iteration, ro)  # after the metrics: the simtrace gets what they leave of logs.max_mb

    def write_simtrace(self, iteration: int, ro, base: Path | None = None) -> None:
        """One iteration's simtrace under `base` (default the model folder; `<model>/<k>` for worker k)."""
        t = ro.trace
        if not t or t["steps"].size == 0:
            return
        n = t["steps"].size
        cols = {
            "episode": t["episode"], "steps": t["steps"], "X": t["X"], "Y": t["Y"], "yaw": t["yaw"],
            "steer": t["steer"], "throttle": t["throttle"], "action": t["actions"], "reward": t["rewards"],
            "done": _episode_ends(t["episode"]), "all_wheels_on_track": t["all_wheels_on_track"],
            "progress": t["progress"], "closest_waypoint": t["closest_waypoint"], "track_len": t["track_len"],
            "tstamp": t["tstamp"], "episode_status": _STATUS[t["codes"]], "pause_duration": np.zeros(n),
            "obstacle_crash_counter": np.zeros(n, int), "wall_clock": t["wall_clock"],
        }
        compress = self.cfg.logs.compress
        path = logs.training_simtrace_path(base or self.model_dir, iteration - 1, compress=compress)
        writer = logs.SimtraceWriter(path, compress=compress, sample_episodes=self.cfg.logs.simtrace_every)
        writer.write(cols)
        self.retention.added(iteration - 1, writer.close())
        self.retention.enforce(reserve=self._metrics_bytes())

    def append_metrics(self, entry: dict) -> None:
        self.jsonl.append(entry)

    # ---- resume ----------------------------------------------------------------------------------
    def truncate(self, iteration: int, episodes: int) -> None:
        """Forget what was logged after the checkpoint a training resumes from."""
        logs.remove_training_simtrace_after(self.model_dir, iteration - 1)
        self.metrics.truncate(episodes)
        self.metrics.save()
        self.jsonl.truncate(iteration)
        self.retention.rescan()
        self.retention.enforce(reserve=self._metrics_bytes())  # a budget lowered since the last run applies now

    def _metrics_bytes(self) -> int:
        """metrics/ (TrainingMetrics.json, its archive, metrics.jsonl): inside logs.max_mb with the simtrace."""
        return logs.disk_bytes(logs.training_metrics_path(self.model_dir).parent)

    def disk_bytes(self) -> int:
        return sum(logs.disk_bytes(p) for p in (logs.training_simtrace_dir(self.model_dir),
                                                logs.training_metrics_path(self.model_dir).parent))

    def close(self) -> None:
        self.jsonl.close()


def metric_entries(episodes, evals, first_episode: int) -> list[dict]:
    """TrainingMetrics.json entries of an iteration's training episodes (numbered on from `first_episode`) and
    of its evaluation episodes after them (each numbered `first_episode + len(episodes)`)."""
    out = [metric_entry(ep, first_episode + n + 1, n, "training") for n, ep in enumerate(episodes)]
    return out + [metric_entry(e, first_episode + len(episodes), n, "evaluation") for n, e in enumerate(evals)]


def metric_entry(ep, episode: int, trial: int, phase: str) -> dict:
    """One TrainingMetrics.json entry for an episode (`Episode` or an evaluation episode)."""
    return {"reward_score": int(round(ep.reward)), "metric_time": int(round(ep.end_time * 1000)),
            "start_time": int(round(ep.start_time * 1000)),
            "elapsed_time_in_milliseconds": int(round((ep.end_time - ep.start_time) * 1000)),
            "episode": episode, "trial": trial + 1, "phase": phase,
            "completion_percentage": int(min(ep.progress, 100.0)),
            "episode_status": STATUS_LABELS.get(ep.status, ep.status)}


def _episode_ends(episode: np.ndarray) -> np.ndarray:
    """True on each episode's last row (rows are grouped by episode, in step order)."""
    return np.append(episode[1:] != episode[:-1], True) if episode.size else np.zeros(0, bool)
