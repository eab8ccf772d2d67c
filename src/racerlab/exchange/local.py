"""The racerlab side of an exchange: an opened model's networks for the AWS sensors, write an imported model folder.

This is the only module of `racerlab.exchange` that knows racerlab's model-folder modules (metadata,
hyperparameters, folder, training config) and the training checkpoint format. Models are read through
`ModelFolder.open`, the door every reader takes, and their networks come from `racerlab.agent.inference_policy`.
"""

from __future__ import annotations

import json
from dataclasses import replace
from typing import TYPE_CHECKING

from racerlab.errors import ConfigError, RacerlabError
from racerlab.model import (
    CheckpointInfo,
    Hyperparameters,
    ModelFolder,
    ModelMetadata,
    OpenModel,
    TrainingConfig,
    TrainingState,
    load_model_metadata,
    parse_hyperparameters,
    parse_model_metadata,
)
from racerlab.model.config import TrackSettings
from racerlab.reward import EXAMPLE_REWARD

if TYPE_CHECKING:
    from racerlab.agent import InferencePolicy

__all__ = ["CheckpointInfo", "Hyperparameters", "ModelFolder", "ModelMetadata", "OpenModel", "aws_shapes", "car_policy",
           "load_model_metadata", "open_for_export", "parse_model_metadata", "write_imported_model"]

IMPORTED_DIR = "imported"


def aws_shapes(metadata: ModelMetadata) -> dict[str, tuple[int, ...]]:
    """racerlab observation input -> shape of one observation for the AWS sensors in `metadata`."""
    from racerlab.sim.sensors.geometry import IMAGE_H, IMAGE_W, LIDAR_RAYS
    from racerlab.sim.sensors.lidar import SECTORS, discretized_config

    shapes: dict[str, tuple[int, ...]] = {}
    for s in metadata.sensor:
        if s == "FEATURES":
            raise ConfigError(f"{metadata.source}: sensor FEATURES is racerlab's own vector of track features; a "
                              "DeepRacer car has no such sensor. Train a model for a sensor it has: "
                              "`racerlab init DIR --sensor camera` (or stereo, lidar)")
        if s == "STEREO_CAMERAS":
            shapes["stereo"] = (IMAGE_H, IMAGE_W, 2)
        elif s in ("FRONT_FACING_CAMERA", "LEFT_CAMERA", "observation"):
            shapes["camera"] = (IMAGE_H, IMAGE_W, 1)
        elif s == "LIDAR":
            shapes["lidar"] = (LIDAR_RAYS,)
        elif s == "SECTOR_LIDAR":
            shapes["sector_lidar"] = (SECTORS,)
        else:  # DISCRETIZED_SECTOR_LIDAR
            n, v, _ = discretized_config(metadata.lidar_config, metadata.source)
            shapes["discretized_sector_lidar"] = (n * v,)
    return shapes


def open_for_export(model_dir, checkpoint: str | int | CheckpointInfo = "best") -> tuple[OpenModel, InferencePolicy]:
    """The model at `checkpoint` through the door every reader takes (`ModelFolder.open`) and its networks for the
    AWS sensors' inputs (`car_policy`), each refusing what it must with `errors.ModelRefused`. A sensor the car
    does not have is said first, before any checkpoint is read (a features model may have none yet)."""
    folder = ModelFolder(model_dir)
    folder.require()
    aws_shapes(folder.metadata())
    model = folder.open(checkpoint)
    return model, car_policy(model)


def car_policy(model: OpenModel) -> InferencePolicy:
    """An opened model's networks for the AWS sensors' inputs (`aws_shapes`), on the CPU in eval mode: what every
    export converts. Weights trained for other inputs (training.toml [run] observation) are refused there."""
    from racerlab.agent import inference_policy  # torch: loaded only where weights are

    return inference_policy(aws_shapes(model.metadata), model.metadata, model.state.agent, where=model.path)


def parse_hyperparameters_text(text: str, source: str) -> Hyperparameters | None:
    """Hyperparameters from an imported hyperparameters.json, or None when racerlab cannot use them."""
    try:
        return parse_hyperparameters(json.loads(text), source)
    except (json.JSONDecodeError, RecursionError, ConfigError):
        return None


def write_imported_model(dst, metadata: ModelMetadata, networks: dict, hyperparameters: Hyperparameters | None,
                         originals: dict[str, bytes], track: str | None, note: dict) -> ModelFolder:
    """A racerlab model folder whose first checkpoint holds `networks` ({"policy", "value"} torch modules).

    `originals` (file name -> bytes) are kept unexecuted under `imported/`; reward_function.py of the new
    folder is racerlab's example reward with a header pointing at the imported one. The checkpoint is
    marked `cloned`, so `racerlab train` continues from these weights with fresh counters. Once written, the folder
    is opened through the door every reader takes (`ModelFolder.open`, `car_policy`), so that an import is never a
    model that evaluation or export would refuse.
    """
    from racerlab.agent import PPO

    folder = ModelFolder(dst)
    if folder.path.exists() and any(folder.path.iterdir()):
        raise RacerlabError(f"{folder.path}: already exists and is not empty; import into a new folder")
    hp = hyperparameters or Hyperparameters()
    agent = PPO(aws_shapes(metadata), metadata, hp, device="cpu", seed=0)
    agent.policy_net.load_state_dict(networks["policy"].state_dict())
    agent.value_net.load_state_dict(networks["value"].state_dict())
    folder.path.mkdir(parents=True)
    for name, data in originals.items():
        folder.write_file(f"{IMPORTED_DIR}/{_kept_name(name)}", data)
    header = ("# racerlab import: this is racerlab's example reward. The imported model's own reward function is\n"
              f"# kept as text, never run, in {IMPORTED_DIR}/reward_function.py.txt: read it, then copy it here\n"
              "# to train with it.\n\n") if "reward_function.py" in originals else ""
    folder.write_reward(header + EXAMPLE_REWARD.read_text())
    folder.write_metadata(metadata)
    folder.write_hyperparameters(hp)
    cfg = TrainingConfig()
    cfg = replace(cfg, run=replace(cfg.run, num_cars=16))  # as `racerlab init` for sensor models
    if track:
        cfg = replace(cfg, track=TrackSettings(names=(track,)))
    folder.write_config(cfg)
    info = folder.save_state(TrainingState(agent.state_dict(), metadata.to_json(), train_steps=0, cloned=True))
    folder.update_index(info, float("nan"), None, None)
    folder.write_lineage({"imported": note})
    car_policy(folder.open())
    return folder


def _kept_name(name: str) -> str:
    return name + ".txt" if name.endswith(".py") else name
