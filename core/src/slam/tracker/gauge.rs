//! The world ← map gauge: the rigid transform that aligns the SLAM map frame to the world, fitted
//! to every view's mean kinematic prior (see [`super::TrackerConfig::anchor_to_prior_mean`]).

use std::collections::BTreeMap;

use nalgebra::{Matrix3, Rotation3, Translation3, UnitQuaternion, Vector3};

use crate::geometry::Se3;
use crate::slam::noise::PriorNoiseConfig;

/// Per-view running sums of the world ← map gauge (see [`TrackerConfig::anchor_to_prior_mean`]).
#[derive(Debug, Clone, Copy)]
struct ViewSums {
    /// Σ R(prior_i) R(map_from_camera_i)ᵀ over the view's tracked frames.
    rotation_sum: Matrix3<f64>,
    /// Σ prior camera centres.
    prior_center_sum: Vector3<f64>,
    /// Σ SLAM (map-frame) camera centres.
    map_center_sum: Vector3<f64>,
    n: f64,
    /// The rotation closest to `rotation_sum / n` (updated on add).
    mean_rotation: Option<UnitQuaternion<f64>>,
}

/// The world ← map gauge: a weighted robust least-squares fit of one rigid transform to every
/// view's mean kinematic prior (one term per view, since the bias is per view).
#[derive(Debug, Clone)]
pub(super) struct Anchor {
    views: BTreeMap<u64, ViewSums>,
    /// Per-axis standard deviation of a view's mean camera-centre prior, metres.
    sigma_t: f64,
    /// Per-axis standard deviation of a view's mean rotation prior, radians.
    sigma_r: f64,
    /// Huber width on a view's whitened 6-DoF residual norm.
    huber: f64,
    /// Cached estimate (also the warm start of the next fit).
    world_from_map: Se3,
    /// Whether `world_from_map` holds a fit.
    solved: bool,
}

impl Anchor {
    pub(super) fn new(noise: &PriorNoiseConfig, huber: f64) -> Self {
        // A view's mean prior is off by the view's bias (uniform direction, fixed size: per-axis
        // variance size² / 3) plus averaged jitter; the floor keeps the weights finite.
        let sigma_t = (noise.bias_trans_m.powi(2) / 3.0 + noise.jitter_trans_m.powi(2)).sqrt().max(1e-5);
        let sigma_r = (noise.bias_rot_deg.to_radians().powi(2) / 3.0 + noise.jitter_rot_deg.to_radians().powi(2))
            .sqrt()
            .max(1e-5);
        Self { views: BTreeMap::new(), sigma_t, sigma_r, huber, world_from_map: Se3::identity(), solved: false }
    }

    pub(super) fn add(&mut self, world_from_camera_prior: &Se3, map_from_camera: &Se3, view_index: u64) {
        let d = world_from_camera_prior.rotation * map_from_camera.rotation.inverse();
        let v = self.views.entry(view_index).or_insert(ViewSums {
            rotation_sum: Matrix3::zeros(),
            prior_center_sum: Vector3::zeros(),
            map_center_sum: Vector3::zeros(),
            n: 0.0,
            mean_rotation: None,
        });
        v.rotation_sum += d.to_rotation_matrix().matrix();
        v.prior_center_sum += world_from_camera_prior.translation.vector;
        v.map_center_sum += map_from_camera.translation.vector;
        v.n += 1.0;
        v.mean_rotation = project_rotation(&(v.rotation_sum / v.n));
        self.world_from_map = self.solve();
        self.solved = true;
    }

    pub(super) fn world_from_map(&self) -> Se3 {
        self.world_from_map
    }

    /// Per view: (mean rotation residual target R̄_v, mean prior centre, mean map centre).
    fn view_means(&self) -> Vec<(UnitQuaternion<f64>, Vector3<f64>, Vector3<f64>)> {
        self.views
            .values()
            .filter(|v| v.n > 0.0)
            .filter_map(|v| Some((v.mean_rotation?, v.prior_center_sum / v.n, v.map_center_sum / v.n)))
            .collect()
    }

    fn solve(&self) -> Se3 {
        let means = self.view_means();
        if means.is_empty() {
            return Se3::identity();
        }
        // Start: the previous fit (one frame moves it little), else the chordal mean of the view
        // rotations and the centroid of the view centres.
        let (mut rot, mut t) = if self.solved {
            (self.world_from_map.rotation, self.world_from_map.translation.vector)
        } else {
            let mut rsum = Matrix3::zeros();
            for (r, _, _) in &means {
                rsum += r.to_rotation_matrix().matrix();
            }
            let Some(rot) = project_rotation(&rsum) else {
                return Se3::identity();
            };
            let n = means.len() as f64;
            let cp: Vector3<f64> = means.iter().map(|m| m.1).sum::<Vector3<f64>>() / n;
            let cm: Vector3<f64> = means.iter().map(|m| m.2).sum::<Vector3<f64>>() / n;
            (rot, cp - rot * cm)
        };
        // Gauss-Newton with Huber weights per view. Unknowns: δθ (left rotation increment), δt.
        // Residuals per view: e_t = c̄P − (R c̄M + t), e_r = log(R̄_v Rᵀ), whitened by σ_t, σ_r.
        for _ in 0..8 {
            let mut h = nalgebra::Matrix6::<f64>::zeros();
            let mut b = nalgebra::Vector6::<f64>::zeros();
            for (rv, pc, mc) in &means {
                let rm = rot * mc;
                let et = (pc - rm - t) / self.sigma_t;
                let er = (rv * rot.inverse()).scaled_axis() / self.sigma_r;
                let norm = (et.norm_squared() + er.norm_squared()).sqrt();
                let w = if norm <= self.huber { 1.0 } else { self.huber / norm };
                // d e_t / d δθ = [R c̄M]ₓ / σ_t, d e_t / d δt = −I / σ_t; d e_r / d δθ ≈ −I / σ_r.
                let mut j = nalgebra::Matrix6::<f64>::zeros();
                j.fixed_view_mut::<3, 3>(0, 0).copy_from(&(rm.cross_matrix() / self.sigma_t));
                j.fixed_view_mut::<3, 3>(0, 3).copy_from(&(-Matrix3::identity() / self.sigma_t));
                j.fixed_view_mut::<3, 3>(3, 0).copy_from(&(-Matrix3::identity() / self.sigma_r));
                let mut e = nalgebra::Vector6::<f64>::zeros();
                e.fixed_rows_mut::<3>(0).copy_from(&et);
                e.fixed_rows_mut::<3>(3).copy_from(&er);
                h += j.transpose() * j * w;
                b -= j.transpose() * e * w;
            }
            let Some(dx) = h.cholesky().map(|c| c.solve(&b)) else {
                break;
            };
            let dth = Vector3::new(dx[0], dx[1], dx[2]);
            let dt = Vector3::new(dx[3], dx[4], dx[5]);
            let dr = UnitQuaternion::from_scaled_axis(dth);
            // Left increment of the rotation: R ← exp(δθ) R, t ← t + δt (the residual model
            // above linearises exp(δθ) R c̄M ≈ R c̄M + δθ × R c̄M).
            rot = dr * rot;
            t += dt;
            if dth.norm() < 1e-9 && dt.norm() < 1e-9 {
                break;
            }
        }
        Se3::from_parts(Translation3::from(t), rot)
    }
}

/// The rotation closest (Frobenius) to a 3x3 matrix, or None if it is degenerate.
fn project_rotation(m: &Matrix3<f64>) -> Option<UnitQuaternion<f64>> {
    let svd = m.svd(true, true);
    let (u, v_t) = (svd.u?, svd.v_t?);
    let mut fix = Matrix3::identity();
    fix[(2, 2)] = (u * v_t).determinant().signum();
    let r = u * fix * v_t;
    Some(UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r)))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::se3_from_yaw;
    use crate::slam::tracker::TrackerConfig;

    /// A perfectly consistent SLAM map (`map_from_camera = map_from_world · gt`) seen through
    /// per-view biased priors, views with very unequal frame counts.
    fn fit(n_views: u64, outlier: Option<u64>) -> (Se3, Se3, Vec<(Se3, u64)>) {
        let noise = PriorNoiseConfig::default(); // 1 cm / 1° per view
        let robot = crate::slam::noise::SyntheticPriorError::new(noise, 1);
        let mut anchor = Anchor::new(&noise, TrackerConfig::default().anchor_huber);
        let map_from_world = se3_from_yaw(Vector3::new(0.3, -0.2, 0.1), 0.7);
        let mut frames = Vec::new();
        for v in 0..n_views {
            // Views of 1..=25 frames on an arc over the table.
            for f in 0..(1 + (v * 7) % 25) {
                let a = 0.3 * v as f64 + 0.01 * f as f64;
                let eye = nalgebra::Point3::new(0.45 + 0.25 * a.cos(), 0.25 * a.sin(), 0.4 + 0.05 * (a * 3.0).sin());
                let gt = crate::slam::synthetic::look_at(eye, nalgebra::Point3::new(0.5, 0.0, 0.0));
                let mut prior = robot.perturb(&gt, v, v * 100 + f);
                if outlier == Some(v) {
                    // A view whose SLAM poses are 8 cm off its prior (e.g. a bad re-localisation).
                    prior = Se3::translation(0.08, 0.0, 0.0) * prior;
                }
                anchor.add(&prior, &(map_from_world * gt), v);
                frames.push((gt, v));
            }
        }
        (anchor.world_from_map(), map_from_world.inverse(), frames)
    }

    /// ATE of the camera centres expressed with the estimated world ← map.
    fn ate(est: &Se3, frames: &[(Se3, u64)], map_from_world: &Se3) -> f64 {
        let s: f64 = frames
            .iter()
            .map(|(gt, _)| ((est * map_from_world * gt).translation.vector - gt.translation.vector).norm_squared())
            .sum();
        (s / frames.len() as f64).sqrt()
    }

    #[test]
    fn the_gauge_averages_per_view_biases_below_the_bias() {
        for n_views in [4u64, 9, 16] {
            let (est, truth, frames) = fit(n_views, None);
            let map_from_world = truth.inverse();
            let e = ate(&est, &frames, &map_from_world);
            // Independent 1 cm biases: the mean of n views is off by ≈ 1 cm / √n (RMS); allow 2x.
            let bound = 0.01 * 2.0 / (n_views as f64).sqrt();
            eprintln!("{n_views} views: ATE {:.2} mm (bound {:.2} mm)", e * 1e3, bound * 1e3);
            assert!(e < bound.min(0.008), "{n_views} views: ATE {e}");
        }
        // Many views: well below the 1 cm bias (≈ 2.5 mm expected).
        let (est, truth, frames) = fit(16, None);
        assert!(ate(&est, &frames, &truth.inverse()) < 0.005);
    }

    #[test]
    fn one_wrong_view_is_down_weighted() {
        let (clean, truth, frames) = fit(12, None);
        let (robust, _, _) = fit(12, Some(3));
        let mfw = truth.inverse();
        let (e_clean, e_robust) = (ate(&clean, &frames, &mfw), ate(&robust, &frames, &mfw));
        eprintln!("ATE clean {:.2} mm, with an 8 cm outlier view {:.2} mm", e_clean * 1e3, e_robust * 1e3);
        // Unweighted, the outlier would move the gauge by 8 cm / 12 ≈ 6.7 mm.
        assert!(e_robust < e_clean + 0.004, "{e_clean} -> {e_robust}");
    }
}
