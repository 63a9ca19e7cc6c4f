//! Small raster charts for the run report: line/dot charts over time and
//! histograms, with numeric tick labels in a built-in 3x5 pixel font (no
//! font files, no plotting dependency). Titles and axis names live in the
//! report's captions.

use image::{Rgb, RgbImage};
use slam::plot::{line, put};

pub const RED: Rgb<u8> = Rgb([215, 40, 40]);
pub const BLUE: Rgb<u8> = Rgb([40, 90, 215]);
pub const GREEN: Rgb<u8> = Rgb([30, 160, 70]);
pub const GREY: Rgb<u8> = Rgb([120, 120, 120]);
const LIGHT: Rgb<u8> = Rgb([225, 225, 225]);
const INK: Rgb<u8> = Rgb([40, 40, 40]);
const WHITE: Rgb<u8> = Rgb([255, 255, 255]);

/// 3x5 glyphs, rows top to bottom, 3 bits each (MSB left).
fn glyph(c: char) -> Option<[u8; 5]> {
    Some(match c {
        '0' => [7, 5, 5, 5, 7],
        '1' => [2, 6, 2, 2, 7],
        '2' => [7, 1, 7, 4, 7],
        '3' => [7, 1, 3, 1, 7],
        '4' => [5, 5, 7, 1, 1],
        '5' => [7, 4, 7, 1, 7],
        '6' => [7, 4, 7, 5, 7],
        '7' => [7, 1, 1, 2, 2],
        '8' => [7, 5, 7, 5, 7],
        '9' => [7, 5, 7, 1, 7],
        '.' => [0, 0, 0, 0, 2],
        '-' => [0, 0, 7, 0, 0],
        _ => return None,
    })
}

/// Draws `text` (digits, '.', '-') with its top-left at (x, y), `scale`
/// pixels per font pixel; returns the width drawn.
pub fn text(img: &mut RgbImage, x: f64, y: f64, text: &str, scale: u32, colour: Rgb<u8>) -> f64 {
    let mut cx = x;
    for c in text.chars() {
        if let Some(rows) = glyph(c) {
            for (r, bits) in rows.iter().enumerate() {
                for col in 0..3 {
                    if bits & (4 >> col) != 0 {
                        for dy in 0..scale {
                            for dx in 0..scale {
                                put(
                                    img,
                                    cx + (col * scale + dx) as f64,
                                    y + (r as u32 * scale + dy) as f64,
                                    colour,
                                );
                            }
                        }
                    }
                }
            }
        }
        cx += 4.0 * scale as f64;
    }
    cx - x
}

/// A tick label with as many decimals as the step needs.
fn label(v: f64, step: f64) -> String {
    let decimals = if step >= 1.0 {
        0
    } else {
        (-step.log10()).ceil() as usize
    };
    format!("{v:.decimals$}")
}

/// A "nice" tick step (1, 2 or 5 times a power of ten) giving about `n` ticks.
fn nice_step(span: f64, n: f64) -> f64 {
    let raw = (span / n).max(1e-12);
    let p = 10f64.powf(raw.log10().floor());
    let m = raw / p;
    p * if m < 1.5 {
        1.0
    } else if m < 3.5 {
        2.0
    } else if m < 7.5 {
        5.0
    } else {
        10.0
    }
}

/// How a series is drawn.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Style {
    Line,
    Dots,
}

pub struct Series {
    pub points: Vec<(f64, f64)>,
    pub colour: Rgb<u8>,
    pub style: Style,
}

/// The plot area and the mapping from data to pixels.
struct Axes {
    x0: f64,
    x1: f64,
    y0: f64,
    y1: f64,
    left: f64,
    top: f64,
    right: f64,
    bottom: f64,
}

impl Axes {
    fn px(&self, (x, y): (f64, f64)) -> (f64, f64) {
        let fx = (x - self.x0) / (self.x1 - self.x0).max(1e-12);
        let fy = (y - self.y0) / (self.y1 - self.y0).max(1e-12);
        (
            self.left + fx * (self.right - self.left),
            self.bottom - fy * (self.bottom - self.top),
        )
    }

    /// Grid, frame and tick labels on both axes.
    fn draw(&self, img: &mut RgbImage) {
        let ystep = nice_step(self.y1 - self.y0, 4.0);
        let mut v = (self.y0 / ystep).ceil() * ystep;
        while v <= self.y1 + 1e-9 {
            let (_, py) = self.px((self.x0, v));
            line(img, (self.left, py), (self.right, py), LIGHT);
            let s = label(v, ystep);
            let w = 8.0 * s.len() as f64;
            text(img, self.left - w - 4.0, py - 5.0, &s, 2, INK);
            v += ystep;
        }
        let xstep = nice_step(self.x1 - self.x0, 6.0);
        let mut v = (self.x0 / xstep).ceil() * xstep;
        while v <= self.x1 + 1e-9 {
            let (px, _) = self.px((v, self.y0));
            line(img, (px, self.top), (px, self.bottom), LIGHT);
            let s = label(v, xstep);
            text(
                img,
                px - 4.0 * s.len() as f64,
                self.bottom + 6.0,
                &s,
                2,
                INK,
            );
            v += xstep;
        }
        for (a, b) in [
            ((self.left, self.top), (self.right, self.top)),
            ((self.left, self.bottom), (self.right, self.bottom)),
            ((self.left, self.top), (self.left, self.bottom)),
            ((self.right, self.top), (self.right, self.bottom)),
        ] {
            line(img, a, b, GREY);
        }
    }
}

/// Data range of `series` (y from 0 when all values are positive).
fn range(series: &[Series]) -> (f64, f64, f64, f64) {
    let all = series.iter().flat_map(|s| s.points.iter());
    let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, 0.0f64, f64::MIN);
    for &(x, y) in all {
        x0 = x0.min(x);
        x1 = x1.max(x);
        y0 = y0.min(y);
        y1 = y1.max(y);
    }
    if x0 > x1 {
        return (0.0, 1.0, 0.0, 1.0);
    }
    if x1 - x0 < 1e-9 {
        x1 = x0 + 1.0;
    }
    if y1 - y0 < 1e-9 {
        y1 = y0 + 1.0;
    }
    (x0, x1, y0, y1 * 1.05)
}

/// A chart of `series` over a shared x axis.
pub fn chart(width: u32, height: u32, series: &[Series], y_max: Option<f64>) -> RgbImage {
    let mut img = RgbImage::from_pixel(width, height, WHITE);
    let (x0, x1, y0, mut y1) = range(series);
    if let Some(m) = y_max {
        y1 = m;
    }
    let axes = Axes {
        x0,
        x1,
        y0,
        y1,
        left: 64.0,
        top: 12.0,
        right: width as f64 - 16.0,
        bottom: height as f64 - 26.0,
    };
    axes.draw(&mut img);
    for s in series {
        match s.style {
            Style::Line => {
                for w in s.points.windows(2) {
                    line(&mut img, axes.px(w[0]), axes.px(w[1]), s.colour);
                }
            }
            Style::Dots => {
                for &p in &s.points {
                    let (px, py) = axes.px(p);
                    for d in [(-1.0, 0.0), (1.0, 0.0), (0.0, -1.0), (0.0, 1.0), (0.0, 0.0)] {
                        put(&mut img, px + d.0, py + d.1, s.colour);
                    }
                }
            }
        }
    }
    img
}

/// A histogram of `values` over [0, x_max] in `bins` bars, x axis in the
/// values' unit, y axis the count.
pub fn histogram(width: u32, height: u32, values: &[f64], x_max: f64, colour: Rgb<u8>) -> RgbImage {
    let bins = 40usize;
    let x_max = x_max.max(1e-9);
    let mut counts = vec![0usize; bins];
    for &v in values {
        let b = ((v / x_max) * bins as f64).floor();
        counts[(b.max(0.0) as usize).min(bins - 1)] += 1;
    }
    let top = counts.iter().copied().max().unwrap_or(1).max(1) as f64;
    let mut img = RgbImage::from_pixel(width, height, WHITE);
    let axes = Axes {
        x0: 0.0,
        x1: x_max,
        y0: 0.0,
        y1: top * 1.1,
        left: 64.0,
        top: 12.0,
        right: width as f64 - 16.0,
        bottom: height as f64 - 26.0,
    };
    axes.draw(&mut img);
    for (b, &n) in counts.iter().enumerate() {
        if n == 0 {
            continue;
        }
        let (xa, ya) = axes.px((b as f64 * x_max / bins as f64, n as f64));
        let (xb, yb) = axes.px(((b + 1) as f64 * x_max / bins as f64, 0.0));
        for x in (xa.ceil() as i64)..(xb.floor() as i64) {
            line(&mut img, (x as f64, ya), (x as f64, yb - 1.0), colour);
        }
    }
    img
}

/// Stacks images vertically (same width assumed; narrower ones are padded).
pub fn stack(images: &[RgbImage]) -> RgbImage {
    let w = images.iter().map(|i| i.width()).max().unwrap_or(1);
    let h: u32 = images.iter().map(|i| i.height()).sum::<u32>().max(1);
    let mut out = RgbImage::from_pixel(w, h, WHITE);
    let mut y = 0;
    for i in images {
        image::imageops::replace(&mut out, i, 0, y as i64);
        y += i.height();
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nice_steps_are_1_2_5() {
        assert_eq!(nice_step(1.0, 4.0), 0.2);
        assert_eq!(nice_step(0.47, 4.0), 0.1);
        assert_eq!(nice_step(150.0, 6.0), 20.0);
        assert_eq!(label(0.25, 0.05), "0.25");
        assert_eq!(label(40.0, 20.0), "40");
    }

    #[test]
    fn series_land_where_their_values_say() {
        let s = Series {
            points: vec![(0.0, 0.0), (10.0, 1.0)],
            colour: RED,
            style: Style::Line,
        };
        let img = chart(300, 200, &[s], Some(1.0));
        // The line ends at the top-right corner of the plot area.
        let (right, top) = (300 - 16, 12);
        assert_eq!(*img.get_pixel(right, top), RED);
        assert_eq!(*img.get_pixel(64, 200 - 26), RED);
        assert!(
            img.pixels().filter(|p| **p == INK).count() > 50,
            "tick labels"
        );
    }

    #[test]
    fn histogram_bars_count_values() {
        let values = vec![1.0; 10];
        let img = histogram(400, 200, &values, 40.0, BLUE);
        let blue = img.pixels().filter(|p| **p == BLUE).count();
        assert!(blue > 100, "{blue}");
        // Nothing beyond the first bin's bar.
        let far_col = 64 + (400 - 16 - 64) / 2;
        assert!((0..200).all(|y| *img.get_pixel(far_col, y) != BLUE));
    }
}
