"""Inference speed of each export format on this machine's CPU, one frame at a time on one core, as the car runs.

For each model: racerlab's own policy in PyTorch (the anchor), the ONNX export in onnxruntime, the TFLite export
in LiteRT's interpreter (float32, as `racerlab export --tflite` writes it, and float16 weights, as the community
car's own converter makes it by default), and the car's model.pb in OpenVINO (`convert_model`, f32, batch 1).
Every runtime gets one thread and the process is pinned to one core (`--core`). Frames: the AWS simulator's
frames in ../shared/reference/gazebo_frames, then racerlab renders (`racerlab.exchange.frames`).

One JSON line per (model, format): `frames_per_s` (best of `--repeat` passes over `--frames` frames),
`ms_per_frame`, `vs_torch` (frames/s over PyTorch's in the same run: stable on a loaded machine), `agree`
(frames whose chosen action matches racerlab's; for continuous models: both outputs within 1e-4),
`max_abs_diff`, and the load average. The car's budget is 15-30 frames a second (its camera runs at 15 fps on the
stock car, 30 on the community car).

    python benchmarks/export_inference.py [MODEL ...] [--frames 300] [--repeat 3] [--core 0]

Without MODEL it makes untrained models for the car's sensor sets (speed does not depend on the weights):
front camera with the 3-layer CNN (the tour's), the same with the 5-layer CNN, stereo, camera + lidar.
"""

from __future__ import annotations

import argparse
import json
import os
import tarfile
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from racerlab.exchange import export_onnx, export_tflite
from racerlab.exchange.export import car_feed, car_inputs, frozen_graph, policy_tower
from racerlab.exchange.frames import car_observations
from racerlab.exchange.graphdef import graph_bytes
from racerlab.exchange.local import open_for_export
from racerlab.exchange.runtimes import OnnxRunner, OpenVinoRunner, TfliteRunner
from racerlab.exchange.tflite import tflite_from_frozen_graph

REAL = Path(__file__).resolve().parents[1].parent / "shared" / "reference" / "gazebo_frames"
SETS = [("camera", None), ("camera", "DEEP_CONVOLUTIONAL_NETWORK"), ("stereo", None), ("lidar", None)]


def untrained(root: Path, sensor: str, network: str | None) -> Path:
    """A model folder from `racerlab init` with one checkpoint of a fresh agent."""
    from racerlab.agent import PPO
    from racerlab.exchange.local import aws_shapes
    from racerlab.model import TrainingState, init_model

    folder = init_model(root / f"{sensor}-{(network or 'shallow').lower()}", sensor=sensor, max_speed=2.0)
    if network:
        data = json.loads(folder.metadata_path.read_text())
        folder.metadata_path.write_text(json.dumps({**data, "neural_network": network}))
    meta = folder.metadata()
    agent = PPO(aws_shapes(meta), meta, device="cpu", seed=0)
    folder.save_state(TrainingState(agent.state_dict(), meta.to_json(), iteration=1, train_steps=1))
    return folder.path


class TorchRunner:
    """racerlab's own policy, one frame at a time: softmax probabilities, the mean, or SAC's tanh(mean)."""

    def __init__(self, model):
        self.model = model

    def __call__(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        nets, discrete = self.model.networks, self.model.metadata.action_space_type == "discrete"
        n = len(next(iter(obs.values())))
        rows = []
        with torch.no_grad():
            for i in range(n):
                x = {k: torch.as_tensor(v[i:i + 1]) for k, v in obs.items()}
                if "actor" in nets:
                    rows.append(nets["actor"].distribution(x).mode()[0].numpy())
                else:
                    out = nets["policy"](x)
                    rows.append((torch.softmax(out, -1) if discrete else out)[0].numpy())
        return np.stack(rows)


def rate(run, feed, repeat: int) -> tuple[float, np.ndarray]:
    """(best frames per second over `repeat` passes, the outputs)."""
    n = len(next(iter(feed.values())))
    run({k: v[:5] for k, v in feed.items()})  # warm-up
    best, out = 0.0, None
    for _ in range(repeat):
        t = time.perf_counter()
        out = run(feed)
        best = max(best, n / (time.perf_counter() - t))
    return best, out


def runners(opened, model, tmp: Path) -> dict:
    """format -> (runner, feeds racerlab observations (True) or the car's named inputs (False))."""
    def unpack(archive):
        with tarfile.open(archive) as tar:
            tar.extractall(archive.with_suffix(""), filter="data")
        return archive.with_suffix("")

    path = opened.folder.path
    onnx_dir = unpack(export_onnx(path, tmp / f"{opened.name}-onnx.tar"))
    lite_dir = unpack(export_tflite(path, tmp / f"{opened.name}-tflite.tar"))
    _, _, output, _ = policy_tower(model)
    fp16 = tmp / f"{opened.name}-fp16.tflite"
    fp16.write_bytes(tflite_from_frozen_graph(graph_bytes(frozen_graph(model)), car_inputs(model), output, fp16=True))
    return {
        "torch": (TorchRunner(model), True),
        "onnxruntime": (OnnxRunner(onnx_dir / "model.onnx"), False),
        "tflite": (TfliteRunner(lite_dir / "model.tflite"), False),
        "tflite-fp16 (the car's own conversion)": (TfliteRunner(fp16), False),
        "openvino (model.pb)": (OpenVinoRunner(lite_dir / "model.pb", car_inputs(model), output), False),
    }


def measure(model_dir: Path, tmp: Path, frames: int, repeat: int) -> None:
    opened, model = open_for_export(model_dir)
    obs, n_real = car_observations(model.shapes, frames, REAL)
    feed = car_feed(model, obs)
    discrete = model.metadata.action_space_type == "discrete"
    anchor, want = None, None
    for name, (run, racerlab_obs) in runners(opened, model, tmp).items():
        fps, out = rate(run, obs if racerlab_obs else feed, repeat)
        if anchor is None:
            anchor, want = fps, out
        diff = np.abs(out - want)
        agree = (out.argmax(1) == want.argmax(1)) if discrete else (diff.max(1) <= 1e-4)
        print(json.dumps({
            "model": opened.name, "sensors": list(model.metadata.sensor), "network": model.metadata.neural_network,
            "actions": model.metadata.action_space_type, "format": name, "frames_per_s": round(fps, 1),
            "ms_per_frame": round(1000.0 / fps, 3), "vs_torch": round(fps / anchor, 2),
            "agree": f"{int(agree.sum())}/{len(agree)}", "max_abs_diff": float(f"{diff.max():.3g}"),
            "frames": frames, "real_frames": n_real, "loadavg": os.getloadavg()[0]}), flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("models", nargs="*", type=Path, help="model folders (default: untrained models of each sensor set)")
    ap.add_argument("--frames", type=int, default=300)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--core", type=int, default=0, help="the CPU core to run on")
    args = ap.parse_args()
    os.sched_setaffinity(0, {args.core})
    torch.set_num_threads(1)
    with tempfile.TemporaryDirectory(prefix="racerlab-bench-") as tmp:
        models = args.models or [untrained(Path(tmp), s, n) for s, n in SETS]
        for m in models:
            measure(m, Path(tmp), args.frames, args.repeat)


if __name__ == "__main__":
    main()
