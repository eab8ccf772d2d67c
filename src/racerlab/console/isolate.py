"""Work the console must be able to give up on, run in a child process with a deadline.

A user's reward function runs when the wizard checks it: an endless loop in a call or at import cannot be
stopped inside one of the console's threads, so it runs in a child (forked from a small server process, not
from the console with its threads), whose main thread arms the reward watchdog (racerlab.reward) around every call.
Past the deadline the child is killed and the request answers in one line.
"""

from __future__ import annotations

import multiprocessing as mp

from racerlab.console.security import ConsoleError
from racerlab.errors import RacerlabError

START_S = 300.0  # a child starts in about a second; on a machine under heavy load it can take far longer
_context = None


def _ctx():
    global _context
    if _context is None:
        method = "forkserver" if "forkserver" in mp.get_all_start_methods() else "spawn"
        _context = mp.get_context(method)
        if method == "forkserver":
            _context.set_forkserver_preload(["racerlab.console.runs"])
    return _context


def _child(conn, fn, args) -> None:
    try:
        conn.send(("started",))
        conn.send(("ok", fn(*args)))
    except ConsoleError as exc:
        conn.send(("error", str(exc), exc.status))
    except RacerlabError as exc:
        conn.send(("error", str(exc), 400))
    except Exception as exc:  # noqa: BLE001 - reported in the answer, not lost in the child
        conn.send(("error", f"{type(exc).__name__}: {exc}", 500))
    finally:
        conn.close()


def run_isolated(fn, *args, timeout_s: float, what: str):
    """`fn(*args)` in a child process (fn and args picklable); its ConsoleError or RacerlabError is raised here
    as a ConsoleError, and a child that has not answered within `timeout_s` is killed."""
    ctx = _ctx()
    reader, writer = ctx.Pipe(duplex=False)
    proc = ctx.Process(target=_child, args=(writer, fn, args), daemon=True, name="racerlab-console-check")
    proc.start()
    writer.close()
    try:
        try:
            for started, wait in enumerate((START_S, timeout_s)):  # the deadline counts from the child's start
                if not reader.poll(wait):
                    if not started:
                        raise ConsoleError(f"{what}: the check's process did not start within {START_S:g} s; the "
                                           "machine is overloaded. Try again", 503)
                    raise ConsoleError(f"{what}: no answer within {timeout_s:g} s (an endless loop?); it was "
                                       "stopped. Fix it and check again", 400)
                answer = reader.recv()
        except EOFError:
            proc.join(5)
            raise ConsoleError(f"{what}: the check's process ended without an answer (exit code "
                               f"{proc.exitcode}); fix it and check again", 400) from None
    finally:
        if proc.is_alive():
            proc.kill()
        proc.join(5)
        reader.close()
    if answer[0] == "ok":
        return answer[1]
    raise ConsoleError(answer[1], answer[2])
