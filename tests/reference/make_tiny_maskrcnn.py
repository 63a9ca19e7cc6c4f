"""Generates tiny ONNX graphs with the output signature of torchvision's Mask R-CNN
export (input `image` float32 [3, H, W] RGB 0..1; outputs `boxes` [N, 4] x0 y0 x1 y1,
`labels` [N] int64 COCO category ids, `scores` [N], `masks` [N, 1, h, w] probabilities),
so the Mask R-CNN backend's decoding runs through real ONNX Runtime without the real
weights, which cannot be obtained here. The outputs are constants chosen by hand.

    python make_tiny_maskrcnn.py OUT_DIR      (needs the `onnx` package)

Writes tiny_maskrcnn_28.onnx (28x28 masks, pasted into the boxes) and
tiny_maskrcnn_full.onnx (full-size 48x64 masks).
"""
import os
import sys

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

H, W = 48, 64


def detections(full):
    boxes = np.array([[8, 4, 24, 36], [30, 10, 60, 30], [2, 2, 10, 10], [40, 36, 62, 46]], np.float32)
    labels = np.array([1, 3, 1, 62], np.int64)   # person, car, person (low score), chair (static)
    scores = np.array([0.97, 0.93, 0.40, 0.99], np.float32)
    if full:
        masks = np.zeros((4, 1, H, W), np.float32)
        masks[0, 0, 4:36, 8:16] = 0.9      # left half of the person's box
        masks[1, 0, 10:30, 30:60] = 0.8    # the whole car box
        masks[1, 0, 10:12, 30:60] = 0.3    # ...except two rows below threshold
        masks[2, 0, 2:10, 2:10] = 0.9
        masks[3, 0, 36:46, 40:62] = 0.9
    else:
        masks = np.zeros((4, 1, 28, 28), np.float32)
        masks[0, 0, :, :14] = 0.9          # left half of the box
        masks[1, 0, :, :] = 0.8            # whole box
        masks[2, 0, :, :] = 0.9
        masks[3, 0, :, :] = 0.9
    return boxes, labels, scores, masks


def graph(full):
    outs = dict(zip(["boxes", "labels", "scores", "masks"], detections(full)))
    nodes, outputs = [], []
    for name, value in outs.items():
        nodes.append(helper.make_node("Constant", [], [name], value=numpy_helper.from_array(value, name + "_value")))
        elem = TensorProto.INT64 if value.dtype == np.int64 else TensorProto.FLOAT
        outputs.append(helper.make_tensor_value_info(name, elem, list(value.shape)))
    image = helper.make_tensor_value_info("image", TensorProto.FLOAT, [3, H, W])
    g = helper.make_graph(nodes, "tiny_maskrcnn", [image], outputs)
    model = helper.make_model(g, opset_imports=[helper.make_opsetid("", 17)], producer_name="dynslam-tests")
    model.ir_version = 8
    onnx.checker.check_model(model)
    return model


if __name__ == "__main__":
    out = sys.argv[1]
    os.makedirs(out, exist_ok=True)
    onnx.save(graph(False), os.path.join(out, "tiny_maskrcnn_28.onnx"))
    onnx.save(graph(True), os.path.join(out, "tiny_maskrcnn_full.onnx"))
