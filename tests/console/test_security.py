"""The console's security rules, each against a running console."""

from __future__ import annotations

import io
import tarfile

import pytest

from racerlab.console.security import ConsoleError, check_archive, check_name, is_loopback
from tests.console.conftest import Console, csrf_of


@pytest.mark.parametrize("name", ["..", "../x", "a/b", "/etc", "a\\b", ".hidden", "", "x" * 65, "a..b", "a b",
                                  "<script>"])
def test_bad_names_are_refused(name):
    with pytest.raises(ConsoleError):
        check_name(name)


@pytest.mark.parametrize("name", ["m1", "my-model_2.v3", "A" * 64])
def test_plain_names_pass(name):
    assert check_name(name) == name


def test_loopback_addresses():
    assert all(is_loopback(h) for h in ("127.0.0.1", "localhost", "::1", "127.1.2.3"))
    assert not any(is_loopback(h) for h in ("0.0.0.0", "192.168.1.5", "example.com"))


def test_state_changes_need_the_csrf_token(console):
    bare = {"Content-Type": "application/json"}
    import httpx

    with httpx.Client(base_url=console.url) as c:
        assert c.post("/api/models", json={"name": "x"}, headers=bare).status_code == 403
        assert c.post("/api/models", json={"name": "x"}, headers={"X-CSRF-Token": "wrong"}).status_code == 403
        # the token is in the page; with it, the same request goes through
        token = csrf_of(c.get("/").text)
        assert c.post("/api/models", json={"name": "x"}, headers={"X-CSRF-Token": token}).status_code == 200
        # a request from another site's page is refused even with the token
        evil = {"X-CSRF-Token": token, "Origin": "http://evil.example"}
        assert c.post("/api/models", json={"name": "y"}, headers=evil).status_code == 403
        assert c.delete("/api/models/x?confirm=x").status_code == 403
    assert (console.app.state.workspace.root / "x").is_dir()
    assert not (console.app.state.workspace.root / "y").exists()


def test_loopback_console_refuses_other_host_names(console):
    r = console.client.get("/api/models", headers={"Host": "evil.example:80"})
    assert r.status_code == 421
    assert console.client.get("/api/models").status_code == 200


def test_non_loopback_console_needs_the_token(tmp_path):
    import httpx

    c = Console(tmp_path / "ws", host="0.0.0.0")
    try:
        token = c.app.state.guard.token
        assert token and len(token) >= 24
        with httpx.Client(base_url=c.url) as anon:
            assert anon.get("/api/models").status_code == 401
            assert anon.get("/").status_code == 401
            assert anon.get("/api/models", headers={"Authorization": "Bearer nope"}).status_code == 401
            assert anon.get("/api/models", headers={"Authorization": f"Bearer {token}"}).status_code == 200
            r = anon.get(f"/?token={token}", follow_redirects=True)  # the printed address: a cookie, then the page
            assert r.status_code == 200 and "racerlab console" in r.text
            assert anon.cookies.get("racerlab_console") == token
            assert anon.get("/api/models").status_code == 200
    finally:
        c.stop()
    given = Console(tmp_path / "ws2", host="192.168.0.1", token="my-secret-token-0123456789")
    try:
        assert given.app.state.guard.token == "my-secret-token-0123456789"
    finally:
        given.stop()


def test_no_endpoint_reads_files_outside_the_workspace(console, tmp_path):
    secret = tmp_path / "secret.txt"
    secret.write_text("TOP SECRET")
    c = console.client
    c.post("/api/models", json={"name": "m"})
    for url in ["/api/models/..%2Fsecret.txt", "/api/models/%2E%2E/evaluations",
                "/api/models/m/evaluations/..%2F..%2Fsecret.txt/video",
                "/api/models/m/evaluations/evaluation-20250101000000%2F..%2F..%2F..%2Fsecret.txt/video",
                "/api/lines/..%2F..%2F..%2Fsecret/mincurv.png", "/api/uploads/..%2F..%2Fsecret.txt/report",
                "/api/tracks/..%2F..%2Fsecret.svg", "/static/..%2F..%2F..%2Fsecret.txt", "/api/models/m/report"]:
        r = c.get(url)
        assert r.status_code in (400, 404), url
        assert "TOP SECRET" not in r.text


def test_delete_needs_the_name_typed(console):
    c = console.client
    c.post("/api/models", json={"name": "keep"})
    assert c.delete("/api/models/keep").status_code == 400
    assert c.delete("/api/models/keep?confirm=other").status_code == 400
    assert (console.app.state.workspace.root / "keep").is_dir()
    assert c.delete("/api/models/keep?confirm=keep").status_code == 200
    assert not (console.app.state.workspace.root / "keep").exists()


def _tar(members) -> bytes:
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w:gz") as tar:
        for name, kind in members:
            info = tarfile.TarInfo(name)
            if kind == "file":
                data = b"episode,steps\n"
                info.size = len(data)
                tar.addfile(info, io.BytesIO(data))
            else:
                info.type = {"symlink": tarfile.SYMTYPE, "hardlink": tarfile.LNKTYPE, "fifo": tarfile.FIFOTYPE}[kind]
                info.linkname = "/etc/passwd"
                tar.addfile(info)
    return buf.getvalue()


@pytest.mark.parametrize("members, why", [
    ([("../evil.csv", "file")], "outside"), ([("/abs/evil.csv", "file")], "outside"),
    ([("logs/a.csv", "file"), ("logs/link", "symlink")], "link"), ([("logs/h", "hardlink")], "link"),
    ([("logs/p", "fifo")], "link or special"), ([], "no files")])
def test_uploaded_archives_are_checked_before_use(console, members, why):
    r = console.client.post("/api/uploads", files={"file": ("logs.tar.gz", _tar(members), "application/gzip")})
    assert r.status_code == 400 and why in r.json()["error"]
    assert console.client.get("/api/uploads").json()["uploads"] == []


def test_archive_limits(tmp_path):
    p = tmp_path / "a.tar.gz"
    p.write_bytes(_tar([(f"f{i}.csv", "file") for i in range(5)]))
    assert check_archive(p) == 5
    with pytest.raises(ConsoleError, match="more than 3 members"):
        check_archive(p, max_members=3)
    with pytest.raises(ConsoleError, match="more than 20 bytes"):
        check_archive(p, max_bytes=20)  # each member is 14 bytes
    p.write_bytes(b"not a tar at all")
    with pytest.raises(ConsoleError, match="not a readable tar archive"):
        check_archive(p)


def test_uploads_have_a_size_limit(tmp_path):
    c = Console(tmp_path / "ws", upload_limit=10_000)
    try:
        big = b"\0" * 200_000
        r = c.client.post("/api/uploads", files={"file": ("big.tar.gz", big, "application/gzip")})
        assert r.status_code == 413
        assert not any((c.app.state.workspace.root / ".console" / "uploads").glob("*"))
        r = c.client.post("/api/uploads", files={"file": ("notes.txt", b"x", "text/plain")})
        assert r.status_code == 400 and ".tar.gz" in r.json()["error"]
    finally:
        c.stop()


def test_reports_are_served_sandboxed(trained):
    c = trained.client
    key = c.post("/api/models/m1/report").json()["key"]
    from tests.console.conftest import wait_task

    wait_task(c, key)
    r = c.get("/api/models/m1/report")
    assert r.status_code == 200 and r.headers["content-type"].startswith("text/html")
    assert r.headers["content-security-policy"].startswith("sandbox")
    assert r.headers["x-content-type-options"] == "nosniff"
