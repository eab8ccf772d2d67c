"""The one door to a trained model: `ModelFolder.open(checkpoint)` and `OpenModel`, what it lets through.

Every reader of a model's weights opens it here: evaluation and races, every export (car, ONNX, TFLite, DRoA, DRfC,
S3), import's check of the folder it wrote, clone, the camera model's teacher, the console (through those) and
resume. The door resolves the checkpoint (best, last, an iteration number or a `CheckpointInfo`), loads it without
running anything in it (`ModelFolder.load_checkpoint`: weights_only) and refuses, with `errors.ModelRefused` and one
wording per cause, a checkpoint that
- cannot be read (damaged, not racerlab's, another format, more than data in it): reason `UNREADABLE`;
- holds NaN or infinite weights (the training diverged there): `NONFINITE`;
- was trained with a model_metadata.json whose weights cannot carry over to the folder's (`ModelMetadata.differences`:
  action space type, number of actions, sensors, network, algorithm): `METADATA`.
From an open model's state to greedy actions or the bare networks is `racerlab.agent.inference_policy`, which refuses
weights that do not fit the network with the same exception (`NETWORK`).

The folder's model_metadata.json is read when it opens; hyperparameters.json and training.toml when a reader first
asks for them (an export to the car needs neither), each with its file's own one-line error.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING

from racerlab.errors import ConfigError, ModelRefused
from racerlab.model.checkpoint import CheckpointInfo, TrainingState, nonfinite_tensors
from racerlab.model.metadata import ModelMetadata, parse_model_metadata

if TYPE_CHECKING:  # folder.py imports this module to give ModelFolder its `open`
    from racerlab.model.config import TrainingConfig
    from racerlab.model.folder import ModelFolder
    from racerlab.model.hyperparameters import Hyperparameters


@dataclass(frozen=True, eq=False)
class OpenModel:
    """A model folder opened at one checkpoint that passed the door's checks."""

    folder: ModelFolder
    metadata: ModelMetadata  # the folder's model_metadata.json (the checkpoint's own is compatible with it)
    checkpoint: CheckpointInfo
    state: TrainingState  # the checkpoint's contents; `state.agent` holds the weights

    @property
    def name(self) -> str:
        """The model's name: its folder's."""
        return self.folder.path.resolve().name

    @property
    def path(self) -> Path:
        """The checkpoint file."""
        return self.folder.checkpoint_path(self.checkpoint)

    @cached_property
    def hyperparameters(self) -> Hyperparameters:
        """hyperparameters.json (racerlab's defaults without one), read on first use."""
        return self.folder.hyperparameters()

    @cached_property
    def config(self) -> TrainingConfig:
        """training.toml (the defaults without one), read on first use."""
        return self.folder.config()

    @property
    def observation(self) -> str:
        """training.toml's run.observation: the inputs the network was built for ("" for the sensors' own)."""
        return self.config.run.observation

    @property
    def look(self) -> str:
        """training.toml's run.look: the world the camera sees."""
        return self.config.run.look


def open_model(folder: ModelFolder, which: str | int | CheckpointInfo = "best") -> OpenModel:
    """`ModelFolder.open`'s body (the module docstring)."""
    folder.require()
    metadata = folder.metadata()
    info = folder.resolve_checkpoint(which)
    state = folder.load_state(info)
    check_finite(folder, info, state)
    check_metadata(folder, info, state, metadata)
    return OpenModel(folder, metadata, info, state)


def check_finite(folder: ModelFolder, info: CheckpointInfo, state: TrainingState) -> None:
    """Refuse a checkpoint with NaN or infinite weights (or optimiser moments), naming the first of them."""
    bad = nonfinite_tensors(state.agent)
    if bad:
        more = f" and {len(bad) - 1} more" if len(bad) > 1 else ""
        raise ModelRefused(folder.checkpoint_path(info), ModelRefused.NONFINITE, f"non-finite weights ({bad[0]}{more})",
                           f"the training diverged there: {folder.instead_of(info)}")


def check_metadata(folder: ModelFolder, info: CheckpointInfo, state: TrainingState, metadata: ModelMetadata) -> None:
    """Refuse a checkpoint whose stored model_metadata.json cannot carry its weights over to the folder's. A checkpoint
    that stores none (an older racerlab's) is taken as trained with the folder's."""
    if state.metadata is None:
        return
    where = folder.checkpoint_path(info)
    try:
        trained = parse_model_metadata(state.metadata, "the model_metadata.json stored in it")
    except ConfigError as exc:
        raise ModelRefused(where, ModelRefused.UNREADABLE, f"{exc}", "it is damaged: train it again") from None
    diffs = trained.differences(metadata)
    if diffs:
        raise ModelRefused(where, ModelRefused.METADATA, f"does not match {folder.metadata_path} (trained → now): "
                           f"{'; '.join(diffs)}", "restore the model_metadata.json it was trained with or train again")
