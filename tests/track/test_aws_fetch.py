"""`racerlab tracks fetch|import`: AWS route files by name, checked against the sha256 sums racerlab ships.

Downloads are tested against a local HTTP server (127.0.0.1, stopped after each test) serving the real
files in ../shared/tracks, the same bytes as the community repositories the sums were taken from.
"""

from __future__ import annotations

import functools
import hashlib
import http.server
import shutil
import threading

import numpy as np
import pytest

from racerlab import track
from racerlab.cli import main
from racerlab.errors import TrackError
from racerlab.track import aws
from tests.conftest import AWS_TRACKS, aws_track_path


@pytest.fixture
def home(tmp_path, monkeypatch):
    monkeypatch.setenv("RACERLAB_HOME", str(tmp_path / "home"))
    monkeypatch.delenv("RACERLAB_TRACK_PATH", raising=False)
    monkeypatch.delenv(aws.MIRROR_ENV, raising=False)
    return tmp_path / "home" / "tracks"


class _Quiet(http.server.SimpleHTTPRequestHandler):
    def log_message(self, *args):
        pass


def serve(folder, monkeypatch):
    """An HTTP server on 127.0.0.1 serving `folder`, named as the mirror; returns (server, request log)."""
    seen = []

    class Handler(_Quiet):
        def do_GET(self):  # noqa: N802 - http.server's name
            seen.append(self.path)
            super().do_GET()

    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), functools.partial(Handler, directory=str(folder)))
    threading.Thread(target=server.serve_forever, daemon=True).start()
    monkeypatch.setenv(aws.MIRROR_ENV, f"http://127.0.0.1:{server.server_address[1]}/")
    return server, seen


@pytest.fixture
def mirror(monkeypatch):
    aws_track_path("reInvent2019_track")  # skips without the real files
    server, seen = serve(AWS_TRACKS, monkeypatch)
    yield seen
    server.shutdown()
    server.server_close()


def test_the_shipped_sums_are_those_of_the_real_files():
    aws_track_path("reInvent2019_track")
    files = sorted(AWS_TRACKS.glob("*.npy"))
    cat = aws.catalogue()
    assert len(cat) == len(files) == 129
    for f in files:
        data = f.read_bytes()
        assert cat[f.stem].sha256 == hashlib.sha256(data).hexdigest() and cat[f.stem].size == len(data)
    assert cat["reInvent2019_track"].url().endswith("/raw_data/tracks/npy/reInvent2019_track.npy")
    carpet = cat["reinvent_carpet"]
    assert "deepracer-simapp" in carpet.url() and carpet.title.endswith("(carpet world)")


def test_a_name_not_fetched_yet_says_how_to_fetch_it(home):
    for name in ("reInvent2019_track", "reInvent2019_track.npy"):
        with pytest.raises(TrackError) as e:
            track.load(name)
        assert str(e.value).count("\n") == 0 and "racerlab tracks fetch reInvent2019_track" in str(e.value)
    with pytest.raises(TrackError, match="unknown track 'no_such'"):
        track.load("no_such")


def test_fetch_downloads_checks_and_saves(home, mirror, capsys):
    assert main(["tracks", "fetch", "reInvent2019_track", "reinvent_carpet.npy"]) == 0
    saved = home / "reInvent2019_track.npy"
    assert saved.read_bytes() == (AWS_TRACKS / "reInvent2019_track.npy").read_bytes()
    assert (home / "reinvent_carpet.npy").is_file() and sorted(mirror) == ["/reInvent2019_track.npy",
                                                                          "/reinvent_carpet.npy"]
    out = capsys.readouterr().out
    assert f"fetched reInvent2019_track (Smile Speedway): {saved}" in out  # the console's display name
    assert "2 downloaded, 0 already there" in out
    # by name, and by the file name the README uses, from any folder
    t = track.load("reInvent2019_track")
    assert t.length == pytest.approx(23.12, abs=0.01) and track.load("reInvent2019_track.npy").length == t.length
    # again: nothing is downloaded
    assert main(["tracks", "fetch", "reInvent2019_track"]) == 0
    assert len(mirror) == 2 and "0 downloaded, 1 already there" in capsys.readouterr().out


def test_fetch_all(home, mirror, capsys):
    assert main(["tracks", "fetch", "--all"]) == 0
    assert len(list(home.glob("*.npy"))) == 129 and len(mirror) == 129
    assert "129 downloaded" in capsys.readouterr().out
    assert np.array_equal(np.load(home / "reinvent_wood.npy"), np.load(home / "reinvent_base.npy"))


def test_a_damaged_download_is_refused_and_nothing_saved(home, tmp_path, monkeypatch, capsys):
    src = aws_track_path("Oval_track")
    bad = tmp_path / "bad"
    bad.mkdir()
    data = bytearray(src.read_bytes())
    data[-1] ^= 0xFF
    (bad / "Oval_track.npy").write_bytes(bytes(data))
    server, _ = serve(bad, monkeypatch)
    try:
        assert main(["tracks", "fetch", "Oval_track"]) == 2
        err = capsys.readouterr().err
        assert "Oval_track.npy: sha256 " in err and "is not the Oval_track.npy racerlab knows" in err
        assert main(["tracks", "fetch", "Bowtie_track"]) == 2
        assert "Bowtie_track.npy: the server answered 404" in capsys.readouterr().err
    finally:
        server.shutdown()
        server.server_close()
    assert not home.exists() or not list(home.iterdir())


def test_fetch_refuses_unknown_names_and_nothing(home, capsys):
    assert main(["tracks", "fetch", "reInvent2019_trak"]) == 2
    assert "did you mean reInvent2019_track" in capsys.readouterr().err
    assert main(["tracks", "fetch"]) == 2
    assert "or use --all" in capsys.readouterr().err
    assert main(["tracks", "fetch", "--list"]) == 0
    listing = {line.split()[0]: line.split(None, 1)[1] for line in capsys.readouterr().out.splitlines()[1:]}
    assert len(listing) == 129 and listing["reinvent_base"] == "re:Invent 2018"


def test_import_copies_the_aws_files_found_in_a_folder(home, tmp_path, capsys):
    checkout = tmp_path / "deepracer-simapp"
    routes = checkout / "bundle" / "routes"
    routes.mkdir(parents=True)
    for name in ("reInvent2019_track", "reinvent_wood"):
        shutil.copy(aws_track_path(name), routes / f"{name}.npy")
    np.save(checkout / "my_raceline.npy", np.zeros((10, 2)))  # not a route file: left alone
    tampered = np.load(aws_track_path("Oval_track"))
    np.save(checkout / "Oval_track.npy", tampered * 1.01)  # an AWS name with other bytes: skipped
    assert main(["tracks", "import", str(checkout)]) == 0
    assert sorted(p.name for p in home.iterdir()) == ["reInvent2019_track.npy", "reinvent_wood.npy"]
    captured = capsys.readouterr()
    assert "2 imported, 0 already there, 1 skipped (different bytes), 1 other .npy files left alone" in captured.out
    assert "Oval_track.npy: not the AWS file of that name" in captured.err
    assert track.load("reinvent_wood").length == pytest.approx(17.71, abs=0.01)
    assert main(["tracks", "import", str(checkout)]) == 0
    assert "0 imported, 2 already there" in capsys.readouterr().out
    assert main(["tracks", "import", str(tmp_path / "nothing")]) == 2
    assert "nothing: not a folder" in capsys.readouterr().err
