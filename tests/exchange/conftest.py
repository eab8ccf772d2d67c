"""Model folders with trained-looking weights for the exchange tests, observation batches, and an S3 server."""

from __future__ import annotations

import json
import socket

import numpy as np
import pytest
import torch

from racerlab.agent import PPO, SAC
from racerlab.exchange.local import aws_shapes
from racerlab.model import TrainingState, init_model

N_OBS = 100


def make_model(path, sensor="camera", action_space="discrete", algorithm="clipped_ppo", network=None, seed=0):
    """A model folder with one checkpoint (iteration 3, 1200 steps) in training's checkpoint format.

    Every weight is perturbed with noise (biases are zero at initialisation), so a wrong bias, transpose
    or flatten order shows in the outputs.
    """
    folder = init_model(path, sensor=sensor, action_space=action_space, algorithm=algorithm)
    meta = folder.metadata()
    if network:
        data = meta.to_json()
        data["neural_network"] = network
        folder.metadata_path.write_text(json.dumps(data))
        meta = folder.metadata()
    cls = SAC if algorithm == "sac" else PPO
    agent = cls(aws_shapes(meta), meta, device="cpu", seed=seed)
    gen = torch.Generator().manual_seed(seed + 1)
    nets = [agent.actor] if algorithm == "sac" else [agent.policy_net, agent.value_net]
    with torch.no_grad():
        for net in nets:
            for p in net.parameters():
                p.add_(0.05 * torch.randn(p.shape, generator=gen))
    folder.save_state(TrainingState(agent.state_dict(), meta.to_json(), iteration=3, episodes=40, env_steps=1200,
                                    train_steps=1200))
    return folder


def observations(shapes, n=N_OBS, seed=0) -> dict[str, np.ndarray]:
    """Images uint8 0-255 (as the camera gives them), lidar ranges in [0.15, 1] m, sector bits."""
    rng = np.random.default_rng(seed)
    out = {}
    for key, shape in shapes.items():
        if len(shape) == 3:
            out[key] = rng.integers(0, 256, (n, *shape)).astype(np.uint8)
        elif key == "lidar":
            out[key] = rng.uniform(0.15, 1.0, (n, *shape)).astype(np.float32)
        else:
            out[key] = rng.integers(0, 2, (n, *shape)).astype(np.float32)
    return out


def racerlab_policy_output(model, obs) -> np.ndarray:
    """What the car's output node must give: softmax probabilities, the continuous mean, or SAC's tanh(mean)."""
    t = {k: torch.as_tensor(v) for k, v in obs.items()}
    with torch.no_grad():
        if "actor" in model.networks:
            return model.networks["actor"].distribution(t).mode().numpy()  # the greedy action, tanh(mean)
        out = model.networks["policy"](t)
        if model.metadata.action_space_type == "discrete":
            out = torch.softmax(out, dim=-1)
        return out.numpy()


@pytest.fixture
def s3_server(monkeypatch):
    moto_server = pytest.importorskip("moto.server", reason="needs moto[server]: pip install -e '.[test]'")
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    server = moto_server.ThreadedMotoServer(ip_address="127.0.0.1", port=port, verbose=False)
    server.start()
    for k, v in {"AWS_ACCESS_KEY_ID": "racerlab", "AWS_SECRET_ACCESS_KEY": "racerlab-secret",
                 "AWS_DEFAULT_REGION": "us-east-1", "AWS_ENDPOINT_URL": f"http://127.0.0.1:{port}"}.items():
        monkeypatch.setenv(k, v)
    monkeypatch.delenv("AWS_PROFILE", raising=False)
    try:
        import boto3

        s3 = boto3.client("s3", endpoint_url=f"http://127.0.0.1:{port}")
        s3.create_bucket(Bucket="races")
        yield s3
    finally:
        server.stop()
