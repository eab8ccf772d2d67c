"""`racerlab console`: a local web app for what the CLI does — models, training, evaluation, races, analysis.

    >>> from racerlab.console import create_app, serve
    >>> serve("my-models", port=8765)       # http://127.0.0.1:8765/, the browser opens

`create_app(root)` is the FastAPI application (tests drive it with httpx); `serve` runs it with uvicorn.
The console calls the same functions as the CLI (training is `racerlab train` in a process of its own);
it needs the `console` extra: `pip install "racerlab[console]"`.
"""

from racerlab.console.app import create_app
from racerlab.console.server import serve

__all__ = ["create_app", "serve"]
