"""`serve()`: run the console with uvicorn and open the browser."""

from __future__ import annotations

import threading
import webbrowser

from racerlab.console.app import create_app
from racerlab.console.security import is_loopback


def console_url(host: str, port: int) -> str:
    shown = "127.0.0.1" if host in ("0.0.0.0", "") else host
    return f"http://{'[' + shown + ']' if ':' in shown else shown}:{port}/"


def serve(root, host: str = "127.0.0.1", port: int = 8765, token: str | None = None, open_browser: bool = True,
          log_level: str = "warning") -> None:
    import uvicorn

    app = create_app(root, host, token)
    url = console_url(host, port)
    guard = app.state.guard
    print(f"racerlab console for the models in {app.state.workspace.root}")
    if guard.token:
        print(f"open {url}?token={guard.token}  (the token is shown only now; anyone with it can run code here)")
    else:
        print(f"open {url}  (loopback only; Ctrl-C stops the console, trainings it started keep running)")
    if open_browser and is_loopback(host):
        threading.Timer(1.0, webbrowser.open, args=(url,)).start()
    uvicorn.run(app, host=host, port=port, log_level=log_level, timeout_graceful_shutdown=1)
