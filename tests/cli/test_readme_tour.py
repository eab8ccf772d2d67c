"""README's tour, read as a script: every line parses with the real `racerlab` parser, and every line uses only
what the lines above it made (a model before it is trained, raced or exported; a reward file before it is
checked; a car archive before it is imported; the car export of a model the car accepts)."""

from __future__ import annotations

import shlex
from pathlib import Path

import pytest

from racerlab.cli import build_parser

README = Path(__file__).resolve().parents[2] / "README.md"
CAR_SENSORS = ("camera", "stereo", "lidar")  # `racerlab init --sensor` values the car's export takes


def tour_lines() -> list[list[str]]:
    text = README.read_text(encoding="utf-8")
    start = text.index("```bash\n", text.index("## A tour")) + len("```bash\n")
    block = text[start:text.index("```", start)]
    return [shlex.split(line, comments=True) for line in block.splitlines() if line.strip()]


class Tour:
    """What the tour has made so far."""

    def __init__(self):
        self.models: dict[str, str] = {}  # name -> sensor
        self.files: set[str] = set()
        self.archives: set[str] = set()
        self.fetched_all = False

    def model(self, name: str) -> None:
        assert name in self.models, f"{name}: no line above makes this model"

    def reward_file(self, path: str) -> None:
        made = path in self.files or any(path == f"{m}/reward_function.py" for m in self.models)
        assert made, f"{path}: no line above makes this file"

    def run(self, argv: list[str]) -> None:
        if argv[0] == "cp":
            self.reward_file(argv[1])
            self.files.add(argv[2])
            return
        assert argv[0] == "racerlab", argv
        args = build_parser().parse_args(argv[1:])  # a wrong flag exits here
        getattr(self, "_" + args.command, lambda a: None)(args)

    def _init(self, a):
        self.models[str(a.model)] = a.sensor

    def _train(self, a):
        self.model(str(a.model))

    def _clone(self, a):
        self.model(str(a.src))
        if a.reward:
            self.reward_file(str(a.reward))
        self.models[str(a.dst)] = self.models[str(a.src)]

    def _evaluate(self, a):
        self.model(str(a.model))
        if a.tracks_from:
            assert self.fetched_all and str(a.tracks_from).startswith("~/.racerlab/tracks"), a.tracks_from

    def _race(self, a):
        for m in a.models:
            self.model(str(m))

    def _report(self, a):
        self.model(str(a.path))

    def _reward(self, a):
        if a.reward_command == "rescore":
            self.model(str(a.log))
        self.reward_file(str(a.reward))

    def _export(self, a):
        self.model(str(a.model))
        if a.car:
            assert self.models[str(a.model)] in CAR_SENSORS, f"{a.model}: the car takes no features model"
            self.archives.add(f"{a.model}-car.tar.gz")

    def _import(self, a):
        assert str(a.path) in self.archives, f"{a.path}: no line above writes this archive"

    def _tracks(self, a):
        if a.tracks_command == "fetch" and a.all:
            self.fetched_all = True


def test_the_tour_runs_as_written_on_the_models_it_makes():
    tour = Tour()
    lines = tour_lines()
    assert len(lines) >= 20
    for argv in lines:
        try:
            tour.run(argv)
        except SystemExit:
            pytest.fail(f"{shlex.join(argv)}: the parser refuses it")
        except AssertionError as exc:
            raise AssertionError(f"{shlex.join(argv)}: {exc}") from None
    assert any(s in CAR_SENSORS for s in tour.models.values()) and tour.archives  # the car export is in it


def test_the_tour_s_first_model_is_the_quickstart_s_model():
    # the README's `racerlab init` makes the model the quickstart made: its actions and its reward
    from racerlab.cli.model import QUICKSTART_ACTIONS, QUICKSTART_MAX_SPEED, QUICKSTART_REWARD

    init = next(a for a in tour_lines() if a[:2] == ["racerlab", "init"])
    args = build_parser().parse_args(init[1:])
    quickstart = build_parser().parse_args(["quickstart"])
    assert args.max_speed == QUICKSTART_MAX_SPEED == quickstart.max_speed
    assert args.action_space == QUICKSTART_ACTIONS == quickstart.action_space
    assert args.reward == QUICKSTART_REWARD == quickstart.reward
