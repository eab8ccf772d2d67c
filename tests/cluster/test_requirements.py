"""What the package asks of Ray (issue 28, case 11): Ray's nodes listen on every interface, and only Ray >= 2.52
has the token authentication a local cluster is started with, so the `cluster` extra may not allow older Ray."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

from racerlab.cluster.collector import RAY_MIN

PYPROJECT = Path(__file__).resolve().parents[2] / "pyproject.toml"


def test_the_cluster_extra_requires_the_ray_that_connect_requires():
    extra = tomllib.loads(PYPROJECT.read_text())["project"]["optional-dependencies"]["cluster"]
    ray = [r for r in extra if re.match(r"ray\b", r)]
    assert len(ray) == 1
    low = re.search(r">=\s*([\d.]+)", ray[0])
    assert low, f"{ray[0]!r} has no lower bound"
    assert tuple(int(p) for p in low.group(1).split(".")[:2]) >= RAY_MIN
