#!/usr/bin/env python3
"""Publishes a TUM RGB-D folder into a dynslam run as its camera (source.kind = "external").

A stand-in for your own camera driver: it writes each frame straight into the
run's shared memory, the way any program can feed the pipeline (README,
"Frames in"). The frame service is the iceoryx2 publish-subscribe service
`dynslam/<run id>/frames` (payload: a slice of u8, user header
`dynslam::FrameHeader.v1`) with the file prefix `dsl_<run id>_`; after each
frame the event service of the same name is notified. Needs the `iceoryx2`
package of the pipeline's version (0.10.0) and Pillow (to read the PNGs):
`pip install iceoryx2==0.10.0 pillow`, or the venv that `just pyiceoryx2`
makes in `.cache/iox2-venv`.

    dynslam run --config configs/external.toml --run-id cam &
    python3 docs/examples/publish_tum.py --run-id cam --folder ../shared/data/tum/rgbd_dataset_freiburg1_rpy_first300

Frames go out at the sequence's own rate (--speed 2: twice as fast); the last
message is the end of the stream, which ends the run.
"""

import argparse
import ctypes
import os
import re
import sys
import time

import iceoryx2 as iox2
from PIL import Image

ERROR_TEXT_LEN = 192
PIXEL_FORMAT_RGB8 = 1
BAD_INPUT = 1 << 0
END_OF_STREAM = 1 << 1


class StageStamps(ctypes.Structure):
    """CLOCK_MONOTONIC nanoseconds per stage; a publisher fills the first two."""

    _fields_ = [
        ("capture_ns", ctypes.c_uint64),
        ("published_ns", ctypes.c_uint64),
        ("routed_ns", ctypes.c_uint64),
        ("masks_start_ns", ctypes.c_uint64),
        ("masks_done_ns", ctypes.c_uint64),
        ("slam_received_ns", ctypes.c_uint64),
        ("track_start_ns", ctypes.c_uint64),
        ("track_done_ns", ctypes.c_uint64),
    ]


class FrameHeader(ctypes.Structure):
    """`shared_types::FrameHeader` (repr(C), 296 bytes): the layout of version 1."""

    _fields_ = [
        ("seq", ctypes.c_uint64),
        ("source_timestamp", ctypes.c_double),
        ("width", ctypes.c_uint32),
        ("height", ctypes.c_uint32),
        ("pixel_format", ctypes.c_uint32),
        ("has_depth", ctypes.c_uint32),
        ("depth_scale", ctypes.c_float),
        ("flags", ctypes.c_uint32),
        ("stamps", StageStamps),
        ("error", ctypes.c_char * ERROR_TEXT_LEN),
    ]

    @staticmethod
    def type_name() -> str:
        # The name the Rust side gives the type (#[type_name]); a layout
        # change comes with a new one, so an old publisher cannot connect.
        return "dynslam::FrameHeader.v1"


assert ctypes.sizeof(FrameHeader) == 296 and ctypes.alignment(FrameHeader) == 8


def now_ns() -> int:
    return time.clock_gettime_ns(time.CLOCK_MONOTONIC)


def read_list(path: str):
    """(timestamp, relative path) rows of a TUM rgb.txt / depth.txt."""
    rows = []
    with open(path) as f:
        for line in f:
            line = line.strip()
            if line and not line.startswith("#"):
                stamp, rel = line.split()[:2]
                rows.append((float(stamp), rel))
    return rows


def associate(rgb, depth, max_dt=0.02):
    """Each colour image with the nearest depth image within max_dt seconds (TUM's associate.py)."""
    pairs, j = [], 0
    for stamp, rel in rgb:
        while j + 1 < len(depth) and abs(depth[j + 1][0] - stamp) <= abs(depth[j][0] - stamp):
            j += 1
        if depth and abs(depth[j][0] - stamp) <= max_dt:
            pairs.append((stamp, rel, depth[j][1]))
    return pairs


def open_frames(run_id: str, consumers: int, wait_s: float):
    """The run's frame service and its event service, once the run's consumers have subscribed.

    Frames sent before then would only be recorded as dropped (real time: a
    camera does not wait either); waits up to `wait_s` seconds.
    """
    config = iox2.config.default()
    config.global_cfg.prefix = iox2.FileName.new(f"dsl_{run_id}_")
    node = iox2.NodeBuilder.new().config(config).create(iox2.ServiceType.Ipc)
    name = iox2.ServiceName.new(f"dynslam/{run_id}/frames")
    deadline = time.monotonic() + wait_s
    frames = events = None
    while True:
        try:
            if frames is None:
                frames = (
                    node.service_builder(name)
                    .publish_subscribe(iox2.Slice[ctypes.c_uint8])
                    .user_header(FrameHeader)
                    .open()
                )
            if events is None:
                events = node.service_builder(name).event().open()
            subscribed = frames.dynamic_config.number_of_subscribers
            if subscribed >= consumers:
                return node, frames, events
            why = f"{subscribed} of its {consumers} consumers subscribed"
        except (iox2.PublishSubscribeOpenError, iox2.EventOpenError) as e:
            why = str(e)
        if time.monotonic() > deadline:
            sys.exit(
                f"error: run '{run_id}' not ready for frames after {wait_s:.0f} s ({why}); "
                'is it live, with source.kind = "external"?'
            )
        time.sleep(0.05)


def send(publisher, notifier, sample, header: FrameHeader) -> None:
    """Writes the whole header (every field: a loaned header is not zeroed), publishes the sample, wakes the run."""
    header.stamps.published_ns = now_ns()
    ctypes.memmove(ctypes.addressof(sample.user_header().contents), ctypes.byref(header), ctypes.sizeof(header))
    sample.assume_init().send()
    notifier.notify()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--run-id", required=True, help="the run's id (dynslam run --run-id)")
    ap.add_argument("--folder", required=True, help="a TUM RGB-D folder (rgb.txt, depth.txt, rgb/, depth/)")
    ap.add_argument("--limit", type=int, default=0, help="publish at most this many frames (default: all)")
    ap.add_argument("--speed", type=float, default=1.0, help="playback speed against the sequence's timestamps")
    ap.add_argument("--depth-scale", type=float, default=5000.0, help="depth value per metre (TUM: 5000; the run's source.depth_scale)")
    ap.add_argument("--wait", type=float, default=60.0, help="seconds to wait for the run to be ready")
    ap.add_argument("--consumers", type=int, default=4, help="subscribers the run has when ready (supervisor, SLAM, segmenter, propagator)")
    args = ap.parse_args()
    if not re.fullmatch(r"[A-Za-z0-9-]{1,32}", args.run_id):
        sys.exit(f"error: --run-id '{args.run_id}': a run id is 1 to 32 ASCII letters, digits or '-'")
    if args.speed <= 0:
        sys.exit(f"error: --speed {args.speed} must be > 0")

    for listing in ("rgb.txt", "depth.txt"):
        if not os.path.isfile(os.path.join(args.folder, listing)):
            sys.exit(f"error: {args.folder} has no {listing}; is it a TUM RGB-D folder?")
    pairs = associate(read_list(os.path.join(args.folder, "rgb.txt")), read_list(os.path.join(args.folder, "depth.txt")))
    if args.limit > 0:
        pairs = pairs[: args.limit]
    if not pairs:
        sys.exit(f"error: no colour image in {args.folder} has a depth image within 0.02 s")

    first = Image.open(os.path.join(args.folder, pairs[0][1]))
    width, height = first.size
    frame_bytes = width * height * 5  # RGB8, then u16 depth

    node, frames, events = open_frames(args.run_id, args.consumers, args.wait)
    publisher = frames.publisher_builder().initial_max_slice_len(frame_bytes).create()
    notifier = events.notifier_builder().create()
    print(f"publishing {len(pairs)} frames of {width}x{height} to dynslam/{args.run_id}/frames", file=sys.stderr)

    start_wall, start_stamp = time.monotonic(), pairs[0][0]
    for seq, (stamp, rgb_rel, depth_rel) in enumerate(pairs):
        due = start_wall + (stamp - start_stamp) / args.speed
        if due > time.monotonic():
            time.sleep(due - time.monotonic())
        capture = now_ns()
        rgb = Image.open(os.path.join(args.folder, rgb_rel)).convert("RGB").tobytes()
        depth_img = Image.open(os.path.join(args.folder, depth_rel))
        if depth_img.mode not in ("I;16", "I"):
            sys.exit(f"error: {depth_rel} is {depth_img.mode}, not 16-bit depth")
        depth = depth_img.convert("I;16").tobytes()  # native (little) endian u16
        if len(rgb) + len(depth) != frame_bytes:
            sys.exit(f"error: {rgb_rel} is not {width}x{height} like the first frame")

        sample = publisher.loan_slice_uninit(frame_bytes)
        ctypes.memmove(sample.payload().as_ptr(), rgb, len(rgb))
        ctypes.memmove(sample.payload().as_ptr() + len(rgb), depth, len(depth))
        header = FrameHeader(
            seq=seq,
            source_timestamp=stamp,
            width=width,
            height=height,
            pixel_format=PIXEL_FORMAT_RGB8,
            has_depth=1,
            depth_scale=args.depth_scale,
        )
        header.stamps.capture_ns = capture
        send(publisher, notifier, sample, header)

    # The end of the stream: no pixels, seq = the number of frames.
    send(publisher, notifier, publisher.loan_slice_uninit(0), FrameHeader(seq=len(pairs), flags=END_OF_STREAM))
    print(f"{len(pairs)} frames published", file=sys.stderr)
    # Leave before the run ends and removes its shared-memory files (ours
    # among them): samples not yet taken stay readable after we go
    # (iceoryx2 keeps a departed publisher's segment for its subscribers).
    return 0


if __name__ == "__main__":
    sys.exit(main())
