"""`serve()`: the league's web server (uvicorn), with TLS, and local evaluation workers beside it.

- Loopback by default. Any other `host` needs TLS (`tls_cert` and `tls_key`, PEM files): people's passwords and
  session cookies must not cross a network in clear. Behind a TLS proxy on the same machine, keep the loopback and
  give `public_url` (the proxy's https:// address): its Host is accepted, cookies are Secure, invite links name it,
  and the client address of the login throttle is the one the proxy forwards.
- `workers` N starts N evaluation processes (`racerlab.league.start_workers`) that stop with the server; without
  them submissions wait in the queue for `racerlab league work` (here or on other machines sharing the database).
  `ray` ADDRESS sends them to the Ray cluster there instead (`racerlab.league.ray_pool`), `ray_workers` at a time
  (default: the cluster's CPUs).
"""

from __future__ import annotations

import signal
from pathlib import Path

from racerlab.console.security import is_loopback
from racerlab.league.store import LeagueError


def check_tls(host: str, cert: str | Path | None, key: str | Path | None, public_url: str | None = None) -> None:
    """One line saying why the server may not start this way (None: it may)."""
    if bool(cert) != bool(key):
        raise LeagueError("TLS needs both --tls-cert FILE and --tls-key FILE (PEM); give both or neither")
    for what, path in (("--tls-cert", cert), ("--tls-key", key)):
        if path and not Path(path).is_file():
            raise LeagueError(f"{what} {path}: no such file")
    if not is_loopback(host) and not cert:
        raise LeagueError(f"--host {host}: a league on the network needs TLS (passwords and session cookies would "
                          "cross it in clear); give --tls-cert FILE --tls-key FILE, or keep the loopback and put a "
                          "TLS proxy in front (--public-url https://...)")
    if public_url and not str(public_url).startswith(("https://", "http://127.", "http://localhost")):
        raise LeagueError(f"--public-url {public_url}: give the proxy's https:// address")


def check_evaluators(workers: int, ray: str | None, ray_workers: int | None) -> None:
    """One line when the evaluation flags do not go together."""
    if ray and workers:
        raise LeagueError(f"--workers {workers} and --ray {ray}: give one of them (the Ray cluster's nodes, the "
                          "server's machine among them if it runs a node, do the evaluations)")
    if ray_workers is not None and not ray:
        raise LeagueError(f"--ray-workers {ray_workers}: give --ray ADDRESS as well (local workers: --workers N)")
    if ray_workers is not None and ray_workers < 1:
        raise LeagueError(f"--ray-workers {ray_workers}: give 1 or more")
    if ray:
        from racerlab.league.ray_pool import check_address

        check_address(ray)


def server_address(host: str, port: int, tls: bool) -> str:
    shown = "127.0.0.1" if host in ("0.0.0.0", "") else host
    return f"{'https' if tls else 'http'}://{'[' + shown + ']' if ':' in shown else shown}:{port}"


def serve(folder, url: str | None = None, *, host: str = "127.0.0.1", port: int = 8000, workers: int = 0,
          tls_cert=None, tls_key=None, public_url: str | None = None, log_level: str = "warning",
          ray: str | None = None, ray_workers: int | None = None) -> None:
    import uvicorn

    from racerlab.league import League
    from racerlab.league.web.app import create_app

    check_tls(host, tls_cert, tls_key, public_url)
    if workers < 0:
        raise LeagueError(f"--workers {workers}: give 0 or more")
    check_evaluators(workers, ray, ray_workers)
    league = League.open(folder, url)
    app = create_app(folder, url, host=host, tls=bool(tls_cert), public_url=public_url, league=league)
    address = public_url or server_address(host, port, bool(tls_cert))
    try:
        pool, where = _evaluators(folder, url, workers, ray, ray_workers)
    except BaseException:
        league.close()
        raise
    print(f"racerlab league {folder}: open {address}/  ({where}; Ctrl-C stops the server)", flush=True)
    previous = signal.signal(signal.SIGTERM, _exit_on_term)
    try:
        uvicorn.run(app, host=host, port=port, log_level=log_level, timeout_graceful_shutdown=2,
                    ssl_certfile=str(tls_cert) if tls_cert else None, ssl_keyfile=str(tls_key) if tls_key else None,
                    proxy_headers=bool(public_url), forwarded_allow_ips="127.0.0.1,::1" if public_url else None)
    finally:
        signal.signal(signal.SIGTERM, previous)
        if pool is not None:
            pool.stop()
        league.close()


def _evaluators(folder, url, workers: int, ray: str | None, ray_workers: int | None):
    """The evaluations beside the server (a pool to stop, or None) and the words that say where they run."""
    from racerlab.league import start_ray_workers, start_workers

    if ray:
        where = f"evaluations on the Ray cluster at {ray}, {ray_workers or 'one per CPU of the cluster'} at a time"
        return start_ray_workers(folder, url, ray, ray_workers), where
    pool = start_workers(folder, url, workers=workers) if workers else None
    return pool, f"{workers or 'no'} local evaluation worker{'s' if workers != 1 else ''}"


def _exit_on_term(signum, frame) -> None:
    """SIGTERM ends the server like Ctrl-C: uvicorn shuts down, then raises the signal again once it has restored
    this handler, and the SystemExit lets `serve` stop its workers (the default handler would leave them
    running without a parent)."""
    raise SystemExit(0)
