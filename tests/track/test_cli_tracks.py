"""`racerlab tracks list|show|generate`, run in-process."""

from __future__ import annotations

import numpy as np
import pytest

from racerlab import track
from racerlab.cli import main
from tests.conftest import aws_track_path

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


@pytest.fixture
def home(tmp_path, monkeypatch):
    """An empty racerlab home, so that the user's own tracks do not leak into the tests."""
    monkeypatch.setenv("RACERLAB_HOME", str(tmp_path / "home"))
    monkeypatch.delenv("RACERLAB_TRACK_PATH", raising=False)
    return tmp_path / "home"


def test_show_writes_a_png_and_prints_the_facts(home, tmp_path, capsys):
    out = tmp_path / "pics" / "tech.png"
    assert main(["tracks", "show", "lab_technical", "--out", str(out)]) == 0
    assert out.read_bytes()[:8] == PNG_MAGIC
    text = capsys.readouterr().out
    for fact in ("length: 18.00 m", "width: 0.76 m", "turns: 8", "waypoints: 120", "counter-clockwise", str(out)):
        assert fact in text


def test_show_reverse_and_a_path(home, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    out = tmp_path / "racerlab-out" / "tracks"  # not the current folder itself (issue 27)
    assert main(["tracks", "show", "lab_oval", "--reverse"]) == 0
    assert (out / "lab_oval_reversed.png").is_file() and not (tmp_path / "lab_oval_reversed.png").exists()
    text = capsys.readouterr().out
    assert "direction: clockwise" in text and f"picture: {out / 'lab_oval_reversed.png'}" in text
    path = aws_track_path("reInvent2019_track")
    assert main(["tracks", "show", str(path), "--out", str(tmp_path / "r.png")]) == 0
    assert "length: 23.1" in capsys.readouterr().out
    assert main(["tracks", "show"]) == 0  # the default track
    assert (out / "lab_technical.png").is_file()


def test_list_shows_bundled_and_user_tracks(home, capsys):
    assert main(["tracks", "generate", "--seed", "3", "--length", "16", "--name", "mine"]) == 0
    saved = home / "tracks" / "mine.npy"
    assert saved.is_file() and "mine" in track.names()
    assert track.load("mine").length == pytest.approx(16.0)
    capsys.readouterr()
    assert main(["tracks", "list"]) == 0
    rows = {line.split()[0]: line.split() for line in capsys.readouterr().out.splitlines()[1:]}
    assert rows["mine"][1:5] == ["user", "16.00", "1.07", str(track.load("mine").turns())]
    assert rows["lab_technical"][1:4] == ["bundled", "18.00", "0.76"]
    assert {"lab_oval", "lab_grand_prix"} <= set(rows)


def test_generate_is_deterministic_and_refuses_to_overwrite(home, capsys):
    assert main(["tracks", "generate", "--seed", "5"]) == 0
    first = np.load(home / "tracks" / "generated_5.npy")
    assert main(["tracks", "generate", "--seed", "5"]) == 2
    assert "already exists" in capsys.readouterr().err
    assert main(["tracks", "generate", "--seed", "5", "--force"]) == 0
    np.testing.assert_array_equal(np.load(home / "tracks" / "generated_5.npy"), first)
    assert not list((home / "tracks").glob(".*"))  # no half-written files left behind


def test_a_broken_user_track_is_listed_not_fatal(home, capsys):
    (home / "tracks").mkdir(parents=True)
    np.save(home / "tracks" / "broken.npy", np.zeros((4, 3)))
    assert main(["tracks", "list"]) == 0
    line = next(x for x in capsys.readouterr().out.splitlines() if x.startswith("broken"))
    assert "user" in line and "unreadable" in line


@pytest.mark.parametrize("argv", [
    ["tracks", "show", "lab_tecnical"],
    ["tracks", "show", "no/such/file.npy"],
    ["tracks", "show", "lab_oval", "--out", "oval.jpg"],
    ["tracks", "generate", "--seed", "1", "--width", "1.5"],
    ["tracks", "generate", "--seed", "1", "--name", "../escape"],
])
def test_user_mistakes_exit_2_with_one_line(home, capsys, argv):
    assert main(argv) == 2
    captured = capsys.readouterr()
    err = captured.err.strip()
    assert err.startswith("racerlab: error: ") and "\n" not in err
    assert "Traceback" not in captured.out + captured.err


def test_unknown_name_suggests_the_close_one(home, capsys):
    assert main(["tracks", "show", "lab_tecnical"]) == 2
    assert "Did you mean lab_technical" in capsys.readouterr().err


def test_draw_track_on_given_axes_numbers_every_kth_waypoint():
    from matplotlib.figure import Figure

    from racerlab.track.plot import draw_track, label_step

    t = track.load("lab_grand_prix")  # 233 waypoints: every 10th is numbered
    ax = Figure().add_subplot()
    assert draw_track(t, ax, label_every=None) is ax
    labels = [x.get_text() for x in ax.texts if x.get_text()]  # the direction arrow is an empty annotation
    assert label_step(233) == 10 and labels == [str(i) for i in range(0, 233, 10)]
    assert ax.get_aspect() == 1.0 and "35.00 m" in ax.get_title()
    bare = draw_track(track.load("lab_oval", reverse=True), waypoint_numbers=False, title=False)
    assert not [x for x in bare.texts if x.get_text()] and bare.get_title() == ""
    open_track = draw_track(track.load_file(aws_track_path("Straight_track")))
    assert open_track.texts
