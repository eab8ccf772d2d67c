"""Where a training's wall time goes, per observation kind, and how fast the learner runs beside its limit.

For each observation kind (a fresh model from `racerlab init` with AWS default hyperparameters: batch_size
64, num_epochs 10, 20 episodes per iteration) it trains a few iterations and prints one JSON line with
- the share of the iterations' wall time spent collecting (the simulator, the sensor and acting; reward
  calls excluded), calling the reward function (building params included), updating, evaluating, and
  logging + checkpointing (the rest of the iteration); `collect_with_reward` adds the training episodes'
  reward calls to collecting (AWS calls the reward function inside the environment's step, so both
  readings are defensible: the JSON gives both);
- the learner's gradient steps per second beside the FLOP-based limit (`racerlab.agent.flops`: the
  networks' FLOPs over a matmul/conv rate measured now on this machine) and the share of it reached;
- env steps per second while collecting and overall, torch's thread count and the load average.

The machine may be shared: read shares and ratios, not absolute seconds, and compare runs taken together.

Usage: python benchmarks/train_throughput.py [--kinds features camera] [--iterations 4] [--track NAME]
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

import torch

from racerlab.agent.flops import gradient_step_limit
from racerlab.agent.networks import observation_shapes
from racerlab.model import init_model
from racerlab.train.loop import Trainer


class _Clock:
    """Accumulates the seconds spent in wrapped calls, by phase."""

    def __init__(self):
        self.seconds: dict[str, float] = {}

    def wrap(self, phase: str, fn):
        def timed(*args, **kwargs):
            t0 = time.perf_counter()
            try:
                return fn(*args, **kwargs)
            finally:
                self.seconds[phase] = self.seconds.get(phase, 0.0) + time.perf_counter() - t0

        return timed


class _TimedReward:
    """Stands in for a world's RewardCaller; the params are built lazily inside the call, so both count."""

    def __init__(self, caller, clock: _Clock, phase: str):
        self.caller = caller
        self.call = clock.wrap(phase, caller.__call__)

    def __call__(self, *args, **kwargs):
        return self.call(*args, **kwargs)


def _instrument(trainer: Trainer, clock: _Clock) -> None:
    trainer.iterate = clock.wrap("iteration", trainer.iterate)
    trainer.collector.collect = clock.wrap("collect", trainer.collector.collect)
    trainer.agent.learn = clock.wrap("update", trainer.agent.learn)
    trainer._evaluate = clock.wrap("evaluate", trainer._evaluate)
    for world in trainer.collector.worlds:
        world.reward = _TimedReward(world.reward, clock, "reward_collect")
    trainer.eval_world.reward = _TimedReward(trainer.eval_world.reward, clock, "reward_evaluate")


def _example_minibatch(trainer: Trainer, size: int) -> dict[str, torch.Tensor]:
    """Random observations shaped as the training's, `size` of them (uint8 images, float vectors)."""
    shapes = observation_shapes(trainer.eval_world.observation.space, trainer.metadata)
    return {k: torch.randint(0, 256, (size, *s), dtype=torch.uint8) if len(s) == 3 else torch.randn(size, *s)
            for k, s in shapes.items()}


def measure(kind: str, iterations: int, track: str | None, threads: int | None) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        folder = init_model(Path(tmp) / "m", track=track, sensor=kind)
        overrides = {"iterations": iterations}
        trainer = Trainer(folder.path, progress=False, **overrides)
        if threads:
            torch.set_num_threads(threads)
            trainer.agent.threads = threads  # PPO's torch update sets its count again each time
        clock = _Clock()
        _instrument(trainer, clock)
        load_before = os.getloadavg()
        result = trainer.run()
        load_after = os.getloadavg()
    sec = clock.seconds
    wall = sec["iteration"]
    r_collect, r_eval = sec.get("reward_collect", 0.0), sec.get("reward_evaluate", 0.0)
    phases = {"collect": sec["collect"] - r_collect, "reward": r_collect + r_eval, "update": sec["update"],
              "evaluate": sec.get("evaluate", 0.0) - r_eval}
    phases["logging"] = wall - sum(phases.values())
    hist = result.history
    grad_steps = sum(h.get("charts/gradient_steps", 0.0) for h in hist)
    mb = int(hist[-1].get("charts/minibatch_size", 64)) if hist else 64
    limit = gradient_step_limit([trainer.agent.policy_net, trainer.agent.value_net],
                                _example_minibatch(trainer, mb))
    steps_per_s = grad_steps / sec["update"] if sec["update"] else float("nan")
    collected = sum(h["collect_seconds"] for h in hist)
    return {
        "bench": "train_throughput", "observation": kind, "track": track or "lab_technical",
        "iterations": result.iterations, "env_steps": result.env_steps,
        "learned_steps_per_iteration": round(hist[-1]["train_steps"] / len(hist)) if hist else 0,
        "wall_s": round(wall, 2),
        "shares": {k: round(v / wall, 3) for k, v in phases.items()},
        "collect_with_reward": round((phases["collect"] + r_collect) / wall, 3),
        "seconds": {k: round(v, 2) for k, v in phases.items()},
        "gradient_steps": int(grad_steps), "gradient_steps_per_s": round(steps_per_s, 1),
        **limit.to_json(),
        "share_of_limit": round(steps_per_s / limit.steps_per_s, 3),
        "collect_env_steps_per_s": round(result.env_steps / collected) if collected else None,
        "overall_env_steps_per_s": round(result.env_steps / wall),
        "torch_threads": torch.get_num_threads(), "cpu_count": os.cpu_count(),
        "loadavg_1min_before_after": [round(load_before[0], 2), round(load_after[0], 2)],
    }


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--kinds", nargs="+", default=["features", "camera"], choices=["features", "camera", "lidar"])
    ap.add_argument("--iterations", type=int, default=4)
    ap.add_argument("--track", default=None, help="track name or .npy path (default: lab_technical)")
    ap.add_argument("--threads", type=int, default=None, help="torch threads (default: the training's own)")
    args = ap.parse_args()
    for kind in args.kinds:
        print(json.dumps(measure(kind, args.iterations, args.track, args.threads)), flush=True)


if __name__ == "__main__":
    main()
