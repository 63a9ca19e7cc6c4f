//! Cut-outs of real people with binary alpha masks, embedded in the binary
//! so that `dynslam synth` and the default run need no download. Made by
//! `tools/make_people_sprites.py` from photos in the scikit-image wheel;
//! provenance and licences in `assets/PROVENANCE.md`.

use image::RgbaImage;

/// One person: RGBA pixels, alpha 0 or 255.
pub struct Sprite {
    pub name: &'static str,
    pub image: RgbaImage,
}

impl Sprite {
    pub fn width(&self) -> usize {
        self.image.width() as usize
    }

    pub fn height(&self) -> usize {
        self.image.height() as usize
    }

    /// The RGB of pixel (x, y) when it belongs to the person.
    pub fn pixel(&self, x: usize, y: usize) -> Option<[u8; 3]> {
        let p = self.image.get_pixel(x as u32, y as u32).0;
        (p[3] >= 128).then_some([p[0], p[1], p[2]])
    }
}

const PEOPLE: [(&str, &[u8]); 2] = [
    (
        "astronaut",
        include_bytes!("../../../assets/people/astronaut.png"),
    ),
    (
        "cameraman",
        include_bytes!("../../../assets/people/cameraman.png"),
    ),
];

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
}
