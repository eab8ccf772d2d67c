"""Run an exported policy in its consumer's own runtime: onnxruntime, the TFLite interpreter, OpenVINO.

Each runner takes the file and a batch of observations as the car feeds them ({placeholder name: float32
array}, cameras raw 0-255 NHWC) and returns the output node's values, one row per observation. The TFLite
runner feeds one frame at a time, as the car does (its model has batch 1). All run on `threads` CPU threads
(1 by default: the figure to compare with a car's single inference thread).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from racerlab.errors import RacerlabError


def _need(module: str, extra: str):
    import importlib

    try:
        return importlib.import_module(module)
    except ImportError:
        raise RacerlabError(f"running the export needs {module.split('.')[0]}; pip install 'racerlab[{extra}]'") \
            from None


class OnnxRunner:
    def __init__(self, path, threads: int = 1):
        ort = _need("onnxruntime", "onnx")
        opts = ort.SessionOptions()
        opts.intra_op_num_threads = opts.inter_op_num_threads = threads
        self.session = ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])
        self.output = self.session.get_outputs()[0].name

    def __call__(self, feed: dict[str, np.ndarray]) -> np.ndarray:
        return self.session.run([self.output], {k: np.asarray(v, np.float32) for k, v in feed.items()})[0]


class TfliteRunner:
    def __init__(self, path, threads: int = 1):
        interpreter = _need("ai_edge_litert.interpreter", "tflite").Interpreter
        self.path = path
        self.it = interpreter(model_path=str(path), num_threads=threads)
        self.it.allocate_tensors()
        self.inputs = {d["name"]: d["index"] for d in self.it.get_input_details()}
        self.output = self.it.get_output_details()[0]["index"]

    def __call__(self, feed: dict[str, np.ndarray]) -> np.ndarray:
        missing = set(self.inputs) - set(feed)
        if missing:
            raise RacerlabError(f"{self.path}: no value for the model's inputs {sorted(missing)}; feed every input by "
                                "its name (racerlab.exchange.export.car_feed gives them for a racerlab model)")
        n = len(next(iter(feed.values())))
        rows = []
        for i in range(n):
            for name, index in self.inputs.items():
                self.it.set_tensor(index, np.asarray(feed[name][i:i + 1], np.float32))
            self.it.invoke()
            rows.append(self.it.get_tensor(self.output)[0].copy())
        return np.stack(rows)


class OpenVinoRunner:
    """The car's `model.pb` through OpenVINO's `convert_model`, as the community car (OpenVINO 2022+) loads it."""

    def __init__(self, path, inputs: dict[str, tuple[int, ...]], output: str, batch: int = 1, threads: int = 1):
        """`batch` frames per call (a static shape, 1 as on the car), or 0 for any number (a dynamic batch)."""
        ov = _need("openvino", "test")
        model = ov.convert_model(str(Path(path)), input=[(f"{k}:0", [batch or -1, *s]) for k, s in inputs.items()],
                                 output=f"{output}:0")
        config = {"INFERENCE_PRECISION_HINT": "f32", "INFERENCE_NUM_THREADS": threads}
        self.compiled = ov.Core().compile_model(model, "CPU", config)
        self.batch = batch

    def __call__(self, feed: dict[str, np.ndarray]) -> np.ndarray:
        n = len(next(iter(feed.values())))
        step = self.batch or n
        out = []
        for i in range(0, n, step):
            chunk = {f"{k}:0": np.asarray(v[i:i + step], np.float32) for k, v in feed.items()}
            out.append(self.compiled(chunk)[self.compiled.output(0)])
        return np.concatenate(out)
