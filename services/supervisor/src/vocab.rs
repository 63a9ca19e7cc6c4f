//! `dynslam vocab`: trains the bag-of-words vocabulary the keyframe
//! database uses (relocalisation, loop detection) from a set of images, and
//! describes a vocabulary file. The product ships one, trained with the
//! command in the README (`assets/vocabulary`).

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use sha2::{Digest, Sha256};
use slam_core::features::orb::{GrayU8, OrbExtractor};
use slam_core::place_recognition::vocabulary::{TrainOptions, Vocabulary};
use slam_core::SlamParams;

/// What training read and made.
#[derive(Debug)]
pub struct Trained {
    pub images: usize,
    pub features: usize,
    pub words: usize,
    pub sha256: String,
    pub seconds: f64,
}

/// The PNG images `inputs` name: files as given, folders expanded to their
/// `*.png` files in name order (so the same arguments give the same
/// vocabulary on every machine).
pub fn image_files(inputs: &[PathBuf]) -> Result<Vec<PathBuf>> {
    let mut files = Vec::new();
    for input in inputs {
        if input.is_dir() {
            let mut found: Vec<PathBuf> = std::fs::read_dir(input)
                .with_context(|| format!("cannot list image folder {}", input.display()))?
                .filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|p| p.extension().is_some_and(|e| e.eq_ignore_ascii_case("png")))
                .collect();
            if found.is_empty() {
                bail!("image folder {} has no .png files", input.display());
            }
            found.sort();
            files.extend(found);
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

/// Hex SHA-256 of `bytes`.
pub fn sha256_hex(bytes: &[u8]) -> String {
    Sha256::digest(bytes)
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect()
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
    let bytes =
        std::fs::read(out).with_context(|| format!("cannot read back {}", out.display()))?;
    Ok(Trained {
        images: files.len(),
        features,
        words: vocabulary.words(),
        sha256: sha256_hex(&bytes),
        seconds: t.elapsed().as_secs_f64(),
    })
}

/// A description of the vocabulary file at `path`, and how long it took
/// to load.
pub fn info(path: &Path) -> Result<String> {
    let bytes = std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
    let t = std::time::Instant::now();
    let v = Vocabulary::decode(&bytes)
        .map_err(|e| anyhow::anyhow!("vocabulary {}: {e}", path.display()))?;
    let ms = t.elapsed().as_secs_f64() * 1e3;
    Ok(format!(
        "{}: {} words (k {}, L {}), {} bytes, sha256 {}, loaded in {ms:.1} ms\ntrained on: {}",
        path.display(),
        v.words(),
        v.branching(),
        v.levels(),
        bytes.len(),
        sha256_hex(&bytes),
        v.description
    ))
}
