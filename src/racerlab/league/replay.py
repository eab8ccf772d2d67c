"""`racerlab league replay`: a stored result evaluated again from its stored model and rules, compared bit for bit.

The evaluation runs in a fresh process set up as a worker is (`evaluation.PIN_ENV` before torch loads), without
the video; the per-lap table must equal the stored one exactly, and so must every simtrace column but the wall
clock. A difference means the evaluation is not the pure function it must be (or the store was changed).
"""

from __future__ import annotations

import json
import multiprocessing as mp
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

from racerlab.league.store import LeagueError, Store

TIMEOUT_S = 1800.0


@dataclass
class ReplayReport:
    submission_id: int
    identical: bool
    laps: int
    differences: list = field(default_factory=list)
    stored: dict = field(default_factory=dict)
    replayed: dict = field(default_factory=dict)

    def text(self) -> str:
        if self.identical:
            return (f"submission {self.submission_id}: replayed {self.laps} laps, identical bit for bit "
                    f"({self.stored.get('reason', '')}; rules {self.stored.get('rules_hash', '')[:12]}, model "
                    f"{self.stored.get('model_hash', '')[:12]})")
        return f"submission {self.submission_id}: the replay differs: " + "; ".join(self.differences[:10])

    def to_json(self) -> dict:
        return {"submission_id": self.submission_id, "identical": self.identical, "laps": self.laps,
                "differences": self.differences}


def _child(model_dir: str, rules_json: str, tracks: str, out: str) -> None:
    from racerlab.league.evaluation import evaluate_stored, pin_environment

    pin_environment()
    from racerlab.league.rules import Rules

    evaluate_stored(Path(model_dir), Rules.from_json(rules_json), Path(tracks), Path(out), video=False)


def replay(store: Store, submission_id: int, model_hash: str, rules_json: str, result_dir: str) -> ReplayReport:
    """Evaluate the stored model under the stored rules again and compare with the stored result."""
    import pandas as pd

    from racerlab.league.evaluation import RESULT_NAME, same_laps

    stored_dir = store.path(result_dir)
    stored = json.loads((stored_dir / RESULT_NAME).read_text())
    with tempfile.TemporaryDirectory(prefix="racerlab-replay-") as tmp:
        out = Path(tmp) / "replay"
        ctx = mp.get_context("spawn")
        p = ctx.Process(target=_child, args=(str(store.model_dir(model_hash)), rules_json, str(store.folder / "tracks"),
                                              str(out)), daemon=True)
        p.start()
        p.join(TIMEOUT_S)
        if p.is_alive():
            p.kill()
            raise LeagueError(f"submission {submission_id}: the replay took longer than {TIMEOUT_S:g} s", 500)
        if p.exitcode != 0 or not (out / RESULT_NAME).is_file():
            raise LeagueError(f"submission {submission_id}: the replay's evaluation failed (status {p.exitcode})",
                              500)
        replayed = json.loads((out / RESULT_NAME).read_text())
        diffs = same_laps(stored["laps"], replayed["laps"])
        a = pd.read_csv(stored_dir / "evaluation-simtrace" / "0-iteration.csv").drop(columns=["wall_clock"])
        b = pd.read_csv(out / "evaluation-simtrace" / "0-iteration.csv").drop(columns=["wall_clock"])
        if a.shape != b.shape:
            diffs.append(f"simtrace {a.shape[0]} rows against {b.shape[0]}")
        else:
            cols = [c for c in a.columns if not a[c].equals(b[c])]
            diffs += [f"simtrace column {c} differs" for c in cols]
    for key in ("status", "score_ms"):
        if stored.get(key) != replayed.get(key):
            diffs.append(f"{key}: {stored.get(key)!r} against {replayed.get(key)!r}")
    return ReplayReport(submission_id, not diffs, len(replayed["laps"]), diffs, stored, replayed)
