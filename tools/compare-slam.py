#!/usr/bin/env python3
"""SLAM core speed, this build against an older one, alternated in one invocation.

Runs each build's `slam-bench` on the same sequence with one and with two extraction threads,
the builds taking turns which goes first, and prints per figure (extraction alone, extract,
track, total per frame: p50 ms; ATE) the median and spread of each build's runs and the ratio
of the medians. Usage:

    tools/compare-slam.py OLD_RELEASE_DIR [--runs 3] [--threads 1,2] [--new-args "--flow-frames 3"]

OLD_RELEASE_DIR is another checkout's target/release (its slam-bench).
"""

import argparse
import re
import shlex
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

# (label, pattern on slam-bench's output, scale)
FIGURES = [
    ("extract p50 ms", re.compile(r"^extract\s+([0-9.]+)", re.M), 1.0),
    ("track p50 ms", re.compile(r"^track\s+([0-9.]+)", re.M), 1.0),
    ("total p50 ms", re.compile(r"^total\s+([0-9.]+)", re.M), 1.0),
    ("ATE mm", re.compile(r"^ATE rmse ([0-9.]+) m", re.M), 1000.0),
]
ALONE = re.compile(r"(1 thread|\d+ threads) p50 ([0-9.]+) ms")


def bench(release: Path, dataset: str, threads: int, out: Path, extra: list) -> dict:
    program = release / "slam-bench"
    if not program.is_file():
        sys.exit(f"{program}: no slam-bench there (build that checkout: cargo build --release --workspace)")
    cmd = [str(program), dataset, "--threads", str(threads), "--out", str(out)] + extra
    done = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    if done.returncode != 0:
        sys.exit(f"{program} failed ({done.returncode}):\n{done.stderr[-2000:]}")
    text = done.stdout
    figures = {}
    for label, pattern, scale in FIGURES:
        m = pattern.search(text)
        if m:
            figures[label] = float(m.group(1)) * scale
    # slam-bench measures extraction alone with one thread whenever it runs with more.
    for line in text.splitlines():
        if line.startswith("extraction alone"):
            for name, value in ALONE.findall(line):
                figures[f"extraction alone, {name}, ms"] = float(value)
    if not figures:
        sys.exit(f"{program}: no figures in its output:\n{text[-2000:]}")
    return figures


def main() -> None:
    here = Path(__file__).resolve().parent.parent
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("old", type=Path, help="the older build's target/release")
    p.add_argument("--new", type=Path, default=here / "target/release", help="this build (default: target/release)")
    p.add_argument("--dataset", default=str(here.parent / "shared/data/tum/rgbd_dataset_freiburg1_rpy_first300"))
    p.add_argument("--runs", type=int, default=3, help="runs per thread count and build")
    p.add_argument("--threads", default="1,2", help="extraction thread counts, comma-separated")
    p.add_argument("--new-args", default="", help="more slam-bench flags for this build only (e.g. \"--flow-frames 3\")")
    a = p.parse_args()
    try:
        thread_counts = [int(t) for t in a.threads.split(",")]
        assert all(t >= 1 for t in thread_counts)
    except (ValueError, AssertionError):
        sys.exit(f"--threads {a.threads}: expected thread counts >= 1, comma-separated (e.g. 1,2)")
    if a.runs < 1:
        sys.exit(f"--runs {a.runs}: at least one run")
    builds = {"old": a.old.resolve(), "new": a.new.resolve()}
    extra = {"old": [], "new": shlex.split(a.new_args)}
    results = {(name, t): [] for name in builds for t in thread_counts}
    with tempfile.TemporaryDirectory(prefix="dynslam-compare-slam-") as tmp:
        for i in range(a.runs):
            for t in thread_counts:
                order = ["old", "new"] if i % 2 == 0 else ["new", "old"]
                for name in order:
                    print(f"run {i + 1}/{a.runs}, {t} thread(s): {name} ({builds[name]})", file=sys.stderr, flush=True)
                    results[(name, t)].append(bench(builds[name], a.dataset, t, Path(tmp) / f"{name}.txt", extra[name]))
    print(f"SLAM core, {a.runs} runs per build and thread count, alternated; median [min-max]")
    if a.new_args:
        print(f"new build with: {a.new_args}")
    print(f"{'threads':>7} {'figure':>32} {'old':>22} {'new':>22} {'new/old':>8}")
    for t in thread_counts:
        labels = sorted({k for r in results[("new", t)] for k in r}, key=lambda k: (not k.startswith("extraction"), k))
        for label in labels:
            cells = {}
            for name in builds:
                v = [r[label] for r in results[(name, t)] if label in r]
                cells[name] = (statistics.median(v), min(v), max(v)) if v else None

            def fmt(c):
                return "-" if c is None else f"{c[0]:.2f} [{c[1]:.2f}-{c[2]:.2f}]"
            ratio = "-"
            if cells["old"] and cells["new"] and cells["old"][0]:
                ratio = f"{cells['new'][0] / cells['old'][0]:.2f}"
            print(f"{t:>7} {label:>32} {fmt(cells['old']):>22} {fmt(cells['new']):>22} {ratio:>8}")


if __name__ == "__main__":
    main()
