//! A PNG of an estimated trajectory against ground truth: two panels, top
//! view (x-y) and side view (x-z), same scale on both axes, ground truth in
//! grey, the aligned estimate in red, the start marked by a green square.

use std::path::Path;

use image::{Rgb, RgbImage};
use nalgebra::Point3;

const PANEL: u32 = 420;
const MARGIN: f64 = 20.0;
const GREY: Rgb<u8> = Rgb([110, 110, 110]);
const RED: Rgb<u8> = Rgb([220, 30, 30]);
const GREEN: Rgb<u8> = Rgb([20, 170, 60]);
const FRAME: Rgb<u8> = Rgb([200, 200, 200]);

/// Draws `pairs` (ground truth, aligned estimate) into a 2-panel image.
pub fn trajectory_png(pairs: &[(Point3<f64>, Point3<f64>)]) -> RgbImage {
    let mut img = RgbImage::from_pixel(2 * PANEL, PANEL, Rgb([255, 255, 255]));
    for (panel, axis) in [(0u32, 1usize), (1, 2)] {
        let pts: Vec<(f64, f64)> = pairs
            .iter()
            .flat_map(|(g, e)| [(g.x, g[axis]), (e.x, e[axis])])
            .collect();
        let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
        for (x, y) in &pts {
            x0 = x0.min(*x);
            x1 = x1.max(*x);
            y0 = y0.min(*y);
            y1 = y1.max(*y);
        }
        let span = (x1 - x0).max(y1 - y0).max(1e-6);
        let scale = (PANEL as f64 - 2.0 * MARGIN) / span;
        let ox = panel as f64 * PANEL as f64
            + MARGIN
            + ((PANEL as f64 - 2.0 * MARGIN) - (x1 - x0) * scale) / 2.0;
        let oy = MARGIN + ((PANEL as f64 - 2.0 * MARGIN) - (y1 - y0) * scale) / 2.0;
        // Image y grows downwards; plot y upwards.
        let to_px = |(x, y): (f64, f64)| {
            (
                ox + (x - x0) * scale,
                PANEL as f64 - (oy + (y - y0) * scale),
            )
        };
        let base = panel * PANEL;
        for i in 0..PANEL {
            for (x, y) in [
                (base + i, 0),
                (base + i, PANEL - 1),
                (base, i),
                (base + PANEL - 1, i),
            ] {
                img.put_pixel(x, y, FRAME);
            }
        }
        for (which, colour) in [(0usize, GREY), (1, RED)] {
            let track: Vec<(f64, f64)> = pairs
                .iter()
                .map(|(g, e)| {
                    let p = if which == 0 { g } else { e };
                    to_px((p.x, p[axis]))
                })
                .collect();
            for w in track.windows(2) {
                line(&mut img, w[0], w[1], colour);
            }
        }
        if let Some((g, _)) = pairs.first() {
            let (cx, cy) = to_px((g.x, g[axis]));
            for dy in -3..=3 {
                for dx in -3..=3 {
                    put(&mut img, cx + dx as f64, cy + dy as f64, GREEN);
                }
            }
        }
    }
    img
}

pub fn put(img: &mut RgbImage, x: f64, y: f64, c: Rgb<u8>) {
    if x >= 0.0 && y >= 0.0 && (x as u32) < img.width() && (y as u32) < img.height() {
        img.put_pixel(x as u32, y as u32, c);
    }
}

pub fn line(img: &mut RgbImage, a: (f64, f64), b: (f64, f64), c: Rgb<u8>) {
    let steps = ((b.0 - a.0).abs().max((b.1 - a.1).abs()).ceil() as usize).max(1);
    for s in 0..=steps {
        let t = s as f64 / steps as f64;
        put(img, a.0 + t * (b.0 - a.0), a.1 + t * (b.1 - a.1), c);
    }
}

/// Writes the plot as PNG.
pub fn write_trajectory_png(
    path: &Path,
    pairs: &[(Point3<f64>, Point3<f64>)],
) -> anyhow::Result<()> {
    trajectory_png(pairs)
        .save(path)
        .map_err(|e| anyhow::anyhow!("cannot write {}: {e}", path.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn both_tracks_and_the_start_are_drawn() {
        let pairs: Vec<_> = (0..50)
            .map(|i| {
                let a = i as f64 * 0.1;
                (
                    Point3::new(a.cos(), a.sin(), 0.1 * a),
                    Point3::new(a.cos() + 0.05, a.sin(), 0.1 * a),
                )
            })
            .collect();
        let img = trajectory_png(&pairs);
        assert_eq!(img.dimensions(), (2 * PANEL, PANEL));
        let count = |c: Rgb<u8>| img.pixels().filter(|p| **p == c).count();
        assert!(
            count(RED) > 200 && count(GREY) > 200,
            "{} {}",
            count(RED),
            count(GREY)
        );
        assert_eq!(count(GREEN), 2 * 49);
    }
}
