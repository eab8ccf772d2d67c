"""`racerlab clone SRC DST`: a new model that starts from SRC's weights, with its lineage recorded.

DST gets SRC's four files (or replacements given here) and SRC's chosen checkpoint as its own
starting checkpoint; checkpoint numbering continues from the parent's, as AWS does. The
weights carry over only when the action count, sensors, network and algorithm match: anything
else is refused before any file is written.
"""

from __future__ import annotations

import json
import shutil
import time
from pathlib import Path

from racerlab.errors import ConfigError, RacerlabError
from racerlab.logs import atomic_write_json
from racerlab.model.folder import ModelFolder
from racerlab.model.metadata import ModelMetadata, load_model_metadata, parse_model_metadata


def clone_model(src, dst, checkpoint: str = "best", reward=None, model_metadata=None, hyperparameters=None,
                track=None) -> ModelFolder:
    source, target = ModelFolder(src), ModelFolder(dst)
    source.require()
    if target.path.exists() and any(target.path.iterdir()):
        raise RacerlabError(f"{target.path}: already exists and is not empty; clone into a new folder")
    info = source.resolve_checkpoint(checkpoint)
    state = source.load_checkpoint(info)
    parent_meta = parse_model_metadata(state["metadata"], str(source.checkpoint_path(info)))
    new_meta = load_model_metadata(model_metadata) if model_metadata else source.metadata()
    check_compatible(parent_meta, new_meta, str(model_metadata or source.metadata_path))
    if track:
        from racerlab import track as tracks

        tracks.load(track)
    if hyperparameters:
        from racerlab.model.hyperparameters import load_hyperparameters

        load_hyperparameters(hyperparameters)  # validate before writing anything
    if reward:
        from racerlab.model.reward import load_reward_function

        load_reward_function(reward)
    copy_model_files(source, target)
    for given, path in ((reward, target.reward_path), (model_metadata, target.metadata_path),
                        (hyperparameters, target.hyperparameters_path)):
        if given:
            shutil.copyfile(given, path)
    if track:
        _set_track(target, track)
    state = dict(state, cloned=True, best_name=None, best_metric=None, rollbacks=0, starts=None,
                 metadata=new_meta.to_json())
    target.save_checkpoint(state, info.iteration, info.steps)
    target.update_index(target.checkpoints()[-1], float("nan"), None, None)
    atomic_write_json(target.lineage_path, {
        "parent": str(source.path.resolve()), "checkpoint": info.name, "iteration": info.iteration,
        "cloned_at": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "changed": [name for name, v in (("reward_function.py", reward), ("model_metadata.json", model_metadata),
                                         ("hyperparameters.json", hyperparameters), ("track", track)) if v],
        "parent_lineage": _read(source.lineage_path)}, indent=2)
    return target


def _read(path: Path):
    try:
        return json.loads(path.read_text())
    except (OSError, json.JSONDecodeError):
        return None


def _set_track(folder: ModelFolder, track: str) -> None:
    from dataclasses import replace

    from racerlab.model.config import TrainingConfig

    cfg: TrainingConfig = folder.config()
    cfg = replace(cfg, track=replace(cfg.track, names=(track,)))
    folder.config_path.write_text(cfg.to_toml())


def check_compatible(parent: ModelMetadata, child: ModelMetadata, where: str) -> None:
    """Refuse weights whose shapes cannot carry over (facts §9): action count, sensors, network, algorithm."""
    problems = []
    if parent.action_space_type != child.action_space_type:
        problems.append(f"action space type {parent.action_space_type} → {child.action_space_type}")
    elif parent.action_space_type == "discrete" and parent.actions.n != child.actions.n:
        problems.append(f"number of actions {parent.actions.n} → {child.actions.n}")
    if tuple(parent.sensor) != tuple(child.sensor):
        problems.append(f"sensors {list(parent.sensor)} → {list(child.sensor)}")
    if parent.neural_network != child.neural_network:
        problems.append(f"neural_network {parent.neural_network} → {child.neural_network}")
    if parent.training_algorithm != child.training_algorithm:
        problems.append(f"training_algorithm {parent.training_algorithm} → {child.training_algorithm}")
    if problems:
        raise ConfigError(f"{where}: cannot reuse the parent's weights: {'; '.join(problems)}. Action values, the "
                          "reward, hyperparameters and track may change; these may not")


def copy_model_files(src: ModelFolder, dst: ModelFolder) -> None:
    dst.path.mkdir(parents=True, exist_ok=True)
    for p in src.model_files:
        if p.is_file():
            shutil.copy2(p, dst.path / p.name)
