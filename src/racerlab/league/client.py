"""The HTTP client of a league server: what `racerlab league login | submit | status | standings` call.

    >>> from racerlab.league.client import Client, login
    >>> login("https://league.example.org", invite="rli_...", password="a long password")   # stores the token
    >>> c = Client.stored()                                   # the last server logged in to, with its token
    >>> c.submit("my-model", "may-cup")["status"]            # a model folder (packed here) or an archive
    >>> c.standings("may-cup")["rows"]

- Logging in (with an invite code, or an alias and password) gets an API token; it is kept in
  `config_dir()/league.json` (mode 0600, in a folder of mode 0700), one per server, and sent as
  `Authorization: Bearer`. The password is never stored.
- A password goes only to the loopback over plain HTTP; any other server must be https:// (a club's own
  certificate: `ca_cert`).
- `pack_model` packs a model folder for upload: only the files a submission is read from (the server's own
  filter, `convert.keep`), and of a racerlab folder's checkpoints only the one chosen here (best, last or an
  iteration: resolved in the folder, so the upload stays small and races what the racer picked). The reward
  function stays on the racer's machine: a league never runs it.
- Every refusal is a `LeagueError` of one line: the server's own, or why the server could not be reached.
"""

from __future__ import annotations

import json
import os
import secrets
import tarfile
import tempfile
from contextlib import contextmanager
from pathlib import Path
from urllib.parse import quote, urlsplit

from racerlab.league.store import LeagueError

CONFIG_NAME = "league.json"
TIMEOUT_S = 30.0
LEFT_OUT = ("reward_function.py",)  # a racer's own business: the server never reads it
UPLOAD_TIMEOUT_S = 600.0  # the server converts the model before it answers (an AWS TF checkpoint: ~15 s)


def config_dir() -> Path:
    """`$RACERLAB_CONFIG_HOME`, else `$XDG_CONFIG_HOME/racerlab`, else ~/.config/racerlab."""
    if os.environ.get("RACERLAB_CONFIG_HOME"):
        return Path(os.environ["RACERLAB_CONFIG_HOME"])
    base = os.environ.get("XDG_CONFIG_HOME") or str(Path.home() / ".config")
    return Path(base) / "racerlab"


def config_path() -> Path:
    return config_dir() / CONFIG_NAME


def read_config() -> dict:
    path = config_path()
    if not path.is_file():
        return {"default": None, "servers": {}}
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise LeagueError(f"{path}: not readable ({exc}); remove it and log in again") from None
    return {"default": data.get("default"), "servers": dict(data.get("servers") or {})}


def write_config(data: dict) -> Path:
    """The config file written whole, readable by its owner only (it holds API tokens)."""
    folder = config_dir()
    folder.mkdir(parents=True, exist_ok=True, mode=0o700)
    path = folder / CONFIG_NAME
    tmp = folder / f".{CONFIG_NAME}.{secrets.token_hex(4)}"
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "w") as f:
        json.dump(data, f, indent=2, sort_keys=True)
        f.write("\n")
    os.replace(tmp, path)
    os.chmod(path, 0o600)
    return path


def server_url(url: str) -> str:
    """A league server's base URL, checked: http(s), and https unless it is this machine."""
    from racerlab.console.security import is_loopback

    text = str(url or "").strip().rstrip("/")
    parts = urlsplit(text)
    if parts.scheme not in ("http", "https") or not parts.hostname:
        raise LeagueError(f"{url!r}: give the server's address, e.g. https://league.example.org or "
                          "http://127.0.0.1:8000")
    if parts.scheme == "http" and not is_loopback(parts.hostname):
        raise LeagueError(f"{text}: plain http to another machine would send your password and token in clear; "
                          "use the server's https:// address")
    if parts.path not in ("", "/") or parts.query:
        raise LeagueError(f"{url!r}: give the server's address without a path (e.g. {parts.scheme}://"
                          f"{parts.netloc})")
    return f"{parts.scheme}://{parts.netloc}"


class Client:
    """Requests to one league server, as the holder of `token` (None: only login calls work)."""

    def __init__(self, url: str, token: str | None = None, ca_cert: str | None = None):
        self.url = server_url(url)
        self.token, self.ca_cert = token, ca_cert

    @classmethod
    def stored(cls, url: str | None = None) -> Client:
        """A client for `url` (or the server logged in to last) with the stored token."""
        cfg = read_config()
        key = server_url(url) if url else cfg["default"]
        entry = cfg["servers"].get(key) if key else None
        if not entry:
            hint = f" {key}" if key else " URL"
            raise LeagueError(f"not logged in{' to ' + key if key else ''}; run `racerlab league login{hint} "
                              "--invite CODE` (or with --alias) first")
        return cls(key, entry.get("token"), entry.get("ca_cert"))

    # ---- transport -----------------------------------------------------------------------------------------
    def request(self, method: str, path: str, *, timeout: float = TIMEOUT_S, **kwargs):
        import httpx

        headers = kwargs.pop("headers", {})
        if self.token:
            headers["Authorization"] = f"Bearer {self.token}"
        verify = self.ca_cert or True
        try:
            with httpx.Client(base_url=self.url, verify=verify, timeout=timeout, follow_redirects=False) as http:
                response = http.request(method, path, headers=headers, **kwargs)
        except httpx.TimeoutException:
            raise LeagueError(f"{self.url}: no answer within {timeout:g} s; try again, or ask the league's "
                              "admin whether the server is up") from None
        except httpx.HTTPError as exc:
            raise LeagueError(f"{self.url}: cannot reach the league server ({_first_line(exc)}); check the "
                              "address and that `racerlab league serve` runs there") from None
        if response.status_code >= 400:
            raise LeagueError(f"{self.url}: {_error_text(response)}", response.status_code)
        return response

    def get(self, path: str, **params) -> dict:
        return self.request("GET", path, params={k: v for k, v in params.items() if v is not None}).json()

    # ---- people --------------------------------------------------------------------------------------------
    def login(self, alias: str, password: str, label: str = "") -> dict:
        body = {"alias": alias, "password": password, "label": label or _label()}
        return self.request("POST", "/api/login", json=body).json()

    def accept_invite(self, code: str, password: str, label: str = "") -> dict:
        body = {"code": code.strip(), "password": password, "label": label or _label()}
        return self.request("POST", "/api/invites/accept", json=body).json()

    def me(self) -> dict:
        return self.get("/api/me")

    # ---- races and results ---------------------------------------------------------------------------------
    def races(self) -> list[dict]:
        return self.get("/api/races")["races"]

    def standings(self, race: str) -> dict:
        return self.get(f"/api/races/{quote(race, safe='')}/standings")

    def standings_csv(self, race: str) -> str:
        return self.request("GET", f"/api/races/{quote(race, safe='')}/standings.csv").text

    def submissions(self, race: str | None = None) -> list[dict]:
        return self.get("/api/submissions", race=race)["submissions"]

    def submission(self, submission_id: int) -> dict:
        return self.get(f"/api/submissions/{int(submission_id)}")

    def download(self, submission_id: int, kind: str, dest: Path) -> Path:
        response = self.request("GET", f"/api/submissions/{int(submission_id)}/files/{quote(kind, safe='')}",
                                params={"download": "true"})
        Path(dest).write_bytes(response.content)
        return Path(dest)

    def submit(self, model, race: str, checkpoint: str = "best", name: str = "") -> dict:
        """Upload `model` (a model folder, packed here, or an archive) to `race`; the submission as the server
        answers it (`status` queued with `position`, or `duplicate` with the earlier result and `note`)."""
        with pack_model(Path(model), checkpoint) as (archive, chosen):
            fields = {"checkpoint": chosen, "name": name or _model_name(Path(model))}
            with open(archive, "rb") as f:
                response = self.request("POST", f"/api/races/{quote(race, safe='')}/submissions",
                                        data=fields, files={"model": (archive.name, f, "application/gzip")},
                                        timeout=UPLOAD_TIMEOUT_S)
        return response.json()


def _label() -> str:
    import socket

    return f"racerlab league login on {socket.gethostname()[:40]}"


def _first_line(exc: Exception) -> str:
    return (str(exc).strip().splitlines() or [type(exc).__name__])[0][:200]


def _error_text(response) -> str:
    try:
        return str(response.json().get("error") or response.text)[:500]
    except ValueError:
        return (response.text.strip().splitlines() or [f"HTTP {response.status_code}"])[0][:500]


def _model_name(model: Path) -> str:
    name = model.name
    for suffix in (".tar.gz", ".tgz", ".tar", ".zip"):
        if name.lower().endswith(suffix):
            return name[: -len(suffix)]
    return name


# ---- logging in -------------------------------------------------------------------------------------------------
def login(url: str, *, invite: str | None = None, alias: str | None = None, password: str,
          ca_cert: str | None = None) -> dict:
    """Log in to a league server (accepting `invite`, or as `alias`) and store its API token; the server's answer
    (alias, role, token id) with `config` (where the token is kept)."""
    client = Client(url, ca_cert=ca_cert)
    if invite:
        answer = client.accept_invite(invite, password)
    elif alias:
        answer = client.login(alias, password)
    else:
        raise LeagueError("give --invite CODE (a new account) or --alias ALIAS (an account you have)")
    cfg = read_config()
    cfg["servers"][client.url] = {"token": answer["token"], "alias": answer["alias"], "role": answer["role"],
                                  "token_id": answer["id"], **({"ca_cert": str(ca_cert)} if ca_cert else {})}
    cfg["default"] = client.url
    path = write_config(cfg)
    return {**{k: v for k, v in answer.items() if k != "token"}, "server": client.url, "config": str(path)}


# ---- packing a model folder -------------------------------------------------------------------------------------
@contextmanager
def pack_model(model: Path, checkpoint: str = "best"):
    """(archive, checkpoint to ask for): an archive as it is; a folder packed into a temporary .tar.gz with the
    files a submission is read from (for a racerlab folder: only the chosen checkpoint)."""
    if not model.exists():
        raise LeagueError(f"{model}: no such model folder or archive")
    if model.is_file():
        yield model, checkpoint
        return
    files, chosen = _model_files(model, checkpoint)
    with tempfile.TemporaryDirectory(prefix="racerlab-submit-") as tmp:
        archive = Path(tmp) / f"{_safe_stem(model.name)}.tar.gz"
        with tarfile.open(archive, "w:gz", compresslevel=1) as tar:
            for path in files:
                tar.add(path, arcname=f"{_safe_stem(model.name)}/{path.relative_to(model).as_posix()}",
                        recursive=False)
        yield archive, chosen


def _model_files(model: Path, checkpoint: str) -> tuple[list[Path], str]:
    from racerlab.errors import RacerlabError
    from racerlab.league.convert import CHECKPOINT_RE, keep
    from racerlab.model import ModelFolder

    folder = ModelFolder(model)
    pick = None
    if folder.checkpoints():
        try:
            pick = folder.resolve_checkpoint(checkpoint or "best")
        except RacerlabError as exc:
            raise LeagueError(str(exc)) from None
    files = []
    for path in sorted(model.rglob("*")):
        if path.is_symlink() or not path.is_file() or keep(path.name) is None or path.name in LEFT_OUT:
            continue
        if pick is not None and CHECKPOINT_RE.match(path.name) and path.name != pick.name:
            continue  # another checkpoint of this folder: not the one that races
        files.append(path)
    if not any(p.name == "model_metadata.json" for p in files):
        raise LeagueError(f"{model}: no model_metadata.json; give a racerlab model folder, an AWS model folder or "
                          "its archive")
    return files, (str(pick.iteration) if pick is not None else checkpoint)


def _safe_stem(name: str) -> str:
    import re

    return re.sub(r"[^A-Za-z0-9._-]+", "_", name).strip("._") or "model"
