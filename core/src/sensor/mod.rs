//! RGB-D sensor model: what an active-stereo RGB-D camera of the Intel RealSense D435 class makes
//! of a rendered frame.
//!
//! This is a *sensor model*, not an estimator: it needs the renderer's geometry (the camera-frame
//! point and surface normal of every pixel of the colour camera) and turns it into the depth image
//! and colour image the robot would receive. It never sees object labels or ids; the renderer's
//! segmentation is not an input at all (silhouettes are found from the geometry's depth jumps).
//!
//! Entry points:
//! - [`SensorUnit::draw`]: the per-episode calibration state of one camera unit (depth-scale
//!   error, colour ↔ depth extrinsic error, true colour and depth intrinsics vs the nominal ones the
//!   estimator assumes), seeded.
//! - [`simulate_frame`]: one frame: [`depth::stereo_depth`] (disparity noise, silhouettes, shadow,
//!   grazing dropouts, range, registration to the colour image by the *assumed* calibration) and
//!   [`colour::colour_image`] (motion blur over the exposure, shot + read noise), each frame seeded
//!   by `(seed, frame index)` so results do not depend on call order.
//!
//! Published figures the defaults use (each config field's doc says which):
//! - Intel, *RealSense D400 Series Product Family Datasheet*: baseline 50 mm (D435), depth field of
//!   view about 87° × 58°, minimum depth Min-Z = focal(px) × baseline / 126 (the 126-pixel
//!   disparity search), absolute accuracy within 2 % of distance.
//! - Grunnet-Jepsen, Sweetser, Woodfill, *Tuning depth cameras for best performance* (Intel white
//!   paper): depth RMS error = distance² × subpixel / (focal(px) × baseline), subpixel RMS about
//!   0.08 px on a well-textured flat target; focal(px) = ½ Xres / tan(HFOV / 2).
//! - Keselman, Woodfill, Grunnet-Jepsen, Bhowmik, *Intel RealSense Stereoscopic Depth Cameras*,
//!   CVPR Workshops 2017: the D400 pipeline (census-based block matching over a 126-disparity
//!   range, left-right check and sub-pixel refinement), depth computed in the left imager's frame,
//!   with the occlusion band where the right imager cannot see.
//! - Depth intrinsics of a D435 at 640 × 480 as librealsense reports them: fx = fy ≈ 381-386 px
//!   (HFOV ≈ 80°); colour at 640 × 480: fx ≈ 597-621 px, principal points several px off centre.
//! - Foi, Trimeche, Katkovnik, Egiazarian, *Practical Poissonian-Gaussian noise modeling and fitting
//!   for single-image raw data*, IEEE TIP 2008: σ²(I) = a·I + b for the colour noise.
//!
//! The modules' docs say what each effect does and what it leaves out.

pub mod colour;
pub mod depth;
pub mod synthetic;

use nalgebra::{Matrix3, Matrix4, Rotation3, Vector3};
use serde::{Deserialize, Serialize};
use std::sync::{Barrier, Mutex, OnceLock, RwLock};
use thiserror::Error;

pub use colour::{colour_image, ColourConfig};
pub use depth::{stereo_depth, DepthStats, StereoDepthConfig};

/// Errors of the sensor model; each names the offending field.
#[derive(Debug, Error, PartialEq)]
pub enum SensorError {
    /// A configuration value is out of range.
    #[error("{field}: {value} {reason}")]
    InvalidParameter {
        /// Dotted field name, as in the run configuration (`camera.stereo.baseline_m`).
        field: &'static str,
        /// The value given.
        value: f64,
        /// What the range is.
        reason: &'static str,
    },
    /// A buffer does not match the image size.
    #[error("{field}: expected {expected} values, got {actual}")]
    BufferLength {
        /// Which buffer.
        field: &'static str,
        /// Values expected (width × height × channels).
        expected: usize,
        /// Values given.
        actual: usize,
    },
}

/// Calibration errors of one camera unit: how far the calibration the estimator assumes is from
/// the truth. Drawn once per episode ([`SensorUnit::draw`]); a real unit's factory calibration is
/// constant too.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CalibrationConfig {
    /// Colour ↔ depth extrinsic translation error, standard deviation per axis, metres (2 mm:
    /// about 3.5 mm in norm, "a few mm").
    pub extrinsic_trans_sigma_m: f64,
    /// Colour ↔ depth extrinsic rotation error, standard deviation per axis of the rotation
    /// vector, degrees (0.2°: about 0.35° in angle, "tenths of a degree").
    pub extrinsic_rot_sigma_deg: f64,
    /// Colour focal length error, standard deviation relative to the nominal focal (0.3 %).
    pub colour_focal_sigma_rel: f64,
    /// Colour principal point error, standard deviation per axis, pixels (1.5 px).
    pub colour_pp_sigma_px: f64,
    /// Depth focal length error (affects the depth image's x, y), relative (0.3 %).
    pub depth_focal_sigma_rel: f64,
    /// Depth principal point error, pixels of the depth imager (1.5 px).
    pub depth_pp_sigma_px: f64,
}

impl Default for CalibrationConfig {
    fn default() -> Self {
        Self {
            extrinsic_trans_sigma_m: 0.002,
            extrinsic_rot_sigma_deg: 0.2,
            colour_focal_sigma_rel: 0.003,
            colour_pp_sigma_px: 1.5,
            depth_focal_sigma_rel: 0.003,
            depth_pp_sigma_px: 1.5,
        }
    }
}

/// The whole sensor model's configuration (mirrors the run configuration's `[camera.stereo]`,
/// `[camera.colour]` and `[camera.calibration]` tables).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, Default)]
#[serde(default, deny_unknown_fields)]
pub struct SensorConfig {
    /// Depth.
    pub stereo: StereoDepthConfig,
    /// Colour.
    pub colour: ColourConfig,
    /// Calibration errors of the unit.
    pub calibration: CalibrationConfig,
}

fn check(field: &'static str, value: f64, ok: bool, reason: &'static str) -> Result<(), SensorError> {
    if ok && value.is_finite() {
        Ok(())
    } else {
        Err(SensorError::InvalidParameter { field, value, reason })
    }
}

impl SensorConfig {
    /// Check every field's range; the error names the field as the run configuration spells it.
    pub fn validate(&self) -> Result<(), SensorError> {
        self.stereo.validate()?;
        self.colour.validate()?;
        let c = &self.calibration;
        for (field, v, hi) in [
            ("camera.calibration.extrinsic_trans_sigma_m", c.extrinsic_trans_sigma_m, 0.05),
            ("camera.calibration.extrinsic_rot_sigma_deg", c.extrinsic_rot_sigma_deg, 5.0),
            ("camera.calibration.colour_focal_sigma_rel", c.colour_focal_sigma_rel, 0.05),
            ("camera.calibration.colour_pp_sigma_px", c.colour_pp_sigma_px, 20.0),
            ("camera.calibration.depth_focal_sigma_rel", c.depth_focal_sigma_rel, 0.05),
            ("camera.calibration.depth_pp_sigma_px", c.depth_pp_sigma_px, 20.0),
        ] {
            check(field, v, (0.0..=hi).contains(&v), "outside its range [0, limit] (see the field's doc)")?;
        }
        Ok(())
    }
}

/// A pinhole camera's intrinsics, pixels.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Intrinsics {
    /// Focal length along x.
    pub fx: f64,
    /// Focal length along y.
    pub fy: f64,
    /// Principal point x.
    pub cx: f64,
    /// Principal point y.
    pub cy: f64,
}

impl Intrinsics {
    /// From a 3 × 3 matrix `[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]`.
    pub fn from_matrix(k: &Matrix3<f64>) -> Self {
        Self { fx: k[(0, 0)], fy: k[(1, 1)], cx: k[(0, 2)], cy: k[(1, 2)] }
    }

    /// As a 3 × 3 matrix.
    pub fn matrix(&self) -> Matrix3<f64> {
        Matrix3::new(self.fx, 0.0, self.cx, 0.0, self.fy, self.cy, 0.0, 0.0, 1.0)
    }
}

/// One camera unit's calibration state over an episode: the truth the simulator renders with and
/// the error the estimator does not know about.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SensorUnit {
    /// Intrinsics the estimator assumes for the colour camera (the nominal ones, given).
    pub colour_assumed: Intrinsics,
    /// True colour intrinsics: the simulator renders the colour image with these.
    pub colour_true: Intrinsics,
    /// Multiplicative error of every depth value (disparity-to-depth calibration), 1 = exact.
    pub depth_scale: f64,
    /// True over assumed depth focal length, 1 = exact.
    pub depth_focal_ratio: f64,
    /// True minus assumed depth principal point, in units of the depth focal length (x, y).
    pub depth_pp_offset: [f64; 2],
    /// Error of the assumed colour ← depth extrinsic, as the transform taking a point in the true
    /// colour frame to where the registration puts it (4 × 4, row-major).
    pub registration_error: [[f64; 4]; 4],
}

/// SplitMix64 (Steele, Lea, Flood 2014): a small, fast, seedable generator for per-pixel draws.
#[derive(Debug, Clone)]
pub(crate) struct SplitMix64(u64);

impl SplitMix64 {
    /// A stream from a seed and stream tags (mixed so that nearby seeds give unrelated streams).
    pub(crate) fn new(seed: u64, tags: &[u64]) -> Self {
        let mut s = SplitMix64(seed);
        for &t in tags {
            let m = s.next_u64();
            s = SplitMix64(m ^ t.wrapping_mul(0xD1B5_4A32_D192_ED03));
        }
        s
    }

    pub(crate) fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1).
    pub(crate) fn uniform(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }

    /// Standard normal (Box-Muller).
    pub(crate) fn normal(&mut self) -> f64 {
        let u1 = 1.0 - self.uniform();
        let u2 = self.uniform();
        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
    }

    /// Fills `out` with standard normals for bulk draws: the normal quantile of a 12-bit uniform
    /// ([`normal_table`]), five per 64-bit draw.
    pub(crate) fn fill_normal(&mut self, out: &mut [f32]) {
        let table = normal_table();
        for chunk in out.chunks_mut(5) {
            let r = self.next_u64();
            for (k, v) in chunk.iter_mut().enumerate() {
                *v = table[((r >> (12 * k)) & 0xFFF) as usize];
            }
        }
    }
}

/// Standard normal quantiles of the `n` midpoints `(i + ½) / n`, rescaled to unit variance.
pub(crate) fn normal_quantiles(n: usize) -> Vec<f32> {
    let q: Vec<f64> = (0..n).map(|i| inverse_normal_cdf((i as f64 + 0.5) / n as f64)).collect();
    let sd = (q.iter().map(|v| v * v).sum::<f64>() / n as f64).sqrt();
    q.iter().map(|v| (v / sd) as f32).collect()
}

/// [`normal_quantiles`] of 4096 midpoints (tails cut at ±3.5 σ).
pub(crate) fn normal_table() -> &'static [f32] {
    static TABLE: OnceLock<Vec<f32>> = OnceLock::new();
    TABLE.get_or_init(|| normal_quantiles(4096))
}

/// Acklam's rational approximation of the standard normal quantile (relative error < 1.2e-9).
fn inverse_normal_cdf(p: f64) -> f64 {
    const A: [f64; 6] = [
        -39.696_830_286_653_76,
        220.946_098_424_520_5,
        -275.928_510_446_968_7,
        138.357_751_867_269,
        -30.664_798_066_147_16,
        2.506_628_277_459_239,
    ];
    const B: [f64; 5] = [
        -54.476_098_798_224_06,
        161.585_836_858_040_9,
        -155.698_979_859_886_6,
        66.801_311_887_719_72,
        -13.280_681_552_885_72,
    ];
    const C: [f64; 6] = [
        -7.784_894_002_430_293e-3,
        -0.322_396_458_041_136_5,
        -2.400_758_277_161_838,
        -2.549_732_539_343_734,
        4.374_664_141_464_968,
        2.938_163_982_698_783,
    ];
    const D: [f64; 4] =
        [7.784_695_709_041_462e-3, 0.322_467_129_070_039_8, 2.445_134_137_142_996, 3.754_408_661_907_416];
    let tail = |q: f64| {
        (((((C[0] * q + C[1]) * q + C[2]) * q + C[3]) * q + C[4]) * q + C[5])
            / ((((D[0] * q + D[1]) * q + D[2]) * q + D[3]) * q + 1.0)
    };
    if p < 0.024_25 {
        tail((-2.0 * p.ln()).sqrt())
    } else if p > 1.0 - 0.024_25 {
        -tail((-2.0 * (1.0 - p).ln()).sqrt())
    } else {
        let q = p - 0.5;
        let r = q * q;
        (((((A[0] * r + A[1]) * r + A[2]) * r + A[3]) * r + A[4]) * r + A[5]) * q
            / (((((B[0] * r + B[1]) * r + B[2]) * r + B[3]) * r + B[4]) * r + 1.0)
    }
}

/// Smaller of two values; `b` if either is NaN (a compare and a select, which vectorises).
#[inline]
pub(crate) fn min_f(a: f32, b: f32) -> f32 {
    if a < b {
        a
    } else {
        b
    }
}

/// Larger of two values; `b` if either is NaN.
#[inline]
pub(crate) fn max_f(a: f32, b: f32) -> f32 {
    if a > b {
        a
    } else {
        b
    }
}

/// Adding this to an `f32` in `(−2^22, 2^22)` rounds it to an integer (halves to even), which
/// then sits in the low bits of the sum's representation.
pub(crate) const ROUND_F32: f32 = 12_582_912.0; // 1.5 · 2^23
/// An integer-valued `f32` in `(−2^22, 2^22)` as an `i32`, by float and integer operations only
/// (so that a row of them vectorises).
#[inline]
pub(crate) fn to_i32(v: f32) -> i32 {
    (v + ROUND_F32).to_bits() as i32 - ROUND_F32.to_bits() as i32
}

/// Stream tags of the per-episode and per-frame draws.
pub(crate) const TAG_UNIT: u64 = 1;
pub(crate) const TAG_DEPTH: u64 = 2;
pub(crate) const TAG_COLOUR: u64 = 3;

impl SensorUnit {
    /// Draw a unit's calibration errors from `seed` around the nominal colour intrinsics
    /// `colour_assumed` (which the estimator keeps using). Deterministic per seed.
    pub fn draw(config: &SensorConfig, colour_assumed: Intrinsics, seed: u64) -> Result<Self, SensorError> {
        config.validate()?;
        let mut rng = SplitMix64::new(seed, &[TAG_UNIT]);
        let c = &config.calibration;
        let s = &config.stereo;
        let f_rel = 1.0 + c.colour_focal_sigma_rel * rng.normal();
        let colour_true = Intrinsics {
            fx: colour_assumed.fx * f_rel,
            fy: colour_assumed.fy * f_rel,
            cx: colour_assumed.cx + c.colour_pp_sigma_px * rng.normal(),
            cy: colour_assumed.cy + c.colour_pp_sigma_px * rng.normal(),
        };
        // The datasheet bounds the absolute error by 2 % of distance; draws are clipped to 3 σ.
        let scale_err = (s.scale_sigma * rng.normal()).clamp(-3.0 * s.scale_sigma, 3.0 * s.scale_sigma);
        let depth_focal_ratio = 1.0 + c.depth_focal_sigma_rel * rng.normal();
        let depth_pp_offset =
            [c.depth_pp_sigma_px * rng.normal() / s.focal_px, c.depth_pp_sigma_px * rng.normal() / s.focal_px];
        let t = Vector3::new(rng.normal(), rng.normal(), rng.normal()) * c.extrinsic_trans_sigma_m;
        let w = Vector3::new(rng.normal(), rng.normal(), rng.normal()) * c.extrinsic_rot_sigma_deg.to_radians();
        let r = Rotation3::new(w);
        let mut m = Matrix4::identity();
        m.fixed_view_mut::<3, 3>(0, 0).copy_from(r.matrix());
        m.fixed_view_mut::<3, 1>(0, 3).copy_from(&t);
        let mut registration_error = [[0.0; 4]; 4];
        for (i, row) in registration_error.iter_mut().enumerate() {
            for (j, v) in row.iter_mut().enumerate() {
                *v = m[(i, j)];
            }
        }
        Ok(Self {
            colour_assumed,
            colour_true,
            depth_scale: 1.0 + scale_err,
            depth_focal_ratio,
            depth_pp_offset,
            registration_error,
        })
    }
}

/// One rendered frame of the colour camera (the renderer's geometry and its colour image).
#[derive(Debug, Clone, Copy)]
pub struct RenderedFrame<'a> {
    /// Image width, pixels.
    pub width: usize,
    /// Image height, pixels.
    pub height: usize,
    /// Per pixel, row-major: the surface point in the colour camera's frame (OpenCV axes, metres),
    /// `z <= 0` or non-finite where nothing was hit. Length `3 · width · height`.
    pub points_in_camera: &'a [f32],
    /// Per pixel: the unit surface normal in the camera frame (any sign). Length `3 · w · h`.
    pub normals_in_camera: &'a [f32],
    /// Per pixel: RGB, 8 bits per channel. Length `3 · w · h`, or empty for depth only.
    pub rgb: &'a [u8],
}

/// A rendered frame as the renderer's camera delivers its buffers (SAPIEN's "Position", "Normal"
/// and "Color" pictures): four floats a pixel, row-major, in the camera's OpenGL axes (x right,
/// y up, z backward).
#[derive(Debug, Clone, Copy)]
pub struct RendererBuffers<'a> {
    /// Image width, pixels.
    pub width: usize,
    /// Image height, pixels.
    pub height: usize,
    /// Per pixel: (x, y, z, w), the surface point in metres; `w >= 1` where nothing was hit (or
    /// where the caller drops the pixel, e.g. the robot's own). Length `4 · width · height`.
    pub position: &'a [f32],
    /// Per pixel: (x, y, z, unused), the surface normal. Length `4 · width · height`.
    pub normal: &'a [f32],
    /// Per pixel: (r, g, b, a) in [0, 1]. Length `4 · width · height`, or empty for depth only.
    pub colour: &'a [f32],
    /// Per pixel: the renderer's segmentation id. Length `width · height`, or empty for none.
    pub segmentation: &'a [u32],
    /// Segmentation ids whose pixels count as nothing hit (the robot's own), each below 2^20;
    /// read only with a segmentation.
    pub dropped_ids: &'a [u32],
}

/// Whether a pixel of the renderer's buffers has a surface: its position's w below 1 (or NaN),
/// and its segmentation id (when given) not dropped.
#[derive(Clone, Copy)]
pub(crate) struct Hits<'a> {
    segmentation: &'a [u32],
    /// Per id: dropped; the last entry is false and stands for every id past it. Empty: no drops.
    dropped: &'a [bool],
}

impl Hits<'_> {
    /// Whether pixel `i`, at position `p` (its four floats), hit a surface.
    #[inline]
    pub(crate) fn hit(&self, i: usize, p: &[f32]) -> bool {
        let hit = p[3] < 1.0 || p[3].is_nan();
        match self.dropped.last() {
            None => hit,
            Some(_) => hit && !self.dropped[(self.segmentation[i] as usize).min(self.dropped.len() - 1)],
        }
    }
}

/// The buffers of a [`RenderedFrame`], owned.
#[derive(Debug, Clone, Default)]
pub struct FrameBuffers {
    /// Image width, pixels.
    pub width: usize,
    /// Image height, pixels.
    pub height: usize,
    /// [`RenderedFrame::points_in_camera`].
    pub points: Vec<f32>,
    /// [`RenderedFrame::normals_in_camera`].
    pub normals: Vec<f32>,
    /// [`RenderedFrame::rgb`].
    pub rgb: Vec<u8>,
}

impl FrameBuffers {
    /// The buffers as the sensor model's input.
    pub fn frame(&self) -> RenderedFrame<'_> {
        RenderedFrame {
            width: self.width,
            height: self.height,
            points_in_camera: &self.points,
            normals_in_camera: &self.normals,
            rgb: &self.rgb,
        }
    }
}

impl RendererBuffers<'_> {
    /// The table of [`Hits`] (empty without a segmentation or dropped ids).
    fn dropped_table(&self) -> Result<Vec<bool>, SensorError> {
        if self.segmentation.is_empty() || self.dropped_ids.is_empty() {
            return Ok(Vec::new());
        }
        let n = self.width * self.height;
        if self.segmentation.len() != n {
            return Err(SensorError::BufferLength {
                field: "segmentation",
                expected: n,
                actual: self.segmentation.len(),
            });
        }
        let mut table = Vec::new();
        for &id in self.dropped_ids {
            check("dropped_ids", id as f64, id < 1 << 20, "is not below 2^20")?;
            let i = id as usize;
            if table.len() < i + 2 {
                table.resize(i + 2, false);
            }
            table[i] = true;
        }
        Ok(table)
    }

    fn hits<'t>(&'t self, dropped: &'t [bool]) -> Hits<'t> {
        Hits { segmentation: self.segmentation, dropped }
    }

    /// The buffers in the sensor model's conventions, into `out` (its allocations reused):
    /// OpenCV axes (y and z negated), the point (0, 0, 0) where nothing was hit (w >= 1, or a
    /// dropped segmentation id), colour to 8 bits
    /// rounded to nearest (`clamp(255 c, 0, 255) + ½`, truncated). On two threads where the
    /// machine has two cores.
    pub fn convert_into(&self, out: &mut FrameBuffers) -> Result<(), SensorError> {
        self.convert(out, true)
    }

    /// [`Self::convert_into`]; without `geometry`, the colour alone (points and normals left
    /// empty: the depth model reads the position and normal buffers in place).
    fn convert(&self, out: &mut FrameBuffers, geometry: bool) -> Result<(), SensorError> {
        let (w, h) = (self.width, self.height);
        let n = w * h;
        for (field, len) in [("position", self.position.len()), ("normal", self.normal.len())] {
            if len != 4 * n {
                return Err(SensorError::BufferLength { field, expected: 4 * n, actual: len });
            }
        }
        if !self.colour.is_empty() && self.colour.len() != 4 * n {
            return Err(SensorError::BufferLength { field: "colour", expected: 4 * n, actual: self.colour.len() });
        }
        let with_colour = !self.colour.is_empty();
        let dropped = self.dropped_table()?;
        let hits = self.hits(&dropped);
        (out.width, out.height) = (w, h);
        out.points.resize(if geometry { 3 * n } else { 0 }, 0.0);
        out.normals.resize(if geometry { 3 * n } else { 0 }, 0.0);
        out.rgb.resize(if with_colour { 3 * n } else { 0 }, 0);
        let convert = |rows: std::ops::Range<usize>, points: &mut [f32], normals: &mut [f32], rgb: &mut [u8]| {
            let span = 4 * rows.start * w..4 * rows.end * w;
            let pixels = self.position[span.clone()].chunks_exact(4).enumerate();
            for (o, (i, p)) in points.chunks_exact_mut(3).zip(pixels) {
                let hit = hits.hit(rows.start * w + i, p);
                o[0] = if hit { p[0] } else { 0.0 };
                o[1] = if hit { -p[1] } else { 0.0 };
                o[2] = if hit { -p[2] } else { 0.0 };
            }
            for (o, v) in normals.chunks_exact_mut(3).zip(self.normal[span.clone()].chunks_exact(4)) {
                (o[0], o[1], o[2]) = (v[0], -v[1], -v[2]);
            }
            if with_colour {
                for (o, c) in rgb.chunks_exact_mut(3).zip(self.colour[span].chunks_exact(4)) {
                    for (o, &c) in o.iter_mut().zip(c) {
                        *o = (min_f(max_f(c * 255.0, 0.0), 255.0) + 0.5) as u8;
                    }
                }
            }
        };
        if crate::worker_threads() < 2 || h < 2 {
            convert(0..h, &mut out.points, &mut out.normals, &mut out.rgb);
            return Ok(());
        }
        // Parts of rows, each thread taking the next when done (as in `simulate_frame`).
        // A buffer left empty gives every part an empty slice.
        let size = PART_ROWS * w.max(1);
        let n_parts = h.div_ceil(PART_ROWS);
        fn chunks<T>(v: &mut [T], size: usize, n_parts: usize) -> Vec<&mut [T]> {
            let mut c: Vec<&mut [T]> = v.chunks_mut(size).collect();
            c.resize_with(n_parts, Default::default);
            c
        }
        let (points, normals) =
            (chunks(&mut out.points, 3 * size, n_parts), chunks(&mut out.normals, 3 * size, n_parts));
        let rgb = chunks(&mut out.rgb, 3 * size, n_parts);
        let parts = (0..h).step_by(PART_ROWS).map(|y| y..(y + PART_ROWS).min(h));
        let queue = Mutex::new(parts.zip(points.into_iter().zip(normals)).zip(rgb));
        let work = || {
            while let Some(((rows, (points, normals)), rgb)) = next_part(&queue) {
                convert(rows, points, normals, rgb);
            }
        };
        std::thread::scope(|s| {
            s.spawn(work);
            work();
        });
        Ok(())
    }
}

/// What the sensor delivers for a frame.
#[derive(Debug, Clone)]
pub struct SensorFrame {
    /// Depth registered to the colour image by the assumed calibration, metres, 0 = no return.
    pub depth_m: Vec<f32>,
    /// Colour image (empty when no colour was given).
    pub rgb: Vec<u8>,
    /// Counts of the depth model's effects on this frame.
    pub stats: DepthStats,
}

/// The sensor model on one frame: depth and colour ([`stereo_depth`] and [`colour_image`], on
/// two threads where the machine has two cores; the result does not depend on it).
/// `camera_end_from_start` is the camera's motion over the colour exposure (4 × 4; identity or
/// `None` = at rest). Per-frame draws are seeded by `(seed, frame_index)`.
pub fn simulate_frame(
    config: &SensorConfig,
    unit: &SensorUnit,
    frame: &RenderedFrame<'_>,
    camera_end_from_start: Option<&Matrix4<f64>>,
    seed: u64,
    frame_index: u64,
) -> Result<SensorFrame, SensorError> {
    simulate_frame_on(crate::worker_threads(), config, unit, frame, None, camera_end_from_start, seed, frame_index)
}

/// Rows a thread takes at a time from a frame's queue of rows: small enough that a thread that
/// starts late (or is descheduled) leaves the rest to the other, large enough that the rows each
/// part computes twice (the mixed band around it, 1 row by default) stay a small share.
const PART_ROWS: usize = 24;

/// The next part of a queue of row parts, if any.
fn next_part<T>(queue: &Mutex<T>) -> Option<T::Item>
where
    T: Iterator,
{
    queue.lock().unwrap_or_else(|e| e.into_inner()).next()
}

/// [`simulate_frame`] on `threads` threads (1 or 2; more count as 2); with `renderer`, the depth
/// model reads its position and normal buffers in place of `frame`'s points and normals (which
/// may then be empty).
#[allow(clippy::too_many_arguments)]
fn simulate_frame_on(
    threads: usize,
    config: &SensorConfig,
    unit: &SensorUnit,
    frame: &RenderedFrame<'_>,
    renderer: Option<&RendererBuffers<'_>>,
    camera_end_from_start: Option<&Matrix4<f64>>,
    seed: u64,
    frame_index: u64,
) -> Result<SensorFrame, SensorError> {
    config.validate()?;
    let n = frame.width * frame.height;
    let geometry = match renderer {
        Some(r) => [("position", r.position.len(), 4 * n), ("normal", r.normal.len(), 4 * n)],
        None => [
            ("points_in_camera", frame.points_in_camera.len(), 3 * n),
            ("normals_in_camera", frame.normals_in_camera.len(), 3 * n),
        ],
    };
    for (field, len, expected) in geometry {
        if len != expected {
            return Err(SensorError::BufferLength { field, expected, actual: len });
        }
    }
    if !frame.rgb.is_empty() && frame.rgb.len() != 3 * n {
        return Err(SensorError::BufferLength { field: "rgb", expected: 3 * n, actual: frame.rgb.len() });
    }
    if !frame.rgb.is_empty() {
        for (field, side) in [("width", frame.width), ("height", frame.height)] {
            check(field, side as f64, side <= colour::MAX_SIDE_PX, "at most 65536 pixels for the colour model")?;
        }
    }
    let (w, h) = (frame.width, frame.height);
    let dropped = renderer.map(|r| r.dropped_table()).transpose()?.unwrap_or_default();
    let mut depth = depth::DepthFrame::new(&config.stereo, unit, frame, seed, frame_index);
    if let Some(r) = renderer {
        depth = depth.on_renderer_buffers(r.position, r.normal, r.hits(&dropped));
    }
    let noise = colour::NoiseTable::shared(&config.colour);
    let with_colour = !frame.rgb.is_empty();
    let mut rgb = vec![0u8; if with_colour { 3 * n } else { 0 }];
    // Every value is written by the depth image pass.
    let mut depth_m = vec![0.0f32; n];
    let two = threads >= 2 && h >= 2;
    // The rows in parts, each with its rows of the colour image; a thread takes the next part
    // when it is done with one, so the split follows how fast each thread actually runs.
    let part_rows = if two { PART_ROWS } else { h.max(1) };
    let mut rgb_parts: Vec<&mut [u8]> = rgb.chunks_mut(3 * part_rows * w.max(1)).collect();
    rgb_parts.resize_with(h.div_ceil(part_rows), Default::default);
    let queue = Mutex::new((0..h).step_by(part_rows).map(|y| y..(y + part_rows).min(h)).zip(rgb_parts));
    // Every part this thread takes: steps 1-3 on its rows and, uncounted, on the mixed band's rows
    // around them (step 4 reads them), registration into the thread's z-buffer, colour. Every
    // row's result is the same whichever thread computes it. Returns the counts and the rows of
    // the z-buffer written.
    let work = |scratch: &mut PartScratch, zbuf: &mut [f32]| {
        let band = config.stereo.mixed_band_px;
        let (mut stats, mut touched) = (DepthStats::default(), 0..0);
        scratch.blur.start_frame();
        while let Some((rows, rgb)) = next_part(&queue) {
            let (lo, hi) = (rows.start.saturating_sub(band), (rows.end + band).min(h));
            let (z, state) = (&mut scratch.z[..n], &mut scratch.state[..n]);
            let mut part = depth.surfaces(
                rows.start,
                &mut z[rows.start * w..rows.end * w],
                &mut state[rows.start * w..rows.end * w],
            );
            depth.surfaces(lo, &mut z[lo * w..rows.start * w], &mut state[lo * w..rows.start * w]);
            depth.surfaces(rows.end, &mut z[rows.end * w..hi * w], &mut state[rows.end * w..hi * w]);
            let written;
            (part.mixed, written) = depth.register(rows.clone(), &scratch.z, &scratch.state, zbuf);
            stats = stats.plus(&part);
            if !written.is_empty() {
                touched = match touched.is_empty() {
                    true => written,
                    false => touched.start.min(written.start)..touched.end.max(written.end),
                };
            }
            if with_colour {
                colour::ColourRows::new(
                    unit,
                    frame,
                    Some(&scratch.z[..n]),
                    camera_end_from_start,
                    noise.as_deref(),
                    seed,
                    frame_index,
                    &mut scratch.blur,
                )
                .run(rows.start, rgb);
            }
        }
        (stats, touched)
    };
    let mut scratch = PartScratch::take(n);
    let mut stats;
    if !two {
        let mut zbuf = std::mem::take(&mut scratch.zbuf);
        let touched;
        (stats, touched) = work(&mut scratch, &mut zbuf);
        stats.valid_out = depth_image(&[&zbuf], &mut depth_m);
        zbuf[touched.start * w..touched.end * w].fill(f32::INFINITY);
        scratch.zbuf = zbuf;
    } else {
        // Two threads, each registering into its own z-buffer; once both are done (the
        // registration moves depths across parts), each makes half of the depth image from both
        // z-buffers, then resets its own.
        let mut second = PartScratch::take(n);
        let half = h / 2;
        let (out_a, out_b) = depth_m.split_at_mut(half * w);
        let zbufs = [RwLock::new(std::mem::take(&mut scratch.zbuf)), RwLock::new(std::mem::take(&mut second.zbuf))];
        let barrier = Barrier::new(2);
        let run = |i: usize, rows: std::ops::Range<usize>, scratch: &mut PartScratch, out: &mut [f32]| {
            // A panic on either thread still meets the other at every rendezvous.
            let mut meet = Rendezvous { barrier: &barrier, owed: 2 };
            let (stats, touched) = work(scratch, &mut write(&zbufs[i]));
            meet.wait();
            let span = rows.start * w..rows.end * w;
            let valid = depth_image(&[&read(&zbufs[0])[span.clone()], &read(&zbufs[1])[span]], out);
            meet.wait();
            write(&zbufs[i])[touched.start * w..touched.end * w].fill(f32::INFINITY);
            (stats, valid)
        };
        let (a, b) = std::thread::scope(|s| {
            let b = s.spawn(|| run(1, half..h, &mut second, out_b));
            (run(0, 0..half, &mut scratch, out_a), b.join())
        });
        let b = b.unwrap_or_else(|e| std::panic::resume_unwind(e));
        stats = a.0.plus(&b.0);
        stats.valid_out = a.1 + b.1;
        let [za, zb] = zbufs.map(|z| z.into_inner().unwrap_or_else(|e| e.into_inner()));
        (scratch.zbuf, second.zbuf) = (za, zb);
        second.give_back();
    }
    scratch.give_back();
    Ok(SensorFrame { depth_m, rgb, stats })
}

/// The depth image from z-buffers of the same pixels (+inf = nothing): the nearest depth, 0
/// where none; returns the count with a depth.
fn depth_image(zbufs: &[&[f32]], out: &mut [f32]) -> usize {
    let mut valid = 0u32;
    if let [a, b] = zbufs {
        for (o, (&u, &v)) in out.iter_mut().zip(a.iter().zip(b.iter())) {
            let m = min_f(u, v);
            let d = if m < f32::INFINITY { m } else { 0.0 };
            valid += u32::from(d > 0.0);
            *o = d;
        }
    } else {
        for (o, &u) in out.iter_mut().zip(zbufs.first().copied().unwrap_or_default()) {
            let d = if u < f32::INFINITY { u } else { 0.0 };
            valid += u32::from(d > 0.0);
            *o = d;
        }
    }
    valid as usize
}

fn read<T>(lock: &RwLock<T>) -> std::sync::RwLockReadGuard<'_, T> {
    lock.read().unwrap_or_else(|e| e.into_inner())
}

fn write<T>(lock: &RwLock<T>) -> std::sync::RwLockWriteGuard<'_, T> {
    lock.write().unwrap_or_else(|e| e.into_inner())
}

/// A thread's remaining meetings at a two-thread barrier: the ones not kept (the thread
/// panicked) are kept when it unwinds, so the other thread never waits forever.
struct Rendezvous<'a> {
    barrier: &'a Barrier,
    owed: usize,
}

impl Rendezvous<'_> {
    fn wait(&mut self) {
        self.owed = self.owed.saturating_sub(1);
        self.barrier.wait();
    }
}

impl Drop for Rendezvous<'_> {
    fn drop(&mut self) {
        while self.owed > 0 {
            self.wait();
        }
    }
}

/// The large buffers of one part of a frame (per-thread scratch), kept in a pool between frames
/// so that frames of the same size allocate none of them.
struct PartScratch {
    /// True depth and state of every pixel (the part's rows and the band around them written).
    z: Vec<f32>,
    state: Vec<u8>,
    /// A z-buffer of the whole image, +inf everywhere between frames.
    zbuf: Vec<f32>,
    /// The motion blur's prefix sums.
    blur: colour::BlurScratch,
}

/// Scratch of finished frames, for the next ones.
static SCRATCH: Mutex<Vec<PartScratch>> = Mutex::new(Vec::new());

impl PartScratch {
    /// Scratch for a frame of `n` pixels: from the pool, or new.
    fn take(n: usize) -> Self {
        let pooled = SCRATCH.lock().unwrap_or_else(|e| e.into_inner()).pop();
        let mut s = pooled.unwrap_or_else(|| Self {
            z: Vec::new(),
            state: Vec::new(),
            zbuf: Vec::new(),
            blur: colour::BlurScratch::default(),
        });
        if s.zbuf.len() != n {
            (s.z, s.state, s.zbuf) = (vec![0.0; n], vec![0; n], vec![f32::INFINITY; n]);
        }
        s
    }

    /// Back into the pool (at most two kept: one per thread).
    fn give_back(self) {
        let mut pool = SCRATCH.lock().unwrap_or_else(|e| e.into_inner());
        if pool.len() < 2 {
            pool.push(self);
        }
    }
}

/// One call of the sensor model as the Python API makes it (`sensor_model(request_json, ...)`).
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SensorRequest {
    /// Stereo, colour and calibration settings (missing keys take the defaults).
    #[serde(default)]
    pub config: SensorConfig,
    /// The episode's seed (the unit's draw and the per-frame draws).
    pub seed: u64,
    /// The frame's index (per-frame draws). Default 0.
    #[serde(default)]
    pub frame_index: u64,
    /// Nominal (assumed) colour intrinsics, 3 × 3 (rows).
    pub intrinsics: [[f64; 3]; 3],
    /// The camera's motion over the colour exposure (4 × 4, rows); None = at rest.
    #[serde(default)]
    pub camera_end_from_start: Option<[[f64; 4]; 4]>,
}

/// What a sensor-model call reports beside the images.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SensorInfo {
    /// The episode's calibration state.
    pub unit: SensorUnit,
    /// The depth model's counts on the frame (None without a frame).
    pub stats: Option<DepthStats>,
}

impl SensorRequest {
    /// Draws the episode's unit and, given a rendered frame, simulates it ([`simulate_frame`]).
    pub fn run(&self, frame: Option<&RenderedFrame<'_>>) -> Result<(SensorInfo, Option<SensorFrame>), SensorError> {
        let unit = self.unit()?;
        let Some(frame) = frame else { return Ok((SensorInfo { unit, stats: None }, None)) };
        let out = self.simulate(&unit, frame)?;
        Ok((SensorInfo { unit, stats: Some(out.stats) }, Some(out)))
    }

    /// [`Self::run`] on the renderer's own buffers: the same result as on the buffers
    /// [`RendererBuffers::convert_into`] makes, with only the colour converted (kept between
    /// calls); the depth model reads the position and normal buffers in place.
    pub fn run_renderer(&self, buffers: &RendererBuffers<'_>) -> Result<(SensorInfo, SensorFrame), SensorError> {
        static CONVERTED: Mutex<Option<FrameBuffers>> = Mutex::new(None);
        let unit = self.unit()?;
        let mut converted = CONVERTED.lock().unwrap_or_else(|e| e.into_inner()).take().unwrap_or_default();
        let out = buffers.convert(&mut converted, false).and_then(|()| {
            let motion = self.camera_end_from_start.map(|m| Matrix4::from_fn(|r, c| m[r][c]));
            let (threads, frame) = (crate::worker_threads(), converted.frame());
            simulate_frame_on(
                threads,
                &self.config,
                &unit,
                &frame,
                Some(buffers),
                motion.as_ref(),
                self.seed,
                self.frame_index,
            )
        });
        *CONVERTED.lock().unwrap_or_else(|e| e.into_inner()) = Some(converted);
        let out = out?;
        Ok((SensorInfo { unit, stats: Some(out.stats) }, out))
    }

    fn unit(&self) -> Result<SensorUnit, SensorError> {
        let k = Intrinsics::from_matrix(&Matrix3::from_fn(|r, c| self.intrinsics[r][c]));
        SensorUnit::draw(&self.config, k, self.seed)
    }

    fn simulate(&self, unit: &SensorUnit, frame: &RenderedFrame<'_>) -> Result<SensorFrame, SensorError> {
        let motion = self.camera_end_from_start.map(|m| Matrix4::from_fn(|r, c| m[r][c]));
        simulate_frame(&self.config, unit, frame, motion.as_ref(), self.seed, self.frame_index)
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // tests may unwrap (STYLE.md 18)
mod tests {
    use super::*;

    /// Renderer buffers of a `w` × `h` frame without segmentation.
    fn unsegmented<'a>(
        w: usize,
        h: usize,
        position: &'a [f32],
        normal: &'a [f32],
        colour: &'a [f32],
    ) -> RendererBuffers<'a> {
        RendererBuffers { width: w, height: h, position, normal, colour, segmentation: &[], dropped_ids: &[] }
    }

    fn nominal() -> Intrinsics {
        Intrinsics { fx: 433.0, fy: 433.0, cx: 320.0, cy: 240.0 }
    }

    #[test]
    fn a_request_draws_the_unit_and_simulates_a_frame() {
        let request: SensorRequest =
            serde_json::from_str(r#"{"seed": 7, "intrinsics": [[433, 0, 320], [0, 433, 240], [0, 0, 1]]}"#).unwrap();
        let (info, frame) = request.run(None).unwrap();
        assert_eq!(info.unit, SensorUnit::draw(&SensorConfig::default(), nominal(), 7).unwrap());
        assert!(frame.is_none() && info.stats.is_none());
        let (points, normals) = ([0.0f32, 0.0, 0.5].repeat(4), [0.0f32, 0.0, -1.0].repeat(4));
        let rendered =
            RenderedFrame { width: 2, height: 2, points_in_camera: &points, normals_in_camera: &normals, rgb: &[] };
        let (info, frame) = request.run(Some(&rendered)).unwrap();
        let frame = frame.unwrap();
        assert_eq!(frame.depth_m.len(), 4);
        assert_eq!(info.stats, Some(frame.stats));
        assert!(serde_json::from_str::<SensorRequest>(r#"{"seed": 1, "intrinsics": [], "bogus": 1}"#).is_err());
    }

    #[test]
    fn a_frame_on_two_threads_equals_its_models_run_alone() {
        // A tilted plane with a nearer box, textured, the camera moving over the exposure: every
        // effect of both models is on (silhouettes, shadow, blur along both axes).
        let (w, h) = (96usize, 64usize);
        let k = Intrinsics { fx: 80.0, fy: 80.0, cx: 48.0, cy: 32.0 };
        let (mut p, mut nrm, mut rgb) = (vec![0.0f32; 3 * w * h], vec![0.0f32; 3 * w * h], vec![0u8; 3 * w * h]);
        for y in 0..h {
            for x in 0..w {
                let i = y * w + x;
                let z = if (30..60).contains(&x) && (20..44).contains(&y) { 0.35 } else { 0.5 + 0.002 * y as f32 };
                p[3 * i] = (x as f32 + 0.5 - 48.0) / 80.0 * z;
                p[3 * i + 1] = (y as f32 + 0.5 - 32.0) / 80.0 * z;
                p[3 * i + 2] = z;
                nrm[3 * i + 2] = -1.0;
                rgb[3 * i..3 * i + 3].copy_from_slice(&[
                    (x * 7 % 256) as u8,
                    (y * 11 % 256) as u8,
                    ((x + y) % 200) as u8,
                ]);
            }
        }
        let cfg = SensorConfig::default();
        let unit = SensorUnit::draw(&cfg, k, 5).unwrap();
        let frame = RenderedFrame { width: w, height: h, points_in_camera: &p, normals_in_camera: &nrm, rgb: &rgb };
        for motion in [Rotation3::new(Vector3::new(0.01, 0.003, 0.0)), Rotation3::new(Vector3::new(0.0, 0.004, 0.02))] {
            let mut m = Matrix4::identity();
            m.fixed_view_mut::<3, 3>(0, 0).copy_from(motion.matrix());
            m[(0, 3)] = 0.003;
            let both = simulate_frame(&cfg, &unit, &frame, Some(&m), 9, 4).unwrap();
            let (depth, stats) = stereo_depth(&cfg.stereo, &unit, &frame, 9, 4);
            assert_eq!(both.depth_m, depth);
            assert_eq!(both.stats, stats);
            assert!(stats.mixed > 0 && stats.shadow > 0);
            assert_eq!(both.rgb, colour_image(&cfg.colour, &unit, &frame, Some(&m), 9, 4));
        }
    }

    #[test]
    fn a_frame_is_the_same_on_one_and_two_threads() {
        // Five parts of rows (the last short), a nearer box and a tilted, textured plane; the
        // camera at rest, rolling about its axis (every blur direction within a row: row and
        // column sums, line changes), and moving steeply.
        let (w, h) = (128usize, 4 * PART_ROWS + 5);
        let k = Intrinsics { fx: 100.0, fy: 100.0, cx: 64.0, cy: h as f64 / 2.0 };
        let (mut p, mut nrm, mut rgb) = (vec![0.0f32; 3 * w * h], vec![0.0f32; 3 * w * h], vec![0u8; 3 * w * h]);
        for y in 0..h {
            for x in 0..w {
                let i = y * w + x;
                let boxed = (40..90).contains(&x) && (30..70).contains(&y);
                let z = if boxed { 0.35 } else { 0.5 + 0.002 * y as f32 };
                p[3 * i] = ((x as f64 + 0.5 - k.cx) / k.fx) as f32 * z;
                p[3 * i + 1] = ((y as f64 + 0.5 - k.cy) / k.fy) as f32 * z;
                p[3 * i + 2] = if x == 7 && y % 9 == 0 { 0.0 } else { z };
                nrm[3 * i + 2] = -1.0;
                rgb[3 * i..3 * i + 3].copy_from_slice(&[
                    (x * 7 % 256) as u8,
                    (y * 11 % 256) as u8,
                    ((x ^ y) % 200) as u8,
                ]);
            }
        }
        let cfg = SensorConfig::default();
        let unit = SensorUnit::draw(&cfg, k, 5).unwrap();
        let frame = RenderedFrame { width: w, height: h, points_in_camera: &p, normals_in_camera: &nrm, rgb: &rgb };
        let motion = |w: Vector3<f64>, t: [f64; 3]| {
            let mut m = Matrix4::identity();
            m.fixed_view_mut::<3, 3>(0, 0).copy_from(Rotation3::new(w).matrix());
            m.fixed_view_mut::<3, 1>(0, 3).copy_from(&Vector3::from(t));
            m
        };
        let rolling = motion(Vector3::new(0.002, -0.001, 0.08), [0.002, -0.001, 0.0]);
        let steep = motion(Vector3::new(0.03, 0.0, 0.0), [0.0, 0.004, 0.0]);
        for m in [None, Some(rolling), Some(steep)] {
            let one = simulate_frame_on(1, &cfg, &unit, &frame, None, m.as_ref(), 9, 4).unwrap();
            assert!(one.stats.mixed > 0 && one.stats.shadow > 0);
            // The parts go to whichever thread asks first: several runs, several splits.
            for _ in 0..6 {
                let two = simulate_frame_on(2, &cfg, &unit, &frame, None, m.as_ref(), 9, 4).unwrap();
                assert_eq!((&two.depth_m, &two.rgb, two.stats), (&one.depth_m, &one.rgb, one.stats));
            }
            if let Some(m) = m {
                // Blurred: differs from the frame at rest.
                assert_ne!(one.rgb, simulate_frame_on(1, &cfg, &unit, &frame, None, None, 9, 4).unwrap().rgb);
                assert_eq!(one.rgb, colour_image(&cfg.colour, &unit, &frame, Some(&m), 9, 4));
            }
        }
    }

    #[test]
    fn renderer_buffers_read_in_place_give_the_converted_frames_result() {
        // A tilted plane (grazing normals on its left third) with a nearer box; pixels without a
        // surface (w = 1 and w = 2, over points that would be surfaces) and a NaN w (a surface
        // to the conversion); at rest, rolling and moving steeply. Then the same with segmentation
        // ids, two of them dropped: the same as their pixels' w set to 1.
        let (w, h) = (128usize, 4 * PART_ROWS + 5);
        let (fx, cx, cy) = (100.0f32, 64.0f32, h as f32 / 2.0);
        let (mut position, mut normal, mut colour) = (Vec::new(), Vec::new(), Vec::new());
        for y in 0..h {
            for x in 0..w {
                let boxed = (40..90).contains(&x) && (30..70).contains(&y);
                let z = if boxed { 0.35 } else { 0.5 + 0.002 * y as f32 };
                let (px, py) = ((x as f32 + 0.5 - cx) / fx * z, (y as f32 + 0.5 - cy) / fx * z);
                let wv = match (x * 31 + y * 17) % 97 {
                    0 => 1.0,
                    1 => 2.0,
                    2 => f32::NAN,
                    _ => 0.5,
                };
                position.extend([px, -py, -z, wv]);
                let n = if x < w / 3 && !boxed { [0.958, 0.02, 0.287] } else { [0.0, 0.0, -1.0] };
                normal.extend([n[0], -n[1], -n[2], 0.0]);
                colour.extend([
                    (x * 7 % 256) as f32 / 255.0,
                    (y * 11 % 256) as f32 / 300.0,
                    ((x ^ y) % 200) as f32 / 199.0,
                    1.0,
                ]);
            }
        }
        let buffers = unsegmented(w, h, &position, &normal, &colour);
        let mut converted = FrameBuffers::default();
        buffers.convert_into(&mut converted).unwrap();
        let rolling = [
            [0.9968, -0.0799, -0.001, 0.002],
            [0.0799, 0.9968, 0.002, -0.001],
            [0.001, -0.002, 1.0, 0.0],
            [0.0, 0.0, 0.0, 1.0],
        ];
        let steep = [[1.0, 0.0, 0.0, 0.0], [0.0, 0.9996, -0.03, 0.004], [0.0, 0.03, 0.9996, 0.0], [0.0, 0.0, 0.0, 1.0]];
        for motion in [None, Some(rolling), Some(steep)] {
            let request = SensorRequest {
                config: SensorConfig::default(),
                seed: 9,
                frame_index: 4,
                intrinsics: [[100.0, 0.0, 64.0], [0.0, 100.0, cy as f64], [0.0, 0.0, 1.0]],
                camera_end_from_start: motion,
            };
            let (_, want) = request.run(Some(&converted.frame())).unwrap();
            let want = want.unwrap();
            assert!(want.stats.grazing > 0 && want.stats.shadow > 0 && want.stats.mixed > 0, "{:?}", want.stats);
            for _ in 0..3 {
                let (info, got) = request.run_renderer(&buffers).unwrap();
                assert_eq!((&got.depth_m, &got.rgb, got.stats), (&want.depth_m, &want.rgb, want.stats));
                assert_eq!(info.stats, Some(want.stats));
            }
        }
        let short = RendererBuffers { position: &position[4..], ..buffers };
        let request = SensorRequest {
            config: SensorConfig::default(),
            seed: 9,
            frame_index: 4,
            intrinsics: [[100.0, 0.0, 64.0], [0.0, 100.0, cy as f64], [0.0, 0.0, 1.0]],
            camera_end_from_start: None,
        };
        assert!(request.run_renderer(&short).unwrap_err().to_string().contains("position"));

        let segmentation: Vec<u32> = (0..w * h).map(|i| ((i % w) / 20 + (i / w) / 30) as u32).collect();
        let dropped_ids = [2u32, 5];
        let mut marked = position.clone();
        for (p, id) in marked.chunks_exact_mut(4).zip(&segmentation) {
            if dropped_ids.contains(id) {
                p[3] = 1.0;
            }
        }
        let with_ids = RendererBuffers { segmentation: &segmentation, dropped_ids: &dropped_ids, ..buffers };
        let marked = RendererBuffers { position: &marked, ..buffers };
        let (mut a, mut b) = (FrameBuffers::default(), FrameBuffers::default());
        with_ids.convert_into(&mut a).unwrap();
        marked.convert_into(&mut b).unwrap();
        assert_eq!((&a.points, &a.normals, &a.rgb), (&b.points, &b.normals, &b.rgb));
        assert_ne!(a.points, converted.points);
        for motion in [None, Some(rolling)] {
            let request = SensorRequest { camera_end_from_start: motion, ..request.clone() };
            let (_, want) = request.run_renderer(&marked).unwrap();
            let (_, got) = request.run_renderer(&with_ids).unwrap();
            assert_eq!((&got.depth_m, &got.rgb, got.stats), (&want.depth_m, &want.rgb, want.stats));
        }
        let short = RendererBuffers { segmentation: &segmentation[1..], ..with_ids };
        assert!(request.run_renderer(&short).unwrap_err().to_string().contains("segmentation"));
        let huge = RendererBuffers { dropped_ids: &[1 << 20], ..with_ids };
        assert!(request.run_renderer(&huge).unwrap_err().to_string().contains("dropped_ids"));
    }

    /// FNV-1a over every depth value's bits and every colour byte.
    fn output_hash(out: &SensorFrame) -> u64 {
        let bytes = out.depth_m.iter().flat_map(|v| v.to_bits().to_le_bytes()).chain(out.rgb.iter().copied());
        bytes.fold(0xcbf2_9ce4_8422_2325, |h, b| (h ^ u64::from(b)).wrapping_mul(0x100_0000_01b3))
    }

    #[test]
    fn bench_frame_outputs_are_unchanged() {
        // Every depth value and colour byte of the bench frame at rest, moving along the rows (the
        // bench's motion), rolling about the optical axis and moving steeply, on one and two
        // threads. A change of the model changes these hashes on purpose (update them then); a
        // change of speed alone must not.
        let cfg = SensorConfig::default();
        let scene = synthetic::TiltedTable::new();
        let unit = SensorUnit::draw(&cfg, scene.intrinsics, 3).unwrap();
        let mut steep = Matrix4::identity();
        steep.fixed_view_mut::<3, 3>(0, 0).copy_from(Rotation3::new(Vector3::new(0.03, 0.004, 0.0)).matrix());
        steep[(1, 3)] = 0.004;
        let exposure = cfg.colour.exposure_s;
        let cases = [
            (None, 0x85fa_23c6_77f3_ce35),
            (Some(synthetic::TiltedTable::motion(exposure)), 0x6a43_e60a_a567_4499),
            (Some(synthetic::TiltedTable::rolling_motion(exposure)), 0xd65a_fbe5_f40d_75c1),
            (Some(steep), 0xcbce_9799_3e63_bbf7),
        ];
        let mut got = vec![];
        for (motion, _) in cases {
            let one = simulate_frame_on(1, &cfg, &unit, &scene.frame(), None, motion.as_ref(), 7, 3).unwrap();
            let two = simulate_frame_on(2, &cfg, &unit, &scene.frame(), None, motion.as_ref(), 7, 3).unwrap();
            got.push((output_hash(&one), output_hash(&two)));
        }
        let want: Vec<(u64, u64)> = cases.iter().map(|(_, h)| (*h, *h)).collect();
        assert_eq!(got, want, "{:x?}", got);
    }

    #[test]
    fn renderer_buffers_convert_to_opencv_axes_and_bytes() {
        let (w, h) = (3usize, 4usize);
        let position: Vec<f32> =
            (0..w * h).flat_map(|i| [0.1 * i as f32, 0.2, -0.5, if i == 5 { 1.0 } else { 0.0 }]).collect();
        let normal: Vec<f32> = (0..w * h).flat_map(|_| [0.0, 0.6, 0.8, 0.0]).collect();
        let colour: Vec<f32> = (0..w * h).flat_map(|i| [-0.2, 0.5, 1.3, 1.0].map(|c| c + 0.001 * i as f32)).collect();
        let buffers = unsegmented(w, h, &position, &normal, &colour);
        let mut out = FrameBuffers::default();
        buffers.convert_into(&mut out).unwrap();
        assert_eq!(&out.points[..3], &[0.0, -0.2, 0.5]);
        assert_eq!(&out.points[15..18], &[0.0, 0.0, 0.0]); // pixel 5: nothing hit
        assert_eq!(&out.normals[..3], &[0.0, -0.6, -0.8]);
        assert_eq!(&out.rgb[..3], &[0, 128, 255]);
        assert_eq!((out.width, out.height, out.rgb.len()), (w, h, 3 * w * h));
        let short = RendererBuffers { normal: &normal[4..], ..buffers };
        assert!(short.convert_into(&mut out).unwrap_err().to_string().contains("normal"));
    }

    #[test]
    fn unit_draw_is_deterministic_per_seed() {
        let cfg = SensorConfig::default();
        let a = SensorUnit::draw(&cfg, nominal(), 7).unwrap();
        let b = SensorUnit::draw(&cfg, nominal(), 7).unwrap();
        let c = SensorUnit::draw(&cfg, nominal(), 8).unwrap();
        assert_eq!(a, b);
        assert_ne!(a.depth_scale, c.depth_scale);
        // Scale error within the 3-sigma clip, which is inside the datasheet's 2 %.
        for seed in 0..200 {
            let u = SensorUnit::draw(&cfg, nominal(), seed).unwrap();
            assert!((u.depth_scale - 1.0).abs() <= 3.0 * cfg.stereo.scale_sigma + 1e-12);
        }
    }

    #[test]
    fn scale_error_spread_matches_sigma() {
        let cfg = SensorConfig::default();
        let n = 2000;
        let v: Vec<f64> = (0..n).map(|s| SensorUnit::draw(&cfg, nominal(), s).unwrap().depth_scale - 1.0).collect();
        let rms = (v.iter().map(|x| x * x).sum::<f64>() / n as f64).sqrt();
        assert!((rms / cfg.stereo.scale_sigma - 1.0).abs() < 0.08, "rms {rms}");
    }

    #[test]
    fn bad_parameter_names_the_field() {
        let cfg =
            SensorConfig { stereo: StereoDepthConfig { baseline_m: -1.0, ..Default::default() }, ..Default::default() };
        let e = cfg.validate().unwrap_err();
        assert!(e.to_string().starts_with("camera.stereo.baseline_m"), "{e}");
        let cfg = SensorConfig {
            calibration: CalibrationConfig { extrinsic_rot_sigma_deg: f64::NAN, ..Default::default() },
            ..Default::default()
        };
        assert!(cfg.validate().unwrap_err().to_string().contains("extrinsic_rot_sigma_deg"));
    }
}
