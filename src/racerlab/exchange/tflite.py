"""The car's frozen graph converted to TensorFlow Lite the way the community car converts it.

The community car stack (aws-deepracer-community/deepracer-custom-car, `model_optimizer_node.py`) makes its
`.tflite` from the uploaded `model.pb` with TensorFlow's v1 `TFLiteConverter.from_frozen_graph`: input arrays =
the sensor placeholders with batch 1 (`[1, 120, 160, C]`, `[1, 64]`), output array = the policy node. racerlab
makes the same call on the same graph (`racerlab[tflite]`: TensorFlow writes it, `ai-edge-litert`'s interpreter,
the car's runtime, reads it back in the tests). It keeps float32 weights; the car's own conversion stores them as
float16 by default (its `--precision FP16`), which is why a car-made file differs in the 4th decimal.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

from racerlab.errors import RacerlabError

EXTRA_HINT = "pip install 'racerlab[tflite]'"


def _tf_v1():
    os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "2")  # the converter's progress lines, as the car sets it
    try:
        import tensorflow.compat.v1 as tf
    except ImportError:
        raise RacerlabError(f"exporting to TFLite needs TensorFlow's converter; {EXTRA_HINT}") from None
    return tf


def tflite_from_frozen_graph(pb: bytes, inputs: dict[str, tuple[int, ...]], output: str, fp16: bool = False) -> bytes:
    """The `.tflite` flatbuffer of a frozen GraphDef: `inputs` placeholder name -> one observation's shape.
    `fp16` stores the weights as float16, as the community car's converter does by default (`--precision FP16`)."""
    tf = _tf_v1()
    with tempfile.TemporaryDirectory(prefix="racerlab-tflite-") as tmp:
        path = Path(tmp) / "model.pb"
        path.write_bytes(pb)
        converter = tf.lite.TFLiteConverter.from_frozen_graph(
            str(path), input_arrays=list(inputs), output_arrays=[output],
            input_shapes={name: [1, *shape] for name, shape in inputs.items()})
        if fp16:
            converter.optimizations = [tf.lite.Optimize.DEFAULT]
            converter.target_spec.supported_types = [tf.float16]
        try:
            return converter.convert()
        except Exception as exc:  # noqa: BLE001 - the converter raises ConverterError, ValueError, ...
            first = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
            raise RacerlabError(f"TensorFlow's TFLite converter refused the car graph ({first}); "
                                "export --car and report the model's sensors and network") from None
