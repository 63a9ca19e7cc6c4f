//! Dynamic-object masks applied at feature detection: a corner inside the
//! (dilated) mask is rejected before anything is computed for it.

/// A label image's non-zero pixels grown by a radius, asked per corner.
pub struct DynamicMask {
    width: usize,
    height: usize,
    masked: Vec<bool>,
}

impl DynamicMask {
    /// The mask of `labels` (non-zero: dynamic object), grown by `r` pixels.
    pub fn new(labels: &[u8], width: usize, height: usize, r: usize) -> Self {
        Self {
            width,
            height,
            masked: dilate(labels, width, height, r),
        }
    }

    /// A corner at level-0 pixel (x, y) may be used.
    pub fn keeps(&self, x: f32, y: f32) -> bool {
        let (xi, yi) = (
            (x as usize).min(self.width - 1),
            (y as usize).min(self.height - 1),
        );
        !self.masked[yi * self.width + xi]
    }
}

/// Binary mask of non-zero labels grown by `r` pixels (square).
fn dilate(labels: &[u8], width: usize, height: usize, r: usize) -> Vec<bool> {
    let mut rows = vec![false; width * height];
    for y in 0..height {
        let mut last: Option<usize> = None;
        for x in 0..width {
            if labels[y * width + x] != 0 {
                last = Some(x);
            }
            rows[y * width + x] = last.is_some_and(|l| x - l <= r);
        }
        let mut next: Option<usize> = None;
        for x in (0..width).rev() {
            if labels[y * width + x] != 0 {
                next = Some(x);
            }
            rows[y * width + x] |= next.is_some_and(|n| n - x <= r);
        }
    }
    let mut out = vec![false; width * height];
    for x in 0..width {
        let mut last: Option<usize> = None;
        for y in 0..height {
            if rows[y * width + x] {
                last = Some(y);
            }
            out[y * width + x] = last.is_some_and(|l| y - l <= r);
        }
        let mut next: Option<usize> = None;
        for y in (0..height).rev() {
            if rows[y * width + x] {
                next = Some(y);
            }
            out[y * width + x] |= next.is_some_and(|n| n - y <= r);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dilation_grows_by_the_radius() {
        let (w, h) = (9, 7);
        let mut l = vec![0u8; w * h];
        l[3 * w + 4] = 1;
        let d = dilate(&l, w, h, 2);
        assert_eq!(d.iter().filter(|&&b| b).count(), 25);
        assert!(d[w + 2] && !d[w + 1]);
        let mask = DynamicMask::new(&l, w, h, 1);
        assert!(!mask.keeps(4.5, 2.0) && mask.keeps(1.0, 1.0));
    }
}
