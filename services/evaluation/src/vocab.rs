//! `dynslam vocab`: trains the bag-of-words vocabulary the keyframe
//! database uses (relocalisation, loop detection) from a set of images, and
//! describes a vocabulary file. The product ships one, trained with the
//! command in the README (`assets/vocabulary`).

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use datasets::source::{image_folder, SourceError};
use provision::sha256_of;
use slam_core::features::orb::{GrayU8, OrbExtractor};
use slam_core::place_recognition::vocabulary::{TrainOptions, Vocabulary};
use slam_core::SlamParams;

/// What training read and made.
#[derive(Debug)]
pub struct Trained {
    /// Images read.
    pub images: usize,
    /// ORB descriptors clustered.
    pub features: usize,
    /// Leaf words of the vocabulary.
    pub words: usize,
    /// SHA-256 of the written file.
    pub sha256: String,
    /// Training time.
    pub seconds: f64,
}

/// The PNG images `inputs` name: files as given, folders expanded to their
/// `*.png` files in name order (so the same arguments give the same
/// vocabulary on every machine).
pub fn image_files(inputs: &[PathBuf]) -> Result<Vec<PathBuf>> {
    let mut files = Vec::new();
    for input in inputs {
        if input.is_dir() {
            let found = image_folder(input, 1.0).map_err(|e| match e {
                SourceError::Empty { .. } => {
                    anyhow::anyhow!("image folder {} has no .png files", input.display())
                }
                other => anyhow::anyhow!("{other}"),
            })?;
            files.extend(found.into_iter().map(|f| f.rgb));
        } else if input.is_file() {
            files.push(input.clone());
        } else {
            bail!("{}: no such image file or folder", input.display());
        }
    }
    if files.is_empty() {
        bail!("no images given: name PNG files or folders of them");
    }
    Ok(files)
}

/// Trains a vocabulary on the ORB features (the SLAM's own extractor and
/// settings) of `inputs` and writes it to `out`; progress on stderr.
pub fn train(inputs: &[PathBuf], out: &Path, opts: TrainOptions) -> Result<Trained> {
    let t = std::time::Instant::now();
    let files = image_files(inputs)?;
    let orb = SlamParams::default().orb;
    let extractor = OrbExtractor::new(orb);
    let mut images = Vec::with_capacity(files.len());
    let step = (files.len() / 10).max(1);
    for (i, file) in files.iter().enumerate() {
        let rgb = image::open(file)
            .with_context(|| format!("cannot read image {}", file.display()))?
            .to_rgb8();
        let (w, h) = (rgb.width() as usize, rgb.height() as usize);
        if w < 64 || h < 64 {
            bail!(
                "image {} is {w}x{h}: too small for ORB (64x64 at least)",
                file.display()
            );
        }
        let gray = GrayU8::from_rgb(rgb.as_raw(), w, h);
        let (_, descs, _) = extractor.extract(&gray, &|_, _| true);
        images.push(descs);
        if (i + 1) % step == 0 || i + 1 == files.len() {
            eprintln!("vocab: ORB features of {}/{} images", i + 1, files.len());
        }
    }
    let features: usize = images.iter().map(Vec::len).sum();
    let sources: Vec<String> = inputs
        .iter()
        .map(|p| {
            p.file_name()
                .map_or_else(|| p.display().to_string(), |n| n.to_string_lossy().into())
        })
        .collect();
    let description = format!(
        "k {} L {} seed {}; {} images ({}), {} ORB features ({} per image, {} levels x{})",
        opts.branching,
        opts.levels,
        opts.seed,
        files.len(),
        sources.join(", "),
        features,
        orb.features,
        orb.levels,
        orb.scale_factor
    );
    let vocabulary = Vocabulary::train(&images, opts, description, &mut |l| {
        eprintln!(
            "vocab: k-means level {}/{}: {} nodes",
            l.level, l.levels, l.nodes
        );
    })
    .map_err(|e| anyhow::anyhow!("{e}"))?;
    vocabulary.write(out)?;
    Ok(Trained {
        images: files.len(),
        features,
        words: vocabulary.words(),
        sha256: sha256_of(out)?,
        seconds: t.elapsed().as_secs_f64(),
    })
}

/// A description of the vocabulary file at `path`, and how long it took
/// to read and check.
pub fn info(path: &Path) -> Result<String> {
    let t = std::time::Instant::now();
    let v = Vocabulary::read(path)?;
    let ms = t.elapsed().as_secs_f64() * 1e3;
    let bytes = std::fs::metadata(path)?.len();
    Ok(format!(
        "{}: {} words (k {}, L {}), {} bytes, sha256 {}, loaded in {ms:.1} ms\ntrained on: {}",
        path.display(),
        v.words(),
        v.branching(),
        v.levels(),
        bytes,
        sha256_of(path)?,
        v.description
    ))
}
