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
//!    unit-variance field interpolated bilinearly from independent standard normals on a grid of
//!    [`StereoDepthConfig::correlation_px`] depth pixels, normalised per pixel; the normals are
//!    the normal quantiles of 12-bit uniforms, tails cut at ±3.5 σ); to first order the
//!    depth RMS is `z² · s / (f · B)` (Intel's tuning white paper), 1.04 mm at 0.5 m with the
//!    defaults. Then the unit's **depth-scale** error multiplies every value.
//! 6. **Registration**: each depth pixel's two corners go through the depth intrinsic error and
//!    the colour ← depth extrinsic error and are projected with the *assumed* colour intrinsics;
//!    the rectangle between them is filled, nearest surface kept (librealsense's align-to-colour).
//!    Colour pixels no depth pixel reaches stay 0.
//! 7. **Quantisation** to [`StereoDepthConfig::unit_m`] (the 16-bit depth unit, 1 mm by default).
//!
//! The random draws of steps 3 and 4 come from a stream per row of `(seed, frame index)`, so rows
//! can be computed in any order, by any thread, with the same result.
//!
//! Not modelled: depth motion blur (the D435's depth imagers have a global shutter and short
//! exposure), the invalid band at the depth image's left border (the depth field of view is wider
//! than the colour's and the band falls outside the registered image), temporal noise
//! correlation, multipath and specular surfaces.

use super::{check, max_f, min_f, to_i32, Hits, RenderedFrame, SensorError, SensorUnit, SplitMix64, TAG_DEPTH};
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

impl DepthStats {
    /// The counts of two parts of a frame together.
    pub(crate) fn plus(&self, o: &Self) -> Self {
        Self {
            surface: self.surface + o.surface,
            out_of_range: self.out_of_range + o.out_of_range,
            shadow: self.shadow + o.shadow,
            grazing: self.grazing + o.grazing,
            mixed: self.mixed + o.mixed,
            valid_out: self.valid_out + o.valid_out,
        }
    }
}

/// Invalid-pixel causes on the rendered grid.
const OK: u8 = 0;
const NONE: u8 = 1;
const RANGE: u8 = 2;
const SHADOW: u8 = 3;
const GRAZING: u8 = 4;

/// Sub-streams of a frame's depth draws: one per effect and, for the per-pixel draws, one per row
/// (so that no pass depends on another's draw count).
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
    let n = frame.width * frame.height;
    let job = DepthFrame::new(cfg, unit, frame, seed, frame_index);
    let (mut z, mut state) = (vec![0.0f32; n], vec![OK; n]);
    let mut stats = job.surfaces(0, &mut z, &mut state);
    let mut out = vec![f32::INFINITY; n];
    (stats.mixed, _) = job.register(0..frame.height, &z, &state, &mut out);
    stats.valid_out = job.finish(&mut out);
    (out, stats)
}

/// The depth model of one frame in parts that can run on separate rows, in any order, with the
/// same result: steps 1-3 on rows ([`Self::surfaces`]), then, once the rows a row reads have
/// them, steps 4-7 on rows into a z-buffer ([`Self::register`]; z-buffers of separate rows merge
/// by their minimum), then the depth image ([`Self::finish`]).
pub(crate) struct DepthFrame<'a> {
    cfg: &'a StereoDepthConfig,
    unit: &'a SensorUnit,
    frame: &'a RenderedFrame<'a>,
    geometry: Geometry<'a>,
    seed: u64,
    frame_index: u64,
    surfaces: Surfaces,
    field: CorrelatedField,
}

impl<'a> DepthFrame<'a> {
    pub(crate) fn new(
        cfg: &'a StereoDepthConfig,
        unit: &'a SensorUnit,
        frame: &'a RenderedFrame<'a>,
        seed: u64,
        frame_index: u64,
    ) -> Self {
        let cell = (cfg.correlation_px * unit.colour_true.fx / cfg.focal_px).max(1.0);
        let mut rng = SplitMix64::new(seed, &[TAG_DEPTH, frame_index, SUB_FIELD]);
        Self {
            cfg,
            unit,
            frame,
            geometry: Geometry::OpenCv { points: frame.points_in_camera, normals: frame.normals_in_camera },
            seed,
            frame_index,
            surfaces: Surfaces::new(cfg, unit, seed, frame_index),
            field: CorrelatedField::new(frame.width, frame.height, cell, &mut rng),
        }
    }

    /// The frame's geometry read from the renderer's own buffers instead of its points and
    /// normals ([`super::RendererBuffers`]' position and normal, `4 · w · h` each, and which
    /// pixels hit): the same result as from the buffers converted by
    /// [`super::RendererBuffers::convert_into`].
    pub(crate) fn on_renderer_buffers(self, position: &'a [f32], normal: &'a [f32], hits: Hits<'a>) -> Self {
        Self { geometry: Geometry::Renderer { position, normal, hits }, ..self }
    }

    /// Steps 1-3 on rows `y0..` (as many as `z` holds): the true depth (0 without a surface) and
    /// each pixel's state; the counts.
    pub(crate) fn surfaces(&self, y0: usize, z: &mut [f32], state: &mut [u8]) -> DepthStats {
        let w = self.frame.width;
        let mut stats = DepthStats::default();
        let mut scratch = vec![0.0f32; w];
        for (y, (zr, sr)) in (y0..).zip(z.chunks_exact_mut(w.max(1)).zip(state.chunks_exact_mut(w.max(1)))) {
            let row = match self.geometry {
                Geometry::OpenCv { points, normals } => {
                    let span = 3 * y * w..3 * (y + 1) * w;
                    self.surfaces.row::<3>(y, &points[span.clone()], &normals[span], None, zr, sr, &mut scratch)
                }
                Geometry::Renderer { position, normal, hits } => {
                    let span = 4 * y * w..4 * (y + 1) * w;
                    let hits = Some((hits, y * w));
                    self.surfaces.row::<4>(y, &position[span.clone()], &normal[span], hits, zr, sr, &mut scratch)
                }
            };
            stats = stats.plus(&row);
        }
        stats
    }

    /// Steps 4-6 on `rows`, from the true depth `z` and `state` (whole images; `z` read on `rows`
    /// and the mixed band's rows around them, `state` on `rows`), into the z-buffer `zbuf` (the
    /// whole image, +inf = nothing yet); returns the count of mixed depths and the rows of `zbuf`
    /// written.
    pub(crate) fn register(
        &self,
        rows: std::ops::Range<usize>,
        z: &[f32],
        state: &[u8],
        zbuf: &mut [f32],
    ) -> (usize, std::ops::Range<usize>) {
        let (cfg, w) = (self.cfg, self.frame.width);
        let mut silhouettes = Silhouettes::new(cfg, w);
        let mut registration = Registration::new(self.unit, cfg.unit_m, w, self.frame.height);
        let (mut row, mut noise, mut between) = (vec![0.0f32; w], vec![0.0f32; w], vec![0.0f32; self.field.gw]);
        let k_noise = (cfg.subpixel_rms_px / (cfg.focal_px * cfg.baseline_m)) as f32;
        let scale = self.unit.depth_scale as f32;
        let mut mixed = 0;
        for y in rows {
            let sr = &state[y * w..(y + 1) * w];
            row.copy_from_slice(&z[y * w..(y + 1) * w]);
            mixed += silhouettes.row(z, sr, y, &mut row, self.seed, self.frame_index);
            // 5. z' = f·B / (f·B / z + s·e) · scale = z · scale / (1 + s·e·z / (f·B)).
            self.field.row(y, &mut between, &mut noise);
            for ((zv, &st), &e) in row.iter_mut().zip(sr).zip(&noise) {
                let den = 1.0 + k_noise * e * *zv;
                *zv = if st == OK && den > 0.0 { *zv * scale / den } else { 0.0 };
            }
            registration.row(y, &row, zbuf);
        }
        (mixed, registration.touched.clone())
    }

    /// The z-buffer (of quantised depths, step 7 done in [`Self::register`]) as the depth image
    /// (0 = no return); returns the count with a depth.
    pub(crate) fn finish(&self, zbuf: &mut [f32]) -> usize {
        let mut valid = 0u32;
        for v in zbuf.iter_mut() {
            let d = if *v < f32::INFINITY { *v } else { 0.0 };
            valid += u32::from(d > 0.0);
            *v = d;
        }
        valid as usize
    }
}

/// Where the depth model reads a frame's surface points and normals.
#[derive(Clone, Copy)]
enum Geometry<'a> {
    /// [`RenderedFrame`]'s: three floats a pixel, OpenCV axes, z <= 0 = no surface.
    OpenCv { points: &'a [f32], normals: &'a [f32] },
    /// The renderer's: four floats a pixel, OpenGL axes (y and z negated), no surface where
    /// `w >= 1` or a dropped segmentation id ([`Hits`]). The products and squares the model takes of a point and its normal are the
    /// same in either axes (each negation meets another), so only the depth reads the axis.
    Renderer { position: &'a [f32], normal: &'a [f32], hits: Hits<'a> },
}

/// Steps 1-3 (range, the second imager's shadow, grazing incidence) on one row of the rendered
/// grid: the true depth (0 without a surface) and each pixel's state.
struct Surfaces {
    min_z: f32,
    max_z: f32,
    shadow: bool,
    /// f·B of the rendered grid (true colour focal length), pixels × metres.
    fb: f32,
    /// Cosines of incidence where dropouts start and where every return drops out.
    cos_start: f64,
    cos_end: f64,
    seed: u64,
    frame_index: u64,
}

impl Surfaces {
    fn new(cfg: &StereoDepthConfig, unit: &SensorUnit, seed: u64, frame_index: u64) -> Self {
        Self {
            min_z: cfg.min_range_m as f32,
            max_z: cfg.max_range_m as f32,
            shadow: cfg.shadow,
            fb: (unit.colour_true.fx * cfg.baseline_m) as f32,
            cos_start: cfg.grazing_start_deg.to_radians().cos(),
            cos_end: cfg.grazing_end_deg.to_radians().cos(),
            seed,
            frame_index,
        }
    }

    /// Row `y`: `pts`, `nrm` its rendered points and normals, `S` floats a pixel ([`Geometry`]:
    /// 3 OpenCV, 4 the renderer's, with which pixels hit and the row's first pixel index);
    /// `scratch` (length of the row) is overwritten.
    #[allow(clippy::too_many_arguments)]
    fn row<const S: usize>(
        &self,
        y: usize,
        pts: &[f32],
        nrm: &[f32],
        hits: Option<(Hits<'_>, usize)>,
        z: &mut [f32],
        state: &mut [u8],
        scratch: &mut [f32],
    ) -> DepthStats {
        let mut stats = DepthStats::default();
        let (mut surface, mut out) = (0u32, 0u32);
        // The depths contiguous first, then the states without branches (several pixels at a time).
        match hits {
            None => {
                for (zv, p) in z.iter_mut().zip(pts.chunks_exact(S)) {
                    *zv = p[2];
                }
            }
            Some((hits, i0)) => {
                for (i, (zv, p)) in z.iter_mut().zip(pts.chunks_exact(S)).enumerate() {
                    *zv = if hits.hit(i0 + i, p) { -p[2] } else { 0.0 };
                }
            }
        }
        for (zv, st) in z.iter_mut().zip(state.iter_mut()) {
            let v = *zv;
            let is_surface = (v > 0.0) & (v < f32::INFINITY);
            let is_out = is_surface & ((v < self.min_z) | (v > self.max_z));
            *zv = if is_surface { v } else { 0.0 };
            *st = u8::from(!is_surface) * NONE + u8::from(is_out) * RANGE;
            surface += u32::from(is_surface);
            out += u32::from(is_out);
        }
        stats.surface = surface as usize;
        stats.out_of_range = out as usize;
        if self.shadow {
            // Right-image coordinate u − f·B/z (the whole row first, so that it runs on several
            // pixels at a time), scanned from the right: a pixel whose coordinate lies beyond the
            // least one to its right is hidden from the right imager.
            for (x, (r, &zv)) in scratch.iter_mut().zip(z.iter()).enumerate() {
                *r = x as i32 as f32 - self.fb / zv;
            }
            // `bound` is the least coordinate plus the 1e-3 px tolerance (added as each coordinate
            // is taken, off the scan's dependency chain).
            let (mut bound, mut shadow) = (f32::INFINITY, 0u32);
            for (st, &r) in state.iter_mut().zip(scratch.iter()).rev() {
                let seen = *st != NONE;
                let hidden = seen & (r > bound);
                bound = if seen & !hidden { r + 1e-3 } else { bound };
                let shadowed = hidden & (*st == OK);
                *st = if shadowed { SHADOW } else { *st };
                shadow += u32::from(shadowed);
            }
            stats.shadow = shadow as usize;
        }
        // Grazing: cos² = (p·n)² / (|p|² |n|²) below cos²(start) makes a pixel a candidate; the
        // square root and the draw only there.
        let c0_sq = (self.cos_start * self.cos_start) as f32;
        let mut candidates = 0u32;
        for ((c, &st), (p, n)) in scratch.iter_mut().zip(state.iter()).zip(pts.chunks_exact(S).zip(nrm.chunks_exact(S)))
        {
            let dot = p[0] * n[0] + p[1] * n[1] + p[2] * n[2];
            let denom = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]) * (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
            let is = st == OK && denom > 0.0 && denom < f32::INFINITY && dot * dot < c0_sq * denom;
            *c = if is { dot * dot / denom } else { -1.0 };
            candidates += u32::from(is);
        }
        if candidates == 0 {
            return stats;
        }
        let mut rng = SplitMix64::new(self.seed, &[TAG_DEPTH, self.frame_index, SUB_GRAZING, y as u64]);
        for (st, &c_sq) in state.iter_mut().zip(scratch.iter()) {
            if c_sq >= 0.0 {
                let p_drop =
                    ((self.cos_start - (c_sq as f64).sqrt()) / (self.cos_start - self.cos_end)).clamp(0.0, 1.0);
                if rng.uniform() < p_drop {
                    *st = GRAZING;
                    stats.grazing += 1;
                }
            }
        }
        stats
    }
}

/// Step 4 (mixed depths at silhouettes) a row at a time, from the true depths of the
/// neighbourhood: min / max of the valid depths over the (2 band + 1)² window, down the columns
/// and then along the row.
struct Silhouettes {
    band: usize,
    fraction: f64,
    jump_m: f32,
    jump_rel: f32,
    /// Scratch: per column the extrema down the window, padded by `band` at both ends.
    col_lo: Vec<f32>,
    col_hi: Vec<f32>,
    lo: Vec<f32>,
    hi: Vec<f32>,
}

impl Silhouettes {
    fn new(cfg: &StereoDepthConfig, w: usize) -> Self {
        let band = if cfg.mixed_fraction > 0.0 { cfg.mixed_band_px } else { 0 };
        Self {
            band,
            fraction: cfg.mixed_fraction,
            jump_m: cfg.edge_jump_m as f32,
            jump_rel: cfg.edge_jump_rel as f32,
            col_lo: vec![f32::INFINITY; w + 2 * band],
            col_hi: vec![0.0; w + 2 * band],
            lo: vec![0.0; w],
            hi: vec![0.0; w],
        }
    }

    /// Mixes row `y` of `row` (a copy of row `y` of the true depths `z`); returns the count.
    fn row(&mut self, z: &[f32], state: &[u8], y: usize, row: &mut [f32], seed: u64, frame_index: u64) -> usize {
        let (band, w) = (self.band, row.len());
        if band == 0 || w == 0 {
            return 0;
        }
        let h = z.len() / w;
        let (y0, y1) = (y.saturating_sub(band), (y + band + 1).min(h));
        // Invalid depths (0) never win a maximum; for the minimum they count as +inf.
        let (col_lo, col_hi) = (&mut self.col_lo[band..band + w], &mut self.col_hi[band..band + w]);
        let first = &z[y0 * w..(y0 + 1) * w];
        for ((lo, hi), &v) in col_lo.iter_mut().zip(col_hi.iter_mut()).zip(first) {
            *lo = if v > 0.0 { v } else { f32::INFINITY };
            *hi = v;
        }
        for yy in y0 + 1..y1 {
            for ((lo, hi), &v) in col_lo.iter_mut().zip(col_hi.iter_mut()).zip(&z[yy * w..(yy + 1) * w]) {
                *lo = min_f(if v > 0.0 { v } else { f32::INFINITY }, *lo);
                *hi = max_f(v, *hi);
            }
        }
        if band == 1 {
            // The default band: the three columns in one pass.
            let (cl, ch) = (&self.col_lo[..w + 2], &self.col_hi[..w + 2]);
            let windows = cl.windows(3).zip(ch.windows(3));
            for ((lo, hi), (l, u)) in self.lo.iter_mut().zip(self.hi.iter_mut()).zip(windows) {
                *lo = min_f(min_f(l[0], l[1]), l[2]);
                *hi = max_f(max_f(u[0], u[1]), u[2]);
            }
        } else {
            self.lo.copy_from_slice(&self.col_lo[..w]);
            self.hi.copy_from_slice(&self.col_hi[..w]);
            for k in 1..=2 * band {
                let (cl, ch) = (&self.col_lo[k..k + w], &self.col_hi[k..k + w]);
                for ((lo, hi), (&l, &u)) in self.lo.iter_mut().zip(self.hi.iter_mut()).zip(cl.iter().zip(ch)) {
                    *lo = min_f(l, *lo);
                    *hi = max_f(u, *hi);
                }
            }
        }
        let (jump_m, jump_rel) = (self.jump_m, self.jump_rel);
        let is_edge = |st: u8, l: f32, u: f32| st == OK && u - l > jump_m + jump_rel * l;
        // Counted without branches (several pixels at a time): most rows have no silhouette.
        let edges: u32 =
            state.iter().zip(self.lo.iter().zip(&self.hi)).map(|(&st, (&l, &u))| u32::from(is_edge(st, l, u))).sum();
        if edges == 0 {
            return 0;
        }
        let mut rng = SplitMix64::new(seed, &[TAG_DEPTH, frame_index, SUB_MIXED, y as u64]);
        let mut mixed = 0;
        for ((zv, &st), (&l, &u)) in row.iter_mut().zip(state).zip(self.lo.iter().zip(&self.hi)) {
            if is_edge(st, l, u) && rng.uniform() < self.fraction {
                *zv = l + (rng.uniform() as f32) * (u - l);
                mixed += 1;
            }
        }
        mixed
    }
}

/// A unit-variance, spatially correlated field: independent standard normals on a grid of
/// spacing `cell_px` pixels, interpolated bilinearly and divided by the interpolation's standard
/// deviation at each pixel (so every pixel has variance 1). Evaluated a row at a time.
pub(crate) struct CorrelatedField {
    width: usize,
    gw: usize,
    grid: Vec<f32>,
    /// Per column: grid column, and the weights of it and the next one (normalisation included).
    xs: Vec<(usize, f32, f32)>,
    /// Per row: grid row, interpolation weight, normalisation.
    ys: Vec<(usize, f32, f32)>,
}

impl CorrelatedField {
    pub(crate) fn new(width: usize, height: usize, cell_px: f64, rng: &mut SplitMix64) -> Self {
        let gw = (width as f64 / cell_px).ceil() as usize + 2;
        let gh = (height as f64 / cell_px).ceil() as usize + 2;
        let mut grid = vec![0.0f32; gw * gh];
        rng.fill_normal(&mut grid);
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
        let xs = axis(width).into_iter().map(|(i, a, nx)| (i, (1.0 - a) * nx, a * nx)).collect();
        Self { width, gw, grid, xs, ys: axis(height) }
    }

    /// Row `y` of the field into `out` (length `width`); `between` (length `gw`) is scratch for
    /// the row interpolated between its two grid rows.
    pub(crate) fn row(&self, y: usize, between: &mut [f32], out: &mut [f32]) {
        let (j, b, ny) = self.ys[y];
        let gw = self.gw;
        let (r0, r1) = (&self.grid[j * gw..(j + 1) * gw], &self.grid[(j + 1) * gw..(j + 2) * gw]);
        let (w0, w1) = ((1.0 - b) * ny, b * ny);
        for ((o, v0), v1) in between.iter_mut().zip(r0).zip(r1) {
            *o = v0 * w0 + v1 * w1;
        }
        for (o, &(i, wa, wb)) in out[..self.width].iter_mut().zip(&self.xs) {
            *o = between[i] * wa + between[i + 1] * wb;
        }
    }
}

/// The whole field as an image (tests).
#[cfg(test)]
pub(crate) fn correlated_field(width: usize, height: usize, cell_px: f64, rng: &mut SplitMix64) -> Vec<f32> {
    let f = CorrelatedField::new(width, height, cell_px, rng);
    let mut between = vec![0.0f32; f.gw];
    let mut out = vec![0.0f32; width * height];
    for (y, row) in out.chunks_exact_mut(width).enumerate() {
        f.row(y, &mut between, row);
    }
    out
}

/// Adding this to an `f64` below 2^51 rounds it to an integer (halves to even).
const ROUND_F64: f64 = 6_755_399_441_055_744.0; // 1.5 · 2^52

/// Widening of each registered pixel's rectangle, pixels (no pinholes from rounding).
const EPS: f32 = 0.02;

/// `v` clamped to `[0, n]` and rounded to the nearest integer, for a bound of a rectangle on an
/// axis of `n` pixels (NaN gives 0); float and integer operations only, so that a row of them
/// vectorises.
#[inline]
fn round_index(v: f32, n: f32) -> i32 {
    to_i32(min_f(max_f(v, 0.0), n))
}

/// Steps 6 (registration) and 7 (quantisation): each depth pixel's two corners go through the
/// depth intrinsic error and the colour ← depth extrinsic error, are projected with the assumed
/// colour intrinsics, and the target rectangle between them keeps the nearest depth, quantised to
/// `unit_m` first (the same as quantising the nearest depth).
struct Registration {
    w: usize,
    h: usize,
    /// Per corner column `x` (0..=w): the direction's components `m · (x − cx) / fx · e_x`.
    col: [Vec<f32>; 3],
    /// Per corner row `y` (0..=h): `m · ((y − cy) / fy · e_y + e_z)`.
    row_dir: Vec<[f32; 3]>,
    t: [f32; 3],
    /// Assumed colour intrinsics fx, fy, cx, cy.
    k: [f32; 4],
    /// Depth unit, metres, and its inverse (0 = no quantisation).
    unit_m: f64,
    inv_unit: f64,
    /// Scratch per depth pixel of a row: the projected corners' extent, the depth, then the
    /// target rectangle `[x0, x1) × [y0, y1)`.
    lo_x: Vec<f32>,
    hi_x: Vec<f32>,
    lo_y: Vec<f32>,
    hi_y: Vec<f32>,
    zq: Vec<f32>,
    rect: [Vec<i32>; 4],
    /// The target rows written so far (empty: none).
    touched: std::ops::Range<usize>,
}

impl Registration {
    fn new(unit: &SensorUnit, unit_m: f64, w: usize, h: usize) -> Self {
        let e = &unit.registration_error;
        let r = Matrix3::new(e[0][0], e[0][1], e[0][2], e[1][0], e[1][1], e[1][2], e[2][0], e[2][1], e[2][2]);
        let s = unit.depth_focal_ratio;
        let [ox, oy] = unit.depth_pp_offset;
        // Depth intrinsic error (x' = s x + o z) then the extrinsic rotation, as one matrix.
        let m = r * Matrix3::new(s, 0.0, ox, 0.0, s, oy, 0.0, 0.0, 1.0);
        let t = Vector3::new(e[0][3], e[1][3], e[2][3]);
        let (kt, ka) = (&unit.colour_true, &unit.colour_assumed);
        let col_scale: Vec<f64> = (0..=w).map(|x| (x as f64 - kt.cx) / kt.fx).collect();
        let col = [0, 1, 2].map(|a| col_scale.iter().map(|s| (m[(a, 0)] * s) as f32).collect());
        let row_dir = (0..=h)
            .map(|y| {
                let v = m.column(1) * ((y as f64 - kt.cy) / kt.fy) + m.column(2);
                [v.x as f32, v.y as f32, v.z as f32]
            })
            .collect();
        Self {
            w,
            h,
            col,
            row_dir,
            t: [t.x as f32, t.y as f32, t.z as f32],
            k: [ka.fx as f32, ka.fy as f32, ka.cx as f32, ka.cy as f32],
            unit_m,
            inv_unit: if unit_m > 0.0 { 1.0 / unit_m } else { 0.0 },
            lo_x: vec![0.0; w],
            hi_x: vec![0.0; w],
            lo_y: vec![0.0; w],
            hi_y: vec![0.0; w],
            zq: vec![0.0; w],
            rect: [0, 1, 2, 3].map(|_| vec![0; w]),
            touched: 0..0,
        }
    }

    /// Registers depth row `y` (metres, 0 = none) into the z-buffer `out`.
    fn row(&mut self, y: usize, z: &[f32], out: &mut [f32]) {
        let w = self.w;
        let (ra, rb) = (self.row_dir[y], self.row_dir[y + 1]);
        let [fx, fy, cx, cy] = self.k;
        let [tx, ty, tz] = self.t;
        let (q, inv_q) = (self.unit_m, self.inv_unit);
        let z = &z[..w];
        let (ca_x, ca_y, ca_z) = (&self.col[0][..w], &self.col[1][..w], &self.col[2][..w]);
        let (cb_x, cb_y, cb_z) = (&self.col[0][1..=w], &self.col[1][1..=w], &self.col[2][1..=w]);
        let (lo_x, hi_x, lo_y, hi_y, zq) =
            (&mut self.lo_x[..w], &mut self.hi_x[..w], &mut self.lo_y[..w], &mut self.hi_y[..w], &mut self.zq[..w]);
        // The corners of the whole row first (no branches, so that it runs on several pixels at a
        // time), then the rectangles, then the z-buffer.
        for x in 0..w {
            let zv = z[x];
            // The pixel's two corners (x, y) and (x + 1, y + 1) at its depth, in the colour frame.
            let (qax, qay, qaz) =
                ((ca_x[x] + ra[0]) * zv + tx, (ca_y[x] + ra[1]) * zv + ty, (ca_z[x] + ra[2]) * zv + tz);
            let (qbx, qby, qbz) =
                ((cb_x[x] + rb[0]) * zv + tx, (cb_y[x] + rb[1]) * zv + ty, (cb_z[x] + rb[2]) * zv + tz);
            let inv = 1.0 / (qaz * qbz);
            let (ia, ib) = (qbz * inv, qaz * inv);
            let (ax, ay) = (fx * qax * ia + cx, fy * qay * ia + cy);
            let (bx, by) = (fx * qbx * ib + cx, fy * qby * ib + cy);
            // Pixel (x, y) spans [x, x + 1) in continuous coordinates; the target pixels are those
            // whose centres the projected corners enclose, a hair wider than the corners so that
            // rounding leaves no pinholes between neighbours.
            lo_x[x] = min_f(ax, bx) - EPS;
            hi_x[x] = max_f(ax, bx) + EPS;
            lo_y[x] = min_f(ay, by) - EPS;
            hi_y[x] = max_f(ay, by) + EPS;
            // No depth, or behind the colour camera: +inf never enters the z-buffer.
            let hit = (zv > 0.0) & (qaz > 1e-6) & (qbz > 1e-6);
            // Step 7 here: the nearest quantised depth is the nearest depth quantised.
            let m = ((qaz + qbz) * 0.5) as f64;
            let quantised = if q > 0.0 { (((m * inv_q + ROUND_F64) - ROUND_F64) * q) as f32 } else { m as f32 };
            zq[x] = if hit { quantised } else { f32::INFINITY };
        }
        let (wf, hf) = (w as f32, self.h as f32);
        // Each bound in an array of its own (so that the rounding runs on several at a time).
        let [rx0, rx1, ry0, ry1] = &mut self.rect;
        let (rx0, rx1, ry0, ry1) = (&mut rx0[..w], &mut rx1[..w], &mut ry0[..w], &mut ry1[..w]);
        for x in 0..w {
            let (lx, hx, ly, hy) = (lo_x[x], hi_x[x], lo_y[x], hi_y[x]);
            (rx0[x], rx1[x], ry0[x], ry1[x]) =
                (round_index(min_f(lx, hx), wf), round_index(hx, wf), round_index(ly, hf), round_index(hy, hf));
        }
        let (mut lo, mut hi) = (i32::MAX, 0);
        let last = out.len().saturating_sub(1);
        for (((&x0, &x1), (&y0, &y1)), &zv) in rx0.iter().zip(&*rx1).zip(ry0.iter().zip(&*ry1)).zip(&*zq) {
            if x1 > x0 && zv < f32::INFINITY {
                (lo, hi) = (lo.min(y0), hi.max(y1));
            }
            let (nx, ny) = (x1 - x0, y1 - y0);
            if (nx == 1) & (ny == 1) {
                // One target pixel (nearly every pixel: the depth and colour grids have nearly
                // the same scale and the rectangles are a hair wider than a pixel).
                let o = &mut out[y0 as usize * w + x0 as usize];
                *o = min_f(zv, *o);
                continue;
            }
            if nx <= 2 && ny <= 2 {
                // At most 2 × 2 target pixels: the four written without branches, +inf outside the
                // rectangle (an index past the image is held at its last pixel).
                let base = y0 as usize * w + x0 as usize;
                for (dy, dx) in [(0, 0), (0, 1), (1, 0), (1, 1)] {
                    let v = if dx < nx && dy < ny { zv } else { f32::INFINITY };
                    let o = &mut out[(base + dy as usize * w + dx as usize).min(last)];
                    *o = min_f(v, *o);
                }
                continue;
            }
            for ty in y0 as usize..y1 as usize {
                for o in &mut out[ty * w + x0 as usize..ty * w + x1 as usize] {
                    *o = min_f(zv, *o);
                }
            }
        }
        if lo < hi {
            let (lo, hi) = (lo as usize, hi as usize);
            self.touched =
                if self.touched.is_empty() { lo..hi } else { self.touched.start.min(lo)..self.touched.end.max(hi) };
        }
    }
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
        // The default band of one pixel and a wider one.
        for band in [1usize, 2] {
            let cfg = StereoDepthConfig {
                subpixel_rms_px: 0.0,
                shadow: false,
                mixed_fraction: 1.0,
                mixed_band_px: band,
                ..Default::default()
            };
            let (p, n) = scene(0.6, Some((0.4, 250..400)));
            let (d, stats) = run(&cfg, &p, &n, 1, 0);
            let y = 240;
            // Mixed values lie between the two surfaces, only within the band of the edge.
            for x in 0..W {
                let v = d[y * W + x];
                let near_edge = (249 - band..=250 + band).contains(&x) || (399 - band..=400 + band).contains(&x);
                if !near_edge {
                    assert!((v - 0.6).abs() < 1e-3 || (v - 0.4).abs() < 1e-3, "band {band} x {x}: {v}");
                } else {
                    assert!((0.399..=0.601).contains(&v), "band {band} x {x}: {v}");
                }
            }
            assert!(stats.mixed > 0);
        }
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
