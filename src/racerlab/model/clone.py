"""`racerlab clone SRC DST`: a new model that starts from SRC's weights, with its lineage recorded.

DST gets SRC's four files (or replacements given here), a taught model's own features teacher (its folder inside
SRC), and SRC's chosen checkpoint as its own starting checkpoint; checkpoint numbering continues from the parent's,
as AWS does. The checkpoint is opened through `ModelFolder.open`, which refuses one that cannot be read, holds
non-finite weights or does not match SRC's model_metadata.json. The weights carry over only when the action count,
sensors, network and algorithm match: anything else is refused before any file is written.
"""

from __future__ import annotations

import json
import shutil
import time
from dataclasses import replace
from pathlib import Path

from racerlab.errors import ConfigError, RacerlabError
from racerlab.model.folder import ModelFolder
from racerlab.model.metadata import ModelMetadata, load_model_metadata, parse_model_metadata


def clone_model(src, dst, checkpoint: str = "best", reward=None, model_metadata=None, hyperparameters=None,
                track=None) -> ModelFolder:
    source, target = ModelFolder(src), ModelFolder(dst)
    source.require()
    if target.path.exists() and any(target.path.iterdir()):
        raise RacerlabError(f"{target.path}: already exists and is not empty; clone into a new folder")
    opened = source.open(checkpoint)  # the door: an unreadable, non-finite or mismatched checkpoint is refused
    info, state = opened.checkpoint, opened.state
    parent_meta = parse_model_metadata(state.metadata, str(source.checkpoint_path(info)))
    new_meta = load_model_metadata(model_metadata) if model_metadata else source.metadata()
    check_compatible(parent_meta, new_meta, str(model_metadata or source.metadata_path))
    if track:
        from racerlab import track as tracks

        tracks.load(track)
    if hyperparameters:
        from racerlab.model.hyperparameters import load_hyperparameters

        load_hyperparameters(hyperparameters)  # validate before writing anything
    if reward:
        from racerlab.reward import load_reward_function

        load_reward_function(reward)
    target.copy_model_files(source)
    teacher = own_teacher(source)
    if teacher is not None:  # a taught model's own teacher comes along, trained: the clone does not train another
        shutil.copytree(source.path / teacher, target.path / teacher,
                        ignore=shutil.ignore_patterns("training.lock", ".*.tmp-*"))
    if reward:
        target.write_reward(Path(reward).read_text())
    if model_metadata:
        target.write_metadata(new_meta)
    if hyperparameters:
        target.write_hyperparameters(json.loads(Path(hyperparameters).read_text()))
    if track:
        _set_track(target, track)
    target.save_state(replace(state.cloned_as(new_meta.to_json()), iteration=info.iteration, train_steps=info.steps))
    target.update_index(target.checkpoints()[-1], float("nan"), None, None)
    target.write_lineage({
        "parent": str(source.path.resolve()), "checkpoint": info.name, "iteration": info.iteration,
        "cloned_at": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "changed": [name for name, v in (("reward_function.py", reward), ("model_metadata.json", model_metadata),
                                         ("hyperparameters.json", hyperparameters), ("track", track)) if v],
        "parent_lineage": _read(source.lineage_path)})
    return target


def own_teacher(folder: ModelFolder) -> Path | None:
    """The features teacher a taught model keeps inside its folder (training.toml's `[teacher] model`), as a path
    relative to the folder; None when it has none there."""
    name = folder.config().teacher.model
    if not name:
        return None
    root = folder.path.resolve()
    path = (folder.path / Path(name).expanduser()).resolve()
    if path == root or not path.is_relative_to(root) or not (path / "model_metadata.json").is_file():
        return None
    return path.relative_to(root)


def _read(path: Path):
    try:
        return json.loads(path.read_text())
    except (OSError, json.JSONDecodeError):
        return None


def _set_track(folder: ModelFolder, track: str) -> None:
    cfg = folder.config()
    cfg = replace(cfg, track=replace(cfg.track, names=(track,)))
    folder.write_config(cfg)


def check_compatible(parent: ModelMetadata, child: ModelMetadata, where: str) -> None:
    """Refuse weights whose shapes cannot carry over (`ModelMetadata.differences`)."""
    problems = parent.differences(child)
    if problems:
        raise ConfigError(f"{where}: cannot reuse the parent's weights: {'; '.join(problems)}. Action values, the "
                          "reward, hyperparameters and track may change; these may not")
