"""A robomaker log read while the simulator still writes it ends in a cut line: that line is left out, the log is
read (the whole log was refused); a malformed line before the last is still an error naming it."""

from __future__ import annotations

from pathlib import Path

import pytest

from racerlab.analysis import load
from racerlab.logs.metrics import LogFileError

LOG = Path(__file__).resolve().parents[2].parent / "shared" / "reference" / "real_logs" / \
    "2019-robomaker-eval-deepracer-eval-sim-sample.log"
pytestmark = pytest.mark.skipif(not LOG.is_file(), reason="the shared real logs are not beside the checkout")


@pytest.mark.parametrize("keep", [60, 20], ids=["cut-after-9-fields", "cut-after-2-fields"])
def test_a_cut_last_line_is_left_out(tmp_path, keep):
    data = LOG.read_bytes()
    last = data.rfind(b"SIM_TRACE_LOG:")
    cut = tmp_path / "running.log"
    cut.write_bytes(data[:last + keep])
    whole = load(LOG, cache=False)
    got = load(cut, cache=False)
    assert len(whole) == 480 and len(got) == 479
    assert got.iloc[-1][["steps", "x", "y"]].tolist() == whole.iloc[-2][["steps", "x", "y"]].tolist()


def test_a_cut_line_before_the_last_is_an_error_naming_it(tmp_path):
    data = LOG.read_bytes()
    last = data.rfind(b"SIM_TRACE_LOG:")
    bad = tmp_path / "bad.log"
    bad.write_bytes(data[:last + 60] + b"\n" + data[last:])
    with pytest.raises(LogFileError, match=r"bad\.log:\d+: expected 15 to 19 fields, got 9"):
        load(bad, cache=False)
