"""The model-folder names (and one car constant) the console uses, imported in one place.

Issue 12 moves these modules to `racerlab.model` (same class and function names), and
MODEL_POINT_AHEAD_M to `racerlab.spec`; re-point the imports
here and nothing else in the console changes.
"""

from racerlab.hyperparameters import Hyperparameters, parse_hyperparameters
from racerlab.metadata import parse_model_metadata
from racerlab.sim.car import MODEL_POINT_AHEAD_M
from racerlab.train.clone import clone_model
from racerlab.train.config import TrainingConfig
from racerlab.train.folder import ModelFolder
from racerlab.train.init import SENSORS, init_model, make_metadata

__all__ = ["MODEL_POINT_AHEAD_M", "SENSORS", "Hyperparameters", "ModelFolder", "TrainingConfig", "clone_model",
           "init_model", "make_metadata", "parse_hyperparameters", "parse_model_metadata"]
