//! Aspect-preserving resize into a square network input with grey padding
//! (value 114/255), as the YOLOv8 export expects, and the inverse mapping.

use raster::RgbView;

/// Geometry of one letterbox.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Letterbox {
    /// Side of the square input.
    pub size: usize,
    /// Input pixels per image pixel.
    pub scale: f32,
    /// Padding left and top (input pixels).
    pub pad_x: usize,
    /// See `pad_x`.
    pub pad_y: usize,
    /// Size of the resized image inside the input.
    pub inner_w: usize,
    /// See `inner_w`.
    pub inner_h: usize,
}

/// The grey of the padding (Ultralytics' 114 of 255).
pub const PAD_VALUE: f32 = 114.0 / 255.0;

impl Letterbox {
    /// A `width` x `height` image fitted into a `size` x `size` input.
    pub fn new(width: usize, height: usize, size: usize) -> Self {
        let scale = (size as f32 / width as f32).min(size as f32 / height as f32);
        let inner_w = ((width as f32 * scale).round() as usize).min(size);
        let inner_h = ((height as f32 * scale).round() as usize).min(size);
        // Ultralytics rounds the halves of the padding this way.
        let pad_x = ((size - inner_w) as f32 / 2.0 - 0.1).round() as usize;
        let pad_y = ((size - inner_h) as f32 / 2.0 - 0.1).round() as usize;
        Self {
            size,
            scale,
            pad_x,
            pad_y,
            inner_w,
            inner_h,
        }
    }

    /// Writes the planar RGB float input (`3*size*size`, values 0..1) from an
    /// RGB8 image, bilinear with pixel centres aligned (OpenCV INTER_LINEAR).
    pub fn fill_input(&self, rgb: RgbView, out: &mut [f32]) {
        let (width, height) = (rgb.width, rgb.height);
        let plane = self.size * self.size;
        out.fill(PAD_VALUE);
        let sx = width as f32 / self.inner_w as f32;
        let sy = height as f32 / self.inner_h as f32;
        for y in 0..self.inner_h {
            let fy = ((y as f32 + 0.5) * sy - 0.5).clamp(0.0, (height - 1) as f32);
            let y0 = fy as usize;
            let y1 = (y0 + 1).min(height - 1);
            let wy = fy - y0 as f32;
            for x in 0..self.inner_w {
                let fx = ((x as f32 + 0.5) * sx - 0.5).clamp(0.0, (width - 1) as f32);
                let x0 = fx as usize;
                let x1 = (x0 + 1).min(width - 1);
                let wx = fx - x0 as f32;
                let o = (y + self.pad_y) * self.size + x + self.pad_x;
                for c in 0..3 {
                    let p = |xx: usize, yy: usize| rgb.at(xx, yy)[c] as f32;
                    let top = p(x0, y0) * (1.0 - wx) + p(x1, y0) * wx;
                    let bottom = p(x0, y1) * (1.0 - wx) + p(x1, y1) * wx;
                    out[c * plane + o] = (top * (1.0 - wy) + bottom * wy) / 255.0;
                }
            }
        }
    }

    /// Input coordinates of an image point.
    pub fn to_input(&self, x: f32, y: f32) -> (f32, f32) {
        (
            x * self.scale + self.pad_x as f32,
            y * self.scale + self.pad_y as f32,
        )
    }

    /// Image coordinates of an input point.
    pub fn to_image(&self, x: f32, y: f32) -> (f32, f32) {
        (
            (x - self.pad_x as f32) / self.scale,
            (y - self.pad_y as f32) / self.scale,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn vga_into_320_pads_top_and_bottom() {
        let lb = Letterbox::new(640, 480, 320);
        assert_eq!(
            (lb.inner_w, lb.inner_h, lb.pad_x, lb.pad_y),
            (320, 240, 0, 40)
        );
        assert_eq!(lb.to_image(160.0, 160.0), (320.0, 240.0));
        assert_eq!(lb.to_input(320.0, 240.0), (160.0, 160.0));
    }

    #[test]
    fn input_is_padded_and_scaled() {
        let lb = Letterbox::new(4, 2, 4);
        let rgb = vec![255u8; 4 * 2 * 3];
        let mut out = vec![0.0; 3 * 16];
        lb.fill_input(RgbView::from_bytes(&rgb, 4, 2).unwrap(), &mut out);
        // Rows 0 and 3 are padding, rows 1-2 are the (white) image.
        assert!((out[0] - PAD_VALUE).abs() < 1e-6);
        assert!((out[4] - 1.0).abs() < 1e-6 && (out[11] - 1.0).abs() < 1e-6);
        assert!((out[12] - PAD_VALUE).abs() < 1e-6);
    }
}
