"""Training: the iteration loop (`Trainer`, composed of a run's parts, `train.parts`, and its seams, `train.seams`:
the collection, the logs, the learner), `train` (which trainer a model gets: `train.recipes`), a taught model's
DAgger parts (`train.distill`), the worlds it drives (`train.worlds`, for anyone who trains, the cluster's workers
included), the run's health (`train.health`), its records and progress."""

from racerlab.train.health import TrainingDiverged
from racerlab.train.loop import AgentLearner, Trainer, TrainResult
from racerlab.train.parts import RunParts, apply_overrides, assemble, trainer_parts
from racerlab.train.recipes import train
from racerlab.train.records import TrainingLogs, metric_entries
from racerlab.train.seams import Collection, IterationLogs, Learner
from racerlab.train.worlds import LocalCollection, WorldBuilder

__all__ = ["AgentLearner", "Collection", "IterationLogs", "Learner", "LocalCollection", "RunParts", "TrainResult",
           "Trainer", "TrainingDiverged", "TrainingLogs", "WorldBuilder", "apply_overrides", "assemble",
           "metric_entries", "train", "trainer_parts"]
