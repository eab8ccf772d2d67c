"""racerlab's PyTorch policy and value networks <-> rl_coach's TensorFlow variables, by name and shape.

A `Tower` is one coach network (`network_0` = value, `network_1` = policy for clipped PPO) in
TensorFlow's layout: conv kernels HWIO, dense kernels [in, out], feature maps flattened in NHWC order.
racerlab's networks are NCHW and flatten in (C, H, W) order, so the first dense layer after a camera
embedder gets its input rows permuted; everything else is a transpose.

Names (relative to `main_level/agent/main/online/network_<i>/`), from rl_coach and the variables of a
console-trained model (`rl_coach_checkpoint_variables.md`):

- camera embedder: `<SENSOR>/Conv2d_0`, `Conv2d_2`, ... (the index counts the activations too); a dense
  layer per position after the convs (5-layer CNN) continues the count as `Dense_<k>`;
- vector embedder (lidar): `<SENSOR>/Dense_0`, `Dense_2`;
- middleware: `middleware_fc_embedder/Dense_0` (and `Dense_2`, DEEP's second layer);
- value head: `v_values_head_0/output`;
- PPO head: `ppo_head_0/policy_fc` (discrete, softmax) or `ppo_head_0/policy_mean` plus `policy_log_std`
  [1, 2] (continuous).

Embedders are concatenated in sorted order of the sensor names, as coach's `general_network` does.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import numpy as np

from racerlab.errors import ConfigError

PREFIX = "main_level/agent/main/online"
POLICY_NETWORK, VALUE_NETWORK = "network_1", "network_0"
POLICY_OUTPUT = f"{PREFIX}/{POLICY_NETWORK}/ppo_head_0/policy"
SAC_PREFIX = "main_level/agent/policy/online"
SAC_OUTPUT = f"{SAC_PREFIX}/network_0/sac_policy_head_0/policy"

# racerlab observation input -> AWS sensor name (a camera input takes the metadata's camera name)
VECTOR_SENSORS = {"lidar": "LIDAR", "sector_lidar": "SECTOR_LIDAR",
                  "discretized_sector_lidar": "DISCRETIZED_SECTOR_LIDAR"}
CAR_SENSORS = ("observation", "FRONT_FACING_CAMERA", "LEFT_CAMERA", "STEREO_CAMERAS", "LIDAR", "SECTOR_LIDAR")


@dataclass
class Layer:
    """One weight layer in TensorFlow layout. kind: conv (HWIO), pointwise (dense on a feature map) or dense."""

    name: str
    kind: str
    kernel: np.ndarray
    bias: np.ndarray
    stride: int = 1


@dataclass
class Embedder:
    sensor: str  # AWS name, also the placeholder's name
    key: str  # racerlab's observation input
    shape: tuple[int, ...]  # one observation, NHWC without N, or (F,)
    layers: list[Layer]

    @property
    def image(self) -> bool:
        return len(self.shape) == 3


@dataclass
class Tower:
    """One coach network: embedders (concatenation order), middleware, head; `log_std` for continuous PPO."""

    embedders: list[Embedder]
    middleware: list[Layer]
    head: Layer
    log_std: np.ndarray | None = None
    extra: dict = field(default_factory=dict)

    def variables(self, network: str, prefix: str = PREFIX) -> dict[str, np.ndarray]:
        """Variable name -> float32 array, in graph order (embedders, middleware, head)."""
        out: dict[str, np.ndarray] = {}
        for layer in [*(ly for e in self.embedders for ly in e.layers), *self.middleware, self.head]:
            out[f"{prefix}/{network}/{layer.name}/kernel"] = _f32(layer.kernel)
            out[f"{prefix}/{network}/{layer.name}/bias"] = _f32(layer.bias)
        if self.log_std is not None:
            out[f"{prefix}/{network}/ppo_head_0/policy_log_std"] = _f32(self.log_std).reshape(1, -1)
        return out


def _f32(a) -> np.ndarray:
    return np.ascontiguousarray(np.asarray(a, dtype=np.float32))


def aws_sensor(key: str, metadata) -> str:
    if key == "camera":
        return metadata.camera or "FRONT_FACING_CAMERA"
    if key == "stereo":
        return "STEREO_CAMERAS"
    if key in VECTOR_SENSORS:
        return VECTOR_SENSORS[key]
    raise ConfigError(f"{metadata.source}: the AWS networks have no input for racerlab's {key!r} observation; "
                      f"AWS sensors are {', '.join(CAR_SENSORS)} (train with --sensor camera, stereo or lidar)")


def _layer_names(n: int, start: int = 0, kind: str = "Dense") -> list[str]:
    return [f"{kind}_{2 * i}" for i in range(start, start + n)]


# ---- racerlab -> coach ----------------------------------------------------------------------------


def tower_from_torch(net, metadata, shapes: Mapping[str, tuple[int, ...]], head_name: str) -> Tower:
    """A racerlab PolicyNet / ValueNet (`net.body`, `net.head`) as a coach Tower."""
    from torch import nn

    body = net.body
    embedders = []
    for key in body.keys:
        emb, shape = body.embedders[key], tuple(shapes[key])
        sensor = aws_sensor(key, metadata)
        mods = [m for m in emb.net if isinstance(m, nn.Linear | nn.Conv2d)]
        layers = []
        if len(shape) == 3:
            convs = [m for m in mods if m.kernel_size != (1, 1) or m.stride != (1, 1)]
            points = mods[len(convs):]
            for name, m in zip(_layer_names(len(convs), kind="Conv2d"), convs, strict=True):
                layers.append(Layer(f"{sensor}/{name}", "conv", _t(m.weight).transpose(2, 3, 1, 0), _t(m.bias),
                                    m.stride[0]))
            for name, m in zip(_layer_names(len(points), len(convs)), points, strict=True):
                layers.append(Layer(f"{sensor}/{name}", "pointwise", _t(m.weight)[:, :, 0, 0].T, _t(m.bias)))
        else:
            for name, m in zip(_layer_names(len(mods)), mods, strict=True):
                layers.append(Layer(f"{sensor}/{name}", "dense", _t(m.weight).T, _t(m.bias)))
        embedders.append(Embedder(sensor, key, shape, layers))
    order = _flat_order(body)
    middleware = []
    mids = [m for m in body.middleware if isinstance(m, nn.Linear)]
    for i, (name, m) in enumerate(zip(_layer_names(len(mids)), mids, strict=True)):
        kernel = _t(m.weight).T
        if i == 0:
            kernel = kernel[order]
        middleware.append(Layer(f"middleware_fc_embedder/{name}", "dense", kernel, _t(m.bias)))
    head = Layer(head_name, "dense", _t(net.head.weight).T, _t(net.head.bias))
    log_std = _t(net.log_std).reshape(1, -1) if hasattr(net, "log_std") else None
    return Tower(_sorted_by_sensor(embedders), middleware, head, log_std)


def _sorted_by_sensor(embedders: list[Embedder]) -> list[Embedder]:
    keys = [e.key for e in embedders]
    ordered = sorted(embedders, key=lambda e: e.sensor)
    if [e.key for e in ordered] != keys:  # racerlab sorts by its input names: the concatenation would differ
        raise ConfigError(f"sensor order {[e.sensor for e in ordered]} differs from racerlab's {keys}; "
                          "this combination cannot be exported")
    return ordered


def _t(p) -> np.ndarray:
    return p.detach().cpu().numpy().astype(np.float32)


def ppo_towers(policy_net, value_net, metadata, shapes) -> tuple[Tower, Tower]:
    """(policy tower for network_1, value tower for network_0) of a racerlab clipped-PPO model."""
    head = "ppo_head_0/policy_fc" if metadata.action_space_type == "discrete" else "ppo_head_0/policy_mean"
    return (tower_from_torch(policy_net, metadata, shapes, head),
            tower_from_torch(value_net, metadata, shapes, "v_values_head_0/output"))


# ---- coach -> racerlab ----------------------------------------------------------------------------


def load_into_torch(net, variables: Callable[[str], np.ndarray | None], network: str, metadata, shapes,
                    where: str, prefix: str = PREFIX) -> None:
    """Copy a coach network's variables (looked up by name; None when absent) into a racerlab net in place.

    The expected variables are the ones `tower_from_torch` names for this net; each must be present
    with the transposed shape of racerlab's parameter, else a ConfigError names the variable.
    """
    import torch

    head_name = _head_name(net, metadata)
    template = tower_from_torch(net, metadata, shapes, head_name)
    wanted = template.variables(network, prefix)
    got = {}
    for name, like in wanted.items():
        value = variables(name)
        if value is None:
            raise ConfigError(f"{where}: no variable {name}; the model is not a {metadata.neural_network} "
                              f"network with sensors {list(metadata.sensor)}, or not clipped PPO")
        value = np.asarray(value, dtype=np.float32)
        if value.shape != like.shape:
            _raise_shape(where, name, value.shape, like.shape, metadata)
        if not np.isfinite(value).all():
            raise ConfigError(f"{where}: variable {name} holds NaN or infinite values (the training diverged); "
                              "import an earlier checkpoint of the model")
        got[name] = value
    state = _torch_state(net, template, got, network, prefix)
    net.load_state_dict({k: torch.as_tensor(v) for k, v in state.items()}, strict=True)


def _head_name(net, metadata) -> str:
    if hasattr(net, "discrete"):
        return "ppo_head_0/policy_fc" if metadata.action_space_type == "discrete" else "ppo_head_0/policy_mean"
    return "v_values_head_0/output"


def _raise_shape(where, name, have, want, metadata) -> None:
    if name.endswith(("policy_fc/kernel", "policy_fc/bias")) and metadata.action_space_type == "discrete":
        raise ConfigError(f"{where}: the checkpoint has {have[-1]} actions but model_metadata.json lists "
                          f"{want[-1]}; use the model_metadata.json the model was trained with")
    raise ConfigError(f"{where}: variable {name} has shape {list(have)}, expected {list(want)} for "
                      f"{metadata.neural_network} with sensors {list(metadata.sensor)}")


def _torch_state(net, template: Tower, got: dict, network: str, prefix: str) -> dict[str, np.ndarray]:
    """Invert `tower_from_torch`: TF-layout arrays back to racerlab's state-dict entries."""
    from torch import nn

    state = {k: v.detach().cpu().numpy() for k, v in net.state_dict().items()}
    base = f"{prefix}/{network}/"
    body = net.body

    def put(module_name: str, layer: Layer, kernel: np.ndarray) -> None:
        state[f"{module_name}.weight"] = kernel
        state[f"{module_name}.bias"] = got[f"{base}{layer.name}/bias"]

    for emb, key in zip(template.embedders, [e.key for e in template.embedders], strict=True):
        mods = [f"body.embedders.{key}.net.{i}" for i, m in enumerate(body.embedders[key].net)
                if isinstance(m, nn.Linear | nn.Conv2d)]
        for mod, layer in zip(mods, emb.layers, strict=True):
            k = got[f"{base}{layer.name}/kernel"]
            if layer.kind == "conv":
                k = k.transpose(3, 2, 0, 1)
            elif layer.kind == "pointwise":
                k = k.T[:, :, None, None]
            else:
                k = k.T
            put(mod, layer, k)
    order = _flat_order(body)
    mids = [f"body.middleware.{i}" for i, m in enumerate(body.middleware) if isinstance(m, nn.Linear)]
    for i, (mod, layer) in enumerate(zip(mids, template.middleware, strict=True)):
        k = got[f"{base}{layer.name}/kernel"]
        if i == 0:
            k = k[np.argsort(order)]
        put(mod, layer, k.T)
    put("head", template.head, got[f"{base}{template.head.name}/kernel"].T)
    if template.log_std is not None:
        state["log_std"] = got[f"{base}ppo_head_0/policy_log_std"].reshape(-1)
    return state


def _flat_order(body) -> np.ndarray:
    """For each position of TF's concatenated embedding (each camera flattened (y, x, c)), racerlab's index
    (each camera flattened (c, y, x)); both concatenate the embedders in the same order."""
    perms, offset = [], 0
    for key in body.keys:
        emb = body.embedders[key]
        if hasattr(emb, "feature_map"):
            h, w, c = emb.feature_map
            perms.append(offset + np.arange(c * h * w).reshape(c, h, w).transpose(1, 2, 0).reshape(-1))
        else:
            perms.append(offset + np.arange(emb.out_dim))
        offset += emb.out_dim
    return np.concatenate(perms)
