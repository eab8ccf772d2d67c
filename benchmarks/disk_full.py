"""A training that fills its disk: one line, nothing half-written, and it resumes once there is room again.

Each run mounts a small tmpfs (needs root; sizes from `--sizes`, in MiB, so the disk fills at different
moments: in a checkpoint, a simtrace, the metrics), trains a features model in it until the disk is full,
then checks what the next run will meet: the exit status and stderr (one line, no traceback), the newest
checkpoint loads, no temporary files and no lock are left. The tmpfs is then grown and the training resumed
for one iteration, which must start at that checkpoint. Prints one JSON object.

    sudo python benchmarks/disk_full.py [--sizes 6,8,10,12,16]
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from racerlab.model import ModelFolder, init_model


def _train(model: Path, iterations: int) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "racerlab", "train", str(model), "--iterations", str(iterations)],
                          capture_output=True, text=True, timeout=1800)


def one_run(size_mib: int) -> dict:
    mnt = Path(tempfile.mkdtemp(prefix="racerlab-diskfull-"))
    subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size_mib}m", "tmpfs", str(mnt)], check=True)
    try:
        model = init_model(mnt / "m", track="lab_oval", num_cars=8)
        folder = ModelFolder(model.path)
        t0 = time.perf_counter()
        full = _train(model.path, 100_000)
        err = full.stderr.strip()
        last = folder.checkpoints()[-1] if folder.checkpoints() else None
        loads = True
        try:
            if last is not None:
                folder.load_checkpoint(last)
        except Exception:  # noqa: BLE001 - counted
            loads = False
        temp_left = [p.name for p in model.path.rglob("*") if ".tmp-" in p.name]
        lock_left = folder.lock_path.exists()
        subprocess.run(["mount", "-o", f"remount,size={size_mib * 8}m", str(mnt)], check=True)
        again = _train(model.path, 1)
        resumed = re.search(r"resuming at iteration (\d+)", again.stdout)
        return {"size_mib": size_mib, "rc": full.returncode, "stderr_lines": len(err.splitlines()),
                "traceback": "Traceback" in full.stderr, "message": err[-300:],
                "iterations_before_full": last.iteration if last else 0, "last_checkpoint_loads": loads,
                "temp_files_left": len(temp_left), "temp_names": temp_left[:3], "lock_left": lock_left,
                "resume_rc": again.returncode, "resumed_at": int(resumed.group(1)) if resumed else None,
                "seconds": round(time.perf_counter() - t0, 1)}
    finally:
        subprocess.run(["umount", str(mnt)], check=False)
        mnt.rmdir()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="6,8,10,12,16", help="tmpfs sizes in MiB, one run each")
    args = ap.parse_args()
    if os.geteuid() != 0:
        sys.exit("disk_full.py mounts a tmpfs: run it as root")
    load_before = os.getloadavg()
    runs = [one_run(int(s)) for s in args.sizes.split(",")]
    ok = [r for r in runs if r["rc"] == 2 and r["stderr_lines"] == 1 and not r["traceback"]
          and r["last_checkpoint_loads"] and not r["temp_files_left"] and not r["lock_left"]
          and r["resume_rc"] == 0 and r["resumed_at"] == r["iterations_before_full"]]
    print(json.dumps({"benchmark": "disk_full", "runs": len(runs), "clean": len(ok), "details": runs,
                      "load_before": [round(x, 2) for x in load_before],
                      "load_after": [round(x, 2) for x in os.getloadavg()]}))


if __name__ == "__main__":
    main()
