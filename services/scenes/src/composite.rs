//! Drawing people into one RGB-D frame.
//!
//! Each person is a cut-out standing upright in the world, facing the
//! camera (a billboard at one depth per frame). A pixel shows the person
//! when the cut-out covers it and the person is nearer than the scene there
//! (or the scene has no depth): the RGB becomes the cut-out's, the depth the
//! person's, the label the person's id. Narrow holes in the scene's depth
//! (a Kinect's shadows, black screens, the band at the image's right edge
//! that its depth camera does not see) occlude like the depth beside them,
//! so a person is not drawn through a desk where the sensor missed it.
//! Everything else is left untouched, byte for byte, so the ground-truth
//! mask is exactly the set of changed pixels' owners.

use nalgebra::{Isometry3, Point3, Vector2, Vector3};
use serde::Serialize;

use crate::sprites::Sprite;
use crate::walkers::Occlusion;

/// Pinhole intrinsics (the images keep their own lens distortion; a
/// cut-out's few hundred pixels do not need it).
#[derive(Debug, Clone, Copy)]
pub struct Pinhole {
    /// Focal length along x, pixels.
    pub fx: f64,
    /// Focal length along y, pixels.
    pub fy: f64,
    /// Principal point x, pixels.
    pub cx: f64,
    /// Principal point y, pixels.
    pub cy: f64,
}

impl Pinhole {
    fn project(&self, p: &Point3<f64>) -> Vector2<f64> {
        Vector2::new(self.fx * p.x / p.z + self.cx, self.fy * p.y / p.z + self.cy)
    }
}

/// One person as drawn into one frame.
#[derive(Debug, Clone, Serialize)]
pub struct Placement {
    /// Instance id in the label image.
    pub id: u8,
    /// Index into the sprites.
    pub sprite: usize,
    /// Drawn mirrored (walking the other way).
    pub mirrored: bool,
    /// Image position of the cut-out's centre (pixels).
    pub centre_px: [f64; 2],
    /// Unit image direction of world "up".
    pub up_px: [f64; 2],
    /// Cut-out height in pixels.
    pub height_px: f64,
    /// Depth of the billboard (metres along the optical axis).
    pub depth_m: f64,
}

/// What one placement left in a frame.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Drawn {
    /// Pixels of the person in the image.
    pub visible_px: usize,
    /// Pixels it would have inside the image were nothing in front of it
    /// (neither the scene nor a nearer person): the full silhouette cut
    /// only by the image border.
    pub unoccluded_px: usize,
    /// The depth it was drawn at (metres): its placement's, or nearer where
    /// it passes in front of nearer scene ([`Occlusion::None`]).
    pub depth_m: f64,
}

/// Where a person of `height_m` with centre `centre` (world) appears to a
/// camera at `pose` (world from camera); `None` when behind or too close.
#[allow(clippy::too_many_arguments)]
pub fn place(
    id: u8,
    sprite: usize,
    mirrored: bool,
    centre: &Point3<f64>,
    up: &Vector3<f64>,
    height_m: f64,
    pose: &Isometry3<f64>,
    camera: &Pinhole,
) -> Option<Placement> {
    let to_camera = pose.inverse();
    let c = to_camera * centre;
    if c.z < 0.3 {
        return None;
    }
    let top = to_camera * (centre + up * 0.25);
    let centre_px = camera.project(&c);
    // The up direction at the person's depth (top point projected at c.z
    // keeps it defined when the top is behind the camera).
    let top_px = camera.project(&Point3::new(top.x, top.y, c.z));
    let up_px = (top_px - centre_px).try_normalize(1e-9)?;
    Some(Placement {
        id,
        sprite,
        mirrored,
        centre_px: [centre_px.x, centre_px.y],
        up_px: [up_px.x, up_px.y],
        height_px: camera.fy * height_m / c.z,
        depth_m: c.z,
    })
}

/// An RGB-D frame being drawn into, with its label image.
pub struct Canvas<'a> {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// RGB8, row-major.
    pub rgb: &'a mut [u8],
    /// Depth values (`depth_scale` a metre; 0: none).
    pub depth: &'a mut [u16],
    /// Instance ids (0: background).
    pub labels: &'a mut [u8],
    /// Depth units per metre.
    pub depth_scale: f64,
    /// Whether the scene's depth hides people ([`Occlusion::Scene`]).
    pub occlusion: Occlusion,
}

/// Holes in a depth row up to this many pixels wide take the depth beside
/// them for occlusion; wider ones (out of range: far walls, sky) stay open.
pub const HOLE_FILL_PX: usize = 64;

/// The scene depth that occludes people: `depth` with each row's holes up
/// to [`HOLE_FILL_PX`] wide filled from their valid neighbours, the farther
/// of the two where both exist (a sensor's shadow belongs to the background
/// beside an edge). Holes at a row's end take their one neighbour.
pub fn occluder_depth(depth: &[u16], width: usize) -> Vec<u16> {
    let mut out = depth.to_vec();
    for row in out.chunks_mut(width) {
        let mut x = 0;
        while x < row.len() {
            if row[x] != 0 {
                x += 1;
                continue;
            }
            let start = x;
            while x < row.len() && row[x] == 0 {
                x += 1;
            }
            let left = start.checked_sub(1).map(|i| row[i]);
            let right = row.get(x).copied();
            let fill = match (left, right) {
                (Some(l), Some(r)) => l.max(r),
                (Some(v), None) | (None, Some(v)) => v,
                (None, None) => 0,
            };
            if x - start <= HOLE_FILL_PX {
                row[start..x].fill(fill);
            }
        }
    }
    out
}

/// The depth value a person at `depth_m` writes.
pub fn depth_units(depth_m: f64, depth_scale: f64) -> u16 {
    (depth_m * depth_scale).round().clamp(1.0, u16::MAX as f64) as u16
}

impl Canvas<'_> {
    /// Draws `placements` (any order: they are drawn far to near). Returns
    /// the number of visible pixels per placement, in the given order.
    pub fn draw(&mut self, placements: &[Placement], sprites: &[Sprite]) -> Vec<usize> {
        self.draw_counted(placements, sprites)
            .into_iter()
            .map(|c| c.visible_px)
            .collect()
    }

    /// [`Self::draw`], with each placement's pixels in view before the
    /// scene and nearer people hid any of them.
    pub fn draw_counted(&mut self, placements: &[Placement], sprites: &[Sprite]) -> Vec<Drawn> {
        let mut order: Vec<usize> = (0..placements.len()).collect();
        order.sort_by(|&a, &b| placements[b].depth_m.total_cmp(&placements[a].depth_m));
        let occluders = match self.occlusion {
            Occlusion::Scene => occluder_depth(self.depth, self.width),
            Occlusion::None => vec![0; self.depth.len()],
        };
        let mut counted = vec![Drawn::default(); placements.len()];
        for k in order {
            counted[k] = self.draw_one(&placements[k], &sprites[placements[k].sprite], &occluders);
        }
        // A nearer person may have covered pixels counted for a farther one.
        for (k, p) in placements.iter().enumerate() {
            if counted[k].visible_px > 0 {
                counted[k].visible_px = self.labels.iter().filter(|&&l| l == p.id).count();
            }
        }
        counted
    }

    /// Draws one person where `occluders` (the scene's depth) is farther;
    /// people are drawn far to near, so a nearer one paints over. Without
    /// scene occlusion a person passes between the camera and the scene: it
    /// is drawn whole, at its placement's depth or, where that is behind the
    /// nearest surface it covers, [`IN_FRONT`] of that surface (a depth
    /// camera sees what it sees in colour; a person drawn over a nearer desk
    /// with the depth of the wall behind would be seen in colour and not in
    /// depth, which no camera shows).
    fn draw_one(&mut self, p: &Placement, sprite: &Sprite, occluders: &[u16]) -> Drawn {
        let pixels = self.silhouette(p, sprite);
        let nearest_covered = pixels
            .iter()
            .map(|&(i, _)| self.depth[i])
            .filter(|&d| d != 0)
            .min();
        let depth_m = match (self.occlusion, nearest_covered) {
            (Occlusion::None, Some(d)) => p.depth_m.min(IN_FRONT * d as f64 / self.depth_scale),
            _ => p.depth_m,
        };
        let units = depth_units(depth_m, self.depth_scale);
        let mut drawn = Drawn {
            unoccluded_px: pixels.len(),
            depth_m,
            ..Drawn::default()
        };
        for (i, rgb) in pixels {
            let scene = occluders[i];
            if scene != 0 && scene <= units {
                continue; // the scene is in front of the person here
            }
            self.rgb[3 * i..3 * i + 3].copy_from_slice(&rgb);
            self.depth[i] = units;
            self.labels[i] = p.id;
            drawn.visible_px += 1;
        }
        drawn
    }

    /// The pixels (index, colour) of `p`'s cut-out inside the image.
    fn silhouette(&self, p: &Placement, sprite: &Sprite) -> Vec<(usize, [u8; 3])> {
        let (sw, sh) = (sprite.width() as f64, sprite.height() as f64);
        let scale = p.height_px / sh; // image pixels per sprite pixel
        if scale <= 0.0 || !scale.is_finite() {
            return Vec::new();
        }
        let up = Vector2::new(p.up_px[0], p.up_px[1]);
        let down = -up;
        let right = Vector2::new(-up.y, up.x);
        let radius = 0.5 * (sw * sw + sh * sh).sqrt() * scale + 1.0;
        let (cx, cy) = (p.centre_px[0], p.centre_px[1]);
        let x0 = (cx - radius).floor().max(0.0) as usize;
        let y0 = (cy - radius).floor().max(0.0) as usize;
        let x1 = ((cx + radius).ceil().max(0.0) as usize).min(self.width);
        let y1 = ((cy + radius).ceil().max(0.0) as usize).min(self.height);
        let mut pixels = Vec::new();
        for y in y0..y1 {
            for x in x0..x1 {
                // Pixel centre relative to the person's centre, in sprite pixels.
                let d = Vector2::new(x as f64 + 0.5 - cx, y as f64 + 0.5 - cy);
                let sx = d.dot(&right) / scale + sw / 2.0;
                let sy = d.dot(&down) / scale + sh / 2.0;
                if sx < 0.0 || sy < 0.0 || sx >= sw || sy >= sh {
                    continue;
                }
                let rgb = if sprite.smooth {
                    sprite.bilinear(if p.mirrored { sw - sx } else { sx }, sy)
                } else {
                    let mut col = sx as usize;
                    if p.mirrored {
                        col = sprite.width() - 1 - col;
                    }
                    let Some(rgb) = sprite.pixel(col, sy as usize) else {
                        continue;
                    };
                    rgb
                };
                pixels.push((y * self.width + x, rgb));
            }
        }
        pixels
    }
}

/// Without scene occlusion, a person drawn over nearer scene is put this
/// share of that scene's distance away (10 cm in front of a desk at 1 m).
pub const IN_FRONT: f64 = 0.9;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sprites::people;

    const CAM: Pinhole = Pinhole {
        fx: 500.0,
        fy: 500.0,
        cx: 320.0,
        cy: 240.0,
    };

    #[test]
    fn placement_scales_with_depth_and_points_up() {
        let up = Vector3::new(0.0, -1.0, 0.0);
        let pose = Isometry3::identity();
        let near = place(
            1,
            0,
            false,
            &Point3::new(0.0, 0.0, 1.0),
            &up,
            0.9,
            &pose,
            &CAM,
        )
        .unwrap();
        let far = place(
            1,
            0,
            false,
            &Point3::new(0.0, 0.0, 2.0),
            &up,
            0.9,
            &pose,
            &CAM,
        )
        .unwrap();
        assert!((near.height_px - 450.0).abs() < 1e-9);
        assert!((far.height_px - 225.0).abs() < 1e-9);
        assert!((near.up_px[1] + 1.0).abs() < 1e-9);
        assert!(place(
            1,
            0,
            false,
            &Point3::new(0.0, 0.0, -1.0),
            &up,
            0.9,
            &pose,
            &CAM
        )
        .is_none());
    }

    #[test]
    fn occlusion_follows_depth_and_untouched_pixels_stay() {
        let sprites = people();
        let (w, h) = (64, 48);
        let rgb0: Vec<u8> = (0..w * h * 3).map(|i| (i % 251) as u8).collect();
        // Left half of the scene is at 0.5 m (in front), right half at 4 m, one hole.
        let mut depth0: Vec<u16> = (0..w * h)
            .map(|i| if i % w < w / 2 { 2500 } else { 20000 })
            .collect();
        depth0[h / 2 * w + w - 5] = 0;
        let (mut rgb, mut depth, mut labels) = (rgb0.clone(), depth0.clone(), vec![0u8; w * h]);
        let p = Placement {
            id: 3,
            sprite: 0,
            mirrored: false,
            centre_px: [32.0, 24.0],
            up_px: [0.0, -1.0],
            height_px: 60.0,
            depth_m: 2.0,
        };
        let mut canvas = Canvas {
            width: w,
            height: h,
            rgb: &mut rgb,
            depth: &mut depth,
            labels: &mut labels,
            depth_scale: 5000.0,
            occlusion: Occlusion::Scene,
        };
        let visible = canvas.draw(std::slice::from_ref(&p), &sprites);
        assert!(visible[0] > 100);
        for i in 0..w * h {
            if labels[i] == 3 {
                assert!(i % w >= w / 2, "drawn behind the near half at {i}");
                assert_eq!(depth[i], 10000);
            } else {
                assert_eq!(labels[i], 0);
                assert_eq!(depth[i], depth0[i]);
                assert_eq!(rgb[3 * i..3 * i + 3], rgb0[3 * i..3 * i + 3]);
            }
        }
        assert_eq!(visible[0], labels.iter().filter(|&&l| l == 3).count());
    }

    #[test]
    fn narrow_depth_holes_occlude_like_their_neighbours_and_wide_ones_stay_open() {
        let w = 200;
        let mut row = vec![3000u16; w];
        row[10..20].fill(0); // between 3000 and 9000: takes the farther
        row[20..40].fill(9000);
        row[100..100 + HOLE_FILL_PX + 1].fill(0); // too wide: stays a hole
        row[w - 30..].fill(0); // the right-edge band: its one neighbour
        let filled = occluder_depth(&row, w);
        assert!(filled[10..20].iter().all(|&d| d == 9000));
        assert!(filled[100..100 + HOLE_FILL_PX + 1].iter().all(|&d| d == 0));
        assert!(filled[w - 30..].iter().all(|&d| d == 3000));
        assert_eq!(filled[..10], row[..10]);
        // A person at 1 m is hidden by the desk at 0.6 m where the band has no depth.
        let (w, h) = (64, 48);
        let mut depth: Vec<u16> = vec![3000; w * h];
        for y in 0..h {
            depth[y * w + w - 8..(y + 1) * w].fill(0);
        }
        let (mut rgb, mut labels) = (vec![0u8; w * h * 3], vec![0u8; w * h]);
        let p = Placement {
            id: 1,
            sprite: 0,
            mirrored: false,
            centre_px: [w as f64 - 4.0, 24.0],
            up_px: [0.0, -1.0],
            height_px: 40.0,
            depth_m: 1.0,
        };
        let mut canvas = Canvas {
            width: w,
            height: h,
            rgb: &mut rgb,
            depth: &mut depth,
            labels: &mut labels,
            depth_scale: 5000.0,
            occlusion: Occlusion::Scene,
        };
        assert_eq!(canvas.draw(&[p], &people()), vec![0]);
        assert!(depth
            .iter()
            .enumerate()
            .all(|(i, &d)| d == if i % w >= w - 8 { 0 } else { 3000 }));
    }

    #[test]
    fn without_scene_occlusion_a_person_is_drawn_whole_and_in_front_of_nearer_scene() {
        let (w, h) = (64, 48);
        let p = Placement {
            id: 2,
            sprite: 0,
            mirrored: false,
            centre_px: [32.0, 24.0],
            up_px: [0.0, -1.0],
            height_px: 40.0,
            depth_m: 2.0,
        };
        let drawn = |occlusion| {
            let mut depth = vec![2500u16; w * h]; // the scene at 0.5 m
            let (mut rgb, mut labels) = (vec![0u8; w * h * 3], vec![0u8; w * h]);
            let mut canvas = Canvas {
                width: w,
                height: h,
                rgb: &mut rgb,
                depth: &mut depth,
                labels: &mut labels,
                depth_scale: 5000.0,
                occlusion,
            };
            let visible = canvas.draw(std::slice::from_ref(&p), &people())[0];
            // Placed at 2 m behind the scene, drawn over it: in front of it.
            let person_depth = depth.iter().filter(|&&d| d == 2250).count();
            (visible, person_depth)
        };
        assert_eq!(drawn(Occlusion::Scene), (0, 0));
        let (visible, person_depth) = drawn(Occlusion::None);
        assert!(visible > 300, "{visible} pixels drawn");
        assert_eq!(person_depth, visible);
    }

    #[test]
    fn nearer_person_covers_farther_one_whatever_the_order() {
        let sprites = people();
        let (w, h) = (64, 48);
        let mk = |id, depth_m| Placement {
            id,
            sprite: 0,
            mirrored: id == 2,
            centre_px: [32.0, 24.0],
            up_px: [0.0, -1.0],
            height_px: 40.0,
            depth_m,
        };
        for placements in [vec![mk(1, 1.0), mk(2, 2.0)], vec![mk(2, 2.0), mk(1, 1.0)]] {
            let (mut rgb, mut depth, mut labels) =
                (vec![0u8; w * h * 3], vec![0u16; w * h], vec![0u8; w * h]);
            let mut c = Canvas {
                width: w,
                height: h,
                rgb: &mut rgb,
                depth: &mut depth,
                labels: &mut labels,
                depth_scale: 5000.0,
                occlusion: Occlusion::Scene,
            };
            let counted = c.draw_counted(&placements, &sprites);
            let centre = 24 * w + 32;
            assert_eq!(labels[centre], 1);
            assert_eq!(depth[centre], 5000);
            // The farther one is mostly hidden; the nearer one not at all.
            let near = placements.iter().position(|p| p.id == 1).unwrap();
            let far = 1 - near;
            assert_eq!(counted[near].visible_px, counted[near].unoccluded_px);
            assert!(
                counted[far].visible_px < counted[far].unoccluded_px / 2,
                "{counted:?}"
            );
            assert_eq!(
                counted[far].visible_px,
                labels.iter().filter(|&&l| l == 2).count()
            );
        }
    }
}
