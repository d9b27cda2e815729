//! Active-stereo depth (Intel RealSense D435 class, 640 × 480), from the renderer's geometry.
//!
//! Per frame, on the colour camera's rendered pixel grid (the depth imager is taken to sit at the
//! colour camera; the calibration error between them is [`super::SensorUnit`]'s):
//! 1. **Range**: surfaces nearer than [`StereoDepthConfig::min_range_m`] (beyond the 126-pixel
//!    disparity search: Min-Z = focal × baseline / 126, D400 datasheet) or farther than
//!    [`StereoDepthConfig::max_range_m`] give no return.
//! 2. **Second-imager shadow**: depth is computed in the left imager's frame; a pixel whose ray
//!    from the right imager, [`StereoDepthConfig::baseline_m`] along +x, is blocked by a nearer
//!    surface has no match and is invalid (Keselman et al. 2017, the left-right check). One
//!    scanline pass per row: in rectified coordinates the right image sees pixel `u` at
//!    `u − f·B/z`; a pixel whose right-image coordinate lies beyond that of a pixel to its right
//!    is hidden from the right imager. The D435's emitter sits between the imagers on the same
//!    line, so its shadow lies inside this one (a texture-poor surface in it would also fail).
//! 3. **Grazing incidence**: the return drops out with a probability rising linearly from 0 at
//!    [`StereoDepthConfig::grazing_start_deg`] to 1 at [`StereoDepthConfig::grazing_end_deg`]
//!    between the viewing ray and the rendered surface normal (the matching window sees the
//!    surface foreshortened to nothing).
//! 4. **Silhouettes (flying pixels)**: a pixel within [`StereoDepthConfig::mixed_band_px`] of a
//!    depth jump larger than `edge_jump_m + edge_jump_rel · z` takes, with probability
//!    [`StereoDepthConfig::mixed_fraction`], a depth mixed between the near and far side
//!    (`z_near + α (z_far − z_near)`, α uniform): the matching window straddles both surfaces.
//! 5. **Disparity noise**: the disparity `d = f·B/z` gets an error of RMS
//!    [`StereoDepthConfig::subpixel_rms_px`], spatially correlated as block matching makes it (a
//!    unit-variance field interpolated bilinearly from independent values on a grid of
//!    [`StereoDepthConfig::correlation_px`] depth pixels, normalised per pixel); to first order the
//!    depth RMS is `z² · s / (f · B)` (Intel's tuning white paper), 1.04 mm at 0.5 m with the
//!    defaults. Then the unit's **depth-scale** error multiplies every value.
//! 6. **Registration**: each depth pixel's two corners go through the depth intrinsic error and
//!    the colour ← depth extrinsic error and are projected with the *assumed* colour intrinsics;
//!    the rectangle between them is filled, nearest surface kept (librealsense's align-to-colour).
//!    Colour pixels no depth pixel reaches stay 0.
//! 7. **Quantisation** to [`StereoDepthConfig::unit_m`] (the 16-bit depth unit, 1 mm by default).
//!
//! Not modelled: depth motion blur (the D435's depth imagers have a global shutter and short
//! exposure), the invalid band at the depth image's left border (the depth field of view is wider
//! than the colour's and the band falls outside the registered image), temporal noise
//! correlation, multipath and specular surfaces.

use super::{check, RenderedFrame, SensorError, SensorUnit, SplitMix64, TAG_DEPTH};
use nalgebra::{Matrix3, Vector3};
use serde::{Deserialize, Serialize};

/// Depth model parameters (run configuration `[camera.stereo]`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct StereoDepthConfig {
    /// Depth imager focal length, pixels (D435 at 640 × 480: librealsense reports fx ≈ 381-386;
    /// 383). Enters the disparity `f·B/z`, hence the noise and Min-Z.
    pub focal_px: f64,
    /// Stereo baseline, metres (D435: 50 mm, datasheet).
    pub baseline_m: f64,
    /// Disparity error RMS, pixels ("subpixel"; about 0.08 on a textured flat target, Intel's
    /// tuning white paper; 0.05-0.1 typical).
    pub subpixel_rms_px: f64,
    /// Correlation length of the disparity error, depth pixels: the spacing of the grid the noise
    /// field is interpolated from (stereo matching windows of the D4 ASIC are several pixels wide).
    pub correlation_px: f64,
    /// Per-episode depth-scale error, standard deviation (0.5 %; clipped to 3 σ = 1.5 %, inside
    /// the datasheet's 2 % absolute-accuracy bound).
    pub scale_sigma: f64,
    /// Minimum range, metres (Min-Z = 383 px × 50 mm / 126 px = 0.152 m at 640 × 480).
    pub min_range_m: f64,
    /// Maximum range, metres (the datasheet quotes up to about 10 m; 3 m is beyond every surface
    /// of the tabletop scenes and equals the renderer's far plane).
    pub max_range_m: f64,
    /// Depth unit, metres (1 mm, the D400 default).
    pub unit_m: f64,
    /// Depth jump marking a silhouette: absolute part, metres.
    pub edge_jump_m: f64,
    /// Depth jump marking a silhouette: part relative to the nearer depth.
    pub edge_jump_rel: f64,
    /// Half-width of the mixed band at silhouettes, pixels (0 = none).
    pub mixed_band_px: usize,
    /// Share of the band's pixels that take a mixed depth.
    pub mixed_fraction: f64,
    /// Incidence angle where grazing dropouts start, degrees.
    pub grazing_start_deg: f64,
    /// Incidence angle where every return drops out, degrees.
    pub grazing_end_deg: f64,
    /// Model the second imager's shadow.
    pub shadow: bool,
}

impl Default for StereoDepthConfig {
    fn default() -> Self {
        Self {
            focal_px: 383.0,
            baseline_m: 0.050,
            subpixel_rms_px: 0.08,
            correlation_px: 4.0,
            scale_sigma: 0.005,
            min_range_m: 0.152,
            max_range_m: 3.0,
            unit_m: 0.001,
            edge_jump_m: 0.01,
            edge_jump_rel: 0.02,
            mixed_band_px: 1,
            mixed_fraction: 0.5,
            grazing_start_deg: 70.0,
            grazing_end_deg: 85.0,
            shadow: true,
        }
    }
}

impl StereoDepthConfig {
    /// Range checks; errors name the field.
    pub fn validate(&self) -> Result<(), SensorError> {
        const R: &str = "outside its range (see the field's doc)";
        check("camera.stereo.focal_px", self.focal_px, (50.0..=5000.0).contains(&self.focal_px), R)?;
        check("camera.stereo.baseline_m", self.baseline_m, self.baseline_m > 0.0 && self.baseline_m <= 1.0, R)?;
        check("camera.stereo.subpixel_rms_px", self.subpixel_rms_px, (0.0..=2.0).contains(&self.subpixel_rms_px), R)?;
        check("camera.stereo.correlation_px", self.correlation_px, (1.0..=64.0).contains(&self.correlation_px), R)?;
        check("camera.stereo.scale_sigma", self.scale_sigma, (0.0..=0.05).contains(&self.scale_sigma), R)?;
        check("camera.stereo.min_range_m", self.min_range_m, self.min_range_m >= 0.0, R)?;
        check(
            "camera.stereo.max_range_m",
            self.max_range_m,
            self.max_range_m > self.min_range_m && self.max_range_m <= 100.0,
            "must exceed min_range_m and be at most 100",
        )?;
        check("camera.stereo.unit_m", self.unit_m, (0.0..=0.01).contains(&self.unit_m), R)?;
        check("camera.stereo.edge_jump_m", self.edge_jump_m, self.edge_jump_m >= 0.0, R)?;
        check("camera.stereo.edge_jump_rel", self.edge_jump_rel, self.edge_jump_rel >= 0.0, R)?;
        check("camera.stereo.mixed_band_px", self.mixed_band_px as f64, self.mixed_band_px <= 8, R)?;
        check("camera.stereo.mixed_fraction", self.mixed_fraction, (0.0..=1.0).contains(&self.mixed_fraction), R)?;
        check(
            "camera.stereo.grazing_start_deg",
            self.grazing_start_deg,
            (0.0..=90.0).contains(&self.grazing_start_deg),
            R,
        )?;
        check(
            "camera.stereo.grazing_end_deg",
            self.grazing_end_deg,
            self.grazing_end_deg > self.grazing_start_deg && self.grazing_end_deg <= 90.0,
            "must exceed grazing_start_deg and be at most 90",
        )?;
        Ok(())
    }

    /// The model's depth RMS at distance `z_m` from disparity noise alone, metres:
    /// `z² · s / (f · B)`.
    pub fn depth_rms_m(&self, z_m: f64) -> f64 {
        z_m * z_m * self.subpixel_rms_px / (self.focal_px * self.baseline_m)
    }
}

/// What the depth model did to a frame (pixel counts on the rendered grid, before registration).
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct DepthStats {
    /// Pixels with a rendered surface.
    pub surface: usize,
    /// Dropped for range.
    pub out_of_range: usize,
    /// Invalid in the second imager's shadow.
    pub shadow: usize,
    /// Dropped at grazing incidence.
    pub grazing: usize,
    /// Given a mixed depth at a silhouette.
    pub mixed: usize,
    /// Registered pixels with a depth.
    pub valid_out: usize,
}

/// Per pixel of a row, the minimum (`lo`) and maximum (`hi`) of the positive values of `z` within
/// `r` pixels along the row; `(inf, 0)` where there are none. `pad` is scratch space.
fn row_min_max(z: &[f32], r: usize, pad: &mut Vec<f32>, lo: &mut [f32], hi: &mut [f32]) {
    let w = z.len();
    pad.clear();
    pad.resize(w + 2 * r, 0.0);
    pad[r..r + w].copy_from_slice(z);
    // Invalid values (0) never win a maximum; for the minimum they count as +inf.
    hi.copy_from_slice(&pad[..w]);
    for k in 1..=2 * r {
        for (o, v) in hi.iter_mut().zip(&pad[k..k + w]) {
            *o = o.max(*v);
        }
    }
    for v in pad.iter_mut() {
        if *v <= 0.0 {
            *v = f32::INFINITY;
        }
    }
    lo.copy_from_slice(&pad[..w]);
    for k in 1..=2 * r {
        for (o, v) in lo.iter_mut().zip(&pad[k..k + w]) {
            *o = o.min(*v);
        }
    }
}

/// Invalid-pixel causes on the rendered grid.
const OK: u8 = 0;
const NONE: u8 = 1;
const RANGE: u8 = 2;
const SHADOW: u8 = 3;
const GRAZING: u8 = 4;

/// Sub-streams of a frame's depth draws (one per effect, so that the passes need not run in a
/// fixed pixel order across effects).
const SUB_GRAZING: u64 = 1;
const SUB_MIXED: u64 = 2;
const SUB_FIELD: u64 = 3;

/// The depth model on one frame (module docs); returns the registered depth image and counts.
/// Buffer lengths are the caller's to check ([`super::simulate_frame`] does).
pub fn stereo_depth(
    cfg: &StereoDepthConfig,
    unit: &SensorUnit,
    frame: &RenderedFrame<'_>,
    seed: u64,
    frame_index: u64,
) -> (Vec<f32>, DepthStats) {
    let (w, h) = (frame.width, frame.height);
    let n = w * h;
    let mut stats = DepthStats::default();
    let pts = frame.points_in_camera;
    let nrm = frame.normals_in_camera;
    let mut z = vec![0.0f32; n];
    let mut state = vec![OK; n];
    // 1-3. Range, the second imager's shadow (in the rendered grid, true colour focal length) and
    // grazing incidence (squared cosines: a square root only where a dropout is possible), row by
    // row.
    let mut rng = SplitMix64::new(seed, &[TAG_DEPTH, frame_index, SUB_GRAZING]);
    let fb = unit.colour_true.fx * cfg.baseline_m;
    let (c0, c1) = (cfg.grazing_start_deg.to_radians().cos(), cfg.grazing_end_deg.to_radians().cos());
    let c0_sq = (c0 * c0) as f32;
    // Per pixel of a row: the right-image coordinate and the squared cosine of incidence where a
    // grazing dropout is possible (NaN elsewhere).
    let (mut right_x, mut cos_sq) = (vec![0.0f64; w], vec![0.0f32; w]);
    for y in 0..h {
        let zr = &mut z[y * w..(y + 1) * w];
        let sr = &mut state[y * w..(y + 1) * w];
        let pr = &pts[3 * y * w..3 * (y + 1) * w];
        for ((zv, st), p) in zr.iter_mut().zip(sr.iter_mut()).zip(pr.chunks_exact(3)) {
            let v = p[2];
            let surface = v.is_finite() && v > 0.0;
            let zi = v as f64;
            let out = surface && (zi < cfg.min_range_m || zi > cfg.max_range_m);
            *zv = if surface { v } else { 0.0 };
            *st = if !surface {
                NONE
            } else if out {
                RANGE
            } else {
                OK
            };
            stats.surface += usize::from(surface);
            stats.out_of_range += usize::from(out);
        }
        if cfg.shadow {
            for (x, (r, zv)) in right_x.iter_mut().zip(zr.iter()).enumerate() {
                *r = x as f64 - fb / *zv as f64;
            }
            let mut m = f64::INFINITY;
            for (st, &r) in sr.iter_mut().zip(&right_x).rev() {
                if *st == NONE {
                    continue;
                }
                if r > m + 1e-3 {
                    if *st == OK {
                        *st = SHADOW;
                        stats.shadow += 1;
                    }
                } else {
                    m = r;
                }
            }
        }
        // Incidence of the whole row first (no branches), then the draws where it is grazing.
        let nr = &nrm[3 * y * w..3 * (y + 1) * w];
        for (((c, st), p), nv) in cos_sq.iter_mut().zip(sr.iter()).zip(pr.chunks_exact(3)).zip(nr.chunks_exact(3)) {
            let (px, py, pz) = (p[0], p[1], p[2]);
            let (nx, ny, nz) = (nv[0], nv[1], nv[2]);
            let dot = px * nx + py * ny + pz * nz;
            let denom = (px * px + py * py + pz * pz) * (nx * nx + ny * ny + nz * nz);
            let usable = *st == OK && denom > 0.0 && denom.is_finite();
            *c = if usable { dot * dot / denom } else { f32::NAN };
        }
        for (st, &c) in sr.iter_mut().zip(&cos_sq) {
            if c < c0_sq {
                let cos = (c as f64).sqrt();
                let p_drop = ((c0 - cos) / (c0 - c1)).clamp(0.0, 1.0);
                if rng.uniform() < p_drop {
                    *st = GRAZING;
                    stats.grazing += 1;
                }
            }
        }
    }
    // 4. Mixed depths at silhouettes, from the true depths of the neighbourhood (min / max over
    // the (2 band + 1)² window, valid depths only: along rows, then across them per output row).
    // The row minima and maxima live in a ring of 2 band + 1 rows, each computed before its row
    // takes mixed depths.
    let band = cfg.mixed_band_px;
    if band > 0 && cfg.mixed_fraction > 0.0 && h > 0 {
        let mut rng = SplitMix64::new(seed, &[TAG_DEPTH, frame_index, SUB_MIXED]);
        let ring = 2 * band + 1;
        let (mut ring_lo, mut ring_hi) = (vec![0.0f32; ring * w], vec![0.0f32; ring * w]);
        let mut pad = Vec::with_capacity(w + 2 * band);
        let mut row_extrema = |yy: usize, z: &[f32], ring_lo: &mut [f32], ring_hi: &mut [f32]| {
            let r = (yy % ring) * w..(yy % ring + 1) * w;
            row_min_max(&z[yy * w..(yy + 1) * w], band, &mut pad, &mut ring_lo[r.clone()], &mut ring_hi[r]);
        };
        for yy in 0..band.min(h) {
            row_extrema(yy, &z, &mut ring_lo, &mut ring_hi);
        }
        let (mut lo, mut hi) = (vec![0.0f32; w], vec![0.0f32; w]);
        let mut edge = vec![false; w];
        let (jump_m, jump_rel) = (cfg.edge_jump_m, cfg.edge_jump_rel);
        for y in 0..h {
            if y + band < h {
                row_extrema(y + band, &z, &mut ring_lo, &mut ring_hi);
            }
            let (y0, y1) = (y.saturating_sub(band), (y + band + 1).min(h));
            let row = |yy: usize| (yy % ring) * w..(yy % ring + 1) * w;
            lo.copy_from_slice(&ring_lo[row(y0)]);
            hi.copy_from_slice(&ring_hi[row(y0)]);
            for yy in y0 + 1..y1 {
                for (o, v) in lo.iter_mut().zip(&ring_lo[row(yy)]) {
                    *o = o.min(*v);
                }
                for (o, v) in hi.iter_mut().zip(&ring_hi[row(yy)]) {
                    *o = o.max(*v);
                }
            }
            // Silhouette pixels of the row first (no branches), then the draws at them, in order.
            for (((e, st), &l), &u) in edge.iter_mut().zip(&state[y * w..(y + 1) * w]).zip(&lo).zip(&hi) {
                *e = (*st == OK) & (((u - l) as f64) > jump_m + jump_rel * l as f64);
            }
            let zr = &mut z[y * w..(y + 1) * w];
            for (((zv, &e), &l), &u) in zr.iter_mut().zip(&edge).zip(&lo).zip(&hi) {
                if e && rng.uniform() < cfg.mixed_fraction {
                    *zv = l + (rng.uniform() as f32) * (u - l);
                    stats.mixed += 1;
                }
            }
        }
    }
    // 5. Correlated disparity noise, then the unit's scale error:
    // z' = f·B / (f·B / z + s·e) · scale = z · scale / (1 + s·e·z / (f·B)).
    let cell = (cfg.correlation_px * unit.colour_true.fx / cfg.focal_px).max(1.0);
    let mut rng = SplitMix64::new(seed, &[TAG_DEPTH, frame_index, SUB_FIELD]);
    let mut field = CorrelatedField::new(w, h, cell, &mut rng);
    let k_noise = (cfg.subpixel_rms_px / (cfg.focal_px * cfg.baseline_m)) as f32;
    let scale = unit.depth_scale as f32;
    let mut row = vec![0.0f32; w];
    for y in 0..h {
        field.row(y, &mut row);
        let zr = &mut z[y * w..(y + 1) * w];
        let sr = &state[y * w..(y + 1) * w];
        for ((zv, st), e) in zr.iter_mut().zip(sr).zip(&row) {
            if *st != OK {
                *zv = 0.0;
                continue;
            }
            let den = 1.0 + k_noise * *e * *zv;
            *zv = if den > 0.0 { *zv * scale / den } else { 0.0 };
        }
    }
    // 6. Registration to the colour image by the assumed calibration.
    let (out, valid) = register(cfg, unit, &z, w, h);
    stats.valid_out = valid;
    (out, stats)
}

/// A unit-variance, spatially correlated field: independent normals on a grid of spacing
/// `cell_px` pixels, interpolated bilinearly and divided by the interpolation's standard
/// deviation at each pixel (so every pixel has variance 1). Evaluated a row at a time.
pub(crate) struct CorrelatedField {
    width: usize,
    gw: usize,
    grid: Vec<f32>,
    /// Per column: grid column, interpolation weight, normalisation.
    xs: Vec<(usize, f32, f32)>,
    /// Per row: grid row, interpolation weight, normalisation.
    ys: Vec<(usize, f32, f32)>,
    /// Scratch: the current row interpolated between its two grid rows.
    between: Vec<f32>,
}

impl CorrelatedField {
    pub(crate) fn new(width: usize, height: usize, cell_px: f64, rng: &mut SplitMix64) -> Self {
        let gw = (width as f64 / cell_px).ceil() as usize + 2;
        let gh = (height as f64 / cell_px).ceil() as usize + 2;
        let grid: Vec<f32> = (0..gw * gh).map(|_| rng.normal() as f32).collect();
        let axis = |n: usize| -> Vec<(usize, f32, f32)> {
            (0..n)
                .map(|i| {
                    let g = (i as f64 + 0.5) / cell_px;
                    let k = g.floor();
                    let a = (g - k) as f32;
                    (k as usize, a, 1.0 / ((1.0 - a) * (1.0 - a) + a * a).sqrt())
                })
                .collect()
        };
        Self { width, gw, grid, xs: axis(width), ys: axis(height), between: vec![0.0; gw] }
    }

    /// Row `y` of the field into `out` (length `width`).
    pub(crate) fn row(&mut self, y: usize, out: &mut [f32]) {
        let (j, b, ny) = self.ys[y];
        let gw = self.gw;
        let (r0, r1) = (&self.grid[j * gw..(j + 1) * gw], &self.grid[(j + 1) * gw..(j + 2) * gw]);
        let between = &mut self.between;
        for ((o, v0), v1) in between.iter_mut().zip(r0).zip(r1) {
            *o = (v0 * (1.0 - b) + v1 * b) * ny;
        }
        for (o, &(i, a, nx)) in out[..self.width].iter_mut().zip(&self.xs) {
            *o = (between[i] * (1.0 - a) + between[i + 1] * a) * nx;
        }
    }
}

/// The whole field as an image (tests).
#[cfg(test)]
pub(crate) fn correlated_field(width: usize, height: usize, cell_px: f64, rng: &mut SplitMix64) -> Vec<f32> {
    let mut f = CorrelatedField::new(width, height, cell_px, rng);
    let mut out = vec![0.0f32; width * height];
    for (y, row) in out.chunks_exact_mut(width).enumerate() {
        f.row(y, row);
    }
    out
}

/// The target pixels `[x0, x1) × [y0, y1)` a depth pixel covers, and its depth there.
#[derive(Debug, Clone, Copy, Default)]
struct Rect {
    x0: usize,
    x1: usize,
    y0: usize,
    y1: usize,
    z: f32,
}

/// `v` rounded to the nearest integer (halves up), for a bound of a rectangle on an axis of `n`
/// pixels: clamped to `[-2, n + 2]` first (rounding is monotonic, so no bound changes once it is
/// clamped to `[0, n]`), then shifted by 2^20 so that a truncating cast rounds down (libm's
/// `round` is not inlined on baseline x86-64).
#[inline]
fn round_index(v: f64, n: usize) -> i32 {
    const OFF: f64 = (1u64 << 20) as f64;
    ((v.clamp(-2.0, n as f64 + 2.0) + 0.5 + OFF) as i32) - (1 << 20)
}

/// Widening of each registered pixel's rectangle, pixels (no pinholes from rounding).
const EPS: f64 = 0.02;

/// Registration (step 6) and quantisation (step 7); also the count of pixels with a depth.
fn register(cfg: &StereoDepthConfig, unit: &SensorUnit, z: &[f32], w: usize, h: usize) -> (Vec<f32>, usize) {
    let e = &unit.registration_error;
    let r = Matrix3::new(e[0][0], e[0][1], e[0][2], e[1][0], e[1][1], e[1][2], e[2][0], e[2][1], e[2][2]);
    let k = unit.depth_focal_ratio;
    let [ox, oy] = unit.depth_pp_offset;
    // Depth intrinsic error (x' = k x + o z) then the extrinsic rotation, as one matrix.
    let m = r * Matrix3::new(k, 0.0, ox, 0.0, k, oy, 0.0, 0.0, 1.0);
    let t = Vector3::new(e[0][3], e[1][3], e[2][3]);
    let (kt, ka) = (&unit.colour_true, &unit.colour_assumed);
    // m · (ray direction of continuous image point (u, v)) = u' · col0 + v' · col1 + col2.
    let (c0, c1, c2) = (m.column(0).into_owned(), m.column(1).into_owned(), m.column(2).into_owned());
    // Per column and row of corners, the direction's components (columns apart, so that the
    // corner pass runs on whole rows at a time).
    let col_scale: Vec<f64> = (0..=w).map(|x| (x as f64 - kt.cx) / kt.fx).collect();
    let col_x: Vec<f64> = col_scale.iter().map(|s| c0.x * s).collect();
    let col_y: Vec<f64> = col_scale.iter().map(|s| c0.y * s).collect();
    let col_z: Vec<f64> = col_scale.iter().map(|s| c0.z * s).collect();
    let row_dir: Vec<Vector3<f64>> = (0..=h).map(|y| c1 * ((y as f64 - kt.cy) / kt.fy) + c2).collect();
    let mut out = vec![f32::INFINITY; w * h];
    // Per depth pixel of a row: the projected corners' extent (x and y, low and high), the depth,
    // whether it lands in front of the colour camera, then the target rectangle [x0, x1) × [y0, y1).
    let (mut lo_x, mut hi_x, mut lo_y, mut hi_y) = (vec![0.0f64; w], vec![0.0f64; w], vec![0.0f64; w], vec![0.0f64; w]);
    let mut zq = vec![0.0f32; w];
    let mut hit = vec![false; w];
    let mut rects = vec![Rect::default(); w];
    for y in 0..h {
        let (ra, rb) = (row_dir[y], row_dir[y + 1]);
        // The corners of the whole row first (no branches, so that the divisions pipeline).
        for x in 0..w {
            let zv = z[y * w + x];
            let skip = zv <= 0.0;
            let zv = zv as f64;
            // The pixel's two corners (x, y) and (x + 1, y + 1) at its depth, in the colour frame.
            let (qax, qay, qaz) =
                ((col_x[x] + ra.x) * zv + t.x, (col_y[x] + ra.y) * zv + t.y, (col_z[x] + ra.z) * zv + t.z);
            let (qbx, qby, qbz) =
                ((col_x[x + 1] + rb.x) * zv + t.x, (col_y[x + 1] + rb.y) * zv + t.y, (col_z[x + 1] + rb.z) * zv + t.z);
            let inv = 1.0 / (qaz * qbz);
            let (ia, ib) = (qbz * inv, qaz * inv);
            let (ax, ay) = (ka.fx * qax * ia + ka.cx, ka.fy * qay * ia + ka.cy);
            let (bx, by) = (ka.fx * qbx * ib + ka.cx, ka.fy * qby * ib + ka.cy);
            // Pixel (x, y) spans [x, x + 1) in continuous coordinates; fill the target pixels whose
            // centres the projected corners enclose, a hair wider than the corners so rounding
            // leaves no pinholes between neighbours.
            lo_x[x] = ax.min(bx) - EPS;
            hi_x[x] = ax.max(bx) + EPS;
            lo_y[x] = ay.min(by) - EPS;
            hi_y[x] = ay.max(by) + EPS;
            zq[x] = ((qaz + qbz) * 0.5) as f32;
            hit[x] = !(skip || qaz <= 1e-6 || qbz <= 1e-6);
        }
        for (x, rect) in rects.iter_mut().enumerate() {
            let x1 = round_index(hi_x[x], w).clamp(0, w as i32);
            let x0 = round_index(lo_x[x], w).max(0).min(x1);
            let y0 = round_index(lo_y[x], h).max(0);
            let y1 = round_index(hi_y[x], h).clamp(0, h as i32);
            *rect = if hit[x] {
                Rect { x0: x0 as usize, x1: x1 as usize, y0: y0 as usize, y1: y1 as usize, z: zq[x] }
            } else {
                Rect::default()
            };
        }
        for r in &rects {
            for ty in r.y0..r.y1 {
                for o in &mut out[ty * w + r.x0..ty * w + r.x1] {
                    if r.z < *o {
                        *o = r.z;
                    }
                }
            }
        }
    }
    let q = cfg.unit_m;
    let inv_q = if q > 0.0 { 1.0 / q } else { 0.0 };
    let mut valid = 0usize;
    for v in out.iter_mut() {
        if !v.is_finite() {
            *v = 0.0;
            continue;
        }
        if q > 0.0 {
            *v = ((*v as f64 * inv_q + 0.5) as i64 as f64 * q) as f32;
        }
        valid += usize::from(*v > 0.0);
    }
    (out, valid)
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // tests may unwrap (STYLE.md 18)
mod tests {
    use super::super::Intrinsics;
    use super::*;

    const W: usize = 640;
    const H: usize = 480;

    fn exact_unit(k: Intrinsics) -> SensorUnit {
        let mut e = [[0.0; 4]; 4];
        for (i, row) in e.iter_mut().enumerate() {
            row[i] = 1.0;
        }
        SensorUnit {
            colour_assumed: k,
            colour_true: k,
            depth_scale: 1.0,
            depth_focal_ratio: 1.0,
            depth_pp_offset: [0.0, 0.0],
            registration_error: e,
        }
    }

    fn k() -> Intrinsics {
        Intrinsics { fx: 433.0, fy: 433.0, cx: 320.0, cy: 240.0 }
    }

    /// A fronto-parallel plane at `z_plane`, with an optional box face at `z_box` over columns
    /// `box_cols` and rows 100..380.
    fn scene(z_plane: f32, z_box: Option<(f32, std::ops::Range<usize>)>) -> (Vec<f32>, Vec<f32>) {
        let k = k();
        let mut p = vec![0.0f32; 3 * W * H];
        let mut nrm = vec![0.0f32; 3 * W * H];
        for y in 0..H {
            for x in 0..W {
                let mut zv = z_plane;
                if let Some((zb, cols)) = &z_box {
                    if cols.contains(&x) && (100..380).contains(&y) {
                        zv = *zb;
                    }
                }
                let i = y * W + x;
                p[3 * i] = ((x as f64 + 0.5 - k.cx) / k.fx) as f32 * zv;
                p[3 * i + 1] = ((y as f64 + 0.5 - k.cy) / k.fy) as f32 * zv;
                p[3 * i + 2] = zv;
                nrm[3 * i + 2] = -1.0;
            }
        }
        (p, nrm)
    }

    fn run(cfg: &StereoDepthConfig, p: &[f32], nrm: &[f32], seed: u64, frame: u64) -> (Vec<f32>, DepthStats) {
        let f = RenderedFrame { width: W, height: H, points_in_camera: p, normals_in_camera: nrm, rgb: &[] };
        stereo_depth(cfg, &exact_unit(k()), &f, seed, frame)
    }

    #[test]
    fn plane_rms_follows_closed_form_and_is_correlated() {
        let cfg = StereoDepthConfig { unit_m: 0.0, shadow: false, ..Default::default() };
        for z0 in [0.3f32, 0.5, 0.7, 1.0] {
            let (p, n) = scene(z0, None);
            let mut sq = 0.0;
            let mut count = 0usize;
            let mut lag1 = 0.0;
            let mut lag_n = 0usize;
            for frame in 0..4 {
                let (d, _) = run(&cfg, &p, &n, 11, frame);
                for y in 20..H - 20 {
                    for x in 20..W - 20 {
                        let e = (d[y * W + x] - z0) as f64;
                        sq += e * e;
                        count += 1;
                        let e1 = (d[y * W + x + 1] - z0) as f64;
                        lag1 += e * e1;
                        lag_n += 1;
                    }
                }
            }
            let rms = (sq / count as f64).sqrt();
            let want = cfg.depth_rms_m(z0 as f64);
            assert!((rms / want - 1.0).abs() < 0.1, "z {z0}: rms {rms} vs {want}");
            // Neighbouring pixels are strongly correlated (correlation length > 1 px).
            let rho = (lag1 / lag_n as f64) / (sq / count as f64);
            assert!(rho > 0.6, "lag-1 correlation {rho}");
        }
    }

    #[test]
    fn correlation_decays_over_the_cell() {
        let mut rng = SplitMix64::new(5, &[1]);
        let f = correlated_field(W, H, 8.0, &mut rng);
        let corr = |lag: usize| {
            let (mut s, mut s0) = (0.0f64, 0.0f64);
            for y in 0..H {
                for x in 0..W - lag {
                    s += (f[y * W + x] * f[y * W + x + lag]) as f64;
                    s0 += (f[y * W + x] * f[y * W + x]) as f64;
                }
            }
            s / s0
        };
        assert!(corr(1) > 0.9);
        assert!(corr(4) > 0.3 && corr(4) < 0.8, "{}", corr(4));
        assert!(corr(24).abs() < 0.1, "{}", corr(24));
    }

    #[test]
    fn shadow_beside_a_step_edge() {
        let cfg = StereoDepthConfig { mixed_band_px: 0, subpixel_rms_px: 0.0, ..Default::default() };
        // A box face at 0.4 m in front of a plane at 0.6 m, columns 250..400.
        let (p, n) = scene(0.6, Some((0.4, 250..400)));
        let (d, stats) = run(&cfg, &p, &n, 1, 0);
        // Hidden from the right imager (at +x): the background just left of the box, over
        // f·B·(1/z_near − 1/z_far) = 433 · 0.05 · (2.5 − 1.667) = 18 px.
        let width = 433.0 * 0.05 * (1.0 / 0.4 - 1.0 / 0.6);
        let y = 240;
        let invalid: Vec<usize> = (200..250).filter(|&x| d[y * W + x] == 0.0).collect();
        assert!((invalid.len() as f64 - width).abs() <= 1.5, "{} vs {width}", invalid.len());
        assert!(invalid.iter().all(|&x| x >= 230), "shadow sits next to the box: {invalid:?}");
        // Right of the box nothing is hidden.
        assert!((400..450).all(|x| d[y * W + x] > 0.0));
        assert!(stats.shadow > 0);
    }

    #[test]
    fn mixed_pixels_only_at_silhouettes() {
        let cfg = StereoDepthConfig { subpixel_rms_px: 0.0, shadow: false, mixed_fraction: 1.0, ..Default::default() };
        let (p, n) = scene(0.6, Some((0.4, 250..400)));
        let (d, stats) = run(&cfg, &p, &n, 1, 0);
        let y = 240;
        // Mixed values lie between the two surfaces, only within one pixel of the edge.
        for x in 0..W {
            let v = d[y * W + x];
            let near_edge = (248..=251).contains(&x) || (398..=401).contains(&x);
            if !near_edge {
                assert!((v - 0.6).abs() < 1e-3 || (v - 0.4).abs() < 1e-3, "x {x}: {v}");
            } else {
                assert!((0.399..=0.601).contains(&v), "x {x}: {v}");
            }
        }
        assert!(stats.mixed > 0);
    }

    #[test]
    fn range_limits() {
        let cfg = StereoDepthConfig::default();
        let (p, n) = scene(0.12, None);
        let (d, stats) = run(&cfg, &p, &n, 1, 0);
        assert!(d.iter().all(|v| *v == 0.0));
        assert_eq!(stats.out_of_range, W * H);
        let (p, n) = scene(3.5, None);
        assert!(run(&cfg, &p, &n, 1, 0).0.iter().all(|v| *v == 0.0));
        let (p, n) = scene(0.16, None);
        let (d, _) = run(&cfg, &p, &n, 1, 0);
        assert!(d.iter().filter(|v| **v > 0.0).count() > W * H * 99 / 100);
    }

    #[test]
    fn grazing_surfaces_drop_out() {
        let cfg = StereoDepthConfig::default();
        let (p, mut n) = scene(0.5, None);
        // Every normal at 88 degrees from its pixel's viewing ray.
        let (c88, s88) = ((88f64).to_radians().cos(), (88f64).to_radians().sin());
        for i in 0..W * H {
            let r = Vector3::new(p[3 * i] as f64, p[3 * i + 1] as f64, p[3 * i + 2] as f64).normalize();
            let u = r.cross(&Vector3::y()).normalize();
            let nv = r * c88 + u * s88;
            for a in 0..3 {
                n[3 * i + a] = nv[a] as f32;
            }
        }
        let (d, stats) = run(&cfg, &p, &n, 1, 0);
        let c = 240 * W + 320;
        assert_eq!(d[c], 0.0);
        assert_eq!(stats.grazing, W * H);
    }

    #[test]
    fn registration_error_shifts_depth_by_the_projected_offset() {
        let cfg = StereoDepthConfig { subpixel_rms_px: 0.0, shadow: false, mixed_band_px: 0, ..Default::default() };
        let (p, n) = scene(0.6, Some((0.4, 250..400)));
        let mut unit = exact_unit(k());
        unit.registration_error[0][3] = 0.004; // 4 mm along x
        let f = RenderedFrame { width: W, height: H, points_in_camera: &p, normals_in_camera: &n, rgb: &[] };
        let (d, _) = stereo_depth(&cfg, &unit, &f, 1, 0);
        // The box's right edge moves by f · t / z = 433 · 0.004 / 0.4 = 4.3 px.
        let y = 240;
        let edge = (300..W).find(|&x| (d[y * W + x] - 0.4).abs() > 0.01).unwrap();
        assert!((edge as i64 - 404).abs() <= 1, "edge at {edge}");
    }

    #[test]
    fn deterministic_per_seed_and_frame() {
        let cfg = StereoDepthConfig::default();
        let (p, n) = scene(0.5, Some((0.3, 200..300)));
        assert_eq!(run(&cfg, &p, &n, 4, 2).0, run(&cfg, &p, &n, 4, 2).0);
        assert_ne!(run(&cfg, &p, &n, 4, 2).0, run(&cfg, &p, &n, 4, 3).0);
    }
}
