//! The `ground-truth` backend: the exact person masks of a `dynslam synth`
//! sequence (its `masks.txt`), looked up by the frame's timestamp. It is an
//! evaluation instrument, not a model: the ablation runs it to measure what
//! perfect masks would give SLAM (row b of `dynslam ablate`).

use std::path::Path;

use anyhow::{bail, Result};
use datasets::source::MaskList;
use mask_model::MaskModel;
use shared_types::views::FrameView;
use shared_types::{Instance, MAX_INSTANCES};

/// COCO's `person`, the class the synthesised objects are.
const PERSON: u32 = 0;

/// The `ground-truth` backend: a synthesised sequence's exact masks
/// (`masks/` of the dataset), as if a perfect segmenter made them.
pub struct GroundTruthMasks {
    masks: MaskList,
}

impl GroundTruthMasks {
    /// The masks of the sequence in `dataset`; an error when it has none.
    pub fn open(dataset: &Path) -> Result<Self> {
        match MaskList::open(dataset)? {
            Some(masks) => Ok(Self { masks }),
            None => bail!(
                "backend ground-truth: {} has no masks.txt (only sequences made by `dynslam synth` have ground-truth masks)",
                dataset.display()
            ),
        }
    }
}

impl MaskModel for GroundTruthMasks {
    fn name(&self) -> &str {
        "ground-truth"
    }

    fn infer(&mut self, frame: &FrameView, labels: &mut [u8]) -> Result<Vec<Instance>> {
        let truth = self
            .masks
            .load_at(frame.header.source_timestamp)
            .map_err(anyhow::Error::msg)?;
        if truth.width() as usize != frame.width() || truth.height() as usize != frame.height() {
            bail!(
                "ground-truth mask at {:.6} is {}x{}, the frame {}x{}",
                frame.header.source_timestamp,
                truth.width(),
                truth.height(),
                frame.width(),
                frame.height()
            );
        }
        // Ground-truth ids (any 1..=255) become instance indices in order of
        // appearance; boxes from the pixels.
        let mut index_of = [0u8; 256];
        let mut instances: Vec<Instance> = Vec::new();
        let w = frame.width();
        for (i, (&id, out)) in truth.as_raw().iter().zip(labels.iter_mut()).enumerate() {
            if id == 0 {
                continue;
            }
            if index_of[id as usize] == 0 {
                if instances.len() == MAX_INSTANCES {
                    continue;
                }
                instances.push(Instance {
                    object_id: id as u32,
                    class_id: PERSON,
                    score: 1.0,
                    bbox: [f32::MAX, f32::MAX, 0.0, 0.0],
                });
                index_of[id as usize] = instances.len() as u8;
            }
            let k = index_of[id as usize];
            *out = k;
            let (x, y) = ((i % w) as f32, (i / w) as f32);
            let b = &mut instances[k as usize - 1].bbox;
            b[0] = b[0].min(x);
            b[1] = b[1].min(y);
            b[2] = b[2].max(x + 1.0);
            b[3] = b[3].max(y + 1.0);
        }
        Ok(instances)
    }
}
