"""Small model folders for evaluation tests: chosen action spaces, a checkpoint of a fresh agent."""

from __future__ import annotations

import json
from pathlib import Path

from racerlab.model import ModelFolder

REWARD = "def reward_function(params):\n    return 1.0 if params['all_wheels_on_track'] else 1e-3\n"
SENSORS = {"features": (["FEATURES"], "MLP"), "camera": (["FRONT_FACING_CAMERA"], "DEEP_CONVOLUTIONAL_NETWORK_SHALLOW"),
           "stereo": (["STEREO_CAMERAS"], "DEEP_CONVOLUTIONAL_NETWORK_SHALLOW"),
           "lidar": (["LIDAR"], "MLP"), "camera+lidar": (["FRONT_FACING_CAMERA", "LIDAR"],
                                                         "DEEP_CONVOLUTIONAL_NETWORK_SHALLOW")}


def write_model(path: Path, track: Path | str, actions=((0.0, 1.0),), sensor: str = "features",
                algorithm: str = "clipped_ppo") -> ModelFolder:
    """A model folder trained on `track` whose actions are `actions`: discrete ((steering °, speed m/s), ...)
    or continuous {"steering_angle": {"low": .., "high": ..}, "speed": {...}}."""
    path.mkdir(parents=True, exist_ok=True)
    sensors, network = SENSORS[sensor]
    if isinstance(actions, dict):
        space, kind = actions, "continuous"
    else:
        space = [{"steering_angle": s, "speed": v, "index": i} for i, (s, v) in enumerate(actions)]
        kind = "discrete"
    meta = {"action_space": space, "action_space_type": kind, "sensor": sensors, "neural_network": network,
            "training_algorithm": algorithm, "version": "5"}
    (path / "model_metadata.json").write_text(json.dumps(meta))
    (path / "reward_function.py").write_text(REWARD)
    (path / "training.toml").write_text(f'[track]\nnames = ["{track}"]\n[run]\nnum_cars = 1\n')
    return ModelFolder(path)


def write_checkpoint(folder: ModelFolder, iteration: int = 1, metadata: dict | None = None):
    """Save a fresh agent's weights as iteration `iteration`'s checkpoint (best and last)."""
    from racerlab.agent import make_agent
    from racerlab.sim.core import Simulator
    from racerlab.sim.observations import make_observation
    from racerlab.track import load

    meta = folder.metadata()
    sim = Simulator(load(folder.config().track.names[0]), 1)
    obs = make_observation(folder.config().run.observation or None, sim, meta)
    agent = make_agent(obs.space, meta, folder.hyperparameters(), device="cpu", seed=0)
    from racerlab.model import TrainingState

    state = TrainingState(agent.state_dict(), metadata or meta.to_json(), iteration=iteration,
                          train_steps=100 * iteration)
    info = folder.save_state(state)
    folder.update_index(info, 0.0, info, 0.0)
    return info
