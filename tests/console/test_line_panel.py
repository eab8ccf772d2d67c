"""The console's racing-line panel on every track racerlab ships and one it generates: the line, and the theoretical
limit the panel shows beside it, both solve (the limit failed on all of them on 4b81135)."""

from __future__ import annotations

from racerlab.cli import main
from racerlab.line import theoretical_limit
from racerlab.track import registry
from tests.console.conftest import wait_task


def test_the_line_panel_solves_every_bundled_track_and_a_generated_one(console, tmp_path, monkeypatch):
    monkeypatch.setenv("RACERLAB_HOME", str(tmp_path / "home"))
    assert main(["tracks", "generate", "--seed", "5", "--name", "gen5"]) == 0
    names = [*sorted(p.stem for p in registry.BUNDLED_DIR.glob("*.npy")), "gen5"]
    assert {"lab_technical", "lab_oval", "lab_grand_prix", "gen5"} <= set(names)
    c = console.client
    for name in names:
        r = c.post("/api/lines", json={"track": name, "method": "mincurv"})
        assert r.status_code == 200, r.text
        summary = wait_task(c, f"line:{name}:mincurv")["result"]["summary"]
        limit = theoretical_limit(name)
        assert summary["track"] == name and limit.kind == "limit"
        assert 0 < limit.lap_time < summary["lap_time_s"] < 30, (name, limit, summary)
        assert c.get(f"/api/lines/{name}/mincurv.png").content[:4] == b"\x89PNG"
