//! The local map tracking matches against.

use std::collections::HashMap;

use super::Tracking;
use crate::map::Map;

/// Neighbours of each directly covisible keyframe added to the local map.
const LOCAL_NEIGHBOURS: usize = 10;
/// At most this many keyframes in the local map (ORB-SLAM2's 80).
const MAX_LOCAL_KEYFRAMES: usize = 80;

impl Tracking {
    /// The local map: the newest `local_keyframes` keyframes, older ones
    /// that observe points the last frame tracked (ORB-SLAM2's K1, most
    /// shared first), and the strongest covisible neighbours and
    /// spanning-tree parents of all of them; the points they observe
    /// (culled ones left out). Measured on fr1_rpy and the room, adding K1
    /// and the neighbours to the newest keyframes changed no figure (the
    /// camera rarely comes back to points older than 20 keyframes there); it
    /// is what a camera returning to a place after a long way needs.
    pub(super) fn local_points(&self, map: &Map) -> Vec<usize> {
        let mut votes: HashMap<usize, u32> = HashMap::new();
        for &p in &self.last_matched {
            for &k in &map.points[p].observers {
                *votes.entry(k).or_default() += 1;
            }
        }
        let mut direct: Vec<(usize, u32)> = votes.into_iter().collect();
        direct.sort_unstable_by(|a, b| b.1.cmp(&a.1).then(b.0.cmp(&a.0)));
        // The newest keyframes that were not culled.
        let mut local: Vec<usize> = map
            .live_keyframes()
            .rev()
            .take(self.params.local_keyframes)
            .map(|(k, _)| k)
            .collect();
        let first = local.last().copied().unwrap_or(0);
        local.extend(
            direct
                .iter()
                .map(|&(k, _)| k)
                .filter(|&k| k < first)
                .take(LOCAL_NEIGHBOURS),
        );
        let mut in_local = vec![false; map.keyframes.len()];
        for &k in &local {
            in_local[k] = true;
        }
        let mut add = |k: usize, local: &mut Vec<usize>| {
            if local.len() < MAX_LOCAL_KEYFRAMES && !in_local[k] {
                in_local[k] = true;
                local.push(k);
            }
        };
        for i in 0..local.len() {
            let kf = &map.keyframes[local[i]];
            for &(n, _) in kf.covisible.iter().take(LOCAL_NEIGHBOURS) {
                add(n, &mut local);
            }
            if let Some(parent) = kf.parent {
                add(parent, &mut local);
            }
        }
        let mut taken = vec![false; map.points.len()];
        let mut points = Vec::new();
        for &k in &local {
            for &p in &map.keyframes[k].points {
                if !taken[p] && map.points[p].visible > 0 {
                    taken[p] = true;
                    points.push(p);
                }
            }
        }
        // Id order: which of two equally good map points wins a keypoint
        // must not depend on how the local map was gathered.
        points.sort_unstable();
        points
    }
}
