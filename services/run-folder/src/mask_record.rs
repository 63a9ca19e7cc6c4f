//! The masks a run used, kept for the report: one `masks.csv` row per set
//! of masks (seq, source, instances, masked pixels, image file), the label
//! images `run.save_masks` keeps (`masks/<seq>.png`: 8-bit, 0 background,
//! i+1 instance i), and where the dataset has ground-truth masks, every
//! set's per-person IoU in `mask_iou.csv` (scored here, from the labels in
//! memory, so the report scores every frame without keeping its image).
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
use datasets::source::MaskList;
use image::GrayImage;
use pipeline_config::SaveMasks;
use shared_types::views::MasksView;
use shared_types::MaskSource;

/// The saved masks, `masks/<seq>.png` (`run.save_masks`).
pub const MASKS_DIR: &str = "masks";
/// One row per set of masks that reached SLAM ([`MaskRow`]).
pub const MASKS_CSV: &str = "masks.csv";
/// Per-person IoU against the dataset's ground truth, when it has some ([`PersonIou`]).
pub const MASK_IOU_CSV: &str = "mask_iou.csv";
const HEADER: &str = "seq,source,instances,masked_px,file,origin";
const IOU_HEADER: &str = "seq,source,iou";

/// Ground-truth people smaller than this are not scored (pixels, as
/// `dynslam masks-eval`'s default).
pub const MIN_PERSON_PX: usize = 2000;

/// One set of masks to write.
struct Job {
    seq: u64,
    source: &'static str,
    /// `mask_flags::origin`: local, remote or fallback.
    origin: &'static str,
    save: bool,
    instances: u32,
    labels: GrayImage,
}

/// The dataset's ground-truth masks and the timestamp of each frame.
pub struct Truth {
    /// The ground-truth mask files.
    pub masks: MaskList,
    /// Each frame's timestamp, by sequence number.
    pub timestamps: Vec<f64>,
    /// Left out of every score (see [`crate::ignore`]).
    pub ignore: crate::ignore::IgnoreRegions,
}

/// Writes `masks.csv`, the mask files and `mask_iou.csv` on a thread of its
/// own, so the run loop never waits on a PNG encoder or the disk.
pub struct MaskRecorder {
    tx: Option<SyncSender<Job>>,
    writer: Option<JoinHandle<Result<()>>>,
    save: SaveMasks,
    skipped: u64,
}

/// The path of frame `seq`'s label image inside a run folder.
pub fn mask_file(run_dir: &Path, seq: u64) -> PathBuf {
    run_dir.join(MASKS_DIR).join(format!("{seq:06}.png"))
}

/// Opens `name` in `run_dir` for appending, with `header` as its first
/// line when the file is new (a resumed run appends to the same files).
fn open_csv(run_dir: &Path, name: &str, header: &str) -> Result<std::fs::File> {
    let path = run_dir.join(name);
    let fresh = !path.exists();
    let mut csv = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(&path)
        .with_context(|| format!("cannot open {}", path.display()))?;
    if fresh {
        writeln!(csv, "{header}").with_context(|| format!("cannot write {}", path.display()))?;
    }
    Ok(csv)
}

impl MaskRecorder {
    /// Creates the files in `run_dir` and starts the writer thread.
    pub fn start(run_dir: &Path, save: SaveMasks, truth: Option<Truth>) -> Result<Self> {
        let dir = run_dir.join(MASKS_DIR);
        std::fs::create_dir_all(&dir)
            .with_context(|| format!("cannot create {}", dir.display()))?;
        let mut csv = open_csv(run_dir, MASKS_CSV, HEADER)?;
        let mut iou_csv = match &truth {
            Some(_) => Some(open_csv(run_dir, MASK_IOU_CSV, IOU_HEADER)?),
            None => None,
        };
        let (tx, rx) = sync_channel::<Job>(32);
        let run_dir = run_dir.to_path_buf();
        let writer = std::thread::Builder::new()
            .name("mask-recorder".into())
            .spawn(move || -> Result<()> {
                let mut ignore_warned = false;
                for job in rx {
                    let mut file = String::new();
                    if job.save {
                        let path = mask_file(&run_dir, job.seq);
                        job.labels
                            .save(&path)
                            .with_context(|| format!("cannot write {}", path.display()))?;
                        file = format!("{MASKS_DIR}/{:06}.png", job.seq);
                    }
                    if let (Some(out), Some(t)) = (iou_csv.as_mut(), truth.as_ref()) {
                        let ts = t.timestamps.get(job.seq as usize).copied();
                        let gt = ts.and_then(|ts| t.masks.load_at(ts).ok());
                        if let (Some(gt), Some(ts)) =
                            (gt.filter(|g| g.dimensions() == job.labels.dimensions()), ts)
                        {
                            let (w, h) = (gt.width() as usize, gt.height() as usize);
                            // An ignore image of the wrong size is said
                            // once; the frame is then scored without it.
                            let ignored = match t.ignore.at(ts, w, h) {
                                Ok(i) => i,
                                Err(e) => {
                                    if !ignore_warned {
                                        tracing::warn!("mask scores: {e:#}");
                                        ignore_warned = true;
                                    }
                                    None
                                }
                            };
                            for p in scenes::truth::instance_ious(
                                job.labels.as_raw(),
                                gt.as_raw(),
                                ignored.as_deref(),
                                gt.width() as usize,
                                MIN_PERSON_PX,
                            ) {
                                writeln!(out, "{},{},{:.6}", job.seq, job.source, p.iou)?;
                            }
                        }
                    }
                    let masked = job.labels.pixels().filter(|p| p[0] != 0).count();
                    writeln!(
                        csv,
                        "{},{},{},{},{},{}",
                        job.seq, job.source, job.instances, masked, file, job.origin
                    )?;
                }
                csv.flush()?;
                Ok(())
            })
            .context("cannot start the mask recorder thread")?;
        Ok(Self {
            tx: Some(tx),
            writer: Some(writer),
            save,
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
            origin: shared_types::mask_flags::origin(h.flags),
            save: self.save.keeps(masks.source()),
            instances: h.num_instances,
            labels,
        };
        self.send(job);
    }

    /// A worker told that no worker could take frame `seq`
    /// (`mask_flags::UNAVAILABLE`, real time): a row without labels.
    pub fn record_unavailable(&mut self, seq: u64, source: MaskSource) {
        self.send(Job {
            seq,
            source: source.as_str(),
            origin: shared_types::mask_flags::origin(shared_types::mask_flags::UNAVAILABLE),
            save: false,
            instances: 0,
            labels: GrayImage::new(0, 0),
        });
    }

    fn send(&mut self, job: Job) {
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
    /// The frame.
    pub seq: u64,
    /// segmenter or propagator.
    pub source: String,
    /// Objects in the masks.
    pub instances: u32,
    /// Pixels covered by any mask.
    pub masked_px: u64,
    /// Whether `masks/<seq>.png` was written (`run.save_masks`).
    pub saved: bool,
    /// Where they were made: local, remote or fallback (`local` in a
    /// masks.csv of an older version).
    pub origin: String,
}

/// Reads `masks.csv` (the last row of each seq wins: a replayed frame's
/// masks are written again); a missing file is an empty record.
pub fn read_rows(run_dir: &Path) -> Result<Vec<MaskRow>> {
    let path = run_dir.join(MASKS_CSV);
    let Ok(text) = std::fs::read_to_string(&path) else {
        return Ok(Vec::new());
    };
    let mut rows = std::collections::BTreeMap::new();
    // Older versions wrote no origin column.
    let columns = text.lines().next().map_or(0, |h| h.split(',').count());
    for (i, line) in text.lines().enumerate().skip(1) {
        let f: Vec<&str> = line.split(',').collect();
        // A killed supervisor may leave a half-written last line.
        if f.len() != columns || columns < 5 {
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
            saved: !f[4].is_empty(),
            origin: f.get(5).unwrap_or(&"local").to_string(),
        };
        rows.insert(row.seq, row);
    }
    Ok(rows.into_values().collect())
}

/// How many sets of `source`'s masks each origin made (every row of
/// `masks.csv`, replays included): local, remote, fallback, unavailable.
pub fn origin_counts(run_dir: &Path, source: &str) -> std::collections::BTreeMap<String, u64> {
    let mut counts = std::collections::BTreeMap::new();
    let Ok(text) = std::fs::read_to_string(run_dir.join(MASKS_CSV)) else {
        return counts;
    };
    for line in text.lines().skip(1) {
        let f: Vec<&str> = line.split(',').collect();
        if f.len() == 6 && f[1] == source {
            *counts.entry(f[5].to_string()).or_insert(0) += 1;
        }
    }
    counts
}

/// Per-person IoU of one set of masks against the ground truth.
#[derive(Debug, Clone, PartialEq)]
pub struct PersonIou {
    /// The frame.
    pub seq: u64,
    /// segmenter or propagator.
    pub source: String,
    /// Intersection over union with the person's ground-truth mask.
    pub iou: f64,
}

/// Reads `mask_iou.csv`: for each frame the scores of its last set of
/// masks (a replayed frame's masks are scored again); a missing file (no
/// ground truth) is an empty record.
pub fn read_ious(run_dir: &Path) -> Result<std::collections::BTreeMap<u64, Vec<PersonIou>>> {
    let path = run_dir.join(MASK_IOU_CSV);
    let mut by_seq: std::collections::BTreeMap<u64, Vec<PersonIou>> = Default::default();
    let Ok(text) = std::fs::read_to_string(&path) else {
        return Ok(by_seq);
    };
    let mut last_seq = None;
    for (i, line) in text.lines().enumerate().skip(1) {
        let f: Vec<&str> = line.split(',').collect();
        if f.len() != 3 {
            continue; // a half-written last line
        }
        let seq: u64 = f[0]
            .parse()
            .with_context(|| format!("{}:{}: seq '{}'", path.display(), i + 1, f[0]))?;
        let Ok(iou) = f[2].parse::<f64>() else {
            continue; // cut mid-number by a kill
        };
        let entry = by_seq.entry(seq).or_default();
        if last_seq != Some(seq) {
            // A new set of masks for this frame replaces the older one.
            entry.clear();
            last_seq = Some(seq);
        }
        entry.push(PersonIou {
            seq,
            source: f[1].to_string(),
            iou,
        });
    }
    Ok(by_seq)
}

#[cfg(test)]
mod tests {
    use super::*;
    use shared_types::MasksHeader;

    fn header(seq: u64, source: MaskSource) -> MasksHeader {
        MasksHeader {
            seq,
            source: source as u32,
            width: 8,
            height: 4,
            num_instances: 2,
            ..Default::default()
        }
    }

    #[test]
    fn recorded_masks_read_back() {
        let dir = std::env::temp_dir().join(format!("dynslam-maskrec-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let mut rec = MaskRecorder::start(&dir, SaveMasks::All, None).unwrap();
        let mut labels = vec![0u8; 8 * 4];
        labels[5] = 1;
        labels[6] = 2;
        for seq in [3u64, 4] {
            let mut h = header(seq, MaskSource::Propagator);
            h.flags = shared_types::mask_flags::REMOTE;
            rec.record(&MasksView::new(&h, &labels).unwrap());
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
                masked_px: 2,
                saved: true,
                origin: "remote".into(),
            }
        );
        let back = image::open(mask_file(&dir, 4)).unwrap().into_luma8();
        assert_eq!(back.as_raw(), &labels);
        assert!(
            !dir.join(MASK_IOU_CSV).exists(),
            "no ground truth, no scores"
        );
        std::fs::remove_dir_all(&dir).ok();
    }

    /// `keyframes` keeps the segmenter's images only, and every set is
    /// scored against the ground truth all the same.
    #[test]
    fn keyframe_images_only_and_every_set_scored() {
        let dir = std::env::temp_dir().join(format!("dynslam-maskiou-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let data = dir.join("data");
        std::fs::create_dir_all(data.join("masks")).unwrap();
        // Ground truth: one person, the left half (2000 px) of 100x40.
        let (w, h) = (100usize, 40usize);
        let mut gt = GrayImage::new(w as u32, h as u32);
        for y in 0..h {
            for x in 0..w / 2 {
                gt.put_pixel(x as u32, y as u32, image::Luma([7]));
            }
        }
        gt.save(data.join("masks/a.png")).unwrap();
        gt.save(data.join("masks/b.png")).unwrap();
        std::fs::write(data.join("masks.txt"), "1.0 masks/a.png\n2.0 masks/b.png\n").unwrap();
        let truth = Truth {
            ignore: Default::default(),
            masks: MaskList::open(&data).unwrap().unwrap(),
            timestamps: vec![1.0, 2.0],
        };
        let run = dir.join("run");
        std::fs::create_dir_all(&run).unwrap();
        let mut rec = MaskRecorder::start(&run, SaveMasks::Keyframes, Some(truth)).unwrap();
        // Frame 0 (segmenter): the whole left half; frame 1 (propagated):
        // a quarter of it (IoU 0.25).
        let mut whole = vec![0u8; w * h];
        let mut quarter = vec![0u8; w * h];
        for y in 0..h {
            for x in 0..w / 2 {
                whole[y * w + x] = 1;
                if x < w / 8 {
                    quarter[y * w + x] = 1;
                }
            }
        }
        let sized = |seq, source| MasksHeader {
            width: w as u32,
            height: h as u32,
            ..header(seq, source)
        };
        let (h0, h1) = (
            sized(0, MaskSource::Segmenter),
            sized(1, MaskSource::Propagator),
        );
        rec.record(&MasksView::new(&h0, &whole).unwrap());
        rec.record(&MasksView::new(&h1, &quarter).unwrap());
        assert_eq!(rec.finish().unwrap(), 0);
        assert!(mask_file(&run, 0).is_file());
        assert!(!mask_file(&run, 1).exists(), "propagated images not kept");
        let rows = read_rows(&run).unwrap();
        assert_eq!(
            rows.iter().map(|r| r.saved).collect::<Vec<_>>(),
            vec![true, false]
        );
        let ious = read_ious(&run).unwrap();
        assert_eq!(ious[&0][0].iou, 1.0);
        assert_eq!(ious[&0][0].source, "segmenter");
        assert!((ious[&1][0].iou - 0.24).abs() < 1e-6, "{:?}", ious[&1]);

        // An ignore.png over the whole image leaves nobody to score.
        GrayImage::from_pixel(w as u32, h as u32, image::Luma([1]))
            .save(data.join("ignore.png"))
            .unwrap();
        let truth = Truth {
            ignore: crate::ignore::IgnoreRegions::open(&data).unwrap(),
            masks: MaskList::open(&data).unwrap().unwrap(),
            timestamps: vec![1.0, 2.0],
        };
        let run = dir.join("run-ignored");
        std::fs::create_dir_all(&run).unwrap();
        let mut rec = MaskRecorder::start(&run, SaveMasks::Keyframes, Some(truth)).unwrap();
        rec.record(&MasksView::new(&h0, &whole).unwrap());
        rec.record(&MasksView::new(&h1, &quarter).unwrap());
        assert_eq!(rec.finish().unwrap(), 0);
        assert!(read_ious(&run).unwrap().is_empty(), "ignored people scored");
        std::fs::remove_dir_all(&dir).ok();
    }
}
