"""What the package asks of torch and numba, and why (pyproject.toml, docs/install.md)."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _lower_bound(name: str) -> tuple[int, ...]:
    deps = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["dependencies"]
    (spec,) = [d for d in deps if re.match(rf"{name}\b", d)]
    low = re.search(r">=\s*([\d.]+)", spec)
    assert low, f"{spec!r} has no lower bound"
    return tuple(int(p) for p in low.group(1).split("."))


def _version(text: str) -> tuple[int, ...]:
    return tuple(int(p) for p in re.findall(r"\d+", text)[:2])


def test_torch_is_one_whose_weights_only_load_runs_no_code():
    """Issue 45, item 11: racerlab loads a stranger's checkpoint with weights_only, which ran the file's code in torch
    up to 2.5.1 (CVE-2025-32434) and before 2.10 (CVE-2026-24747); pyproject allowed torch >= 2.2."""
    import torch

    assert _lower_bound("torch")[:2] >= (2, 10)
    assert _version(torch.__version__) >= (2, 10)
    install = (ROOT / "docs" / "install.md").read_text()
    assert "torch ≥ 2.10" in install and "CVE-2025-32434" in install and "CVE-2026-24747" in install
    assert "≥ 2.2" not in install


def test_numba_is_one_whose_cache_locators_racerlab_extends():
    """racerlab.kernelcache subclasses numba's UserProvidedCacheLocator and puts it first in CacheImpl's locators,
    public names from numba 0.62 on (before: _UserProvidedCacheLocator)."""
    import numba
    from numba.core import caching

    import racerlab  # noqa: F401 - puts the locator in

    assert _lower_bound("numba")[:2] >= (0, 62) and _version(numba.__version__) >= (0, 62)
    first = caching.CacheImpl._locator_classes[0]
    assert issubclass(first, caching.UserProvidedCacheLocator) and first.__name__ == "KernelCacheLocator"
