//! Keypoints and descriptors of one photo: FAST-9 corners and 256-bit BRIEF descriptors from
//! `imageproc`, with our own non-maximum suppression, ordering and test pairs so that the
//! result is the same bytes on every run and thread count.

use augsplat_core::ImageF32;
use image::GrayImage;
use imageproc::binary_descriptors::brief::{brief, TestPair};
use imageproc::binary_descriptors::BinaryDescriptor;
use imageproc::point::Point;

/// Bits per descriptor.
pub const DESCRIPTOR_BITS: usize = 256;
/// Side of BRIEF's patch; keypoints keep this far (plus the sub-patch average) from the edges.
const PATCH_DIAMETER: u32 = 31;
/// Distance from the image edge a keypoint keeps (BRIEF's patch radius, the radius-2 sub-patch
/// average, and one pixel of margin).
pub const EDGE_MARGIN: u32 = 18;
/// Radius of the non-maximum suppression (a corner survives when no stronger one lies within
/// this Chebyshev distance).
const SUPPRESSION_RADIUS: i32 = 1;

/// A 256-bit binary descriptor.
pub type Descriptor = [u64; 4];

/// Keypoints of one view, structure of arrays: pixel centres (continuous coordinates, pixel
/// (x, y) at (x + 0.5, y + 0.5)) and descriptors.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Keypoints {
    /// Continuous x (column + 0.5).
    pub u: Vec<f64>,
    /// Continuous y (row + 0.5).
    pub v: Vec<f64>,
    /// BRIEF descriptors.
    pub descriptors: Vec<Descriptor>,
    /// The FAST threshold the corners were found at.
    pub threshold: u8,
}

impl Keypoints {
    /// Number of keypoints.
    pub fn len(&self) -> usize {
        self.u.len()
    }
    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.u.is_empty()
    }
}

/// Hamming distance of two descriptors.
#[inline]
pub fn hamming(a: &Descriptor, b: &Descriptor) -> u32 {
    (a[0] ^ b[0]).count_ones()
        + (a[1] ^ b[1]).count_ones()
        + (a[2] ^ b[2]).count_ones()
        + (a[3] ^ b[3]).count_ones()
}

/// BRIEF's test pairs, drawn once from `seed` (isotropic Gaussian of σ = 6.6 px around the
/// patch centre, as Calonder et al.), so descriptors of every view compare.
pub fn test_pairs(seed: u64) -> Vec<TestPair> {
    let mut rng = augsplat_core::Rng::new(seed);
    let centre = (PATCH_DIAMETER / 2) as f64 + 1.0;
    let mut pairs = Vec::with_capacity(DESCRIPTOR_BITS);
    let coord = |rng: &mut augsplat_core::Rng| {
        let c = centre + 6.6 * rng.normal();
        (c >= 0.0 && c < PATCH_DIAMETER as f64).then_some(c as u32)
    };
    while pairs.len() < DESCRIPTOR_BITS {
        let p = (
            coord(&mut rng),
            coord(&mut rng),
            coord(&mut rng),
            coord(&mut rng),
        );
        if let (Some(x0), Some(y0), Some(x1), Some(y1)) = p {
            pairs.push(TestPair {
                p0: Point::new(x0, y0),
                p1: Point::new(x1, y1),
            });
        }
    }
    pairs
}

/// 8-bit luma of an RGB image in [0, 1] (Rec. 601 weights).
pub fn luma(img: &ImageF32) -> GrayImage {
    let c = img.channels as usize;
    GrayImage::from_fn(img.width, img.height, |x, y| {
        let i = (y as usize * img.width as usize + x as usize) * c;
        let l = if c >= 3 {
            0.299 * img.data[i] + 0.587 * img.data[i + 1] + 0.114 * img.data[i + 2]
        } else {
            img.data[i]
        };
        image::Luma([(l.clamp(0.0, 1.0) * 255.0).round() as u8])
    })
}

/// FAST-9 corners at `threshold`, away from the edges, suppressed to local maxima of the
/// score, strongest first (ties by row, then column), at most `max` of them.
fn strongest_corners(gray: &GrayImage, threshold: u8, max: usize) -> Vec<(u32, u32, f32)> {
    let (w, h) = gray.dimensions();
    let mut corners: Vec<(u32, u32, f32)> = imageproc::corners::corners_fast9(gray, threshold)
        .into_iter()
        .filter(|c| {
            c.x >= EDGE_MARGIN
                && c.y >= EDGE_MARGIN
                && c.x + EDGE_MARGIN < w
                && c.y + EDGE_MARGIN < h
        })
        .map(|c| (c.x, c.y, c.score))
        .collect();
    // Score image for the suppression.
    let mut score = vec![-1f32; (w * h) as usize];
    for &(x, y, s) in &corners {
        score[(y * w + x) as usize] = s;
    }
    corners.retain(|&(x, y, s)| {
        for dy in -SUPPRESSION_RADIUS..=SUPPRESSION_RADIUS {
            for dx in -SUPPRESSION_RADIUS..=SUPPRESSION_RADIUS {
                let (nx, ny) = (x as i32 + dx, y as i32 + dy);
                if (dx, dy) == (0, 0) || nx < 0 || ny < 0 || nx >= w as i32 || ny >= h as i32 {
                    continue;
                }
                let o = score[(ny as u32 * w + nx as u32) as usize];
                // A stronger neighbour wins; of equal ones the first in row-major order.
                if o > s || (o == s && (ny, nx) < (y as i32, x as i32)) {
                    return false;
                }
            }
        }
        true
    });
    corners.sort_by(|a, b| b.2.total_cmp(&a.2).then((a.1, a.0).cmp(&(b.1, b.0))));
    corners.truncate(max);
    corners
}

/// The FAST thresholds tried, strongest first: the first that yields `min_features` corners
/// is used (a low-contrast photo falls back to the lower ones).
pub const FAST_THRESHOLDS: [u8; 5] = [20, 12, 8, 5, 3];

/// Detects and describes up to `max_features` keypoints of `img` with BRIEF's `pairs`. Tries
/// the thresholds of [`FAST_THRESHOLDS`] in turn until `min_features` are found.
pub fn detect(
    img: &ImageF32,
    max_features: usize,
    min_features: usize,
    pairs: &Vec<TestPair>,
) -> Keypoints {
    if img.width <= 2 * EDGE_MARGIN || img.height <= 2 * EDGE_MARGIN {
        return Keypoints::default();
    }
    let gray = luma(img);
    let mut corners = Vec::new();
    let mut used = FAST_THRESHOLDS[0];
    for &t in &FAST_THRESHOLDS {
        corners = strongest_corners(&gray, t, max_features);
        used = t;
        if corners.len() >= min_features {
            break;
        }
    }
    let points: Vec<Point<u32>> = corners.iter().map(|&(x, y, _)| Point::new(x, y)).collect();
    // Every corner keeps EDGE_MARGIN from the edges, which BRIEF requires: no error.
    let descriptors = match brief(&gray, &points, DESCRIPTOR_BITS, Some(pairs)) {
        Ok((d, _)) => d,
        Err(_) => return Keypoints::default(),
    };
    let mut k = Keypoints {
        threshold: used,
        ..Keypoints::default()
    };
    for d in &descriptors {
        let p = d.position();
        k.u.push(p.x as f64 + 0.5);
        k.v.push(p.y as f64 + 0.5);
        k.descriptors.push(pack(&d.bits));
    }
    k
}

/// Packs imageproc's 128-bit chunks into four words.
fn pack(bits: &[u128]) -> Descriptor {
    let mut out = [0u64; 4];
    for (i, chunk) in bits.iter().take(2).enumerate() {
        out[2 * i] = *chunk as u64;
        out[2 * i + 1] = (*chunk >> 64) as u64;
    }
    out
}
