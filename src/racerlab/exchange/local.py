"""The racerlab side of an exchange: read a model folder's networks, write an imported model folder.

This is the only module of `racerlab.exchange` that knows racerlab's model-folder modules (metadata,
hyperparameters, folder, training config) and the training checkpoint format.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, replace

from racerlab.errors import ConfigError, RacerlabError
from racerlab.model import (
    CheckpointInfo,
    Hyperparameters,
    ModelFolder,
    ModelMetadata,
    TrainingConfig,
    TrainingState,
    load_model_metadata,
    parse_hyperparameters,
    parse_model_metadata,
)
from racerlab.model.config import TrackSettings
from racerlab.reward import EXAMPLE_REWARD

__all__ = ["CheckpointInfo", "Hyperparameters", "LocalModel", "ModelFolder", "ModelMetadata", "aws_shapes",
           "load_local_model", "load_model_metadata", "parse_model_metadata", "write_imported_model"]

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


@dataclass
class LocalModel:
    """A racerlab model's files and the networks of one checkpoint, on the CPU in eval mode."""

    folder: ModelFolder
    metadata: ModelMetadata
    hyperparameters: Hyperparameters
    checkpoint: CheckpointInfo
    shapes: dict[str, tuple[int, ...]]
    networks: dict  # "policy", "value" (clipped PPO) or "actor" (SAC) -> nn.Module

    @property
    def name(self) -> str:
        return self.folder.path.resolve().name


def load_local_model(model_dir, checkpoint: str | int = "best") -> LocalModel:
    from racerlab.agent import build_networks, inference_networks

    folder = ModelFolder(model_dir)
    folder.require()
    meta = folder.metadata()
    shapes = aws_shapes(meta)
    info = folder.resolve_checkpoint(checkpoint)
    agent = folder.load_state(info).agent
    where = folder.checkpoint_path(info)
    nets = build_networks(shapes, meta)
    names = inference_networks(meta)
    networks = {}
    for name, net in zip(names, nets, strict=False):
        try:
            net.load_state_dict(agent[name])
        except (KeyError, RuntimeError) as exc:
            first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            raise RacerlabError(f"{where}: its {name} weights do not fit the AWS {meta.neural_network} network for "
                                f"sensors {list(meta.sensor)} ({first}); export a model trained on AWS sensors "
                                "(training.toml [run] observation left empty)") from None
        networks[name] = net.eval()
    return LocalModel(folder, meta, folder.hyperparameters(), info, shapes, networks)


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
    marked `cloned`, so `racerlab train` continues from these weights with fresh counters.
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
    return folder


def _kept_name(name: str) -> str:
    return name + ".txt" if name.endswith(".py") else name
