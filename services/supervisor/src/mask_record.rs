//! The masks a run used, kept for the report: `masks/<seq>.png` (8-bit
//! label image, 0 background, i+1 instance i) and one `masks.csv` row per
//! set of masks (seq, source, instances, masked pixels).
//!
//! The supervisor reads each Masks sample in place, copies its labels once
//! and hands them to a writer thread, so PNG encoding never delays routing.
//! Recording is best effort: when the writer falls behind (real-time mode on
//! a loaded machine) sets are skipped and counted, never queued without
//! bound.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::mpsc::{sync_channel, SyncSender, TrySendError};
use std::thread::JoinHandle;

use anyhow::{Context, Result};
use image::GrayImage;
use pipeline::views::MasksView;

pub const MASKS_DIR: &str = "masks";
pub const MASKS_CSV: &str = "masks.csv";
const HEADER: &str = "seq,source,instances,masked_px,file";

/// One set of masks to write.
struct Job {
    seq: u64,
    source: &'static str,
    instances: u32,
    labels: GrayImage,
}

pub struct MaskRecorder {
    tx: Option<SyncSender<Job>>,
    writer: Option<JoinHandle<Result<()>>>,
    skipped: u64,
}

/// The path of frame `seq`'s label image inside a run folder.
pub fn mask_file(run_dir: &Path, seq: u64) -> PathBuf {
    run_dir.join(MASKS_DIR).join(format!("{seq:06}.png"))
}

impl MaskRecorder {
    pub fn start(run_dir: &Path) -> Result<Self> {
        let dir = run_dir.join(MASKS_DIR);
        std::fs::create_dir_all(&dir)
            .with_context(|| format!("cannot create {}", dir.display()))?;
        let csv_path = run_dir.join(MASKS_CSV);
        let fresh = !csv_path.exists();
        let mut csv = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(&csv_path)
            .with_context(|| format!("cannot open {}", csv_path.display()))?;
        if fresh {
            writeln!(csv, "{HEADER}")?;
        }
        let (tx, rx) = sync_channel::<Job>(32);
        let run_dir = run_dir.to_path_buf();
        let writer = std::thread::Builder::new()
            .name("mask-recorder".into())
            .spawn(move || -> Result<()> {
                for job in rx {
                    let path = mask_file(&run_dir, job.seq);
                    job.labels
                        .save(&path)
                        .with_context(|| format!("cannot write {}", path.display()))?;
                    let masked = job.labels.pixels().filter(|p| p[0] != 0).count();
                    writeln!(
                        csv,
                        "{},{},{},{},{}/{:06}.png",
                        job.seq, job.source, job.instances, masked, MASKS_DIR, job.seq
                    )?;
                }
                csv.flush()?;
                Ok(())
            })
            .context("cannot start the mask recorder thread")?;
        Ok(Self {
            tx: Some(tx),
            writer: Some(writer),
            skipped: 0,
        })
    }

    /// Queues a copy of `masks` for writing.
    pub fn record(&mut self, masks: &MasksView) {
        let h = masks.header;
        let Some(labels) = GrayImage::from_raw(h.width, h.height, masks.labels.to_vec()) else {
            return;
        };
        let job = Job {
            seq: h.seq,
            source: masks.source().as_str(),
            instances: h.num_instances,
            labels,
        };
        if let Some(tx) = &self.tx {
            match tx.try_send(job) {
                Ok(()) => {}
                Err(TrySendError::Full(_)) => self.skipped += 1,
                Err(TrySendError::Disconnected(_)) => {
                    // The writer stopped on an error; `finish` reports it.
                    self.tx = None;
                }
            }
        }
    }

    /// Waits for everything queued to be written.
    pub fn finish(mut self) -> Result<u64> {
        drop(self.tx.take());
        if let Some(w) = self.writer.take() {
            w.join()
                .map_err(|_| anyhow::anyhow!("the mask recorder thread panicked"))??;
        }
        Ok(self.skipped)
    }
}

/// One row of `masks.csv`.
#[derive(Debug, Clone, PartialEq)]
pub struct MaskRow {
    pub seq: u64,
    pub source: String,
    pub instances: u32,
    pub masked_px: u64,
}

/// Reads `masks.csv` (the last row of each seq wins: a replayed frame's
/// masks are written again); a missing file is an empty record.
pub fn read_rows(run_dir: &Path) -> Result<Vec<MaskRow>> {
    let path = run_dir.join(MASKS_CSV);
    let Ok(text) = std::fs::read_to_string(&path) else {
        return Ok(Vec::new());
    };
    let mut rows = std::collections::BTreeMap::new();
    for (i, line) in text.lines().enumerate().skip(1) {
        let f: Vec<&str> = line.split(',').collect();
        // A killed supervisor may leave a half-written last line.
        if f.len() != 5 {
            continue;
        }
        let parse = |k: usize| {
            f[k].parse::<u64>().with_context(|| {
                format!("{}:{}: field {} '{}'", path.display(), i + 1, k + 1, f[k])
            })
        };
        let row = MaskRow {
            seq: parse(0)?,
            source: f[1].to_string(),
            instances: parse(2)? as u32,
            masked_px: parse(3)?,
        };
        rows.insert(row.seq, row);
    }
    Ok(rows.into_values().collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use shared_types::{MaskSource, MasksHeader};

    #[test]
    fn recorded_masks_read_back() {
        let dir = std::env::temp_dir().join(format!("dynslam-maskrec-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let mut rec = MaskRecorder::start(&dir).unwrap();
        let mut labels = vec![0u8; 8 * 4];
        labels[5] = 1;
        labels[6] = 2;
        for seq in [3u64, 4] {
            let header = MasksHeader {
                seq,
                source: MaskSource::Propagator as u32,
                width: 8,
                height: 4,
                num_instances: 2,
                ..Default::default()
            };
            rec.record(&MasksView::new(&header, &labels).unwrap());
        }
        assert_eq!(rec.finish().unwrap(), 0);
        let rows = read_rows(&dir).unwrap();
        assert_eq!(rows.len(), 2);
        assert_eq!(
            rows[1],
            MaskRow {
                seq: 4,
                source: "propagator".into(),
                instances: 2,
                masked_px: 2
            }
        );
        let back = image::open(mask_file(&dir, 4)).unwrap().into_luma8();
        assert_eq!(back.as_raw(), &labels);
        std::fs::remove_dir_all(&dir).ok();
    }
}
