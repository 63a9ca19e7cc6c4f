//! Cut-outs of real people with binary alpha masks, embedded in the binary
//! so that `dynslam synth` and the default run need no download. Made by
//! `tools/make_people_sprites.py` from photos in the scikit-image and
//! matplotlib wheels; provenance and licences in `assets/PROVENANCE.md`.

use image::RgbaImage;

/// One person: RGBA pixels, alpha 0 or 255.
pub struct Sprite {
    /// Its name (the asset file's).
    pub name: &'static str,
    /// The pixels.
    pub image: RgbaImage,
    /// Drawn with bilinear sampling (an opaque, drawn texture: nearest
    /// sampling of its fine print would flicker between frames, which no
    /// camera's optics do); the photos' cut-outs are drawn nearest, which
    /// keeps their alpha edge exact.
    pub smooth: bool,
}

impl Sprite {
    /// Width in pixels.
    pub fn width(&self) -> usize {
        self.image.width() as usize
    }

    /// Height in pixels.
    pub fn height(&self) -> usize {
        self.image.height() as usize
    }

    /// The RGB of pixel (x, y) when it belongs to the person.
    pub fn pixel(&self, x: usize, y: usize) -> Option<[u8; 3]> {
        let p = self.image.get_pixel(x as u32, y as u32).0;
        (p[3] >= 128).then_some([p[0], p[1], p[2]])
    }

    /// The RGB at sprite coordinates (sx, sy) (pixel centres at +0.5),
    /// bilinear between the four nearest pixels, for opaque sprites.
    pub fn bilinear(&self, sx: f64, sy: f64) -> [u8; 3] {
        let (w, h) = (self.width() as f64, self.height() as f64);
        let x = (sx - 0.5).clamp(0.0, w - 1.0);
        let y = (sy - 0.5).clamp(0.0, h - 1.0);
        let (x0, y0) = (x.floor() as u32, y.floor() as u32);
        let (x1, y1) = ((x0 + 1).min(w as u32 - 1), (y0 + 1).min(h as u32 - 1));
        let (fx, fy) = (x - x0 as f64, y - y0 as f64);
        let p = |x, y| self.image.get_pixel(x, y).0;
        let (a, b, c, d) = (p(x0, y0), p(x1, y0), p(x0, y1), p(x1, y1));
        std::array::from_fn(|i| {
            let top = a[i] as f64 * (1.0 - fx) + b[i] as f64 * fx;
            let bottom = c[i] as f64 * (1.0 - fx) + d[i] as f64 * fx;
            (top * (1.0 - fy) + bottom * fy).round() as u8
        })
    }
}

const PEOPLE: [(&str, &[u8]); 3] = [
    (
        "astronaut",
        include_bytes!("../../../assets/people/astronaut.png"),
    ),
    (
        "cameraman",
        include_bytes!("../../../assets/people/cameraman.png"),
    ),
    (
        "hopper",
        include_bytes!("../../../assets/people/hopper.png"),
    ),
];

/// A carried cardboard box (a mover that no class list names, for the
/// SLAM's motion check): drawn here, not a photo, so no licence to track.
/// Brown board, a darker border, printed blocks and tape in a fixed random
/// layout: corners for ORB to find.
pub fn moving_box() -> Sprite {
    const N: u32 = 128;
    let mut rng = slam_core::rng::SplitMix64::new(0xB0C5);
    let mut image = RgbaImage::from_pixel(N, N, image::Rgba([176, 134, 86, 255]));
    let fill = |image: &mut RgbaImage, x0: u32, y0: u32, w: u32, h: u32, c: [u8; 3]| {
        for y in y0..(y0 + h).min(N) {
            for x in x0..(x0 + w).min(N) {
                image.put_pixel(x, y, image::Rgba([c[0], c[1], c[2], 255]));
            }
        }
    };
    // Printing: a few large blocks, many small marks (letters, a barcode's
    // worth of detail) so that corners exist at the fine pyramid levels.
    for k in 0..260 {
        let (x, y) = (rng.below(N as usize) as u32, rng.below(N as usize) as u32);
        let big = k < 20;
        let (w, h) = if big {
            (6 + rng.below(14) as u32, 6 + rng.below(14) as u32)
        } else {
            (1 + rng.below(4) as u32, 1 + rng.below(4) as u32)
        };
        let shade = match rng.below(3) {
            0 => [40, 32, 28],
            1 => [235, 228, 210],
            _ => [120, 84, 50],
        };
        fill(&mut image, x, y, w, h, shade);
    }
    // Tape across the middle, and the board's edge.
    fill(&mut image, 0, N / 2 - 6, N, 12, [214, 196, 150]);
    for (x, y, w, h) in [
        (0, 0, N, 4),
        (0, N - 4, N, 4),
        (0, 0, 4, N),
        (N - 4, 0, 4, N),
    ] {
        fill(&mut image, x, y, w, h, [96, 66, 38]);
    }
    Sprite {
        name: "box",
        image,
        smooth: true,
    }
}

/// The embedded people, decoded.
pub fn people() -> Vec<Sprite> {
    PEOPLE
        .iter()
        .map(|(name, png)| Sprite {
            name,
            // Embedded at build time and decoded by a test: cannot fail at run time.
            image: image::load_from_memory(png)
                .expect("embedded sprite is a valid PNG")
                .to_rgba8(),
            smooth: false,
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn embedded_people_decode_with_binary_alpha_and_a_person_inside() {
        for s in people() {
            let alpha: Vec<u8> = s.image.pixels().map(|p| p.0[3]).collect();
            assert!(alpha.iter().all(|&a| a == 0 || a == 255), "{}", s.name);
            let inside = alpha.iter().filter(|&&a| a == 255).count();
            let frac = inside as f64 / alpha.len() as f64;
            assert!((0.3..0.95).contains(&frac), "{}: {frac}", s.name);
            assert_eq!(s.height(), 400);
        }
    }

    #[test]
    fn the_box_is_opaque_and_textured() {
        let b = moving_box();
        assert!(b.image.pixels().all(|p| p.0[3] == 255));
        let mut shades: Vec<[u8; 3]> = b.image.pixels().map(|p| [p.0[0], p.0[1], p.0[2]]).collect();
        shades.sort();
        shades.dedup();
        assert!(shades.len() >= 5, "{shades:?}");
    }
}
