//! Colour image: motion blur over the exposure, then shot + read noise.
//!
//! - **Motion blur**: frames are taken while the arm moves. Each pixel's image motion over the
//!   exposure is the displacement of its rendered surface point under the camera's motion
//!   `camera_end_from_start` (pixels without a surface use a point 10 m along their ray); the pixel
//!   becomes the mean of the rendered image sampled (nearest pixel) at evenly spaced points along
//!   that displacement, centred on the pixel, at most [`ColourConfig::max_blur_taps`] samples.
//!   The caller computes the motion from the joint velocities and
//!   [`ColourConfig::exposure_s`].
//! - **Noise**: Poissonian-Gaussian (Foi et al. 2008) on 8-bit values:
//!   `σ²(I) = shot_gain · I + read_noise²`, one draw per channel (the normal quantile of a 12-bit
//!   uniform, five per 64-bit draw, scaled to unit variance), rounded and clipped to 0-255.
//!
//! Not modelled: rolling shutter (the D435's colour imager has one), exposure and white-balance
//! changes, lens distortion and vignetting.

use super::{check, RenderedFrame, SensorError, SensorUnit, SplitMix64, TAG_COLOUR};
use nalgebra::Matrix4;
use serde::{Deserialize, Serialize};
use std::sync::OnceLock;

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
    /// Most samples along a pixel's blur path (longer paths are sampled more sparsely).
    pub max_blur_taps: usize,
}

impl Default for ColourConfig {
    fn default() -> Self {
        Self { exposure_s: 0.015, shot_gain: 0.03, read_noise: 1.0, max_blur_taps: 12 }
    }
}

impl ColourConfig {
    /// Range checks; errors name the field.
    pub fn validate(&self) -> Result<(), SensorError> {
        const R: &str = "outside its range (see the field's doc)";
        check("camera.colour.exposure_s", self.exposure_s, (0.0..=0.2).contains(&self.exposure_s), R)?;
        check("camera.colour.shot_gain", self.shot_gain, (0.0..=10.0).contains(&self.shot_gain), R)?;
        check("camera.colour.read_noise", self.read_noise, (0.0..=50.0).contains(&self.read_noise), R)?;
        check("camera.colour.max_blur_taps", self.max_blur_taps as f64, (1..=64).contains(&self.max_blur_taps), R)?;
        Ok(())
    }
}

/// Blur, then noise (module docs). `rgb` of `frame` must be non-empty.
pub fn colour_image(
    cfg: &ColourConfig,
    unit: &SensorUnit,
    frame: &RenderedFrame<'_>,
    camera_end_from_start: Option<&Matrix4<f64>>,
    seed: u64,
    frame_index: u64,
) -> Vec<u8> {
    let (w, h) = (frame.width, frame.height);
    let src = frame.rgb;
    let mut out = match camera_end_from_start {
        Some(m) if (m - Matrix4::identity()).abs().max() > 1e-9 => blur(cfg, unit, frame, m),
        _ => src.to_vec(),
    };
    if cfg.shot_gain > 0.0 || cfg.read_noise > 0.0 {
        let mut sigma = [0.0f32; 256];
        for (i, s) in sigma.iter_mut().enumerate() {
            *s = (cfg.shot_gain * i as f64 + cfg.read_noise * cfg.read_noise).sqrt() as f32;
        }
        let table = normal_table();
        let mut rng = SplitMix64::new(seed, &[TAG_COLOUR, frame_index]);
        // Five 12-bit quantile indices per 64-bit draw.
        let noisy = |v: &mut u8, r: u64| {
            let g = table[(r & 0xFFF) as usize];
            let x = *v as f32 + sigma[*v as usize] * g + 0.5;
            *v = x.clamp(0.0, 255.0) as u8;
        };
        let mut chunks = out[..3 * w * h].chunks_exact_mut(5);
        for chunk in &mut chunks {
            let r = rng.next_u64();
            for (k, v) in chunk.iter_mut().enumerate() {
                noisy(v, r >> (12 * k));
            }
        }
        let rest = chunks.into_remainder();
        if !rest.is_empty() {
            let r = rng.next_u64();
            for (k, v) in rest.iter_mut().enumerate() {
                noisy(v, r >> (12 * k));
            }
        }
    }
    out
}

/// Standard normal quantiles of the 4096 midpoints `(i + ½) / 4096`, rescaled to unit variance.
fn normal_table() -> &'static [f32; 4096] {
    static TABLE: OnceLock<[f32; 4096]> = OnceLock::new();
    TABLE.get_or_init(|| {
        let q: Vec<f64> = (0..4096).map(|i| inverse_normal_cdf((i as f64 + 0.5) / 4096.0)).collect();
        let sd = (q.iter().map(|v| v * v).sum::<f64>() / q.len() as f64).sqrt();
        let mut table = [0.0f32; 4096];
        for (t, v) in table.iter_mut().zip(&q) {
            *t = (v / sd) as f32;
        }
        table
    })
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

/// `(x + n / 2) / n` for `x < 2^16`, `1 <= n <= 64` by a multiply and a shift (exact: the
/// reciprocal's error stays below 1 / n over that range).
#[inline]
fn div_round(x: u32, n: u32, recip: u64) -> u8 {
    (((x + n / 2) as u64 * recip) >> 32) as u8
}

fn blur(cfg: &ColourConfig, unit: &SensorUnit, frame: &RenderedFrame<'_>, m: &Matrix4<f64>) -> Vec<u8> {
    const FAR_M: f64 = 10.0;
    let (w, h) = (frame.width, frame.height);
    let k = &unit.colour_true;
    let src = frame.rgb;
    let pts = frame.points_in_camera;
    let mut out = vec![0u8; 3 * w * h];
    // The three channels of each source pixel in 16-bit lanes of one word: a tap is one load and
    // one add (sums of at most 64 taps of 255 fit a lane).
    let packed: Vec<u64> =
        src.chunks_exact(3).map(|p| p[0] as u64 | (p[1] as u64) << 16 | (p[2] as u64) << 32).collect();
    let recip: Vec<u64> = (0..=64u64).map(|n| (1u64 << 32).checked_div(n).map_or(0, |q| q + 1)).collect();
    // Tap spacing as a share of the path, per tap count.
    let step_of: Vec<f64> = (0..=64usize).map(|n| 1.0 / n.saturating_sub(1).max(1) as f64).collect();
    let (r00, r01, r02) = (m[(0, 0)], m[(0, 1)], m[(0, 2)]);
    let (r10, r11, r12) = (m[(1, 0)], m[(1, 1)], m[(1, 2)]);
    let (r20, r21, r22) = (m[(2, 0)], m[(2, 1)], m[(2, 2)]);
    let (tx, ty, tz) = (m[(0, 3)], m[(1, 3)], m[(2, 3)]);
    // Ray direction (x / z, y / z, 1) of each pixel centre, rotated: r = rot · (ax, ay, 1).
    let ax: Vec<f64> = (0..w).map(|x| (x as f64 + 0.5 - k.cx) / k.fx).collect();
    let (wi, hi) = (w as i64 - 1, h as i64 - 1);
    // Per pixel of a row: depth along the ray, image motion (du, dv), its squared length and
    // length, the projected depth and the path's start in pixels × 2^16.
    let mut zs = vec![0.0f64; w];
    let [mut dus, mut dvs, mut len_sqs, mut lens, mut qzs, mut start_xs, mut start_ys] =
        [(); 7].map(|_| vec![0.0f64; w]);
    for y in 0..h {
        let ay = (y as f64 + 0.5 - k.cy) / k.fy;
        let (px, py, pz) = (r01 * ay + r02, r11 * ay + r12, r21 * ay + r22);
        // The motion of every pixel of the row first (no branches: the divisions and square roots
        // run on two pixels at a time), then its taps.
        for (zo, p) in zs.iter_mut().zip(pts[3 * y * w..3 * (y + 1) * w].chunks_exact(3)) {
            let zp = p[2] as f64;
            *zo = if zp.is_finite() && zp > 0.0 { zp } else { FAR_M };
        }
        for x in 0..w {
            let (z, ax_x) = (zs[x], ax[x]);
            let (rx, ry, rz) = (r00 * ax_x + px, r10 * ax_x + py, r20 * ax_x + pz);
            let qz = z * rz + tz;
            let inv = 1.0 / qz;
            let du = k.fx * ((z * rx + tx) * inv - ax_x);
            let dv = k.fy * ((z * ry + ty) * inv - ay);
            let len_sq = du * du + dv * dv;
            (dus[x], dvs[x], len_sqs[x], lens[x], qzs[x]) = (du, dv, len_sq, len_sq.sqrt(), qz);
            start_xs[x] = (x as f64 + 0.5 - 0.5 * du) * 65536.0;
            start_ys[x] = (y as f64 + 0.5 - 0.5 * dv) * 65536.0;
        }
        let row_out = &mut out[3 * y * w..3 * (y + 1) * w];
        let row_src = &src[3 * y * w..3 * (y + 1) * w];
        for (x, (o, s)) in row_out.chunks_exact_mut(3).zip(row_src.chunks_exact(3)).enumerate() {
            // Under half a pixel, or the surface behind the moved camera: the pixel stays.
            if qzs[x] <= 1e-6 || len_sqs[x] < 0.25 {
                o.copy_from_slice(s);
                continue;
            }
            // Whole pixels of the path's length (a NaN length counts as 0).
            let whole = if lens[x] >= 64.0 { 64 } else { lens[x] as i32 as usize };
            let taps = (whole + 2).min(cfg.max_blur_taps).max(2);
            // Fixed point 16.16 along the path from −½ to +½ of the motion, centred on the pixel.
            let step = step_of[taps];
            let (mut fx, mut fy) = (start_xs[x] as i64, start_ys[x] as i64);
            let (sx, sy) = ((dus[x] * step * 65536.0) as i64, (dvs[x] * step * 65536.0) as i64);
            let mut acc = 0u64;
            // The path is a line: inside the image at both ends means inside throughout; on one
            // row at both ends, on that row throughout.
            let (ex, ey) = (fx + (taps as i64 - 1) * sx, fy + (taps as i64 - 1) * sy);
            let inside = |a: i64, b: i64, hi: i64| (0..=hi).contains(&(a >> 16)) && (0..=hi).contains(&(b >> 16));
            if inside(fx, ex, wi) && inside(fy, ey, hi) {
                if fy >> 16 == ey >> 16 {
                    let row = &packed[(fy >> 16) as usize * w..][..w];
                    for _ in 0..taps {
                        acc += row[(fx >> 16) as usize];
                        fx += sx;
                    }
                } else {
                    for _ in 0..taps {
                        acc += packed[(fy >> 16) as usize * w + (fx >> 16) as usize];
                        fx += sx;
                        fy += sy;
                    }
                }
            } else {
                for _ in 0..taps {
                    acc += packed[(fy >> 16).clamp(0, hi) as usize * w + (fx >> 16).clamp(0, wi) as usize];
                    fx += sx;
                    fy += sy;
                }
            }
            let (n, rc) = (taps as u32, recip[taps]);
            o[0] = div_round((acc & 0xFFFF) as u32, n, rc);
            o[1] = div_round((acc >> 16 & 0xFFFF) as u32, n, rc);
            o[2] = div_round((acc >> 32 & 0xFFFF) as u32, n, rc);
        }
    }
    out
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
    fn rounded_division_by_reciprocal_is_exact() {
        for n in 1..=64u32 {
            let recip = (1u64 << 32) / n as u64 + 1;
            for x in 0..=255 * n {
                assert_eq!(u32::from(div_round(x, n, recip)), (x + n / 2) / n, "{x} / {n}");
            }
        }
    }

    #[test]
    fn blur_spreads_an_edge_along_the_motion() {
        let cfg = ColourConfig { shot_gain: 0.0, read_noise: 0.0, ..Default::default() };
        let (p, n) = plane(0.5);
        // A vertical edge: left half black, right half white.
        let mut rgb = vec![0u8; 3 * W * H];
        for y in 0..H {
            for x in W / 2..W {
                rgb[3 * (y * W + x)..3 * (y * W + x) + 3].fill(255);
            }
        }
        let f = RenderedFrame { width: W, height: H, points_in_camera: &p, normals_in_camera: &n, rgb: &rgb };
        // Camera moves 2.3 cm along x over the exposure: scene shifts 108 · 0.023 / 0.5 ≈ 5 px.
        let mut m = Matrix4::identity();
        m[(0, 3)] = -0.023;
        let out = colour_image(&cfg, &unit(), &f, Some(&m), 1, 0);
        let row = 60;
        let grey: Vec<usize> =
            (0..W).filter(|&x| out[3 * (row * W + x)] > 10 && out[3 * (row * W + x)] < 245).collect();
        assert!((3..=6).contains(&grey.len()), "blurred band {grey:?}");
        // Vertical motion does not blur a vertical edge.
        let mut m = Matrix4::identity();
        m[(1, 3)] = -0.023;
        let out = colour_image(&cfg, &unit(), &f, Some(&m), 1, 0);
        assert!((0..W).all(|x| out[3 * (row * W + x)] == rgb[3 * (row * W + x)]));
    }
}
