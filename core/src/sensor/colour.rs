//! Colour image: motion blur over the exposure, then shot + read noise.
//!
//! - **Motion blur**: frames are taken while the arm moves. Each pixel's image motion over the
//!   exposure `(du, dv)`, pixels, is the displacement of its rendered surface point under the
//!   camera's motion `camera_end_from_start` (pixels without a surface use a point 10 m along their
//!   ray); the caller computes that motion from the joint velocities and
//!   [`ColourConfig::exposure_s`], so the blur length is exposure time × image velocity. The pixel
//!   becomes the mean of the rendered image (nearest-pixel reconstruction) along the segment of
//!   that displacement centred on the pixel: a box of length `L = max(|du|, |dv|)` along the
//!   segment's major axis, one sample per pixel of that axis at the row (column) the segment
//!   crosses it, the two end pixels weighted by the share of them the segment covers; beyond the
//!   image border the border pixels extend it. A sharp edge moving across the image thus becomes
//!   a linear ramp `L` pixels wide; motion under one pixel leaves the image unchanged. The sums
//!   come from prefix sums along the rows (and, for motion steeper than 45°, down the columns), so
//!   a pixel costs one difference per row (column) its segment crosses, whatever its length.
//! - **Noise**: Poissonian-Gaussian (Foi et al. 2008) on 8-bit values:
//!   `σ²(I) = shot_gain · I + read_noise²`, one draw per channel, rounded and clipped to 0-255: a
//!   256 × 256 table (one per noise setting) maps (value, 8-bit uniform) to the value plus
//!   σ(value) times the normal quantile of that uniform's midpoint (scaled to unit variance;
//!   tails cut at ±2.9 σ).
//!   Each row draws from its own stream of `(seed, frame index, row)`, so rows can be computed in
//!   any order, by any thread, with the same result.
//!
//! Not modelled: rolling shutter (the D435's colour imager has one), exposure and white-balance
//! changes, lens distortion and vignetting.

use super::{
    check, max_f, min_f, normal_quantiles, to_i32, RenderedFrame, SensorError, SensorUnit, SplitMix64, ROUND_F32,
    TAG_COLOUR,
};
use nalgebra::Matrix4;
use serde::{Deserialize, Serialize};
use std::sync::{Arc, Mutex};

/// Colour model parameters (run configuration `[camera.colour]`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ColourConfig {
    /// Exposure time, seconds (15 ms: an indoor auto-exposure of the D435's colour imager at
    /// 30 fps is 10-33 ms). The simulator turns it and the joint velocities into the camera's
    /// motion over the exposure; 0 = no motion blur.
    pub exposure_s: f64,
    /// Signal-dependent noise variance per 8-bit level (0.03: σ ≈ 2 levels at mid grey).
    pub shot_gain: f64,
    /// Signal-independent noise, standard deviation in 8-bit levels (1.0).
    pub read_noise: f64,
}

impl Default for ColourConfig {
    fn default() -> Self {
        Self { exposure_s: 0.015, shot_gain: 0.03, read_noise: 1.0 }
    }
}

impl ColourConfig {
    /// Range checks; errors name the field.
    pub fn validate(&self) -> Result<(), SensorError> {
        const R: &str = "outside its range (see the field's doc)";
        check("camera.colour.exposure_s", self.exposure_s, (0.0..=0.2).contains(&self.exposure_s), R)?;
        check("camera.colour.shot_gain", self.shot_gain, (0.0..=10.0).contains(&self.shot_gain), R)?;
        check("camera.colour.read_noise", self.read_noise, (0.0..=50.0).contains(&self.read_noise), R)?;
        Ok(())
    }
}

/// Longest image side the blur's prefix sums hold exactly (`f32` sums of 8-bit values).
pub(crate) const MAX_SIDE_PX: usize = 1 << 16;

/// Blur, then noise (module docs). `rgb` of `frame` must be non-empty and at most
/// [`MAX_SIDE_PX`] on a side ([`super::simulate_frame`] checks).
pub fn colour_image(
    cfg: &ColourConfig,
    unit: &SensorUnit,
    frame: &RenderedFrame<'_>,
    camera_end_from_start: Option<&Matrix4<f64>>,
    seed: u64,
    frame_index: u64,
) -> Vec<u8> {
    let mut out = vec![0u8; 3 * frame.width * frame.height];
    let table = NoiseTable::new(cfg);
    let mut scratch = BlurScratch::default();
    scratch.start_frame();
    ColourRows::new(unit, frame, None, camera_end_from_start, table.as_ref(), seed, frame_index, &mut scratch)
        .run(0, &mut out);
    out
}

/// The noisy value of each (8-bit value, 8-bit uniform) pair, at `value << 8 | uniform`.
pub(crate) struct NoiseTable(Box<[u8; 1 << 16]>);

impl NoiseTable {
    /// [`Self::new`], kept for the next call with the same noise settings (the same table).
    pub(crate) fn shared(cfg: &ColourConfig) -> Option<Arc<Self>> {
        type Last = Option<((u64, u64), Option<Arc<NoiseTable>>)>;
        static LAST: Mutex<Last> = Mutex::new(None);
        let key = (cfg.shot_gain.to_bits(), cfg.read_noise.to_bits());
        let mut last = LAST.lock().unwrap_or_else(|e| e.into_inner());
        if let Some((k, table)) = &*last {
            if *k == key {
                return table.clone();
            }
        }
        let table = Self::new(cfg).map(Arc::new);
        *last = Some((key, table.clone()));
        table
    }

    /// The table of `cfg`'s noise; None without noise.
    pub(crate) fn new(cfg: &ColourConfig) -> Option<Self> {
        if cfg.shot_gain <= 0.0 && cfg.read_noise <= 0.0 {
            return None;
        }
        let g = normal_quantiles(256);
        let mut table = Box::new([0u8; 1 << 16]);
        for (v, row) in table.chunks_exact_mut(256).enumerate() {
            let sigma = (cfg.shot_gain * v as f64 + cfg.read_noise * cfg.read_noise).sqrt() as f32;
            for (o, q) in row.iter_mut().zip(&g) {
                *o = (v as f32 + sigma * q + 0.5).clamp(0.0, 255.0) as u8;
            }
        }
        Some(Self(table))
    }

    /// Adds the noise of row `y` (its own stream) to `row`.
    fn apply(&self, row: &mut [u8], seed: u64, frame_index: u64, y: usize) {
        self.apply_with(row, &mut SplitMix64::new(seed, &[TAG_COLOUR, frame_index, y as u64]));
    }

    /// The noise of `bytes` in place, eight 8-bit uniforms per 64-bit draw of `rng`.
    fn apply_with(&self, bytes: &mut [u8], rng: &mut SplitMix64) {
        for chunk in bytes.chunks_mut(8) {
            for (v, u) in chunk.iter_mut().zip(rng.next_u64().to_le_bytes()) {
                *v = self.0[(*v as usize) << 8 | u as usize];
            }
        }
    }

    /// [`Self::apply`] on the RGB of `rgbx` (four bytes a pixel, the fourth ignored), written to
    /// `row` (three bytes a pixel): the same bytes as copying the RGB and then applying.
    fn apply_from(&self, rgbx: &[u8], row: &mut [u8], seed: u64, frame_index: u64, y: usize) {
        let mut rng = SplitMix64::new(seed, &[TAG_COLOUR, frame_index, y as u64]);
        // Eight pixels take three draws (24 uniforms, one per byte, in byte order).
        let mut out = row.chunks_exact_mut(24);
        let mut src = rgbx.chunks_exact(32);
        for (o, p) in (&mut out).zip(&mut src) {
            let mut u = [0u8; 24];
            for (c, d) in u.chunks_exact_mut(8).zip([rng.next_u64(), rng.next_u64(), rng.next_u64()]) {
                c.copy_from_slice(&d.to_le_bytes());
            }
            for ((o, p), u) in o.chunks_exact_mut(3).zip(p.chunks_exact(4)).zip(u.chunks_exact(3)) {
                for c in 0..3 {
                    o[c] = self.0[(p[c] as usize) << 8 | u[c] as usize];
                }
            }
        }
        let rest = out.into_remainder();
        for (o, p) in rest.chunks_exact_mut(3).zip(src.remainder().chunks_exact(4)) {
            o.copy_from_slice(&p[..3]);
        }
        self.apply_with(rest, &mut rng);
    }
}

/// The colour model on whole rows of one frame, in any order (each row's result depends on the
/// row alone); one per thread.
pub(crate) struct ColourRows<'a> {
    w: usize,
    src: &'a [u8],
    blur: Option<MotionBlur<'a>>,
    noise: Option<&'a NoiseTable>,
    seed: u64,
    frame_index: u64,
}

impl<'a> ColourRows<'a> {
    /// `true_depth`: the frame's true depth, one value a pixel (0 without a surface), as
    /// [`super::depth::DepthFrame::surfaces`] makes it, on the rows that will be run; the motion
    /// blur reads it in place of the points' z (the same values, contiguous). None: the points'.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn new(
        unit: &SensorUnit,
        frame: &RenderedFrame<'a>,
        true_depth: Option<&'a [f32]>,
        camera_end_from_start: Option<&Matrix4<f64>>,
        noise: Option<&'a NoiseTable>,
        seed: u64,
        frame_index: u64,
        scratch: &'a mut BlurScratch,
    ) -> Self {
        let blur = match camera_end_from_start {
            Some(m) if (m - Matrix4::identity()).abs().max() > 1e-9 => {
                Some(MotionBlur::new(unit, frame, true_depth, m, scratch))
            }
            _ => None,
        };
        Self { w: frame.width, src: frame.rgb, blur, noise, seed, frame_index }
    }

    /// Rows `y0..` of the colour image into `out` (whole rows).
    pub(crate) fn run(&mut self, y0: usize, out: &mut [u8]) {
        let w = self.w;
        for (y, row) in (y0..).zip(out.chunks_exact_mut(3 * w.max(1))) {
            match (self.blur.as_mut(), self.noise) {
                (Some(b), Some(table)) => {
                    b.row(y);
                    table.apply_from(&b.bytes, row, self.seed, self.frame_index, y);
                }
                (Some(b), None) => {
                    b.row(y);
                    for (o, p) in row.chunks_exact_mut(3).zip(b.bytes.chunks_exact(4)) {
                        o.copy_from_slice(&p[..3]);
                    }
                }
                (None, table) => {
                    row.copy_from_slice(&self.src[3 * y * w..3 * (y + 1) * w]);
                    if let Some(table) = table {
                        table.apply(row, self.seed, self.frame_index, y);
                    }
                }
            }
        }
    }
}

/// `v` rounded to the nearest integer (halves to even), as a float.
#[inline]
fn round_f(v: f32) -> f32 {
    (v + ROUND_F32) - ROUND_F32
}

/// `floor(v)` for `|v| < 2^22`.
#[inline]
fn floor_f(v: f32) -> f32 {
    let r = round_f(v);
    if r > v {
        r - 1.0
    } else {
        r
    }
}

/// `ceil(v)` for `|v| < 2^22`.
#[inline]
fn ceil_f(v: f32) -> f32 {
    let r = round_f(v);
    if r < v {
        r + 1.0
    } else {
        r
    }
}

/// RGB and a zero lane.
type Px = [f32; 4];

#[inline]
fn px4(p: &[u8]) -> Px {
    [p[0] as f32, p[1] as f32, p[2] as f32, 0.0]
}

#[inline]
fn add4(a: Px, b: Px) -> Px {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2], a[3] + b[3]]
}

#[inline]
fn sub4(a: Px, b: Px) -> Px {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2], a[3] - b[3]]
}

/// `a + f · b`.
#[inline]
fn fma4(a: Px, f: f32, b: Px) -> Px {
    [a[0] + f * b[0], a[1] + f * b[1], a[2] + f * b[2], a[3] + f * b[3]]
}

/// Prefix sums of the image along one axis (exact in `f32`: sums of at most 2^16 values of 8
/// bits), computed as rows need them: the sum over the first `k` pixels of line `l` sits at
/// `l · line_stride + k · pos_stride`, `k` in `0..=len`.
#[derive(Default)]
struct Prefix {
    sums: Vec<Px>,
    /// Along the rows: which rows are computed. Down the columns (`steep`): rows of sums are
    /// computed in order, `done` of them.
    row_done: Vec<bool>,
    done: usize,
    steep: bool,
}

impl Prefix {
    /// Ready for a frame along the rows: `(w + 1)` sums per row, none computed (the buffer is
    /// kept when its size fits; every sum is written before it is read).
    fn reset_rows(&mut self, w: usize, h: usize) {
        self.sums.resize((w + 1) * h, [0.0; 4]);
        self.row_done.clear();
        self.row_done.resize(h, false);
        (self.done, self.steep) = (0, false);
    }

    /// Ready for a frame down the columns: `h + 1` rows of `w` sums, the first (zeros) computed.
    fn reset_cols(&mut self, w: usize, h: usize) {
        self.sums.resize(w * (h + 1), [0.0; 4]);
        self.sums[..w].fill([0.0; 4]);
        self.row_done.clear();
        (self.done, self.steep) = (1, true);
    }

    /// Computes the rows of sums `lo..=hi` (down the columns: every row up to `hi`).
    fn ensure(&mut self, src: &[u8], w: usize, lo: usize, hi: usize) {
        if self.steep {
            while self.done <= hi {
                let r = self.done;
                let (above, below) = self.sums.split_at_mut(r * w);
                let row = &src[3 * (r - 1) * w..3 * r * w];
                for ((o, a), p) in below[..w].iter_mut().zip(&above[(r - 1) * w..]).zip(row.chunks_exact(3)) {
                    *o = add4(*a, px4(p));
                }
                self.done += 1;
            }
            return;
        }
        let h = self.row_done.len();
        if h == 0 || (lo..=hi.min(h - 1)).all(|r| self.row_done[r]) {
            return;
        }
        // A row missing: the next rows too (the following image rows need them), four at a time
        // where four in a row are missing, so that four running sums advance side by side.
        let end = (hi + AHEAD).min(h - 1);
        let mut r = lo;
        while r <= end {
            if self.row_done[r] {
                r += 1;
                continue;
            }
            let k = if r + 4 <= end + 1 && !self.row_done[r..r + 4].contains(&true) { 4 } else { 1 };
            let sums = &mut self.sums[r * (w + 1)..(r + k) * (w + 1)];
            let src = &src[3 * r * w..3 * (r + k) * w];
            if k == 4 {
                prefix_rows4(src, sums, w);
            } else {
                let mut acc = [0.0f32; 4];
                sums[0] = acc;
                for (o, p) in sums[1..].iter_mut().zip(src.chunks_exact(3)) {
                    acc = add4(acc, px4(p));
                    *o = acc;
                }
            }
            self.row_done[r..r + k].fill(true);
            r += k;
        }
    }
}

/// Rows of sums computed ahead of the rows asked for, when one is missing.
const AHEAD: usize = 3;

/// The prefix sums along four image rows (`src`, `3 w` bytes each) into `sums` (`w + 1` each).
fn prefix_rows4(src: &[u8], sums: &mut [Px], w: usize) {
    let (s0, rest) = sums.split_at_mut(w + 1);
    let (s1, rest) = rest.split_at_mut(w + 1);
    let (s2, s3) = rest.split_at_mut(w + 1);
    let (p0, rest) = src.split_at(3 * w);
    let (p1, rest) = rest.split_at(3 * w);
    let (p2, p3) = rest.split_at(3 * w);
    let mut acc = [[0.0f32; 4]; 4];
    (s0[0], s1[0], s2[0], s3[0]) = (acc[0], acc[1], acc[2], acc[3]);
    let outs = s0[1..].iter_mut().zip(&mut s1[1..]).zip(s2[1..].iter_mut().zip(&mut s3[1..]));
    let ins = p0.chunks_exact(3).zip(p1.chunks_exact(3)).zip(p2.chunks_exact(3).zip(p3.chunks_exact(3)));
    for (((o0, o1), (o2, o3)), ((a, b), (c, d))) in outs.zip(ins) {
        acc = [add4(acc[0], px4(a)), add4(acc[1], px4(b)), add4(acc[2], px4(c)), add4(acc[3], px4(d))];
        (*o0, *o1, *o2, *o3) = (acc[0], acc[1], acc[2], acc[3]);
    }
}

/// Pixels without a surface move like a point this far along their ray, metres.
const FAR_M: f32 = 10.0;

/// Which prefix sums the boxes of a row use: every box along the rows, every box down the
/// columns, or each its own.
const ROWS: u8 = 0;
const COLS: u8 = 1;
const MIXED: u8 = 2;

/// The prefix sums one thread computes for a frame's rows, kept from frame to frame (a frame of
/// the same size reuses them without allocating) and from part to part of a frame (the sums of
/// one part's rows serve the next part the thread takes).
#[derive(Default)]
pub(crate) struct BlurScratch {
    rows: Prefix,
    cols: Prefix,
    /// Whether the sums are of the current frame: false from [`Self::start_frame`] until the
    /// frame's first blurred part resets them.
    in_frame: bool,
}

impl BlurScratch {
    /// A new frame: the sums held are stale.
    pub(crate) fn start_frame(&mut self) {
        self.in_frame = false;
    }
}

/// The motion blur of one frame (module docs), a row at a time.
struct MotionBlur<'a> {
    w: usize,
    h: usize,
    src: &'a [u8],
    pts: &'a [f32],
    /// The true depth of every pixel (0 without a surface), when given: read in place of `pts`.
    true_depth: Option<&'a [f32]>,
    rows: &'a mut Prefix,
    cols: &'a mut Prefix,
    /// Whether `cols` is in use: from the first time a pixel's motion is steeper than 45° (in
    /// any part of the frame this thread took).
    cols_ready: bool,
    /// Rotation (rows) and translation of the camera's motion.
    r: [[f32; 3]; 3],
    t: [f32; 3],
    /// True colour intrinsics fx, fy, cx, cy.
    k: [f32; 4],
    /// Per column: `(x + ½ − cx) / fx`.
    ax: Vec<f32>,
    /// Per pixel of the current row: image motion, pixels.
    du: Vec<f32>,
    dv: Vec<f32>,
    /// Per pixel of the current row, its box: down the columns (1) or along the rows; whether its
    /// segment changes lines; the index of the sums before the pixels holding its two ends and
    /// where in those pixels the ends lie (0-1); 1 / its length; 1 / the slope of the line
    /// index; its start and end as (line, position) along the sums' axis.
    steep: Vec<u32>,
    multi: Vec<u32>,
    i0: Vec<u32>,
    i1: Vec<u32>,
    ends: Vec<[u32; 4]>,
    f0: Vec<f32>,
    f1: Vec<f32>,
    inv_len: Vec<f32>,
    inv_slope: Vec<f32>,
    /// The row's blurred values, then as bytes (four a pixel).
    tot: Vec<Px>,
    bytes: Vec<u8>,
}

impl<'a> MotionBlur<'a> {
    fn new(
        unit: &SensorUnit,
        frame: &RenderedFrame<'a>,
        true_depth: Option<&'a [f32]>,
        m: &Matrix4<f64>,
        scratch: &'a mut BlurScratch,
    ) -> Self {
        let (w, h) = (frame.width, frame.height);
        let k = &unit.colour_true;
        let (f, i) = (vec![0.0f32; w], vec![0u32; w]);
        if !scratch.in_frame {
            scratch.rows.reset_rows(w, h);
            // The column sums wait for the first steep motion (reset then).
            scratch.cols.steep = false;
            scratch.in_frame = true;
        }
        Self {
            w,
            h,
            src: frame.rgb,
            pts: frame.points_in_camera,
            true_depth,
            cols_ready: scratch.cols.steep,
            rows: &mut scratch.rows,
            cols: &mut scratch.cols,
            r: [0, 1, 2].map(|i| [0, 1, 2].map(|j| m[(i, j)] as f32)),
            t: [0, 1, 2].map(|i| m[(i, 3)] as f32),
            k: [k.fx as f32, k.fy as f32, k.cx as f32, k.cy as f32],
            ax: (0..w).map(|x| ((x as f64 + 0.5 - k.cx) / k.fx) as f32).collect(),
            du: f.clone(),
            dv: f.clone(),
            steep: i.clone(),
            multi: i.clone(),
            i0: i.clone(),
            i1: i,
            ends: vec![[0; 4]; w],
            f0: f.clone(),
            f1: f.clone(),
            inv_len: f.clone(),
            inv_slope: f,
            tot: vec![[0.0; 4]; w],
            bytes: vec![0; 4 * w],
        }
    }

    /// Blurs row `y` into `bytes` (four bytes a pixel: RGB and a spare).
    fn row(&mut self, y: usize) {
        let (w, h) = (self.w, self.h);
        let (any, all) = self.motion(y);
        let mode = if all {
            COLS
        } else if any {
            MIXED
        } else {
            ROWS
        };
        match mode {
            ROWS => self.boxes::<ROWS>(y),
            COLS => self.boxes::<COLS>(y),
            _ => self.boxes::<MIXED>(y),
        }
        // The rows of sums the row reads (of either array, at most).
        let (lo, hi) =
            self.i0[..w].iter().chain(&self.i1[..w]).fold((u32::MAX, 0), |(lo, hi), &i| (lo.min(i), hi.max(i)));
        if mode != COLS {
            self.rows.ensure(self.src, w, lo as usize / (w + 1), hi as usize / (w + 1));
        }
        if mode != ROWS {
            if !self.cols_ready {
                self.cols.reset_cols(w, h);
                self.cols_ready = true;
            }
            self.cols.ensure(self.src, w, 0, (hi as usize / w + 1).min(h));
        }
        match mode {
            ROWS => self.sums::<ROWS>(y),
            COLS => self.sums::<COLS>(y),
            _ => self.sums::<MIXED>(y),
        }
        // Rounded to the nearest level (the low byte of the rounding sum).
        for (b, t) in self.bytes.iter_mut().zip(self.tot.as_flattened()) {
            *b = (min_f(max_f(*t, 0.0), 255.0) + ROUND_F32).to_bits() as u8;
        }
    }

    /// The image motion of each pixel of row `y` into `du`, `dv` (0 where the surface is behind
    /// the moved camera or the motion is not finite); whether any and whether every pixel's
    /// motion is steeper than 45°.
    fn motion(&mut self, y: usize) -> (bool, bool) {
        let w = self.w;
        let [fx, fy, _, cy] = self.k;
        let [[r00, r01, r02], [r10, r11, r12], [r20, r21, r22]] = self.r;
        let [tx, ty, tz] = self.t;
        let ay = (y as f32 + 0.5 - cy) / fy;
        // Rotated ray direction r · (ax, ay, 1) = ax · col0 + (ay · col1 + col2).
        let (px, py, pz) = (r01 * ay + r02, r11 * ay + r12, r21 * ay + r22);
        // Depths of the row, contiguous (so that the loop below runs on several pixels at a time);
        // the true depth is the points' z where that is a surface, 0 elsewhere, so it gives the
        // same motion.
        if let Some(z) = self.true_depth {
            self.du[..w].copy_from_slice(&z[y * w..(y + 1) * w]);
        } else {
            for (z, p) in self.du.iter_mut().zip(self.pts[3 * y * w..3 * (y + 1) * w].chunks_exact(3)) {
                *z = p[2];
            }
        }
        let mut steep = 0u32;
        for ((du, dv), &ax) in self.du[..w].iter_mut().zip(&mut self.dv[..w]).zip(&self.ax[..w]) {
            let zp = *du;
            let z = if zp > 0.0 && zp < f32::INFINITY { zp } else { FAR_M };
            let (rx, ry, rz) = (r00 * ax + px, r10 * ax + py, r20 * ax + pz);
            let qz = z * rz + tz;
            let inv = 1.0 / qz;
            let (u, v) = (fx * ((z * rx + tx) * inv - ax), fy * ((z * ry + ty) * inv - ay));
            let ok = qz > 1e-6 && u.abs() < 1e6 && v.abs() < 1e6;
            *du = if ok { u } else { 0.0 };
            *dv = if ok { v } else { 0.0 };
            steep += u32::from(dv.abs() > du.abs());
        }
        (steep > 0, steep as usize == w)
    }

    /// The boxes of row `y` (no branches: this runs on several pixels at a time).
    fn boxes<const MODE: u8>(&mut self, y: usize) {
        let w = self.w;
        let (wf, hf, yf) = (w as f32, self.h as f32, y as f32);
        let (du, dv) = (&self.du[..w], &self.dv[..w]);
        let (steep, multi, i0, i1, ends, f0, f1, inv_len, inv_slope) = (
            &mut self.steep[..w],
            &mut self.multi[..w],
            &mut self.i0[..w],
            &mut self.i1[..w],
            &mut self.ends[..w],
            &mut self.f0[..w],
            &mut self.f1[..w],
            &mut self.inv_len[..w],
            &mut self.inv_slope[..w],
        );
        // Sums along the rows: index line · (w + 1) + k; down the columns: line + k · w.
        let (row_stride, col_stride) = ((w + 1) as u32, w as u32);
        for x in 0..w {
            let (du, dv) = (du[x], dv[x]);
            let is_steep = match MODE {
                ROWS => false,
                COLS => true,
                _ => dv.abs() > du.abs(),
            };
            let (major, minor) = if is_steep { (dv, du) } else { (du, dv) };
            let len = major.abs();
            // Under a pixel of motion: a box of one pixel, the pixel itself.
            let moving = len >= 1.0;
            let r = 1.0 / major;
            let s = if moving { minor * r } else { 0.0 };
            let half = if moving { 0.5 * len } else { 0.5 };
            let xf = x as i32 as f32;
            let (p, q) = if is_steep { (yf, xf) } else { (xf, yf) };
            let (n_pos, n_line) = if is_steep { (hf, wf) } else { (wf, hf) };
            // Along the lines pixel k spans [k, k + 1) once shifted by ½: the segment runs from a
            // to b, starting in pixel ka on line la and ending in kb on lb (border pixels extend
            // it beyond the image).
            let (a, b) = (p - half + 0.5, p + half + 0.5);
            let ka = min_f(max_f(floor_f(a), 0.0), n_pos - 1.0);
            let kb = min_f(max_f(floor_f(b), 0.0), n_pos - 1.0);
            let la = min_f(max_f(round_f(q + (ka - p) * s), 0.0), n_line - 1.0);
            let lb = min_f(max_f(round_f(q + (kb - p) * s), 0.0), n_line - 1.0);
            let [la_i, ka_i, lb_i, kb_i] = [la, ka, lb, kb].map(|v| to_i32(v) as u32);
            ends[x] = [la_i, ka_i, lb_i, kb_i];
            (i0[x], i1[x]) = if is_steep {
                (la_i + ka_i * col_stride, lb_i + kb_i * col_stride)
            } else {
                (la_i * row_stride + ka_i, lb_i * row_stride + kb_i)
            };
            steep[x] = u32::from(is_steep);
            multi[x] = u32::from(la != lb);
            (f0[x], f1[x]) = (a - ka, b - kb);
            inv_len[x] = if moving { r.abs() } else { 1.0 };
            inv_slope[x] = 1.0 / s;
        }
    }

    /// Each box's mean into `tot`: the integral of the line (nearest-pixel reconstruction) to
    /// the end minus that to the start, plus the line changes in between.
    fn sums<const MODE: u8>(&mut self, y: usize) {
        let w = self.w;
        let mut tots = std::mem::take(&mut self.tot);
        let rows = &self.rows.sums;
        let cols = if self.cols_ready { &self.cols.sums } else { rows };
        let ends = self.i0[..w].iter().zip(&self.i1[..w]).zip(self.f0[..w].iter().zip(&self.f1[..w]));
        let rest = self.inv_len[..w].iter().zip(&self.multi[..w]).zip(&self.steep[..w]);
        for (x, ((tot, ((&ia, &ib), (&fa, &fb))), ((&inv_len, &multi), &steep))) in
            tots[..w].iter_mut().zip(ends).zip(rest).enumerate()
        {
            let steep = match MODE {
                ROWS => false,
                COLS => true,
                _ => steep != 0,
            };
            let (sums, ps) = if steep { (cols, w) } else { (rows, 1) };
            let (ia, ib) = (ia as usize, ib as usize);
            let (a, b) = (&sums[ia..=ia + ps], &sums[ib..=ib + ps]);
            let (a0, a1, b0, b1) = (a[0], a[ps], b[0], b[ps]);
            let mut total = sub4(fma4(b0, fb, sub4(b1, b0)), fma4(a0, fa, sub4(a1, a0)));
            if multi != 0 {
                total = add4(total, self.line_changes(x, y));
            }
            *tot = total.map(|t| t * inv_len);
        }
        self.tot = tots;
    }

    /// Where pixel (x, y)'s segment changes lines (crosses l ± ½): the sum up to there on the
    /// line it leaves minus the same on the line it enters.
    #[inline(always)]
    fn line_changes(&self, x: usize, y: usize) -> Px {
        let w = self.w;
        let steep = self.steep[x] != 0;
        let (pre, line_stride, ps) =
            if steep && self.cols_ready { (&self.cols.sums, 1, w) } else { (&self.rows.sums, w + 1, 1) };
        let [la, ka, lb, kb] = self.ends[x].map(|v| v as usize);
        let (p, q) = if steep { (y as f32, x as f32) } else { (x as f32, y as f32) };
        let up = lb > la;
        let inv = self.inv_slope[x];
        // The crossings come in order along the segment (t grows from line to line), so each is
        // clamped to the segment's own ends: no crossing waits for the one before it.
        let (kaf, kbf) = (ka as f32, kb as f32);
        let (step, off, next_off) =
            if up { (line_stride as isize, 0.5, 0.0) } else { (-(line_stride as isize), -0.5, 1.0) };
        let mut total = [0.0f32; 4];
        let mut lf = la as f32;
        let mut i = (la * line_stride) as isize;
        for _ in 0..la.abs_diff(lb) {
            let t = p + (lf + off - q) * inv;
            // The first pixel past line l's run.
            let next = if up { ceil_f(t) } else { floor_f(t) } + next_off;
            let next = (to_i32(min_f(max_f(next, kaf), kbf)) as usize * ps) as isize;
            total = add4(total, sub4(pre[(i + next) as usize], pre[(i + step + next) as usize]));
            i += step;
            lf += if up { 1.0 } else { -1.0 };
        }
        total
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // tests may unwrap (STYLE.md 18)
mod tests {
    use super::super::Intrinsics;
    use super::*;

    const W: usize = 160;
    const H: usize = 120;

    fn unit() -> SensorUnit {
        let k = Intrinsics { fx: 108.0, fy: 108.0, cx: 80.0, cy: 60.0 };
        let mut e = [[0.0; 4]; 4];
        for (i, row) in e.iter_mut().enumerate() {
            row[i] = 1.0;
        }
        SensorUnit {
            colour_assumed: k,
            colour_true: k,
            depth_scale: 1.0,
            depth_focal_ratio: 1.0,
            depth_pp_offset: [0.0; 2],
            registration_error: e,
        }
    }

    fn plane(z: f32) -> (Vec<f32>, Vec<f32>) {
        let k = unit().colour_true;
        let mut p = vec![0.0f32; 3 * W * H];
        for y in 0..H {
            for x in 0..W {
                let i = y * W + x;
                p[3 * i] = ((x as f64 + 0.5 - k.cx) / k.fx) as f32 * z;
                p[3 * i + 1] = ((y as f64 + 0.5 - k.cy) / k.fy) as f32 * z;
                p[3 * i + 2] = z;
            }
        }
        (p, vec![0.0; 3 * W * H])
    }

    #[test]
    fn noise_variance_follows_the_model() {
        let cfg = ColourConfig::default();
        let (p, n) = plane(0.5);
        for level in [20u8, 128, 230] {
            let rgb = vec![level; 3 * W * H];
            let f = RenderedFrame { width: W, height: H, points_in_camera: &p, normals_in_camera: &n, rgb: &rgb };
            let out = colour_image(&cfg, &unit(), &f, None, 3, 0);
            let var = out.iter().map(|v| (*v as f64 - level as f64).powi(2)).sum::<f64>() / out.len() as f64;
            // Rounding adds 1/12.
            let want = cfg.shot_gain * level as f64 + cfg.read_noise.powi(2) + 1.0 / 12.0;
            assert!((var / want - 1.0).abs() < 0.1, "level {level}: var {var} vs {want}");
        }
    }

    #[test]
    fn row_prefix_sums_are_running_sums() {
        for w in [1usize, 2, 7, 10] {
            let h = 9;
            let src: Vec<u8> = (0..3 * w * h).map(|i| (i * 53 % 256) as u8).collect();
            let mut prefix = Prefix::default();
            prefix.reset_rows(w, h);
            // Rows four at a time (0-3, then 5-8) and one at a time (4).
            for (lo, hi) in [(0, 0), (5, 5), (0, h - 1)] {
                prefix.ensure(&src, w, lo, hi);
            }
            assert!(prefix.row_done.iter().all(|&d| d));
            for r in 0..h {
                let mut want = [0.0f32; 4];
                for k in 0..=w {
                    assert_eq!(prefix.sums[r * (w + 1) + k], want, "w {w} row {r} k {k}");
                    if k < w {
                        want = add4(want, px4(&src[3 * (r * w + k)..]));
                    }
                }
            }
        }
    }

    #[test]
    fn noise_from_four_byte_pixels_equals_copy_then_noise() {
        let table = NoiseTable::new(&ColourConfig::default()).unwrap();
        // Row lengths with and without a remainder after groups of eight pixels.
        for w in [1usize, 5, 8, 13, 16, 21] {
            let rgbx: Vec<u8> = (0..4 * w).map(|i| (i * 37 % 251) as u8).collect();
            let mut want: Vec<u8> = rgbx.chunks_exact(4).flat_map(|p| p[..3].to_vec()).collect();
            table.apply(&mut want, 9, 2, 7);
            let mut got = vec![0u8; 3 * w];
            table.apply_from(&rgbx, &mut got, 9, 2, 7);
            assert_eq!(got, want, "w {w}");
        }
    }

    /// An image black where `white(x, y)` is false and white elsewhere.
    fn two_tone(white: impl Fn(usize, usize) -> bool) -> Vec<u8> {
        let mut rgb = vec![0u8; 3 * W * H];
        for y in 0..H {
            for x in 0..W {
                if white(x, y) {
                    rgb[3 * (y * W + x)..3 * (y * W + x) + 3].fill(255);
                }
            }
        }
        rgb
    }

    /// The camera translating by `t` metres (x, y) over the exposure, in front of a plane at 0.5 m:
    /// every pixel moves by `−108 · t / 0.5` pixels.
    fn blurred(rgb: &[u8], t: [f64; 2]) -> Vec<u8> {
        let cfg = ColourConfig { shot_gain: 0.0, read_noise: 0.0, ..Default::default() };
        let (p, n) = plane(0.5);
        let f = RenderedFrame { width: W, height: H, points_in_camera: &p, normals_in_camera: &n, rgb };
        let mut m = Matrix4::identity();
        (m[(0, 3)], m[(1, 3)]) = (t[0], t[1]);
        colour_image(&cfg, &unit(), &f, Some(&m), 1, 0)
    }

    /// A box of length `len` px centred on pixel `i` over an edge at `edge − ½` (white from pixel
    /// `edge` on): the share of the box on the white side, in 8-bit levels.
    fn ramp(i: usize, edge: usize, len: f64) -> f64 {
        255.0 * ((i as f64 + 0.5 * len - (edge as f64 - 0.5)) / len).clamp(0.0, 1.0)
    }

    #[test]
    fn a_moving_edge_becomes_a_ramp_as_long_as_the_motion() {
        let vertical_edge = two_tone(|x, _| x >= W / 2);
        let horizontal_edge = two_tone(|_, y| y >= H / 2);
        // 2.5 cm over the exposure at 0.5 m: 108 · 0.025 / 0.5 = 5.4 px.
        let len = 108.0 * 0.025 / 0.5;
        // Along x (row sums), along y (column sums), and diagonally (one row per pixel along x): the
        // profile across the edge is the box's share on the white side.
        for (t, axis_x) in [([-0.025, 0.0], true), ([0.0, 0.025], false), ([0.025, -0.025], true)] {
            let (img, out) = if axis_x {
                (&vertical_edge, blurred(&vertical_edge, t))
            } else {
                (&horizontal_edge, blurred(&horizontal_edge, t))
            };
            let (y, x) = (H / 2 + 7, W / 2 + 9);
            let profile: Vec<f64> = if axis_x {
                (0..W).map(|x| out[3 * (y * W + x)] as f64).collect()
            } else {
                (0..H).map(|y| out[3 * (y * W + x)] as f64).collect()
            };
            let edge = if axis_x { W / 2 } else { H / 2 };
            for (i, v) in profile.iter().enumerate() {
                assert!((v - ramp(i, edge, len)).abs() <= 1.0, "t {t:?}: pixel {i}: {v} vs {}", ramp(i, edge, len));
            }
            // The grey band is the motion's length wide.
            let grey = profile.iter().filter(|v| **v > 0.0 && **v < 255.0).count();
            assert_eq!(grey, 6, "t {t:?}");
            assert_ne!(out, *img);
        }
        // Motion along an edge leaves it sharp: vertically over a vertical edge, and along the
        // diagonal over a diagonal edge (away from the image border, where the border pixels
        // extend the path).
        assert_eq!(blurred(&vertical_edge, [0.0, -0.025]), vertical_edge);
        let diagonal_edge = two_tone(|x, y| x + y >= 140);
        let out = blurred(&diagonal_edge, [0.025, -0.025]);
        for y in 4..H - 4 {
            let row = 3 * y * W..3 * (y + 1) * W;
            assert_eq!(out[row.clone()], diagonal_edge[row], "row {y}");
        }
        // Under a pixel of motion nothing changes.
        assert_eq!(blurred(&vertical_edge, [-0.004, 0.0]), vertical_edge);
    }
}
