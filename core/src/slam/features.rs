//! ORB features: pyramid, FAST-9 with 3x3 non-maximum suppression, Harris ranking spread over a
//! grid, intensity-centroid orientation, steered BRIEF with the learned 256-pair pattern on a
//! Gaussian-smoothed level (Rublee et al. 2011, as in OpenCV and ORB-SLAM2).
//!
//! [`OrbExtractor::extract`] runs on the calling thread (the benchmark against OpenCV compares
//! one thread each); [`OrbExtractor::extract_with_threads`] spreads the levels over two threads
//! with the same output (the tracker uses it with `crate::worker_threads`).

use std::sync::atomic::{AtomicUsize, Ordering};

use serde::{Deserialize, Serialize};

use super::orb_pattern::LEARNED_PATTERN;
use super::SlamError;
use crate::frame::GreyImage;

/// A 256-bit binary descriptor.
pub type Descriptor = [u64; 4];

/// Hamming distance between two descriptors (0..=256).
#[inline]
pub fn hamming(a: &Descriptor, b: &Descriptor) -> u32 {
    // Bit counts per byte of each word (SWAR), summed over the four words (≤ 32 per byte), then
    // over pairs of bytes (≤ 64 per 16 bits) and over those by one multiply (≤ 256 in the top 16
    // bits): the baseline x86-64 target has no popcount instruction.
    const M1: u64 = 0x5555_5555_5555_5555;
    const M2: u64 = 0x3333_3333_3333_3333;
    const M4: u64 = 0x0F0F_0F0F_0F0F_0F0F;
    const M8: u64 = 0x00FF_00FF_00FF_00FF;
    const H16: u64 = 0x0001_0001_0001_0001;
    let bytes = |x: u64| {
        let x = x - ((x >> 1) & M1);
        let x = (x & M2) + ((x >> 2) & M2);
        (x + (x >> 4)) & M4
    };
    let sum = bytes(a[0] ^ b[0]) + bytes(a[1] ^ b[1]) + bytes(a[2] ^ b[2]) + bytes(a[3] ^ b[3]);
    let pairs = (sum & M8) + ((sum >> 8) & M8);
    (pairs.wrapping_mul(H16) >> 48) as u32
}

/// Radius of the orientation patch (intensity centroid), pixels of the level (ORB: 15).
pub const HALF_PATCH_PX: usize = 15;
/// Keypoints are kept this far from the border of their level, pixels (the rotated pattern
/// reaches 18.4 px from the keypoint).
pub const EDGE_PX: usize = 19;
/// Radius of the Gaussian smoothing each level before the binary tests (3 → 7x7, σ = 2 px, as
/// OpenCV's ORB).
pub const BLUR_RADIUS_PX: usize = 3;
/// Largest distance of a rotated pattern point from the keypoint along x or y, pixels
/// (|(−13, −13)| = 18.4 rounded).
const PATTERN_REACH_PX: usize = 18;
/// Row stride of the descriptor patch (a copy of the smoothed level's square of side
/// 2 [`PATTERN_REACH_PX`] + 1 around the keypoint), pixels; a power of two.
const PATCH_STRIDE: usize = 64;
/// Length of the descriptor patch buffer (a power of two, so that indices masked by
/// `PATCH_LEN − 1` need no bounds check).
const PATCH_LEN: usize = PATCH_STRIDE * PATCH_STRIDE;

/// Index in the descriptor patch of the pixel at offset `(dx, dy)` from the keypoint.
fn patch_index(d: [i8; 2]) -> u16 {
    let r = PATTERN_REACH_PX as isize;
    let (x, y) = ((isize::from(d[0]) + r).clamp(0, 2 * r), (isize::from(d[1]) + r).clamp(0, 2 * r));
    (y as usize * PATCH_STRIDE + x as usize) as u16
}

/// Column offsets −15..=15 of the orientation patch.
const U_WEIGHTS: [i16; 2 * HALF_PATCH_PX + 1] = {
    let mut u = [0i16; 2 * HALF_PATCH_PX + 1];
    let mut i = 0;
    while i < u.len() {
        u[i] = i as i16 - HALF_PATCH_PX as i16;
        i += 1;
    }
    u
};
/// Side of the Harris window, pixels (OpenCV's ORB: 7), with `HARRIS_K` 0.04.
pub const HARRIS_BLOCK_PX: usize = 7;
/// Orientation bins of the pre-rotated descriptor pattern (1.4° each; the steering error at the
/// 18-px pattern rim is ≤ 0.23 px).
pub const ANGLE_BINS: usize = 256;
/// Number of binary tests of a descriptor.
pub const DESCRIPTOR_BITS: usize = 256;

/// Configuration of the ORB extractor.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct OrbConfig {
    /// Features wanted per image over all levels (ORB-SLAM2: 1000 at 640x480).
    pub n_features: usize,
    /// Pyramid levels (ORB-SLAM2: 8).
    pub n_levels: usize,
    /// Scale ratio between consecutive levels (ORB-SLAM2: 1.2). Must be > 1.
    pub scale_factor: f64,
    /// FAST threshold, grey levels (ORB-SLAM2 `iniThFAST`: 20).
    pub fast_threshold: u8,
    /// Lower FAST threshold used only in grid cells with no corner at `fast_threshold`, off when
    /// not below it (default 20: off, as OpenCV; ORB-SLAM2 `minThFAST`: 7). Weak corners spread
    /// the features into flat regions but match less reliably.
    pub fast_min_threshold: u8,
    /// Side of the grid cells used to spread features, pixels of each level (ORB-SLAM2: 30).
    pub cell_size_px: usize,
    /// Share of each level's features taken round-robin over the grid cells (emptiest cells
    /// first, the strongest corner of a cell first), in [0, 1]; the others are the level's
    /// strongest corners. 1 spreads the features most evenly, 0 ranks by strength alone (OpenCV).
    pub spread_share: f64,
    /// What ranks the corners of a level: the Harris response (default, OpenCV's ORB) or the
    /// FAST score.
    pub ranking: Ranking,
}

/// The score that ranks corners within a level.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Ranking {
    /// Harris corner response over a [`HARRIS_BLOCK_PX`] window (k = 0.04) of the level; the
    /// FAST score preselects twice the level's quota first.
    Harris,
    /// FAST score (the largest threshold at which the segment test still passes).
    Fast,
}

impl Default for OrbConfig {
    fn default() -> Self {
        Self {
            n_features: 1000,
            n_levels: 8,
            scale_factor: 1.2,
            fast_threshold: 20,
            fast_min_threshold: 20,
            cell_size_px: 30,
            spread_share: 0.2,
            ranking: Ranking::Harris,
        }
    }
}

/// A keypoint in level-0 pixel indices: `(x, y)` = `(column, row)`, the centre of pixel `(i, j)`
/// at `(i, j)` (a keypoint found at level `l` is at `(x_l + 0.5) s − 0.5`). The camera model's
/// image coordinates put that centre at `(i + 0.5, j + 0.5)` ([`crate::geometry::PinholeCamera`]):
/// use [`Keypoint::image_point`] wherever a keypoint meets the camera model.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Keypoint {
    /// Column index, level-0 pixels.
    pub x: f32,
    /// Row index, level-0 pixels.
    pub y: f32,
    /// Pyramid level it was detected at.
    pub level: u8,
    /// Scale of its level relative to level 0 (`scale_factor^level`).
    pub scale: f32,
    /// Orientation (intensity centroid), radians, image axes (x right, y down).
    pub angle_rad: f32,
    /// FAST score (largest threshold at which it is still a corner).
    pub score: u16,
}

impl Keypoint {
    /// The keypoint in the camera model's image coordinates (pixel centres at index + 0.5).
    pub fn image_point(&self) -> [f64; 2] {
        [f64::from(self.x) + 0.5, f64::from(self.y) + 0.5]
    }
}

/// Keypoints and their descriptors (same length, same order).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Features {
    /// Keypoints.
    pub keypoints: Vec<Keypoint>,
    /// Descriptors, `descriptors[i]` belongs to `keypoints[i]`.
    pub descriptors: Vec<Descriptor>,
}

impl Features {
    /// The keypoints as rows `[x, y, level, angle_rad, score]`.
    pub fn keypoint_rows(&self) -> Vec<[f32; 5]> {
        self.keypoints.iter().map(|k| [k.x, k.y, f32::from(k.level), k.angle_rad, f32::from(k.score)]).collect()
    }

    /// The descriptors as 32 bytes each (the four words little-endian).
    pub fn descriptor_bytes(&self) -> Vec<[u8; 32]> {
        let bytes = |d: &Descriptor| std::array::from_fn(|i| d[i / 8].to_le_bytes()[i % 8]);
        self.descriptors.iter().map(bytes).collect()
    }
}

/// One pyramid level's image.
#[derive(Debug, Clone, Default)]
struct Level {
    width: usize,
    height: usize,
    scale: f32,
    image: Vec<u8>,
}

#[derive(Debug, Clone, Copy)]
struct Corner {
    x: u32,
    y: u32,
    /// FAST score.
    score: u16,
    /// Ranking strength (larger is better): the FAST score or the Harris response's ordered bits.
    strength: u32,
    /// Grid cell.
    cell: u32,
    /// Round of the round-robin over cells in which the corner is taken.
    round: u32,
}

/// The 16 pixels of the radius-3 Bresenham circle, clockwise from the top.
const CIRCLE: [(isize, isize); 16] = [
    (0, -3),
    (1, -3),
    (2, -2),
    (3, -1),
    (3, 0),
    (3, 1),
    (2, 2),
    (1, 3),
    (0, 3),
    (-1, 3),
    (-2, 2),
    (-3, 1),
    (-3, 0),
    (-3, -1),
    (-2, -2),
    (-1, -3),
];

/// ORB extractor with reusable buffers: build once, call [`OrbExtractor::extract`] (one thread)
/// or [`OrbExtractor::extract_with_threads`] per frame.
#[derive(Debug, Clone)]
pub struct OrbExtractor {
    tables: Tables,
    levels: Vec<Level>,
    /// One per thread of the last extraction.
    scratch: Vec<LevelScratch>,
}

/// What the detection and description of every level read: the configuration and its tables.
#[derive(Debug, Clone)]
struct Tables {
    config: OrbConfig,
    /// The pattern rotated to each of `ANGLE_BINS` angles, rounded to pixels, as indices of the
    /// test's two pixels in a descriptor patch (see [`patch_index`]).
    rotated: Vec<[u16; 2]>,
    umax: [usize; HALF_PATCH_PX + 1],
    features_per_level: Vec<usize>,
}

/// The buffers of one thread's level work, reused from level to level and frame to frame.
#[derive(Debug, Clone, Default)]
struct LevelScratch {
    /// FAST scores of the level being detected (row stride: the level's width; 0: no corner).
    score_buf: Vec<u8>,
    corners: Vec<Corner>,
    /// Keep flags of one row of the non-maximum suppression.
    keep_row: Vec<u8>,
    /// The level smoothed for the binary tests ([`gaussian_blur`]).
    blurred: Vec<u8>,
    blur_rows: Vec<u16>,
}

impl OrbExtractor {
    /// Check the configuration and rotate the sampling pattern.
    pub fn new(config: OrbConfig) -> Result<Self, SlamError> {
        if !(config.scale_factor.is_finite() && config.scale_factor > 1.0) {
            return Err(SlamError::Config {
                field: "orb.scale_factor",
                reason: format!("{} must be > 1", config.scale_factor),
            });
        }
        if config.n_levels == 0 || config.n_levels > 32 {
            return Err(SlamError::Config {
                field: "orb.n_levels",
                reason: format!("{} not in 1..=32", config.n_levels),
            });
        }
        if config.cell_size_px < 4 {
            return Err(SlamError::Config { field: "orb.cell_size_px", reason: "must be ≥ 4".into() });
        }
        if config.fast_min_threshold == 0 {
            return Err(SlamError::Config { field: "orb.fast_min_threshold", reason: "must be ≥ 1".into() });
        }
        if !(0.0..=1.0).contains(&config.spread_share) {
            return Err(SlamError::Config {
                field: "orb.spread_share",
                reason: format!("{} not in [0, 1]", config.spread_share),
            });
        }
        let mut umax = [0usize; HALF_PATCH_PX + 1];
        for (v, u) in umax.iter_mut().enumerate() {
            let r2 = (HALF_PATCH_PX * HALF_PATCH_PX - v * v) as f64;
            *u = r2.sqrt().round() as usize;
        }
        // Features per level: geometric with ratio 1 / scale_factor (OpenCV, ORB-SLAM2).
        let inv = 1.0 / config.scale_factor;
        let n = config.n_levels;
        let first = config.n_features as f64 * (1.0 - inv) / (1.0 - inv.powi(n as i32));
        let mut features_per_level = Vec::with_capacity(n);
        let mut total = 0usize;
        for l in 0..n {
            let k = if l + 1 == n {
                config.n_features.saturating_sub(total)
            } else {
                (first * inv.powi(l as i32)).round() as usize
            };
            total += k;
            features_per_level.push(k);
        }
        let mut rotated = Vec::with_capacity(ANGLE_BINS * DESCRIPTOR_BITS);
        for bin in 0..ANGLE_BINS {
            let (s, c) = (std::f32::consts::TAU * bin as f32 / ANGLE_BINS as f32).sin_cos();
            for p in &LEARNED_PATTERN {
                let r = |x: i8, y: i8| {
                    let (x, y) = (f32::from(x), f32::from(y));
                    [round_i(x * c - y * s) as i8, round_i(x * s + y * c) as i8]
                };
                let (a, b) = (r(p[0], p[1]), r(p[2], p[3]));
                rotated.push([patch_index(a), patch_index(b)]);
            }
        }
        Ok(Self {
            tables: Tables { config, rotated, umax, features_per_level },
            levels: Vec::new(),
            scratch: Vec::new(),
        })
    }

    /// The configuration.
    pub fn config(&self) -> &OrbConfig {
        &self.tables.config
    }

    /// Detect and describe up to `n_features` keypoints on one thread. An image smaller than the
    /// patch gives an empty set (not an error); a buffer of the wrong length is an error.
    pub fn extract(&mut self, image: &GreyImage) -> Result<Features, SlamError> {
        self.extract_with_threads(image, 1)
    }

    /// [`OrbExtractor::extract`] on up to `threads` threads (1: the calling thread only; 2 or
    /// more: two). The levels are independent once the pyramid is built: with two threads a
    /// second one builds the pyramid while the calling thread works on level 0, then both take
    /// the remaining levels, largest first, as they finish. The output is the same for any
    /// `threads` (the levels' keypoints are concatenated in level order).
    pub fn extract_with_threads(&mut self, image: &GreyImage, threads: usize) -> Result<Features, SlamError> {
        let (w, h) = (image.width as usize, image.height as usize);
        if image.data.len() != w * h {
            return Err(SlamError::BufferLength { field: "grey", expected: w * h, actual: image.data.len() });
        }
        self.size_levels(w, h);
        if let Some(l0) = self.levels.first_mut() {
            l0.image.copy_from_slice(&image.data);
        }
        let threads = threads.clamp(1, 2);
        if self.scratch.len() < threads {
            self.scratch.resize_with(threads, LevelScratch::default);
        }
        let tables = &self.tables;
        let mut out = Features::default();
        let (Some((level0, rest)), [scratch_a, others @ ..]) = (self.levels.split_first_mut(), &mut self.scratch[..])
        else {
            return Ok(out);
        };
        let level0 = &*level0;
        match others.first_mut() {
            Some(scratch_b) if threads > 1 && !rest.is_empty() => {
                let next = AtomicUsize::new(1);
                let next = &next;
                let (tx, rx) = std::sync::mpsc::sync_channel::<&[Level]>(1);
                let (parts_a, parts_b) = std::thread::scope(|s| {
                    let second = s.spawn(move || {
                        build_pyramid(level0, rest);
                        let rest: &[Level] = rest;
                        // The receiver outlives this thread's send (it is dropped after the join).
                        let _ = tx.send(rest);
                        tables.take_levels(rest, next, scratch_b)
                    });
                    tables.level_features(0, level0, scratch_a, &mut out);
                    let parts_a = match rx.recv() {
                        Ok(rest) => tables.take_levels(rest, next, scratch_a),
                        Err(_) => Vec::new(),
                    };
                    (parts_a, second.join().unwrap_or_else(|e| std::panic::resume_unwind(e)))
                });
                let mut parts: Vec<(usize, Features)> = parts_a.into_iter().chain(parts_b).collect();
                parts.sort_unstable_by_key(|(l, _)| *l);
                for (_, f) in parts {
                    out.keypoints.extend(f.keypoints);
                    out.descriptors.extend(f.descriptors);
                }
            }
            _ => {
                build_pyramid(level0, rest);
                tables.level_features(0, level0, scratch_a, &mut out);
                for (i, level) in rest.iter().enumerate() {
                    tables.level_features(i + 1, level, scratch_a, &mut out);
                }
            }
        }
        Ok(out)
    }

    /// Size the levels for a `w0` x `h0` image (kept while the size stays the same).
    fn size_levels(&mut self, w0: usize, h0: usize) {
        let config = &self.tables.config;
        let n = config.n_levels;
        let same = self.levels.len() == n && self.levels.first().is_some_and(|l| l.width == w0 && l.height == h0);
        if !same {
            self.levels = (0..n)
                .map(|l| {
                    let s = config.scale_factor.powi(l as i32);
                    let (w, h) = (((w0 as f64) / s).round() as usize, ((h0 as f64) / s).round() as usize);
                    Level { width: w, height: h, scale: s as f32, image: vec![0; w * h] }
                })
                .collect();
        }
    }
}

/// Resample the levels after the first from the one before each ([`resize_bilinear`]).
fn build_pyramid(first: &Level, rest: &mut [Level]) {
    if let Some(l1) = rest.first_mut() {
        resize_bilinear(first, l1);
    }
    for l in 1..rest.len() {
        let (prev, next) = rest.split_at_mut(l);
        if let (Some(src), Some(dst)) = (prev.last(), next.first_mut()) {
            resize_bilinear(src, dst);
        }
    }
}

impl Tables {
    /// Take levels `1 + i` of `rest` by the shared counter `next` (level numbers) until none is
    /// left; their features, each with its level.
    fn take_levels(&self, rest: &[Level], next: &AtomicUsize, scratch: &mut LevelScratch) -> Vec<(usize, Features)> {
        let mut parts = Vec::new();
        loop {
            let l = next.fetch_add(1, Ordering::Relaxed);
            let Some(level) = rest.get(l.wrapping_sub(1)) else {
                return parts;
            };
            let mut f = Features::default();
            self.level_features(l, level, scratch, &mut f);
            parts.push((l, f));
        }
    }

    /// Detect and describe the features of level `l` (image `level`), appended to `out`.
    fn level_features(&self, l: usize, level: &Level, scratch: &mut LevelScratch, out: &mut Features) {
        let want = self.features_per_level.get(l).copied().unwrap_or(0);
        if want == 0 {
            return;
        }
        self.detect_level(level, want, scratch);
        if scratch.corners.is_empty() {
            return;
        }
        gaussian_blur(level, &mut scratch.blurred, &mut scratch.blur_rows);
        self.describe_level(l, level, scratch, out);
    }

    /// The level's corners into `scratch.corners`: FAST, 3x3 suppression, selection of `want`
    /// spread over the grid, in raster order.
    fn detect_level(&self, level: &Level, want: usize, scratch: &mut LevelScratch) {
        scratch.corners.clear();
        let (w, h) = (level.width, level.height);
        if w <= 2 * EDGE_PX || h <= 2 * EDGE_PX {
            return;
        }
        if scratch.score_buf.len() < w * h {
            scratch.score_buf.resize(w * h, 0);
        }
        let cell = self.config.cell_size_px;
        let (nx, ny) = (w - 2 * EDGE_PX, h - 2 * EDGE_PX);
        let (ncx, ncy) = (nx.div_ceil(cell), ny.div_ceil(cell));
        let strong = self.config.fast_threshold;
        let weak = self.config.fast_min_threshold;
        // FAST scores into the level's score map (0: no corner): strong corners over the level,
        // weak ones (score below the FAST threshold) only in the cells without a strong one. The
        // one-pixel ring around the scanned area is cleared so that the suppression below reads
        // zeros there.
        let area = ScanArea { width: w, xs: (EDGE_PX, EDGE_PX + nx), ys: (EDGE_PX, EDGE_PX + ny) };
        let map = &mut scratch.score_buf;
        let ring_rows = [(EDGE_PX - 1) * w, (EDGE_PX + ny) * w];
        for r in ring_rows {
            if let Some(row) = map.get_mut(r + EDGE_PX - 1..=r + EDGE_PX + nx) {
                row.fill(0);
            }
        }
        for y in EDGE_PX..EDGE_PX + ny {
            for x in [EDGE_PX - 1, EDGE_PX + nx] {
                if let Some(v) = map.get_mut(y * w + x) {
                    *v = 0;
                }
            }
        }
        scan_fast(&level.image, &area, strong, map);
        if weak < strong {
            let mut has_strong = vec![false; ncx * ncy];
            for (y, row) in map.chunks_exact(w).enumerate().take(EDGE_PX + ny).skip(EDGE_PX) {
                for (x, _) in row.iter().enumerate().take(EDGE_PX + nx).skip(EDGE_PX).filter(|(_, &v)| v != 0) {
                    if let Some(f) = has_strong.get_mut(((y - EDGE_PX) / cell) * ncx + (x - EDGE_PX) / cell) {
                        *f = true;
                    }
                }
            }
            for (cid, _) in has_strong.iter().enumerate().filter(|(_, s)| !**s) {
                let (x0, y0) = (EDGE_PX + (cid % ncx) * cell, EDGE_PX + (cid / ncx) * cell);
                let cell_area = ScanArea {
                    width: w,
                    xs: (x0, (x0 + cell).min(EDGE_PX + nx)),
                    ys: (y0, (y0 + cell).min(EDGE_PX + ny)),
                };
                scan_fast(&level.image, &cell_area, weak, map);
            }
        }
        // 3x3 non-maximum suppression over the map (ties: the first in raster order wins): a row
        // of keep flags lane-wise (a score beats the row above and its left neighbour, and is
        // not beaten by its right neighbour and the row below; a zero never passes), then the
        // survivors become the level's corners, in raster order.
        let map = &scratch.score_buf;
        let keep = &mut scratch.keep_row;
        keep.resize(nx, 0);
        for y in EDGE_PX..EDGE_PX + ny {
            let band = |r: usize| map.get(r * w + EDGE_PX - 1..r * w + EDGE_PX + nx + 1);
            let (Some(up), Some(mid), Some(dn)) = (band(y - 1), band(y), band(y + 1)) else {
                continue;
            };
            let keep: &mut [u8] = keep;
            let n = keep.len();
            let (u0, u1, u2) = (&up[..n], &up[1..=n], &up[2..n + 2]);
            let (m0, m1, m2) = (&mid[..n], &mid[1..=n], &mid[2..n + 2]);
            let (d0, d1, d2) = (&dn[..n], &dn[1..=n], &dn[2..n + 2]);
            for (i, k) in keep.iter_mut().enumerate() {
                let s = m1[i];
                let up_max = u0[i].max(u1[i]).max(u2[i]);
                let dn_max = d0[i].max(d1[i]).max(d2[i]);
                *k = u8::from((s > up_max) & (s > m0[i]) & (s >= m2[i]) & (s >= dn_max));
            }
            let cell_row = ((y - EDGE_PX) / cell) * ncx;
            // Eight flags a word; the row's last flags (fewer than eight) in a zero-padded word.
            let chunks = keep.chunks_exact(8);
            let mut last = [0u8; 8];
            if let Some(dst) = last.get_mut(..chunks.remainder().len()) {
                dst.copy_from_slice(chunks.remainder());
            }
            let words = chunks.map(|c| <[u8; 8]>::try_from(c).unwrap_or_default()).chain(std::iter::once(last));
            for (k, word) in words.enumerate() {
                let mut bits = u64::from_le_bytes(word);
                while bits != 0 {
                    let x = EDGE_PX + k * 8 + (bits.trailing_zeros() / 8) as usize;
                    bits &= bits - 1;
                    let score = u16::from(mid[x - EDGE_PX + 1]);
                    scratch.corners.push(Corner {
                        x: x as u32,
                        y: y as u32,
                        score,
                        strength: u32::from(score),
                        cell: (cell_row + (x - EDGE_PX) / cell) as u32,
                        round: 0,
                    });
                }
            }
        }
        let spread = (self.config.spread_share * want as f64).round() as usize;
        if self.config.ranking == Ranking::Harris {
            // Preselect by FAST score (spread over the grid as well), then rank by Harris.
            select_spread(&mut scratch.corners, 2 * want, 2 * spread);
            let img = &level.image;
            for c in &mut scratch.corners {
                let r = harris_response(img, w, c.x as usize, c.y as usize);
                c.strength = ordered_bits(r);
            }
        }
        select_spread(&mut scratch.corners, want, spread);
        // Deterministic output order.
        scratch.corners.sort_unstable_by_key(|c| (c.y, c.x));
    }

    /// Orientation and descriptor of each of `scratch.corners` (on `scratch.blurred`), appended
    /// to `out` as keypoints of level `l`.
    fn describe_level(&self, l: usize, level: &Level, scratch: &LevelScratch, out: &mut Features) {
        let w = level.width;
        let mut patch = [0u8; PATCH_LEN];
        for c in &scratch.corners {
            let (x, y) = (c.x as usize, c.y as usize);
            // Intensity centroid over the radius-15 disc, a row pair (±v) at a time on 31-wide
            // i16 rows zeroed outside the disc (multiply-adds of i16 pairs into i32).
            let center = y * w + x;
            let img = &level.image;
            let hp = HALF_PATCH_PX;
            let (mut m10, mut m01) = (0i32, 0i32);
            let mut sum = [0i16; 2 * HALF_PATCH_PX + 1];
            let mut dif = [0i16; 2 * HALF_PATCH_PX + 1];
            for v in 0..=hp {
                let d = self.umax[v];
                sum.iter_mut().for_each(|e| *e = 0);
                dif.iter_mut().for_each(|e| *e = 0);
                let (up_row, dn_row) = (center - v * w, center + v * w);
                let (Some(up), Some(dn)) = (img.get(up_row - d..=up_row + d), img.get(dn_row - d..=dn_row + d)) else {
                    continue;
                };
                let (s_row, d_row) = (&mut sum[hp - d..=hp + d], &mut dif[hp - d..=hp + d]);
                for (((s, e), &a), &b) in s_row.iter_mut().zip(d_row.iter_mut()).zip(up).zip(dn) {
                    let (a, b) = (i16::from(a), i16::from(b));
                    *s = if v == 0 { a } else { a + b };
                    *e = b - a;
                }
                let mut row_m10 = 0i32;
                let mut row_sum = 0i32;
                for ((&s, &e), &u) in sum.iter().zip(&dif).zip(&U_WEIGHTS) {
                    row_m10 += i32::from(s) * i32::from(u);
                    row_sum += i32::from(e);
                }
                m10 += row_m10;
                m01 += v as i32 * row_sum;
            }
            let angle = (m01 as f32).atan2(m10 as f32);
            // Steered pattern from the table of ANGLE_BINS rotations.
            let bin =
                (round_i(angle / std::f32::consts::TAU * ANGLE_BINS as f32).rem_euclid(ANGLE_BINS as isize)) as usize;
            // The rotated pattern (radius ≤ PATTERN_REACH_PX ≤ EDGE_PX) lies inside the level:
            // copy its square of the smoothed level into the patch, then read the tests' pixels
            // at precomputed indices.
            let r = PATTERN_REACH_PX;
            for (k, dst) in patch.chunks_exact_mut(PATCH_STRIDE).take(2 * r + 1).enumerate() {
                let s = (y + k - r) * w + x - r;
                if let (Some(src), Some(dst)) = (scratch.blurred.get(s..=s + 2 * r), dst.get_mut(..=2 * r)) {
                    dst.copy_from_slice(src);
                }
            }
            let mut desc = [0u64; 4];
            if let Some(rot) = self.rotated.get(bin * DESCRIPTOR_BITS..(bin + 1) * DESCRIPTOR_BITS) {
                for (word, tests) in desc.iter_mut().zip(rot.chunks_exact(64)) {
                    let mut bits = 0u64;
                    for (b, p) in tests.iter().enumerate() {
                        let a = patch[usize::from(p[0]) & (PATCH_LEN - 1)];
                        let c = patch[usize::from(p[1]) & (PATCH_LEN - 1)];
                        bits |= u64::from(a < c) << b;
                    }
                    *word = bits;
                }
            }
            out.keypoints.push(Keypoint {
                // Pixel x_l of level l spans level-0 [x_l s, (x_l + 1) s) (the pyramid resamples
                // centre-aligned), so its centre's level-0 index is (x_l + 0.5) s − 0.5.
                x: (c.x as f32 + 0.5) * level.scale - 0.5,
                y: (c.y as f32 + 0.5) * level.scale - 0.5,
                level: l as u8,
                scale: level.scale,
                angle_rad: angle,
                score: c.score,
            });
            out.descriptors.push(desc);
        }
    }
}

/// Where [`scan_fast`] looks: the level's width, its columns `xs.0..xs.1` and rows `ys.0..ys.1`.
struct ScanArea {
    width: usize,
    xs: (usize, usize),
    ys: (usize, usize),
}

/// FAST-9 at threshold `t` over `area` (inside the level by [`EDGE_PX`]): each pixel's FAST score
/// (0: no corner) written into `scores` (row stride `area.width`); pixels outside `area` are left
/// as they are.
fn scan_fast(img: &[u8], area: &ScanArea, t: u8, scores: &mut [u8]) {
    let w = area.width;
    let offsets: [isize; 16] = CIRCLE.map(|(dx, dy)| dy * w as isize + dx);
    let (x_from, x_to) = area.xs;
    if x_to <= x_from {
        return;
    }
    let n = x_to - x_from;
    for y in area.ys.0..area.ys.1 {
        let row = y * w;
        // `LANES` pixels at a time (OpenCV's SIMD FAST); the last chunk overlaps the previous one
        // (back from the row end) rather than leave the row.
        let mut x0 = x_from;
        let mut done_to = x_from;
        while done_to < x_to {
            if x0 + LANES > x_to {
                x0 = x_to.saturating_sub(LANES).max(EDGE_PX);
            }
            let lanes = fast_lanes(img, row + x0, &offsets, t);
            // Lanes hold the score + 1 (0: no corner); only those inside the area are written.
            let (from, to) = (x0.max(x_from), (x0 + LANES).min(x_to));
            if let Some(dst) = scores.get_mut(row + from..row + to) {
                if let Ok(whole) = <&mut [u8; LANES]>::try_from(&mut *dst) {
                    // The common case, a whole chunk inside the area: one 16-byte store.
                    *whole = lanes.map(|s| s.saturating_sub(1));
                } else if let Some(src) = lanes.get(from - x0..to - x0) {
                    for (d, &s) in dst.iter_mut().zip(src) {
                        *d = s.saturating_sub(1);
                    }
                }
            }
            done_to = (x0 + LANES).min(x_to);
            x0 += LANES;
            if n < LANES {
                break;
            }
        }
    }
}

/// Pixels processed together by [`fast_lanes`].
const LANES: usize = 16;

/// FAST-9 at threshold `t` for the `LANES` pixels starting at `start`: per pixel 0 (no corner) or
/// its FAST score + 1 (the largest over the 16 arcs of 9 contiguous circle pixels of the arc's
/// smallest excess over the centre, brighter or darker side; a corner when it exceeds `t`).
/// Written on fixed-size u8 arrays (saturating differences, lane-wise min and max) so that it
/// compiles to SIMD.
#[inline]
fn fast_lanes(img: &[u8], start: usize, offsets: &[isize; 16], t: u8) -> [u8; LANES] {
    let load = |o: isize| {
        let s = (start as isize + o) as usize;
        let mut p = [0u8; LANES];
        if let Some(src) = img.get(s..s + LANES) {
            p.copy_from_slice(src);
        }
        p
    };
    let c = load(0);
    // Quick reject of the whole chunk: a 9-arc holds two adjacent compass pixels (circle
    // indices 0/4, 4/8, 8/12, 12/0) beyond the threshold on the same side.
    let compass = [load(offsets[0]), load(offsets[4]), load(offsets[8]), load(offsets[12])];
    let (mut any_bright, mut any_dark) = (0u8, 0u8);
    for j in 0..LANES {
        let b: [u8; 4] = std::array::from_fn(|k| u8::from(compass[k][j].saturating_sub(c[j]) > t));
        let d: [u8; 4] = std::array::from_fn(|k| u8::from(c[j].saturating_sub(compass[k][j]) > t));
        any_bright |= (b[0] & b[1]) | (b[1] & b[2]) | (b[2] & b[3]) | (b[3] & b[0]);
        any_dark |= (d[0] & d[1]) | (d[1] & d[2]) | (d[2] & d[3]) | (d[3] & d[0]);
    }
    if any_bright | any_dark == 0 {
        return [0u8; LANES];
    }
    // Excess of each circle pixel over (bright) and under (dark) the centre.
    let mut bright = [[0u8; LANES]; 16];
    let mut dark = [[0u8; LANES]; 16];
    for (k, &o) in offsets.iter().enumerate() {
        let p = load(o);
        for j in 0..LANES {
            bright[k][j] = p[j].saturating_sub(c[j]);
            dark[k][j] = c[j].saturating_sub(p[j]);
        }
    }
    let sb = if any_bright != 0 { best_arc(&bright) } else { [0u8; LANES] };
    let sd = if any_dark != 0 { best_arc(&dark) } else { [0u8; LANES] };
    let mut out = [0u8; LANES];
    for j in 0..LANES {
        let s = sb[j].max(sd[j]);
        out[j] = if s > t { s } else { 0 };
    }
    out
}

/// Per lane, the largest over the 16 arcs of 9 contiguous entries of the circle `v` of the arc's
/// smallest entry (a min tree: pairs, fours, eights, nines).
#[inline]
fn best_arc(v: &[[u8; LANES]; 16]) -> [u8; LANES] {
    let mut m2 = [[0u8; LANES]; 16];
    for k in 0..16 {
        m2[k] = min_lanes(v[k], v[(k + 1) & 15]);
    }
    let mut m4 = [[0u8; LANES]; 16];
    for k in 0..16 {
        m4[k] = min_lanes(m2[k], m2[(k + 2) & 15]);
    }
    let mut best = [0u8; LANES];
    for k in 0..16 {
        let m9 = min_lanes(min_lanes(m4[k], m4[(k + 4) & 15]), v[(k + 8) & 15]);
        for j in 0..LANES {
            best[j] = best[j].max(m9[j]);
        }
    }
    best
}

/// Lane-wise minimum.
#[inline(always)]
fn min_lanes(mut a: [u8; LANES], b: [u8; LANES]) -> [u8; LANES] {
    for j in 0..LANES {
        a[j] = a[j].min(b[j]);
    }
    a
}

/// Round half away from zero without a libm call.
#[inline]
fn round_i(v: f32) -> isize {
    (v + 0.5f32.copysign(v)) as isize
}

/// Keep `want` of `corners`: the `want − spread` strongest, then `spread` more taken round-robin
/// over the grid cells, the cells holding the fewest chosen corners first, each cell's strongest
/// first (ties by position). `spread = want` spreads most evenly, `spread = 0` ranks by strength
/// alone (OpenCV's `retainBest`).
fn select_spread(corners: &mut Vec<Corner>, want: usize, spread: usize) {
    if corners.len() <= want {
        return;
    }
    let best = want - spread.min(want);
    let by_strength = |c: &Corner| (u32::MAX - c.strength, c.y, c.x);
    if best > 0 {
        corners.select_nth_unstable_by_key(best, by_strength);
    }
    // Round of each corner: 0 for the strongest; else 1 + the chosen corners in its cell + its
    // rank among the rest of its cell.
    corners[best..].sort_unstable_by_key(|c| (c.cell, u32::MAX - c.strength, c.y, c.x));
    let n_cells = corners.iter().map(|c| c.cell as usize + 1).max().unwrap_or(0);
    let mut chosen = vec![0u32; n_cells];
    for c in &mut corners[..best] {
        if let Some(n) = chosen.get_mut(c.cell as usize) {
            *n += 1;
        }
        c.round = 0;
    }
    let (mut rank, mut prev) = (0u32, u32::MAX);
    for c in &mut corners[best..] {
        rank = if c.cell == prev { rank + 1 } else { 0 };
        prev = c.cell;
        c.round = 1 + chosen.get(c.cell as usize).copied().unwrap_or(0) + rank;
    }
    corners.select_nth_unstable_by_key(want, |c| (c.round, u32::MAX - c.strength, c.y, c.x));
    corners.truncate(want);
}

/// An `f32` as a `u32` of the same order (larger float, larger integer; NaN last).
#[inline]
fn ordered_bits(v: f32) -> u32 {
    let b = v.to_bits();
    if b >> 31 == 1 {
        !b
    } else {
        b | (1 << 31)
    }
}

/// Harris corner response `det M − 0.04 trace² M` of the structure tensor `M` summed over the
/// [`HARRIS_BLOCK_PX`] window centred on `(x, y)`, with 3x3 Sobel gradients (OpenCV's ORB). The
/// window and its gradients stay inside the level (keypoints are [`EDGE_PX`] from its border).
fn harris_response(img: &[u8], w: usize, x: usize, y: usize) -> f32 {
    const B: usize = HARRIS_BLOCK_PX;
    const R: usize = B / 2;
    /// Lanes of a window row's gradients (the window's B columns and a cleared lane).
    const L: usize = B + 1;
    // The window's rows and the one above and below, B + 2 columns each (and a zero pad), as i16.
    let mut rows = [[0i16; L + 2]; B + 2];
    for (k, row) in rows.iter_mut().enumerate() {
        let start = (y + k - R - 1) * w + x - R - 1;
        if let Some(src) = img.get(start..start + B + 2) {
            for (d, &v) in row.iter_mut().zip(src) {
                *d = i16::from(v);
            }
        }
    }
    // Per lane sums of the structure tensor's entries over the window's rows (exact integers,
    // so the lane-wise order gives the same sums).
    let (mut sa, mut sb, mut sc) = ([0i32; L], [0i32; L], [0i32; L]);
    for k in 1..=B {
        let (up, mid, dn) = (&rows[k - 1], &rows[k], &rows[k + 1]);
        let mut dx = [0i16; L];
        let mut dy = [0i16; L];
        for i in 0..L {
            dx[i] = (mid[i + 2] - mid[i]) * 2 + (up[i + 2] - up[i]) + (dn[i + 2] - dn[i]);
            dy[i] = (dn[i + 1] - up[i + 1]) * 2 + (dn[i] - up[i]) + (dn[i + 2] - up[i + 2]);
        }
        dx[L - 1] = 0;
        dy[L - 1] = 0;
        for i in 0..L {
            let (gx, gy) = (i32::from(dx[i]), i32::from(dy[i]));
            sa[i] += gx * gx;
            sb[i] += gy * gy;
            sc[i] += gx * gy;
        }
    }
    let (a, b, c) = (sa.iter().sum::<i32>() as f32, sb.iter().sum::<i32>() as f32, sc.iter().sum::<i32>() as f32);
    a * b - c * c - 0.04 * (a + b) * (a + b)
}

/// Bilinear downscale of `src` into `dst` (sizes already set), fixed point (8-bit weights).
fn resize_bilinear(src: &Level, dst: &mut Level) {
    let (sw, sh, dw, dh) = (src.width, src.height, dst.width, dst.height);
    if sw == 0 || sh == 0 || dw == 0 || dh == 0 {
        return;
    }
    let (rx, ry) = (sw as f32 / dw as f32, sh as f32 / dh as f32);
    // Per output column: its left source column and the two weights (left, right).
    let mut x0s = Vec::with_capacity(dw);
    let mut w_left = Vec::with_capacity(dw);
    let mut w_right = Vec::with_capacity(dw);
    for x in 0..dw {
        let fx = ((x as f32 + 0.5) * rx - 0.5).clamp(0.0, (sw - 1) as f32);
        let x0 = (fx as usize).min(sw.saturating_sub(2));
        let wx = ((fx - x0 as f32) * 256.0).round().min(256.0) as u32;
        x0s.push(x0);
        w_left.push(256 - wx);
        w_right.push(wx);
    }
    let mut tmp = vec![0u16; sw];
    // Each column's vertical blend and its right neighbour's in one word (low, high 16 bits), so
    // that the horizontal pass gathers one word per output pixel.
    let mut pairs = vec![0u32; sw];
    let mut gathered = vec![0u32; dw];
    for y in 0..dh {
        let fy = ((y as f32 + 0.5) * ry - 0.5).clamp(0.0, (sh - 1) as f32);
        let y0 = (fy as usize).min(sh.saturating_sub(2));
        let wy = ((fy - y0 as f32) * 256.0).round().min(256.0) as u16;
        let y1 = (y0 + 1).min(sh - 1);
        let (r0, r1) = (&src.image[y0 * sw..y0 * sw + sw], &src.image[y1 * sw..y1 * sw + sw]);
        // Vertical blend (vectorisable), the gather, then the horizontal blend (vectorisable).
        for ((t, &a), &b) in tmp.iter_mut().zip(r0).zip(r1) {
            *t = u16::from(a) * (256 - wy) + u16::from(b) * wy;
        }
        let n = sw - 1;
        let (lo, hi, pr) = (&tmp[..n], &tmp[1..], &mut pairs[..n]);
        for i in 0..n {
            pr[i] = u32::from(lo[i]) | (u32::from(hi[i]) << 16);
        }
        pairs[n] = u32::from(tmp[n]);
        let pairs: &[u32] = &pairs;
        for (g, &x0) in gathered.iter_mut().zip(&x0s) {
            *g = pairs.get(x0).copied().unwrap_or(0);
        }
        let out = &mut dst.image[y * dw..y * dw + dw];
        let (g, wl, wr) = (&gathered[..dw], &w_left[..dw], &w_right[..dw]);
        for (i, o) in out.iter_mut().enumerate() {
            *o = (((g[i] & 0xFFFF) * wl[i] + (g[i] >> 16) * wr[i] + 32768) >> 16) as u8;
        }
    }
}

/// Gaussian weights of the smoothing before the binary tests (σ = 2 px, 7 taps, sum 256).
const GAUSS_7: [u16; 2 * BLUR_RADIUS_PX + 1] = [18, 33, 49, 56, 49, 33, 18];

/// Separable Gaussian smoothing ([`GAUSS_7`]) of a level into `blurred` (resized to the level;
/// fixed point; the `BLUR_RADIUS_PX` rows and columns along the border copied unsmoothed).
/// `rows` holds the horizontal pass of the last `2 BLUR_RADIUS_PX + 1` rows (a ring).
fn gaussian_blur(level: &Level, blurred: &mut Vec<u8>, rows: &mut Vec<u16>) {
    const R: usize = BLUR_RADIUS_PX;
    const N: usize = 2 * R + 1;
    let (w, h) = (level.width, level.height);
    blurred.clear();
    blurred.extend_from_slice(&level.image);
    if w < N || h < N {
        return;
    }
    rows.resize(N * w, 0);
    let m = w - 2 * R;
    let [g0, g1, g2, g3, ..] = GAUSS_7;
    // Vertical weights scaled for a multiply-high: (h g 256) >> 16.
    let gv = GAUSS_7.map(|g| u32::from(g) << 8);
    for (y, src) in level.image.chunks_exact(w).enumerate() {
        // Horizontal pass (symmetric taps) in u16: sums ≤ 255 × 256.
        let slot = &mut rows[(y % N) * w..(y % N) * w + m];
        let tap = |k: usize| &src[k..k + m];
        let (s0, s1, s2, s3, s4, s5, s6) = (tap(0), tap(1), tap(2), tap(3), tap(4), tap(5), tap(6));
        for i in 0..m {
            slot[i] = g0 * (u16::from(s0[i]) + u16::from(s6[i]))
                + g1 * (u16::from(s1[i]) + u16::from(s5[i]))
                + g2 * (u16::from(s2[i]) + u16::from(s4[i]))
                + g3 * u16::from(s3[i]);
        }
        if y + 1 < N {
            continue;
        }
        // Vertical pass for the row R above: each term (h g 256) >> 16, their sum ≤ 255 × 256,
        // rounded back to 8 bits.
        let yc = y - R;
        let ring = |k: usize| {
            let q = (yc + k - R) % N;
            &rows[q * w..q * w + m]
        };
        let (r0, r1, r2, r3, r4, r5, r6) = (ring(0), ring(1), ring(2), ring(3), ring(4), ring(5), ring(6));
        let out = &mut blurred[yc * w + R..yc * w + R + m];
        let mh = |v: u16, g: u32| ((u32::from(v) * g) >> 16) as u16;
        for i in 0..m {
            let acc = mh(r0[i], gv[0])
                + mh(r1[i], gv[1])
                + mh(r2[i], gv[2])
                + mh(r3[i], gv[3])
                + mh(r4[i], gv[4])
                + mh(r5[i], gv[5])
                + mh(r6[i], gv[6]);
            out[i] = ((u32::from(acc) + 128) >> 8) as u8;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::slam::matcher::{match_brute_force, MatchConfig};
    use crate::slam::synthetic::shapes_texture;

    fn extractor() -> OrbExtractor {
        OrbExtractor::new(OrbConfig::default()).unwrap()
    }

    #[test]
    fn keypoint_rows_and_descriptor_bytes_follow_the_features() {
        let kp = Keypoint { x: 3.0, y: 4.0, level: 2, scale: 1.44, angle_rad: 0.5, score: 17 };
        let f = Features { keypoints: vec![kp], descriptors: vec![[1, 0x0203, 0, u64::MAX]] };
        assert_eq!(f.keypoint_rows(), vec![[3.0, 4.0, 2.0, 0.5, 17.0]]);
        let b = f.descriptor_bytes();
        assert_eq!((b[0][0], b[0][8], b[0][9], b[0][16], b[0][31]), (1, 3, 2, 0, 255));
    }

    /// Rotate by `angle_rad` and scale by `scale` about the image centre (bilinear, grey 0 outside).
    fn warp(img: &GreyImage, angle_rad: f64, scale: f64) -> GreyImage {
        let (w, h) = (img.width as usize, img.height as usize);
        let (cx, cy) = (w as f64 / 2.0, h as f64 / 2.0);
        let (s, c) = angle_rad.sin_cos();
        let mut data = vec![0u8; w * h];
        for y in 0..h {
            for x in 0..w {
                // Inverse map: p_src = R⁻¹ (p_dst − c) / scale + c.
                let (dx, dy) = ((x as f64 - cx) / scale, (y as f64 - cy) / scale);
                let (sx, sy) = (c * dx + s * dy + cx, -s * dx + c * dy + cy);
                if sx < 0.0 || sy < 0.0 || sx >= (w - 1) as f64 || sy >= (h - 1) as f64 {
                    continue;
                }
                let (x0, y0) = (sx.floor() as usize, sy.floor() as usize);
                let (a, b) = (sx - x0 as f64, sy - y0 as f64);
                let p = |xx: usize, yy: usize| f64::from(img.data[yy * w + xx]);
                let v = (p(x0, y0) * (1.0 - a) + p(x0 + 1, y0) * a) * (1.0 - b)
                    + (p(x0, y0 + 1) * (1.0 - a) + p(x0 + 1, y0 + 1) * a) * b;
                data[y * w + x] = v.round() as u8;
            }
        }
        GreyImage { width: img.width, height: img.height, data }
    }

    /// (precision, recall over ground-truth correspondences, matches) for a warp of
    /// `shapes_texture(640, 480, 11)`.
    fn warp_scores(angle_deg: f64, scale: f64) -> (f64, f64, usize) {
        let img = shapes_texture(640, 480, 11);
        let warped = warp(&img, angle_deg.to_radians(), scale);
        let mut orb = extractor();
        let a = orb.extract(&img).unwrap();
        let b = orb.extract(&warped).unwrap();
        let (s, c) = angle_deg.to_radians().sin_cos();
        let map = |k: &Keypoint| {
            let (dx, dy) = (f64::from(k.x) - 320.0, f64::from(k.y) - 240.0);
            ((c * dx - s * dy) * scale + 320.0, (s * dx + c * dy) * scale + 240.0)
        };
        let tol = 4.0;
        let close = |ka: &Keypoint, kb: &Keypoint| {
            let (x, y) = map(ka);
            (x - f64::from(kb.x)).hypot(y - f64::from(kb.y)) <= tol * f64::from(kb.scale)
        };
        // Ground-truth correspondences: a keypoint of the warped image within 4 px (x its scale)
        // of the mapped position, at the expected pyramid level ±1.
        let level_shift = (scale.ln() / 1.2f64.ln()).round() as i32;
        let level_ok =
            |ka: &Keypoint, kb: &Keypoint| (i32::from(kb.level) - i32::from(ka.level) - level_shift).abs() <= 1;
        // Counted one-to-one: the smaller of the two sides' counts of keypoints with a counterpart.
        let in_a =
            a.keypoints.iter().filter(|ka| b.keypoints.iter().any(|kb| close(ka, kb) && level_ok(ka, kb))).count();
        let in_b =
            b.keypoints.iter().filter(|kb| a.keypoints.iter().any(|ka| close(ka, kb) && level_ok(ka, kb))).count();
        let repeatable = in_a.min(in_b);
        let matches =
            match_brute_force(&a.descriptors, &a.keypoints, &b.descriptors, &b.keypoints, &MatchConfig::default());
        let correct =
            matches.iter().filter(|m| close(&a.keypoints[m.query_index], &b.keypoints[m.train_index])).count();
        (correct as f64 / matches.len().max(1) as f64, correct as f64 / repeatable.max(1) as f64, matches.len())
    }

    #[test]
    fn hamming_counts_the_differing_bits() {
        let mut x = 0x9E37_79B9_7F4A_7C15u64;
        let mut next = || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            x
        };
        for _ in 0..1000 {
            let (a, b): (Descriptor, Descriptor) = ([next(), next(), next(), next()], [next(), next(), next(), next()]);
            let want: u32 = a.iter().zip(&b).map(|(p, q)| (p ^ q).count_ones()).sum();
            assert_eq!(hamming(&a, &b), want);
        }
        assert_eq!(hamming(&[0; 4], &[u64::MAX; 4]), 256);
        assert_eq!(hamming(&[u64::MAX; 4], &[u64::MAX; 4]), 0);
        assert_eq!(hamming(&[1, 0, 0, 1 << 63], &[0; 4]), 2);
    }

    #[test]
    fn python_port_of_the_texture_is_bit_exact() {
        // Sums printed by experiments/bench/slam_refs.py's `shapes_texture` for seeds 0 and 7.
        let sum = |seed| shapes_texture(640, 480, seed).data.iter().map(|&v| u64::from(v)).sum::<u64>();
        assert_eq!(sum(0), 39_142_074);
        assert_eq!(sum(7), 43_270_714);
    }

    #[test]
    fn extracts_the_requested_number_of_spread_features() {
        let img = shapes_texture(640, 480, 3);
        let f = extractor().extract(&img).unwrap();
        assert_eq!(f.keypoints.len(), f.descriptors.len());
        assert!((950..=1000).contains(&f.keypoints.len()), "{}", f.keypoints.len());
        let levels: std::collections::BTreeSet<u8> = f.keypoints.iter().map(|k| k.level).collect();
        assert_eq!(levels.len(), 8);
        for k in &f.keypoints {
            let margin = EDGE_PX as f32 * k.scale - 1.0;
            assert!(k.x >= margin && k.y >= margin && k.x <= 640.0 - margin && k.y <= 480.0 - margin);
        }
        // Spread: every quadrant holds at least 15 % of the features.
        for (qx, qy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
            let n = f.keypoints.iter().filter(|k| (k.x >= 320.0) == (qx == 1) && (k.y >= 240.0) == (qy == 1)).count();
            assert!(n * 100 >= 15 * f.keypoints.len(), "quadrant {qx},{qy}: {n}");
        }
        // Deterministic.
        assert_eq!(extractor().extract(&img).unwrap(), f);
    }

    #[test]
    fn matches_survive_rotation_and_scale() {
        for (angle, scale) in [(30.0, 1.0), (0.0, 1.2), (30.0, 1.2)] {
            let (precision, recall, n) = warp_scores(angle, scale);
            eprintln!("warp {angle}° x{scale}: {n} matches, precision {precision:.3}, recall {recall:.3}");
            // Recall over ground-truth correspondences ≥ 50 % (cv2.ORB_create(1000) + BFMatcher with
            // the same ratio test: 0.59–0.67 on these warps), precision ≥ 95 %.
            assert!(recall >= 0.5, "warp {angle}° x{scale}: recall {recall}");
            assert!(precision >= 0.95, "warp {angle}° x{scale}: precision {precision}");
            assert!(n >= 200);
        }
    }

    #[test]
    fn two_threads_give_the_one_thread_features() {
        // One extractor per thread count, each reused over frames of changing size and content
        // (stale scratch must not leak into the next level or frame), with the weak threshold's
        // second scan on and off, FAST and Harris ranking.
        let frames = [
            shapes_texture(640, 480, 5),
            shapes_texture(640, 480, 6),
            shapes_texture(333, 251, 7),
            shapes_texture(640, 480, 8),
            shapes_texture(45, 40, 9),
        ];
        let configs = [
            OrbConfig::default(),
            OrbConfig { fast_min_threshold: 7, spread_share: 0.5, ..OrbConfig::default() },
            OrbConfig { ranking: Ranking::Fast, n_levels: 3, n_features: 500, ..OrbConfig::default() },
        ];
        for config in configs {
            let mut one = OrbExtractor::new(config).unwrap();
            let mut two = OrbExtractor::new(config).unwrap();
            for (i, img) in frames.iter().enumerate() {
                let a = one.extract(img).unwrap();
                let b = two.extract_with_threads(img, 2).unwrap();
                assert_eq!(a, b, "frame {i}, {config:?}");
                if img.width == 640 {
                    assert!(a.keypoints.len() >= config.n_features * 9 / 10, "frame {i}: {}", a.keypoints.len());
                }
            }
            // More threads than levels, and than two.
            let img = &frames[0];
            assert_eq!(two.extract_with_threads(img, 8).unwrap(), one.extract(img).unwrap());
        }
    }

    #[test]
    fn fast_score_is_the_largest_passing_threshold() {
        // A 9-arc 50 grey levels above the centre whose weakest member is 30 above: score 29 (a
        // corner at threshold 29, not at 30); the lane holds score + 1.
        let w = 40;
        let mut img = vec![100u8; w * 9];
        let centre = 4 * w + 10;
        let offsets: [isize; 16] = CIRCLE.map(|(dx, dy)| dy * w as isize + dx);
        let at = |o: isize| (centre as isize + o) as usize;
        for &o in &offsets[3..12] {
            img[at(o)] = 150;
        }
        img[at(offsets[7])] = 130;
        assert_eq!(fast_lanes(&img, centre, &offsets, 20)[0], 30);
        assert_eq!(fast_lanes(&img, centre, &offsets, 29)[0], 30);
        assert_eq!(fast_lanes(&img, centre, &offsets, 30)[0], 0);
        // The darker side likewise, wrapping past index 15.
        let mut dark = vec![100u8; w * 9];
        for k in 12..21 {
            dark[at(offsets[k % 16])] = 40;
        }
        dark[at(offsets[2])] = 75;
        assert_eq!(fast_lanes(&dark, centre, &offsets, 20)[0], 25);
        // An 8-arc is no corner.
        img[at(offsets[11])] = 100;
        assert_eq!(fast_lanes(&img, centre, &offsets, 20)[0], 0);
    }

    #[test]
    fn degenerate_images_give_no_features_or_an_error() {
        let mut orb = extractor();
        let flat = GreyImage { width: 640, height: 480, data: vec![90; 640 * 480] };
        assert!(orb.extract(&flat).unwrap().keypoints.is_empty());
        let tiny = shapes_texture(20, 20, 1);
        assert!(orb.extract(&tiny).unwrap().keypoints.is_empty());
        let empty = GreyImage { width: 0, height: 0, data: vec![] };
        assert!(orb.extract(&empty).unwrap().keypoints.is_empty());
        let bad = GreyImage { width: 10, height: 10, data: vec![0; 99] };
        assert!(matches!(orb.extract(&bad), Err(SlamError::BufferLength { .. })));
        assert!(OrbExtractor::new(OrbConfig { scale_factor: 1.0, ..OrbConfig::default() }).is_err());
        assert!(OrbExtractor::new(OrbConfig { n_levels: 0, ..OrbConfig::default() }).is_err());
    }
}
