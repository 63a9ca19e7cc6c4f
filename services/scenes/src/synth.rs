//! `dynslam synth`: a TUM RGB-D folder in, the same sequence with people
//! walking through it out, with exact ground truth.
//!
//! Output folder: `rgb/`, `depth/` (same file names as the input),
//! `rgb.txt`, `depth.txt`, `associations.txt`, the input's `groundtruth.txt`
//! byte for byte (the camera did not change), `masks/` (8-bit PNG, the
//! instance id of the person seen at each pixel, 0 for none), `masks.txt`,
//! with `--boxes` `movers/` and `movers.txt` (the same for carried boxes:
//! movers no class list names, kept out of `masks/` so that the person
//! scores stay about people) and `objects.json` (options, walkers, and per frame where each person was
//! drawn and how many pixels it covers). Frames are independent, so they are
//! rendered on all cores.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Mutex;

use datasets::progress::Progress;
use datasets::source::{tum_folder, FrameEntry};
use image::{ImageBuffer, Luma, RgbImage};
use nalgebra::Isometry3;
use serde::Serialize;
use slam_core::io::trajectory::Trajectory;

use crate::composite::{place, Canvas, Pinhole, Placement};
use crate::sprites::{moving_box, people, Sprite};
use crate::walkers::{walkers, Kind, Occlusion, Stage, WalkOptions, Walker};

/// Why a synthesis failed (each names the file or option).
#[derive(Debug, thiserror::Error)]
pub enum SynthError {
    /// The input sequence's lists.
    #[error("{0}")]
    Source(#[from] datasets::source::SourceError),
    /// The input's ground-truth trajectory.
    #[error("{0}")]
    Trajectory(#[from] slam_core::io::trajectory::TrajectoryError),
    /// An option out of range.
    #[error("options: {0}")]
    Options(String),
    #[error(
        "output folder {0} exists and is not empty: choose a new folder (nothing was overwritten)"
    )]
    /// The output folder has files (never overwritten).
    OutputNotEmpty(PathBuf),
    /// A file could not be read or written.
    #[error("{path}: {message}")]
    Io {
        /// The file.
        path: PathBuf,
        /// What the system said.
        message: String,
    },
    /// The input has no depth.
    #[error("{path}: frame without depth: dynslam synth needs an RGB-D sequence")]
    NoDepth {
        /// The input's frame.
        path: PathBuf,
    },
    /// An image that does not decode or has the wrong size.
    #[error("{path}: {message}")]
    BadImage {
        /// The image.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
}

fn io_err(path: &Path) -> impl Fn(std::io::Error) -> SynthError + '_ {
    move |e| SynthError::Io {
        path: path.to_path_buf(),
        message: e.to_string(),
    }
}

/// Everything `objects.json` holds.
#[derive(Debug, Serialize)]
pub struct SceneRecord {
    /// The sequence the people were drawn into.
    pub input: PathBuf,
    /// What was asked for.
    pub options: WalkOptions,
    /// The cut-outs' names, by sprite index.
    pub sprites: Vec<&'static str>,
    /// What drew it ([`SYNTH_VERSION`]): a cached sequence of another
    /// version is made again (`just synth-people`).
    pub synth_version: u32,
    /// Where the cut-outs come from (licences).
    pub sprite_provenance: &'static str,
    /// The objects' class (COCO name).
    pub class: &'static str,
    /// Each object's walk.
    pub walkers: Vec<Walker>,
    /// Each frame's files and objects.
    pub frames: Vec<FrameRecord>,
}

/// Bumped when the same options draw different frames: 2, a third person
/// cut-out and people drawn without scene occlusion in front of what they
/// cover in depth too.
pub const SYNTH_VERSION: u32 = 2;

/// One frame of a synthesised sequence.
#[derive(Debug, Clone, Serialize)]
pub struct FrameRecord {
    /// The input frame's timestamp.
    pub timestamp: f64,
    /// The colour image (relative to the output folder).
    pub rgb: String,
    /// The depth image.
    pub depth: String,
    /// The ground-truth label image.
    pub mask: String,
    /// The people drawn into this frame (possibly fully occluded: then
    /// `visible_px` is 0).
    pub objects: Vec<ObjectRecord>,
}

/// One object in one frame.
#[derive(Debug, Clone, Serialize)]
pub struct ObjectRecord {
    /// Where and how it was drawn.
    #[serde(flatten)]
    pub placement: Placement,
    /// Its pixels in the label image.
    pub visible_px: usize,
    /// Pixels in the image were nothing in front of the person: what
    /// `visible_px` falls short of it was hidden (`masks-eval`'s
    /// "occluded" cause).
    pub unoccluded_px: usize,
}

/// What a synthesis did, for the command's summary line.
#[derive(Debug)]
pub struct SynthSummary {
    /// Frames written.
    pub frames: usize,
    /// Frames with a visible person.
    pub frames_with_people: usize,
    /// Mean share of the image covered by people.
    pub mean_coverage: f64,
    /// Largest share of one frame covered by people.
    pub max_coverage: f64,
}

/// Synthesises `output` from `input`; see the module documentation.
pub fn synthesize(
    input: &Path,
    output: &Path,
    camera: &Pinhole,
    depth_scale: f64,
    options: &WalkOptions,
    limit: Option<usize>,
) -> Result<SynthSummary, SynthError> {
    options.validate().map_err(SynthError::Options)?;
    let mut frames = tum_folder(input, 0.02)?;
    if let Some(n) = limit {
        frames.truncate(n.max(1));
    }
    let gt_path = input.join("groundtruth.txt");
    let gt = Trajectory::load_tum(&gt_path)?;
    if output.exists()
        && std::fs::read_dir(output)
            .map_err(io_err(output))?
            .next()
            .is_some()
    {
        return Err(SynthError::OutputNotEmpty(output.to_path_buf()));
    }
    for sub in ["rgb", "depth", "masks"] {
        let dir = output.join(sub);
        std::fs::create_dir_all(&dir).map_err(io_err(&dir))?;
    }

    // The camera pose of each frame; frames outside the ground truth's span
    // keep the nearest pose (people are then placed as seen from there).
    let poses: Vec<Isometry3<f64>> = frames
        .iter()
        .map(|f| {
            gt.interpolate(f.timestamp, f64::INFINITY)
                .expect("trajectory is not empty")
        })
        .collect();
    let stage = Stage::from_camera(&poses[0]);
    let mut sprites = people();
    let aspects: Vec<f64> = sprites
        .iter()
        .map(|s| s.width() as f64 / s.height() as f64)
        .collect();
    sprites.push(moving_box());
    if options.boxes > 0 {
        let dir = output.join("movers");
        std::fs::create_dir_all(&dir).map_err(io_err(&dir))?;
    }
    // The frame size from the first image's header (walk widths and coverage).
    let (width, height) =
        image::image_dimensions(&frames[0].rgb).map_err(|e| SynthError::BadImage {
            path: frames[0].rgb.clone(),
            message: e.to_string(),
        })?;
    let half_fov_tan = camera.cx.max(width as f64 - camera.cx) / camera.fx;
    let walkers = walkers(options, half_fov_tan, &aspects);
    let t0 = frames[0].timestamp;

    let frames_out: Vec<FrameRecord> = for_each_frame("synth", frames.len(), |k| {
        FrameJob {
            frame: &frames[k],
            pose: &poses[k],
            t: frames[k].timestamp - t0,
            stage: &stage,
            walkers: &walkers,
            sprites: &sprites,
            camera,
            depth_scale,
            occlusion: options.occlusion,
            boxes: options.boxes > 0,
        }
        .render(output)
    })?;

    write_lists(output, &frames_out, options.boxes > 0)?;
    let is_person = |id: u8| walkers.iter().any(|w| w.id == id && w.kind == Kind::Person);
    let coverages: Vec<f64> = frames_out
        .iter()
        .map(|f| {
            f.objects
                .iter()
                .filter(|o| is_person(o.placement.id))
                .map(|o| o.visible_px)
                .sum::<usize>() as f64
                / (width as f64 * height as f64)
        })
        .collect();
    let gt_out = output.join("groundtruth.txt");
    std::fs::copy(&gt_path, &gt_out).map_err(io_err(&gt_out))?;
    let record = SceneRecord {
        input: input.to_path_buf(),
        options: options.clone(),
        sprites: sprites.iter().map(|s| s.name).collect(),
        synth_version: SYNTH_VERSION,
        sprite_provenance: "assets/PROVENANCE.md: scikit-image 0.26.0 sample data (astronaut: NASA, public domain; camera: CC0), matplotlib 3.11.2 sample data (grace_hopper: U.S. Navy, public domain)",
        class: "person",
        walkers,
        frames: frames_out,
    };
    let json_path = output.join("objects.json");
    let json = serde_json::to_string_pretty(&record).expect("scene record serialises");
    std::fs::write(&json_path, json).map_err(io_err(&json_path))?;

    Ok(SynthSummary {
        frames: coverages.len(),
        frames_with_people: coverages.iter().filter(|&&c| c > 0.0).count(),
        mean_coverage: coverages.iter().sum::<f64>() / coverages.len().max(1) as f64,
        max_coverage: coverages.iter().cloned().fold(0.0, f64::max),
    })
}

/// Runs `job(k)` for every frame index on all cores (at most 8 threads)
/// with a progress line; results in frame order, or the first error (the
/// remaining frames are then skipped).
pub fn for_each_frame<T: Send>(
    label: &str,
    count: usize,
    job: impl Fn(usize) -> Result<T, SynthError> + Sync,
) -> Result<Vec<T>, SynthError> {
    let results: Mutex<Vec<Option<T>>> = Mutex::new((0..count).map(|_| None).collect());
    let next = AtomicU64::new(0);
    let failure: Mutex<Option<SynthError>> = Mutex::new(None);
    let progress = Mutex::new(Progress::new(label, count as u64));
    let done = AtomicU64::new(0);
    let threads = std::thread::available_parallelism()
        .map_or(2, |n| n.get())
        .min(8);
    std::thread::scope(|scope| {
        for _ in 0..threads {
            scope.spawn(|| loop {
                let k = next.fetch_add(1, Ordering::Relaxed) as usize;
                if k >= count || failure.lock().unwrap().is_some() {
                    break;
                }
                match job(k) {
                    Ok(r) => results.lock().unwrap()[k] = Some(r),
                    Err(e) => {
                        failure.lock().unwrap().get_or_insert(e);
                    }
                }
                let n = done.fetch_add(1, Ordering::Relaxed) + 1;
                progress.lock().unwrap().set(n);
            });
        }
    });
    progress.lock().unwrap().finish();
    if let Some(e) = failure.into_inner().unwrap() {
        return Err(e);
    }
    Ok(results
        .into_inner()
        .unwrap()
        .into_iter()
        .flatten()
        .collect())
}

/// A 16-bit depth image as TUM stores it.
type Depth16 = ImageBuffer<Luma<u16>, Vec<u16>>;

struct FrameJob<'a> {
    frame: &'a FrameEntry,
    pose: &'a Isometry3<f64>,
    t: f64,
    stage: &'a Stage,
    walkers: &'a [Walker],
    sprites: &'a [Sprite],
    camera: &'a Pinhole,
    depth_scale: f64,
    occlusion: Occlusion,
    /// Write `movers/` (the boxes' labels).
    boxes: bool,
}

impl FrameJob<'_> {
    fn render(&self, output: &Path) -> Result<FrameRecord, SynthError> {
        let rgb_path = &self.frame.rgb;
        let (mut rgb, mut depth, depth_path) = self.load()?;
        let (w, h) = (rgb.width() as usize, rgb.height() as usize);
        let placements = self.placements();
        let mut labels = vec![0u8; w * h];
        let visible = {
            let mut canvas = Canvas {
                width: w,
                height: h,
                rgb: &mut rgb,
                depth: &mut depth,
                labels: &mut labels,
                depth_scale: self.depth_scale,
                occlusion: self.occlusion,
            };
            canvas.draw_counted(&placements, self.sprites)
        };
        let name = |p: &Path| {
            p.file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default()
        };
        let (rgb_rel, depth_rel) = (
            format!("rgb/{}", name(rgb_path)),
            format!("depth/{}", name(depth_path)),
        );
        // People stay in masks/, boxes go to movers/ (same ids).
        let movers = self.take_boxes(&mut labels);
        let mask_rel = format!("masks/{}", name(rgb_path));
        let save_err = |p: PathBuf| {
            move |e: image::ImageError| SynthError::Io {
                path: p,
                message: e.to_string(),
            }
        };
        rgb.save(output.join(&rgb_rel))
            .map_err(save_err(output.join(&rgb_rel)))?;
        depth
            .save(output.join(&depth_rel))
            .map_err(save_err(output.join(&depth_rel)))?;
        ImageBuffer::<Luma<u8>, _>::from_raw(w as u32, h as u32, labels)
            .expect("label buffer has the frame's size")
            .save(output.join(&mask_rel))
            .map_err(save_err(output.join(&mask_rel)))?;
        if self.boxes {
            let movers_path = output.join(format!("movers/{}", name(rgb_path)));
            ImageBuffer::<Luma<u8>, _>::from_raw(w as u32, h as u32, movers)
                .expect("label buffer has the frame's size")
                .save(&movers_path)
                .map_err(save_err(movers_path.clone()))?;
        }
        Ok(FrameRecord {
            timestamp: self.frame.timestamp,
            rgb: rgb_rel,
            depth: depth_rel,
            mask: mask_rel,
            objects: placements
                .into_iter()
                .zip(visible)
                .map(|(placement, drawn)| ObjectRecord {
                    placement: Placement {
                        depth_m: drawn.depth_m,
                        ..placement
                    },
                    visible_px: drawn.visible_px,
                    unoccluded_px: drawn.unoccluded_px,
                })
                .collect(),
        })
    }

    /// The frame's colour and depth images (16-bit, of the same size), and
    /// the depth image's path.
    fn load(&self) -> Result<(RgbImage, Depth16, &Path), SynthError> {
        let rgb_path = &self.frame.rgb;
        let depth_path = self
            .frame
            .depth
            .as_ref()
            .ok_or_else(|| SynthError::NoDepth {
                path: rgb_path.clone(),
            })?;
        let bad = |path: &Path, message: String| SynthError::BadImage {
            path: path.to_path_buf(),
            message,
        };
        let rgb = image::open(rgb_path)
            .map_err(|e| bad(rgb_path, e.to_string()))?
            .to_rgb8();
        let depth_img = image::open(depth_path).map_err(|e| bad(depth_path, e.to_string()))?;
        let depth = match depth_img {
            image::DynamicImage::ImageLuma16(d) => d,
            other => {
                return Err(bad(
                    depth_path,
                    format!("depth must be 16-bit grey, found {:?}", other.color()),
                ))
            }
        };
        let (w, h) = (rgb.width() as usize, rgb.height() as usize);
        if (depth.width() as usize, depth.height() as usize) != (w, h) {
            return Err(bad(
                depth_path,
                format!(
                    "{}x{} does not match the colour image's {w}x{h}",
                    depth.width(),
                    depth.height()
                ),
            ));
        }
        Ok((rgb, depth, depth_path))
    }

    /// Where each walker is in this frame's image (those in view).
    fn placements(&self) -> Vec<Placement> {
        self.walkers
            .iter()
            .filter_map(|walker| {
                let s = walker.state(self.stage, self.t);
                place(
                    walker.id,
                    walker.sprite,
                    s.leftwards,
                    &s.centre,
                    &self.stage.up,
                    walker.height_m,
                    self.pose,
                    self.camera,
                )
            })
            .collect()
    }

    /// Moves the boxes' labels out of `labels` into a label image of their
    /// own (`movers/`; people stay in `masks/`, ids unchanged).
    fn take_boxes(&self, labels: &mut [u8]) -> Vec<u8> {
        let mut movers = vec![0u8; labels.len()];
        for (label, mover) in labels.iter_mut().zip(movers.iter_mut()) {
            if *label != 0
                && self
                    .walkers
                    .iter()
                    .any(|wk| wk.id == *label && wk.kind == Kind::Box)
            {
                *mover = std::mem::take(label);
            }
        }
        movers
    }
}

/// rgb.txt, depth.txt, associations.txt and masks.txt. The depth
/// timestamps are the colour frame's: the pair was associated on input and
/// is rendered as one instant.
fn write_lists(output: &Path, frames: &[FrameRecord], boxes: bool) -> Result<(), SynthError> {
    let header = "# dynslam synth: people composited over a TUM RGB-D sequence (see objects.json)\n# timestamp filename\n";
    let mut rgb = String::from(header);
    let mut depth = String::from(header);
    let mut masks = String::from(
        "# dynslam synth: ground-truth instance ids (0: none)\n# timestamp filename\n",
    );
    let mut movers = String::from(
        "# dynslam synth: carried boxes' instance ids (0: none), movers no class names\n# timestamp filename\n",
    );
    let mut assoc = String::new();
    for f in frames {
        movers += &format!(
            "{:.6} {}\n",
            f.timestamp,
            f.mask.replacen("masks/", "movers/", 1)
        );
        rgb += &format!("{:.6} {}\n", f.timestamp, f.rgb);
        depth += &format!("{:.6} {}\n", f.timestamp, f.depth);
        masks += &format!("{:.6} {}\n", f.timestamp, f.mask);
        assoc += &format!(
            "{:.6} {} {:.6} {}\n",
            f.timestamp, f.rgb, f.timestamp, f.depth
        );
    }
    let mut lists = vec![
        ("rgb.txt", rgb),
        ("depth.txt", depth),
        ("masks.txt", masks),
        ("associations.txt", assoc),
    ];
    if boxes {
        lists.push(("movers.txt", movers));
    }
    for (name, text) in lists {
        let p = output.join(name);
        std::fs::write(&p, text).map_err(io_err(&p))?;
    }
    Ok(())
}
