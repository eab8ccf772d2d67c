"""Simulator throughput on one core: car-steps per second with the `features` observation.

Prints one JSON line per measurement:
- the vector env (autoreset, observation) at 1, 64 and 1024 cars without a reward function;
- the same with an AWS-style centre-line reward, and the cost per car-step of building the
  params and calling the Python reward (budget: <= 5 us).

Usage: python benchmarks/sim_throughput.py [--track NAME_OR_PATH] [--seconds 3] [--jitter]

`--jitter` drives the training car (the droa car with its measured step-length jitter, as `racerlab train` does);
without it the default car, exact 1/15 s steps.
"""

from __future__ import annotations

import argparse
import json
import os
import time

os.environ.setdefault("NUMBA_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from racerlab.sim.env import DeepRacerVectorEnv  # noqa: E402


def centre_line_reward(params):
    """The AWS console's 'follow the centre line' example."""
    track_width = params["track_width"]
    distance_from_center = params["distance_from_center"]
    marker_1 = 0.1 * track_width
    marker_2 = 0.25 * track_width
    marker_3 = 0.5 * track_width
    if distance_from_center <= marker_1:
        reward = 1.0
    elif distance_from_center <= marker_2:
        reward = 0.5
    elif distance_from_center <= marker_3:
        reward = 0.1
    else:
        reward = 1e-3
    return float(reward)


def measure(track, cars, reward, seconds, car=None):
    env = DeepRacerVectorEnv(cars, track, reward_function=reward, observation="features", car=car)
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    actions = rng.integers(0, env.single_action_space.n, size=(64, cars))
    for k in range(20):  # warm up (compilation is cached, but touch every path)
        env.step(actions[k % 64])
    steps = 0
    t0 = time.perf_counter()
    while True:
        for k in range(16):
            env.step(actions[(steps + k) % 64])
        steps += 16
        elapsed = time.perf_counter() - t0
        if elapsed >= seconds:
            break
    return cars * steps / elapsed


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--track", default="lab_technical")
    ap.add_argument("--seconds", type=float, default=3.0)
    ap.add_argument("--jitter", action="store_true", help="the training car: steps of jittered length")
    args = ap.parse_args()
    car = {"step_jitter": True} if args.jitter else None
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})
    results = {}
    for reward in (None, centre_line_reward):
        for cars in (1, 64, 1024):
            rate = measure(args.track, cars, reward, args.seconds, car)
            results[(reward is not None, cars)] = rate
            line = {"bench": "sim_features", "track": args.track, "cars": cars, "reward": reward is not None,
                    "jitter": args.jitter, "car_steps_per_s": round(rate)}
            if cars == 1024 and reward is None:
                line["budget"] = ">= 500000"
                line["x_drfc_gazebo_15_per_s"] = round(rate / 15)
            print(json.dumps(line), flush=True)
    for cars in (64, 1024):
        us = params_and_call_us(args.track, cars, args.seconds)
        print(json.dumps({"bench": "reward_params_and_call", "cars": cars, "us_per_car_step": round(us, 3),
                          "budget_us": 5.0}), flush=True)


def params_and_call_us(track, cars, seconds):
    """Building the AWS params dict and calling the reward, per car, with every car mid-episode."""
    env = DeepRacerVectorEnv(cars, track, reward_function=centre_line_reward)
    env.reset(seed=0)
    env.step(np.zeros(cars, dtype=np.int64))  # the prepare step
    env.step(np.zeros(cars, dtype=np.int64))
    world = env.unwrapped.world
    idx = np.arange(cars)
    calls = 0
    t0 = time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        world.reward(world.builder.each(idx), idx)
        calls += cars
    return (time.perf_counter() - t0) / calls * 1e6


if __name__ == "__main__":
    main()
