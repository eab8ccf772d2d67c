"""The AWS DeepRacer network topologies in PyTorch (facts §4), plus racerlab's `MLP`.

A network is a `Body` (one embedder per observation input, concatenated, then the middleware) and a
small head. Like AWS (`use_separate_networks_per_head`), PPO gets two complete networks: a policy and a
value network that share nothing. SAC gets an actor and two Q networks; the SAC class keeps their targets.

Embedders by observation input (the simulator's names):

| input | network name | embedder (kernel/stride; valid padding) |
|---|---|---|
| `camera` (H, W, 1) uint8 | SHALLOW | Conv 32@8/4 → 64@4/2 → 64@3/1 (11x16x64 on 120x160) |
| | DEEP | Conv 32@5/2 → 32@3/1 → 64@3/2 → 64@3/1 → Dense 64 per position (25x35x64) |
| | DEEP_DEEP | Conv 32@8/4 → 32@4/2 → 64@4/2 → 64@3/1 → Dense 512 → 512 per position |
| `stereo` (H, W, 2) uint8 | SHALLOW | as the camera |
| | DEEP, DEEP_DEEP | Conv 32@3/1 → 64@3/2 → 64@3/1 → 128@3/2 → 128@3/1 |
| `lidar`, `sector_lidar`, other vectors | any AWS name | FC 256 → FC 256 |

(SHALLOW = DEEP_CONVOLUTIONAL_NETWORK_SHALLOW, the console's "3-layer CNN"; DEEP =
DEEP_CONVOLUTIONAL_NETWORK, the "5-layer CNN"; DEEP_DEEP = DEEP_CONVOLUTIONAL_NETWORK_DEEP.)

Middleware: FC 512 (SHALLOW and DEEP), FC 256 → FC 128 (DEEP_DEEP). All layers ReLU, "valid" padding,
no batch-norm or dropout (AWS builds the plain scheme whatever the scheme dicts say). Dense layers on a
feature map act per spatial position, as Keras Dense does on a 4-D tensor. Images arrive NHWC uint8 and
are divided by 255 and moved to NCHW inside; vectors are used as they are (AWS rescales only images).
Weights start as Keras does: Glorot-uniform, zero biases. Flattening is NCHW order (PyTorch), so weights
are not interchangeable with AWS TensorFlow checkpoints anyway.

`MLP` (racerlab, for the `features` observation): all inputs must be vectors; they are concatenated
and go through 2 x 256 ReLU layers (`mlp_hidden`), Keras initialisation, like the AWS networks. Not tanh
(the CleanRL / SB3 habit for vector observations): with Glorot or orthogonal initialisation a tanh MLP
sat on a plateau for hundreds of steps when fitting a quadratic reward from raw, unnormalised inputs,
where the ReLU one converged at once (measured while writing the SAC toy test); value and Q functions
have to fit returns of any scale, and ReLU does that better.
"""

from __future__ import annotations

from collections.abc import Mapping

import torch
from torch import nn

from racerlab.agent.distributions import Categorical, DiagGaussian, TanhGaussian
from racerlab.errors import ConfigError

SHALLOW = "DEEP_CONVOLUTIONAL_NETWORK_SHALLOW"
DEEP = "DEEP_CONVOLUTIONAL_NETWORK"
DEEP_DEEP = "DEEP_CONVOLUTIONAL_NETWORK_DEEP"
MLP = "MLP"
# (convs as (filters, kernel, stride), per-position dense widths)
_CAMERA_SCHEMES = {
    SHALLOW: (((32, 8, 4), (64, 4, 2), (64, 3, 1)), ()),
    DEEP: (((32, 5, 2), (32, 3, 1), (64, 3, 2), (64, 3, 1)), (64,)),
    DEEP_DEEP: (((32, 8, 4), (32, 4, 2), (64, 4, 2), (64, 3, 1)), (512, 512)),
}
_STEREO_DEEP = (((32, 3, 1), (64, 3, 2), (64, 3, 1), (128, 3, 2), (128, 3, 1)), ())
_STEREO_SCHEMES = {SHALLOW: _CAMERA_SCHEMES[SHALLOW], DEEP: _STEREO_DEEP, DEEP_DEEP: _STEREO_DEEP}
_MIDDLEWARE = {SHALLOW: (512,), DEEP: (512,), DEEP_DEEP: (256, 128), MLP: ()}
LIDAR_LAYERS = (256, 256)
MLP_HIDDEN = (256, 256)  # SAC's networks on vectors
# PPO's on vectors (features): 64 wide, the usual size for PPO on low-dimensional control. It learns the
# reInvent2019 lap as well as 256 did (7.40 s best at 6 min vs 7.67 s at 15 min) at 1/14 of the FLOPs
# per gradient step, which is what lets the update keep up with the simulator (benchmarks/train_throughput.py).
PPO_MLP_HIDDEN = (64, 64)


def _init_keras(module: nn.Module) -> None:
    if isinstance(module, nn.Linear | nn.Conv2d):
        nn.init.xavier_uniform_(module.weight)
        nn.init.zeros_(module.bias)


def _dense(in_dim: int, widths, activation=nn.ReLU) -> tuple[nn.Sequential, int]:
    layers: list[nn.Module] = []
    for w in widths:
        layers += [nn.Linear(in_dim, w), activation()]
        in_dim = w
    return nn.Sequential(*layers), in_dim


class ConvEmbedder(nn.Module):
    """uint8 images [B, H, W, C] -> [B, features]: valid convolutions, per-position dense, flatten."""

    def __init__(self, shape: tuple[int, int, int], convs, dense=()):
        super().__init__()
        h, w, c = shape
        layers: list[nn.Module] = []
        for filters, k, s in convs:
            layers += [nn.Conv2d(c, filters, k, stride=s), nn.ReLU()]
            h, w, c = (h - k) // s + 1, (w - k) // s + 1, filters
            if h < 1 or w < 1:
                raise ValueError(f"image {shape} is too small for this network")
        for width in dense:  # Keras Dense on [B, H, W, C] acts on C alone: a 1x1 convolution
            layers += [nn.Conv2d(c, width, 1), nn.ReLU()]
            c = width
        self.net = nn.Sequential(*layers, nn.Flatten())
        self.feature_map = (h, w, c)
        self.out_dim = h * w * c

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.net(x.permute(0, 3, 1, 2).float() / 255.0)


class VectorEmbedder(nn.Module):
    """Vectors [B, F] -> [B, widths[-1]] through dense layers (none: used as they are)."""

    def __init__(self, dim: int, widths=LIDAR_LAYERS):
        super().__init__()
        self.net, self.out_dim = _dense(dim, widths)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.net(x.float())


class Body(nn.Module):
    """Embedders per input (sorted by name), concatenated with `extra` (SAC's action), then middleware."""

    def __init__(self, shapes: Mapping[str, tuple[int, ...]], network: str, extra_dim: int = 0,
                 mlp_hidden=MLP_HIDDEN):
        super().__init__()
        self.keys = tuple(sorted(shapes))
        self.embedders = nn.ModuleDict({k: _embedder(k, tuple(shapes[k]), network) for k in self.keys})
        in_dim = sum(e.out_dim for e in self.embedders.values()) + extra_dim
        if network == MLP:
            self.middleware, self.out_dim = _dense(in_dim, mlp_hidden)
        else:
            self.middleware, self.out_dim = _dense(in_dim, _MIDDLEWARE[network])

    def forward(self, obs: Mapping[str, torch.Tensor], extra: torch.Tensor | None = None) -> torch.Tensor:
        parts = [self.embedders[k](obs[k]) for k in self.keys]
        if extra is not None:
            parts.append(extra.float())
        return self.middleware(parts[0] if len(parts) == 1 else torch.cat(parts, dim=-1))


def _embedder(key: str, shape: tuple[int, ...], network: str) -> nn.Module:
    if len(shape) == 3:
        if network == MLP:
            raise ValueError("MLP has no image embedder")
        schemes = _STEREO_SCHEMES if shape[-1] == 2 or key == "stereo" else _CAMERA_SCHEMES
        convs, dense = schemes[network]
        return ConvEmbedder(shape, convs, dense)
    if len(shape) != 1:
        raise ValueError(f"observation {key!r} has shape {shape}; expected (H, W, C) or (F,)")
    return VectorEmbedder(shape[0], () if network == MLP else LIDAR_LAYERS)


class PolicyNet(nn.Module):
    """PPO policy: logits [B, N] (discrete) or mean [B, D] with a state-independent log-std (continuous)."""

    def __init__(self, body: Body, num_actions: int | None = None, action_dim: int | None = None):
        super().__init__()
        self.body = body
        self.discrete = num_actions is not None
        self.head = nn.Linear(body.out_dim, num_actions if self.discrete else action_dim)
        self.apply(_init_keras)
        if not self.discrete:
            self.log_std = nn.Parameter(torch.zeros(action_dim))  # std 1 at the start, as AWS

    def forward(self, obs: Mapping[str, torch.Tensor]) -> torch.Tensor:
        return self.head(self.body(obs))

    def distribution(self, obs: Mapping[str, torch.Tensor]) -> Categorical | DiagGaussian:
        out = self(obs)
        return Categorical(out) if self.discrete else DiagGaussian(out, self.log_std)


class ValueNet(nn.Module):
    """State value V(s) [B]."""

    def __init__(self, body: Body):
        super().__init__()
        self.body = body
        self.head = nn.Linear(body.out_dim, 1)
        self.apply(_init_keras)

    def forward(self, obs: Mapping[str, torch.Tensor]) -> torch.Tensor:
        return self.head(self.body(obs)).squeeze(-1)


class SACActor(nn.Module):
    """SAC policy: mean and state-dependent log-std [B, D] -> `TanhGaussian`."""

    def __init__(self, body: Body, action_dim: int):
        super().__init__()
        self.body = body
        self.head = nn.Linear(body.out_dim, 2 * action_dim)
        self.apply(_init_keras)

    def distribution(self, obs: Mapping[str, torch.Tensor]) -> TanhGaussian:
        mean, log_std = self.head(self.body(obs)).chunk(2, dim=-1)
        return TanhGaussian(mean, log_std)


class QNet(nn.Module):
    """Q(s, a) [B]; the action [B, D] joins the embeddings before the middleware."""

    def __init__(self, body: Body):
        super().__init__()
        self.body = body
        self.head = nn.Linear(body.out_dim, 1)
        self.apply(_init_keras)

    def forward(self, obs: Mapping[str, torch.Tensor], action: torch.Tensor) -> torch.Tensor:
        return self.head(self.body(obs, action)).squeeze(-1)


# ---------------------------------------------------------------------------------------------------
# Building from an observation space and model_metadata
# ---------------------------------------------------------------------------------------------------


def observation_shapes(obs, metadata=None) -> dict[str, tuple[int, ...]]:
    """Input name -> shape (without the batch axis) from a gymnasium space, a dict or a single shape.

    Accepts a `gymnasium.spaces.Dict`, a mapping of name -> shape or Box, or one Box or shape. A single
    unnamed input is named by its shape: (H, W, 1) camera, (H, W, 2) stereo, and a vector after the
    metadata's lidar sensor (`lidar`, `sector_lidar`, `discretized_sector_lidar`), else `features`.
    """
    spaces = getattr(obs, "spaces", None)
    if isinstance(spaces, Mapping):
        obs = spaces
    if isinstance(obs, Mapping):
        return {str(k): tuple(int(d) for d in getattr(v, "shape", v)) for k, v in obs.items()}
    shape = tuple(int(d) for d in getattr(obs, "shape", obs))
    return {_name_for(shape, metadata): shape}


def _name_for(shape: tuple[int, ...], metadata) -> str:
    if len(shape) == 3:
        return "stereo" if shape[-1] == 2 else "camera"
    # Only the name differs: every vector gets the same embedder under a given network.
    lidar = getattr(metadata, "lidar", None)
    return lidar.lower() if lidar else "features"


def _network_name(shapes: Mapping[str, tuple[int, ...]], metadata) -> str:
    network = metadata.neural_network
    if network == MLP and any(len(s) == 3 for s in shapes.values()):
        raise ConfigError(f"{metadata.source}: neural_network \"MLP\" takes vector observations only "
                          f"(features, lidar, sector_lidar), got {sorted(shapes)}; use {SHALLOW} for cameras")
    return network


def build_ppo_networks(obs, metadata, mlp_hidden=PPO_MLP_HIDDEN) -> tuple[PolicyNet, ValueNet]:
    """Separate policy and value networks for clipped PPO (AWS `use_separate_networks_per_head`)."""
    shapes = observation_shapes(obs, metadata)
    network = _network_name(shapes, metadata)
    actions = metadata.actions
    discrete = metadata.action_space_type == "discrete"
    policy = PolicyNet(Body(shapes, network, mlp_hidden=mlp_hidden),
                       num_actions=actions.n if discrete else None, action_dim=None if discrete else 2)
    value = ValueNet(Body(shapes, network, mlp_hidden=mlp_hidden))
    return policy, value


def build_sac_networks(obs, metadata, mlp_hidden=MLP_HIDDEN) -> tuple[SACActor, QNet, QNet]:
    """Actor and two independent Q networks for SAC (continuous actions only)."""
    if metadata.action_space_type != "continuous":
        raise ConfigError(f"{metadata.source}: training_algorithm \"sac\" needs "
                          "action_space_type \"continuous\"")
    shapes = observation_shapes(obs, metadata)
    network = _network_name(shapes, metadata)
    actor = SACActor(Body(shapes, network, mlp_hidden=mlp_hidden), action_dim=2)
    q1, q2 = (QNet(Body(shapes, network, extra_dim=2, mlp_hidden=mlp_hidden)) for _ in range(2))
    return actor, q1, q2


def build_networks(obs, metadata, mlp_hidden=None) -> tuple[nn.Module, ...]:
    """(policy, value) for clipped_ppo; (actor, q1, q2) for sac, per `metadata.training_algorithm`."""
    if metadata.training_algorithm == "sac":
        return build_sac_networks(obs, metadata, mlp_hidden or MLP_HIDDEN)
    return build_ppo_networks(obs, metadata, mlp_hidden or PPO_MLP_HIDDEN)


def inference_networks(metadata) -> tuple[str, ...]:
    """The networks a trained model is used through (exported, imported, raced), named as `build_networks` returns
    them and as the agent's `state_dict()` keys their weights: policy and value for clipped_ppo, the actor for sac."""
    return ("actor",) if metadata.training_algorithm == "sac" else ("policy", "value")


def count_parameters(module: nn.Module) -> int:
    return sum(p.numel() for p in module.parameters())


def parameter_summary(**modules: nn.Module) -> str:
    """One line per named network, e.g. `policy    5,846,186 parameters`, and a total."""
    width = max(len(n) for n in [*modules, "total"])
    counts = {n: count_parameters(m) for n, m in modules.items()}
    lines = [f"{n:<{width}}  {c:>12,} parameters" for n, c in counts.items()]
    lines.append(f"{'total':<{width}}  {sum(counts.values()):>12,} parameters")
    return "\n".join(lines)
