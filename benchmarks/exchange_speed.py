"""Export and import timings for the console's default model: front camera, 3-layer CNN ("shallow"),
10 discrete actions, clipped PPO. One JSON line per measurement.

Budget (issue 13): `racerlab export MODEL --car` <= 10 s for the 3-layer CNN on this machine. Imports of
TensorFlow and PyTorch are paid once, before the clock starts; the anchor is `torch.save` of the same
checkpoint (racerlab's own save), so the ratio stays meaningful on a loaded machine.

    python benchmarks/exchange_speed.py [--repeat 3]
"""

from __future__ import annotations

import argparse
import io
import json
import shutil
import tempfile
import time
from pathlib import Path

import torch

from racerlab.agent import PPO
from racerlab.exchange import export_car, export_drfc, export_droa, import_model
from racerlab.exchange.local import aws_shapes
from racerlab.model import TrainingState, init_model


def make_model(path: Path):
    folder = init_model(path, sensor="camera")
    meta = folder.metadata()
    agent = PPO(aws_shapes(meta), meta, device="cpu", seed=0)
    state = TrainingState(agent.state_dict(), meta.to_json(), iteration=3, train_steps=1200)
    folder.save_state(state)
    return folder, state.to_dict()


def best_of(fn, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return min(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    import tensorflow  # noqa: F401 - imported before timing, as a long-running process would have it

    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        folder, state = make_model(root / "cam")
        anchor = best_of(lambda: torch.save(state, io.BytesIO()), args.repeat)

        def drfc():
            shutil.rmtree(root / "drfc", ignore_errors=True)
            export_drfc(folder.path, root / "drfc")

        def imported(src):
            shutil.rmtree(root / "back", ignore_errors=True)
            import_model(src, root / "back")

        runs = {
            "export_car": lambda: export_car(folder.path, root / "cam-car.tar.gz"),
            "export_droa": lambda: export_droa(folder.path, root / "cam-droa.tar.gz"),
            "export_drfc": drfc,
            "import_car_archive": lambda: imported(root / "cam-car.tar.gz"),
            "import_droa_archive": lambda: imported(root / "cam-droa.tar.gz"),
        }
        print(json.dumps({"what": "anchor_torch_save_checkpoint", "seconds": round(anchor, 3)}))
        for name, fn in runs.items():
            s = best_of(fn, args.repeat)
            print(json.dumps({"what": name, "seconds": round(s, 3), "vs_anchor": round(s / anchor, 1),
                              "budget_s": 10.0 if name == "export_car" else None}))


if __name__ == "__main__":
    main()
