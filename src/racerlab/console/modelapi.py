"""The model-folder names (and one car constant) the console uses, imported in one place.

If the model folder's public names move, re-point the imports here and nothing else in the
console changes.
"""

from racerlab.model import ModelFolder, TrainingConfig, clone_model, init_model, make_metadata
from racerlab.model.hyperparameters import Hyperparameters, parse_hyperparameters
from racerlab.model.init import SENSORS
from racerlab.model.metadata import parse_model_metadata
from racerlab.spec import MODEL_POINT_AHEAD_M

__all__ = ["MODEL_POINT_AHEAD_M", "SENSORS", "Hyperparameters", "ModelFolder", "TrainingConfig", "clone_model",
           "init_model", "make_metadata", "parse_hyperparameters", "parse_model_metadata"]
