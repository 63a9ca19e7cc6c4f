"""A ROS 2 client we did not write, for tests/ros2_bridge.rs.

`listen`: a Zenoh router (eclipse-zenoh, PyPI) that records every sample and
liveliness token; each sample is decoded by `rosbags` from its Jazzy type
store (CDR), and each key's type hash is checked against the RIHS01 that
`rosbags` computes; the occupancy grid is recomputed here (numpy) from the
point cloud of the same map. `sdk`: `zenoh-ros2-sdk` (ROBOTIS, PyPI)
discovers the graph and subscribes to the odometry as a ROS 2 node would,
with message definitions written from rosbags' store (it must not clone
anything). `services`: zenoh-ros2-sdk's service client calls the map
services during a run, with type hashes it computes itself.

Runs until its standard input closes (or --seconds pass), then writes the
JSON record named by --out and exits.
"""

import argparse
import json
import os
import sys
import threading
import time

import zenoh
from rosbags.typesys import Stores, get_typestore

STORE = get_typestore(Stores.ROS2_JAZZY)


def ros_type(dds):
    # nav_msgs::msg::dds_::Odometry_ -> nav_msgs/msg/Odometry
    pkg, kind, _, name = dds.split("::")
    return f"{pkg}/{kind}/{name.rstrip('_')}"


def pose_list(p):
    return [p.position.x, p.position.y, p.position.z,
            p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w]


def attachment(a):
    """rmw_zenoh's attachment: i64 sequence number, i64 source timestamp,
    the gid's length and the gid."""
    if a is None:
        return None
    b = a.to_bytes()
    seq = int.from_bytes(b[0:8], "little", signed=True)
    ts = int.from_bytes(b[8:16], "little", signed=True)
    n = b[16]
    return {"seq": seq, "ts": ts, "gid": b[17:17 + n].hex(), "len": len(b)}


def summarise(typ, msg):
    if typ == "nav_msgs/msg/Odometry":
        return {"stamp": [msg.header.stamp.sec, msg.header.stamp.nanosec],
                "frame_id": msg.header.frame_id, "child_frame_id": msg.child_frame_id,
                "pose": pose_list(msg.pose.pose),
                "covariance0": msg.pose.covariance[0]}
    if typ == "tf2_msgs/msg/TFMessage":
        return {"transforms": [{"stamp": [t.header.stamp.sec, t.header.stamp.nanosec],
                                "frame_id": t.header.frame_id,
                                "child_frame_id": t.child_frame_id,
                                "pose": [t.transform.translation.x, t.transform.translation.y,
                                         t.transform.translation.z, t.transform.rotation.x,
                                         t.transform.rotation.y, t.transform.rotation.z,
                                         t.transform.rotation.w]}
                               for t in msg.transforms]}
    if typ == "nav_msgs/msg/Path":
        return {"frame_id": msg.header.frame_id, "poses": len(msg.poses)}
    if typ == "geometry_msgs/msg/PoseArray":
        return {"poses": len(msg.poses)}
    if typ == "diagnostic_msgs/msg/DiagnosticArray":
        return {"status": [{"name": s.name, "level": int(s.level), "message": s.message,
                            "values": {kv.key: kv.value for kv in s.values}}
                           for s in msg.status]}
    if typ == "sensor_msgs/msg/Image":
        return {"stamp": [msg.header.stamp.sec, msg.header.stamp.nanosec],
                "frame_id": msg.header.frame_id, "encoding": msg.encoding,
                "width": int(msg.width), "height": int(msg.height), "step": int(msg.step),
                "data_len": len(msg.data), "labelled": int((msg.data > 0).sum())}
    if typ == "std_msgs/msg/String":
        return {"data": msg.data}
    if typ == "sensor_msgs/msg/PointCloud2":
        return {"stamp": [msg.header.stamp.sec, msg.header.stamp.nanosec],
                "frame_id": msg.header.frame_id,
                "fields": [[f.name, int(f.offset), int(f.datatype), int(f.count)] for f in msg.fields],
                "width": int(msg.width), "height": int(msg.height),
                "point_step": int(msg.point_step), "row_step": int(msg.row_step),
                "data_len": len(msg.data), "is_dense": bool(msg.is_dense),
                "_xyz": cloud_xyz(msg)}
    if typ == "nav_msgs/msg/OccupancyGrid":
        import numpy as np
        data = np.asarray(msg.data, dtype=np.int8)
        return {"stamp": [msg.header.stamp.sec, msg.header.stamp.nanosec],
                "frame_id": msg.header.frame_id, "resolution": float(msg.info.resolution),
                "width": int(msg.info.width), "height": int(msg.info.height),
                "origin": pose_list(msg.info.origin), "data_len": len(data),
                "occupied": int((data == 100).sum()), "free": int((data == 0).sum()),
                "unknown": int((data == -1).sum()),
                "_occupied_cells": [int(i) for i in np.flatnonzero(data == 100)]}
    return {}


def cloud_xyz(msg):
    """The cloud's x y z as a numpy array, read by the fields' offsets."""
    import numpy as np
    raw = np.frombuffer(bytes(msg.data), dtype=np.uint8).reshape(-1, msg.point_step)
    off = {f.name: int(f.offset) for f in msg.fields}
    return np.stack([raw[:, off[a]:off[a] + 4].copy().view("<f4")[:, 0] for a in "xyz"], axis=1)


def grid_check(record, band, min_points):
    """For each grid, the occupied cells recomputed from the cloud of the
    same map (same stamp): points in the height band, counted per cell."""
    import numpy as np
    clouds = {tuple(c["stamp"]): c.pop("_xyz") for c in record["samples"].get("/dynslam/map_points", [])}
    checks = []
    for g in record["samples"].get("/map", []):
        cells = set(g.pop("_occupied_cells"))
        xyz = clouds.get(tuple(g["stamp"]))
        if xyz is None:
            continue
        res = round(g["resolution"], 6)
        ox, oy = g["origin"][0], g["origin"][1]
        inside = (xyz[:, 2] >= band[0]) & (xyz[:, 2] < band[1])
        cx = np.floor((xyz[inside, 0].astype(np.float64) - ox) / res).astype(np.int64)
        cy = np.floor((xyz[inside, 1].astype(np.float64) - oy) / res).astype(np.int64)
        ok = (cx >= 0) & (cy >= 0) & (cx < g["width"]) & (cy < g["height"])
        idx, counts = np.unique(cy[ok] * g["width"] + cx[ok], return_counts=True)
        mine = set(int(i) for i in idx[counts >= min_points])
        checks.append({"grid": len(cells), "recomputed": len(mine), "common": len(cells & mine),
                       "points": int(len(xyz)), "in_band": int(inside.sum())})
    for c in record["samples"].get("/dynslam/map_points", []):
        c.pop("_xyz", None)
    for g in record["samples"].get("/map", []):
        g.pop("_occupied_cells", None)
    record["grid_checks"] = checks


def wait_for_end(seconds):
    done = threading.Event()
    threading.Thread(target=lambda: (sys.stdin.read(), done.set()), daemon=True).start()
    done.wait(seconds)


def listen(args):
    conf = zenoh.Config()
    if args.config:
        conf = zenoh.Config.from_file(args.config)
    else:
        conf.insert_json5("mode", '"router"')
        conf.insert_json5("listen/endpoints", json.dumps([args.endpoint]))
        conf.insert_json5("scouting/multicast/enabled", "false")
    session = zenoh.open(conf)
    lock = threading.Lock()
    record = {"samples": {}, "tokens": [], "hashes": {}, "errors": []}

    def on_sample(s):
        key = str(s.key_expr)
        if args.count_only:
            with lock:
                record["samples"][key] = record["samples"].get(key, 0) + 1
            return
        parts = key.split("/")
        try:
            dds, hsh = parts[-2], parts[-1]
            typ = ros_type(dds)
            if typ not in record["hashes"]:
                record["hashes"][typ] = {"key": hsh, "rosbags": STORE.hash_rihs01(typ)}
            msg = STORE.deserialize_cdr(s.payload.to_bytes(), typ)
            entry = summarise(typ, msg)
            entry["attachment"] = attachment(s.attachment)
        except Exception as e:  # recorded, the test fails on it
            with lock:
                record["errors"].append(f"{key}: {e!r}")
            return
        topic = "/" + "/".join(parts[1:-2])
        with lock:
            record["samples"].setdefault(topic, []).append(entry)

    def on_token(s):
        with lock:
            record["tokens"].append([str(s.kind), str(s.key_expr)])

    def late_joiner():
        """Once the run is under way, a late subscriber of each latched
        (transient-local) topic asks the publisher's cache, as rmw_zenoh's
        transient-local subscriptions do (zenoh's advanced subscriber); a
        plain subscriber declared at the same moment gets only what is
        published from then on. Counts what each got within 0.3 s."""
        import zenoh.ext
        while not any(k.startswith("/dynslam/map_points") for k in record["samples"]):
            time.sleep(0.05)
        time.sleep(0.4)
        got = {}
        subs = []
        for topic in ["tf_static", "map", "dynslam/map_points"]:
            got[topic] = {"cached": 0, "plain": 0}
            key = f"{args.domain}/{topic}/**"

            def count(kind, topic=topic):
                def f(_):
                    with lock:
                        got[topic][kind] += 1
                return f
            subs.append(session.declare_subscriber(key, count("plain")))
            subs.append(zenoh.ext.declare_advanced_subscriber(
                session, key, count("cached"),
                history=zenoh.ext.HistoryConfig(detect_late_publishers=True, max_samples=1)))
        time.sleep(0.3)
        with lock:
            record["late_joiner"] = {t: dict(v) for t, v in got.items()}
        time.sleep(1.0)
        del subs

    subs = [session.declare_subscriber(f"{args.domain}/**", on_sample),
            session.liveliness().declare_subscriber("@ros2_lv/**", on_token, history=True)]
    if args.publish_odom:
        threading.Thread(target=publish_odom, args=(session, args), daemon=True).start()
    if args.late_joiner:
        threading.Thread(target=late_joiner, daemon=True).start()
    print("ready", flush=True)
    wait_for_end(args.seconds)
    with lock:
        for c in record["samples"].get("/dynslam/map_points", []):
            c["finite"] = bool(__import__("numpy").isfinite(c["_xyz"]).all())
        grid_check(record, args.grid_band, args.grid_min_points)
        text = json.dumps(record)
    with open(args.out, "w") as f:
        f.write(text)
    del subs
    os._exit(0)  # a zenoh session can hold the interpreter at exit


def odom_at(t, t0):
    """The robot's made-up odometry: 0.2 m/s along x, a fixed 0.3 rad yaw."""
    import math
    return [0.2 * (t - t0), 0.05, 0.0, 0.0, 0.0, math.sin(0.15), math.cos(0.15)]


def publish_odom(session, args):
    """odom -> base_link at every frame stamp of an rgb.txt, serialised by
    rosbags, over and over (30 stamps a message, one message each 10 ms);
    and a few hostile samples on the same topic."""
    Header = STORE.types["std_msgs/msg/Header"]
    Time = STORE.types["builtin_interfaces/msg/Time"]
    TS = STORE.types["geometry_msgs/msg/TransformStamped"]
    Transform = STORE.types["geometry_msgs/msg/Transform"]
    V3 = STORE.types["geometry_msgs/msg/Vector3"]
    Q = STORE.types["geometry_msgs/msg/Quaternion"]
    TF = STORE.types["tf2_msgs/msg/TFMessage"]
    stamps = [float(l.split()[0]) for l in open(args.publish_odom)
              if l.strip() and not l.startswith("#")]
    t0 = stamps[0]
    key = f"{args.domain}/tf/tf2_msgs::msg::dds_::TFMessage_/{STORE.hash_rihs01('tf2_msgs/msg/TFMessage')}"
    pub = session.declare_publisher(key)
    msgs = []
    for i in range(0, len(stamps), 30):
        ts = []
        for t in stamps[i:i + 30]:
            sec = int(t)
            nsec = int(round((t - sec) * 1e9))
            o = odom_at(t, t0)
            ts.append(TS(header=Header(stamp=Time(sec=sec, nanosec=nsec), frame_id="odom"),
                         child_frame_id="base_link",
                         transform=Transform(translation=V3(x=o[0], y=o[1], z=o[2]),
                                             rotation=Q(x=o[3], y=o[4], z=o[5], w=o[6]))))
        msgs.append(bytes(STORE.serialize_cdr(TF(transforms=ts), "tf2_msgs/msg/TFMessage")))
    good = msgs[0]
    hostile = [
        good[: len(good) // 2],                                 # truncated
        good[:4] + (0xFFFFFFFF).to_bytes(4, "little") + good[8:],  # 4 billion transforms
        b"\x00\x01\x00\x00" + os.urandom(64),                 # noise
    ]
    wrong = session.declare_publisher(
        f"{args.domain}/tf/std_msgs::msg::dds_::String_/{STORE.hash_rihs01('std_msgs/msg/String')}")
    n = 0
    while True:
        pub.put(msgs[n % len(msgs)])
        if n % 50 == 0:
            for h in hostile:
                pub.put(h)
            wrong.put(bytes(STORE.serialize_cdr(STORE.types["std_msgs/msg/String"](data="x"),
                                                "std_msgs/msg/String")))
        n += 1
        time.sleep(0.01)


TUM_FR1 = {"k": [517.306408, 0.0, 318.643040, 0.0, 516.469215, 255.313989, 0.0, 0.0, 1.0],
           "d": [0.262383, -0.953104, -0.005358, 0.002628, 1.163314]}


def play(args):
    """A ROS 2 camera driver (rosbags serialising): the router, a CameraInfo
    every 0.2 s, and the TUM folder's frames as rgb8 Image + 32FC1 depth
    (metres, exact) at --fps once the colour topic has a subscriber; then
    waits for stdin to close. Records what it published."""
    import numpy as np
    from PIL import Image as PILImage
    conf = zenoh.Config()
    conf.insert_json5("mode", '"router"')
    conf.insert_json5("listen/endpoints", json.dumps([args.endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    session = zenoh.open(conf)
    T = STORE.types
    Header, Time = T["std_msgs/msg/Header"], T["builtin_interfaces/msg/Time"]
    Image, CameraInfo = T["sensor_msgs/msg/Image"], T["sensor_msgs/msg/CameraInfo"]
    ROI = T["sensor_msgs/msg/RegionOfInterest"]

    def key(topic, typ):
        return f"{args.domain}/{topic}/{typ.replace('/msg/', '::msg::dds_::')}_/{STORE.hash_rihs01(typ)}"

    def header(t, frame="camera_color_optical_frame"):
        sec = int(t)
        return Header(stamp=Time(sec=sec, nanosec=int(round((t - sec) * 1e9))), frame_id=frame)

    colour = session.declare_publisher(key("camera/color/image_raw", "sensor_msgs/msg/Image"))
    depth = session.declare_publisher(key("camera/aligned_depth_to_color/image_raw", "sensor_msgs/msg/Image"))
    info = session.declare_publisher(key("camera/color/camera_info", "sensor_msgs/msg/CameraInfo"))
    frames = []
    for line in open(os.path.join(args.tum, "associations.txt")):
        if line.startswith("#") or not line.strip():
            continue
        t_rgb, rgb, t_d, d = line.split()[:4]
        frames.append((float(t_rgb), rgb, float(t_d), d))
    frames = frames[: args.limit]
    decoded = []
    for t_rgb, rgb, t_d, d in frames:
        c = np.asarray(PILImage.open(os.path.join(args.tum, rgb)).convert("RGB"))
        z = np.asarray(PILImage.open(os.path.join(args.tum, d))).astype(np.uint32)
        metres = (z / 5000.0).astype(np.float32)  # TUM: 5000 a metre; 0 is no depth
        decoded.append((t_rgb, c, t_d, metres))

    def camera_info():
        h, w = decoded[0][1].shape[:2]
        return bytes(STORE.serialize_cdr(CameraInfo(
            header=header(frames[0][0]), height=h, width=w, distortion_model="plumb_bob",
            d=np.array(TUM_FR1["d"], dtype=np.float64), k=np.array(TUM_FR1["k"], dtype=np.float64),
            r=np.eye(3).flatten(), p=np.zeros(12), binning_x=0, binning_y=0,
            roi=ROI(x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)),
            "sensor_msgs/msg/CameraInfo"))

    info_bytes = camera_info()
    stop = threading.Event()

    def keep_info():
        while not stop.is_set():
            info.put(info_bytes)
            time.sleep(0.2)

    threading.Thread(target=keep_info, daemon=True).start()
    print("ready", flush=True)
    # The frames start once the run's camera listens (and a moment more).
    while not colour.matching_status.matching:
        time.sleep(0.05)
    time.sleep(1.0)
    published = []
    period = 1.0 / args.fps
    start = time.time()
    for i, (t_rgb, c, t_d, mm) in enumerate(decoded):
        h, w = c.shape[:2]
        img = Image(header=header(t_rgb), height=h, width=w, encoding="rgb8", is_bigendian=0,
                    step=w * 3, data=c.reshape(-1))
        dep = Image(header=header(t_d), height=h, width=w, encoding="32FC1", is_bigendian=0,
                    step=w * 4, data=mm.reshape(-1).view(np.uint8))
        depth.put(bytes(STORE.serialize_cdr(dep, "sensor_msgs/msg/Image")))
        colour.put(bytes(STORE.serialize_cdr(img, "sensor_msgs/msg/Image")))
        published.append(t_rgb)
        delay = start + (i + 1) * period - time.time()
        if delay > 0:
            time.sleep(delay)
    wait_for_end(args.seconds)
    stop.set()
    with open(args.out, "w") as f:
        json.dump({"published": published}, f)
    os._exit(0)


def write_msg_files(root, types):
    """One .msg file a type and its dependencies, from rosbags' Jazzy store."""
    for typ in types:
        text, _ = STORE.generate_msgdef(typ, ros_version=2)
        sections = text.split("=" * 80 + "\n")
        main, deps = sections[0], sections[1:]
        files = {typ: main}
        for d in deps:
            head, _, body = d.partition("\n")
            name = head.removeprefix("MSG: ")
            pkg, msg = name.split("/")
            files[f"{pkg}/msg/{msg}"] = body
        for name, body in files.items():
            pkg, _, msg = name.split("/")
            os.makedirs(os.path.join(root, pkg, "msg"), exist_ok=True)
            with open(os.path.join(root, pkg, "msg", msg + ".msg"), "w") as f:
                f.write(body)


def sdk(args):
    from zenoh_ros2_sdk import ROS2Subscriber, get_topic_names_and_types
    from zenoh_ros2_sdk.message_registry import get_registry

    write_msg_files(args.msgs, ["nav_msgs/msg/Odometry"])
    get_registry(args.msgs)
    host, port = args.endpoint.removeprefix("tcp/").rsplit(":", 1)
    received = []
    sub = ROS2Subscriber(topic=args.topic, msg_type="nav_msgs/msg/Odometry",
                         callback=lambda m: received.append(
                             [m.header.stamp.sec, m.header.stamp.nanosec, m.pose.pose.position.x]),
                         router_ip=host, router_port=int(port), domain_id=args.domain)
    print("ready", flush=True)
    # The graph as the query that found the topic saw it: a second query could come after a short
    # run's bridge has left the graph.
    types = []
    deadline = time.time() + args.seconds
    while time.time() < deadline and not any(t == args.topic for t, _ in types):
        types = get_topic_names_and_types(domain_id=args.domain, router_ip=host, router_port=int(port))
        time.sleep(0.2)
    wait_for_end(args.seconds)
    with open(args.out, "w") as f:
        json.dump({"topics": types, "received": received, "subscriber_hash": sub.type_hash}, f)
    os._exit(0)


SRV_DEFS = {
    # Request, response: as `ros2 interface show` prints them (Jazzy).
    "std_srvs/srv/Trigger": ("", "bool success\nstring message"),
    "std_srvs/srv/SetBool": ("bool data", "bool success\nstring message"),
}


def services(args):
    """Calls the map services as a ROS 2 node would (zenoh-ros2-sdk's
    client, type hashes computed by the SDK from the definitions), while
    counting the run's odometry; records each response with the odometry
    count at request and response."""
    from zenoh_ros2_sdk import ROS2ServiceClient
    from zenoh_ros2_sdk.discovery import get_service_names_and_types
    from zenoh_ros2_sdk.utils import compute_service_type_hash

    req, _, resp = open(args.srv).read().partition("---")
    defs = dict(SRV_DEFS)
    defs["dynslam_interfaces/srv/SaveMap"] = (req.strip(), resp.strip())
    host, port = args.endpoint.removeprefix("tcp/").rsplit(":", 1)
    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps([args.endpoint]))
    session = zenoh.open(conf)
    count = [0]
    sub = session.declare_subscriber(f"{args.domain}/dynslam/odometry/**",
                                     lambda s: count.__setitem__(0, count[0] + 1))
    hashes = {t: compute_service_type_hash(t, d[0] or "# empty", d[1]) for t, d in defs.items()}
    clients = {}

    def client(service, typ):
        if service not in clients:
            clients[service] = ROS2ServiceClient(
                service_name=service, srv_type=typ, request_definition=defs[typ][0] or "# empty",
                response_definition=defs[typ][1], type_hash=hashes[typ], router_ip=host,
                router_port=int(port), domain_id=args.domain, timeout=60.0)
        return clients[service]

    def wait_frames(n):
        deadline = time.time() + args.seconds
        while count[0] < n and time.time() < deadline:
            time.sleep(0.02)

    calls = []

    def call(service, typ, **kw):
        before = count[0]
        r = client(service, typ).call(**kw)
        calls.append({"service": service, "request": kw, "at_request": before, "at_response": count[0],
                      "success": None if r is None else bool(r.success),
                      "message": None if r is None else r.message})

    print("ready", flush=True)
    wait_frames(30)
    # Discovery is a liveliness query: asked again until the graph has them.
    listed, deadline = [], time.time() + 10
    while len(listed) < 3 and time.time() < deadline:
        listed = [s for s in get_service_names_and_types(domain_id=args.domain, router_ip=host,
                                                          router_port=int(port))
                  if s[0].startswith("/dynslam/")]
        time.sleep(0.2)
    call("/dynslam/save_map", "dynslam_interfaces/srv/SaveMap", name="office")
    call("/dynslam/save_map", "dynslam_interfaces/srv/SaveMap", name="../evil")
    call("/dynslam/set_localization_mode", "std_srvs/srv/SetBool", data=True)
    wait_frames(calls[-1]["at_response"] + 40)
    call("/dynslam/set_localization_mode", "std_srvs/srv/SetBool", data=False)
    wait_frames(calls[-1]["at_response"] + 20)
    call("/dynslam/reset", "std_srvs/srv/Trigger")
    wait_for_end(args.seconds)
    with open(args.out, "w") as f:
        json.dump({"services": listed, "calls": calls, "hashes": hashes}, f)
    del sub
    os._exit(0)


def main():
    p = argparse.ArgumentParser()
    p.add_argument("mode", choices=["listen", "sdk", "play", "services"])
    p.add_argument("--srv", help="services: the SaveMap.srv of docs/ros2/dynslam_interfaces")
    p.add_argument("--grid-band", type=float, nargs=2, default=[0.1, 1.5],
                   help="listen: the run's grid_min_height and grid_max_height")
    p.add_argument("--grid-min-points", type=int, default=2)
    p.add_argument("--late-joiner", action="store_true",
                   help="listen: check the latched topics' cache with a late subscriber")
    p.add_argument("--tum", help="play: the TUM folder to play")
    p.add_argument("--limit", type=int, default=300, help="play: frames")
    p.add_argument("--fps", type=float, default=15.0, help="play: frames a second")
    p.add_argument("--endpoint", default="tcp/127.0.0.1:7447")
    p.add_argument("--config", help="a Zenoh JSON5 config for the router (TLS)")
    p.add_argument("--domain", type=int, default=0)
    p.add_argument("--topic", default="/dynslam/odometry")
    p.add_argument("--msgs", help="sdk: where to write the message definitions")
    p.add_argument("--publish-odom", metavar="RGB_TXT",
                   help="listen: also publish odom -> base_link at these frames' stamps")
    p.add_argument("--count-only", action="store_true",
                   help="listen: count samples per key, decode nothing (benchmarks)")
    p.add_argument("--seconds", type=float, default=300)
    p.add_argument("--out", required=True)
    args = p.parse_args()
    {"listen": listen, "sdk": sdk, "play": play, "services": services}[args.mode](args)


if __name__ == "__main__":
    main()
