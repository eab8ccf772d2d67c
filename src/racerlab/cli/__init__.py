"""The `racerlab` command. Thin: parses arguments, calls the packages, prints.

Each sub-command lives in its own module here with a `register(subparsers)` function that adds
its parser and sets `func`; heavy imports happen inside the command functions so that
`racerlab --help` stays instant.
"""

from __future__ import annotations

import argparse
import errno
import importlib
import sys
import warnings
from pathlib import Path

from racerlab import __version__
from racerlab.errors import RacerlabError, RacerlabWarning

DISK_ERRORS = {  # errors of the disk rather than of racerlab: one line, with what to do
    errno.ENOSPC: "free some disk space and run the command again",
    errno.EDQUOT: "your disk quota is used up; free some space and run the command again",
    errno.EROFS: "the folder is on a read-only disk; choose a folder you can write",
    errno.EACCES: "you may not write there; choose a folder you own",
}

# module names under racerlab.cli, in the order `racerlab --help` lists them
COMMAND_MODULES = ["quickstart", "model", "evaluate", "tracks", "line", "calibrate", "report", "reward", "sim",
                   "exchange", "console", "cluster", "league"]


OUT_DIR = Path("racerlab-out")  # where commands with no model folder to write into put their files


def require_models(*paths) -> None:
    """Model folders a command needs, checked before its heavy imports (torch, the simulator): a typo in a
    name is answered at once, not after seconds of loading."""
    from racerlab.model.folder import ModelFolder

    for p in paths:
        ModelFolder(p).require()


def require_path(path: Path, what: str = "log folder or file") -> None:
    """A path a command reads, checked before its heavy imports."""
    if not Path(path).exists():
        raise RacerlabError(f"{path}: no such {what}")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="racerlab",
        description="Train, race and analyse AWS-DeepRacer-style cars locally.",
    )
    parser.add_argument("--version", action="version", version=f"racerlab {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for mod in COMMAND_MODULES:
        importlib.import_module(f"racerlab.cli.{mod}").register(sub)
    return parser


def _one_line_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """racerlab's warnings (a skipped file, dropped rows) as the one line they are; others as Python shows them."""
    if issubclass(category, RacerlabWarning):
        print(f"racerlab: warning: {message}", file=sys.stderr)
    else:
        sys.stderr.write(warnings.formatwarning(message, category, filename, lineno, line))


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        with warnings.catch_warnings():
            warnings.showwarning = _one_line_warning
            return int(args.func(args) or 0)
    except RacerlabError as exc:
        print(f"racerlab: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("racerlab: interrupted", file=sys.stderr)
        return 130
    except OSError as exc:
        if exc.errno not in DISK_ERRORS:
            raise
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"racerlab: error: {where}{exc.strerror}; {DISK_ERRORS[exc.errno]} (files are written whole or not "
              "at all: a training resumes from its last complete iteration)", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
