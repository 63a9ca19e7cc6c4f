//! Which pixel kernels the extractor runs: SSE2 intrinsics on x86-64 (every
//! x86-64 CPU has SSE2, so nothing needs detecting at run time), portable
//! Rust elsewhere (aarch64 included: the compiler vectorises what it can).
//! `DYNSLAM_SIMD=off` forces the portable kernels on x86-64 too, to check
//! them on a desktop or to rule the intrinsics out when chasing a bug. Both
//! give the same keypoints and descriptors, bit for bit (unit-tested on real
//! frames).

use std::sync::OnceLock;

/// The environment variable that turns the intrinsics off.
pub const SIMD_ENV: &str = "DYNSLAM_SIMD";

/// Which set of kernels FAST and BRIEF run (picked once per process from the CPU and `DYNSLAM_SIMD`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kernels {
    /// Plain Rust, on every CPU.
    Portable,
    /// `std::arch` SSE2 (x86-64's baseline).
    #[cfg(target_arch = "x86_64")]
    Sse2,
}

impl Kernels {
    /// The kernels this process uses: the fastest this CPU has unless
    /// `DYNSLAM_SIMD=off`; decided once.
    pub fn selected() -> Self {
        static SELECTED: OnceLock<Kernels> = OnceLock::new();
        *SELECTED.get_or_init(|| {
            let setting = std::env::var(SIMD_ENV).ok();
            let (kernels, problem) = Self::from_setting(setting.as_deref());
            if let Some(problem) = problem {
                tracing::warn!("{problem}");
            }
            kernels
        })
    }

    /// The kernels a `DYNSLAM_SIMD` value asks for, and what was wrong
    /// with it (an unknown value keeps the default: a typo must not slow a
    /// robot down, but it is said).
    pub fn from_setting(setting: Option<&str>) -> (Self, Option<String>) {
        match setting.map(str::trim) {
            None | Some("" | "on" | "1" | "auto") => (Self::fastest(), None),
            Some("off" | "0" | "portable") => (Self::Portable, None),
            Some(other) => (
                Self::fastest(),
                Some(format!(
                    "{SIMD_ENV}={other}: expected `off` (portable kernels) or `on`; using {:?}",
                    Self::fastest()
                )),
            ),
        }
    }

    /// The fastest kernels this build and CPU run.
    pub fn fastest() -> Self {
        #[cfg(target_arch = "x86_64")]
        return Self::Sse2;
        #[cfg(not(target_arch = "x86_64"))]
        return Self::Portable;
    }

    /// Every kernel set this build has (tests compare them).
    pub fn all() -> Vec<Self> {
        let mut all = vec![Self::Portable];
        if Self::fastest() != Self::Portable {
            all.push(Self::fastest());
        }
        all
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_setting_picks_the_kernels_and_names_a_bad_value() {
        assert_eq!(Kernels::from_setting(None), (Kernels::fastest(), None));
        assert_eq!(Kernels::from_setting(Some("off")).0, Kernels::Portable);
        assert_eq!(Kernels::from_setting(Some(" 0 ")).0, Kernels::Portable);
        let (kernels, problem) = Kernels::from_setting(Some("avx9"));
        assert_eq!(kernels, Kernels::fastest());
        assert!(problem.unwrap().contains("DYNSLAM_SIMD=avx9"));
    }
}
