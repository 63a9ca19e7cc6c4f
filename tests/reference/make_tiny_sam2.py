"""Generates tiny ONNX graphs with the signature of the common SAM 2 ONNX export (an image
encoder and a prompt/mask decoder, as samexporter's export_sam2.py writes them), so the
`sam2` propagator backend runs through real ONNX Runtime without SAM 2's weights, which
cannot be obtained here. The graphs compute simple things from their inputs, chosen so a
test can tell whether the backend fed them correctly:

Encoder: `image` float32 [1, 3, 1024, 1024] (RGB resized to 1024x1024, ImageNet mean/std)
  -> `high_res_feats_0` [1, 32, 256, 256], `high_res_feats_1` [1, 64, 128, 128],
     `image_embed` [1, 256, 64, 64]: the image averaged over 4/8/16-pixel cells, each
     channel the mean of R, G, B (so image_embed's mean is the normalised image's mean).

Decoder: `image_embed`, `high_res_feats_0`, `high_res_feats_1`, `point_coords` [B, N, 2]
  (pixels of the 1024 input), `point_labels` [B, N] (1 positive, 0 negative, 2/3 box
  corners, -1 padding), `mask_input` [B, 1, 256, 256] (low-resolution logits),
  `has_mask_input` [B]
  -> `masks` [B, 3, 256, 256] logits (clamped to +-32), `iou_predictions` [B, 3]:
     candidate 0: mask_input as given (times has_mask_input, else -32);
     candidate 1: the box of the first two points (signed distance in input pixels from
                  the box border at each low-res cell centre, (j + 0.5) * 4);
     candidate 2: -32 everywhere;
     iou_predictions = [0.5 s, 0.9 s, 0.05] with s = sigmoid(4 * mean(image_embed)):
     a bright or mid-grey frame prefers the box, a black frame predicts < 0.5 for all.

    python make_tiny_sam2.py OUT_DIR      (needs the `onnx` package)

Writes tiny_sam2_encoder.onnx and tiny_sam2_decoder.onnx.
"""
import os
import sys

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

N = 1024


def const(name, array):
    return numpy_helper.from_array(np.asarray(array), name)


def encoder():
    nodes, inits = [], []
    for name, cell, channels in [("high_res_feats_0", 4, 32), ("high_res_feats_1", 8, 64), ("image_embed", 16, 256)]:
        nodes.append(helper.make_node("AveragePool", ["image"], [f"{name}_pool"], kernel_shape=[cell, cell], strides=[cell, cell]))
        inits.append(const(f"{name}_w", np.full((channels, 3, 1, 1), 1.0 / 3.0, np.float32)))
        nodes.append(helper.make_node("Conv", [f"{name}_pool", f"{name}_w"], [name]))
    g = helper.make_graph(
        nodes,
        "tiny_sam2_encoder",
        [helper.make_tensor_value_info("image", TensorProto.FLOAT, [1, 3, N, N])],
        [
            helper.make_tensor_value_info("high_res_feats_0", TensorProto.FLOAT, [1, 32, 256, 256]),
            helper.make_tensor_value_info("high_res_feats_1", TensorProto.FLOAT, [1, 64, 128, 128]),
            helper.make_tensor_value_info("image_embed", TensorProto.FLOAT, [1, 256, 64, 64]),
        ],
        inits,
    )
    return g


def decoder():
    nodes, inits = [], []
    # Candidate 0: the mask prompt (no mask: -32).
    inits += [const("has_shape", np.array([-1, 1, 1, 1], np.int64)), const("c32", np.array(32.0, np.float32)),
              const("one", np.array(1.0, np.float32))]
    nodes += [
        helper.make_node("Reshape", ["has_mask_input", "has_shape"], ["has4"]),
        helper.make_node("Mul", ["mask_input", "has4"], ["m_in"]),
        helper.make_node("Sub", ["one", "has4"], ["no_mask"]),
        helper.make_node("Mul", ["no_mask", "c32"], ["no_mask32"]),
        helper.make_node("Sub", ["m_in", "no_mask32"], ["cand0"]),
    ]
    # Candidate 1: the box of the first two points, at low-res cell centres in input pixels.
    centres = ((np.arange(256, dtype=np.float32) + 0.5) * 4.0)
    inits += [const("xs", centres.reshape(1, 1, 1, 256)), const("ys", centres.reshape(1, 1, 256, 1)),
              const("pt_shape", np.array([-1, 1, 1, 1], np.int64))]
    for k, corner in [(0, "tl"), (1, "br")]:
        inits.append(const(f"idx_{corner}", np.array(k, np.int64)))
        nodes.append(helper.make_node("Gather", ["point_coords", f"idx_{corner}"], [f"{corner}"], axis=1))  # [B, 2]
        for a, axis in [(0, "x"), (1, "y")]:
            inits.append(const(f"ax_{corner}_{axis}", np.array(a, np.int64)))
            nodes.append(helper.make_node("Gather", [f"{corner}", f"ax_{corner}_{axis}"], [f"{corner}_{axis}_b"], axis=1))
            nodes.append(helper.make_node("Reshape", [f"{corner}_{axis}_b", "pt_shape"], [f"{corner}_{axis}"]))
    nodes += [
        helper.make_node("Sub", ["xs", "tl_x"], ["d_left"]),
        helper.make_node("Sub", ["br_x", "xs"], ["d_right"]),
        helper.make_node("Sub", ["ys", "tl_y"], ["d_top"]),
        helper.make_node("Sub", ["br_y", "ys"], ["d_bottom"]),
        helper.make_node("Min", ["d_left", "d_right", "d_top", "d_bottom"], ["cand1"]),
    ]
    # Candidate 2: nothing.
    nodes += [
        helper.make_node("Mul", ["mask_input", "zero_f"], ["zeros"]),
        helper.make_node("Sub", ["zeros", "c32"], ["cand2"]),
        helper.make_node("Concat", ["cand0", "cand1", "cand2"], ["masks_raw"], axis=1),
        helper.make_node("Clip", ["masks_raw", "neg32", "c32"], ["masks"]),
    ]
    inits += [const("zero_f", np.array(0.0, np.float32)), const("neg32", np.array(-32.0, np.float32))]
    # iou_predictions from the frame's brightness.
    inits += [const("four", np.array(4.0, np.float32)), const("iou_w", np.array([[0.5, 0.9, 0.0]], np.float32)),
              const("iou_b", np.array([[0.0, 0.0, 0.05]], np.float32)), const("iou_shape", np.array([1, 1], np.int64))]
    nodes += [
        helper.make_node("ReduceMean", ["image_embed"], ["embed_mean"], keepdims=0),
        helper.make_node("Mul", ["embed_mean", "four"], ["logit"]),
        helper.make_node("Sigmoid", ["logit"], ["s"]),
        helper.make_node("Reshape", ["s", "iou_shape"], ["s2"]),
        helper.make_node("Mul", ["s2", "iou_w"], ["iou_s"]),
        helper.make_node("Add", ["iou_s", "iou_b"], ["iou_predictions"]),
    ]
    # The high-resolution features and point labels are inputs of the real decoder; here
    # they only have to be accepted (a shape check keeps them in the graph).
    nodes += [
        helper.make_node("Shape", ["high_res_feats_0"], ["hrf0_shape"]),
        helper.make_node("Shape", ["high_res_feats_1"], ["hrf1_shape"]),
        helper.make_node("Shape", ["point_labels"], ["labels_shape"]),
    ]
    g = helper.make_graph(
        nodes,
        "tiny_sam2_decoder",
        [
            helper.make_tensor_value_info("image_embed", TensorProto.FLOAT, [1, 256, 64, 64]),
            helper.make_tensor_value_info("high_res_feats_0", TensorProto.FLOAT, [1, 32, 256, 256]),
            helper.make_tensor_value_info("high_res_feats_1", TensorProto.FLOAT, [1, 64, 128, 128]),
            helper.make_tensor_value_info("point_coords", TensorProto.FLOAT, ["num_labels", "num_points", 2]),
            helper.make_tensor_value_info("point_labels", TensorProto.FLOAT, ["num_labels", "num_points"]),
            helper.make_tensor_value_info("mask_input", TensorProto.FLOAT, ["num_labels", 1, 256, 256]),
            helper.make_tensor_value_info("has_mask_input", TensorProto.FLOAT, ["num_labels"]),
        ],
        [
            helper.make_tensor_value_info("masks", TensorProto.FLOAT, ["num_labels", 3, 256, 256]),
            helper.make_tensor_value_info("iou_predictions", TensorProto.FLOAT, [1, 3]),
            helper.make_tensor_value_info("hrf0_shape", TensorProto.INT64, [4]),
            helper.make_tensor_value_info("hrf1_shape", TensorProto.INT64, [4]),
            helper.make_tensor_value_info("labels_shape", TensorProto.INT64, [2]),
        ],
        inits,
    )
    return g


def save(graph, path):
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)], producer_name="dynslam-tests")
    model.ir_version = 8
    onnx.checker.check_model(model)
    onnx.save(model, path)


if __name__ == "__main__":
    out = sys.argv[1] if len(sys.argv) > 1 else "."
    save(encoder(), os.path.join(out, "tiny_sam2_encoder.onnx"))
    save(decoder(), os.path.join(out, "tiny_sam2_decoder.onnx"))
