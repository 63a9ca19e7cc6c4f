//! The RGB-D camera: pinhole intrinsics with OpenCV radial-tangential
//! distortion, registered depth, and the virtual stereo baseline ORB-SLAM2
//! uses to give depth measurements the same form as a right-image
//! coordinate (`ur = u - bf / z`).

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

/// An image extent in pixels: x0, x1, y0, y1.
pub type Bounds = (f64, f64, f64, f64);

/// A pinhole camera with Brown-Conrady distortion and, for RGB-D, the depth camera's virtual stereo baseline.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Camera {
    /// Focal length in pixels, x.
    pub fx: f64,
    /// Focal length in pixels, y.
    pub fy: f64,
    /// Principal point, x (pixels).
    pub cx: f64,
    /// Principal point, y (pixels).
    pub cy: f64,
    /// k1 k2 p1 p2 k3.
    pub dist: [f64; 5],
    /// fx times the virtual baseline (metres * pixels); 40 for TUM as ORB-SLAM2.
    pub bf: f64,
    /// Depth units per metre.
    pub depth_scale: f64,
    /// Rolling-shutter readout, first row to last (seconds; 0: global).
    pub readout_s: f64,
}

impl Camera {
    /// A camera with intrinsics `fx fy cx cy`, distortion `dist` (k1 k2
    /// p1 p2 k3), depth in `depth_scale` units per metre, a rolling
    /// shutter reading out in `readout_s` (0: global shutter) and
    /// ORB-SLAM2's virtual baseline for TUM (bf = 40).
    pub fn new(
        [fx, fy, cx, cy]: [f64; 4],
        dist: [f64; 5],
        depth_scale: f64,
        readout_s: f64,
    ) -> Self {
        Self {
            fx,
            fy,
            cx,
            cy,
            dist,
            bf: 40.0,
            depth_scale,
            readout_s,
        }
    }

    /// TUM RGB-D Freiburg 1 (the calibration the benchmark publishes, its
    /// depth in 5000 units per metre, 18 ms rolling-shutter readout).
    pub fn tum_fr1() -> Self {
        Self::new(
            [517.306408, 516.469215, 318.643040, 255.313989],
            [0.262383, -0.953104, -0.005358, 0.002628, 1.163314],
            5000.0,
            0.018,
        )
    }

    /// Pixel of a distorted image to the ideal pinhole pixel (fixed-point
    /// iterations, OpenCV's `undistortPoints` scheme; 20 reach 0.05 px in
    /// the corners of TUM Freiburg 1's strong distortion).
    pub fn undistort(&self, u: f64, v: f64) -> (f64, f64) {
        let [k1, k2, p1, p2, k3] = self.dist;
        if self.dist.iter().all(|&d| d == 0.0) {
            return (u, v);
        }
        let (xd, yd) = ((u - self.cx) / self.fx, (v - self.cy) / self.fy);
        let (mut x, mut y) = (xd, yd);
        for _ in 0..20 {
            let r2 = x * x + y * y;
            let radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
            let dx = 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x);
            let dy = p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y;
            x = (xd - dx) / radial;
            y = (yd - dy) / radial;
        }
        (x * self.fx + self.cx, y * self.fy + self.cy)
    }

    /// Extent of a `width x height` image after undistortion (x0, x1, y0,
    /// y1), from its corners as ORB-SLAM2's `ComputeImageBounds`: map points
    /// projecting outside it cannot be in view.
    pub fn undistorted_bounds(&self, width: usize, height: usize) -> Bounds {
        let (w, h) = (width as f64, height as f64);
        let corners = [(0.0, 0.0), (w, 0.0), (0.0, h), (w, h)].map(|(u, v)| self.undistort(u, v));
        (
            corners[0].0.min(corners[2].0),
            corners[1].0.max(corners[3].0),
            corners[0].1.min(corners[1].1),
            corners[2].1.max(corners[3].1),
        )
    }

    /// Distorts an ideal pixel (the forward model).
    pub fn distort(&self, u: f64, v: f64) -> (f64, f64) {
        let [k1, k2, p1, p2, k3] = self.dist;
        let (x, y) = ((u - self.cx) / self.fx, (v - self.cy) / self.fy);
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
        let xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x);
        let yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y;
        (xd * self.fx + self.cx, yd * self.fy + self.cy)
    }

    /// The pixel where a point in the camera frame lands (pinhole, no distortion: undistorted keypoints are compared with it).
    pub fn project(&self, p: &Vector3<f64>) -> (f64, f64) {
        (self.fx * p.x / p.z + self.cx, self.fy * p.y / p.z + self.cy)
    }

    /// The 3D point (camera frame) at ideal pixel (u, v) and depth z.
    pub fn unproject(&self, u: f64, v: f64, z: f64) -> Vector3<f64> {
        Vector3::new((u - self.cx) * z / self.fx, (v - self.cy) * z / self.fy, z)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn undistort_inverts_distort_over_the_image() {
        let cam = Camera::tum_fr1();
        for (u, v) in [(10.0, 10.0), (320.0, 240.0), (630.0, 470.0), (100.0, 400.0)] {
            let (ud, vd) = cam.distort(u, v);
            let (uu, vv) = cam.undistort(ud, vd);
            assert!(
                (uu - u).abs() < 0.05 && (vv - v).abs() < 0.05,
                "{u},{v} -> {uu},{vv}"
            );
        }
    }
}
