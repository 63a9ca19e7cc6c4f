//! Keyframe instance segmentation.
//!
//! - [`coco`]: the class list of the COCO-trained models.
//! - [`letterbox`]: the network input (aspect-preserving resize + padding)
//!   and its inverse.
//! - [`yolo`]: YOLO-seg output decoding (class-wise NMS, prototype masks),
//!   pure Rust, testable without a model.
//! - [`exports`]: the YOLOv8n-seg and YOLO11n-seg files the product knows,
//!   by input size, sha256 pinned.
//! - [`foreground`]: evidence that keeps a weak detection (a mask on an
//!   object of the frame before, or standing in front of its surroundings
//!   in depth).
//! - [`onnx`]: the YOLO-seg backends (`yolov8-seg`, `yolo11-seg`) on ONNX
//!   Runtime, a `MaskModel`.
//! - [`ground_truth`]: the exact masks of a synthesised sequence (the
//!   ablation's reference row), a `MaskModel` too.
//! - [`maskrcnn`]: the Mask R-CNN backend (torchvision ONNX export signature).
//! - [`models`]: the backends by name, as `[services.segmenter]` selects.

#![deny(missing_docs)]

pub mod coco;
pub mod exports;
pub mod foreground;
pub mod ground_truth;
pub mod letterbox;
pub mod maskrcnn;
pub mod models;
pub mod onnx;
pub mod yolo;
