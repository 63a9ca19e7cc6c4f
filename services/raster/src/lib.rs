//! The project's one image type, for grey, colour, depth and mask images
//! alike: [`Image`] owns its pixels, [`ImageView`] borrows them (a frame in
//! shared memory, read in place). Pixels are row-major, `T` per pixel:
//! `u8` or `f32` grey, `[u8; 3]` RGB, `[u8; 2]` a depth camera's raw
//! native-endian u16, `bool` a mask.
//!
//! The one RGB-to-grey formula ([`luma`]) is here too, so ORB extraction,
//! optical flow and every other reader see the same grey values.

#![deny(missing_docs)]

mod grey;

pub use grey::{luma, LUMA_WEIGHTS};

/// An owned image: `width x height` pixels, row by row.
#[derive(Debug, Clone, PartialEq)]
pub struct Image<T> {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// The pixels, row by row (`width * height` of them).
    pub data: Vec<T>,
}

/// Grey levels 0-255 (ORB extraction's image).
pub type GrayU8 = Image<u8>;
/// Grey levels 0-255 as floats (optical flow's image).
pub type GrayF32 = Image<f32>;

impl<T: Copy> Image<T> {
    /// An image of `width x height` pixels, all `value`.
    pub fn filled(width: usize, height: usize, value: T) -> Self {
        Self {
            width,
            height,
            data: vec![value; width * height],
        }
    }

    /// The pixel at column `x`, row `y` (inside the image).
    #[inline]
    pub fn at(&self, x: usize, y: usize) -> T {
        self.data[y * self.width + x]
    }

    /// Row `y`'s pixels.
    #[inline]
    pub fn row(&self, y: usize) -> &[T] {
        &self.data[y * self.width..(y + 1) * self.width]
    }

    /// The same size, each pixel through `f`.
    pub fn map<U>(&self, f: impl FnMut(T) -> U) -> Image<U> {
        Image {
            width: self.width,
            height: self.height,
            data: self.data.iter().copied().map(f).collect(),
        }
    }

    /// The image borrowed.
    pub fn view(&self) -> ImageView<'_, T> {
        ImageView {
            width: self.width,
            height: self.height,
            data: &self.data,
        }
    }
}

/// A borrowed image: `width x height` pixels, row by row, in someone else's
/// memory (a frame in shared memory, a decoded file).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImageView<'a, T> {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// The pixels, row by row (`width * height` of them).
    pub data: &'a [T],
}

/// Colour, three bytes (R, G, B) a pixel.
pub type RgbView<'a> = ImageView<'a, [u8; 3]>;

impl<'a, T: Copy> ImageView<'a, T> {
    /// `data` as a `width x height` image; None when it holds another
    /// number of pixels.
    pub fn new(width: usize, height: usize, data: &'a [T]) -> Option<Self> {
        (width.checked_mul(height) == Some(data.len())).then_some(Self {
            width,
            height,
            data,
        })
    }

    /// The pixel at column `x`, row `y` (inside the image).
    #[inline]
    pub fn at(&self, x: usize, y: usize) -> T {
        self.data[y * self.width + x]
    }

    /// The pixel at column `x`, row `y`; None outside the image.
    #[inline]
    pub fn get(&self, x: usize, y: usize) -> Option<T> {
        if x < self.width && y < self.height {
            Some(self.data[y * self.width + x])
        } else {
            None
        }
    }

    /// Row `y`'s pixels.
    #[inline]
    pub fn row(&self, y: usize) -> &'a [T] {
        &self.data[y * self.width..(y + 1) * self.width]
    }

    /// An owned copy.
    pub fn to_image(&self) -> Image<T> {
        Image {
            width: self.width,
            height: self.height,
            data: self.data.to_vec(),
        }
    }
}

impl<'a, const N: usize> ImageView<'a, [u8; N]> {
    /// Bytes of `N` per pixel (RGB: 3; raw u16 depth: 2) read in place as
    /// a `width x height` image; None when `bytes` is not exactly that
    /// size.
    pub fn from_bytes(bytes: &'a [u8], width: usize, height: usize) -> Option<Self> {
        let (pixels, rest) = bytes.as_chunks::<N>();
        if rest.is_empty() {
            Self::new(width, height, pixels)
        } else {
            None
        }
    }

    /// The pixels' bytes, row by row.
    pub fn as_bytes(&self) -> &'a [u8] {
        self.data.as_flattened()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pixels_are_row_major() {
        let img = Image {
            width: 3,
            height: 2,
            data: vec![0, 1, 2, 3, 4, 5],
        };
        assert_eq!(img.at(2, 0), 2);
        assert_eq!(img.at(0, 1), 3);
        assert_eq!(img.row(1), &[3, 4, 5]);
        assert_eq!(img.view().get(2, 1), Some(5));
        assert_eq!(img.view().get(3, 1), None);
        assert_eq!(img.view().get(0, 2), None);
        assert_eq!(img.map(|v| v * 2).data, vec![0, 2, 4, 6, 8, 10]);
        assert_eq!(img.view().to_image(), img);
    }

    #[test]
    fn bytes_are_read_in_place_only_at_their_exact_size() {
        let bytes: Vec<u8> = (0..18).collect();
        let rgb = RgbView::from_bytes(&bytes, 3, 2).unwrap();
        assert_eq!(rgb.at(1, 1), [12, 13, 14]);
        assert_eq!(rgb.as_bytes().as_ptr(), bytes.as_ptr());
        assert!(RgbView::from_bytes(&bytes, 3, 3).is_none());
        assert!(RgbView::from_bytes(&bytes[..17], 3, 2).is_none());
        assert!(ImageView::<[u8; 2]>::from_bytes(&bytes, 3, 3).is_some());
        assert!(ImageView::new(usize::MAX, 2, &bytes).is_none());
        assert_eq!(Image::filled(2, 2, 7u8).data, vec![7; 4]);
    }
}
