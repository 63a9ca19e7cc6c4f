//! Ignore regions of a sequence folder: real people in the source footage
//! are not in a synthesised ground truth, and the segmenter is right to
//! mask them. A folder may hold `ignore.png` (one label image for every
//! frame) and/or `ignore.txt` (per-frame label images, listed like
//! `masks.txt`); their non-zero pixels are left out of every mask score:
//! `dynslam masks-eval`'s and a run's (`mask_iou.csv`, the report).

use std::path::Path;

use anyhow::{bail, Context, Result};
use datasets::source::MaskList;

/// The ignore regions of a sequence folder.
#[derive(Default)]
pub struct IgnoreRegions {
    everywhere: Option<image::GrayImage>,
    per_frame: Option<MaskList>,
}

impl IgnoreRegions {
    /// The folder's `ignore.png` and `ignore.txt`, where present.
    pub fn open(dataset: &Path) -> Result<Self> {
        let png = dataset.join("ignore.png");
        let everywhere = if png.is_file() {
            Some(
                image::open(&png)
                    .with_context(|| format!("{}: not a readable image", png.display()))?
                    .to_luma8(),
            )
        } else {
            None
        };
        Ok(Self {
            everywhere,
            per_frame: MaskList::open_list(dataset, "ignore.txt")?,
        })
    }

    /// Whether the folder has any.
    pub fn any(&self) -> bool {
        self.everywhere.is_some() || self.per_frame.is_some()
    }

    /// The frame's ignore mask (union of both sources), `None` if neither.
    pub fn at(&self, timestamp: f64, w: usize, h: usize) -> Result<Option<Vec<u8>>> {
        if !self.any() {
            return Ok(None);
        }
        let mut out = vec![0u8; w * h];
        let per_frame = match &self.per_frame {
            // A frame ignore.txt does not list has no ignore region of its own.
            Some(list) if list.path_at(timestamp).is_some() => {
                Some(list.load_at(timestamp).map_err(anyhow::Error::msg)?)
            }
            _ => None,
        };
        for (img, what) in [
            (self.everywhere.as_ref(), "ignore.png"),
            (per_frame.as_ref(), "the ignore.txt entry"),
        ] {
            let Some(img) = img else { continue };
            if (img.width() as usize, img.height() as usize) != (w, h) {
                bail!(
                    "{what} for frame {timestamp:.6} is {}x{}, the frame {w}x{h}",
                    img.width(),
                    img.height()
                );
            }
            for (o, &m) in out.iter_mut().zip(img.as_raw()) {
                *o |= (m != 0) as u8;
            }
        }
        Ok(Some(out))
    }
}
