//! The camera's turn between two frames from their small, blurred images
//! (PTAM's "small blurry image" alignment): a prediction of the rotation
//! that does not assume the turn goes on as before. A hand-held camera
//! reverses its turn within a tenth of a second; where frames are left out
//! (real time on a busy machine) the constant-velocity model then puts the
//! map points further from their keypoints than tracking's search radius.
//!
//! Each image is averaged down by 8 (and that by 2 more) and blurred; the
//! rotation (and a brightness offset) that warps the older image onto the
//! newer is found by Gauss-Newton on the photometric error, coarse to fine,
//! from the motion model's rotation. Translation is left to the motion
//! model: at this size the turn is what moves the image. Pixels of the
//! dynamic mask (in either image, grown by the blur) take no part: people
//! walking across the view would pull the turn their way.

use nalgebra::{Matrix4, UnitQuaternion, Vector3, Vector4};

use crate::camera::Camera;
use crate::features::orb::GrayU8;

/// Downsampling factors of the two levels, coarse first.
const FACTORS: [usize; 2] = [16, 8];
/// Gauss-Newton steps at most per level, coarse first (about 0.3 ms for
/// both on the 2-core machine; fewer at the fine level, [10, 4], relocalised
/// one frame more in `tests/frames_left_out.rs`).
const ITERATIONS: [usize; 2] = [12, 12];
/// Huber threshold of the photometric error (grey levels).
const HUBER: f32 = 12.0;

/// One level: the image averaged down and blurred, its gradients and the
/// pinhole camera at that size.
#[derive(Clone)]
struct Level {
    width: usize,
    height: usize,
    data: Vec<f32>,
    gx: Vec<f32>,
    gy: Vec<f32>,
    /// False where the dynamic mask (grown by a pixel) covers the pixel.
    valid: Vec<bool>,
    fx: f64,
    fy: f64,
    cx: f64,
    cy: f64,
}

/// A frame's small images, with gradients and mask (about 80 KB for
/// 640x480).
#[derive(Clone)]
pub struct SmallImage {
    levels: Vec<Level>,
}

impl SmallImage {
    /// `mask`: the frame's labels (non-zero: a dynamic object), one per
    /// pixel of `gray`.
    pub fn new(gray: &GrayU8, mask: Option<&[u8]>, camera: &Camera) -> Self {
        // One pass over the full image at the fine factor; the coarse level
        // averages that by 2x2.
        let fine = FACTORS[1];
        let (width, height) = (gray.width / fine, gray.height / fine);
        let mut sums = vec![0u32; width * height];
        let mut masked = vec![false; width * height];
        let mask = mask.filter(|m| m.len() == gray.width * gray.height);
        for y in 0..height * fine {
            let row = &gray.data[y * gray.width..][..width * fine];
            let out = &mut sums[(y / fine) * width..][..width];
            for (sum, block) in out.iter_mut().zip(row.chunks_exact(fine)) {
                *sum += block.iter().map(|&v| v as u32).sum::<u32>();
            }
            if let Some(mask) = mask {
                let labels = &mask[y * gray.width..][..width * fine];
                let out = &mut masked[(y / fine) * width..][..width];
                for (m, block) in out.iter_mut().zip(labels.chunks_exact(fine)) {
                    *m |= block.iter().any(|&l| l != 0);
                }
            }
        }
        let norm = 1.0 / (fine * fine) as f32;
        let boxed: Vec<f32> = sums.iter().map(|&s| s as f32 * norm).collect();
        let (cw, ch) = (width / 2, height / 2);
        let mut coarse = vec![0f32; cw * ch];
        let mut coarse_masked = vec![false; cw * ch];
        for y in 0..ch {
            for x in 0..cw {
                let i = 2 * y * width + 2 * x;
                coarse[y * cw + x] =
                    0.25 * (boxed[i] + boxed[i + 1] + boxed[i + width] + boxed[i + width + 1]);
                coarse_masked[y * cw + x] =
                    masked[i] || masked[i + 1] || masked[i + width] || masked[i + width + 1];
            }
        }
        let levels = vec![
            Level::new(coarse, &coarse_masked, cw, ch, camera, FACTORS[0]),
            Level::new(boxed, &masked, width, height, camera, fine),
        ];
        Self { levels }
    }
}

impl SmallImage {
    /// Leaves out the pixels inside `boxes` (min and max pixel of the
    /// full-size image each): regions the motion check found moving.
    pub fn without_boxes(&mut self, boxes: impl Iterator<Item = ([f32; 2], [f32; 2])> + Clone) {
        for (level, &factor) in self.levels.iter_mut().zip(&FACTORS) {
            let f = factor as f32;
            for (min, max) in boxes.clone() {
                let x0 = ((min[0] / f).floor().max(0.0) as usize).saturating_sub(1);
                let y0 = ((min[1] / f).floor().max(0.0) as usize).saturating_sub(1);
                let x1 = ((max[0] / f).ceil().max(0.0) as usize + 1).min(level.width);
                let y1 = ((max[1] / f).ceil().max(0.0) as usize + 1).min(level.height);
                for y in y0..y1 {
                    level.valid[y * level.width + x0.min(x1)..y * level.width + x1].fill(false);
                }
            }
        }
    }
}

impl Level {
    /// A level from the image averaged down by `factor` (`boxed`, `width`
    /// by `height`) and where the mask covers it.
    fn new(
        boxed: Vec<f32>,
        masked: &[bool],
        width: usize,
        height: usize,
        camera: &Camera,
        factor: usize,
    ) -> Self {
        // The blur below spreads a masked pixel to its neighbours.
        let valid: Vec<bool> = (0..width * height)
            .map(|i| {
                let (x, y) = ((i % width) as isize, (i / width) as isize);
                !(-1..=1).any(|dy| {
                    (-1..=1).any(|dx| {
                        let (nx, ny) = (x + dx, y + dy);
                        nx >= 0
                            && ny >= 0
                            && (nx as usize) < width
                            && (ny as usize) < height
                            && masked[ny as usize * width + nx as usize]
                    })
                })
            })
            .collect();
        // A 3x3 binomial blur: a wider basin for the alignment.
        let at = |x: isize, y: isize| {
            let x = x.clamp(0, width as isize - 1) as usize;
            let y = y.clamp(0, height as isize - 1) as usize;
            boxed[y * width + x]
        };
        let mut data = vec![0f32; width * height];
        for y in 0..height as isize {
            for x in 0..width as isize {
                let mut s = 0.0;
                for (dy, wy) in [(-1, 1.0), (0, 2.0), (1, 1.0)] {
                    for (dx, wx) in [(-1, 1.0), (0, 2.0), (1, 1.0)] {
                        s += wy * wx * at(x + dx, y + dy);
                    }
                }
                data[y as usize * width + x as usize] = s / 16.0;
            }
        }
        let (mut gx, mut gy) = (vec![0f32; width * height], vec![0f32; width * height]);
        for y in 1..height.saturating_sub(1) {
            for x in 1..width.saturating_sub(1) {
                let i = y * width + x;
                gx[i] = 0.5 * (data[i + 1] - data[i - 1]);
                gy[i] = 0.5 * (data[i + width] - data[i - width]);
            }
        }
        let s = factor as f64;
        Self {
            width,
            height,
            data,
            gx,
            gy,
            valid,
            fx: camera.fx / s,
            fy: camera.fy / s,
            cx: (camera.cx + 0.5) / s - 0.5,
            cy: (camera.cy + 0.5) / s - 0.5,
        }
    }

    /// Bilinear samples of the image and its gradients at (x, y), inside
    /// the 1-pixel border where gradients exist and off the mask.
    fn sample(&self, x: f64, y: f64) -> Option<(f32, f32, f32)> {
        if !(x >= 1.0 && y >= 1.0 && x < (self.width - 2) as f64 && y < (self.height - 2) as f64) {
            return None;
        }
        let (x0, y0) = (x.floor() as usize, y.floor() as usize);
        if !self.valid[y0 * self.width + x0] {
            return None;
        }
        let (ax, ay) = ((x - x0 as f64) as f32, (y - y0 as f64) as f32);
        let i = y0 * self.width + x0;
        let w = self.width;
        let bil = |v: &[f32]| {
            (1.0 - ay) * ((1.0 - ax) * v[i] + ax * v[i + 1])
                + ay * ((1.0 - ax) * v[i + w] + ax * v[i + w + 1])
        };
        Some((bil(&self.data), bil(&self.gx), bil(&self.gy)))
    }
}

/// The rotation (newer camera from older) that best warps `older` onto
/// `newer`, from `start`; None when too little of the image overlaps or
/// the photometric error did not fall.
pub fn turn_between(
    older: &SmallImage,
    newer: &SmallImage,
    start: &UnitQuaternion<f64>,
) -> Option<UnitQuaternion<f64>> {
    let mut rotation = *start;
    let mut bias = 0f64;
    let mut first_error = None;
    let mut last_error = f64::INFINITY;
    for ((old, new), iterations) in older.levels.iter().zip(&newer.levels).zip(ITERATIONS) {
        for _ in 0..iterations {
            let (step, error, used) = gauss_newton_step(old, new, &rotation, bias)?;
            if used * 2 < old.width * old.height {
                return None;
            }
            first_error.get_or_insert(error);
            last_error = error;
            rotation =
                UnitQuaternion::from_scaled_axis(step.fixed_rows::<3>(0).into_owned()) * rotation;
            bias += step[3];
            if step.fixed_rows::<3>(0).norm() < 1e-4 {
                break;
            }
        }
    }
    (last_error < first_error?).then_some(rotation)
}

/// One Gauss-Newton step in (rotation increment, brightness offset): the
/// step, the mean robust error before it and the pixels that took part.
fn gauss_newton_step(
    old: &Level,
    new: &Level,
    rotation: &UnitQuaternion<f64>,
    bias: f64,
) -> Option<(Vector4<f64>, f64, usize)> {
    let mut h = Matrix4::<f64>::zeros();
    let mut g = Vector4::<f64>::zeros();
    let (mut error, mut used) = (0f64, 0usize);
    let r = rotation.to_rotation_matrix();
    for y in 1..old.height - 1 {
        for x in 1..old.width - 1 {
            if !old.valid[y * old.width + x] {
                continue;
            }
            let bearing = Vector3::new(
                (x as f64 - old.cx) / old.fx,
                (y as f64 - old.cy) / old.fy,
                1.0,
            );
            let p = r * bearing;
            if p.z < 0.2 {
                continue;
            }
            let (u, v) = (new.fx * p.x / p.z + new.cx, new.fy * p.y / p.z + new.cy);
            let Some((value, gx, gy)) = new.sample(u, v) else {
                continue;
            };
            let residual = value as f64 + bias - old.data[y * old.width + x] as f64;
            let weight = if residual.abs() <= HUBER as f64 {
                1.0
            } else {
                HUBER as f64 / residual.abs()
            };
            // d(pixel)/d(point) times d(point)/d(rotation increment) = -[p]x.
            let (iz, iz2) = (1.0 / p.z, 1.0 / (p.z * p.z));
            let du = Vector3::new(new.fx * iz, 0.0, -new.fx * p.x * iz2);
            let dv = Vector3::new(0.0, new.fy * iz, -new.fy * p.y * iz2);
            let di = du * gx as f64 + dv * gy as f64;
            // di . (-(p x w)) = di . (w x p) = w . (p x di)
            let jw = p.cross(&di);
            let j = Vector4::new(jw.x, jw.y, jw.z, 1.0);
            h += weight * j * j.transpose();
            g += weight * j * residual;
            error += weight * residual * residual;
            used += 1;
        }
    }
    if used == 0 {
        return None;
    }
    let step = h.lu().solve(&(-g))?;
    step.iter()
        .all(|s| s.is_finite())
        .then_some((step, error / used as f64, used))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn camera() -> Camera {
        Camera::new([525.0, 525.0, 319.5, 239.5], [0.0; 5], 5000.0, 0.0)
    }

    /// Brightness of a far, textured scene in direction `d`.
    fn scene(d: Vector3<f64>) -> u8 {
        let d = d.normalize();
        let v = 120.0
            + 50.0 * (9.0 * d.x).sin() * (7.0 * d.y).cos()
            + 30.0 * (13.0 * d.y + 5.0 * d.x).sin()
            + 20.0 * (40.0 * d.x * d.y).cos();
        v.clamp(0.0, 255.0) as u8
    }

    /// The scene seen from `world_from_camera`; the columns from `mover` on
    /// show the scene as seen from `mover_view` instead (something large
    /// that moves otherwise than the scene).
    fn render(
        world_from_camera: &UnitQuaternion<f64>,
        mover: usize,
        mover_view: &UnitQuaternion<f64>,
    ) -> GrayU8 {
        let c = camera();
        let (w, h) = (640, 480);
        let mut data = vec![0u8; w * h];
        for y in 0..h {
            for x in 0..w {
                let b = Vector3::new((x as f64 - c.cx) / c.fx, (y as f64 - c.cy) / c.fy, 1.0);
                let view = if x >= mover {
                    mover_view
                } else {
                    world_from_camera
                };
                data[y * w + x] = scene(view * b);
            }
        }
        GrayU8 {
            width: w,
            height: h,
            data,
        }
    }

    fn degrees_off(found: &UnitQuaternion<f64>, truth: &UnitQuaternion<f64>) -> f64 {
        (found.inverse() * truth).angle().to_degrees()
    }

    /// A camera that turns: the turn is found from the images alone, from a
    /// start that turns the other way (a reversal the motion model missed).
    #[test]
    fn a_turn_is_found_from_the_images() {
        let older_pose = UnitQuaternion::identity();
        let newer_pose = UnitQuaternion::from_euler_angles(0.02, -0.07, 0.01);
        let older = SmallImage::new(&render(&older_pose, 640, &older_pose), None, &camera());
        let newer = SmallImage::new(&render(&newer_pose, 640, &newer_pose), None, &camera());
        // Newer camera from older: (world from newer)^-1 (world from older).
        let truth = newer_pose.inverse() * older_pose;
        let start = UnitQuaternion::from_euler_angles(0.0, -0.03, 0.0);
        assert!(degrees_off(&start, &truth) > 5.0);
        let found = turn_between(&older, &newer, &start).expect("aligned");
        let error = degrees_off(&found, &truth);
        assert!(
            error < 0.3,
            "{error} degrees off a {} degree turn",
            truth.angle().to_degrees()
        );
    }

    /// A third of the view moves with the camera's old view (a person
    /// walking along): masked, it takes no part and the turn is found;
    /// unmasked, it pulls the turn its way.
    #[test]
    fn a_masked_mover_does_not_pull_the_turn() {
        let older_pose = UnitQuaternion::identity();
        let newer_pose = UnitQuaternion::from_euler_angles(0.0, -0.05, 0.0);
        let mover = 400;
        let mut mask = vec![0u8; 640 * 480];
        for row in mask.chunks_mut(640) {
            row[mover..].fill(1);
        }
        let older_image = render(&older_pose, mover, &older_pose);
        // The mover's columns still show what the camera saw before.
        let newer_image = render(&newer_pose, mover, &older_pose);
        let truth = newer_pose.inverse() * older_pose;
        let start = UnitQuaternion::identity();
        let masked = turn_between(
            &SmallImage::new(&older_image, Some(&mask), &camera()),
            &SmallImage::new(&newer_image, Some(&mask), &camera()),
            &start,
        )
        .expect("aligned");
        let unmasked = turn_between(
            &SmallImage::new(&older_image, None, &camera()),
            &SmallImage::new(&newer_image, None, &camera()),
            &start,
        );
        let masked_error = degrees_off(&masked, &truth);
        let unmasked_error = unmasked.map_or(f64::INFINITY, |u| degrees_off(&u, &truth));
        eprintln!("masked {masked_error:.3} deg off, unmasked {unmasked_error:.3} deg off");
        assert!(masked_error < 0.3, "{masked_error} degrees off");
        assert!(
            unmasked_error > 2.0 * masked_error.max(0.05),
            "the mover should pull an unmasked alignment: {unmasked_error} degrees off"
        );
    }
}
