"""Loading a track takes memory in proportion to its points: the border check held every pair of segments at once
(a 10 000-point track: 3 GB, then a traceback; a 2 km ring at 10 cm: minutes)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import racerlab
from racerlab.errors import TrackError
from racerlab.track import load_file
from racerlab.track.core import segments_cross


def _ring(n: int, length_m: float, width_m: float = 1.0) -> np.ndarray:
    t = np.linspace(0.0, 2 * np.pi, n)
    centre = length_m / (2 * np.pi) * np.stack([np.cos(t), np.sin(t)], axis=1)
    centre[-1] = centre[0]
    out = centre / np.linalg.norm(centre, axis=1, keepdims=True)
    return np.hstack([centre, centre - 0.5 * width_m * out, centre + 0.5 * width_m * out])


@pytest.mark.parametrize("n, length_m", [(10_000, 125.0), (20_000, 2000.0)], ids=["10k-points", "2km-ring"])
def test_a_long_track_loads_in_little_memory(tmp_path, n, length_m):
    """In a child whose address space is capped at 2 GB, so that a loader that builds the N x N matrices (5 GB at
    10 000 points, 19 GB at 20 000) fails there instead of taking the machine's memory."""
    path = tmp_path / "ring.npy"
    np.save(path, _ring(n, length_m))
    code = ("import resource, sys, tracemalloc\n"
            "from racerlab.track import load_file\n"
            "resource.setrlimit(resource.RLIMIT_AS, (2 << 30, 2 << 30))\n"
            "tracemalloc.start()\n"
            "track = load_file(sys.argv[1])\n"
            "print(track.length, tracemalloc.get_traced_memory()[1])\n")
    env = {**os.environ, "PYTHONPATH": str(Path(racerlab.__file__).parents[1])}
    out = subprocess.run([sys.executable, "-c", code, str(path)], capture_output=True, text=True, timeout=120,
                         env=env)
    assert out.returncode == 0, out.stderr[-500:]
    length, peak = (float(v) for v in out.stdout.split())
    assert length == pytest.approx(length_m, rel=1e-3)
    assert peak < 64e6, f"{peak / 1e6:.0f} MB to load {n} points"  # the arrays themselves: ~1 MB per 10 000


def test_borders_that_cross_late_in_a_long_track_are_still_found(tmp_path):
    arr = _ring(3000, 125.0)
    arr[2101, 4:6] = arr[2101, 2:4] - 0.3 * (arr[2101, 4:6] - arr[2101, 2:4])  # one outer point inside the inner
    np.save(tmp_path / "bad.npy", arr)
    with pytest.raises(TrackError, match=r"borders cross \(inner segment 210\d, outer segment 210\d\)"):
        load_file(tmp_path / "bad.npy")


def test_the_first_crossing_is_the_one_named():
    # a polyline that crosses itself twice: segments (1, 4) and, later, (6, 9); the first is named
    line = np.array([[0, 0], [2, 0], [2, 2], [1, 2], [1, -1], [3, -1], [5, 0], [7, 0], [7, 2], [6, 2], [6, -1.0]])
    assert segments_cross(line, line, skip_adjacent=True, chunk=2) == (0, 3)
    assert segments_cross(line, line, skip_adjacent=True) == (0, 3)
    assert segments_cross(line[5:], line[5:], skip_adjacent=True, chunk=1) == (1, 4)  # found in a later chunk
    assert segments_cross(line[:6], line[6:], skip_adjacent=False) is None
