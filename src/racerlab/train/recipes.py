"""`train(model_dir)`: which trainer a model folder gets. The agent learning alone (`Trainer` with its defaults:
PPO or SAC), or, with a teacher (`[teacher] model` in training.toml or one given for the run), a student taught
by a features teacher (`train.distill.taught_trainer`: DAgger). Both are the same `Trainer`, composed of other
parts."""

from __future__ import annotations

from racerlab.model import ModelFolder
from racerlab.train.distill import taught_trainer
from racerlab.train.loop import Trainer, TrainResult


def train(model_dir, *, progress: bool = True, stop_at_first_lap: bool = False, teacher=None,
          **overrides) -> TrainResult:
    """Train the model in `model_dir` (resuming if it has checkpoints). Keyword overrides: minutes,
    episodes, iterations, num_cars, device, seed, tracks. With a teacher (`teacher`, a features model's folder, or
    training.toml's `[teacher] model`) the iterations are DAgger rounds from it (`racerlab.train.distill`)."""
    if teacher is not None or ModelFolder(model_dir).config().teacher.model:
        return taught_trainer(model_dir, teacher=teacher, progress=progress, stop_at_first_lap=stop_at_first_lap,
                              **overrides).run()
    return Trainer(model_dir, progress=progress, stop_at_first_lap=stop_at_first_lap, **overrides).run()
