"""How fast the learner could go: network FLOPs, this machine's matmul/conv rate, gradient steps/s limit.

A gradient step of PPO runs the policy and the value network forward on a minibatch and back again.
We count the multiply-adds of every `nn.Linear` and `nn.Conv2d` (2 FLOPs each) in one forward pass,
and take a forward + backward pass as 3× the forward FLOPs (the backward pass computes the gradients
of both the inputs and the weights: two products of the same size as the forward one). Element-wise
work (ReLU, softmax, Adam) is not counted: the limit is what the dense arithmetic alone would allow.

The rates are measured, not looked up: a large square matmul for the dense layers, and the network's
own convolutions on a minibatch (forward) for the convolutional ones. So the limit is
`1 / (linear_flops / matmul_rate + conv_flops / conv_rate)` gradient steps per second.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import torch
from torch import nn

BACKWARD_FACTOR = 3.0  # forward + backward ≈ 3 forward passes of dense arithmetic


@dataclass(frozen=True)
class Flops:
    """FLOPs of one forward pass of a batch, split by kind of layer."""

    linear: float = 0.0
    conv: float = 0.0

    @property
    def total(self) -> float:
        return self.linear + self.conv

    def __add__(self, other: Flops) -> Flops:
        return Flops(self.linear + other.linear, self.conv + other.conv)


def forward_flops(module: nn.Module, inputs) -> tuple[Flops, list[tuple[nn.Conv2d, torch.Size]]]:
    """FLOPs of `module(inputs)` (one forward pass), and each convolution with the input shape it saw."""
    counts = {"linear": 0.0, "conv": 0.0}
    convs: list[tuple[nn.Conv2d, torch.Size]] = []

    def on_linear(mod, args, out):
        counts["linear"] += 2.0 * out.numel() * mod.in_features

    def on_conv(mod, args, out):
        k = mod.kernel_size[0] * mod.kernel_size[1] * mod.in_channels // mod.groups
        counts["conv"] += 2.0 * out.numel() * k
        convs.append((mod, args[0].shape))

    device = next(module.parameters()).device  # a network on CUDA counts on CUDA inputs
    inputs = {k: v.to(device) for k, v in inputs.items()} if isinstance(inputs, dict) else inputs.to(device)
    hooks = []
    for m in module.modules():
        if isinstance(m, nn.Linear):
            hooks.append(m.register_forward_hook(on_linear))
        elif isinstance(m, nn.Conv2d):
            hooks.append(m.register_forward_hook(on_conv))
    try:
        with torch.no_grad():
            module(inputs)
    finally:
        for h in hooks:
            h.remove()
    return Flops(counts["linear"], counts["conv"]), convs


def _best_seconds(fn, repeats: int, min_seconds: float, sync=None) -> float:
    """The fastest of `repeats` timed calls after one warm-up, each call repeated for `min_seconds`; `sync` waits
    for the device's queued work (CUDA runs asynchronously: without it the timer reads the queueing)."""
    if sync is not None:
        inner = fn

        def fn():
            inner()
            sync()
    fn()
    best = float("inf")
    for _ in range(repeats):
        n, t0 = 0, time.perf_counter()
        while True:
            fn()
            n += 1
            dt = time.perf_counter() - t0
            if dt >= min_seconds:
                break
        best = min(best, dt / n)
    return best


def matmul_rate(size: int = 1024, repeats: int = 3, min_seconds: float = 0.1) -> float:
    """FLOP/s of a float32 [size × size] @ [size × size] product on the CPU threads torch uses."""
    a, b = torch.randn(size, size), torch.randn(size, size)
    return 2.0 * size ** 3 / _best_seconds(lambda: a @ b, repeats, min_seconds)


def conv_rate(convs: list[tuple[nn.Conv2d, torch.Size]], repeats: int = 3, min_seconds: float = 0.05) -> float:
    """FLOP/s of the given convolutions run forward on inputs of the shapes they saw (float32)."""
    if not convs:
        return float("nan")
    flops, seconds = 0.0, 0.0
    with torch.no_grad():
        for mod, shape in convs:
            x = torch.randn(shape, device=mod.weight.device)
            out = mod(x)
            k = mod.kernel_size[0] * mod.kernel_size[1] * mod.in_channels // mod.groups
            flops += 2.0 * out.numel() * k
            sync = torch.cuda.synchronize if x.is_cuda else None
            seconds += _best_seconds(lambda m=mod, x=x: m(x), repeats, min_seconds, sync)
    return flops / seconds


@dataclass(frozen=True)
class StepLimit:
    """The FLOP-based ceiling of gradient steps per second for one minibatch size."""

    minibatch: int
    forward: Flops  # one forward pass of all networks on a minibatch
    matmul_flops_per_s: float
    conv_flops_per_s: float

    @property
    def seconds_per_step(self) -> float:
        s = BACKWARD_FACTOR * self.forward.linear / self.matmul_flops_per_s
        if self.forward.conv:
            s += BACKWARD_FACTOR * self.forward.conv / self.conv_flops_per_s
        return s

    @property
    def steps_per_s(self) -> float:
        return 1.0 / self.seconds_per_step

    def to_json(self) -> dict:
        return {"minibatch": self.minibatch, "forward_gflop": round(self.forward.total / 1e9, 6),
                "step_gflop": round(BACKWARD_FACTOR * self.forward.total / 1e9, 6),
                "matmul_gflop_per_s": round(self.matmul_flops_per_s / 1e9, 2),
                "conv_gflop_per_s": None if not self.forward.conv else round(self.conv_flops_per_s / 1e9, 2),
                "limit_gradient_steps_per_s": round(self.steps_per_s, 1)}


def gradient_step_limit(networks: list[nn.Module], example: dict[str, torch.Tensor],
                        rate: float | None = None) -> StepLimit:
    """The limit for `networks` (each called as `net(obs)`) on the minibatch `example` ({input: [M, ...]}).

    `rate` overrides the measured matmul FLOP/s (tests); the conv rate is always measured. Each rate is
    the better of torch's thread count and 1 thread, as the update itself picks (`common.ThreadChooser`):
    with the other core busy, 2 threads ran the camera's convolutions at a fifth of 1 thread's rate.
    """
    total, convs = Flops(), []
    for net in networks:
        f, c = forward_flops(net, example)
        total, convs = total + f, convs + c
    m = next(iter(example.values())).shape[0]
    mm = _best_over_threads(matmul_rate) if rate is None else rate
    return StepLimit(m, total, mm, _best_over_threads(lambda: conv_rate(convs)) if convs else float("nan"))


def _best_over_threads(measure) -> float:
    """The larger of `measure()` on torch's threads and on 1 thread."""
    threads = torch.get_num_threads()
    best = measure()
    if threads > 1:
        torch.set_num_threads(1)
        try:
            best = max(best, measure())
        finally:
            torch.set_num_threads(threads)
    return best
