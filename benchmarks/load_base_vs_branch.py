"""A 1 M-row cold load (`racerlab.analysis.load`, the public API) by two source trees in one run: this checkout's
`src` and another one's (`--base-src`, e.g. `git archive <base> src | tar -x -C /tmp/base`), each in a fresh
Python process, alternating (ABBA) `--rounds` times, on the same folder. One JSON line per tree with the median
wall seconds, then the ratio of the medians and the load average before and after (the machine may be shared).

    python benchmarks/load_base_vs_branch.py --base-src /tmp/base/src [--rows 1000000] [--rounds 4]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

from racerlab.logs.synthetic import write_training_folder

COLD = """
import sys, time
from racerlab.analysis import load
t = time.perf_counter(); df = load(sys.argv[1], cache=False)
print(len(df), time.perf_counter() - t)
"""
HERE = Path(__file__).resolve().parents[1] / "src"


def cold(src: Path, folder: Path) -> tuple[int, float]:
    env = {**os.environ, "PYTHONPATH": str(src)}
    out = subprocess.run([sys.executable, "-c", COLD, str(folder)], env=env, capture_output=True, text=True,
                         check=True).stdout.split()
    return int(out[0]), float(out[1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base-src", required=True, type=Path)
    ap.add_argument("--rows", type=int, default=1_000_000)
    ap.add_argument("--rounds", type=int, default=4)
    args = ap.parse_args()
    before = os.getloadavg()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "drfc"
        # 1 M rows in 400 files
        write_training_folder(folder, 400, max(1, round(args.rows / (400 * 120))), 1, 120, seed=3)
        times: dict[str, list[float]] = {"base": [], "branch": []}
        rows = {}
        for r in range(args.rounds):
            for name in (("base", "branch") if r % 2 == 0 else ("branch", "base")):
                rows[name], dt = cold(args.base_src if name == "base" else HERE, folder)
                times[name].append(dt)
    med = {k: statistics.median(v) for k, v in times.items()}
    for k in times:
        print(json.dumps({"bench": "cold_load", "tree": k, "rows": rows[k], "median_s": round(med[k], 3),
                          "runs_s": [round(t, 3) for t in times[k]]}))
    print(json.dumps({"bench": "cold_load_ratio", "branch_over_base": round(med["branch"] / med["base"], 3),
                      "loadavg_before": before, "loadavg_after": os.getloadavg()}))


if __name__ == "__main__":
    main()
