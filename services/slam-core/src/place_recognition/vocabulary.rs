//! A DBoW2-style vocabulary: a tree of binary descriptor clusters made by
//! hierarchical k-means (branching `k`, depth `L`), whose leaves are the
//! words, weighted by TF-IDF, compared with the L1 score (Galvez-Lopez and
//! Tardos 2012, as ORB-SLAM2 uses it).
//!
//! No pretrained vocabulary can be had here, so the product trains its own
//! ([`Vocabulary::train`], `dynslam vocab train`) and embeds the one it
//! ships ([`Vocabulary::embedded`], `assets/vocabulary`, see its
//! provenance). Training is deterministic for a seed on every machine: the
//! arithmetic is integer (Hamming distances, bit majorities) except the IDF
//! weights, which are computed in one fixed order.
//!
//! File layout: the magic `DSLAMVOC` and the framing of
//! [`crate::io::framed`] (version, length, CRC-32), then the payload in
//! postcard. A file that decodes is checked for a well-formed
//! tree before anything walks it.

use std::path::{Path, PathBuf};
use std::sync::{Arc, OnceLock};

use serde::{Deserialize, Serialize};

use crate::features::orb::{hamming, Descriptor};
use crate::io::framed::{frame, unframe, FrameProblem};
use crate::rng::SplitMix64;

/// The first eight bytes of a vocabulary file.
pub const MAGIC: &[u8; 8] = b"DSLAMVOC";
/// Bumped whenever the payload's layout changes.
pub const VERSION: u32 = 1;
/// The tree level (the root is level 0) whose nodes group features for
/// matching by bag of words: two features are compared only when they fall
/// under the same node there (ORB-SLAM2: 4 levels up from the leaves of its
/// 6-level tree, i.e. also level 2).
pub const FEATURE_LEVEL: u32 = 2;
/// Marks an inner node in `Node::word`.
const INNER: u32 = u32::MAX;
/// k-means stops after this many assignment rounds if it has not settled.
const KMEANS_ROUNDS: usize = 30;

/// The vocabulary the product ships: trained by `dynslam vocab train` with
/// the command in the README, verified by its SHA-256 in `just setup`.
const EMBEDDED: &[u8] = include_bytes!("../../../../assets/vocabulary/orb-k10-l4.vocab");

#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
struct Node {
    /// The cluster's centre (bitwise majority of its descriptors).
    descriptor: Descriptor,
    /// Its children are `first_child..first_child + children` (all after
    /// it: the tree is stored breadth first).
    first_child: u32,
    children: u32,
    /// Word id of a leaf; `INNER` for an inner node.
    word: u32,
}

/// The tree and its weights.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct Vocabulary {
    branching: u32,
    levels: u32,
    /// Breadth first; node 0 is the root (it has no descriptor of its own).
    nodes: Vec<Node>,
    /// Per word: its inverse document frequency, ln(N / n_i) over the
    /// training images.
    idf: Vec<f32>,
    /// What it was trained on and how (shown by `dynslam vocab info`).
    pub description: String,
    /// CRC-32 of its encoding: names the vocabulary a keyframe database was
    /// made with (not stored: computed when encoded or decoded).
    #[serde(skip)]
    id: u32,
}

/// A bag-of-words vector: (word, weight) sorted by word, weights summing to 1.
#[derive(Debug, Clone, Default, Serialize, Deserialize, PartialEq)]
pub struct BowVector(pub Vec<(u32, f32)>);

/// Features grouped by their node at [`FEATURE_LEVEL`]: (node, indices of
/// the descriptors under it), sorted by node.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct FeatureVector(pub Vec<(u32, Vec<u32>)>);

impl BowVector {
    /// DBoW2's L1 score of two normalised vectors: 1 for the same
    /// distribution of words, 0 for no word in common.
    pub fn score(&self, other: &BowVector) -> f32 {
        let (a, b) = (&self.0, &other.0);
        let (mut i, mut j, mut sum) = (0, 0, 0.0f32);
        while i < a.len() && j < b.len() {
            match a[i].0.cmp(&b[j].0) {
                std::cmp::Ordering::Less => i += 1,
                std::cmp::Ordering::Greater => j += 1,
                std::cmp::Ordering::Equal => {
                    let (v, w) = (a[i].1, b[j].1);
                    sum += v.abs() + w.abs() - (v - w).abs();
                    i += 1;
                    j += 1;
                }
            }
        }
        0.5 * sum
    }

    /// The words it has.
    pub fn words(&self) -> impl Iterator<Item = u32> + '_ {
        self.0.iter().map(|w| w.0)
    }

    /// No words (not trained).
    pub fn is_empty(&self) -> bool {
        self.0.is_empty()
    }
}

/// How a vocabulary is trained.
#[derive(Debug, Clone, Copy)]
pub struct TrainOptions {
    /// Children per node (k).
    pub branching: usize,
    /// Tree depth (L): up to k^L words.
    pub levels: usize,
    /// Seeds k-means++'s choices: one seed, one vocabulary.
    pub seed: u64,
}

impl Default for TrainOptions {
    /// k = 10, L = 4: 10^4 words, 0.4 MB; enough words for a few hundred
    /// thousand training features (ORB-SLAM2's 10^6 words need millions).
    fn default() -> Self {
        Self {
            branching: 10,
            levels: 4,
            seed: 1,
        }
    }
}

/// Training's progress, for a progress line.
#[derive(Debug, Clone, Copy)]
pub struct LevelDone {
    /// The level just done (from 1).
    pub level: usize,
    /// Levels in all.
    pub levels: usize,
    /// Nodes made at this level.
    pub nodes: usize,
}

/// What is wrong with a vocabulary (file or training input).
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum VocabularyProblem {
    /// Reading or writing the file failed.
    #[error("{0}")]
    Io(String),
    /// Not a vocabulary file.
    #[error("not a dynslam vocabulary (no DSLAMVOC header)")]
    NotAVocabulary,
    /// Another format version than this build reads.
    #[error("format version {found}, this build reads version {supported}")]
    Version {
        /// The file's version.
        found: u32,
        /// The version this build reads.
        supported: u32,
    },
    /// Shorter than its header promises.
    #[error("truncated: the header promises {expected} bytes, the file has {found}")]
    Truncated {
        /// Bytes the header promises.
        expected: u64,
        /// Bytes the file has.
        found: u64,
    },
    /// Bytes after the vocabulary.
    #[error("{0} bytes after the vocabulary (not written by dynslam, or two files joined)")]
    TrailingBytes(u64),
    /// The body does not match its checksum.
    #[error("checksum mismatch: the file is corrupted")]
    Checksum,
    /// The body could not be decoded.
    #[error("cannot decode the vocabulary: {0}")]
    Decode(String),
    /// Decoded, but the tree is not a tree.
    #[error("malformed tree: {0}")]
    Malformed(String),
    /// Training could not run on the input given.
    #[error("cannot train: {0}")]
    Training(String),
}

/// A vocabulary file that could not be read, written or trained, and why.
#[derive(Debug, thiserror::Error, PartialEq)]
#[error("vocabulary {}: {problem}", path.display())]
pub struct VocabularyError {
    /// The file.
    pub path: PathBuf,
    /// What is wrong.
    pub problem: VocabularyProblem,
}

impl Vocabulary {
    /// The vocabulary the product ships, decoded once per process.
    ///
    /// # Panics
    /// If the embedded file does not decode: a broken build, which the
    /// crate's tests catch (`the_embedded_vocabulary_is_sound`).
    pub fn embedded() -> Arc<Vocabulary> {
        static SHIPPED: OnceLock<Arc<Vocabulary>> = OnceLock::new();
        SHIPPED
            .get_or_init(|| {
                Arc::new(
                    Vocabulary::decode(EMBEDDED)
                        .unwrap_or_else(|e| panic!("the embedded vocabulary is broken: {e}")),
                )
            })
            .clone()
    }

    /// The embedded vocabulary's file bytes.
    pub fn embedded_bytes() -> &'static [u8] {
        EMBEDDED
    }

    /// Names this vocabulary (the CRC-32 of its encoding).
    pub fn id(&self) -> u32 {
        self.id
    }

    /// Number of words (leaves).
    pub fn words(&self) -> usize {
        self.idf.len()
    }

    /// Children per node.
    pub fn branching(&self) -> usize {
        self.branching as usize
    }

    /// Depth of the tree.
    pub fn levels(&self) -> usize {
        self.levels as usize
    }

    /// The word of `d` and its node at [`FEATURE_LEVEL`] (or the leaf, if
    /// the branch ends above that level).
    pub fn word_of(&self, d: &Descriptor) -> (u32, u32) {
        let mut node = 0usize;
        let mut at_feature_level = 0u32;
        let mut level = 0;
        loop {
            let n = &self.nodes[node];
            if n.word != INNER {
                if level < FEATURE_LEVEL {
                    at_feature_level = node as u32;
                }
                return (n.word, at_feature_level);
            }
            let first = n.first_child as usize;
            let children = &self.nodes[first..first + n.children as usize];
            let mut best = (u32::MAX, first);
            for (c, child) in children.iter().enumerate() {
                let h = hamming(d, &child.descriptor);
                if h < best.0 {
                    best = (h, first + c);
                }
            }
            node = best.1;
            level += 1;
            if level == FEATURE_LEVEL {
                at_feature_level = node as u32;
            }
        }
    }

    /// The bag-of-words vector of a set of descriptors (TF-IDF, L1 normalised).
    pub fn bow(&self, descs: &[Descriptor]) -> BowVector {
        let words: Vec<u32> = descs.iter().map(|d| self.word_of(d).0).collect();
        self.bow_of_words(words)
    }

    /// The bag-of-words vector and the feature vector of a set of descriptors.
    pub fn transform(&self, descs: &[Descriptor]) -> (BowVector, FeatureVector) {
        let (words, nodes): (Vec<u32>, Vec<u32>) = descs.iter().map(|d| self.word_of(d)).unzip();
        (self.bow_of_words(words), feature_vector(nodes))
    }

    /// The feature vector alone.
    pub fn features(&self, descs: &[Descriptor]) -> FeatureVector {
        feature_vector(descs.iter().map(|d| self.word_of(d).1).collect())
    }

    /// TF-IDF vector of the descriptors' words, L1 normalised.
    fn bow_of_words(&self, mut words: Vec<u32>) -> BowVector {
        words.sort_unstable();
        let mut bow: Vec<(u32, f32)> = Vec::new();
        for w in words {
            let weight = self.idf[w as usize];
            match bow.last_mut() {
                Some(last) if last.0 == w => last.1 += weight,
                _ => bow.push((w, weight)),
            }
        }
        // Words in every training image weigh 0: they say nothing.
        bow.retain(|w| w.1 > 0.0);
        let total: f32 = bow.iter().map(|w| w.1).sum();
        if total > 0.0 {
            for w in &mut bow {
                w.1 /= total;
            }
        }
        BowVector(bow)
    }

    /// Trains a vocabulary on the descriptors of `images` (one list per
    /// image; the IDF weights count images), calling `progress` after each
    /// tree level.
    pub fn train(
        images: &[Vec<Descriptor>],
        opts: TrainOptions,
        description: String,
        progress: &mut dyn FnMut(LevelDone),
    ) -> Result<Vocabulary, VocabularyProblem> {
        if !(2..=64).contains(&opts.branching) || !(1..=8).contains(&opts.levels) {
            return Err(VocabularyProblem::Training(format!(
                "branching {} and levels {}: branching must be 2..=64 and levels 1..=8",
                opts.branching, opts.levels
            )));
        }
        let all: Vec<Descriptor> = images.iter().flatten().copied().collect();
        if all.len() < opts.branching {
            return Err(VocabularyProblem::Training(format!(
                "{} descriptors from {} images: need at least {} (the branching)",
                all.len(),
                images.len(),
                opts.branching
            )));
        }
        let mut rng = SplitMix64::new(opts.seed);
        let mut nodes = vec![Node {
            descriptor: [0; 4],
            first_child: 0,
            children: 0,
            word: INNER,
        }];
        // Breadth first: the nodes of one level, each with its descriptors.
        let mut level: Vec<(usize, Vec<u32>)> = vec![(0, (0..all.len() as u32).collect())];
        for depth in 1..=opts.levels {
            let mut next = Vec::new();
            for (node, members) in level {
                let clusters = if members.len() <= opts.branching {
                    members
                        .iter()
                        .map(|&m| (all[m as usize], vec![m]))
                        .collect()
                } else {
                    kmeans(&all, &members, opts.branching, &mut rng)
                };
                nodes[node].first_child = nodes.len() as u32;
                nodes[node].children = clusters.len() as u32;
                for (centre, cluster) in clusters {
                    next.push((nodes.len(), cluster));
                    nodes.push(Node {
                        descriptor: centre,
                        first_child: 0,
                        children: 0,
                        word: INNER,
                    });
                }
            }
            progress(LevelDone {
                level: depth,
                levels: opts.levels,
                nodes: next.len(),
            });
            // A cluster of one descriptor cannot split: it stays a leaf.
            level = next
                .into_iter()
                .filter(|(_, m)| m.len() > 1 && depth < opts.levels)
                .collect();
        }
        // Words are numbered over the whole tree, breadth first.
        let mut word = 0;
        for n in nodes.iter_mut().skip(1).filter(|n| n.children == 0) {
            n.word = word;
            word += 1;
        }
        let mut vocabulary = Vocabulary {
            branching: opts.branching as u32,
            levels: opts.levels as u32,
            nodes,
            idf: vec![0.0; word as usize],
            description,
            id: 0,
        };
        // IDF from the words the finished tree gives each training image.
        let mut images_with = vec![0u32; word as usize];
        let mut seen = vec![usize::MAX; word as usize];
        for (i, image) in images.iter().enumerate() {
            for d in image {
                let (w, _) = vocabulary.word_of(d);
                if seen[w as usize] != i {
                    seen[w as usize] = i;
                    images_with[w as usize] += 1;
                }
            }
        }
        let n = images.len() as f64;
        for (idf, &with) in vocabulary.idf.iter_mut().zip(&images_with) {
            *idf = if with == 0 {
                // Never the word of a training feature: as rare as can be.
                n.ln() as f32
            } else {
                (n / with as f64).ln() as f32
            };
        }
        vocabulary.id = crc32fast::hash(&vocabulary.payload()?);
        Ok(vocabulary)
    }

    fn payload(&self) -> Result<Vec<u8>, VocabularyProblem> {
        postcard::to_stdvec(self).map_err(|e| VocabularyProblem::Decode(e.to_string()))
    }

    /// The file's bytes.
    pub fn encode(&self) -> Result<Vec<u8>, VocabularyProblem> {
        Ok(frame(MAGIC, VERSION, &self.payload()?))
    }

    /// A vocabulary from its file's bytes, checked.
    pub fn decode(bytes: &[u8]) -> Result<Self, VocabularyProblem> {
        let (payload, crc) = unframe(bytes, MAGIC, VERSION).map_err(|p| match p {
            FrameProblem::Foreign => VocabularyProblem::NotAVocabulary,
            FrameProblem::Version { found, supported } => {
                VocabularyProblem::Version { found, supported }
            }
            FrameProblem::Truncated { expected, found } => {
                VocabularyProblem::Truncated { expected, found }
            }
            FrameProblem::TrailingBytes(n) => VocabularyProblem::TrailingBytes(n),
            FrameProblem::Checksum => VocabularyProblem::Checksum,
        })?;
        let mut vocabulary: Vocabulary =
            postcard::from_bytes(payload).map_err(|e| VocabularyProblem::Decode(e.to_string()))?;
        vocabulary.check().map_err(VocabularyProblem::Malformed)?;
        vocabulary.id = crc;
        Ok(vocabulary)
    }

    /// Reads and checks the vocabulary file at `path`.
    pub fn read(path: &Path) -> Result<Self, VocabularyError> {
        let named = |problem| VocabularyError {
            path: path.to_path_buf(),
            problem,
        };
        let bytes = std::fs::read(path).map_err(|e| named(VocabularyProblem::Io(e.to_string())))?;
        Self::decode(&bytes).map_err(named)
    }

    /// Writes the vocabulary to `path`.
    pub fn write(&self, path: &Path) -> Result<(), VocabularyError> {
        let named = |problem| VocabularyError {
            path: path.to_path_buf(),
            problem,
        };
        let bytes = self.encode().map_err(named)?;
        std::fs::write(path, bytes).map_err(|e| named(VocabularyProblem::Io(e.to_string())))
    }

    /// A well-formed tree: every node's children lie after it and inside
    /// the arena, each node but the root is some node's child exactly once,
    /// leaves and only leaves have words, each word once, no deeper than
    /// `levels`.
    fn check(&self) -> Result<(), String> {
        let n = self.nodes.len();
        if n < 2 || self.nodes[0].children == 0 {
            return Err("no words".into());
        }
        if self.branching < 2 || self.levels == 0 || self.levels > 8 {
            return Err(format!(
                "branching {} / levels {} out of range",
                self.branching, self.levels
            ));
        }
        let mut parent_of = vec![usize::MAX; n];
        let mut depth = vec![0u32; n];
        let mut word_seen = vec![false; self.idf.len()];
        for (i, node) in self.nodes.iter().enumerate() {
            if node.children == 0 {
                let w = node.word as usize;
                if i == 0 || w >= self.idf.len() || std::mem::replace(&mut word_seen[w], true) {
                    return Err(format!("leaf {i} has a missing or repeated word {w}"));
                }
                continue;
            }
            if node.word != INNER || node.children > self.branching {
                return Err(format!("inner node {i} has a word or too many children"));
            }
            let first = node.first_child as usize;
            let end = first + node.children as usize;
            if first <= i || end > n {
                return Err(format!(
                    "node {i}: children {first}..{end} out of order or range"
                ));
            }
            for c in first..end {
                if parent_of[c] != usize::MAX {
                    return Err(format!("node {c} has two parents"));
                }
                parent_of[c] = i;
                depth[c] = depth[i] + 1;
                if depth[c] > self.levels {
                    return Err(format!("node {c} is deeper than {} levels", self.levels));
                }
            }
        }
        if let Some(orphan) = (1..n).find(|&i| parent_of[i] == usize::MAX) {
            return Err(format!("node {orphan} has no parent"));
        }
        if let Some(w) = word_seen.iter().position(|s| !s) {
            return Err(format!("word {w} has no leaf"));
        }
        if self.idf.iter().any(|w| !w.is_finite() || *w < 0.0) {
            return Err("a weight is negative or not finite".into());
        }
        Ok(())
    }
}

/// Descriptor indices grouped by their node (`nodes[i]` is descriptor
/// i's), sorted by node.
fn feature_vector(nodes: Vec<u32>) -> FeatureVector {
    let mut order: Vec<(u32, u32)> = nodes
        .into_iter()
        .enumerate()
        .map(|(i, n)| (n, i as u32))
        .collect();
    order.sort_unstable();
    let mut features: Vec<(u32, Vec<u32>)> = Vec::new();
    for (node, i) in order {
        match features.last_mut() {
            Some(last) if last.0 == node => last.1.push(i),
            _ => features.push((node, vec![i])),
        }
    }
    FeatureVector(features)
}

/// k-means of the descriptors `members` (indices into `all`) into at most
/// `k` clusters: k-means++ seeding, then assignment to the nearest centre
/// and bitwise-majority centres until nothing moves. Empty clusters are
/// dropped. Returns (centre, members) per cluster.
fn kmeans(
    all: &[Descriptor],
    members: &[u32],
    k: usize,
    rng: &mut SplitMix64,
) -> Vec<(Descriptor, Vec<u32>)> {
    let at = |m: u32| &all[m as usize];
    // k-means++: each next centre drawn with probability proportional to
    // its squared distance to the nearest centre so far.
    let mut centres = vec![*at(members[rng.below(members.len())])];
    let mut nearest: Vec<u32> = members
        .iter()
        .map(|&m| hamming(at(m), &centres[0]))
        .collect();
    while centres.len() < k {
        let total: u64 = nearest.iter().map(|&d| (d as u64) * (d as u64)).sum();
        if total == 0 {
            break; // every descriptor sits on a centre
        }
        let mut pick = rng.next_u64() % total;
        let mut chosen = members.len() - 1;
        for (i, &d) in nearest.iter().enumerate() {
            let w = (d as u64) * (d as u64);
            if pick < w {
                chosen = i;
                break;
            }
            pick -= w;
        }
        let c = *at(members[chosen]);
        for (i, &m) in members.iter().enumerate() {
            nearest[i] = nearest[i].min(hamming(at(m), &c));
        }
        centres.push(c);
    }
    let mut assignment = vec![usize::MAX; members.len()];
    for _ in 0..KMEANS_ROUNDS {
        let mut moved = false;
        for (i, &m) in members.iter().enumerate() {
            let d = at(m);
            let mut best = (u32::MAX, 0);
            for (c, centre) in centres.iter().enumerate() {
                let h = hamming(d, centre);
                if h < best.0 {
                    best = (h, c);
                }
            }
            if assignment[i] != best.1 {
                assignment[i] = best.1;
                moved = true;
            }
        }
        if !moved {
            break;
        }
        // Bitwise majority (ties set the bit, as DBoW2's ORB mean).
        let mut counts = vec![[0u32; 256]; centres.len()];
        let mut sizes = vec![0u32; centres.len()];
        for (i, &m) in members.iter().enumerate() {
            let c = assignment[i];
            sizes[c] += 1;
            for (w, word) in at(m).iter().enumerate() {
                let mut bits = *word;
                while bits != 0 {
                    let b = bits.trailing_zeros() as usize;
                    counts[c][w * 64 + b] += 1;
                    bits &= bits - 1;
                }
            }
        }
        for (c, centre) in centres.iter_mut().enumerate() {
            if sizes[c] == 0 {
                continue;
            }
            let half = sizes[c].div_ceil(2);
            let mut d = [0u64; 4];
            for (bit, &count) in counts[c].iter().enumerate() {
                if count >= half {
                    d[bit / 64] |= 1 << (bit % 64);
                }
            }
            *centre = d;
        }
    }
    let mut clusters: Vec<(Descriptor, Vec<u32>)> =
        centres.into_iter().map(|c| (c, Vec::new())).collect();
    for (i, &m) in members.iter().enumerate() {
        clusters[assignment[i]].1.push(m);
    }
    clusters.retain(|c| !c.1.is_empty());
    clusters
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Descriptors around `centres` (each bit flipped with probability
    /// `noise`), `per` of each, as `images` images.
    fn clustered(centres: &[Descriptor], per: usize, noise: f64, seed: u64) -> Vec<Descriptor> {
        let mut rng = SplitMix64::new(seed);
        let mut out = Vec::new();
        for c in centres {
            for _ in 0..per {
                let mut d = *c;
                for bit in 0..256 {
                    if rng.uniform(0.0, 1.0) < noise {
                        d[bit / 64] ^= 1 << (bit % 64);
                    }
                }
                out.push(d);
            }
        }
        out
    }

    fn random_descriptors(n: usize, seed: u64) -> Vec<Descriptor> {
        let mut rng = SplitMix64::new(seed);
        (0..n)
            .map(|_| {
                [
                    rng.next_u64(),
                    rng.next_u64(),
                    rng.next_u64(),
                    rng.next_u64(),
                ]
            })
            .collect()
    }

    fn small() -> (Vocabulary, Vec<Vec<Descriptor>>) {
        let centres = random_descriptors(6, 3);
        let images: Vec<Vec<Descriptor>> = (0..6)
            .map(|i| clustered(&centres[..=i.min(5)], 40, 0.05, i as u64))
            .collect();
        let opts = TrainOptions {
            branching: 3,
            levels: 3,
            seed: 9,
        };
        let v = Vocabulary::train(&images, opts, "test".into(), &mut |_| {}).unwrap();
        (v, images)
    }

    #[test]
    fn training_is_deterministic_and_the_tree_well_formed() {
        let (a, images) = small();
        let opts = TrainOptions {
            branching: 3,
            levels: 3,
            seed: 9,
        };
        let mut levels = Vec::new();
        let b =
            Vocabulary::train(&images, opts, "test".into(), &mut |l| levels.push(l.level)).unwrap();
        assert_eq!(levels, [1, 2, 3]);
        assert_eq!(a.encode().unwrap(), b.encode().unwrap());
        a.check().unwrap();
        assert!(a.words() > 6 && a.words() <= 27, "{} words", a.words());
        let other = Vocabulary::train(
            &images,
            TrainOptions { seed: 10, ..opts },
            "test".into(),
            &mut |_| {},
        )
        .unwrap();
        assert_ne!(a.id(), other.id(), "another seed, another vocabulary");
    }

    #[test]
    fn vectors_score_alike_images_higher() {
        let (v, images) = small();
        let bows: Vec<BowVector> = images.iter().map(|i| v.bow(i)).collect();
        for b in &bows {
            let sum: f32 = b.0.iter().map(|w| w.1).sum();
            assert!((sum - 1.0).abs() < 1e-4 || b.is_empty());
            assert!(b.0.windows(2).all(|w| w[0].0 < w[1].0), "sorted, unique");
        }
        // Image 5 is image 4 plus one more cluster; image 1 shares less.
        assert!((bows[5].score(&bows[5]) - 1.0).abs() < 1e-4);
        assert!(bows[5].score(&bows[4]) > bows[5].score(&bows[1]));
        // Fresh noise around the same centres lands on the same words.
        let centres = random_descriptors(6, 3);
        let again = v.bow(&clustered(&centres, 40, 0.05, 77));
        assert!(again.score(&bows[5]) > 0.8, "{}", again.score(&bows[5]));
        // Unrelated descriptors share little.
        let noise = v.bow(&random_descriptors(240, 5));
        assert!(noise.score(&bows[5]) < again.score(&bows[5]));
    }

    #[test]
    fn feature_vectors_group_every_descriptor_once() {
        let (v, images) = small();
        let f = v.features(&images[5]);
        let mut all: Vec<u32> = f.0.iter().flat_map(|n| n.1.clone()).collect();
        all.sort_unstable();
        assert_eq!(all, (0..images[5].len() as u32).collect::<Vec<_>>());
        assert!(f.0.windows(2).all(|w| w[0].0 < w[1].0));
    }

    #[test]
    fn bad_training_input_is_named() {
        let too_few = vec![random_descriptors(3, 1)];
        let e = Vocabulary::train(
            &too_few,
            TrainOptions::default(),
            String::new(),
            &mut |_| {},
        )
        .unwrap_err();
        assert!(e.to_string().contains("need at least 10"), "{e}");
        let opts = TrainOptions {
            branching: 1,
            ..Default::default()
        };
        let e = Vocabulary::train(
            &[random_descriptors(50, 1)],
            opts,
            String::new(),
            &mut |_| {},
        )
        .unwrap_err();
        assert!(e.to_string().contains("branching 1"), "{e}");
    }

    #[test]
    fn damaged_files_are_refused_with_the_reason() {
        let (v, _) = small();
        let bytes = v.encode().unwrap();
        let back = Vocabulary::decode(&bytes).unwrap();
        assert_eq!(back, v);
        assert_eq!(back.id(), v.id());
        assert_eq!(
            Vocabulary::decode(b"DSLAMMAP and more"),
            Err(VocabularyProblem::NotAVocabulary)
        );
        assert!(matches!(
            Vocabulary::decode(&bytes[..bytes.len() - 3]),
            Err(VocabularyProblem::Truncated { .. })
        ));
        assert!(matches!(
            Vocabulary::decode(&bytes[..10]),
            Err(VocabularyProblem::Truncated { .. })
        ));
        let mut joined = bytes.clone();
        joined.extend_from_slice(&bytes);
        assert!(matches!(
            Vocabulary::decode(&joined),
            Err(VocabularyProblem::TrailingBytes(_))
        ));
        let mut flipped = bytes.clone();
        flipped[crate::io::framed::HEADER + 20] ^= 0x10;
        assert_eq!(
            Vocabulary::decode(&flipped),
            Err(VocabularyProblem::Checksum)
        );
        let mut other = bytes.clone();
        other[8] = 9;
        assert!(matches!(
            Vocabulary::decode(&other),
            Err(VocabularyProblem::Version { found: 9, .. })
        ));
        // Decodes, but the tree is broken: refused before anything walks it.
        let mut broken = v.clone();
        broken.nodes[0].first_child = 0;
        let e = Vocabulary::decode(&broken.encode().unwrap()).unwrap_err();
        assert!(matches!(e, VocabularyProblem::Malformed(_)), "{e}");
        let mut looping = v.clone();
        let last = looping.nodes.len() - 1;
        looping.nodes[last].word = INNER;
        looping.nodes[last].first_child = 1;
        looping.nodes[last].children = 1;
        assert!(Vocabulary::decode(&looping.encode().unwrap()).is_err());
        // Every truncation and every single-byte change is an error, never a panic.
        for cut in 0..bytes.len() {
            assert!(Vocabulary::decode(&bytes[..cut]).is_err());
        }
        let e = Vocabulary::read(Path::new("/nonexistent/v.vocab")).unwrap_err();
        assert!(
            e.to_string()
                .starts_with("vocabulary /nonexistent/v.vocab: "),
            "{e}"
        );
    }

    #[test]
    fn the_embedded_vocabulary_is_sound() {
        let t = std::time::Instant::now();
        let v = Vocabulary::decode(Vocabulary::embedded_bytes()).unwrap();
        eprintln!(
            "embedded vocabulary: {} words, k {} L {}, decoded in {:.1} ms: {}",
            v.words(),
            v.branching(),
            v.levels(),
            t.elapsed().as_secs_f64() * 1e3,
            v.description
        );
        assert!(v.words() > 5000, "{} words", v.words());
        assert_eq!(v.id(), Vocabulary::embedded().id());
    }
}
