//! The YOLO-seg exports the product knows: two network generations, each at
//! three input sizes, every file pinned by its sha256. The shared ones are
//! in ../shared/models (its README); the others are rewrites of a shared
//! 320 export that `just setup` makes into `.cache/models` with
//! tools/yolo_input_size.py (same weights, the size-bound constants of the
//! head regenerated; deterministic, so the hash is pinned in
//! tools/yolo_input_size.sha256 too). Both generations have the same
//! interface (`images` -> `output0` [1,116,A], `output1` prototypes), so one
//! decoder ([`crate::yolo`]) serves them.

/// A generation of YOLO-seg networks: what `[services.segmenter] backend`
/// chooses.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum YoloFamily {
    /// YOLOv8n-seg (mask mAP50-95 30.5 at 640, published).
    V8,
    /// YOLO11n-seg, the generation after (32.0), about twice the time.
    V11,
}

impl YoloFamily {
    /// Every family, in the order the benchmarks print them.
    pub const ALL: [YoloFamily; 2] = [YoloFamily::V8, YoloFamily::V11];

    /// The `[services.segmenter] backend` name that selects it.
    pub fn backend(self) -> &'static str {
        match self {
            YoloFamily::V8 => "yolov8-seg",
            YoloFamily::V11 => "yolo11-seg",
        }
    }

    /// The family a backend name selects (another name: none).
    pub fn from_backend(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|f| f.backend() == name)
    }

    /// The network's name, for logs and reports.
    pub fn network(self) -> &'static str {
        match self {
            YoloFamily::V8 => "YOLOv8n-seg",
            YoloFamily::V11 => "YOLO11n-seg",
        }
    }
}

/// One model file the product knows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Export {
    /// The network generation.
    pub family: YoloFamily,
    /// The square network input in pixels.
    pub input_size: usize,
    /// The file name, looked up as `provision::locate_model` says.
    pub file: &'static str,
    /// Checked before the file is loaded.
    pub sha256: &'static str,
    /// In ../shared/models (else made by `just setup`).
    pub shared: bool,
}

/// The known exports.
pub const EXPORTS: [Export; 6] = [
    Export {
        family: YoloFamily::V8,
        input_size: 320,
        file: "yolov8n-seg_f32.onnx",
        sha256: "38459a0adc72f8b13be368e641b3c1a9815799b9bddbb86e0140aa18ec059942",
        shared: true,
    },
    Export {
        family: YoloFamily::V8,
        input_size: 480,
        file: "yolov8n-seg_f32_480.onnx",
        sha256: "f6c4d2e295738414d7110a3d271e83539feac8315890025a96e231b0ec370dfc",
        shared: false,
    },
    Export {
        family: YoloFamily::V8,
        input_size: 640,
        file: "yolov8n-seg_f32_640.onnx",
        sha256: "8a64b5282e3eb8e8829373635df8b3141cac2f6ae04cc753fc35713b4aef72e2",
        shared: false,
    },
    Export {
        family: YoloFamily::V11,
        input_size: 320,
        file: "yolo11n-seg_320_f32.onnx",
        sha256: "f9fe9dd16f0de070016e47a8643d27c190b46fd911607f0049a0dbaaafd31846",
        shared: true,
    },
    Export {
        family: YoloFamily::V11,
        input_size: 480,
        file: "yolo11n-seg_480_f32.onnx",
        sha256: "a46f87fb023f777cb9133d533055b71db0fe7c398b15e3cbe19158c9a33696b1",
        shared: false,
    },
    // Shared, and also what the rewrite of the 320 file gives, byte for
    // byte (docs/measurements.md): the proof that the rewrite of the 480
    // file is right.
    Export {
        family: YoloFamily::V11,
        input_size: 640,
        file: "yolo11n-seg_640_f32.onnx",
        sha256: "91d2ee1d461ddc798f55595a037982b937c987222a083b08568cf8ef7a64f001",
        shared: true,
    },
];

/// The known export with this file name.
pub fn named(file: &str) -> Option<&'static Export> {
    EXPORTS.iter().find(|e| e.file == file)
}

/// The export of `family` for an input size; another size is an error
/// naming the key and the sizes there are.
pub fn export_for(family: YoloFamily, input_size: usize) -> Result<&'static Export, String> {
    let of_family = || EXPORTS.iter().filter(move |e| e.family == family);
    of_family()
        .find(|e| e.input_size == input_size)
        .ok_or_else(|| {
            let sizes: Vec<String> = of_family().map(|e| e.input_size.to_string()).collect();
            format!(
                "key `services.segmenter.input_size`: no {} export is provided for {input_size} (provided: {}); set `model` and `model_sha256` to an export of that size",
                family.network(),
                sizes.join(", ")
            )
        })
}

/// The input sizes every family has an export for, ascending.
pub fn input_sizes() -> Vec<usize> {
    let mut sizes: Vec<usize> = EXPORTS
        .iter()
        .map(|e| e.input_size)
        .filter(|&n| YoloFamily::ALL.iter().all(|&f| export_for(f, n).is_ok()))
        .collect();
    sizes.sort_unstable();
    sizes.dedup();
    sizes
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_pinned_hashes_are_the_ones_just_setup_checks() {
        // `just setup` checks the rewritten files against this list; the
        // segmenter against EXPORTS: one may not move without the other.
        let list = include_str!("../../../tools/yolo_input_size.sha256");
        let mut derived = 0;
        for e in EXPORTS.iter().filter(|e| !e.shared) {
            assert!(e.file.contains(&e.input_size.to_string()), "{}", e.file);
            assert!(
                list.contains(&format!("{}  {}", e.sha256, e.file)),
                "{} {}\n{list}",
                e.file,
                e.sha256
            );
            derived += 1;
        }
        assert_eq!(list.lines().count(), derived);
    }

    #[test]
    fn each_family_has_each_size_once_and_a_backend_name() {
        for family in YoloFamily::ALL {
            assert_eq!(YoloFamily::from_backend(family.backend()), Some(family));
            for size in [320, 480, 640] {
                assert_eq!(export_for(family, size).unwrap().input_size, size);
            }
        }
        assert_eq!(input_sizes(), vec![320, 480, 640]);
        assert_eq!(YoloFamily::from_backend("maskrcnn"), None);
        assert_eq!(
            named("yolo11n-seg_320_f32.onnx").unwrap().family,
            YoloFamily::V11
        );
    }

    #[test]
    fn input_size_alone_picks_the_export_of_that_size() {
        let v8 = |n| export_for(YoloFamily::V8, n);
        assert_eq!(v8(320).unwrap().file, "yolov8n-seg_f32.onnx");
        assert_eq!(v8(640).unwrap().file, "yolov8n-seg_f32_640.onnx");
        assert_eq!(
            export_for(YoloFamily::V11, 480).unwrap().file,
            "yolo11n-seg_480_f32.onnx"
        );
        let err = v8(416).unwrap_err();
        assert!(
            err.contains("services.segmenter.input_size")
                && err.contains("YOLOv8n-seg")
                && err.contains("320, 480, 640"),
            "{err}"
        );
    }
}
