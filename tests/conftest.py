"""Shared fixtures: the real AWS track files live in ../shared/tracks next to the repository."""

from __future__ import annotations

from pathlib import Path

import pytest

from racerlab.track import load_file

REPO = Path(__file__).resolve().parents[1]
AWS_TRACKS = REPO.parent / "shared" / "tracks"


def aws_track_path(name: str) -> Path:
    p = AWS_TRACKS / f"{name}.npy"
    if not p.is_file():
        pytest.skip(f"real AWS track {name} not found in {AWS_TRACKS}")
    return p


@pytest.fixture
def aws_track():
    """Load a real AWS track by file stem, e.g. aws_track('reInvent2019_track')."""
    return lambda name: load_file(aws_track_path(name))
