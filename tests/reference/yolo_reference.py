"""Reference YOLOv8-seg decoding: onnxruntime's Python API + straightforward NumPy.

Produces the fixture that tests the Rust decoder (services/segmentation/tests/equivalence.rs):

    python yolo_reference.py MODEL.onnx IMAGE.png OUT.json

Same definitions as the Rust code, written independently: letterbox with
pixel-centre bilinear resize (pad 114/255), best class per anchor, score and
dynamic-class filter, class-wise greedy NMS, mask = sigmoid(coefficients .
prototypes) > 0.5 sampled bilinearly at each image pixel centre inside the box,
an earlier (higher-score) instance keeps a pixel. Masks are stored run-length
encoded over the row-major label image.
"""
import json
import sys

import numpy as np
import onnxruntime as ort
from PIL import Image

DYNAMIC = [0, 1, 2, 3, 5, 7, 16, 15]  # person bicycle car motorcycle bus truck dog cat
SCORE, IOU, SIZE, MAX_INSTANCES = 0.5, 0.7, 320, 32


def rust_round(x):
    return int(np.floor(x + 0.5))  # half away from zero for positive x, like f32::round


def letterbox(img):
    h, w = img.shape[:2]
    r = min(SIZE / w, SIZE / h)
    iw, ih = min(rust_round(w * r), SIZE), min(rust_round(h * r), SIZE)
    px, py = rust_round((SIZE - iw) / 2 - 0.1), rust_round((SIZE - ih) / 2 - 0.1)
    fy = np.clip((np.arange(ih) + 0.5) * (h / ih) - 0.5, 0, h - 1)
    fx = np.clip((np.arange(iw) + 0.5) * (w / iw) - 0.5, 0, w - 1)
    y0, x0 = fy.astype(int), fx.astype(int)
    y1, x1 = np.minimum(y0 + 1, h - 1), np.minimum(x0 + 1, w - 1)
    wy, wx = (fy - y0)[:, None, None], (fx - x0)[None, :, None]
    f = img.astype(np.float64)
    top = f[y0][:, x0] * (1 - wx) + f[y0][:, x1] * wx
    bottom = f[y1][:, x0] * (1 - wx) + f[y1][:, x1] * wx
    inner = (top * (1 - wy) + bottom * wy) / 255.0
    out = np.full((3, SIZE, SIZE), 114.0 / 255.0, dtype=np.float32)
    out[:, py:py + ih, px:px + iw] = inner.transpose(2, 0, 1)
    return out, r, px, py


def iou(a, b):
    iw = max(min(a[2], b[2]) - max(a[0], b[0]), 0.0)
    ih = max(min(a[3], b[3]) - max(a[1], b[1]), 0.0)
    inter = iw * ih
    union = (a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter
    return inter / union if union > 0 else 0.0


def main(model, image, out_path):
    img = np.asarray(Image.open(image).convert("RGB"))
    h, w = img.shape[:2]
    x, r, px, py = letterbox(img)
    sess = ort.InferenceSession(model, providers=["CPUExecutionProvider"])
    out0, out1 = sess.run(["output0", "output1"], {"images": x[None]})
    p, protos = out0[0], out1[0]
    nc = p.shape[0] - 4 - 32
    scores = p[4:4 + nc]
    best, best_score = scores.argmax(0), scores.max(0)
    dets = []
    for a in np.nonzero((best_score >= SCORE) & np.isin(best, DYNAMIC))[0]:
        cx, cy, bw, bh = p[0:4, a]
        dets.append((int(best[a]), float(best_score[a]),
                     [cx - bw / 2, cy - bh / 2, cx + bw / 2, cy + bh / 2], p[4 + nc:, a]))
    dets.sort(key=lambda d: -d[1])
    kept = []
    for d in dets:
        if len(kept) >= MAX_INSTANCES:
            break
        if all(k[0] != d[0] or iou(k[2], d[2]) <= IOU for k in kept):
            kept.append(d)

    ph, pw = protos.shape[1:]
    stride = SIZE / pw
    labels = np.zeros((h, w), dtype=np.uint8)
    instances = []
    for i, (cls, score, box, coef) in enumerate(kept):
        gx0 = min(max(int(np.floor(box[0] / stride)), 0), pw)
        gy0 = min(max(int(np.floor(box[1] / stride)), 0), ph)
        gx1 = min(int(np.ceil(box[2] / stride)) + 1, pw)
        gy1 = min(int(np.ceil(box[3] / stride)) + 1, ph)
        logits = np.tensordot(coef, protos, axes=1)
        ix0, iy0 = np.clip((box[0] - px) / r, 0, w), np.clip((box[1] - py) / r, 0, h)
        ix1, iy1 = np.clip((box[2] - px) / r, 0, w), np.clip((box[3] - py) / r, 0, h)
        ys = np.arange(int(np.floor(iy0)), min(int(np.ceil(iy1)), h))
        xs = np.arange(int(np.floor(ix0)), min(int(np.ceil(ix1)), w))
        lx = (xs + 0.5) * r + px
        ly = (ys + 0.5) * r + py
        inside = ((ly >= box[1]) & (ly < box[3]))[:, None] & ((lx >= box[0]) & (lx < box[2]))[None, :]
        fx = np.clip(lx / stride - 0.5, gx0, max(gx1, gx0 + 1) - 1)
        fy = np.clip(ly / stride - 0.5, gy0, max(gy1, gy0 + 1) - 1)
        x0, y0 = fx.astype(int), fy.astype(int)
        x1, y1 = np.minimum(x0 + 1, gx1 - 1), np.minimum(y0 + 1, gy1 - 1)
        wx, wy = (fx - x0)[None, :], (fy - y0)[:, None]
        top = logits[y0][:, x0] * (1 - wx) + logits[y0][:, x1] * wx
        bottom = logits[y1][:, x0] * (1 - wx) + logits[y1][:, x1] * wx
        on = inside & ((top * (1 - wy) + bottom * wy) > 0)
        region = labels[ys[0]:ys[-1] + 1, xs[0]:xs[-1] + 1] if len(ys) and len(xs) else None
        if region is not None:
            region[on & (region == 0)] = i + 1
        instances.append({"class_id": cls, "score": score,
                          "bbox": [float(ix0), float(iy0), float(ix1), float(iy1)]})
    flat = labels.reshape(-1)
    for i, inst in enumerate(instances):
        m = np.concatenate([[0], (flat == i + 1).astype(np.int8), [0]])
        d = np.diff(m)
        starts, ends = np.nonzero(d == 1)[0], np.nonzero(d == -1)[0]
        inst["rle"] = [[int(s), int(e - s)] for s, e in zip(starts, ends)]
        inst["pixels"] = int((ends - starts).sum())
    json.dump({"width": w, "height": h, "score_threshold": SCORE, "iou_threshold": IOU,
               "onnxruntime": ort.__version__, "instances": instances}, open(out_path, "w"))
    for inst in instances:
        print(inst["class_id"], round(inst["score"], 3), [round(v, 1) for v in inst["bbox"]], inst["pixels"])


if __name__ == "__main__":
    main(*sys.argv[1:4])
