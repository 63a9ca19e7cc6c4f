#!/usr/bin/env python3
"""Prints the poses of a running dynslam pipeline as they come (TUM format).

The pose stream is the iceoryx2 publish-subscribe service
`dynslam/<run id>/poses` with the file prefix `dsl_<run id>_` (README,
"Poses out"). Needs the `iceoryx2` package of the same version as the
pipeline's crate (0.10.0): `pip install iceoryx2==0.10.0`, or the venv that
`just pyiceoryx2` makes in `.cache/iox2-venv`.

    python3 docs/examples/poses.py --run-id demo            # every pose, until the run ends
    python3 docs/examples/poses.py --run-id demo --count 100 --out poses.txt

Each line: seq state keyframe | timestamp tx ty tz qx qy qz qw.
"""

import argparse
import ctypes
import sys
import time

import iceoryx2 as iox2

POSE_VERSION = 1
STATES = {0: "not_initialised", 1: "ok", 2: "lost", 3: "relocalised", 4: "skipped"}


class Pose(ctypes.Structure):
    """`shared_types::Pose` (repr(C), 88 bytes): the layout of version 1."""

    _fields_ = [
        ("version", ctypes.c_uint32),
        ("state", ctypes.c_uint32),
        ("seq", ctypes.c_uint64),
        ("timestamp", ctypes.c_double),
        ("pose", ctypes.c_double * 7),
        ("keyframe", ctypes.c_uint32),
        ("reserved", ctypes.c_uint32),
    ]

    @staticmethod
    def type_name() -> str:
        # The name the Rust side gives the type (#[type_name]); a layout
        # change comes with a new one, so an old reader cannot connect.
        return "dynslam::Pose.v1"


def open_stream(run_id: str, wait_s: float):
    """The run's pose service, waiting up to `wait_s` for the pipeline to create it."""
    config = iox2.config.default()
    config.global_cfg.prefix = iox2.FileName.new(f"dsl_{run_id}_")
    node = iox2.NodeBuilder.new().config(config).create(iox2.ServiceType.Ipc)
    name = iox2.ServiceName.new(f"dynslam/{run_id}/poses")
    deadline = time.monotonic() + wait_s
    while True:
        try:
            service = node.service_builder(name).publish_subscribe(Pose).open()
            return node, service.subscriber_builder().create()
        except iox2.PublishSubscribeOpenError as e:
            if time.monotonic() > deadline:
                sys.exit(f"error: no pose stream for run '{run_id}' after {wait_s:.0f} s ({e}); is the run live?")
            time.sleep(0.02)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--run-id", required=True, help="the run's id (dynslam run --run-id, or the run folder's name)")
    ap.add_argument("--count", type=int, default=0, help="stop after this many poses (default: until the run ends)")
    ap.add_argument("--wait", type=float, default=30.0, help="seconds to wait for the run to start")
    ap.add_argument("--idle", type=float, default=5.0, help="stop after this many seconds without a pose")
    ap.add_argument("--out", help="also write the lines to this file")
    args = ap.parse_args()

    node, subscriber = open_stream(args.run_id, args.wait)
    out = open(args.out, "w") if args.out else None
    received, last = 0, time.monotonic()
    while args.count == 0 or received < args.count:
        sample = subscriber.receive()
        if sample is None:
            if time.monotonic() - last > args.idle:
                break
            node.wait(iox2.Duration.from_millis(5))
            continue
        p = sample.payload().contents
        if p.version != POSE_VERSION:
            sys.exit(f"error: pose layout version {p.version}, this reader knows {POSE_VERSION}")
        line = "{} {} {} | {:.6f} {}".format(
            p.seq, STATES.get(p.state, p.state), p.keyframe, p.timestamp, " ".join(f"{v:.6f}" for v in p.pose)
        )
        print(line, flush=True)
        if out:
            out.write(line + "\n")
            out.flush()
        received += 1
        last = time.monotonic()
    print(f"{received} poses", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
