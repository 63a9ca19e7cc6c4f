//! Timestamped pose trajectories in the TUM format
//! (`timestamp tx ty tz qx qy qz qw`, world-from-camera).

use std::path::{Path, PathBuf};

use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion};

/// A trajectory: poses with their timestamps, in file order.
#[derive(Debug, Clone, PartialEq)]
pub struct Trajectory {
    /// Timestamps (seconds), one per pose.
    pub stamps: Vec<f64>,
    /// World-from-camera poses.
    pub poses: Vec<Isometry3<f64>>,
}

/// Why a TUM trajectory file could not be read.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum TrajectoryError {
    /// The file could not be read.
    #[error("{path}: cannot read: {message}")]
    Unreadable {
        /// The file.
        path: PathBuf,
        /// Why.
        message: String,
    },
    /// A line that is not `timestamp tx ty tz qx qy qz qw`.
    #[error("{path} line {line}: {message}")]
    BadLine {
        /// The file.
        path: PathBuf,
        /// The line number (from 1).
        line: usize,
        /// What is wrong with it.
        message: String,
    },
    /// No pose in the file.
    #[error("{path}: contains no poses")]
    Empty {
        /// The file.
        path: PathBuf,
    },
}

impl Trajectory {
    /// Number of poses.
    pub fn len(&self) -> usize {
        self.poses.len()
    }

    /// No poses.
    pub fn is_empty(&self) -> bool {
        self.poses.is_empty()
    }

    /// Parses TUM text; `path` only names the source in errors. Comment
    /// lines start with '#'; commas are accepted as separators too.
    pub fn parse_tum(text: &str, path: &Path) -> Result<Self, TrajectoryError> {
        let mut stamps = Vec::new();
        let mut poses = Vec::new();
        for (i, raw) in text.lines().enumerate() {
            let line = raw.trim();
            if line.is_empty() || line.starts_with('#') {
                continue;
            }
            let bad = |message: String| TrajectoryError::BadLine {
                path: path.to_path_buf(),
                line: i + 1,
                message,
            };
            let fields: Vec<&str> = line
                .split(|c: char| c.is_whitespace() || c == ',')
                .filter(|f| !f.is_empty())
                .collect();
            if fields.len() != 8 {
                return Err(bad(format!(
                    "expected 8 values 'timestamp tx ty tz qx qy qz qw', found {}",
                    fields.len()
                )));
            }
            let mut v = [0.0f64; 8];
            for (k, f) in fields.iter().enumerate() {
                v[k] = f
                    .parse::<f64>()
                    .ok()
                    .filter(|x| x.is_finite())
                    .ok_or_else(|| bad(format!("'{f}' is not a finite number")))?;
            }
            let q = Quaternion::new(v[7], v[4], v[5], v[6]);
            if q.norm() < 1e-6 {
                return Err(bad("quaternion has zero length".into()));
            }
            stamps.push(v[0]);
            poses.push(Isometry3::from_parts(
                Translation3::new(v[1], v[2], v[3]),
                UnitQuaternion::from_quaternion(q),
            ));
        }
        if poses.is_empty() {
            return Err(TrajectoryError::Empty {
                path: path.to_path_buf(),
            });
        }
        Ok(Self { stamps, poses })
    }

    /// Reads a TUM trajectory (`timestamp tx ty tz qx qy qz qw` per line, `#` comments).
    pub fn load_tum(path: &Path) -> Result<Self, TrajectoryError> {
        let text = std::fs::read_to_string(path).map_err(|e| TrajectoryError::Unreadable {
            path: path.to_path_buf(),
            message: e.to_string(),
        })?;
        Self::parse_tum(&text, path)
    }

    /// The pose at time `t`: linear in translation and spherical-linear in
    /// rotation between the two bracketing poses (stamps must be sorted);
    /// `None` outside the trajectory's time span by more than `tolerance` s
    /// (inside the tolerance the end pose is used).
    pub fn interpolate(&self, t: f64, tolerance: f64) -> Option<Isometry3<f64>> {
        let (first, last) = (*self.stamps.first()?, *self.stamps.last()?);
        if t <= first {
            return (first - t <= tolerance).then(|| self.poses[0]);
        }
        if t >= last {
            return (t - last <= tolerance).then(|| self.poses[self.len() - 1]);
        }
        let hi = self.stamps.partition_point(|&s| s <= t);
        let (a, b) = (&self.poses[hi - 1], &self.poses[hi]);
        let span = self.stamps[hi] - self.stamps[hi - 1];
        let f = if span > 0.0 {
            (t - self.stamps[hi - 1]) / span
        } else {
            0.0
        };
        let translation = a.translation.vector.lerp(&b.translation.vector, f);
        let rotation = a.rotation.slerp(&b.rotation, f);
        Some(Isometry3::from_parts(translation.into(), rotation))
    }

    /// TUM text: a header comment, then `timestamp tx ty tz qx qy qz qw`
    /// per pose (the format `parse_tum` reads and evo expects).
    pub fn to_tum(&self) -> String {
        let mut out = String::from("# timestamp tx ty tz qx qy qz qw\n");
        for (t, p) in self.stamps.iter().zip(&self.poses) {
            let (v, q) = (p.translation.vector, p.rotation);
            out.push_str(&format!(
                "{t:.6} {:.7} {:.7} {:.7} {:.7} {:.7} {:.7} {:.7}\n",
                v.x, v.y, v.z, q.i, q.j, q.k, q.w
            ));
        }
        out
    }

    /// The trajectory keeping only the poses at `ids`.
    pub fn select(&self, ids: &[usize]) -> Self {
        Self {
            stamps: ids.iter().map(|&i| self.stamps[i]).collect(),
            poses: ids.iter().map(|&i| self.poses[i]).collect(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_tum_lines_and_comments() {
        let t = Trajectory::parse_tum(
            "# ground truth\n1.0 1 2 3 0 0 0 1\n2.0,4,5,6,0,0,0.7071068,0.7071068\n",
            Path::new("gt.txt"),
        )
        .unwrap();
        assert_eq!(t.len(), 2);
        assert_eq!(t.poses[0].translation.vector.z, 3.0);
        let angle = t.poses[1].rotation.angle();
        assert!((angle - std::f64::consts::FRAC_PI_2).abs() < 1e-6);
    }

    #[test]
    fn tum_text_round_trips() {
        let t = Trajectory::parse_tum(
            "1.5 1 2 3 0 0 0.7071068 0.7071068\n2.25 4 5 6 0 0 0 1\n",
            Path::new("a"),
        )
        .unwrap();
        let back = Trajectory::parse_tum(&t.to_tum(), Path::new("b")).unwrap();
        assert_eq!(back.stamps, t.stamps);
        for (a, b) in back.poses.iter().zip(&t.poses) {
            assert!((a.translation.vector - b.translation.vector).norm() < 1e-6);
            assert!(a.rotation.angle_to(&b.rotation) < 1e-6);
        }
    }

    #[test]
    fn interpolates_between_and_clamps_near_the_ends() {
        let t = Trajectory::parse_tum(
            "1.0 0 0 0 0 0 0 1\n2.0 2 0 0 0 0 0.7071068 0.7071068\n",
            Path::new("gt.txt"),
        )
        .unwrap();
        let mid = t.interpolate(1.5, 0.01).unwrap();
        assert!((mid.translation.vector.x - 1.0).abs() < 1e-9);
        assert!((mid.rotation.angle() - std::f64::consts::FRAC_PI_4).abs() < 1e-6);
        assert_eq!(t.interpolate(0.995, 0.01).unwrap(), t.poses[0]);
        assert!(t.interpolate(0.9, 0.01).is_none());
        assert!(t.interpolate(2.1, 0.01).is_none());
    }

    #[test]
    fn random_trajectories_are_errors_or_values_never_panics() {
        for text in datasets::fuzz::texts(13, 3000) {
            if let Err(e) = Trajectory::parse_tum(&text, Path::new("t.txt")) {
                assert!(e.to_string().starts_with("t.txt"), "{e}");
            }
        }
    }

    #[test]
    fn errors_name_file_and_line() {
        let err = Trajectory::parse_tum("1 2 3\n", Path::new("est.txt")).unwrap_err();
        assert_eq!(
            err.to_string(),
            "est.txt line 1: expected 8 values 'timestamp tx ty tz qx qy qz qw', found 3"
        );
        let err = Trajectory::parse_tum("# x\n1 0 0 0 0 0 0 nan\n", Path::new("e")).unwrap_err();
        assert!(err.to_string().contains("line 2"), "{err}");
        let err = Trajectory::parse_tum("1 0 0 0 0 0 0 0\n", Path::new("e")).unwrap_err();
        assert!(err.to_string().contains("zero length"), "{err}");
        assert!(matches!(
            Trajectory::parse_tum("# none\n", Path::new("e")),
            Err(TrajectoryError::Empty { .. })
        ));
    }
}
