"""The car's policy as an ONNX model, built node by node from a coach `Tower` (as `graphdef` builds model.pb).

Inputs and output keep the frozen graph's names, so whatever looks tensors up by the car's names finds them:
`main_level/agent/main/online/network_0/<SENSOR>/<SENSOR>` (float32; cameras NHWC `[N, 120, 160, C]` raw 0-255,
the graph divides by 255 itself; lidars `[N, 64]` / `[N, 8]`), output `.../network_1/ppo_head_0/policy`
(softmax probabilities, the continuous mean, or SAC's tanh(mean)). The batch dimension is free (`N`).

ONNX convolutions are NCHW: each camera input is transposed to NCHW, convolved with the tower's kernels
(HWIO -> OIHW), and transposed back to NHWC before it is flattened, so the tower's dense layers (whose rows
follow TensorFlow's (H, W, C) flatten order) are used as they are. Ops: Transpose, Div, Conv, Relu, Reshape,
Concat, Gemm, Softmax / Identity / Tanh, opset 17 (onnxruntime 1.14 and later, OpenVINO 2023 and later).
"""

from __future__ import annotations

import numpy as np

from racerlab.errors import RacerlabError
from racerlab.exchange.coach import Tower
from racerlab.exchange.graphdef import feature_map

EXTRA_HINT = "pip install 'racerlab[onnx]'"
OPSET = 17


def _onnx():
    try:
        import onnx
        from onnx import helper, numpy_helper
    except ImportError:
        raise RacerlabError(f"exporting to ONNX needs the onnx package; {EXTRA_HINT}") from None
    return onnx, helper, numpy_helper


class _Builder:
    def __init__(self):
        self.onnx, self.helper, self.numpy_helper = _onnx()
        self.nodes, self.inits = [], []

    def const(self, name: str, array) -> str:
        self.inits.append(self.numpy_helper.from_array(np.ascontiguousarray(array), name))
        return name

    def op(self, name: str, op: str, inputs: list[str], **attrs) -> str:
        self.nodes.append(self.helper.make_node(op, inputs, [name], name=name, **attrs))
        return name


def build_onnx(tower: Tower, scope: str, output: str, activation: str):
    """An ONNX ModelProto of `tower`, named like `graphdef.build_graph(tower, scope, output, activation)`."""
    b = _Builder()
    h, tp = b.helper, b.onnx.TensorProto
    input_scope = scope.rsplit("/", 1)[0] + "/network_0"
    inputs, embeddings = [], []
    for emb in tower.embedders:
        name = f"{input_scope}/{emb.sensor}/{emb.sensor}"
        inputs.append(h.make_tensor_value_info(name, tp.FLOAT, ["N", *emb.shape]))
        x = name
        base = f"{scope}/{emb.sensor}"
        if emb.image:
            x = b.op(f"{base}/nchw", "Transpose", [x], perm=[0, 3, 1, 2])
            x = b.op(f"{base}/truediv", "Div", [x, b.const(f"{base}/truediv/y", np.array(255.0, np.float32))])
            for layer in emb.layers:
                x = _conv(b, scope, layer, x)
            x = b.op(f"{base}/nhwc", "Transpose", [x], perm=[0, 2, 3, 1])
            x = b.op(f"{base}/Flatten/Reshape", "Reshape",
                     [x, b.const(f"{base}/Flatten/shape", np.array([-1, np.prod(feature_map(emb))], np.int64))])
        else:
            for layer in emb.layers:
                x = _dense(b, scope, layer, x)
        embeddings.append(x)
    x = embeddings[0] if len(embeddings) == 1 else b.op(f"{scope}/merger", "Concat", embeddings, axis=-1)
    for layer in tower.middleware:
        x = _dense(b, scope, layer, x)
    x = _dense(b, scope, tower.head, x, relu=False)
    if activation == "softmax":
        b.op(output, "Softmax", [x], axis=-1)
    else:
        b.op(output, {"identity": "Identity", "tanh": "Tanh"}[activation], [x])
    width = tower.head.kernel.shape[1]
    graph = h.make_graph(b.nodes, "racerlab_policy", inputs, [h.make_tensor_value_info(output, tp.FLOAT, ["N", width])],
                         initializer=b.inits)
    model = h.make_model(graph, opset_imports=[h.make_opsetid("", OPSET)], producer_name="racerlab")
    model.ir_version = 8  # opset 17's IR version: read by onnxruntime >= 1.14
    b.onnx.checker.check_model(model)
    return model


def _conv(b: _Builder, scope: str, layer, x: str) -> str:
    base = f"{scope}/{layer.name}"
    if layer.kind == "pointwise":  # a dense layer on each position: a 1x1 convolution
        kernel = layer.kernel.T[:, :, None, None]
    else:
        kernel = layer.kernel.transpose(3, 2, 0, 1)  # HWIO -> OIHW
    x = b.op(f"{base}/Conv2D", "Conv", [x, b.const(f"{base}/kernel", kernel.astype(np.float32)),
                                         b.const(f"{base}/bias", layer.bias.astype(np.float32))],
             strides=[layer.stride, layer.stride], pads=[0, 0, 0, 0])
    return b.op(f"{base}/Relu", "Relu", [x])


def _dense(b: _Builder, scope: str, layer, x: str, relu: bool = True) -> str:
    base = f"{scope}/{layer.name}"
    x = b.op(f"{base}/MatMul", "Gemm", [x, b.const(f"{base}/kernel", layer.kernel.astype(np.float32)),
                                         b.const(f"{base}/bias", layer.bias.astype(np.float32))])
    return b.op(f"{base}/Relu", "Relu", [x]) if relu else x


def onnx_bytes(model) -> bytes:
    return model.SerializeToString(deterministic=True)
