//! Local mapping's culling (ORB-SLAM2's rules): recent points that are
//! rarely found or that too few keyframes confirm stop being matched, and
//! keyframes whose close points others measure as well go.

use std::collections::HashMap;

use crate::map::Map;

/// A keyframe goes when this share of its close points is seen by at least
/// `REDUNDANT_OBSERVERS` other keyframes at the same or a finer scale
/// (ORB-SLAM2's 90 % and 3).
const REDUNDANT_SHARE: f64 = 0.9;
const REDUNDANT_OBSERVERS: usize = 3;
/// A triangulated point must be measured by this many keyframes two
/// keyframes after its creation, or it goes (ORB-SLAM2's recent-point rule:
/// a point only its two creators agree on is likely a wrong match).
const TRIANGULATED_MIN_OBSERVERS: usize = 3;

impl Map {
    /// Recent-point culling when keyframe `id` arrives: points seen in
    /// under a quarter of the frames that should have seen them stop being
    /// matched, and so do triangulated points that two keyframes later fewer
    /// than `TRIANGULATED_MIN_OBSERVERS` keyframes measure.
    pub(super) fn cull_points(&mut self, id: usize) {
        let mut culled = Vec::new();
        for (i, p) in self.points.iter_mut().enumerate() {
            if !p.is_live() {
                continue;
            }
            let rarely_found = p.visible >= 20 && (p.found as f64) < 0.25 * p.visible as f64;
            let unconfirmed = match p.triangulated_in {
                Some(k) if id >= k + 2 => {
                    p.triangulated_in = None;
                    p.observers.len() < TRIANGULATED_MIN_OBSERVERS
                }
                _ => false,
            };
            if rarely_found || unconfirmed {
                culled.push(i);
            }
        }
        for p in culled {
            self.cull_point(p);
        }
    }

    /// Keyframe culling (ORB-SLAM2's rule) among the neighbours of `id`:
    /// a keyframe most of whose close points (those with depth) are
    /// measured by at least three other keyframes at the same or a finer
    /// pyramid level (`scale_factor`: the pyramid's step) adds nothing to
    /// the map and goes. The first keyframe (it defines the world), `id`
    /// itself and keyframes with loop edges stay.
    pub(super) fn cull_keyframes(&mut self, id: usize, scale_factor: f64) {
        let candidates: Vec<usize> = self.keyframes[id]
            .covisible
            .iter()
            .map(|&(k, _)| k)
            .filter(|&k| k != 0 && k != id && self.keyframes[k].loops.is_empty())
            .collect();
        // How each keyframe measured each point (info = 1 / sigma^2 of its
        // level), built for the keyframes consulted.
        let mut measured: HashMap<usize, HashMap<usize, f64>> = HashMap::new();
        for k in candidates {
            if self.keyframes[k].culled {
                continue;
            }
            let (mut close, mut redundant) = (0usize, 0usize);
            let kf = &self.keyframes[k];
            for (&p, m) in kf.points.iter().zip(&kf.measurements) {
                if m.ur.is_none() || self.points[p].visible == 0 {
                    continue;
                }
                close += 1;
                let observers = &self.points[p].observers;
                if observers.len() <= REDUNDANT_OBSERVERS {
                    continue;
                }
                let mut others = 0;
                for &o in observers.iter().filter(|&&o| o != k) {
                    let info = measured
                        .entry(o)
                        .or_insert_with(|| {
                            let other = &self.keyframes[o];
                            other
                                .points
                                .iter()
                                .zip(&other.measurements)
                                .map(|(&q, m)| (q, m.info))
                                .collect()
                        })
                        .get(&p)
                        .copied()
                        .unwrap_or(0.0);
                    // Same or finer level: sigma at most one level larger.
                    if info * scale_factor * scale_factor >= m.info * (1.0 - 1e-9) {
                        others += 1;
                        if others >= REDUNDANT_OBSERVERS {
                            break;
                        }
                    }
                }
                if others >= REDUNDANT_OBSERVERS {
                    redundant += 1;
                }
            }
            if close > 0 && redundant as f64 > REDUNDANT_SHARE * close as f64 {
                self.cull_keyframe(k);
                measured.remove(&k);
            }
        }
    }
}
