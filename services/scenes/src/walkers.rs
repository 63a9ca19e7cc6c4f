//! Where each person is: walks fixed in the world, across the view of the
//! sequence's first camera pose, back and forth at walking speed.
//!
//! The stage is the first camera's frame: `forward` its optical axis, `right`
//! its x axis, `up` its -y axis (cameras are held roughly level at the
//! start). A walker keeps a distance in front of the first camera (swaying
//! slowly nearer and farther) and walks along `right` between two turning
//! points outside the view, so people enter, cross and leave
//! ([`Behaviour::Across`], every walker by default). With
//! [`Behaviours::Mixed`] the people take turns at three behaviours: across,
//! toward and away from the camera (along `forward`, inside the view), and
//! across with stops (standing still between stretches of walking).

use nalgebra::{Isometry3, Point3, Vector3};
use serde::Serialize;

use slam_core::rng::SplitMix64;

/// The world frame the walks are laid out in.
#[derive(Debug, Clone, Copy)]
pub struct Stage {
    /// The camera's centre (world).
    pub origin: Point3<f64>,
    /// Across the view (world unit vector).
    pub right: Vector3<f64>,
    /// Up (world unit vector).
    pub up: Vector3<f64>,
    /// Away from the camera (world unit vector).
    pub forward: Vector3<f64>,
}

impl Stage {
    /// The stage of a camera pose (world from camera).
    pub fn from_camera(pose: &Isometry3<f64>) -> Self {
        Self {
            origin: Point3::from(pose.translation.vector),
            right: pose.rotation * Vector3::x(),
            up: -(pose.rotation * Vector3::y()),
            forward: pose.rotation * Vector3::z(),
        }
    }
}

/// How one walker moves.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Behaviour {
    /// Back and forth along `right`, turning outside the view.
    Across,
    /// Back and forth along `forward` between its distance and twice the
    /// farthest, at a fixed place across the view.
    TowardAway,
    /// [`Self::Across`], standing still for [`STOP_S`] after every
    /// [`WALK_S`] of walking.
    StopAndGo,
}

/// Stop-and-go: seconds of walking, then of standing.
pub const WALK_S: f64 = 2.0;
/// Stop-and-go: seconds of standing after each walk.
pub const STOP_S: f64 = 1.5;

/// Which behaviours a scene's people take.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Behaviours {
    /// Everyone walks across (what sequences were made with before).
    #[default]
    Across,
    /// Person k takes across, toward-away, stop-and-go for k = 0, 1, 2, ...
    /// (boxes always go across).
    Mixed,
}

/// What walks.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Kind {
    /// A person: in the ground-truth masks (`masks/`), what a segmenter
    /// should find.
    Person,
    /// A carried box: in `movers/` only, what no class list names (the
    /// SLAM's motion check should find it).
    Box,
}

/// Height of a carried box in the world (metres).
pub const BOX_HEIGHT_M: f64 = 0.4;

/// One person's (or box's) walk.
#[derive(Debug, Clone, Serialize)]
pub struct Walker {
    /// Instance id in the ground-truth masks (1..=255).
    pub id: u8,
    /// A person or a box.
    pub kind: Kind,
    /// How it moves.
    pub behaviour: Behaviour,
    /// Toward-away: where across the view (metres along `right`).
    pub lateral_m: f64,
    /// Toward-away: the far turning point (metres in front).
    pub far_m: f64,
    /// Index into the sprites.
    pub sprite: usize,
    /// Height of the cut-out in the world (metres).
    pub height_m: f64,
    /// Metres in front of the first camera.
    pub distance_m: f64,
    /// Turning points at +-half_span_m along `right`.
    pub half_span_m: f64,
    /// Walking speed, metres per second.
    pub speed_mps: f64,
    /// Start position along the back-and-forth loop (metres).
    pub phase_m: f64,
    /// Height of the person's centre relative to the first camera (metres).
    pub height_offset_m: f64,
    /// Amplitude and period of the slow sway in distance.
    pub sway_m: f64,
    /// Period of the sway, seconds.
    pub sway_period_s: f64,
}

/// A walker's state at one time.
#[derive(Debug, Clone, Copy)]
pub struct WalkerState {
    /// The person's centre, world coordinates.
    pub centre: Point3<f64>,
    /// Walking towards -right (the cut-out is mirrored to face its way).
    pub leftwards: bool,
}

/// What hides a person besides other people.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Occlusion {
    /// The scene hides a person where its depth is nearer: people walk
    /// through the scene's geometry, so a walk that crosses furniture
    /// shows only what sticks out of it (a head above a desk).
    Scene,
    /// People pass between the camera and the scene: always drawn whole
    /// (cut only by the image border and nearer people), in front of what
    /// they cover: the depth channel holds the person's distance, or where
    /// that is behind the nearest surface it covers, a little in front of
    /// that surface (`composite::IN_FRONT`).
    None,
}

/// What a scene asks for.
#[derive(Debug, Clone, Serialize)]
pub struct WalkOptions {
    /// People to walk.
    pub objects: usize,
    /// Carried boxes besides the people (ids after theirs).
    #[serde(default)]
    pub boxes: usize,
    /// Walking speed, metres per second.
    pub speed_mps: f64,
    /// Nearest distance from the first camera, metres.
    pub near_m: f64,
    /// Farthest distance from the first camera, metres.
    pub far_m: f64,
    /// Height of the person cut-out in the world (metres).
    pub height_m: f64,
    /// Seeds the walks (same seed, same scene).
    pub seed: u64,
    /// Whether the scene's depth hides people.
    pub occlusion: Occlusion,
    /// Which behaviours the people take.
    #[serde(default)]
    pub behaviours: Behaviours,
}

impl Default for WalkOptions {
    fn default() -> Self {
        Self {
            objects: 2,
            boxes: 0,
            speed_mps: 1.0,
            near_m: 0.7,
            far_m: 1.4,
            height_m: 0.75,
            seed: 1,
            occlusion: Occlusion::Scene,
            behaviours: Behaviours::Across,
        }
    }
}

impl WalkOptions {
    /// Checks the options' ranges; the error names the option.
    pub fn validate(&self) -> Result<(), String> {
        if self.objects + self.boxes == 0 || self.objects + self.boxes > 255 {
            return Err(format!(
                "--objects {} --boxes {}: together must be 1..=255",
                self.objects, self.boxes
            ));
        }
        if !(self.speed_mps.is_finite() && self.speed_mps > 0.0 && self.speed_mps <= 10.0) {
            return Err(format!(
                "--speed {}: must be in (0, 10] m/s",
                self.speed_mps
            ));
        }
        if !(self.near_m.is_finite()
            && self.near_m >= 0.3
            && self.far_m >= self.near_m
            && self.far_m <= 20.0)
        {
            return Err(format!(
                "--near {} / --far {}: need 0.3 <= near <= far <= 20 metres",
                self.near_m, self.far_m
            ));
        }
        if !(self.height_m.is_finite() && self.height_m > 0.1 && self.height_m <= 3.0) {
            return Err(format!(
                "--height {}: must be in (0.1, 3] metres",
                self.height_m
            ));
        }
        Ok(())
    }
}

/// Draws the walkers for `options` (deterministic for the seed): the
/// people (sprites `0..aspects.len()`, cycled), then the boxes (sprite
/// `aspects.len()`, square). `half_fov_tan` is the tangent of the
/// horizontal half field of view and `aspects` the width/height of each
/// person sprite.
pub fn walkers(options: &WalkOptions, half_fov_tan: f64, aspects: &[f64]) -> Vec<Walker> {
    let mut rng = SplitMix64::new(options.seed);
    let total = options.objects + options.boxes;
    (0..total)
        .map(|k| {
            let person = k < options.objects;
            let (kind, sprite, height_m, aspect) = if person {
                let sprite = k % aspects.len();
                (Kind::Person, sprite, options.height_m, aspects[sprite])
            } else {
                (Kind::Box, aspects.len(), BOX_HEIGHT_M, 1.0)
            };
            // Spread distances over the range so that crowds overlap in depth.
            let slot = (k as f64 + rng.uniform(0.0, 1.0)) / total as f64;
            let distance_m = options.near_m + (options.far_m - options.near_m) * slot;
            let half_width = 0.5 * height_m * aspect;
            let half_span_m = (distance_m + options.far_m * 0.2) * half_fov_tan + half_width + 0.3;
            let behaviour = match options.behaviours {
                Behaviours::Mixed if person => [
                    Behaviour::Across,
                    Behaviour::TowardAway,
                    Behaviour::StopAndGo,
                ][k % 3],
                _ => Behaviour::Across,
            };
            // Toward-away keeps inside the middle half of the view at its
            // nearest point. Drawn from a stream of its own, so that scenes
            // made before behaviours existed come out the same.
            let mut own =
                SplitMix64::new(options.seed ^ 0xb3ba_7105_u64.wrapping_mul(k as u64 + 1));
            let lateral_m = own.uniform(-0.5, 0.5) * options.near_m * half_fov_tan;
            Walker {
                id: (k + 1) as u8,
                kind,
                behaviour,
                lateral_m,
                far_m: 2.0 * options.far_m,
                sprite,
                height_m,
                distance_m,
                half_span_m,
                speed_mps: options.speed_mps * rng.uniform(0.8, 1.2),
                phase_m: rng.uniform(0.0, 4.0 * half_span_m),
                height_offset_m: rng.uniform(-0.3, 0.0),
                sway_m: rng.uniform(0.0, 0.2 * distance_m),
                sway_period_s: rng.uniform(4.0, 9.0),
            }
        })
        .collect()
}

impl Walker {
    /// Where the walker is `t` seconds after the sequence start.
    pub fn state(&self, stage: &Stage, t: f64) -> WalkerState {
        // Time spent walking (a stop-and-go walker stands between stretches).
        let walked = match self.behaviour {
            Behaviour::StopAndGo => {
                let cycle = WALK_S + STOP_S;
                (t / cycle).floor() * WALK_S + (t.rem_euclid(cycle)).min(WALK_S)
            }
            _ => t,
        };
        let sway = self.sway_m * (2.0 * std::f64::consts::PI * walked / self.sway_period_s).sin();
        let (lateral, distance, leftwards) = match self.behaviour {
            Behaviour::TowardAway => {
                let (near, far) = (self.distance_m.min(self.far_m), self.far_m);
                let span = far - near;
                let s = (self.phase_m + self.speed_mps * walked).rem_euclid(2.0 * span.max(1e-9));
                let distance = if s < span { far - s } else { near + (s - span) };
                (self.lateral_m, distance, self.id.is_multiple_of(2))
            }
            Behaviour::Across | Behaviour::StopAndGo => {
                let span = 2.0 * self.half_span_m;
                let s = (self.phase_m + self.speed_mps * walked).rem_euclid(2.0 * span);
                let (lateral, leftwards) = if s < span {
                    (-self.half_span_m + s, false)
                } else {
                    (self.half_span_m - (s - span), true)
                };
                (lateral, self.distance_m + sway, leftwards)
            }
        };
        // A walker's centre bobs about 2 cm at step frequency (about 1.8 Hz).
        let bob = 0.02 * (2.0 * std::f64::consts::PI * 1.8 * walked).sin();
        let centre = stage.origin
            + stage.forward * distance
            + stage.right * lateral
            + stage.up * (self.height_offset_m + bob);
        WalkerState { centre, leftwards }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn stage() -> Stage {
        Stage::from_camera(&Isometry3::identity())
    }

    #[test]
    fn walks_back_and_forth_at_the_given_speed() {
        let opts = WalkOptions {
            objects: 3,
            ..Default::default()
        };
        let ws = walkers(&opts, 0.62, &[0.7, 0.65]);
        assert_eq!(ws.len(), 3);
        for w in &ws {
            assert!((0.8..=1.2).contains(&w.speed_mps));
            assert!((opts.near_m..=opts.far_m).contains(&w.distance_m));
            // Lateral speed matches the walking speed away from the turns.
            let dt = 0.01;
            let mut fast = 0;
            for i in 0..1000 {
                let t = i as f64 * 0.05;
                let (a, b) = (w.state(&stage(), t), w.state(&stage(), t + dt));
                let lateral = (b.centre.x - a.centre.x).abs() / dt;
                if (lateral - w.speed_mps).abs() < 1e-6 {
                    fast += 1;
                }
                assert!(b.centre.x.abs() <= w.half_span_m + 1e-9);
            }
            assert!(fast > 950, "{fast}");
        }
    }

    #[test]
    fn mixed_behaviours_walk_toward_and_away_and_stop() {
        let opts = WalkOptions {
            objects: 3,
            boxes: 1,
            behaviours: Behaviours::Mixed,
            ..Default::default()
        };
        let ws = walkers(&opts, 0.62, &[0.7, 0.65]);
        let kinds: Vec<_> = ws.iter().map(|w| w.behaviour).collect();
        assert_eq!(
            kinds,
            [
                Behaviour::Across,
                Behaviour::TowardAway,
                Behaviour::StopAndGo,
                Behaviour::Across
            ]
        );
        let at = |w: &Walker, t: f64| w.state(&stage(), t).centre;
        // Toward-away: one place across the view, from its distance to
        // twice the farthest, at walking speed.
        let w = &ws[1];
        let (mut nearest, mut farthest) = (f64::MAX, f64::MIN);
        for i in 0..2000 {
            let c = at(w, i as f64 * 0.01);
            assert!((c.x - w.lateral_m).abs() < 1e-9);
            nearest = nearest.min(c.z);
            farthest = farthest.max(c.z);
        }
        assert!(nearest < w.distance_m + 0.05 && farthest > 2.0 * opts.far_m - 0.05);
        let at_speed = (0..1000)
            .filter(|&i| {
                let t = i as f64 * 0.05;
                ((at(w, t + 0.01).z - at(w, t).z).abs() / 0.01 - w.speed_mps).abs() < 1e-6
            })
            .count();
        assert!(at_speed > 900, "{at_speed} of 1000 steps at walking speed");
        // Stop-and-go: stands still (bob included) for STOP_S after WALK_S.
        let w = &ws[2];
        let standing = (at(w, WALK_S + 0.2) - at(w, WALK_S + STOP_S - 0.2)).norm();
        assert!(standing < 1e-9, "moved {standing} m while standing");
        let walking = (at(w, 0.2) - at(w, 1.2)).norm();
        assert!(
            walking > 0.5 * w.speed_mps,
            "walked {walking} m in a second"
        );
        // Default: everyone across, as before.
        let across = walkers(&WalkOptions::default(), 0.62, &[0.7]);
        assert!(across.iter().all(|w| w.behaviour == Behaviour::Across));
    }

    #[test]
    fn same_seed_same_walks_other_seed_other_walks() {
        let opts = WalkOptions::default();
        let a = walkers(&opts, 0.62, &[0.7]);
        let b = walkers(&opts, 0.62, &[0.7]);
        let c = walkers(
            &WalkOptions {
                seed: 2,
                ..opts.clone()
            },
            0.62,
            &[0.7],
        );
        assert_eq!(format!("{a:?}"), format!("{b:?}"));
        assert_ne!(format!("{a:?}"), format!("{c:?}"));
    }

    #[test]
    fn bad_options_name_the_flag() {
        let bad = WalkOptions {
            speed_mps: 0.0,
            ..Default::default()
        };
        assert!(bad.validate().unwrap_err().contains("--speed"));
        let bad = WalkOptions {
            near_m: 3.0,
            far_m: 2.0,
            ..Default::default()
        };
        assert!(bad.validate().unwrap_err().contains("--near"));
        assert!(WalkOptions::default().validate().is_ok());
    }
}
