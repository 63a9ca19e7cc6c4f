//! The 80 COCO class names in the order of the shipped models' outputs.

/// COCO's class names, index = the models' class id.
pub const CLASSES: [&str; 80] = [
    "person",
    "bicycle",
    "car",
    "motorcycle",
    "airplane",
    "bus",
    "train",
    "truck",
    "boat",
    "traffic light",
    "fire hydrant",
    "stop sign",
    "parking meter",
    "bench",
    "bird",
    "cat",
    "dog",
    "horse",
    "sheep",
    "cow",
    "elephant",
    "bear",
    "zebra",
    "giraffe",
    "backpack",
    "umbrella",
    "handbag",
    "tie",
    "suitcase",
    "frisbee",
    "skis",
    "snowboard",
    "sports ball",
    "kite",
    "baseball bat",
    "baseball glove",
    "skateboard",
    "surfboard",
    "tennis racket",
    "bottle",
    "wine glass",
    "cup",
    "fork",
    "knife",
    "spoon",
    "bowl",
    "banana",
    "apple",
    "sandwich",
    "orange",
    "broccoli",
    "carrot",
    "hot dog",
    "pizza",
    "donut",
    "cake",
    "chair",
    "couch",
    "potted plant",
    "bed",
    "dining table",
    "toilet",
    "tv",
    "laptop",
    "mouse",
    "remote",
    "keyboard",
    "cell phone",
    "microwave",
    "oven",
    "toaster",
    "sink",
    "refrigerator",
    "book",
    "clock",
    "vase",
    "scissors",
    "teddy bear",
    "hair drier",
    "toothbrush",
];

/// COCO's original category id (as torchvision's detection models output
/// them; ids 12, 26, 29, 30, 45, 66, 68, 69, 71 and 83 are unused) of each
/// class in [`CLASSES`].
pub const CATEGORY_IDS: [u8; 80] = [
    1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 13, 14, 15, 16, 17, 18, 19, 20, 21, 22, 23, 24, 25, 27, 28,
    31, 32, 33, 34, 35, 36, 37, 38, 39, 40, 41, 42, 43, 44, 46, 47, 48, 49, 50, 51, 52, 53, 54, 55,
    56, 57, 58, 59, 60, 61, 62, 63, 64, 65, 67, 70, 72, 73, 74, 75, 76, 77, 78, 79, 80, 81, 82, 84,
    85, 86, 87, 88, 89, 90,
];

/// Index in [`CLASSES`] of a COCO category id.
pub fn class_of_category(category: i64) -> Option<usize> {
    CATEGORY_IDS.iter().position(|&c| i64::from(c) == category)
}

/// The movable classes masked by default (DESIGN section 1).
pub use pipeline_config::DEFAULT_DYNAMIC_CLASSES as DEFAULT_DYNAMIC;

/// The configured dynamic classes (default: [`DEFAULT_DYNAMIC`]) as class
/// ids; an unknown name is a configuration error naming the key.
pub fn dynamic_classes(configured: &[String], section: &str) -> Result<Vec<usize>, String> {
    let names: Vec<String> = if configured.is_empty() {
        DEFAULT_DYNAMIC.iter().map(|s| s.to_string()).collect()
    } else {
        configured.to_vec()
    };
    class_ids(&names).map_err(|e| format!("key `services.{section}.classes`: {e}"))
}

/// Class ids of `names`; an unknown name is an error that lists the known ones.
pub fn class_ids(names: &[String]) -> Result<Vec<usize>, String> {
    names
        .iter()
        .map(|n| {
            CLASSES.iter().position(|c| c == n).ok_or_else(|| {
                format!(
                    "unknown class name '{n}' (COCO classes: {})",
                    CLASSES.join(", ")
                )
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ids_follow_the_models_readme() {
        let ids =
            class_ids(&["person".into(), "car".into(), "truck".into(), "boat".into()]).unwrap();
        assert_eq!(ids, vec![0, 2, 7, 8]);
        let err = class_ids(&["pedestrian".into()]).unwrap_err();
        assert!(err.starts_with("unknown class name 'pedestrian'"), "{err}");
    }
}
