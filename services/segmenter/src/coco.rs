//! The 80 COCO class names in the order of the shipped models' outputs.

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

/// The movable classes masked by default (DESIGN section 1).
pub const DEFAULT_DYNAMIC: [&str; 8] = [
    "person",
    "bicycle",
    "car",
    "motorcycle",
    "bus",
    "truck",
    "dog",
    "cat",
];

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
