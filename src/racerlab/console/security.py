"""What keeps the console safe to leave running: who may talk to it, which names and files it accepts.

- Loopback by default. Bound to any other address the console needs a token (`--token`, or one generated
  and printed once); the browser presents it once as `?token=...` and gets an HttpOnly cookie.
- Every state-changing request (POST, PUT, DELETE) carries the page's CSRF token in `X-CSRF-Token`, and a
  request whose Origin is another site is refused.
- On loopback, the Host header must name the loopback (a page of another site that rebinds its DNS
  name to 127.0.0.1 cannot talk to the console).
- Model, evaluation and upload names are plain names (no path separators, no `..`); every file the
  console serves is found from such a name, inside the workspace.
- Uploads are size-limited while they stream; a tar archive is checked member by member (plain files
  and folders only, relative paths that stay inside, total size and member count bounded) before any
  part of it is read.
"""

from __future__ import annotations

import hmac
import ipaddress
import math
import re
import secrets
import tarfile
from pathlib import Path, PurePosixPath

from racerlab.errors import RacerlabError
from racerlab.spec import MAX_ARCHIVE_BYTES

NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,63}$")
COOKIE = "racerlab_console"
CSRF_HEADER = "X-CSRF-Token"
MAX_UPLOAD_BYTES = 512 * 1024 * 1024
MAX_ARCHIVE_MEMBERS = 100_000
MIN_TOKEN_CHARS = 16  # a token guessed by anyone who can reach the port is no token
SAFE_METHODS = ("GET", "HEAD", "OPTIONS")


class ConsoleError(RacerlabError):
    """A request the console refuses; `status` is the HTTP status it answers with."""

    def __init__(self, message: str, status: int = 400):
        super().__init__(message)
        self.status = status


def is_loopback(host: str) -> bool:
    if host in ("localhost", ""):
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


def check_name(name: str, what: str = "model name") -> str:
    """A plain folder name: letters, digits, `.`, `_`, `-`, starting with a letter or digit, at most 64."""
    if not isinstance(name, str) or not NAME_RE.fullmatch(name) or ".." in name:
        raise ConsoleError(f"{what} {name!r}: use 1-64 letters, digits, '.', '_' or '-' starting with a letter "
                           "or digit (no '/', no '..')")
    return name


def number(body: dict, key: str, default=None, *, integer: bool = False, low: float | None = None,
           high: float | None = None, above: float | None = None):
    """`body[key]` as a finite number (an int when `integer`) within [low, high] and over `above`; `default` when
    absent or empty. Numbers may come as JSON numbers or strings ("0.5"); anything else, a fraction where a whole
    number is asked for included, is one line naming the field (never rounded: 2.5 episodes is a mistake)."""
    value = body.get(key)
    if value is None or value == "":
        return default
    what = f"{key} must be a finite {'whole ' if integer else ''}number{_span(low, high, above)}, got {value!r}"
    if isinstance(value, bool) or not isinstance(value, int | float | str):
        raise ConsoleError(what)
    try:
        x = float(value)
    except (ValueError, OverflowError):
        raise ConsoleError(what) from None
    if (not math.isfinite(x) or (low is not None and x < low) or (high is not None and x > high)
            or (above is not None and x <= above) or (integer and x != int(x))):
        raise ConsoleError(what)
    return int(x) if integer else x


def _span(low: float | None, high: float | None, above: float | None) -> str:
    """The allowed range as the error says it: " in [1, 100]", " >= 0", " > 0", " <= 1"."""
    if low is not None and high is not None:
        return f" in [{low:g}, {high:g}]"
    parts = [f">= {low:g}" if low is not None else "", f"> {above:g}" if above is not None else "",
             f"<= {high:g}" if high is not None else ""]
    return "".join(f" {p}" for p in parts if p)


def flag(body: dict, key: str, default: bool) -> bool:
    """`body[key]` as a yes/no: true/false (JSON or the strings "true"/"false"), 1/0; else one line."""
    value = body.get(key)
    if value is None or value == "":
        return default
    if isinstance(value, bool):
        return value
    text = str(value).strip().lower()
    if text in ("true", "1", "yes", "on"):
        return True
    if text in ("false", "0", "no", "off"):
        return False
    raise ConsoleError(f"{key} must be true or false, got {value!r}")


def inside(root: Path, *names: str) -> Path:
    """`root/names...` after checking each name; refuses anything that resolves outside `root`."""
    path = Path(root)
    for n in names:
        path = path / check_name(n, "name")
    real_root = Path(root).resolve()
    if not path.resolve().is_relative_to(real_root):
        raise ConsoleError(f"{'/'.join(names)}: outside the workspace", 404)
    return path


def plain_file(path: Path) -> bool:
    """A regular file that is not a symbolic link (the console serves no link, wherever it points)."""
    return path.is_file() and not path.is_symlink()


class Guard:
    """The token (None on loopback) and the CSRF token of one console process."""

    def __init__(self, host: str, token: str | None = None):
        if token is not None and (len(token) < MIN_TOKEN_CHARS or not token.isprintable() or " " in token):
            raise ConsoleError(f"--token: {len(token)} characters; a token needs at least {MIN_TOKEN_CHARS} "
                               "printable characters without spaces (leave --token out for a random one)")
        self.loopback = is_loopback(host)
        self.token = token or (None if self.loopback else secrets.token_urlsafe(24))
        self.csrf = secrets.token_urlsafe(24)

    def host_allowed(self, host_header: str) -> bool:
        if not self.loopback:
            return True
        name = host_header.rsplit(":", 1)[0] if not host_header.endswith("]") else host_header
        return is_loopback(name.strip("[]")) or name == "localhost"

    def authorized(self, cookie: str | None, bearer: str | None, query_token: str | None) -> bool:
        if self.token is None:
            return True
        return any(v and hmac.compare_digest(v, self.token) for v in (cookie, bearer, query_token))

    def csrf_ok(self, method: str, header: str | None, origin: str | None, host_header: str) -> bool:
        if method in SAFE_METHODS:
            return True
        if origin and origin != "null":
            origin_host = origin.split("://", 1)[-1]
            if origin_host != host_header:
                return False
        return bool(header) and hmac.compare_digest(header, self.csrf)


def check_archive(path: Path, max_bytes: int = MAX_ARCHIVE_BYTES, max_members: int = MAX_ARCHIVE_MEMBERS) -> int:
    """Refuse a tar archive with links, devices, absolute or escaping paths, too many members or too many
    bytes; returns the number of files. Called before anything reads the archive's contents."""
    try:
        with tarfile.open(path) as tar:
            total, files = 0, 0
            for n, m in enumerate(tar):
                if n >= max_members:
                    raise ConsoleError(f"{path.name}: more than {max_members} members; upload a smaller archive")
                if not (m.isfile() or m.isdir()):
                    raise ConsoleError(f"{path.name}: member {m.name!r} is a link or special file; only plain "
                                       "files and folders are accepted")
                p = PurePosixPath(m.name)
                if p.is_absolute() or ".." in p.parts or m.name.startswith(("/", "\\")) or ":" in p.parts[0]:
                    raise ConsoleError(f"{path.name}: member {m.name!r} points outside the archive")
                total += m.size
                files += m.isfile()
                if total > max_bytes:
                    raise ConsoleError(f"{path.name}: unpacks to more than {max_bytes} bytes")
    except (tarfile.TarError, EOFError, OSError) as exc:
        raise ConsoleError(f"{path.name}: not a readable tar archive ({exc}); upload a .tar.gz of log files") from None
    if files == 0:
        raise ConsoleError(f"{path.name}: the archive holds no files")
    return files


async def save_upload(upload, dest: Path, limit: int = MAX_UPLOAD_BYTES) -> int:
    """Stream an UploadFile to `dest`, stopping (and deleting) as soon as it passes `limit` bytes."""
    size = 0
    tmp = dest.with_name(dest.name + ".part")
    try:
        with open(tmp, "wb") as f:
            while chunk := await upload.read(1 << 20):
                size += len(chunk)
                if size > limit:
                    raise ConsoleError(f"{upload.filename}: larger than the upload limit of {limit} bytes", 413)
                f.write(chunk)
        tmp.replace(dest)
    except OSError as exc:
        raise ConsoleError(f"{upload.filename}: cannot store the upload ({exc.strerror}); free some disk space "
                           "and upload again", 507) from None
    finally:
        tmp.unlink(missing_ok=True)
    return size
