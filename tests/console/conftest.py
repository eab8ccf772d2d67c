"""A real console (uvicorn on 127.0.0.1, a free port, in a thread) over a temporary workspace, and an httpx
client that sends the page's CSRF token like the page does. One trained model is shared by the module's
tests that need checkpoints and logs."""

from __future__ import annotations

import re
import socket
import threading
import time
from pathlib import Path

import pytest

pytest.importorskip("fastapi")
pytest.importorskip("uvicorn")
httpx = pytest.importorskip("httpx")


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Console:
    """A running console: `url`, `app`, `client` (CSRF header set), `stop()`."""

    def __init__(self, root: Path, host: str = "127.0.0.1", token: str | None = None, **kw):
        import uvicorn

        from racerlab.console import create_app

        self.app = create_app(root, host, token, **kw)
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        cfg = uvicorn.Config(self.app, host="127.0.0.1", port=self.port, log_level="error")
        self.server = uvicorn.Server(cfg)
        self.thread = threading.Thread(target=self.server.run, daemon=True)
        self.thread.start()
        deadline = time.monotonic() + 20
        while not self.server.started:
            if time.monotonic() > deadline:
                raise RuntimeError("the console did not start")
            time.sleep(0.05)
        self.client = httpx.Client(base_url=self.url, timeout=60,
                                   headers={"X-CSRF-Token": self.app.state.guard.csrf})

    def stop(self) -> None:
        self.client.close()
        self.server.should_exit = True
        self.thread.join(10)


@pytest.fixture
def console(tmp_path):
    c = Console(tmp_path / "ws")
    yield c
    c.stop()


def wait_task(client, key: str, timeout: float = 300) -> dict:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        t = client.get(f"/api/tasks/{key}").json()
        if t["status"] != "running":
            assert t["status"] == "done", t["message"]
            return t
        time.sleep(0.3)
    raise AssertionError(f"task {key} still running after {timeout} s")


def sse_events(client, url: str, until, timeout: float = 120) -> list[tuple[str, dict | str]]:
    """Read server-sent events from `url` until `until(events)` is true."""
    import json

    events = []
    with client.stream("GET", url, timeout=timeout) as resp:
        assert resp.status_code == 200
        event, deadline = None, time.monotonic() + timeout
        for line in resp.iter_lines():
            if line.startswith("event: "):
                event = line[7:]
            elif line.startswith("data: "):
                events.append((event, json.loads(line[6:])))
                if until(events):
                    return events
            if time.monotonic() > deadline:
                break
    raise AssertionError(f"{url}: condition not met; got {[e for e, _ in events]}")


TINY = {"cars": 4, "hyperparameters": {"num_episodes_between_training": 4}}


def wait_idle(client, name: str, timeout: float = 120) -> None:
    deadline = time.monotonic() + timeout
    while client.get(f"/api/models/{name}").json()["state"] != "idle":
        assert time.monotonic() < deadline, f"{name} still busy after {timeout} s"
        time.sleep(0.3)


@pytest.fixture(scope="session")
def trained(tmp_path_factory):
    """A console whose workspace holds `m1`, trained for 2 iterations by `racerlab train` started from the
    console (4 cars, 4 episodes an iteration, lab_oval)."""
    c = Console(tmp_path_factory.mktemp("trained") / "ws")
    r = c.client.post("/api/models", json={"name": "m1", "track": "lab_oval", **TINY})
    assert r.status_code == 200, r.text
    assert c.client.post("/api/models/m1/train", json={"iterations": 2}).status_code == 200
    wait_idle(c.client, "m1", 600)
    yield c
    c.stop()


def csrf_of(page_html: str) -> str:
    return re.search(r'name="csrf-token" content="([^"]+)"', page_html).group(1)
