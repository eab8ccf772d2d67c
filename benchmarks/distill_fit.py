"""The camera student's fit and greedy inference (racerlab.agent.imitate) by precision, minibatch and threads.

For the AWS 3-layer CNN on 120x160 grey frames (the console's camera model) it times `Imitation.fit` on random
frames and targets (rows per second, best of `--repeat`) and `Imitation.greedy` on a batch of 64 (frames per
second), for float32 and bfloat16 autocast at each minibatch and thread count, and prints one JSON line each with
the load average (the machine may be shared: compare rows taken in the same run).

Usage: python benchmarks/distill_fit.py [--batches 64 256] [--threads 1 2] [--steps 4] [--repeat 3]
       [--device cpu|cuda]
"""

from __future__ import annotations

import argparse
import json
import os
import time

import gymnasium as gym
import numpy as np
import torch

from racerlab.agent import PPO
from racerlab.agent.imitate import Imitation
from racerlab.model.init import make_metadata


def measure(precision: str, batch: int, threads: int, steps: int, repeat: int, device: str) -> dict:
    meta = make_metadata("camera", "continuous", max_speed=4.0)
    agent = PPO(gym.spaces.Box(0, 255, (120, 160, 1), np.uint8), meta, device=device, seed=0)
    imitation = Imitation(agent, batch_size=batch, precision=precision, threads=threads)
    rng = np.random.default_rng(0)
    frames = rng.integers(0, 256, (max(batch * steps, 256), 120, 160, 1), dtype=np.uint8)
    targets = rng.uniform(-1, 1, (len(frames), 2)).astype(np.float32)
    imitation.fit({"camera": frames}, targets, 1)  # warm-up: oneDNN picks its kernels
    fit_s = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        imitation.fit({"camera": frames}, targets, steps)
        fit_s.append(time.perf_counter() - t0)
    torch.set_num_threads(threads)
    greedy_s = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        imitation.greedy({"camera": frames[:64]})
        greedy_s.append(time.perf_counter() - t0)
    return {"bench": "distill_fit", "device": device, "precision": precision,
            "autocast": str(imitation.dtype).replace("torch.", "") if imitation.dtype else "float32",
            "minibatch": batch, "threads": threads, "fit_rows_per_s": round(batch * steps / min(fit_s), 1),
            "greedy_frames_per_s": round(64 / min(greedy_s), 1), "loadavg_1min": round(os.getloadavg()[0], 2)}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--batches", type=int, nargs="+", default=[64, 256])
    ap.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--steps", type=int, default=4, help="gradient steps per timing")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--device", choices=["cpu", "cuda"], default="cpu")
    args = ap.parse_args()
    for threads in args.threads:
        for precision in ("float32", "bfloat16"):
            for batch in args.batches:
                print(json.dumps(measure(precision, batch, threads, args.steps, args.repeat, args.device)),
                      flush=True)


if __name__ == "__main__":
    main()
