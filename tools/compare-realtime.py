#!/usr/bin/env python3
"""Real time, this build against an older one, alternated in one invocation.

Runs each build's `realtime-bench` (one run per condition per call, the builds taking turns
which goes first) and prints per condition the median and the spread of each build's runs, and
the ratio of the medians. Usage:

    tools/compare-realtime.py OLD_RELEASE_DIR [--runs 3] [--only 30:0,30:2,60:2,30:2:480]

OLD_RELEASE_DIR is another checkout's target/release (its realtime-bench and services).
"""

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

FIGURES = [
    ("tracked_fps", "tracked fps", 1.0),
    ("dropped_pct", "dropped %", 1.0),
    ("end_to_end_p50_ms", "e2e p50 ms", 1.0),
    ("end_to_end_p99_ms", "e2e p99 ms", 1.0),
    ("ate_rmse_m", "ATE mm", 1000.0),
]


def bench(release: Path, dataset: str, only: str, out: Path, runs_dir: Path) -> list:
    program = release / "realtime-bench"
    if not program.is_file():
        sys.exit(f"{program}: no realtime-bench there (build that checkout: cargo build --release --workspace)")
    cmd = [str(program), dataset, "--runs", "1", "--no-lockstep", "--only", only,
           "--out", str(out), "--output-dir", str(runs_dir)]
    done = subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    if done.returncode != 0:
        sys.exit(f"{program} failed ({done.returncode}):\n{done.stderr[-2000:]}")
    return json.loads(out.read_text())["runs"]


def main() -> None:
    here = Path(__file__).resolve().parent.parent
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("old", type=Path, help="the older build's target/release")
    p.add_argument("--new", type=Path, default=here / "target/release", help="this build (default: target/release)")
    p.add_argument("--dataset", default=str(here.parent / "shared/data/tum/rgbd_dataset_freiburg1_rpy_first300"))
    p.add_argument("--runs", type=int, default=3, help="runs per condition and build")
    p.add_argument("--only", default="30:0,30:2,60:2", help="conditions, FPS:BUSY or FPS:BUSY:SEGMENTER_PX (an older realtime-bench may not take the third)")
    a = p.parse_args()
    builds = {"old": a.old.resolve(), "new": a.new.resolve()}
    results = {"old": [], "new": []}
    with tempfile.TemporaryDirectory(prefix="dynslam-compare-") as tmp:
        tmp = Path(tmp)
        for i in range(a.runs):
            order = ["old", "new"] if i % 2 == 0 else ["new", "old"]
            for name in order:
                print(f"run {i + 1}/{a.runs}: {name} ({builds[name]})", file=sys.stderr, flush=True)
                out = tmp / f"{name}-{i}.json"
                results[name] += bench(builds[name], a.dataset, a.only, out, tmp / "runs")
    conditions = sorted({(r["fps_in"], r["busy_processes"], r.get("segmenter_px") or 0) for r in results["new"]})
    print(f"real time, {a.runs} runs per condition and build, alternated; median [min-max]")
    print(f"{'fps':>4} {'busy':>4} {'seg px':>6} {'figure':>12} {'old':>24} {'new':>24} {'new/old':>8}")
    for fps, busy, px in conditions:
        for key, label, scale in FIGURES:
            cells = {}
            for name in ("old", "new"):
                v = [r[key] * scale for r in results[name]
                     if r["fps_in"] == fps and r["busy_processes"] == busy
                     and (r.get("segmenter_px") or 0) == px and r.get(key) is not None]
                cells[name] = (statistics.median(v), min(v), max(v)) if v else None
            def fmt(c):
                return "-" if c is None else f"{c[0]:.1f} [{c[1]:.1f}-{c[2]:.1f}]"
            ratio = "-"
            if cells["old"] and cells["new"] and cells["old"][0]:
                ratio = f"{cells['new'][0] / cells['old'][0]:.2f}"
            print(f"{fps:>4.0f} {busy:>4} {px or '-':>6} {label:>12} {fmt(cells['old']):>24} {fmt(cells['new']):>24} {ratio:>8}")


if __name__ == "__main__":
    main()
