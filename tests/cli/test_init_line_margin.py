"""`racerlab init --line-margin`: a margin the track has no room for is one line before the folder is made."""

from __future__ import annotations

import pytest

from racerlab.cli import main


@pytest.mark.parametrize("margin, words", [
    ("1e300", "--line-margin 1e+300: lab_technical is 0.76 m wide at its narrowest, which leaves at most 0.264 m"),
    ("0.3", "--line-margin 0.3: lab_technical is 0.76 m wide at its narrowest"),
    ("inf", "--line-margin inf: not a distance"),
    ("nan", "--line-margin nan: not a distance"),
], ids=["1e300", "past-the-edge", "inf", "nan"])
def test_a_margin_out_of_range_is_one_line_and_no_folder(tmp_path, capsys, margin, words):
    """Issue 45, item 10: past the upper edge the margin was refused only after the folder was made (with the example
    reward in it, so the corrected command found a reward there), 1e300 printed 300 digits, and the message named
    `racerlab line`'s --margin."""
    folder = tmp_path / "m"
    assert main(["init", str(folder), "--reward", "racing_line", f"--line-margin={margin}"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and words in err[0], err
    assert "--margin" not in err[0].replace("--line-margin", "") and len(err[0]) < 250
    assert not folder.exists()


def test_the_margins_edge_is_the_narrowest_place_of_the_track(tmp_path, capsys):
    # lab_technical's narrowest place is 0.76 m; the car's half track and wheel take 0.116 m of each half: 0.264 m
    assert main(["init", str(tmp_path / "m"), "--reward", "racing_line", "--line-margin", "0.265"]) == 2
    assert "at most 0.264 m" in capsys.readouterr().err
    assert main(["init", str(tmp_path / "m"), "--reward", "racing_line", "--line-margin", "0.25"]) == 0
    assert "margin 0.25 m" in (tmp_path / "m" / "reward_function.py").read_text()
