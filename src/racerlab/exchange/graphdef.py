"""Frozen TensorFlow GraphDefs (`model.pb`) written and read without TensorFlow.

TensorFlow's graph protos ship compiled in the `tensorboard` wheel (`tensorboard.compat.proto`), so a
frozen graph is built node by node with plain `protobuf`: Placeholder, Const, RealDiv, Conv2D (NHWC,
VALID), BiasAdd, Relu, Reshape, ConcatV2, MatMul, Softmax / Identity / Tanh. That is the op set the stock
car's OpenVINO 2021 model optimizer and the community car's `convert_model` / TFLite converter accept.
Weights are `Const` nodes named like coach's variables, so one reader serves console, DRfC and racerlab
graphs alike.
"""

from __future__ import annotations

import math

import numpy as np

from racerlab.errors import ConfigError, RacerlabError
from racerlab.exchange.coach import Tower

EXTRA_HINT = "pip install 'racerlab[export]'"
PRODUCER = 26  # GraphDef version of TensorFlow 1.1x, which the car's converters read
MAX_CONST_VALUES = 1 << 26  # 256 MiB of float32; the largest AWS layer (FC 512 of a 5-layer CNN) is far smaller
MAX_RANK = 8


def _protos():
    try:
        from tensorboard.compat.proto import (
            attr_value_pb2,
            graph_pb2,
            node_def_pb2,
            tensor_pb2,
            tensor_shape_pb2,
            types_pb2,
        )
    except ImportError:
        raise RacerlabError(f"writing or reading a TensorFlow model.pb needs TensorFlow's graph protos from the "
                            f"tensorboard package; {EXTRA_HINT}") from None
    return attr_value_pb2, graph_pb2, node_def_pb2, tensor_pb2, tensor_shape_pb2, types_pb2


class _Builder:
    """Appends nodes to a GraphDef; each method returns the new node's name."""

    def __init__(self):
        self.av, graph_pb2, self.nd, self.tp, self.ts, self.types = _protos()
        self.graph = graph_pb2.GraphDef()
        self.graph.versions.producer = PRODUCER
        self.f32 = self.types.DT_FLOAT

    def _shape(self, dims):
        return self.ts.TensorShapeProto(dim=[self.ts.TensorShapeProto.Dim(size=int(d)) for d in dims])

    def node(self, name, op, inputs=(), **attrs) -> str:
        n = self.graph.node.add()
        n.name, n.op = name, op
        n.input.extend(inputs)
        for k, v in attrs.items():
            n.attr[k].CopyFrom(v)
        return name

    def type_attr(self, dtype=None):
        return self.av.AttrValue(type=dtype if dtype is not None else self.f32)

    def const(self, name, array) -> str:
        a = np.array(array, order="C")  # keeps 0-d scalars 0-d (ascontiguousarray would make them 1-d)
        dtype = self.types.DT_INT32 if a.dtype.kind == "i" else self.f32
        a = a.astype(np.int32 if dtype == self.types.DT_INT32 else np.float32)
        tensor = self.tp.TensorProto(dtype=dtype, tensor_shape=self._shape(a.shape), tensor_content=a.tobytes())
        return self.node(name, "Const", dtype=self.type_attr(dtype), value=self.av.AttrValue(tensor=tensor))

    def placeholder(self, name, dims) -> str:
        return self.node(name, "Placeholder", dtype=self.type_attr(), shape=self.av.AttrValue(shape=self._shape(dims)))

    def op(self, name, op, inputs, **extra) -> str:
        return self.node(name, op, inputs, T=self.type_attr(), **extra)

    def ints(self, values):
        return self.av.AttrValue(list=self.av.AttrValue.ListValue(i=list(values)))


def build_graph(tower: Tower, scope: str, output: str, activation: str):
    """A frozen GraphDef of `tower`: placeholders `<prefix>/network_0/<SENSOR>/<SENSOR>` (images raw 0-255,
    NHWC), weights under `scope` (e.g. `.../online/network_1`), output node `output` = softmax, identity
    (continuous PPO mean) or tanh (SAC mean) of the head."""
    b = _Builder()
    input_scope = scope.rsplit("/", 1)[0] + "/network_0"
    embeddings = []
    for emb in tower.embedders:
        x = b.placeholder(f"{input_scope}/{emb.sensor}/{emb.sensor}", (-1, *emb.shape))
        if emb.image:  # coach's embedder divides images by input_rescaling = 255
            x = b.op(f"{scope}/{emb.sensor}/truediv", "RealDiv",
                     [x, b.const(f"{scope}/{emb.sensor}/truediv/y", np.float32(255.0))])
        for layer in emb.layers:
            x = _layer(b, scope, layer, x)
        if emb.image:
            flat = int(np.prod(feature_map(emb)))
            x = b.node(f"{scope}/{emb.sensor}/Flatten/Reshape", "Reshape",
                       [x, b.const(f"{scope}/{emb.sensor}/Flatten/shape", np.array([-1, flat], np.int32))],
                       T=b.type_attr(), Tshape=b.type_attr(b.types.DT_INT32))
        embeddings.append(x)
    if len(embeddings) > 1:
        x = b.node(f"{scope}/merger", "ConcatV2",
                   [*embeddings, b.const(f"{scope}/merger/axis", np.array(-1, np.int32))],
                   N=b.av.AttrValue(i=len(embeddings)), T=b.type_attr(), Tidx=b.type_attr(b.types.DT_INT32))
    for layer in tower.middleware:
        x = _layer(b, scope, layer, x)
    x = _layer(b, scope, tower.head, x, relu=False)
    b.op(output, {"softmax": "Softmax", "identity": "Identity", "tanh": "Tanh"}[activation], [x])
    return b.graph


def feature_map(emb) -> tuple[int, int, int]:
    h, w, c = emb.shape
    for layer in emb.layers:
        k = layer.kernel.shape[0] if layer.kind == "conv" else 1
        h, w, c = (h - k) // layer.stride + 1, (w - k) // layer.stride + 1, layer.kernel.shape[-1]
    return h, w, c


def _layer(b: _Builder, scope: str, layer, x: str, relu: bool = True) -> str:
    base = f"{scope}/{layer.name}"
    kernel = b.const(f"{base}/kernel", layer.kernel)
    if layer.kind == "dense":
        x = b.op(f"{base}/MatMul", "MatMul", [x, kernel], transpose_a=b.av.AttrValue(b=False),
                 transpose_b=b.av.AttrValue(b=False))
    else:
        if layer.kind == "pointwise":  # Keras Dense on a feature map: a 1x1 convolution
            kernel = b.const(f"{base}/kernel_1x1", layer.kernel[None, None])
        x = b.op(f"{base}/Conv2D", "Conv2D", [x, kernel], strides=b.ints([1, layer.stride, layer.stride, 1]),
                 padding=b.av.AttrValue(s=b"VALID"), data_format=b.av.AttrValue(s=b"NHWC"),
                 dilations=b.ints([1, 1, 1, 1]), use_cudnn_on_gpu=b.av.AttrValue(b=True))
    x = b.op(f"{base}/BiasAdd", "BiasAdd", [x, b.const(f"{base}/bias", layer.bias)],
             data_format=b.av.AttrValue(s=b"NHWC"))
    return b.op(f"{base}/Relu", "Relu", [x]) if relu else x


def graph_bytes(graph) -> bytes:
    return graph.SerializeToString(deterministic=True)


# ---- reading ------------------------------------------------------------------------------------


class FrozenGraph:
    """A parsed model.pb: its float constants by node name, its placeholders and its node names."""

    def __init__(self, path, data: bytes):
        _, graph_pb2, _, _, _, types = _protos()
        graph = graph_pb2.GraphDef()
        try:
            graph.ParseFromString(data)
        except Exception as exc:  # noqa: BLE001 - protobuf raises DecodeError and friends
            raise ConfigError(f"{path}: not a TensorFlow GraphDef ({type(exc).__name__}); export the frozen "
                              "model.pb again or import the checkpoint instead") from None
        if not graph.node:
            raise ConfigError(f"{path}: the GraphDef has no nodes; export the frozen model.pb again")
        self.path = path
        self.nodes = {n.name: n for n in graph.node}
        self.placeholders = {n.name: [d.size for d in n.attr["shape"].shape.dim]
                             for n in graph.node if n.op == "Placeholder"}
        self._types = types

    def constant(self, name: str) -> np.ndarray | None:
        node = self.nodes.get(name)
        if node is None or node.op != "Const":
            return None
        t = node.attr["value"].tensor
        if t.dtype != self._types.DT_FLOAT:
            raise ConfigError(f"{self.path}: constant {name} is not float32; only float32 models are supported")
        shape = [int(d.size) for d in t.tensor_shape.dim]
        if len(shape) > MAX_RANK or any(d < 0 for d in shape):
            raise ConfigError(f"{self.path}: constant {name} has shape {shape}; a weight has 0-{MAX_RANK} "
                              "dimensions of size >= 0. Export the frozen model.pb again")
        size = math.prod(shape)  # Python integers: no overflow, checked before anything is allocated
        if size > MAX_CONST_VALUES:
            raise ConfigError(f"{self.path}: constant {name} claims shape {shape} ({size} values), more than any "
                              f"DeepRacer network's layer (<= {MAX_CONST_VALUES}); not reading it")
        if t.tensor_content:
            a = np.frombuffer(t.tensor_content, dtype="<f4", count=len(t.tensor_content) // 4)
        else:
            a = np.asarray(t.float_val, dtype=np.float32)
            a = np.full(size, a[0] if a.size else 0.0, np.float32) if a.size <= 1 else a
        if a.size != size:
            raise ConfigError(f"{self.path}: constant {name} holds {a.size} values for shape {shape}")
        return a.reshape(shape).copy()

    def lookup(self, name: str) -> np.ndarray | None:
        """A variable's frozen value by its coach name (the Const itself, or what its `/read` reads)."""
        value = self.constant(name)
        if value is None and f"{name}/read" in self.nodes:
            src = self.nodes[f"{name}/read"].input[0].lstrip("^").split(":")[0]
            value = self.constant(src)
        return value
