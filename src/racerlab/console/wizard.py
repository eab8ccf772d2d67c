"""The create-model wizard's request, checked whole before a single file is written, then written with
the same `init_model` as `racerlab init`."""

from __future__ import annotations

import shutil
import tempfile
from pathlib import Path

from racerlab.console.modelapi import (
    Hyperparameters,
    init_model,
    make_metadata,
    parse_hyperparameters,
    parse_model_metadata,
)
from racerlab.console.security import ConsoleError, check_name, number
from racerlab.errors import RacerlabError
from racerlab.reward import EXAMPLE_REWARD, load_reward_function

MAX_REWARD_BYTES = 256 * 1024
MAX_CARS = 4096  # cars of one training world


def check_reward_text(text: str, where: str = "reward_function.py"):
    """Import the reward function from `text` (in a temporary file); its one-line error when it fails."""
    if not isinstance(text, str) or not text.strip():
        raise ConsoleError(f"{where}: empty; write a reward_function(params)")
    if len(text.encode()) > MAX_REWARD_BYTES:
        raise ConsoleError(f"{where}: larger than {MAX_REWARD_BYTES} bytes")
    with tempfile.TemporaryDirectory(prefix="racerlab-reward-") as tmp:
        path = Path(tmp) / "reward_function.py"
        path.write_text(text, encoding="utf-8")
        fn = load_reward_function(path)
    return fn


def _metadata(body: dict):
    meta = make_metadata(str(body.get("sensor", "features")), str(body.get("action_space", "discrete")),
                         str(body.get("algorithm", "clipped_ppo")), number(body, "max_speed", 1.0))
    data = meta.to_json()
    if body.get("actions") is not None:
        data["action_space"] = body["actions"]
    return parse_model_metadata(data, "model_metadata.json (wizard)")


def _hyperparameters(body: dict):
    given = body.get("hyperparameters") or {}
    if not isinstance(given, dict):
        raise ConsoleError("hyperparameters: expected an object of AWS keys")
    return parse_hyperparameters({**Hyperparameters().to_json(), **given}, "hyperparameters.json (wizard)")


def create_model(workspace, body: dict) -> str:
    """Create the model folder the wizard describes; returns its name."""
    from racerlab.track import registry

    name = check_name(body.get("name"))
    path = workspace.folder(name, must_exist=False).path
    if path.exists():
        raise ConsoleError(f"{name}: already exists in the workspace; choose another name", 409)
    track = str(body.get("track") or registry.names()[0])
    if track not in registry.names():
        raise ConsoleError(f"track {track!r}: not a known track name")
    meta = _metadata(body)
    hp = _hyperparameters(body)
    reward = body.get("reward") or EXAMPLE_REWARD.read_text(encoding="utf-8")
    check_reward_text(reward)
    cars = number(body, "cars", None, integer=True, low=1, high=MAX_CARS)
    try:
        folder = init_model(path, track=track, sensor=str(body.get("sensor", "features")),
                            action_space=meta.action_space_type, algorithm=meta.training_algorithm,
                            max_speed=number(body, "max_speed", 1.0), num_cars=cars)
        folder.write_metadata(meta)
        folder.write_hyperparameters(hp)
        folder.write_reward(reward)
    except (RacerlabError, OSError, ValueError):
        shutil.rmtree(path, ignore_errors=True)
        raise
    return name
