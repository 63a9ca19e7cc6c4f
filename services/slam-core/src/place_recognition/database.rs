//! The keyframe database (ORB-SLAM2's KeyFrameDatabase): each mapped
//! keyframe's bag-of-words vector and an inverted index from word to the
//! keyframes that have it, so that the keyframes a frame looks like are
//! found without comparing it with every keyframe. Part of the map (and of
//! the map file); culling a keyframe removes it here too.

use serde::{Deserialize, Serialize};

use super::vocabulary::{BowVector, Vocabulary};

/// Covisible keyframes whose scores add to a candidate's (ORB-SLAM2: 10).
const GROUP_NEIGHBOURS: usize = 10;
/// A candidate shares at least this share of the most words any keyframe
/// shares with the query (ORB-SLAM2: 0.8).
const MIN_COMMON_WORDS: f32 = 0.8;
/// Groups scoring at least this share of the best group's score are kept
/// (ORB-SLAM2: 0.75).
const MIN_GROUP_SCORE: f32 = 0.75;

/// Keyframes by visual word (an inverted index), for relocalisation and loop detection.
#[derive(Debug, Clone, Default, Serialize, Deserialize, PartialEq)]
pub struct KeyframeDatabase {
    /// The id of the vocabulary the vectors were made with (0: none yet).
    vocabulary: u32,
    /// Per keyframe id: its vector, None while not in the database (not yet
    /// mapped, or culled).
    vectors: Vec<Option<BowVector>>,
    /// Per word: the keyframes whose vector has it, in insertion order.
    inverted: Vec<Vec<u32>>,
}

impl KeyframeDatabase {
    /// An empty database for `vocabulary`.
    pub fn new(vocabulary: &Vocabulary) -> Self {
        Self {
            vocabulary: vocabulary.id(),
            vectors: Vec::new(),
            inverted: vec![Vec::new(); vocabulary.words()],
        }
    }

    /// The vectors were made with `vocabulary`.
    pub fn is_made_with(&self, vocabulary: &Vocabulary) -> bool {
        self.vocabulary == vocabulary.id() && self.inverted.len() == vocabulary.words()
    }

    /// Puts keyframe `kf` in with its vector (replacing an earlier one).
    pub fn add(&mut self, kf: usize, vector: BowVector) {
        self.remove(kf);
        for w in vector.words() {
            if let Some(list) = self.inverted.get_mut(w as usize) {
                list.push(kf as u32);
            }
        }
        if self.vectors.len() <= kf {
            self.vectors.resize(kf + 1, None);
        }
        self.vectors[kf] = Some(vector);
    }

    /// Takes keyframe `kf` out (nothing if it is not in).
    pub fn remove(&mut self, kf: usize) {
        let Some(vector) = self.vectors.get_mut(kf).and_then(Option::take) else {
            return;
        };
        for w in vector.words() {
            if let Some(list) = self.inverted.get_mut(w as usize) {
                list.retain(|&k| k as usize != kf);
            }
        }
    }

    /// Keyframe `kf`'s vector, if it is in.
    pub fn vector(&self, kf: usize) -> Option<&BowVector> {
        self.vectors.get(kf).and_then(Option::as_ref)
    }

    /// The keyframes in the database.
    pub fn len(&self) -> usize {
        self.vectors.iter().flatten().count()
    }

    /// No keyframe in it.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The keyframes a frame with vector `query` may be taken at
    /// (ORB-SLAM2's DetectRelocalizationCandidates), best first: see
    /// [`KeyframeDatabase::candidates`], over all keyframes.
    pub fn relocalisation_candidates(
        &self,
        query: &BowVector,
        covisible: impl Fn(usize) -> Vec<usize>,
    ) -> Vec<usize> {
        self.candidates(query, 0.0, |_| false, covisible)
    }

    /// Candidates for `query`, best first (loop detection: ORB-SLAM2's
    /// DetectLoopCandidates, with the keyframes connected to the new one
    /// `excluded` and `min_score` the lowest score of its neighbours):
    /// keyframes (not `excluded`)
    /// sharing at least 80 % of the most words any of them shares with it,
    /// scoring at least `min_score`; each one's score accumulated over its
    /// `covisible` neighbours among them (a place is seen by a group of
    /// keyframes, a lone look-alike is not); the best keyframe of every
    /// group within 75 % of the best group's score.
    pub fn candidates(
        &self,
        query: &BowVector,
        min_score: f32,
        excluded: impl Fn(usize) -> bool,
        covisible: impl Fn(usize) -> Vec<usize>,
    ) -> Vec<usize> {
        let mut common: Vec<u32> = vec![0; self.vectors.len()];
        for w in query.words() {
            if let Some(list) = self.inverted.get(w as usize) {
                for &k in list {
                    if !excluded(k as usize) {
                        common[k as usize] += 1;
                    }
                }
            }
        }
        let most = common.iter().copied().max().unwrap_or(0);
        if most == 0 {
            return Vec::new();
        }
        let min_common = (MIN_COMMON_WORDS * most as f32) as u32;
        let mut score: Vec<Option<f32>> = vec![None; self.vectors.len()];
        for (k, &n) in common.iter().enumerate() {
            if n > min_common || n == most {
                if let Some(v) = self.vector(k) {
                    score[k] = Some(query.score(v)).filter(|&s| s >= min_score);
                }
            }
        }
        // (group score, best keyframe of the group, its score)
        let mut groups: Vec<(f32, usize, f32)> = Vec::new();
        for (k, s) in score.iter().enumerate() {
            let Some(s) = *s else { continue };
            let (mut total, mut best) = (s, (s, k));
            for n in covisible(k).into_iter().take(GROUP_NEIGHBOURS) {
                if let Some(sn) = score.get(n).copied().flatten() {
                    total += sn;
                    if sn > best.0 {
                        best = (sn, n);
                    }
                }
            }
            groups.push((total, best.1, best.0));
        }
        let best_group = groups.iter().map(|g| g.0).fold(0.0f32, f32::max);
        groups.retain(|g| g.0 >= MIN_GROUP_SCORE * best_group);
        groups.sort_by(|a, b| b.2.total_cmp(&a.2).then(b.0.total_cmp(&a.0)));
        let mut out: Vec<usize> = Vec::new();
        for (_, k, _) in groups {
            if !out.contains(&k) {
                out.push(k);
            }
        }
        out
    }

    /// The inverted index lists exactly the words of the stored vectors,
    /// and only `live` keyframes are stored.
    pub(crate) fn check(&self, live: impl Fn(usize) -> bool) -> Result<(), String> {
        let mut listed = 0usize;
        for (w, list) in self.inverted.iter().enumerate() {
            for &k in list {
                listed += 1;
                let has = self
                    .vector(k as usize)
                    .is_some_and(|v| v.words().any(|x| x as usize == w));
                if !has {
                    return Err(format!(
                        "keyframe database lists keyframe {k} under word {w} it does not have"
                    ));
                }
            }
        }
        let mut stored = 0usize;
        for (k, v) in self.vectors.iter().enumerate() {
            let Some(v) = v else { continue };
            if !live(k) {
                return Err(format!(
                    "keyframe database holds culled or missing keyframe {k}"
                ));
            }
            if v.words().any(|w| w as usize >= self.inverted.len()) {
                return Err(format!(
                    "keyframe {k}'s vector has a word beyond the vocabulary"
                ));
            }
            stored += v.0.len();
        }
        if stored != listed {
            return Err(format!(
                "keyframe database: {stored} words in vectors, {listed} in the inverted index"
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn vector(words: &[u32]) -> BowVector {
        let w = 1.0 / words.len() as f32;
        BowVector(words.iter().map(|&x| (x, w)).collect())
    }

    fn database(words: usize) -> KeyframeDatabase {
        KeyframeDatabase {
            vocabulary: 1,
            vectors: Vec::new(),
            inverted: vec![Vec::new(); words],
        }
    }

    #[test]
    fn add_remove_and_the_index_agree() {
        let mut db = database(20);
        db.add(0, vector(&[1, 2, 3]));
        db.add(2, vector(&[3, 4]));
        db.check(|_| true).unwrap();
        assert_eq!(db.len(), 2);
        assert_eq!(db.inverted[3], vec![0, 2]);
        db.add(0, vector(&[5])); // replaces
        assert_eq!(db.inverted[3], vec![2]);
        db.remove(2);
        db.remove(7); // not in: nothing
        db.check(|_| true).unwrap();
        assert_eq!(db.len(), 1);
        assert!(db.check(|k| k != 0).unwrap_err().contains("culled"));
        db.inverted[9].push(0);
        assert!(db.check(|_| true).unwrap_err().contains("does not have"));
    }

    #[test]
    fn candidates_are_the_best_of_each_look_alike_group() {
        let mut db = database(100);
        // Keyframes 0-2 see one place (words 0..10), 3-4 another (50..60),
        // 5 shares a few words with the first place only.
        for k in 0..3 {
            db.add(k, vector(&(k as u32..10 + k as u32).collect::<Vec<_>>()));
        }
        for k in 3..5 {
            db.add(k, vector(&(50..60).collect::<Vec<_>>()));
        }
        db.add(5, vector(&[0, 1, 90, 91, 92, 93, 94, 95]));
        let covisible = |k: usize| match k {
            0..=2 => (0..3).filter(|&o| o != k).collect(),
            3 | 4 => vec![7 - k],
            _ => Vec::new(),
        };
        let query = vector(&(1..11).collect::<Vec<_>>());
        let c = db.relocalisation_candidates(&query, covisible);
        assert_eq!(c, vec![1], "keyframe 1 has exactly the query's words");
        let elsewhere = vector(&(50..60).collect::<Vec<_>>());
        let c = db.relocalisation_candidates(&elsewhere, covisible);
        assert!(c.contains(&3) || c.contains(&4));
        assert!(!c.iter().any(|&k| k < 3 || k == 5), "{c:?}");
        assert!(db
            .relocalisation_candidates(&vector(&[99]), covisible)
            .is_empty());
    }
}
