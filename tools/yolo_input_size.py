"""Rewrites a shared YOLO-seg ONNX export (fixed 320x320 input) for another input size.

    python tools/yolo_input_size.py SRC.onnx DST.onnx --size 640

`just setup` runs it (Python `onnx`, pinned, in .cache/onnx-venv) to make the sizes ../shared/models
lacks (YOLOv8n-seg 480 and 640 from yolov8n-seg_f32.onnx, YOLO11n-seg 480 from
yolo11n-seg_320_f32.onnx) and checks each result against its pinned sha256; the files are never
committed (the weights are AGPL-3.0: ../shared/models/README.md).

Why a rewrite is needed: the exports are static. Convolutions, pooling and the nearest-neighbour
upsampling work at any size that is a multiple of 32, but the detection head has the anchor grid
baked in as constants for 320 (2100 anchors = 40x40 + 20x20 + 10x10 at strides 8, 16, 32):
  - the anchor-centre tensor [1, 2, A] (x, y of each cell centre in grid units, +0.5; YOLOv8n-seg
    holds it twice),
  - the stride per anchor [1, A] (YOLO11n-seg: [1, 1, A]),
  - the DFL reshape targets [1, 4, 16, A] and (YOLOv8n-seg) [1, 4, A],
  - YOLO11n-seg only: 20 reshape targets holding the feature maps' cell counts (1600, 400, 100) or
    the stride-32 side (10): its attention block (C2PSA) and the per-level head outputs,
and the graph's declared input / output / intermediate shapes. This script finds those constants
by their values (not by node names), proves it understands their layout by regenerating the 320
ones bit for bit from Ultralytics' make_anchors rule, writes the ones for the new size, drops the
stale intermediate shapes, and checks the result with onnx's checker and shape inference (output0
[1, 116, A'], output1 [1, 32, size/4, size/4]). The weights are untouched: the network is the same,
it just looks at more pixels. The YOLO11n-seg 320 file rewritten for 640 is byte for byte the
shared 640 file: the check that the rule for its extra reshapes is right.
"""
import argparse
import sys

import numpy as np
import onnx
from onnx import numpy_helper, shape_inference

STRIDES = (8, 16, 32)
DFL_BINS = 16


def anchor_count(size):
    return sum((size // s) ** 2 for s in STRIDES)


def anchors(size):
    """Ultralytics make_anchors: per stride, cell centres row by row (y outer, x inner)."""
    points, strides = [], []
    for s in STRIDES:
        n = size // s
        ys, xs = np.meshgrid(np.arange(n, dtype=np.float32) + 0.5,
                             np.arange(n, dtype=np.float32) + 0.5, indexing="ij")
        points.append(np.stack([xs.ravel(), ys.ravel()]))
        strides.append(np.full(n * n, s, dtype=np.float32))
    return np.concatenate(points, axis=1)[None], np.concatenate(strides)[None]


def fail(msg):
    sys.exit(f"error: {msg}")


def input_size_of(model):
    dims = [d.dim_value for d in model.graph.input[0].type.tensor_type.shape.dim]
    if len(dims) != 4 or dims[:2] != [1, 3] or dims[2] != dims[3] or dims[2] <= 0:
        fail(f"input {model.graph.input[0].name} has shape {dims}, expected a static [1, 3, N, N]")
    return dims[2]


def grid_cells(size):
    """Cells of the three feature maps (strides 8, 16, 32) at an input size."""
    return [(size // s) ** 2 for s in STRIDES]


def reshape_shapes(model):
    """Names of the int64 initializers that are the shape input of a Reshape."""
    return {n.input[1] for n in model.graph.node if n.op_type == "Reshape" and len(n.input) > 1}


def spatial_shape(a, old, size):
    """A Reshape target of YOLO11's attention block or of its per-level head
    outputs, for `size`: the flattened cell counts of the three levels and the
    stride-32 side in a [1, C, side, side] shape. None if `a` holds neither.
    Only the 320 export is rewritten (tools' callers), where these values
    (1600, 400, 100, 10) differ from every channel count (1..256)."""
    cells = dict(zip(grid_cells(old), grid_cells(size)))
    side_old, side_new = old // 32, size // 32
    values = a.tolist()
    if len(values) == 4 and values[2:] == [side_old, side_old]:
        return np.array(values[:2] + [side_new, side_new], dtype=np.int64)
    if not any(v in cells for v in values):
        return None
    return np.array([cells.get(v, v) for v in values], dtype=np.int64)


# What each export family's head holds that depends on the input size:
# YOLOv8-seg: the anchor grid twice (x1y1 and x2y2), the stride per anchor
# [1, A], the DFL reshapes [1, 4, 16, A] and [1, 4, A]. YOLO11-seg (the float
# rebuild of the TFLite export): the grid once, the stride [1, 1, A], the DFL
# reshape once, and 20 reshapes with the feature maps' cell counts (its
# attention block at stride 32 and the per-level head outputs).
FAMILIES = {
    "YOLOv8n-seg": {"points": 2, "strides": 1, "reshape": 2, "spatial": 0},
    "YOLO11n-seg": {"points": 1, "strides": 1, "reshape": 1, "spatial": 20},
}


def rewrite(model, size):
    old = input_size_of(model)
    old_a, new_a = anchor_count(old), anchor_count(size)
    old_points, old_strides = anchors(old)
    new_points, new_strides = anchors(size)
    shapes = reshape_shapes(model)
    found = {"points": 0, "strides": 0, "reshape": 0, "spatial": 0}
    for t in model.graph.initializer:
        a = numpy_helper.to_array(t)
        if a.dtype == np.float32 and a.shape == (1, 2, old_a):
            if not np.array_equal(a, old_points):
                fail(f"initializer {t.name} {a.shape} is not the anchor grid make_anchors gives at {old}")
            t.CopyFrom(numpy_helper.from_array(new_points, t.name))
            found["points"] += 1
        elif a.dtype == np.float32 and a.shape in ((1, old_a), (1, 1, old_a)):
            if not np.array_equal(a.reshape(1, old_a), old_strides):
                fail(f"initializer {t.name} {a.shape} is not the per-anchor stride at {old}")
            t.CopyFrom(numpy_helper.from_array(new_strides.reshape((1,) * (a.ndim - 1) + (new_a,)), t.name))
            found["strides"] += 1
        elif a.dtype == np.int64 and a.ndim == 1 and old_a in a.tolist():
            if a.tolist() not in ([1, 4, DFL_BINS, old_a], [1, 4, old_a]):
                fail(f"initializer {t.name} = {a.tolist()} holds the anchor count in an unknown shape")
            b = np.where(a == old_a, new_a, a).astype(np.int64)
            t.CopyFrom(numpy_helper.from_array(b, t.name))
            found["reshape"] += 1
        elif a.dtype == np.int64 and a.ndim == 1 and t.name in shapes:
            b = spatial_shape(a, old, size)
            if b is not None:
                t.CopyFrom(numpy_helper.from_array(b, t.name))
                found["spatial"] += 1
    for n in model.graph.node:
        if n.op_type == "Constant":
            fail(f"Constant node {n.name} not expected in this export (the head's constants are initializers)")
    family = next((name for name, want in FAMILIES.items() if found == want), None)
    if family is None:
        fail(f"the head's constants are not those of a known export ({', '.join(FAMILIES)}): found {found}")
    if family != "YOLOv8n-seg" and old != 320:
        fail(f"{family}: only the 320 export is rewritten (its cell counts are told from channel counts there), got {old}")

    model.graph.input[0].type.tensor_type.shape.dim[2].dim_value = size
    model.graph.input[0].type.tensor_type.shape.dim[3].dim_value = size
    for out in model.graph.output:
        dims = out.type.tensor_type.shape.dim
        if out.name == "output0":
            dims[2].dim_value = new_a
        elif out.name == "output1":
            dims[2].dim_value = size // 4
            dims[3].dim_value = size // 4
    del model.graph.value_info[:]
    for p in model.metadata_props:
        if p.key == "imgsz":
            p.value = f"[{size}, {size}]"
    return model, family


def check(model, size):
    onnx.checker.check_model(model)
    inferred = shape_inference.infer_shapes(model, strict_mode=True)
    want = {"output0": [1, 116, anchor_count(size)], "output1": [1, 32, size // 4, size // 4]}
    for out in inferred.graph.output:
        dims = [d.dim_value for d in out.type.tensor_type.shape.dim]
        if dims != want[out.name]:
            fail(f"after the rewrite {out.name} infers to {dims}, expected {want[out.name]}")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("src")
    ap.add_argument("dst")
    ap.add_argument("--size", type=int, required=True, help="new square input size, a multiple of 32")
    args = ap.parse_args()
    if args.size < 64 or args.size % 32:
        fail(f"--size {args.size}: must be a multiple of 32, at least 64")
    try:
        model = onnx.load(args.src)
    except Exception as e:  # noqa: BLE001 - onnx raises several kinds; all mean "not a model"
        fail(f"{args.src}: cannot load as ONNX: {e}")
    model, family = rewrite(model, args.size)
    check(model, args.size)
    onnx.save(model, args.dst)
    print(f"{args.dst}: {family} at {args.size}x{args.size}, {anchor_count(args.size)} anchors")


if __name__ == "__main__":
    main()
