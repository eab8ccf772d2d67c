"""`sim_throughput.py` by two source trees in one run: this checkout's `src` and another one's (`--base-src`, e.g.
`git -C /work/main archive main src | tar -x -C /tmp/base`), each in a fresh Python process, alternating (ABBA)
`--rounds` times. One JSON line per measurement with each tree's median and the ratio branch / base (car-steps per
second: above 1 is faster; microseconds per call: below 1 is faster), then the median of the throughput ratios and
the load average before and after (the machine may be shared).

    python benchmarks/sim_base_vs_branch.py --base-src /tmp/base/src [--rounds 4] [--seconds 2] [--jitter]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "benchmarks" / "sim_throughput.py"
METRICS = ("car_steps_per_s", "us_per_car_step")


def run(src: Path, extra: list[str]) -> dict[tuple, dict]:
    """One `sim_throughput.py` run with `src` first on the path: {measurement key: its JSON line}."""
    env = {**os.environ, "PYTHONPATH": str(src)}
    out = subprocess.run([sys.executable, str(SCRIPT), *extra], env=env, capture_output=True, text=True, check=True)
    lines = [json.loads(line) for line in out.stdout.splitlines() if line.startswith("{")]
    return {tuple((k, v) for k, v in line.items() if k not in METRICS and k != "x_drfc_gazebo_15_per_s"): line
            for line in lines}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base-src", required=True, type=Path)
    ap.add_argument("--rounds", type=int, default=4)
    ap.add_argument("--seconds", type=float, default=2.0)
    ap.add_argument("--jitter", action="store_true")
    args = ap.parse_args()
    extra = ["--seconds", str(args.seconds), *(["--jitter"] if args.jitter else [])]
    before = os.getloadavg()
    runs: dict[str, list[dict]] = {"base": [], "branch": []}
    for r in range(args.rounds):
        for name in (("base", "branch") if r % 2 == 0 else ("branch", "base")):
            runs[name].append(run(args.base_src if name == "base" else ROOT / "src", extra))
    ratios = []
    for key, line in runs["base"][0].items():
        metric = next(m for m in METRICS if m in line)
        med = {name: statistics.median(run_[key][metric] for run_ in runs[name]) for name in runs}
        ratio = med["branch"] / med["base"]
        if metric == "car_steps_per_s":
            ratios.append(ratio)
        print(json.dumps({**dict(key), f"base_{metric}": med["base"], f"branch_{metric}": med["branch"],
                          "branch_over_base": round(ratio, 3)}), flush=True)
    print(json.dumps({"bench": "sim_base_vs_branch", "median_throughput_ratio": round(statistics.median(ratios), 3),
                      "rounds": args.rounds, "loadavg_before": before, "loadavg_after": os.getloadavg()}))


if __name__ == "__main__":
    main()
