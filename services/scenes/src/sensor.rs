//! What a real RGB-D camera does to a rendered frame: depth noise, holes
//! and quantisation as a Kinect (structured light) or a RealSense (active
//! stereo) makes them, and motion blur over the exposure (the blur is
//! rendered: `room::render_room` averages sub-frames). Rendered frames are
//! otherwise exact, and the things real data has and renders lack were
//! where our measurements on real sequences parted from those on renders
//! (docs/measurements.md).
//!
//! The depth models, per pixel of depth z (metres):
//! - Kinect v1 (Khoshelham and Elberink 2012; Nguyen, Izadi and Lovell
//!   2012): range 0.5-4.5 m; the projector's shadow (7.5 cm baseline) as
//!   holes beside the left of foreground edges; jagged edges (an edge pixel
//!   takes a neighbour's depth half the time); axial noise sigma = 0.0012 +
//!   0.0019 (z - 0.4)^2; disparity quantised to 1/8 pixel at the camera's
//!   focal length; speckle holes (0.2 % of pixels).
//! - RealSense D435 (active stereo, 5 cm baseline): range 0.3-6 m; the
//!   occlusion band beside the left of foreground edges; sigma = 0.08 z^2 /
//!   (f b) (0.08 px subpixel); speckle holes (0.5 %); no quantisation at
//!   this scale.
//!
//! Noise is seeded per frame, so a render is the same on every machine.

use slam_core::rng::SplitMix64;

/// How depth is measured.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum DepthSensor {
    /// The ray cast's depth, rounded to the depth image's units.
    #[default]
    Exact,
    /// A Kinect v1 (structured light), as the module documentation says.
    Kinect,
    /// A RealSense D435 (active stereo), likewise.
    RealSense,
}

/// The camera's imperfections a render gets.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct SensorModel {
    /// The depth camera's noise, holes and quantisation.
    pub depth: DepthSensor,
    /// Exposure time (seconds; 0: no motion blur). Fr1's frames show blur of
    /// several pixels in fast turns: 10-20 ms at the turn rates there.
    pub exposure_s: f64,
}

/// Constants of one depth sensor.
struct DepthProfile {
    min_m: f64,
    max_m: f64,
    /// Between the projector (or second imager) and the depth camera (m).
    baseline_m: f64,
    /// Axial noise sigma (m) at depth z.
    sigma: fn(f64, f64) -> f64,
    /// Disparity quantisation (pixels; 0: none).
    disparity_step_px: f64,
    /// Edge pixels that take a neighbour's depth (probability).
    edge_jitter: f64,
    /// Isolated holes (probability per pixel).
    speckle: f64,
}

fn kinect_sigma(z: f64, _fb: f64) -> f64 {
    0.0012 + 0.0019 * (z - 0.4).powi(2)
}

fn realsense_sigma(z: f64, fb: f64) -> f64 {
    0.08 * z * z / fb
}

const KINECT: DepthProfile = DepthProfile {
    min_m: 0.5,
    max_m: 4.5,
    baseline_m: 0.075,
    sigma: kinect_sigma,
    disparity_step_px: 0.125,
    edge_jitter: 0.5,
    speckle: 0.002,
};

const REALSENSE: DepthProfile = DepthProfile {
    min_m: 0.3,
    max_m: 6.0,
    baseline_m: 0.05,
    sigma: realsense_sigma,
    disparity_step_px: 0.0,
    edge_jitter: 0.3,
    speckle: 0.005,
};

/// Neighbouring depths differing by more than this share are an edge.
const EDGE_STEP: f64 = 0.05;

/// The widest shadow looked for (pixels).
const MAX_SHADOW_PX: usize = 40;

impl DepthSensor {
    fn profile(self) -> Option<&'static DepthProfile> {
        match self {
            Self::Exact => None,
            Self::Kinect => Some(&KINECT),
            Self::RealSense => Some(&REALSENSE),
        }
    }

    /// Degrades `depth` (`w` x `h`, `depth_scale` units per metre, 0: no
    /// depth) as this sensor measures, for a camera of focal length `fx`
    /// (pixels); `seed` makes the noise (one per frame).
    pub fn degrade(
        self,
        depth: &mut [u16],
        (w, h): (usize, usize),
        depth_scale: f64,
        fx: f64,
        seed: u64,
    ) {
        let Some(p) = self.profile() else {
            return;
        };
        let metres: Vec<f64> = depth.iter().map(|&d| d as f64 / depth_scale).collect();
        let mut rng = SplitMix64::new(seed ^ 0x5EB5_0D3E_9F1A_77C1);
        let fb = fx * p.baseline_m;
        let shadowed = shadow(&metres, (w, h), fb);
        for y in 0..h {
            for x in 0..w {
                let i = y * w + x;
                let mut z = metres[i];
                if z <= 0.0 || shadowed[i] || rng.uniform(0.0, 1.0) < p.speckle {
                    depth[i] = 0;
                    continue;
                }
                if rng.uniform(0.0, 1.0) < p.edge_jitter {
                    if let Some(other) = edge_neighbour(&metres, (w, h), (x, y), &mut rng) {
                        z = other;
                    }
                }
                z += (p.sigma)(z, fb) * gaussian(&mut rng);
                if p.disparity_step_px > 0.0 {
                    let d = (fb / z / p.disparity_step_px).round() * p.disparity_step_px;
                    z = if d > 0.0 { fb / d } else { 0.0 };
                }
                let units = (z * depth_scale).round();
                depth[i] = if (p.min_m..=p.max_m).contains(&z) && units < 65535.0 {
                    units as u16
                } else {
                    0
                };
            }
        }
    }
}

/// Pixels the projector (or the second imager, to the right of the depth
/// camera) cannot see: background just left of a nearer surface, as far
/// as the parallax between the two, `fb` (focal length times baseline)
/// times the difference of inverse depths, reaches.
fn shadow(metres: &[f64], (w, h): (usize, usize), fb: f64) -> Vec<bool> {
    let mut out = vec![false; metres.len()];
    for y in 0..h {
        let row = &metres[y * w..(y + 1) * w];
        for x in 0..w {
            let z = row[x];
            if z <= 0.0 {
                continue;
            }
            let reach = (x + 1..(x + 1 + MAX_SHADOW_PX).min(w)).any(|xf| {
                let zf = row[xf];
                zf > 0.0
                    && zf < z * (1.0 - EDGE_STEP)
                    && fb * (1.0 / zf - 1.0 / z) >= (xf - x) as f64
            });
            out[y * w + x] = reach;
        }
    }
    out
}

/// At a depth edge (a 4-neighbour differs by more than [`EDGE_STEP`]), one
/// of those neighbours' depth, picked at random; None off edges.
fn edge_neighbour(
    metres: &[f64],
    (w, h): (usize, usize),
    (x, y): (usize, usize),
    rng: &mut SplitMix64,
) -> Option<f64> {
    let z = metres[y * w + x];
    let mut across = [0.0; 4];
    let mut n = 0;
    let neighbours = [
        (x > 0).then(|| metres[y * w + x - 1]),
        (x + 1 < w).then(|| metres[y * w + x + 1]),
        (y > 0).then(|| metres[(y - 1) * w + x]),
        (y + 1 < h).then(|| metres[(y + 1) * w + x]),
    ];
    for o in neighbours.into_iter().flatten() {
        if o > 0.0 && (o - z).abs() > EDGE_STEP * z {
            across[n] = o;
            n += 1;
        }
    }
    (n > 0).then(|| across[rng.below(n)])
}

/// A standard normal sample (Box-Muller).
fn gaussian(rng: &mut SplitMix64) -> f64 {
    let u1 = rng.uniform(f64::MIN_POSITIVE, 1.0);
    let u2 = rng.uniform(0.0, 1.0);
    (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
}

#[cfg(test)]
mod tests {
    use super::*;

    const SCALE: f64 = 5000.0;

    /// A wall at `far` with a box at `near` in the middle third.
    fn scene(w: usize, h: usize, near: f64, far: f64) -> Vec<u16> {
        (0..w * h)
            .map(|i| {
                let x = i % w;
                let z = if x >= w / 3 && x < 2 * w / 3 {
                    near
                } else {
                    far
                };
                (z * SCALE) as u16
            })
            .collect()
    }

    fn stats(
        depth: &[u16],
        exact: &[u16],
        range: std::ops::Range<usize>,
        w: usize,
    ) -> (f64, f64, f64) {
        let (mut n, mut holes, mut sum, mut sq) = (0.0, 0.0, 0.0, 0.0);
        for (i, (&d, &e)) in depth.iter().zip(exact).enumerate() {
            if !range.contains(&(i % w)) {
                continue;
            }
            n += 1.0;
            if d == 0 {
                holes += 1.0;
                continue;
            }
            let err = (d as f64 - e as f64) / SCALE;
            sum += err;
            sq += err * err;
        }
        let valid = n - holes;
        (
            holes / n,
            sum / valid,
            (sq / valid - (sum / valid).powi(2)).sqrt(),
        )
    }

    #[test]
    fn kinect_noise_grows_with_depth_and_the_shadow_is_left_of_the_box() {
        let (w, h) = (300, 200);
        for (far, sigma) in [(1.5, kinect_sigma(1.5, 0.0)), (3.5, kinect_sigma(3.5, 0.0))] {
            let exact = scene(w, h, 1.0, far);
            let mut depth = exact.clone();
            DepthSensor::Kinect.degrade(&mut depth, (w, h), SCALE, 525.0, 7);
            // The wall right of the box: no shadow there, noise as modelled
            // (quantisation adds a little at 3.5 m: its step is 2.7 cm).
            let (holes, mean, sd) = stats(&depth, &exact, 2 * w / 3 + 5..w, w);
            assert!(holes < 0.05, "holes {holes}");
            assert!(mean.abs() < 0.2 * sigma + 0.002, "mean {mean} at {far} m");
            assert!(
                sd > 0.7 * sigma && sd < 1.6 * sigma + 0.008,
                "sd {sd} vs {sigma} at {far} m"
            );
            // Left of the box: a band of holes as wide as the parallax.
            let band = (525.0 * 0.075 * (1.0 / 1.0 - 1.0 / far)) as usize;
            let (holes, _, _) = stats(&depth, &exact, w / 3 - band + 2..w / 3 - 1, w);
            assert!(
                holes > 0.95,
                "shadow holes {holes} over {band} px at {far} m"
            );
        }
        // Out of range: no depth.
        let mut far = scene(w, h, 5.0, 5.0);
        DepthSensor::Kinect.degrade(&mut far, (w, h), SCALE, 525.0, 7);
        assert!(far.iter().all(|&d| d == 0));
    }

    #[test]
    fn realsense_noise_follows_its_formula_and_exact_changes_nothing() {
        let (w, h) = (300, 200);
        let exact = scene(w, h, 1.0, 3.0);
        let mut depth = exact.clone();
        DepthSensor::RealSense.degrade(&mut depth, (w, h), SCALE, 600.0, 3);
        let sigma = realsense_sigma(3.0, 600.0 * 0.05);
        let (holes, mean, sd) = stats(&depth, &exact, 2 * w / 3 + 5..w, w);
        assert!(
            holes < 0.05 && mean.abs() < 0.2 * sigma,
            "holes {holes} mean {mean}"
        );
        assert!(sd > 0.85 * sigma && sd < 1.15 * sigma, "sd {sd} vs {sigma}");
        let mut same = exact.clone();
        DepthSensor::Exact.degrade(&mut same, (w, h), SCALE, 600.0, 3);
        assert_eq!(same, exact);
        // Seeded: the same frame twice is the same.
        let mut again = exact.clone();
        DepthSensor::RealSense.degrade(&mut again, (w, h), SCALE, 600.0, 3);
        assert_eq!(again, depth);
    }
}
