"""Network topologies: output shapes, feature maps, separate networks, SAC nets, errors."""

import dataclasses

import pytest
import torch

from racerlab.agent.networks import (
    DEEP,
    DEEP_DEEP,
    MLP,
    SHALLOW,
    build_networks,
    count_parameters,
    observation_shapes,
    parameter_summary,
)
from racerlab.errors import ConfigError
from racerlab.model import DEFAULT_CONTINUOUS, ModelMetadata, default_discrete_actions

DISCRETE = ModelMetadata(default_discrete_actions())  # 10 actions, SHALLOW, front camera


def meta(network=SHALLOW, continuous=False, sensor=("FRONT_FACING_CAMERA",), algo="clipped_ppo"):
    actions = DEFAULT_CONTINUOUS if continuous else default_discrete_actions()
    return ModelMetadata(actions, sensor, network, algo)


def camera(b=3, c=1):
    return torch.randint(0, 256, (b, 120, 160, c), dtype=torch.uint8)


@pytest.mark.parametrize("network, fmap", [(SHALLOW, (11, 16, 64)), (DEEP, (25, 35, 64)),
                                           (DEEP_DEEP, (3, 6, 512))])
def test_camera_topologies(network, fmap):
    policy, value = build_networks({"camera": (120, 160, 1)}, meta(network))
    emb = policy.body.embedders["camera"]
    assert emb.feature_map == fmap and emb.out_dim == fmap[0] * fmap[1] * fmap[2]
    x = {"camera": camera()}
    assert policy(x).shape == (3, 10) and value(x).shape == (3,)
    middleware = [m.out_features for m in policy.body.middleware if isinstance(m, torch.nn.Linear)]
    assert middleware == ([256, 128] if network == DEEP_DEEP else [512])


def test_shallow_layers_are_the_aws_ones():
    policy, _ = build_networks((120, 160, 1), meta())
    convs = [m for m in policy.body.embedders["camera"].net if isinstance(m, torch.nn.Conv2d)]
    assert [(c.out_channels, c.kernel_size, c.stride, c.padding) for c in convs] == [
        (32, (8, 8), (4, 4), (0, 0)), (64, (4, 4), (2, 2), (0, 0)), (64, (3, 3), (1, 1), (0, 0))]
    # 11 264 features → FC 512 → 10 logits, plus the three convolutions
    assert count_parameters(policy) == (32 * 64 + 32) + (64 * 32 * 16 + 64) + (64 * 64 * 9 + 64) \
        + (11264 * 512 + 512) + (512 * 10 + 10)


def test_policy_and_value_share_nothing():
    policy, value = build_networks((120, 160, 1), meta())
    assert not {id(p) for p in policy.parameters()} & {id(p) for p in value.parameters()}


def test_images_are_scaled_by_255_and_channels_moved():
    policy, _ = build_networks((120, 160, 1), meta())
    emb = policy.body.embedders["camera"]
    x = camera(2)
    expected = emb.net(x.permute(0, 3, 1, 2).float() / 255.0)
    assert torch.allclose(emb(x), expected)


@pytest.mark.parametrize("network, fmap", [(SHALLOW, (11, 16, 64)), (DEEP, (25, 35, 128))])
def test_stereo(network, fmap):
    policy, value = build_networks({"stereo": (120, 160, 2)}, meta(network, sensor=("STEREO_CAMERAS",)))
    assert policy.body.embedders["stereo"].feature_map == fmap
    assert policy({"stereo": camera(2, 2)}).shape == (2, 10)


@pytest.mark.parametrize("key, dim", [("lidar", 64), ("sector_lidar", 8)])
def test_lidar_embedders(key, dim):
    policy, value = build_networks({key: (dim,)}, meta())
    widths = [m.out_features for m in policy.body.embedders[key].net if isinstance(m, torch.nn.Linear)]
    assert widths == [256, 256]
    assert value({key: torch.rand(4, dim)}).shape == (4,)


def test_camera_plus_lidar_concatenates_before_middleware():
    policy, value = build_networks({"camera": (120, 160, 1), "lidar": (64,)}, meta())
    first = next(m for m in policy.body.middleware if isinstance(m, torch.nn.Linear))
    assert first.in_features == 11264 + 256
    obs = {"camera": camera(2), "lidar": torch.rand(2, 64)}
    assert policy(obs).shape == (2, 10) and value(obs).shape == (2,)


def test_mlp_for_features_and_continuous_head():
    policy, value = build_networks({"features": (12,)}, meta(MLP, continuous=True, sensor=("FEATURES",)))
    layers = list(policy.body.middleware)
    assert [type(m).__name__ for m in layers] == ["Linear", "ReLU", "Linear", "ReLU"]
    assert layers[0].in_features == 12 and layers[2].out_features == 64  # PPO_MLP_HIDDEN
    x = {"features": torch.randn(5, 12)}
    dist = policy.distribution(x)
    assert dist.mean.shape == (5, 2) and torch.equal(policy.log_std, torch.zeros(2))
    assert value(x).shape == (5,)


def test_mlp_refuses_images():
    with pytest.raises(ConfigError, match="MLP"):
        build_networks((120, 160, 1), dataclasses.replace(meta(MLP), source="m/model_metadata.json"))


def test_sac_networks():
    md = meta(MLP, continuous=True, sensor=("FEATURES",), algo="sac")
    actor, q1, q2 = build_networks((7,), md)
    x = {"features": torch.randn(4, 7)}
    a, logp = actor.distribution(x).rsample()
    assert a.shape == (4, 2) and logp.shape == (4,)
    assert q1(x, a).shape == (4,) and q2(x, a).shape == (4,)
    assert not {id(p) for p in q1.parameters()} & {id(p) for p in q2.parameters()}
    with pytest.raises(ConfigError, match="continuous"):
        build_networks((7,), dataclasses.replace(md, actions=default_discrete_actions()))


def test_observation_shapes_names_single_inputs():
    import gymnasium as gym

    assert observation_shapes((120, 160, 1)) == {"camera": (120, 160, 1)}
    assert observation_shapes(gym.spaces.Box(0, 255, (120, 160, 2))) == {"stereo": (120, 160, 2)}
    assert observation_shapes((64,), meta(sensor=("LIDAR",))) == {"lidar": (64,)}
    cam_sector = meta(sensor=("FRONT_FACING_CAMERA", "SECTOR_LIDAR"))
    assert observation_shapes((8,), cam_sector) == {"sector_lidar": (8,)}
    assert observation_shapes((12,)) == {"features": (12,)}
    space = gym.spaces.Dict({"camera": gym.spaces.Box(0, 255, (120, 160, 1)),
                             "lidar": gym.spaces.Box(0, 1, (64,))})
    assert observation_shapes(space) == {"camera": (120, 160, 1), "lidar": (64,)}


def test_parameter_summary_is_printable():
    policy, value = build_networks({"features": (12,)}, meta(MLP))
    text = parameter_summary(policy=policy, value=value)
    lines = text.splitlines()
    assert lines[0].startswith("policy") and lines[-1].startswith("total") and "," in lines[-1]
    assert f"{count_parameters(policy) + count_parameters(value):,}" in lines[-1]
