"""A hostile Zenoh client (eclipse-zenoh from PyPI, not our code): sends a
remote segmenter worker queries that are no frames of its run (empty,
random bytes, a 16 MB blob, a postcard-like header that lies about its
sizes) and prints what came back as JSON: each is expected to be refused
with an error reply while the worker keeps serving."""

import argparse
import json
import os
import struct

import zenoh


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--endpoint", required=True)
    p.add_argument("--run", required=True)
    a = p.parse_args()
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("connect/endpoints", json.dumps([a.endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    key = f"dynslam/{a.run}/segmenter/frames"
    # version 1, run name, seq, a huge width and height, then nothing.
    lying = struct.pack("<BB", 1, len(a.run)) + a.run.encode() + bytes([7, 0]) + b"\xff\xff\xff\xff\x0f" * 2
    payloads = {
        "empty": b"",
        "random": os.urandom(1024),
        "huge": bytes(16 * 1024 * 1024),
        "lying": lying,
    }
    out = {}
    with zenoh.open(conf) as session:
        for name, payload in payloads.items():
            replies = []
            for reply in session.get(key, payload=payload, timeout=10.0):
                if reply.ok is not None:
                    replies.append({"ok": len(reply.ok.payload.to_bytes())})
                else:
                    replies.append({"err": reply.err.payload.to_string()})
            out[name] = replies
    print(json.dumps(out))


if __name__ == "__main__":
    main()
