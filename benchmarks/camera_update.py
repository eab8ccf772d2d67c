"""Where a camera PPO gradient step spends its time, beside the FLOP limit (`racerlab.agent.flops`).

Builds PPO for the AWS console's camera model (SHALLOW, separate policy and value networks, 120x160x1
uint8 images) and times gradient steps of `PPO.update` on minibatches of 64, split into forward (both
networks and the loss), backward and the Adam step, with the per-layer forward and backward convolution
times from torch.profiler. Prints one JSON line:
- gradient steps/s of the real update (`PPO.update`, 10 epochs over `--samples` steps) and of the split loop;
- the FLOP limit (3 forward passes at the networks' own forward conv rate, measured now at the threads the
  update used, and again at every core) and the share reached of each;
- from the profile, the backward convolutions' time over the forward ones' (the limit assumes 2: input and
  weight gradients at the forward rate; the first layer computes no input gradient, so 2 is generous);
- with --threads-ab, a step's median time at 1 thread and at every core, interleaved;
- torch's thread count and the load average.

Usage: python benchmarks/camera_update.py [--threads N] [--samples 640] [--repeats 3]
"""

from __future__ import annotations

import argparse
import json
import os
import time

import numpy as np
import torch
from torch.profiler import ProfilerActivity, profile

from racerlab.agent.common import learner_threads
from racerlab.agent.flops import gradient_step_limit
from racerlab.agent.ppo import PPO, PPOBatch
from racerlab.model.init import make_metadata

SHAPE = (120, 160, 1)
MINIBATCH = 64


def _batch(n: int, seed: int = 0) -> PPOBatch:
    rng = np.random.default_rng(seed)
    obs = {"camera": rng.integers(0, 256, (n, *SHAPE), dtype=np.uint8)}
    return PPOBatch(obs, rng.integers(0, 5, n).astype(np.int64), np.full(n, -np.log(5), np.float32),
                    rng.normal(size=n).astype(np.float32), rng.normal(size=n).astype(np.float32),
                    rng.normal(size=n).astype(np.float32))


def _split_step(ppo: PPO, obs, idx, tensors) -> tuple[float, float, float]:
    """Forward (+ loss), backward, optimizer seconds of one gradient step, as `_update_torch` runs it."""
    t0 = time.perf_counter()
    losses = ppo._minibatch_losses(obs, idx, *tensors)
    t1 = time.perf_counter()
    ppo.optimizer.zero_grad(set_to_none=True)
    losses.loss.backward()
    t2 = time.perf_counter()
    ppo.optimizer.step()
    t3 = time.perf_counter()
    return t1 - t0, t2 - t1, t3 - t2


def _tensors(batch: PPOBatch):
    return (torch.as_tensor(batch.actions), torch.as_tensor(batch.log_probs), torch.as_tensor(batch.advantages),
            torch.as_tensor(batch.returns))


def _obs(batch: PPOBatch) -> dict[str, torch.Tensor]:
    return {"camera": torch.as_tensor(batch.obs["camera"])}


def _threads_ab(ppo: PPO, batch: PPOBatch, rounds: int) -> dict:
    """Median seconds of a gradient step at 1 thread and at every core, interleaved round by round so that
    both see the same load."""
    obs, tensors, n = _obs(batch), _tensors(batch), len(batch.advantages)
    gen = torch.Generator().manual_seed(3)
    before = torch.get_num_threads()
    counts = sorted({1, os.cpu_count() or 1})
    times: dict[int, list[float]] = {c: [] for c in counts}
    for _ in range(rounds):
        for c in counts:
            torch.set_num_threads(c)
            _split_step(ppo, obs, torch.randperm(n, generator=gen)[:MINIBATCH], tensors)
            times[c].append(sum(_split_step(ppo, obs, torch.randperm(n, generator=gen)[:MINIBATCH], tensors)))
    torch.set_num_threads(before)
    return {f"step_ms_threads_{c}": round(1e3 * float(np.median(t)), 1) for c, t in times.items()}


def _split(ppo: PPO, batch: PPOBatch, steps: int) -> dict:
    obs = _obs(batch)
    tensors = _tensors(batch)
    n = len(batch.advantages)
    gen = torch.Generator().manual_seed(1)
    times = []
    for i in range(steps + 1):
        idx = torch.randperm(n, generator=gen)[:MINIBATCH]
        t = _split_step(ppo, obs, idx, tensors)
        if i:
            times.append(t)
    med = np.median(np.array(times), axis=0)
    return {"forward_ms": round(1e3 * med[0], 2), "backward_ms": round(1e3 * med[1], 2),
            "optimizer_ms": round(1e3 * med[2], 2), "step_ms": round(1e3 * med.sum(), 2)}


def _profile_convs(ppo: PPO, batch: PPOBatch, steps: int) -> dict:
    """Per-op self CPU time (ms per gradient step) of the convolution ops, forward and backward."""
    obs = _obs(batch)
    tensors = _tensors(batch)
    n = len(batch.advantages)
    gen = torch.Generator().manual_seed(2)
    _split_step(ppo, obs, torch.randperm(n, generator=gen)[:MINIBATCH], tensors)
    with profile(activities=[ProfilerActivity.CPU], record_shapes=True) as prof:
        for _ in range(steps):
            _split_step(ppo, obs, torch.randperm(n, generator=gen)[:MINIBATCH], tensors)
    rows = {}
    for ev in prof.key_averages(group_by_input_shape=True):
        key = f"{ev.key} {ev.input_shapes[:2] if ev.input_shapes else ''}"
        rows[key] = round(ev.self_cpu_time_total / 1e3 / steps, 3)
    top = dict(sorted(rows.items(), key=lambda kv: -kv[1])[:16])
    total = {}
    for ev in prof.key_averages():
        if ev.key in ("aten::convolution_backward", "aten::mkldnn_convolution", "aten::_convolution",
                      "aten::convolution", "aten::conv2d"):
            total[ev.key] = round(ev.cpu_time_total / 1e3 / steps, 3)
    fwd, bwd = total.get("aten::mkldnn_convolution"), total.get("aten::convolution_backward")
    ratio = round(bwd / fwd, 2) if fwd and bwd else None
    return {"per_op_self_ms": top, "conv_total_ms": total, "conv_backward_over_forward_time": ratio}


def _timed_update(ppo: PPO, batch: PPOBatch) -> tuple[float, int]:
    t0 = time.perf_counter()
    metrics = ppo.update(batch)
    return time.perf_counter() - t0, int(metrics["charts/gradient_steps"])


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--threads", type=int, default=0, help="torch threads (default: learner_threads)")
    ap.add_argument("--samples", type=int, default=640, help="env steps in the batch (10 epochs over them)")
    ap.add_argument("--repeats", type=int, default=3, help="updates timed; the fastest counts")
    ap.add_argument("--no-profile", action="store_true")
    ap.add_argument("--threads-ab", type=int, default=0, metavar="ROUNDS",
                    help="also time steps at 1 thread and at every core, interleaved, ROUNDS times")
    args = ap.parse_args()
    ppo = PPO({"camera": SHAPE}, make_metadata("camera"), device="cpu", seed=0)
    torch.set_num_threads(learner_threads(ppo.networks(), args.threads))
    batch = _batch(args.samples)
    load_before = os.getloadavg()[0]
    _timed_update(ppo, _batch(2 * MINIBATCH, seed=1))  # warm-up
    best, steps = float("inf"), 0
    for _ in range(args.repeats):
        sec, steps = _timed_update(ppo, batch)
        best = min(best, sec)
    update_steps_per_s = steps / best
    split = _split(ppo, batch, 10)
    example = {"camera": torch.randint(0, 256, (MINIBATCH, *SHAPE), dtype=torch.uint8)}
    limit = gradient_step_limit([ppo.policy_net, ppo.value_net], example)
    used = torch.get_num_threads()
    torch.set_num_threads(os.cpu_count() or 1)  # the stricter limit: every core's rates, measured now
    all_cores = gradient_step_limit([ppo.policy_net, ppo.value_net], example)
    torch.set_num_threads(used)
    out = {"bench": "camera_update", "threads": torch.get_num_threads(), "samples": args.samples,
           "gradient_steps": steps, "update_s": round(best, 3), "gradient_steps_per_s": round(update_steps_per_s, 2),
           **split, "split_steps_per_s": round(1e3 / split["step_ms"], 2), **limit.to_json(),
           "share_of_limit": round(update_steps_per_s / limit.steps_per_s, 3),
           "limit_all_cores_gradient_steps_per_s": round(all_cores.steps_per_s, 1),
           "share_of_limit_all_cores": round(update_steps_per_s / all_cores.steps_per_s, 3)}
    if args.threads_ab:
        out["threads_ab"] = _threads_ab(ppo, batch, args.threads_ab)
    if not args.no_profile:
        out["profile"] = _profile_convs(ppo, batch, 5)
    out["loadavg_1min_before_after"] = [round(load_before, 2), round(os.getloadavg()[0], 2)]
    print(json.dumps(out), flush=True)


if __name__ == "__main__":
    main()
