//! A synthetic moving object over a real image, for tests and benchmarks of
//! propagation: an ellipse textured from a second real image, moving with
//! the object, over a (possibly shifted) background. The object's true mask
//! comes with every frame.

/// One rendered frame: RGB8 and the object's true mask.
pub struct Rendered {
    /// RGB8, row by row.
    pub rgb: Vec<u8>,
    /// The object's true mask, row by row.
    pub mask: Vec<bool>,
}

/// Renders `background` shifted by `bg_shift`, with an ellipse of radii
/// `(55, 75) * scale` centred at `centre`, textured from `texture` (both
/// RGB8, `width x height`).
pub fn render(
    background: &[u8],
    texture: &[u8],
    width: usize,
    height: usize,
    bg_shift: (f32, f32),
    centre: (f32, f32),
    scale: f32,
) -> Rendered {
    let (rx, ry) = (55.0 * scale, 75.0 * scale);
    let (cx_tex, cy_tex) = (width as f32 / 2.0, height as f32 / 2.0);
    let mut rgb = vec![0u8; width * height * 3];
    let mut mask = vec![false; width * height];
    for y in 0..height {
        for x in 0..width {
            let (dx, dy) = ((x as f32 - centre.0) / rx, (y as f32 - centre.1) / ry);
            let inside = dx * dx + dy * dy <= 1.0;
            let (sx, sy, img) = if inside {
                (
                    (x as f32 - centre.0) / scale + cx_tex,
                    (y as f32 - centre.1) / scale + cy_tex,
                    texture,
                )
            } else {
                (x as f32 - bg_shift.0, y as f32 - bg_shift.1, background)
            };
            let ix = sx.round().clamp(0.0, (width - 1) as f32) as usize;
            let iy = sy.round().clamp(0.0, (height - 1) as f32) as usize;
            let (o, i) = ((y * width + x) * 3, (iy * width + ix) * 3);
            rgb[o..o + 3].copy_from_slice(&img[i..i + 3]);
            mask[y * width + x] = inside;
        }
    }
    Rendered { rgb, mask }
}

/// Intersection over union of label `label` in `labels` and `truth`.
pub fn iou(labels: &[u8], label: u8, truth: &[bool]) -> f64 {
    let (mut inter, mut union) = (0usize, 0usize);
    for (l, &t) in labels.iter().zip(truth) {
        let m = *l == label;
        inter += (m && t) as usize;
        union += (m || t) as usize;
    }
    inter as f64 / union.max(1) as f64
}
