"""Training: model folders, the iteration loop, checkpoints, resume and clone, NaN guard, progress."""

from racerlab.train.loop import Trainer, TrainingDiverged, TrainResult, train

__all__ = ["TrainResult", "Trainer", "TrainingDiverged", "train"]
