"""`racerlab console`: the web console on 127.0.0.1 (see racerlab.console)."""

from __future__ import annotations

from pathlib import Path


def register(sub) -> None:
    p = sub.add_parser("console", help="a web console in the browser: models, training, evaluation, analysis",
                       description="Serve the racerlab console for the model folders in --dir and open the "
                                   "browser. Loopback only by default; any other --host needs a token (given "
                                   "with --token or generated and printed once).")
    p.add_argument("--port", type=int, default=8765, help="port (default 8765)")
    p.add_argument("--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1)")
    p.add_argument("--dir", type=Path, default=Path("."), help="workspace: the folder holding model folders "
                                                               "(default: here)")
    p.add_argument("--token", help="the access token for a non-loopback --host (default: a random one)")
    p.add_argument("--no-browser", action="store_true", help="do not open the browser")
    p.set_defaults(func=run_console)


def run_console(args) -> int:
    from racerlab.errors import RacerlabError

    try:
        from racerlab.console import serve
    except ImportError as exc:
        raise RacerlabError(f"the console needs FastAPI and uvicorn ({exc.name} is missing): "
                            'pip install "racerlab[console]"') from None
    if not 0 < args.port < 65536:
        raise RacerlabError(f"--port must be within 1-65535, got {args.port}")
    serve(args.dir, host=args.host, port=args.port, token=args.token, open_browser=not args.no_browser)
    return 0
