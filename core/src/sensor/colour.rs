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
//!   `σ²(I) = shot_gain · I + read_noise²`, one draw per channel (a sum of four uniforms: unit
//!   variance, tails cut at 3.5 σ), rounded and clipped to 0-255.
//!
//! Not modelled: rolling shutter (the D435's colour imager has one), exposure and white-balance
//! changes, lens distortion and vignetting.

use super::{check, RenderedFrame, SensorError, SensorUnit, SplitMix64, TAG_COLOUR};
use nalgebra::{Matrix4, Vector4};
use serde::{Deserialize, Serialize};

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
        let sigma: Vec<f32> =
            (0..256).map(|i| (cfg.shot_gain * i as f64 + cfg.read_noise * cfg.read_noise).sqrt() as f32).collect();
        let mut rng = SplitMix64::new(seed, &[TAG_COLOUR, frame_index]);
        for v in out.iter_mut().take(3 * w * h) {
            let x = *v as f32 + sigma[*v as usize] * rng.approx_normal();
            *v = x.round().clamp(0.0, 255.0) as u8;
        }
    }
    out
}

fn blur(cfg: &ColourConfig, unit: &SensorUnit, frame: &RenderedFrame<'_>, m: &Matrix4<f64>) -> Vec<u8> {
    let (w, h) = (frame.width, frame.height);
    let k = &unit.colour_true;
    let src = frame.rgb;
    let pts = frame.points_in_camera;
    let mut out = vec![0u8; 3 * w * h];
    let far = 10.0;
    for y in 0..h {
        for x in 0..w {
            let i = y * w + x;
            let zp = pts[3 * i + 2];
            let p = if zp.is_finite() && zp > 0.0 {
                Vector4::new(pts[3 * i] as f64, pts[3 * i + 1] as f64, zp as f64, 1.0)
            } else {
                Vector4::new((x as f64 + 0.5 - k.cx) / k.fx * far, (y as f64 + 0.5 - k.cy) / k.fy * far, far, 1.0)
            };
            let q = m * p;
            let (du, dv) =
                if q.z > 1e-6 { (k.fx * (q.x / q.z - p.x / p.z), k.fy * (q.y / q.z - p.y / p.z)) } else { (0.0, 0.0) };
            let len = (du * du + dv * dv).sqrt();
            let taps = ((len.ceil() as usize) + 1).min(cfg.max_blur_taps);
            if taps <= 1 || len < 0.5 {
                out[3 * i..3 * i + 3].copy_from_slice(&src[3 * i..3 * i + 3]);
                continue;
            }
            let mut acc = [0u32; 3];
            for t in 0..taps {
                let s = t as f64 / (taps - 1) as f64 - 0.5;
                let sx = (x as f64 + s * du).round().clamp(0.0, (w - 1) as f64) as usize;
                let sy = (y as f64 + s * dv).round().clamp(0.0, (h - 1) as f64) as usize;
                let j = 3 * (sy * w + sx);
                acc[0] += src[j] as u32;
                acc[1] += src[j + 1] as u32;
                acc[2] += src[j + 2] as u32;
            }
            let n = taps as u32;
            for c in 0..3 {
                out[3 * i + c] = ((acc[c] + n / 2) / n) as u8;
            }
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
