"""Steps/s of racerlab's SB3 adapter (one batched env) against SB3's DummyVecEnv over N single envs.

Both step the same track, reward function and random actions through SB3's `VecEnv.step`, episodes
resetting themselves as SB3 expects; `--rounds` alternating timed runs each, after a warm-up (numba
compilation), and the figures are the medians. One JSON line per car count; `ratio` is adapter / dummy,
the figure to quote (both measured in the same run, so a loaded machine slows both alike).

    python benchmarks/sb3_adapter.py [--num-envs 8 64] [--steps 300] [--rounds 3] [--track lab_oval]
"""

from __future__ import annotations

import argparse
import json
import statistics
import time

import numpy as np
from stable_baselines3.common.vec_env import DummyVecEnv

from racerlab.sim.env import DeepRacerEnv
from racerlab.sim.sb3 import DeepRacerSB3VecEnv


def centre_reward(params):
    w = params["track_width"]
    d = params["distance_from_center"]
    return 1.0 if d <= 0.1 * w else 0.5 if d <= 0.25 * w else 1e-3


def steps_per_s(venv, actions) -> float:
    venv.reset()
    start = time.perf_counter()
    for a in actions:
        venv.step(a)
    return actions.shape[0] * actions.shape[1] / (time.perf_counter() - start)


def measure(num_envs: int, steps: int, rounds: int, track: str) -> dict:
    kwargs = {"track": track, "reward_function": centre_reward, "max_episode_steps": 500}
    adapter = DeepRacerSB3VecEnv(num_envs, **kwargs)
    dummy = DummyVecEnv([lambda: DeepRacerEnv(**kwargs)] * num_envs)
    actions = np.random.default_rng(0).integers(0, adapter.action_space.n, size=(steps, num_envs))
    steps_per_s(adapter, actions[:20]), steps_per_s(dummy, actions[:20])  # warm-up: numba compiles
    ours, theirs = [], []
    for _ in range(rounds):
        ours.append(steps_per_s(adapter, actions))
        theirs.append(steps_per_s(dummy, actions))
    a, d = statistics.median(ours), statistics.median(theirs)
    return {"benchmark": "sb3_adapter", "track": track, "num_envs": num_envs, "steps": steps, "rounds": rounds,
            "adapter_steps_per_s": round(a), "dummy_vec_env_steps_per_s": round(d), "ratio": round(a / d, 2)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--num-envs", type=int, nargs="+", default=[8, 64])
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--track", default="lab_oval")
    args = parser.parse_args()
    for n in args.num_envs:
        print(json.dumps(measure(n, args.steps, args.rounds, args.track)), flush=True)


if __name__ == "__main__":
    main()
