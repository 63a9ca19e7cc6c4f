//! The embedded default input: a textured room rendered by ray casting, a
//! camera moving through it, exact depth and ground-truth poses, written as
//! a TUM RGB-D folder. `default_scene` then walks people through it with
//! [`crate::synth`], so `dynslam run` needs no dataset.
//!
//! The room is procedural (nothing to license, nothing to download): walls,
//! floor and ceiling carry value noise, floor tiles and posters whose
//! corners give ORB something to find; three boxes stand on the floor for
//! depth variety and occlusion. Edges and noise octaves are filtered by the
//! pixel footprint at the hit point, so the frames do not alias (aliasing
//! shimmer would be a feature-tracking artefact no real camera has). Pixels
//! are cast through the configured camera model, distortion included, so
//! the SLAM core sees the same camera it is configured for.

use std::path::{Path, PathBuf};

use image::{ImageBuffer, Luma, Rgb, RgbImage};
use nalgebra::{Isometry3, Matrix3, Rotation3, Translation3, UnitQuaternion, Vector3};
use slam_core::io::trajectory::Trajectory;
use slam_core::Camera;

use crate::composite::Pinhole;
use crate::sensor::SensorModel;
use crate::synth::{for_each_frame, synthesize, SynthError, SynthSummary};
use crate::walkers::WalkOptions;

/// What to render.
#[derive(Debug, Clone)]
pub struct RoomOptions {
    /// Frames to render.
    pub frames: usize,
    /// Frame rate (the timestamps' spacing).
    pub fps: f64,
    /// Image width, pixels.
    pub width: usize,
    /// Image height, pixels.
    pub height: usize,
    /// How the camera moves.
    pub path: CameraPath,
    /// Depth noise and holes, motion blur (default: none, exact frames).
    pub sensor: SensorModel,
}

/// The camera's path through the room.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum CameraPath {
    /// The default scene's: a glide sideways and forward, looking across
    /// the room (nothing is seen twice from afar).
    #[default]
    Glide,
    /// A closed circuit: round an ellipse in the middle of the room while
    /// turning a full circle, looking out at the walls, back to the first
    /// pose at the end (a loop for loop closing; the start leaves the local
    /// map long before the camera returns to it).
    Circuit,
    /// A closed orbit: round an ellipse about the middle of the room,
    /// looking in across it (the sideways motion gives a monocular camera
    /// parallax all the way round; looking out, as on the circuit, it sees
    /// a near wall turn past it), back to the first pose at the end.
    Orbit,
}

impl Default for RoomOptions {
    fn default() -> Self {
        Self {
            frames: 150,
            fps: 30.0,
            width: 640,
            height: 480,
            path: CameraPath::Glide,
            sensor: SensorModel::default(),
        }
    }
}

/// An axis-aligned box: min and max corners (world, metres; y points down).
#[derive(Debug, Clone, Copy)]
struct Aabb {
    min: Vector3<f64>,
    max: Vector3<f64>,
}

/// The room's interior; the camera starts near the origin looking along +z.
const ROOM: Aabb = Aabb {
    min: Vector3::new(-2.6, -1.6, -1.5),
    max: Vector3::new(2.6, 1.1, 4.2),
};

/// Furniture standing on the floor (y = ROOM.max.y).
const BOXES: [Aabb; 3] = [
    Aabb {
        min: Vector3::new(-1.5, 0.3, 2.6),
        max: Vector3::new(-0.4, 1.1, 3.4),
    },
    Aabb {
        min: Vector3::new(1.2, -0.7, 3.0),
        max: Vector3::new(2.2, 1.1, 3.8),
    },
    Aabb {
        min: Vector3::new(0.5, 0.55, 2.2),
        max: Vector3::new(1.0, 1.1, 2.7),
    },
];

/// Walkers for the default scene: between the camera and the furniture.
pub fn default_walks() -> WalkOptions {
    WalkOptions {
        objects: 2,
        boxes: 0,
        speed_mps: 1.0,
        near_m: 1.1,
        far_m: 2.0,
        height_m: 0.9,
        seed: 3,
        occlusion: crate::walkers::Occlusion::Scene,
        behaviours: crate::walkers::Behaviours::Across,
    }
}

/// The camera's orientation looking along `forward` (unit), upright: its x
/// axis level, its y axis (image down) towards the floor.
fn looking_along(forward: &Vector3<f64>) -> UnitQuaternion<f64> {
    let right = Vector3::y().cross(forward).normalize();
    let down = forward.cross(&right);
    let look = Rotation3::from_matrix_unchecked(Matrix3::from_columns(&[right, down, *forward]));
    UnitQuaternion::from_rotation_matrix(&look)
}

/// World from camera at time `t` of a `duration` long sequence: a slow
/// sideways-and-forward glide (about 0.3 m/s) while looking across the
/// room, with a little bob and roll, as a hand-held camera.
pub fn camera_pose(t: f64, duration: f64) -> Isometry3<f64> {
    let s = (t / duration).clamp(0.0, 1.0);
    let ease = s * s * (3.0 - 2.0 * s);
    let position = Vector3::new(
        -0.7 + 1.3 * ease,
        -0.05 + 0.04 * (std::f64::consts::TAU * 1.3 * t).sin(),
        -0.3 + 0.6 * ease,
    );
    let target = Vector3::new(0.5 - 1.2 * ease, 0.35 + 0.1 * (0.9 * t).sin(), 3.6);
    let forward = (target - position).normalize();
    let right = Vector3::y().cross(&forward).normalize();
    let down = forward.cross(&right);
    let look = Rotation3::from_matrix_unchecked(Matrix3::from_columns(&[right, down, forward]));
    let roll = Rotation3::from_axis_angle(&Vector3::z_axis(), 0.05 * (1.7 * t).sin());
    Isometry3::from_parts(
        Translation3::from(position),
        UnitQuaternion::from_rotation_matrix(&(look * roll)),
    )
}

/// World from camera at time `t` of a `duration` long circuit: once round
/// an ellipse (0.7 x 0.5 m) about the middle of the room, turning a full
/// circle to look out at the walls, with a little bob; the last pose is the
/// first.
pub fn circuit_pose(t: f64, duration: f64) -> Isometry3<f64> {
    let a = std::f64::consts::TAU * (t / duration);
    let position = Vector3::new(
        0.7 * a.sin(),
        -0.05 + 0.03 * (3.0 * a).sin(),
        1.3 - 0.5 * a.cos(),
    );
    // Looking out: away from the ellipse's centre, a little ahead of it.
    let heading = a + 0.3;
    let forward = Vector3::new(heading.sin(), 0.08, -heading.cos()).normalize();
    Isometry3::from_parts(Translation3::from(position), looking_along(&forward))
}

/// World from camera at time `t` of a `duration` long orbit: once round
/// an ellipse (0.9 x 0.8 m) about the middle of the room at 1.15 m over the
/// floor, above the two low boxes, looking in at a point a little below
/// the eye, across the room at the far side's walls, floor and boxes; the
/// last pose is the first.
pub fn orbit_pose(t: f64, duration: f64) -> Isometry3<f64> {
    let a = std::f64::consts::TAU * (t / duration);
    let centre = Vector3::new(0.0, 0.3, 1.6);
    let position = Vector3::new(
        -0.9 * a.sin(),
        -0.05 + 0.03 * (3.0 * a).sin(),
        centre.z - 0.8 * a.cos(),
    );
    let forward = (centre - position).normalize();
    Isometry3::from_parts(Translation3::from(position), looking_along(&forward))
}

impl CameraPath {
    /// World from camera at `t` of a `duration` long sequence.
    pub fn pose(self, t: f64, duration: f64) -> Isometry3<f64> {
        match self {
            CameraPath::Glide => camera_pose(t, duration),
            CameraPath::Circuit => circuit_pose(t, duration),
            CameraPath::Orbit => orbit_pose(t, duration),
        }
    }
}

/// Renders the static room into `output` (a TUM RGB-D folder with
/// groundtruth.txt). `output` must not exist or be empty.
pub fn render_room(
    output: &Path,
    camera: &Camera,
    options: &RoomOptions,
) -> Result<usize, SynthError> {
    let io = |path: &Path| {
        let path = path.to_path_buf();
        move |e: std::io::Error| SynthError::Io {
            path: path.clone(),
            message: e.to_string(),
        }
    };
    if options.frames == 0 || options.width == 0 || options.height == 0 || options.fps <= 0.0 {
        return Err(SynthError::Options(format!(
            "room: frames {}, size {}x{} and fps {} must be positive",
            options.frames, options.width, options.height, options.fps
        )));
    }
    let exposure = options.sensor.exposure_s;
    if !(0.0..1.0 / options.fps).contains(&exposure) {
        return Err(SynthError::Options(format!(
            "room: exposure {:.1} ms must be at least 0 and shorter than a frame ({:.1} ms at {} fps)",
            exposure * 1e3,
            1e3 / options.fps,
            options.fps
        )));
    }
    if output.exists()
        && std::fs::read_dir(output)
            .map_err(io(output))?
            .next()
            .is_some()
    {
        return Err(SynthError::OutputNotEmpty(output.to_path_buf()));
    }
    for sub in ["rgb", "depth"] {
        let dir = output.join(sub);
        std::fs::create_dir_all(&dir).map_err(io(&dir))?;
    }
    let (w, h) = (options.width, options.height);
    // One ray per pixel through the (distorted) camera, camera frame, z = 1:
    // the hit parameter along it is then the pixel's depth.
    let rays: Vec<Vector3<f64>> = (0..h)
        .flat_map(|v| (0..w).map(move |u| (u, v)))
        .map(|(u, v)| {
            let (x, y) = camera.undistort(u as f64, v as f64);
            Vector3::new(
                (x - camera.cx) / camera.fx,
                (y - camera.cy) / camera.fy,
                1.0,
            )
        })
        .collect();
    let duration = (options.frames.max(2) - 1) as f64 / options.fps;
    let t0 = 1_000.0;
    let stamps: Vec<f64> = (0..options.frames)
        .map(|k| t0 + k as f64 / options.fps)
        .collect();

    for_each_frame("room", options.frames, |k| {
        let t = stamps[k] - t0;
        let (rgb, mut depth) = render_exposed(options, (t, duration), &rays, camera);
        options
            .sensor
            .depth
            .degrade(&mut depth, (w, h), camera.depth_scale, camera.fx, k as u64);
        let name = format!("{:.6}.png", stamps[k]);
        rgb.save(output.join("rgb").join(&name))
            .and_then(|()| depth.save(output.join("depth").join(&name)))
            .map_err(|e| SynthError::Io {
                path: output.join("rgb").join(&name),
                message: e.to_string(),
            })
    })?;

    let header = format!(
        "# dynslam room: rendered by dynslam (scenes::room), exact poses, depth {:?}, exposure {:.1} ms\n# timestamp filename\n",
        options.sensor.depth,
        options.sensor.exposure_s * 1e3
    );
    let mut rgb_txt = header.clone();
    let mut depth_txt = header;
    let mut assoc = String::new();
    for t in &stamps {
        rgb_txt += &format!("{t:.6} rgb/{t:.6}.png\n");
        depth_txt += &format!("{t:.6} depth/{t:.6}.png\n");
        assoc += &format!("{t:.6} rgb/{t:.6}.png {t:.6} depth/{t:.6}.png\n");
    }
    let gt = Trajectory {
        stamps: stamps.clone(),
        poses: stamps
            .iter()
            .map(|t| options.path.pose(t - t0, duration))
            .collect(),
    };
    for (name, text) in [
        ("rgb.txt", rgb_txt),
        ("depth.txt", depth_txt),
        ("associations.txt", assoc),
        ("groundtruth.txt", gt.to_tum()),
    ] {
        let p = output.join(name);
        std::fs::write(&p, text).map_err(io(&p))?;
    }
    Ok(options.frames)
}

/// The embedded default input under `dir`: the static room in `dir/room`,
/// the same with people walking through it in `dir/scene` (returned).
pub fn default_scene(
    dir: &Path,
    camera: &Camera,
    options: &RoomOptions,
) -> Result<(PathBuf, SynthSummary), SynthError> {
    let room = dir.join("room");
    let scene = dir.join("scene");
    render_room(&room, camera, options)?;
    let pinhole = Pinhole {
        fx: camera.fx,
        fy: camera.fy,
        cx: camera.cx,
        cy: camera.cy,
    };
    let summary = synthesize(
        &room,
        &scene,
        &pinhole,
        camera.depth_scale,
        &default_walks(),
        None,
    )?;
    Ok((scene, summary))
}

/// The camera pose of every image row of the frame at `t`: a rolling
/// shutter (`readout_s` > 0) exposes row y `readout_s * (y - h/2) / h`
/// seconds after the middle row, whose pose is the frame's ground truth (the
/// instant the SLAM core reports, see `System::track_rgbd`).
fn row_poses(
    path: CameraPath,
    t: f64,
    duration: f64,
    h: usize,
    readout_s: f64,
) -> Vec<Isometry3<f64>> {
    (0..h)
        .map(|y| {
            let offset = readout_s * (y as f64 - h as f64 / 2.0) / h as f64;
            path.pose(t + offset, duration)
        })
        .collect()
}

/// Sub-frames a blurred frame averages over its exposure.
const BLUR_SAMPLES: usize = 5;

/// One frame at time `t` of a `duration` long path: colour averaged over
/// the exposure (motion blur, [`BLUR_SAMPLES`] sub-frames, each with the
/// rolling shutter), depth at the frame's instant.
fn render_exposed(
    options: &RoomOptions,
    (t, duration): (f64, f64),
    rays: &[Vector3<f64>],
    camera: &Camera,
) -> (RgbImage, ImageBuffer<Luma<u16>, Vec<u16>>) {
    let (w, h) = (options.width, options.height);
    let rows = |t| row_poses(options.path, t, duration, h, camera.readout_s);
    let (rgb, depth) = render_frame(&rows(t), rays, w, h, camera);
    let exposure = options.sensor.exposure_s;
    if exposure <= 0.0 {
        return (rgb, depth);
    }
    let mut sum: Vec<u32> = rgb.as_raw().iter().map(|&c| c as u32).collect();
    for i in 0..BLUR_SAMPLES {
        let offset = exposure * (i as f64 / (BLUR_SAMPLES - 1) as f64 - 0.5);
        if i == BLUR_SAMPLES / 2 {
            continue; // the frame's instant, rendered above
        }
        let (sub, _) = render_frame(&rows(t + offset), rays, w, h, camera);
        for (s, &c) in sum.iter_mut().zip(sub.as_raw()) {
            *s += c as u32;
        }
    }
    let n = BLUR_SAMPLES as u32;
    let blurred = sum.iter().map(|&s| ((s + n / 2) / n) as u8).collect();
    let rgb = RgbImage::from_raw(w as u32, h as u32, blurred).expect("the frame's size");
    (rgb, depth)
}

/// Colour and 16-bit depth of one frame, row `y` seen from `rows[y]`.
fn render_frame(
    rows: &[Isometry3<f64>],
    rays: &[Vector3<f64>],
    w: usize,
    h: usize,
    camera: &Camera,
) -> (RgbImage, ImageBuffer<Luma<u16>, Vec<u16>>) {
    let mut rgb = RgbImage::new(w as u32, h as u32);
    let mut depth = ImageBuffer::<Luma<u16>, Vec<u16>>::new(w as u32, h as u32);
    for (i, ray) in rays.iter().enumerate() {
        let pose = &rows[i / w];
        let origin = pose.translation.vector;
        let dir = pose.rotation * ray;
        let hit = cast(&origin, &dir);
        // Footprint of a pixel on the surface (metres), for filtering.
        let footprint = hit.t * ray.norm() / camera.fx * 1.5;
        let p = origin + dir * hit.t;
        let colour = shade(&p, hit.surface, hit.axis, footprint);
        let (u, v) = ((i % w) as u32, (i / w) as u32);
        rgb.put_pixel(u, v, Rgb(colour));
        let d = (hit.t * camera.depth_scale).round();
        depth.put_pixel(u, v, Luma([if d < 65535.0 { d as u16 } else { 0 }]));
    }
    (rgb, depth)
}

struct Hit {
    /// Ray parameter (the depth, for camera rays with z = 1).
    t: f64,
    /// 0..6 room faces, 6.. box faces.
    surface: usize,
    /// The axis the surface is normal to.
    axis: usize,
}

/// Nearest surface along `origin + t * dir`: a box face or the room's
/// inside.
fn cast(origin: &Vector3<f64>, dir: &Vector3<f64>) -> Hit {
    // Leaving the room: the smallest exit distance over the three axes.
    let mut best = Hit {
        t: f64::INFINITY,
        surface: 0,
        axis: 0,
    };
    for a in 0..3 {
        if dir[a].abs() < 1e-12 {
            continue;
        }
        let (bound, side) = if dir[a] > 0.0 {
            (ROOM.max[a], 1)
        } else {
            (ROOM.min[a], 0)
        };
        let t = (bound - origin[a]) / dir[a];
        if t < best.t {
            best = Hit {
                t,
                surface: 2 * a + side,
                axis: a,
            };
        }
    }
    for (b, bx) in BOXES.iter().enumerate() {
        let (mut t_in, mut t_out, mut axis_in) = (0.0f64, f64::INFINITY, 0);
        let mut entered_side = 0;
        for a in 0..3 {
            let inv = 1.0 / dir[a];
            let (mut t0, mut t1) = ((bx.min[a] - origin[a]) * inv, (bx.max[a] - origin[a]) * inv);
            let mut side = 0;
            if t0 > t1 {
                std::mem::swap(&mut t0, &mut t1);
                side = 1;
            }
            if t0 > t_in {
                t_in = t0;
                axis_in = a;
                entered_side = side;
            }
            t_out = t_out.min(t1);
        }
        if t_in > 0.0 && t_in <= t_out && t_in < best.t {
            best = Hit {
                t: t_in,
                surface: 6 + 6 * b + 2 * axis_in + entered_side,
                axis: axis_in,
            };
        }
    }
    best
}

/// A hash of integer coordinates to [0, 1).
fn hash(x: i64, y: i64, salt: u64) -> f64 {
    let mut z = (x as u64)
        .wrapping_mul(0x9E37_79B9_7F4A_7C15)
        .wrapping_add((y as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F))
        .wrapping_add(salt.wrapping_mul(0x1656_67B1_9E37_79F9));
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^= z >> 31;
    (z >> 11) as f64 / (1u64 << 53) as f64
}

/// Smooth value noise in [0, 1).
fn value_noise(x: f64, y: f64, salt: u64) -> f64 {
    let (ix, iy) = (x.floor(), y.floor());
    let (fx, fy) = (x - ix, y - iy);
    let (sx, sy) = (fx * fx * (3.0 - 2.0 * fx), fy * fy * (3.0 - 2.0 * fy));
    let (ix, iy) = (ix as i64, iy as i64);
    let a = hash(ix, iy, salt);
    let b = hash(ix + 1, iy, salt);
    let c = hash(ix, iy + 1, salt);
    let d = hash(ix + 1, iy + 1, salt);
    a + (b - a) * sx + (c - a) * sy + (a - b - c + d) * sx * sy
}

/// Fractal noise with octaves finer than the footprint faded out.
fn fbm(x: f64, y: f64, wavelength: f64, footprint: f64, salt: u64) -> f64 {
    let (mut sum, mut weight, mut amp, mut wl) = (0.0, 0.0, 1.0, wavelength);
    for octave in 0..5u64 {
        // Full weight at 4+ pixels per wavelength, none below 2.
        let fade = ((wl / footprint - 2.0) / 2.0).clamp(0.0, 1.0);
        sum += amp * fade * (value_noise(x / wl, y / wl, salt + octave) - 0.5);
        weight += amp;
        amp *= 0.6;
        wl *= 0.5;
    }
    0.5 + sum / weight
}

/// Coverage of `inside_by` (signed distance into a shape, metres) by a
/// pixel of the given footprint: an anti-aliased edge.
fn coverage(inside_by: f64, footprint: f64) -> f64 {
    (inside_by / footprint + 0.5).clamp(0.0, 1.0)
}

fn mix(a: [f64; 3], b: [f64; 3], k: f64) -> [f64; 3] {
    [
        a[0] + (b[0] - a[0]) * k,
        a[1] + (b[1] - a[1]) * k,
        a[2] + (b[2] - a[2]) * k,
    ]
}

/// The colour of surface point `p`.
fn shade(p: &Vector3<f64>, surface: usize, axis: usize, footprint: f64) -> [u8; 3] {
    // Surface coordinates: the two axes in the surface's plane.
    let (a, b) = match axis {
        0 => (p.z, p.y),
        1 => (p.x, p.z),
        _ => (p.x, p.y),
    };
    let salt = surface as u64 * 7919;
    let base = [
        0.35 + 0.5 * hash(surface as i64, 1, 11),
        0.35 + 0.5 * hash(surface as i64, 2, 11),
        0.35 + 0.5 * hash(surface as i64, 3, 11),
    ];
    let grain = fbm(a, b, 0.4, footprint, salt);
    let mut colour = base.map(|c| c * (0.55 + 0.9 * (grain - 0.5) + 0.45));
    let floor = surface == 3;
    if floor {
        // Tiles with dark grout.
        let tile = 0.5;
        let (fa, fb) = ((a / tile).rem_euclid(1.0), (b / tile).rem_euclid(1.0));
        let edge = (fa.min(1.0 - fa)).min(fb.min(1.0 - fb)) * tile;
        let grout = 1.0 - coverage(edge - 0.012, footprint);
        let shade = 0.8 + 0.4 * hash((a / tile).floor() as i64, (b / tile).floor() as i64, salt);
        colour = colour.map(|c| c * shade);
        colour = mix(colour, [0.12, 0.12, 0.12], grout);
    } else {
        // Posters: one rectangle in some cells of a 0.7 m grid.
        let cell = 0.7;
        let (ca, cb) = ((a / cell).floor(), (b / cell).floor());
        let (ia, ib) = (ca as i64, cb as i64);
        if hash(ia, ib, salt + 1) < 0.55 {
            let m = |k: u64| 0.04 + 0.18 * hash(ia, ib, salt + k);
            let (a0, a1) = (ca * cell + m(2), (ca + 1.0) * cell - m(3));
            let (b0, b1) = (cb * cell + m(4), (cb + 1.0) * cell - m(5));
            let inside = (a - a0).min(a1 - a).min(b - b0).min(b1 - b);
            let k = coverage(inside, footprint);
            if k > 0.0 {
                let tone = [
                    hash(ia, ib, salt + 6),
                    hash(ia, ib, salt + 7),
                    hash(ia, ib, salt + 8),
                ];
                let detail = fbm(a, b, 0.08, footprint, salt + 9);
                let poster = tone.map(|c| (0.1 + 0.85 * c) * (0.6 + 0.8 * detail));
                colour = mix(colour, poster, k);
            }
        }
    }
    // Faces facing different ways are lit differently.
    let light = [0.95, 0.85, 0.7, 1.0, 0.9, 0.8][(surface % 6).min(5)];
    colour.map(|c| (255.0 * (c * light).clamp(0.0, 1.0)).round() as u8)
}

/// The ground-truth trajectory of `render_room`'s folder.
pub fn ground_truth(dir: &Path) -> Result<Trajectory, SynthError> {
    Ok(Trajectory::load_tum(&dir.join("groundtruth.txt"))?)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn camera() -> Camera {
        Camera::tum_fr1()
    }

    /// The camera for 160x120 renders: fr1's at a quarter of the size.
    fn quarter_camera() -> Camera {
        let cam = camera();
        Camera {
            fx: cam.fx / 4.0,
            fy: cam.fy / 4.0,
            cx: cam.cx / 4.0,
            cy: cam.cy / 4.0,
            ..cam
        }
    }

    #[test]
    fn rays_hit_the_room_at_the_distance_the_geometry_says() {
        let origin = Vector3::new(0.0, 0.0, 0.0);
        // Straight ahead: the far wall at z = 4.2 (no box on the axis).
        let hit = cast(&origin, &Vector3::new(0.0, 0.0, 1.0));
        assert!((hit.t - ROOM.max.z).abs() < 1e-12);
        assert_eq!(hit.surface, 5);
        // Straight down: the floor.
        let hit = cast(&origin, &Vector3::new(0.0, 1.0, 0.0));
        assert!((hit.t - ROOM.max.y).abs() < 1e-12);
        assert_eq!(hit.surface, 3);
        // Towards the small box's front face.
        let centre = (BOXES[2].min + BOXES[2].max) / 2.0;
        let dir = Vector3::new(centre.x, centre.y, BOXES[2].min.z);
        let hit = cast(&origin, &dir);
        assert!((hit.t - 1.0).abs() < 1e-9, "t {}", hit.t);
        assert_eq!(hit.surface, 6 + 12 + 4);
    }

    #[test]
    fn camera_paths_stay_inside_the_room_and_move_smoothly() {
        for (path, duration) in [
            (CameraPath::Glide, 5.0),
            (CameraPath::Circuit, 20.0),
            (CameraPath::Orbit, 20.0),
        ] {
            path_is_smooth(path, duration);
        }
        for closed in [CameraPath::Circuit, CameraPath::Orbit] {
            let (start, end) = (closed.pose(0.0, 20.0), closed.pose(20.0, 20.0));
            let back = start.inverse() * end;
            assert!(back.translation.vector.norm() < 1e-9 && back.rotation.angle() < 1e-9);
        }
    }

    fn path_is_smooth(path: CameraPath, duration: f64) {
        let mut last: Option<Isometry3<f64>> = None;
        for k in 0..=(duration * 30.0) as usize {
            let pose = path.pose(k as f64 / 30.0, duration);
            let p = pose.translation.vector;
            for a in 0..3 {
                assert!(p[a] > ROOM.min[a] + 0.5 && p[a] < ROOM.max[a] - 0.5);
            }
            if let Some(prev) = last {
                let step = prev.inverse() * pose;
                assert!(step.translation.vector.norm() < 0.02, "{k}");
                assert!(step.rotation.angle() < 0.02, "{k}");
            }
            last = Some(pose);
        }
    }

    #[test]
    fn rendered_depth_matches_the_ray_cast_and_frames_are_textured() {
        let dir = std::env::temp_dir().join(format!("dynslam-room-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let opts = RoomOptions {
            frames: 2,
            width: 160,
            height: 120,
            ..Default::default()
        };
        let cam_small = quarter_camera();
        assert_eq!(render_room(&dir, &cam_small, &opts).unwrap(), 2);
        let gt = ground_truth(&dir).unwrap();
        assert_eq!(gt.poses.len(), 2);
        let depth = image::open(dir.join("depth/1000.000000.png"))
            .unwrap()
            .into_luma16();
        // The centre pixel's depth is where its ray meets the room.
        let (u, v) = (80u32, 60u32);
        let (x, y) = cam_small.undistort(u as f64, v as f64);
        let ray = Vector3::new(
            (x - cam_small.cx) / cam_small.fx,
            (y - cam_small.cy) / cam_small.fy,
            1.0,
        );
        let pose = gt.poses[0];
        let hit = cast(&pose.translation.vector, &(pose.rotation * ray));
        let stored = depth.get_pixel(u, v)[0] as f64 / 5000.0;
        assert!((stored - hit.t).abs() < 1e-3, "{stored} vs {}", hit.t);
        // The top row was exposed half a readout earlier (rolling shutter).
        assert!(cam_small.readout_s > 0.0);
        let (x, y) = cam_small.undistort(u as f64, 0.0);
        let ray = Vector3::new(
            (x - cam_small.cx) / cam_small.fx,
            (y - cam_small.cy) / cam_small.fy,
            1.0,
        );
        let early = camera_pose(-cam_small.readout_s / 2.0, 1.0 / 30.0);
        let hit = cast(&early.translation.vector, &(early.rotation * ray));
        let stored = depth.get_pixel(u, 0)[0] as f64 / 5000.0;
        assert!((stored - hit.t).abs() < 1e-3, "{stored} vs {}", hit.t);
        assert!(depth.pixels().all(|p| p[0] > 0));
        // Texture: many distinct grey levels, not a flat fill.
        let rgb = image::open(dir.join("rgb/1000.033333.png"))
            .unwrap()
            .into_luma8();
        let mut seen = [false; 256];
        for p in rgb.pixels() {
            seen[p[0] as usize] = true;
        }
        assert!(seen.iter().filter(|&&s| s).count() > 100);
        // A second render into the same folder is refused.
        assert!(matches!(
            render_room(&dir, &cam_small, &opts),
            Err(SynthError::OutputNotEmpty(_))
        ));
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// Motion blur averages the colour over the exposure (less fine detail,
    /// as a moving camera gets) and leaves depth at the frame's instant; an
    /// exposure as long as a frame is refused; the Kinect model leaves holes.
    #[test]
    fn exposure_blurs_the_colour_and_the_sensor_degrades_depth() {
        let cam_small = quarter_camera();
        let base = std::env::temp_dir().join(format!("dynslam-room-blur-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&base);
        let render = |name: &str, sensor: SensorModel| {
            let opts = RoomOptions {
                frames: 2,
                width: 160,
                height: 120,
                path: CameraPath::Circuit,
                sensor,
                ..Default::default()
            };
            let dir = base.join(name);
            render_room(&dir, &cam_small, &opts).map(|_| {
                let rgb = image::open(dir.join("rgb/1000.033333.png"))
                    .unwrap()
                    .into_luma8();
                let depth = image::open(dir.join("depth/1000.033333.png"))
                    .unwrap()
                    .into_luma16();
                (rgb, depth)
            })
        };
        let detail = |g: &image::GrayImage| -> u64 {
            g.as_raw()
                .windows(2)
                .map(|p| (p[0] as i32 - p[1] as i32).unsigned_abs() as u64)
                .sum()
        };
        let (sharp, sharp_depth) = render("sharp", SensorModel::default()).unwrap();
        let blurred = SensorModel {
            exposure_s: 0.02,
            ..Default::default()
        };
        let (soft, soft_depth) = render("blurred", blurred).unwrap();
        assert_eq!(sharp_depth, soft_depth);
        assert!(
            (detail(&soft) as f64) < 0.9 * detail(&sharp) as f64,
            "detail {} blurred against {} sharp",
            detail(&soft),
            detail(&sharp)
        );
        let too_long = SensorModel {
            exposure_s: 0.04,
            ..Default::default()
        };
        let e = render("too-long", too_long).unwrap_err().to_string();
        assert!(e.contains("exposure 40.0 ms"), "{e}");
        let kinect = SensorModel {
            depth: crate::sensor::DepthSensor::Kinect,
            ..Default::default()
        };
        let (_, noisy) = render("kinect", kinect).unwrap();
        let holes = noisy.pixels().filter(|p| p[0] == 0).count();
        let changed = noisy
            .pixels()
            .zip(sharp_depth.pixels())
            .filter(|(a, b)| a != b)
            .count();
        assert!(
            holes > 0 && changed > noisy.len() / 2,
            "{holes} holes, {changed} changed"
        );
        let _ = std::fs::remove_dir_all(&base);
    }
}
