//! The estimator's assumed error of the kinematic camera-pose prior.
//!
//! The tracker receives the prior as it is (forward kinematics of the robot's nominal model on
//! its joint readings: whatever error the real robot has is already in it) and never perturbs it.
//! [`PriorNoiseConfig`] is what the estimator *believes* about that error: it sets the weights of
//! the world ← map gauge fit ([`super::TrackerConfig::anchor_to_prior_mean`]) and the sizes of the
//! prior and motion gates. It is a tuning choice of the estimator and need not equal the error of
//! the robot it runs on (in the simulator that error is the `[robot]` model of `objslam.calibration`).
//!
//! [`SyntheticPriorError`] makes a noisy prior for the core's own tests and benchmarks (a seeded
//! per-view bias and per-frame jitter); the tracker never uses it.

use nalgebra::{Translation3, UnitQuaternion, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::geometry::Se3;

/// The estimator's assumed size of the kinematic prior's error, in the camera frame. The model
/// behind it: a part that is constant over a view (calibration error of the arm's configuration
/// during one move) and a part drawn per frame.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PriorNoiseConfig {
    /// Assumed translation error constant over a view, metres (its magnitude; default 0.01).
    /// Sets the gauge fit's per-view weight (per-axis σ = size / √3) and the prior gate.
    pub bias_trans_m: f64,
    /// Assumed rotation error constant over a view, degrees (its angle; default 1.0).
    pub bias_rot_deg: f64,
    /// Assumed per-frame translation error, standard deviation per axis, metres (default 0.0005).
    pub jitter_trans_m: f64,
    /// Assumed per-frame rotation error, standard deviation per axis of the rotation vector,
    /// degrees (default 0.05).
    pub jitter_rot_deg: f64,
}

impl Default for PriorNoiseConfig {
    fn default() -> Self {
        Self { bias_trans_m: 0.01, bias_rot_deg: 1.0, jitter_trans_m: 0.0005, jitter_rot_deg: 0.05 }
    }
}

impl PriorNoiseConfig {
    /// No error assumed (the gates fall back to their floors, the gauge weights to 1e-5).
    pub fn none() -> Self {
        Self { bias_trans_m: 0.0, bias_rot_deg: 0.0, jitter_trans_m: 0.0, jitter_rot_deg: 0.0 }
    }

    /// A config error naming the first negative or non-finite field (`prefix` + field name).
    pub(crate) fn validate(&self) -> Result<(), (&'static str, f64)> {
        for (field, v) in [
            ("prior_noise.bias_trans_m", self.bias_trans_m),
            ("prior_noise.bias_rot_deg", self.bias_rot_deg),
            ("prior_noise.jitter_trans_m", self.jitter_trans_m),
            ("prior_noise.jitter_rot_deg", self.jitter_rot_deg),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err((field, v));
            }
        }
        Ok(())
    }
}

/// A seeded stand-in for a robot's prior error, for the core's tests and benchmarks only: the
/// prior of frame `f` in view `v` is `world_from_camera_true · bias(v) · jitter(f)`, the bias of
/// fixed size in a direction uniform on the sphere, the jitter Gaussian per axis.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SyntheticPriorError {
    /// Sizes of the bias and jitter (same meaning as for the estimator's assumption).
    pub size: PriorNoiseConfig,
    /// Seed; the bias of view `v` and the jitter of frame `f` depend only on (seed, v) and
    /// (seed, f), never on call order.
    pub seed: u64,
}

impl SyntheticPriorError {
    /// Errors of `size`, seeded.
    pub fn new(size: PriorNoiseConfig, seed: u64) -> Self {
        Self { size, seed }
    }

    /// The camera-frame bias of view `view_index`.
    pub fn bias(&self, view_index: u64) -> Se3 {
        let mut rng = stream(self.seed, 0xB1A5, view_index);
        let t = unit_vector(&mut rng) * self.size.bias_trans_m;
        let axis = unit_vector(&mut rng);
        let r = UnitQuaternion::from_scaled_axis(axis * self.size.bias_rot_deg.to_radians());
        Se3::from_parts(Translation3::from(t), r)
    }

    /// The camera-frame jitter of frame `frame_index`.
    pub fn jitter(&self, frame_index: u64) -> Se3 {
        let mut rng = stream(self.seed, 0x7177, frame_index);
        let t = Vector3::new(gauss(&mut rng), gauss(&mut rng), gauss(&mut rng)) * self.size.jitter_trans_m;
        let w = Vector3::new(gauss(&mut rng), gauss(&mut rng), gauss(&mut rng)) * self.size.jitter_rot_deg.to_radians();
        Se3::from_parts(Translation3::from(t), UnitQuaternion::from_scaled_axis(w))
    }

    /// The noisy prior: `world_from_camera_true · bias(view) · jitter(frame)`.
    pub fn perturb(&self, world_from_camera_true: &Se3, view_index: u64, frame_index: u64) -> Se3 {
        world_from_camera_true * self.bias(view_index) * self.jitter(frame_index)
    }
}

fn stream(seed: u64, tag: u64, index: u64) -> ChaCha8Rng {
    let mut s = seed ^ tag.rotate_left(32);
    let a = super::synthetic::splitmix64(&mut s);
    let mut s2 = a ^ index;
    ChaCha8Rng::seed_from_u64(super::synthetic::splitmix64(&mut s2))
}

fn gauss(rng: &mut ChaCha8Rng) -> f64 {
    let u1: f64 = rng.random::<f64>().max(1e-300);
    let u2: f64 = rng.random();
    (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
}

fn unit_vector(rng: &mut ChaCha8Rng) -> Vector3<f64> {
    loop {
        let v = Vector3::new(gauss(rng), gauss(rng), gauss(rng));
        let n = v.norm();
        if n > 1e-9 {
            return v / n;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bias_has_the_configured_size_and_is_order_independent() {
        let c = SyntheticPriorError::new(PriorNoiseConfig::default(), 1);
        for v in 0..20 {
            let b = c.bias(v);
            assert!((b.translation.vector.norm() - 0.01).abs() < 1e-12);
            assert!((b.rotation.angle().to_degrees() - 1.0).abs() < 1e-9);
        }
        assert_eq!(c.bias(3), c.bias(3));
        assert_ne!(c.bias(3), c.bias(4));
        let none = SyntheticPriorError::new(PriorNoiseConfig::none(), 0);
        let p = crate::geometry::se3_from_yaw(Vector3::new(0.1, 0.2, 0.3), 0.4);
        assert!((none.perturb(&p, 5, 9).to_homogeneous() - p.to_homogeneous()).norm() < 1e-12);
    }

    #[test]
    fn jitter_statistics_match_the_configured_sigma() {
        let size = PriorNoiseConfig { jitter_trans_m: 0.001, ..PriorNoiseConfig::default() };
        let c = SyntheticPriorError::new(size, 1);
        let n = 4000;
        let var: f64 = (0..n).map(|f| c.jitter(f).translation.vector.norm_squared()).sum::<f64>() / (3 * n) as f64;
        // Per-axis standard deviation within 5 % of 1 mm (4000 x 3 samples).
        assert!((var.sqrt() - 0.001).abs() < 5e-5, "sigma {}", var.sqrt());
    }

    #[test]
    fn a_negative_size_names_its_field() {
        let bad = PriorNoiseConfig { bias_rot_deg: -1.0, ..PriorNoiseConfig::default() };
        assert_eq!(bad.validate().map_err(|e| e.0), Err("prior_noise.bias_rot_deg"));
    }
}
