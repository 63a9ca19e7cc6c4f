//! One frame as tracking sees it: ORB keypoints outside the dynamic mask,
//! undistorted, with their depth, colour and descriptors, bucketed in a
//! grid for search by projection.

use std::sync::Arc;

use crate::camera::{Bounds, Camera};
use crate::features::grid::Grid;
use crate::features::mask::DynamicMask;
use crate::features::orb::{Descriptor, GrayU8, KeyPoint, OrbExtractor};
use crate::flow::pyramid::{GrayF32, Pyramid};
use crate::map::KeyFrameObservation;
use crate::params::SlamParams;
use crate::tracking::small_image::SmallImage;

/// An RGB-D image pair with its optional dynamic-object mask.
#[derive(Debug, Clone, Copy)]
pub struct RgbdInput<'a> {
    /// RGB8, row-major.
    pub rgb: &'a [u8],
    /// Depth in `Camera::depth_scale` units per metre (0: no depth).
    pub depth: &'a [u16],
    /// Labels (non-zero: dynamic object), one per pixel.
    pub mask: Option<&'a [u8]>,
    /// Image columns.
    pub width: usize,
    /// Image rows.
    pub height: usize,
    /// Seconds (the exposure of the middle row with a rolling shutter).
    pub timestamp: f64,
}

impl RgbdInput<'_> {
    /// The buffers match the size (depth may be empty: a colour camera)
    /// and the image is big enough to track.
    pub fn is_well_formed(&self) -> bool {
        let pixels = self.width * self.height;
        self.width >= 64
            && self.height >= 64
            && self.rgb.len() == 3 * pixels
            && (self.depth.len() == pixels || self.depth.is_empty())
            && self.mask.is_none_or(|m| m.len() == pixels)
    }
}

/// One frame's features.
#[derive(Clone)]
pub struct Frame {
    /// The keypoints (pixels as detected, distorted).
    pub kps: Vec<KeyPoint>,
    /// Undistorted keypoint pixels.
    pub un: Vec<(f64, f64)>,
    /// One descriptor per keypoint.
    pub descs: Vec<Descriptor>,
    /// Metres, where the depth image had a value in range.
    pub depth: Vec<Option<f64>>,
    /// Colour under each keypoint.
    pub colours: Vec<[u8; 3]>,
    /// Keypoints by image cell, for matching in a window.
    pub grid: Grid,
    /// Undistorted image extent.
    pub bounds: Bounds,
    /// Each pyramid level's scale (`scale_factor^l`, f32 as the extractor
    /// computes it): looked up per keypoint in pose optimisation, where
    /// `powi` was a runtime call per observation (1.5 % of the SLAM's CPU).
    pub level_scales: Arc<[f64]>,
    /// Corners the dynamic mask rejected.
    pub masked: usize,
    /// Image columns and rows (the rolling shutter's extent is the rows).
    pub width: usize,
    /// See `width`.
    pub height: usize,
    /// The image averaged down and blurred: the turn since the last frame
    /// (`tracking::small_image`). Shared: tracking keeps the last one, a
    /// frame without some keypoints keeps its image.
    pub small: Option<Arc<SmallImage>>,
    /// The grey image's pyramid, where frames between keyframes are tracked
    /// by optical flow (`SlamParams::flow_frames`): the next frame follows
    /// this one's points in it.
    pub pyramid: Option<Arc<Pyramid>>,
}

/// Keypoints found in an image (raw pixels), their descriptors, and how
/// many the dynamic mask rejected.
pub struct Detected {
    /// The keypoints kept.
    pub kps: Vec<KeyPoint>,
    /// One descriptor per keypoint kept.
    pub descs: Vec<Descriptor>,
    /// Keypoints dropped because the dynamic mask covers them.
    pub masked: usize,
}

/// What turns keypoints into a frame: the camera, the parameters, the
/// undistorted image extent and the pyramid levels' scales.
pub struct FrameContext<'a> {
    /// The camera.
    pub camera: &'a Camera,
    /// The SLAM settings.
    pub params: &'a SlamParams,
    /// The undistorted image's extent (min x, max x, min y, max y).
    pub bounds: Bounds,
    /// Each pyramid level's scale (level 0: 1).
    pub level_scales: Arc<[f64]>,
    /// Build the frame's flow pyramid: the next frame may be tracked by
    /// optical flow from it (RGB-D, `SlamParams::flow_frames`, the SLAM
    /// behind its frames).
    pub flow_pyramid: bool,
}

/// Pyramid levels optical flow tracks over (level 2 is a quarter of the
/// image: the reach is about 3 x 4 x the window from the guess).
const FLOW_LEVELS: usize = 3;

/// The pyramid optical flow reads, of the grey image.
fn flow_pyramid(gray: &GrayU8) -> Pyramid {
    Pyramid::new(GrayF32::from_u8(gray), FLOW_LEVELS)
}

impl Frame {
    /// Extracts the features of `input` outside its (dilated) mask.
    /// `bounds` is the undistorted image extent for this size; `correct`
    /// may move the undistorted pixels and depths (the rolling-shutter
    /// correction) before they are indexed for search.
    pub fn extract(
        input: &RgbdInput,
        extractor: &OrbExtractor,
        camera: &Camera,
        params: &SlamParams,
        bounds: Bounds,
        correct: impl FnOnce(&[KeyPoint], &mut [(f64, f64)], &mut [Option<f64>]),
    ) -> Self {
        let context = FrameContext {
            camera,
            params,
            bounds,
            level_scales: extractor.level_scales(),
            flow_pyramid: params.flow_on(),
        };
        Self::with_keypoints(
            input,
            |gray, _, keep| {
                let (kps, descs, masked) = extractor.extract(gray, keep);
                Detected { kps, descs, masked }
            },
            &context,
            correct,
        )
    }

    /// A frame of the keypoints `detect` finds in `input`'s grey image (and,
    /// with flow tracking on, its pyramid) where the mask keeps them: ORB
    /// extraction, or the last frame's points followed by optical flow.
    pub fn with_keypoints(
        input: &RgbdInput,
        detect: impl FnOnce(&GrayU8, Option<&Pyramid>, &(dyn Fn(f32, f32) -> bool + Sync)) -> Detected,
        context: &FrameContext,
        correct: impl FnOnce(&[KeyPoint], &mut [(f64, f64)], &mut [Option<f64>]),
    ) -> Self {
        let FrameContext {
            camera,
            params,
            bounds,
            flow_pyramid,
            ..
        } = *context;
        let (width, height) = (input.width, input.height);
        let gray = GrayU8::from_rgb(input.rgb, width, height);
        // Only a frame that flow tracking may follow from needs it (RGB-D:
        // `Tracking::may_follow`).
        let pyramid = flow_pyramid.then(|| Arc::new(self::flow_pyramid(&gray)));
        let mask = input
            .mask
            .map(|m| DynamicMask::new(m, width, height, params.mask_dilation_px));
        let keep = |x: f32, y: f32| mask.as_ref().is_none_or(|m| m.keeps(x, y));
        let Detected { kps, descs, masked } = detect(&gray, pyramid.as_deref(), &keep);
        let mut un: Vec<(f64, f64)> = kps
            .iter()
            .map(|k| camera.undistort(k.x as f64, k.y as f64))
            .collect();
        // A monocular system ignores depth that comes with the frames.
        let depth_image: &[u16] = if params.is_monocular() {
            &[]
        } else {
            input.depth
        };
        let mut depth: Vec<Option<f64>> = kps
            .iter()
            .map(|k| {
                let (x, y) = (
                    (k.x.round() as usize).min(width - 1),
                    (k.y.round() as usize).min(height - 1),
                );
                let raw = depth_image.get(y * width + x).copied().unwrap_or(0);
                let d = raw as f64 / camera.depth_scale;
                (d >= params.min_depth_m && d <= params.max_depth_m).then_some(d)
            })
            .collect();
        let colours = kps
            .iter()
            .map(|k| {
                let i =
                    3 * ((k.y as usize).min(height - 1) * width + (k.x as usize).min(width - 1));
                [input.rgb[i], input.rgb[i + 1], input.rgb[i + 2]]
            })
            .collect();
        correct(&kps, &mut un, &mut depth);
        let small = params
            .turn_from_images
            .then(|| Arc::new(SmallImage::new(&gray, input.mask, camera)));
        Self {
            small,
            grid: Grid::new(&un, width, height),
            kps,
            un,
            descs,
            depth,
            colours,
            bounds,
            level_scales: context.level_scales.clone(),
            masked,
            width,
            height,
            pyramid,
        }
    }

    /// This frame without the keypoints `drop` marks (a better mask that
    /// came later), and the old index of every keypoint kept.
    pub fn without(&self, drop: impl Fn(&KeyPoint) -> bool) -> (Frame, Vec<usize>) {
        self.without_index(|k| drop(&self.kps[k]))
    }

    /// [`Frame::without`], `drop` given the keypoint's index.
    pub fn without_index(&self, drop: impl Fn(usize) -> bool) -> (Frame, Vec<usize>) {
        let kept: Vec<usize> = (0..self.kps.len()).filter(|&k| !drop(k)).collect();
        let un: Vec<(f64, f64)> = kept.iter().map(|&k| self.un[k]).collect();
        let frame = Frame {
            grid: Grid::new(&un, self.width, self.height),
            kps: kept.iter().map(|&k| self.kps[k]).collect(),
            un,
            descs: kept.iter().map(|&k| self.descs[k]).collect(),
            depth: kept.iter().map(|&k| self.depth[k]).collect(),
            colours: kept.iter().map(|&k| self.colours[k]).collect(),
            bounds: self.bounds,
            level_scales: self.level_scales.clone(),
            masked: self.masked + self.kps.len() - kept.len(),
            width: self.width,
            height: self.height,
            small: self.small.clone(),
            pyramid: self.pyramid.clone(),
        };
        (frame, kept)
    }

    /// Keypoint `k`'s scale (sigma of its pyramid level).
    pub fn scale(&self, k: usize) -> f64 {
        self.level_scale(self.kps[k].level)
    }

    /// The scale (sigma) of pyramid level `level`.
    pub fn level_scale(&self, level: u8) -> f64 {
        match self.level_scales.get(level as usize) {
            Some(&scale) => scale,
            // A level the parameters do not name (another extractor's).
            None => self
                .level_scales
                .get(1)
                .map_or(1.0, |f| f.powi(level as i32)),
        }
    }

    /// How keypoint `k` measures a point: its pixel, the virtual right
    /// pixel when its depth is nearer than `close_depth_m` (trusted), and
    /// the information (1 / sigma^2) of its pyramid level.
    pub fn measure(&self, k: usize, camera: &Camera, close_depth_m: f64) -> KeyFrameObservation {
        let (u, v) = self.un[k];
        let sigma = self.scale(k);
        KeyFrameObservation {
            u,
            v,
            ur: self.depth[k]
                .filter(|&d| d < close_depth_m)
                .map(|d| u - camera.bf / d),
            info: 1.0 / (sigma * sigma),
            descriptor: self.descs[k],
            angle: self.kps[k].angle,
        }
    }
}
