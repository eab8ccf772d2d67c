"""A model folder: the only place that knows its layout and reads, validates and writes its files.

    my-model/
      reward_function.py        the racer's reward (AWS)                       `racerlab.reward`
      model_metadata.json       action space, sensors, network, algorithm (AWS) `model.metadata`
      hyperparameters.json      training hyperparameters (AWS, optional)       `model.hyperparameters`
      training.toml             racerlab's run settings: tracks, cars, stop... `model.config`
      checkpoints/              <N>_Step-<S>.pt, deepracer_checkpoints.json   `model.checkpoint`
      lineage.json              the parent of a cloned model                  `model.clone`

`ModelFolder` gives the paths and the parsed files, and `ModelFolder.open(checkpoint)` the one way every reader
opens a trained model (`OpenModel`; a checkpoint it must not use is refused with `errors.ModelRefused`);
`resolve_track` says which track a model drives;
`init_model` and `clone_model` create folders. The logs written beside these files are `racerlab.logs`'s.
"""

from racerlab.model.checkpoint import CheckpointInfo, TrainingState, nonfinite_tensors
from racerlab.model.clone import check_compatible, clone_model
from racerlab.model.config import TrainingConfig, load_training_config, parse_training_config
from racerlab.model.folder import ModelFolder, resolve_track
from racerlab.model.hyperparameters import Hyperparameters, load_hyperparameters, parse_hyperparameters
from racerlab.model.init import init_model, make_metadata
from racerlab.model.metadata import (
    DEFAULT_CONTINUOUS,
    ContinuousActions,
    DiscreteActions,
    ModelMetadata,
    as_model_metadata,
    default_discrete_actions,
    load_model_metadata,
    parse_model_metadata,
    read_json_file,
)
from racerlab.model.opened import OpenModel

__all__ = [
    "DEFAULT_CONTINUOUS", "CheckpointInfo", "ContinuousActions", "DiscreteActions", "Hyperparameters", "ModelFolder",
    "ModelMetadata", "OpenModel", "TrainingConfig", "TrainingState", "as_model_metadata", "check_compatible",
    "clone_model", "default_discrete_actions", "init_model", "load_hyperparameters", "load_model_metadata",
    "load_training_config", "make_metadata", "nonfinite_tensors", "parse_hyperparameters", "parse_model_metadata",
    "parse_training_config", "read_json_file", "resolve_track",
]
