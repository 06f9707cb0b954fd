//! Step 1 of §IV-A: HSV thresholding of every pixel into the four marker colours, then
//! 8-connected components per colour, each summarised as a [`Blob`]. All buffers are
//! owned by [`Segmenter`] and reused from frame to frame.

use crate::config::HsvRange;

/// The four marker colours, in `HsvConfig::ranges` order. Class 0 of the class map is
/// "no marker colour"; colour c is stored as `c as u8 + 1`.
#[derive(
    Debug,
    Clone,
    Copy,
    PartialEq,
    Eq,
    strum::EnumString,
    strum::IntoStaticStr,
    strum::Display,
    strum::VariantNames,
    strum::VariantArray,
)]
#[strum(serialize_all = "lowercase")]
pub enum Colour {
    Red = 0,
    Blue = 1,
    Yellow = 2,
    Green = 3,
}

impl Colour {
    pub const ALL: &'static [Colour] = <Colour as strum::VariantArray>::VARIANTS;
    /// The spelling in configs, reports and on the command line.
    pub fn as_str(self) -> &'static str {
        self.into()
    }
}

/// Upper bound on stored components per frame. A frame with more (a colourful scene, or
/// colour noise with `min_blob_pixels` set too low) keeps the first ones found and counts
/// the rest in [`Segmenter::dropped_blobs`].
pub const MAX_BLOBS: usize = 512;

const VISITED: u8 = 0x80;

/// One connected component of one colour.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Blob {
    pub colour: u8,
    /// Range of its pixel indices (row-major, `v * width + u`) in [`Segmenter::pixels`].
    pub start: u32,
    pub len: u32,
    pub u_min: u32,
    pub u_max: u32,
    pub v_min: u32,
    pub v_max: u32,
    /// Pixels with a depth reading inside the configured range.
    pub n_depth: u32,
    /// Mean of those depths, mm.
    pub mean_depth_mm: f64,
}

impl Blob {
    /// Physical area the blob covers at its mean depth, mm² (pixel count × pixel footprint).
    /// Used to tell a large base sphere from a small jaw sphere of the same colour.
    pub fn area_mm2(&self, fx: f64, fy: f64) -> f64 {
        self.len as f64 * (self.mean_depth_mm / fx) * (self.mean_depth_mm / fy)
    }
}

/// Read access to a depth plane, so the same code serves a `&[u16]` and the little-endian
/// bytes of an interfaces payload (which need not be 2-byte aligned).
pub trait DepthPlane {
    fn depth(&self, i: usize) -> u16;
    /// Number of depth readings.
    fn len(&self) -> usize;
    fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

impl DepthPlane for [u16] {
    #[inline]
    fn depth(&self, i: usize) -> u16 {
        self[i]
    }
    fn len(&self) -> usize {
        <[u16]>::len(self)
    }
}

/// The depth plane of an interfaces payload: `2·n` little-endian bytes.
pub struct LeDepthBytes<'a>(pub &'a [u8]);

impl DepthPlane for LeDepthBytes<'_> {
    #[inline]
    fn depth(&self, i: usize) -> u16 {
        u16::from_le_bytes([self.0[2 * i], self.0[2 * i + 1]])
    }
    fn len(&self) -> usize {
        self.0.len() / 2
    }
}

/// HSV of an RGB8 pixel: hue in degrees [0, 360), saturation and value in [0, 1].
#[inline]
pub fn rgb_to_hsv(r: u8, g: u8, b: u8) -> (f32, f32, f32) {
    let max = r.max(g).max(b);
    let min = r.min(g).min(b);
    let v = max as f32 / 255.0;
    if max == 0 {
        return (0.0, 0.0, 0.0);
    }
    let d = (max - min) as f32;
    let s = d / max as f32;
    if d == 0.0 {
        return (0.0, s, v);
    }
    let (rf, gf, bf) = (r as f32, g as f32, b as f32);
    let mut h = if max == r {
        60.0 * ((gf - bf) / d)
    } else if max == g {
        60.0 * ((bf - rf) / d + 2.0)
    } else {
        60.0 * ((rf - gf) / d + 4.0)
    };
    if h < 0.0 {
        h += 360.0;
    }
    (h, s, v)
}

/// Rows of the coarse pass: every `COARSE_ROW_STEP`-th row, every second pixel. A
/// component containing a block of `COARSE_ROW_STEP` rows × 2 columns is always seeded; a
/// marker sphere smaller than that (under ~4 px) cannot be fitted anyway.
pub const COARSE_ROW_STEP: usize = 4;

/// Thresholds of one frame, with the cheap grey/dark rejection precomputed.
struct Classifier<'a> {
    ranges: &'a [HsvRange; 4],
    /// Lowest s_min of any colour, ×256 rounded down, and lowest v_min ×255 rounded down:
    /// integer tests that reject only pixels every colour rejects.
    s_floor_q8: u32,
    v_floor_u8: u8,
}

impl<'a> Classifier<'a> {
    fn new(ranges: &'a [HsvRange; 4]) -> Self {
        let s_floor = ranges.iter().map(|r| r.s_min).fold(f64::INFINITY, f64::min);
        let v_floor = ranges.iter().map(|r| r.v_min).fold(f64::INFINITY, f64::min);
        Self {
            ranges,
            s_floor_q8: (s_floor * 256.0).floor().clamp(0.0, 256.0) as u32,
            v_floor_u8: (v_floor * 255.0).floor().clamp(0.0, 255.0) as u8,
        }
    }

    /// 0 for no marker colour, c + 1 for colour c.
    #[inline(always)]
    fn classify(&self, r: u8, g: u8, b: u8) -> u8 {
        // Grey, dark and washed-out pixels (almost the whole image) are rejected with integer
        // tests before any hue is computed.
        let max = r.max(g).max(b);
        let min = r.min(g).min(b);
        if max < self.v_floor_u8 || ((max - min) as u32) * 256 < self.s_floor_q8 * max as u32 || max == min {
            return 0;
        }
        self.classify_colour(r, g, b)
    }

    #[inline(never)]
    fn classify_colour(&self, r: u8, g: u8, b: u8) -> u8 {
        let (h, s, v) = rgb_to_hsv(r, g, b);
        for (c, range) in self.ranges.iter().enumerate() {
            if range.contains(h, s, v) {
                return c as u8 + 1;
            }
        }
        0
    }
}

/// Thresholding and connected components with buffers reused across frames.
///
/// Coarse to fine: only every second pixel of every [`COARSE_ROW_STEP`]-th row is
/// classified up front; the flood fill from the coloured ones classifies the pixels it
/// reaches. A frame of grey background thus reads an eighth of the pixels (and a quarter of
/// the image's memory), and nothing per pixel is reset between frames but a bitset.
#[derive(Debug, Default)]
pub struct Segmenter {
    /// Per-pixel class (0 none, 1..=4 colour), bit 7 once labelled; meaningful only where
    /// `known` has the pixel's bit.
    class_map: Vec<u8>,
    /// Bit i: pixel i has been classified this frame.
    known: Vec<u64>,
    /// Pixel indices of every stored blob, contiguous per blob; also the flood fill's queue.
    pub pixels: Vec<u32>,
    /// Coarse-grid pixels that passed a colour threshold (flood fill seeds).
    seeds: Vec<u32>,
    pub blobs: Vec<Blob>,
    /// Components dropped because [`MAX_BLOBS`] were already stored.
    pub dropped_blobs: u32,
    width: usize,
    height: usize,
}

impl Segmenter {
    /// Makes room for `width × height` frames (the only allocation; later frames of the
    /// same or smaller size allocate nothing).
    pub fn reserve(&mut self, width: usize, height: usize) {
        let n = width * height;
        if self.class_map.len() < n {
            self.class_map.resize(n, 0);
        }
        if self.known.len() < n.div_ceil(64) {
            self.known.resize(n.div_ceil(64), 0);
        }
        if self.pixels.capacity() < n {
            self.pixels.reserve_exact(n - self.pixels.len());
        }
        if self.seeds.capacity() < n {
            self.seeds.reserve_exact(n - self.seeds.len());
        }
        if self.blobs.capacity() < MAX_BLOBS {
            self.blobs.reserve_exact(MAX_BLOBS - self.blobs.len());
        }
    }

    pub fn width(&self) -> usize {
        self.width
    }

    /// Thresholds `rgb` (`width·height·3` bytes) into the colour ranges and labels the
    /// components. `depth` gives each blob its depth statistics (readings outside
    /// `[depth_min, depth_max]` in depth units count as missing). Buffers shorter than the
    /// frame size give no components (the estimator checks sizes before and reports them).
    #[allow(clippy::too_many_arguments)]
    pub fn run<D: DepthPlane + ?Sized>(
        &mut self,
        rgb: &[u8],
        depth: &D,
        width: usize,
        height: usize,
        ranges: &[HsvRange; 4],
        min_blob_pixels: u32,
        depth_range: (u16, u16),
        depth_unit_mm: f64,
    ) {
        self.reserve(width, height);
        self.width = width;
        self.height = height;
        self.pixels.clear();
        self.seeds.clear();
        self.blobs.clear();
        self.dropped_blobs = 0;
        if rgb.len() < 3 * width * height || depth.len() < width * height || width == 0 || height == 0 {
            self.width = 0;
            self.height = 0;
            return;
        }
        let classifier = Classifier::new(ranges);
        self.coarse_pass(rgb, &classifier);
        self.label(rgb, &classifier, depth, min_blob_pixels, depth_range, depth_unit_mm);
    }

    #[inline]
    fn is_known(&self, i: usize) -> bool {
        self.known[i >> 6] & (1u64 << (i & 63)) != 0
    }

    #[inline]
    fn set_class(&mut self, i: usize, c: u8) {
        self.class_map[i] = c;
        self.known[i >> 6] |= 1u64 << (i & 63);
    }

    fn coarse_pass(&mut self, rgb: &[u8], cl: &Classifier<'_>) {
        let (w, h) = (self.width, self.height);
        self.known[..(w * h).div_ceil(64)].fill(0);
        for v in (0..h).step_by(COARSE_ROW_STEP) {
            let row0 = v * w;
            let rgb_row = &rgb[3 * row0..3 * (row0 + w)];
            // Pixel pairs: the first of each is classified (no bounds checks in the loop).
            let pairs = rgb_row.chunks_exact(6);
            let rest = pairs.remainder();
            for (k, px) in pairs.enumerate() {
                let c = cl.classify(px[0], px[1], px[2]);
                let i = row0 + 2 * k;
                self.set_class(i, c);
                if c != 0 {
                    self.seeds.push(i as u32);
                }
            }
            // An odd width leaves one last even pixel.
            if rest.len() == 3 {
                let c = cl.classify(rest[0], rest[1], rest[2]);
                self.set_class(row0 + w - 1, c);
                if c != 0 {
                    self.seeds.push((row0 + w - 1) as u32);
                }
            }
        }
    }

    fn label<D: DepthPlane + ?Sized>(
        &mut self,
        rgb: &[u8],
        cl: &Classifier<'_>,
        depth: &D,
        min_blob_pixels: u32,
        depth_range: (u16, u16),
        depth_unit_mm: f64,
    ) {
        let (w, h) = (self.width, self.height);
        for si in 0..self.seeds.len() {
            let seed = self.seeds[si] as usize;
            let cls = self.class_map[seed];
            if cls & VISITED != 0 {
                continue;
            }
            let start = self.pixels.len();
            self.class_map[seed] = cls | VISITED;
            self.pixels.push(seed as u32);
            let mut head = start;
            // Breadth-first flood fill; the component's pixel list is its own queue.
            while head < self.pixels.len() {
                let p = self.pixels[head] as usize;
                head += 1;
                let (u, v) = (p % w, p / w);
                let (u0, u1) = (u.saturating_sub(1), (u + 1).min(w - 1));
                let (v0, v1) = (v.saturating_sub(1), (v + 1).min(h - 1));
                for vv in v0..=v1 {
                    let row = vv * w;
                    for uu in u0..=u1 {
                        let q = row + uu;
                        let c = if self.is_known(q) {
                            self.class_map[q]
                        } else {
                            let c = cl.classify(rgb[3 * q], rgb[3 * q + 1], rgb[3 * q + 2]);
                            self.set_class(q, c);
                            c
                        };
                        if c == cls {
                            self.class_map[q] = cls | VISITED;
                            self.pixels.push(q as u32);
                        }
                    }
                }
            }
            let len = self.pixels.len() - start;
            if len < min_blob_pixels as usize {
                self.pixels.truncate(start);
                continue;
            }
            if self.blobs.len() >= MAX_BLOBS {
                self.pixels.truncate(start);
                self.dropped_blobs += 1;
                continue;
            }
            let mut blob = Blob {
                colour: cls - 1,
                start: start as u32,
                len: len as u32,
                u_min: u32::MAX,
                u_max: 0,
                v_min: u32::MAX,
                v_max: 0,
                n_depth: 0,
                mean_depth_mm: 0.0,
            };
            let mut sum_depth = 0u64;
            for &p in &self.pixels[start..] {
                let p = p as usize;
                let (u, v) = ((p % w) as u32, (p / w) as u32);
                blob.u_min = blob.u_min.min(u);
                blob.u_max = blob.u_max.max(u);
                blob.v_min = blob.v_min.min(v);
                blob.v_max = blob.v_max.max(v);
                let d = depth.depth(p);
                if d >= depth_range.0 && d <= depth_range.1 && d != 0 {
                    blob.n_depth += 1;
                    sum_depth += d as u64;
                }
            }
            if blob.n_depth > 0 {
                blob.mean_depth_mm = sum_depth as f64 / blob.n_depth as f64 * depth_unit_mm;
            }
            self.blobs.push(blob);
        }
    }

    /// Colour class of pixel `i` of the last frame (0 none, c + 1 for colour c).
    #[inline]
    pub fn class_at(&self, i: usize) -> u8 {
        if self.is_known(i) {
            self.class_map[i] & !VISITED
        } else {
            0
        }
    }

    pub fn height(&self) -> usize {
        self.height
    }

    /// Pixel indices of a blob.
    pub fn blob_pixels(&self, blob: &Blob) -> &[u32] {
        &self.pixels[blob.start as usize..(blob.start + blob.len) as usize]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::EstimatorConfig;

    #[test]
    fn hsv_of_primaries() {
        let close = |a: (f32, f32, f32), b: (f32, f32, f32)| {
            (a.0 - b.0).abs() < 1e-3 && (a.1 - b.1).abs() < 1e-3 && (a.2 - b.2).abs() < 1e-3
        };
        assert!(close(rgb_to_hsv(255, 0, 0), (0.0, 1.0, 1.0)));
        assert!(close(rgb_to_hsv(0, 255, 0), (120.0, 1.0, 1.0)));
        assert!(close(rgb_to_hsv(0, 0, 255), (240.0, 1.0, 1.0)));
        assert!(close(rgb_to_hsv(255, 255, 0), (60.0, 1.0, 1.0)));
        assert!(close(rgb_to_hsv(255, 0, 128), (329.88235, 1.0, 1.0)));
        assert!(close(rgb_to_hsv(128, 128, 128), (0.0, 0.0, 128.0 / 255.0)));
        assert!(close(rgb_to_hsv(0, 0, 0), (0.0, 0.0, 0.0)));
    }

    #[test]
    fn two_blobs_of_one_colour_and_noise_speck() {
        let (w, h) = (40usize, 30usize);
        let mut rgb = vec![90u8; w * h * 3];
        let mut depth = vec![500u16; w * h];
        let paint = |rgb: &mut Vec<u8>, u: usize, v: usize, c: [u8; 3]| {
            rgb[3 * (v * w + u)..3 * (v * w + u) + 3].copy_from_slice(&c);
        };
        for v in 5..10 {
            for u in 5..10 {
                paint(&mut rgb, u, v, [200, 20, 20]);
            }
        }
        for v in 20..25 {
            for u in 25..28 {
                paint(&mut rgb, u, v, [150, 10, 30]);
            }
        }
        // A diagonal neighbour belongs to the blob (8-connectivity).
        paint(&mut rgb, 10, 10, [200, 20, 20]);
        paint(&mut rgb, 35, 2, [20, 200, 20]); // one green pixel: below min_blob_pixels
        depth[5 * w + 5] = 0;
        let cfg = EstimatorConfig::paper_default();
        let mut s = Segmenter::default();
        s.run(&rgb, depth.as_slice(), w, h, &cfg.hsv.ranges(), 4, (30, 3000), 1.0);
        assert_eq!(s.blobs.len(), 2, "{:?}", s.blobs);
        let b0 = s.blobs[0];
        assert_eq!((b0.colour, b0.len, b0.n_depth), (Colour::Red as u8, 26, 25));
        assert_eq!((b0.u_min, b0.u_max, b0.v_min, b0.v_max), (5, 10, 5, 10));
        assert!((b0.mean_depth_mm - 500.0).abs() < 1e-12);
        assert_eq!(s.blobs[1].len, 15);
        // The same buffers serve the next frame.
        let cap = s.pixels.capacity();
        s.run(&rgb, depth.as_slice(), w, h, &cfg.hsv.ranges(), 4, (30, 3000), 1.0);
        assert_eq!(s.blobs.len(), 2);
        assert_eq!(s.pixels.capacity(), cap);
        // Buffers shorter than the frame: nothing, no panic.
        s.run(
            &rgb[..100],
            depth.as_slice(),
            w,
            h,
            &cfg.hsv.ranges(),
            4,
            (30, 3000),
            1.0,
        );
        assert!(s.blobs.is_empty());
        s.run(&rgb, &depth[..10], w, h, &cfg.hsv.ranges(), 4, (30, 3000), 1.0);
        assert!(s.blobs.is_empty());
    }
}
