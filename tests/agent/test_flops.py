"""The FLOP count behind the learner's speed limit (`benchmarks/train_throughput.py`), worked out by hand."""

from __future__ import annotations

import pytest
import torch
from torch import nn

from racerlab.agent.flops import forward_flops


class _Net(nn.Module):
    def __init__(self):
        super().__init__()
        self.conv = nn.Conv2d(1, 4, kernel_size=3)  # 1×8×8 → 4×6×6
        self.fc = nn.Linear(4 * 6 * 6, 10)

    def forward(self, obs):
        return self.fc(self.conv(obs["camera"]).flatten(1))


def test_forward_flops_counts_each_layer_by_hand():
    flops, convs = forward_flops(_Net(), {"camera": torch.zeros(2, 1, 8, 8)})
    # conv: 2 FLOPs per multiply-add, 3·3·1 of them per output value, 2·4·6·6 outputs
    assert flops.conv == 2.0 * (2 * 4 * 6 * 6) * 9
    # linear: 2 FLOPs × 144 inputs per output value, 2·10 outputs
    assert flops.linear == 2.0 * (2 * 10) * 144
    assert [tuple(shape) for _, shape in convs] == [(2, 1, 8, 8)]


@pytest.mark.gpu
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_forward_flops_of_a_network_on_cuda_takes_a_cpu_example():
    """train_throughput builds its example minibatch on the CPU; a camera network trained on CUDA failed on it."""
    flops, _ = forward_flops(_Net().cuda(), {"camera": torch.zeros(2, 1, 8, 8)})
    assert flops.conv == 2.0 * (2 * 4 * 6 * 6) * 9
