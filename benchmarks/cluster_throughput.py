"""Collection over Ray workers: env steps per second with the local Collector (the anchor), 1 and 2 Ray
workers, side by side in one run; the per-iteration overhead Ray adds (1 worker minus local, same cars
and episodes); and the bytes of weights and rollouts per iteration. One JSON line per measurement.

    python benchmarks/cluster_throughput.py [--cars 8] [--episodes 16] [--iterations 3] [--sensor features]
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time
from pathlib import Path

import torch

from racerlab.cluster.collector import RayCollector, array_bytes, connect
from racerlab.model import init_model
from racerlab.train.loop import Trainer


def emit(**fields) -> None:
    print(json.dumps(fields), flush=True)


def measure(collect, agent, episodes: int, iterations: int) -> tuple[float, float, int]:
    """Median seconds per collection, env steps per second and env steps of the last one."""
    times, steps = [], 0
    collect(agent, episodes, 10_000, 0)  # warm-up: numba compilation, actor start
    for _ in range(iterations):
        t = time.perf_counter()
        ro = collect(agent, episodes, 10_000, 0)
        times.append(time.perf_counter() - t)
        steps = ro.env_steps
    med = statistics.median(times)
    return med, steps / med, steps


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--cars", type=int, default=8)
    ap.add_argument("--episodes", type=int, default=16)
    ap.add_argument("--iterations", type=int, default=3)
    ap.add_argument("--sensor", default="features")
    ap.add_argument("--workers", type=int, nargs="*", default=[1, 2])
    args = ap.parse_args()
    model = Path(tempfile.mkdtemp(prefix="rlbench")) / "m"
    init_model(model, num_cars=args.cars, sensor=args.sensor)
    trainer = Trainer(model, progress=False)
    torch.set_num_threads(1)  # as each Ray worker runs: one core per worker
    agent = trainer.agent
    connect(num_cpus=2)
    local_s, local_rate, steps = measure(trainer.collector.collect, agent, args.episodes, args.iterations)
    emit(setup="local Collector (anchor)", cars=args.cars, episodes=args.episodes, env_steps=steps,
         seconds=round(local_s, 3), env_steps_per_s=round(local_rate))
    for workers in args.workers:
        col = RayCollector(model, workers, {"num_cars": args.cars * workers}, note=lambda s: None)
        s, rate, steps = measure(col.collect, agent, args.episodes * workers, args.iterations)
        rep = col.report
        emit(setup=f"{workers} Ray worker(s)", cars_per_worker=args.cars, episodes=args.episodes * workers,
             env_steps=steps, seconds=round(s, 3), env_steps_per_s=round(rate),
             ratio_to_local=round(rate / local_rate, 2), weights_bytes=rep.weights_bytes,
             rollout_bytes_per_worker=sorted(rep.rollout_bytes.values()),
             rollout_bytes_per_env_step=round(sum(rep.rollout_bytes.values()) / max(steps, 1), 1))
        if workers == 1:
            emit(measure="Ray overhead per iteration (1 worker minus local, same work)",
                 seconds=round(s - local_s, 3), share=round((s - local_s) / s, 3))
        col.close()
    ro = trainer.collector.collect(agent, args.episodes, 10_000, 0)
    emit(measure="rollout arrays per env step (local)", bytes=round(array_bytes(ro) / max(ro.env_steps, 1), 1))
    t = time.perf_counter()
    agent.learn(ro)
    learn_s = time.perf_counter() - t
    emit(measure="learner (driver, one core): PPO update of one iteration", learned_steps=int(ro.rewards.size),
         seconds=round(learn_s, 3), learned_steps_per_s=round(ro.rewards.size / learn_s),
         epochs=trainer.hp.num_epochs, batch_size=trainer.hp.batch_size)


if __name__ == "__main__":
    main()
