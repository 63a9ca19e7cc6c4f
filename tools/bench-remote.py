#!/usr/bin/env python3
"""`just bench-remote`, its second part: real time at 30 fps on the shared sequence with the
segmenter local, remote over loopback and remote through a relay that delays each byte 20 ms
each way, the three alternated in one invocation; then the robot's services pinned to one core
with the 480 px segmenter local on that core against remote on the other core.

Per configuration it prints the median (and range) of tracked fps, masked share (masks per
tracked frame) and ATE, and each remote one's ratio to the local one with the issue's bars:
loopback within 10 % on all three, the relay within 10 % on tracked fps and 1.2x on ATE;
pinned, the remote 480 px segmenter keeps >= 28 tracked fps. Usage:

    tools/bench-remote.py [--runs 3] [--delay-ms 20] [--skip-pinned]
"""

import argparse
import json
import os
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent.parent
RELEASE = HERE / "target/release"
DATASET = HERE.parent / "shared/data/tum/rgbd_dataset_freiburg1_rpy_first300"


def free_port() -> int:
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


def write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def worker(port: int, size: int, tmp: Path, cores: str = "") -> subprocess.Popen:
    config = write(tmp / f"worker-{size}.toml", f"[services.segmenter]\ninput_size = {size}\n")
    cmd = [str(RELEASE / "mask-worker"), "segmenter", "--run", "bench", "--listen",
           f"tcp/127.0.0.1:{port}", "--config", str(config)]
    if cores:
        cmd = ["taskset", "-c", cores] + cmd
    log = open(tmp / f"worker-{size}-{port}.log", "w")
    p = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=log)
    deadline = time.time() + 60
    while "serving run" not in (tmp / f"worker-{size}-{port}.log").read_text():
        if p.poll() is not None or time.time() > deadline:
            sys.exit(f"the worker did not start: {(tmp / f'worker-{size}-{port}.log').read_text()[-2000:]}")
        time.sleep(0.1)
    return p


def remote_config(tmp: Path, name: str, endpoint: str, size: int) -> Path:
    return write(tmp / f"{name}.toml",
                 f"[services.segmenter]\nlocation = \"remote\"\ninput_size = {size}\n"
                 f"[remote]\nrun = \"bench\"\nlisten = []\nconnect = [\"{endpoint}\"]\n")


def realtime(config: Path, tmp: Path, name: str, cores: str = "") -> dict:
    out = tmp / f"{name}-{time.time_ns()}.json"
    cmd = [str(RELEASE / "realtime-bench"), str(DATASET), "--runs", "1", "--no-lockstep",
           "--only", "30:0", "--config", str(config), "--out", str(out),
           "--output-dir", str(tmp / "runs")]
    if cores:
        cmd = ["taskset", "-c", cores] + cmd
    done = subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    if done.returncode != 0:
        sys.exit(f"realtime-bench ({name}) failed ({done.returncode}):\n{done.stderr[-3000:]}")
    return json.loads(out.read_text())["runs"][0]


FIGURES = [("tracked_fps", "tracked fps", 1.0, "{:.1f}"),
           ("masked_share", "masked %", 100.0, "{:.1f}"),
           ("ate_rmse_m", "ATE mm", 1000.0, "{:.1f}")]


def summary(runs: list) -> dict:
    return {key: statistics.median(r[key] * scale for r in runs) for key, _, scale, _ in FIGURES}


def row(name: str, runs: list) -> str:
    cells = []
    for key, _, scale, fmt in FIGURES:
        values = [r[key] * scale for r in runs]
        cells.append(f"{fmt.format(statistics.median(values))} ({fmt.format(min(values))}-{fmt.format(max(values))})")
    return f"{name:<22}" + "".join(f"{c:>24}" for c in cells)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--runs", type=int, default=3, help="runs per configuration")
    p.add_argument("--delay-ms", type=int, default=20)
    p.add_argument("--skip-pinned", action="store_true", help="leave out the pinned 480 px part")
    a = p.parse_args()
    results = {}
    with tempfile.TemporaryDirectory(prefix="dynslam-bench-remote-") as tmp:
        tmp = Path(tmp)
        port, relay_port = free_port(), free_port()
        w = worker(port, 320, tmp)
        relay = subprocess.Popen([str(RELEASE / "remote-bench"), "relay", "--listen",
                                  f"127.0.0.1:{relay_port}", "--to", f"127.0.0.1:{port}",
                                  "--delay-ms", str(a.delay_ms)],
                                 stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        configs = {
            "local": write(tmp / "local.toml", "[services.segmenter]\ninput_size = 320\n"),
            "remote loopback": remote_config(tmp, "loopback", f"tcp/127.0.0.1:{port}", 320),
            f"remote relay {a.delay_ms} ms": remote_config(tmp, "relay", f"tcp/127.0.0.1:{relay_port}", 320),
        }
        names = list(configs)
        for i in range(a.runs):
            order = names[i % 3:] + names[:i % 3]
            for name in order:
                print(f"run {i + 1}/{a.runs}: {name}", file=sys.stderr, flush=True)
                results.setdefault(name, []).append(realtime(configs[name], tmp, name.split()[0]))
        relay.kill()
        w.kill()
        w.wait()
        pinned = {}
        if not a.skip_pinned and (os.cpu_count() or 1) >= 2:
            # The robot's services on core 0; the remote worker alone on core 1.
            local480 = write(tmp / "local480.toml", "[services.segmenter]\ninput_size = 480\n")
            port = free_port()
            w = worker(port, 480, tmp, cores="1")
            remote480 = remote_config(tmp, "remote480", f"tcp/127.0.0.1:{port}", 480)
            for i in range(a.runs):
                for name, config in ([("local 480 px", local480), ("remote 480 px", remote480)]
                                     if i % 2 == 0 else
                                     [("remote 480 px", remote480), ("local 480 px", local480)]):
                    print(f"pinned run {i + 1}/{a.runs}: {name}", file=sys.stderr, flush=True)
                    pinned.setdefault(name, []).append(realtime(config, tmp, name.split()[0], cores="0"))
            w.kill()
            w.wait()

    print(f"\nreal time 30 fps, shared sequence, segmenter 320 px, {a.runs} runs each (median, range)")
    print(f"{'':<22}" + "".join(f"{label:>24}" for _, label, _, _ in FIGURES))
    for name in names:
        print(row(name, results[name]))
    base = summary(results["local"])
    print("\nagainst local (the issue's bars):")
    for name in names[1:]:
        s = summary(results[name])
        fps = s["tracked_fps"] / base["tracked_fps"]
        masked = s["masked_share"] / max(base["masked_share"], 1e-9)
        ate = s["ate_rmse_m"] / base["ate_rmse_m"]
        if "loopback" in name:
            ok = all(abs(r - 1.0) <= 0.10 for r in (fps, masked, ate))
            bar = "fps, masked, ATE within 10 %"
        else:
            ok = abs(fps - 1.0) <= 0.10 and ate <= 1.2
            bar = "fps within 10 %, ATE <= 1.2x"
        print(f"  {name:<20} fps x{fps:.3f}  masked x{masked:.3f}  ATE x{ate:.3f}  [{bar}: {'met' if ok else 'NOT met'}]")
    if pinned:
        print("\nrobot's services pinned to core 0, segmenter 480 px (the remote worker on core 1):")
        print(f"{'':<22}" + "".join(f"{label:>24}" for _, label, _, _ in FIGURES))
        for name, runs in pinned.items():
            print(row(name, runs))
        fps = summary(pinned["remote 480 px"])["tracked_fps"]
        print(f"  remote 480 px keeps >= 28 tracked fps: {'met' if fps >= 28 else 'NOT met'} ({fps:.1f})")
    out = HERE / "bench-results/remote_realtime.json"
    out.parent.mkdir(exist_ok=True)
    out.write_text(json.dumps({"runs": results, "pinned": pinned}, indent=1, default=str))
    print(f"(written to {out.relative_to(HERE)})")


if __name__ == "__main__":
    main()
