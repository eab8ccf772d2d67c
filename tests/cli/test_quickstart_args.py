"""`racerlab quickstart` checks its command line before it makes a folder or trains."""

from __future__ import annotations

import pytest

from racerlab.cli import main

# each bad option and the words its one-line error says
BAD_OPTIONS = {
    "--iterations -1": "--iterations must be a number >= 0 (0 = no limit), got -1",
    "--minutes nan": "--minutes must be a number >= 0 (0 = no limit), got nan",
    "--minutes -2": "--minutes must be a number >= 0",
    "--max-speed inf": "--max-speed inf: give a speed in m/s",
}


@pytest.mark.parametrize("option", list(BAD_OPTIONS))
def test_bad_options_are_one_line_before_anything_is_made(tmp_path, capsys, option):
    argv, words = option.split(), BAD_OPTIONS[option]
    model = tmp_path / "qs"
    assert main(["quickstart", "--model", str(model), *argv]) == 2
    err = capsys.readouterr().err.strip()
    assert words in err and "\n" not in err
    assert not model.exists()


def test_a_file_given_as_the_model_is_one_line_and_left_alone(tmp_path, capsys):
    notes = tmp_path / "notes.txt"
    notes.write_text("mine\n")
    assert main(["quickstart", "--model", str(notes), "--iterations", "1"]) == 2
    err = capsys.readouterr().err.strip()
    assert f"--model {notes}: a file, not a model folder" in err and "\n" not in err
    assert notes.read_text() == "mine\n" and sorted(p.name for p in tmp_path.iterdir()) == ["notes.txt"]
