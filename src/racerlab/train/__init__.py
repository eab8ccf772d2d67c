"""Training: the iteration loop (`Trainer`, `train`), the worlds it drives (`train.worlds`, for anyone who
trains, the cluster's workers included), the run's health (`train.health`), its records and progress."""

from racerlab.train.health import TrainingDiverged
from racerlab.train.loop import Trainer, TrainResult, apply_overrides, train
from racerlab.train.records import TrainingLogs, metric_entries
from racerlab.train.seams import Collection, IterationLogs
from racerlab.train.worlds import LocalCollection, WorldBuilder

__all__ = ["Collection", "IterationLogs", "LocalCollection", "TrainResult", "Trainer", "TrainingDiverged",
           "TrainingLogs", "WorldBuilder", "apply_overrides", "metric_entries", "train"]
