//! Camera pose from 2D–3D correspondences (with optional depth): robust Gauss-Newton refinement
//! (Huber) and RANSAC over prior-seeded 3-point minimal sets.
//!
//! Residual of a correspondence (pixels, predicted − measured, scaled by `1 / sigma_px`):
//! `(u − u_m, v − v_m)` and, when the keypoint has depth, a third "disparity" term
//! `bf / z − bf / z_m` with `bf = fx · depth_baseline_m` (ORB-SLAM2's RGB-D virtual stereo residual
//! in spirit). Inlier tests are χ² tests with 2 or 3 degrees of freedom at 95 % (5.991 / 7.815,
//! ORB-SLAM2), Huber widths are their square roots.
//!
//! Minimal solver (choice, documented in the module docs): since tracking always has a pose prior
//! within a few cm / degrees, each RANSAC hypothesis is the prior refined by Gauss-Newton on a
//! random set of 3 correspondences (6–9 equations, 6 unknowns). This avoids P3P's root selection
//! and converges in a few iterations from such priors; the prior itself is scored as hypothesis 0.

use nalgebra::{Matrix3, Matrix6, Point3, Vector3, Vector6};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use super::SlamError;
use crate::geometry::{PinholeCamera, Se3};

/// χ² at 95 % with 2 degrees of freedom (pixel residual).
pub const CHI2_2DOF: f64 = 5.991;
/// χ² at 95 % with 3 degrees of freedom (pixel + disparity residual).
pub const CHI2_3DOF: f64 = 7.815;

/// A 2D–3D correspondence.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Correspondence {
    /// The 3D point, world (or map) frame, metres.
    pub p_in_world: Point3<f64>,
    /// Its observed pixel (level-0 pixels).
    pub pixel: [f64; 2],
    /// Measured depth of the keypoint, metres, if any.
    pub depth_m: Option<f64>,
    /// Standard deviation of the pixel measurement (ORB-SLAM2: the level's scale), pixels.
    pub sigma_px: f64,
}

/// Configuration of robust pose refinement.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PoseRefineConfig {
    /// Virtual stereo baseline for the depth residual, metres (ORB-SLAM2 RGB-D: `bf / fx` ≈
    /// 0.08). Larger trusts depth more; 0 ignores depth.
    pub depth_baseline_m: f64,
    /// Gauss-Newton iterations per round (ORB-SLAM2: 10).
    pub iterations: usize,
    /// Rounds of (optimise, re-classify outliers by χ²) (ORB-SLAM2: 4).
    pub rounds: usize,
}

impl Default for PoseRefineConfig {
    fn default() -> Self {
        Self { depth_baseline_m: 0.08, iterations: 10, rounds: 4 }
    }
}

/// Configuration of RANSAC.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RansacConfig {
    /// Maximum number of hypotheses (adaptive stopping may use fewer).
    pub max_iterations: usize,
    /// Stop once P(an all-inlier sample was drawn) reaches this.
    pub confidence: f64,
    /// Fewer inliers than this is a failure (ORB-SLAM2 tracking: 10–30).
    pub min_inliers: usize,
    /// Gauss-Newton iterations of the minimal solver.
    pub minimal_iterations: usize,
    /// Seed of the sample generator (the tracker mixes in the frame index).
    pub seed: u64,
}

impl Default for RansacConfig {
    fn default() -> Self {
        Self { max_iterations: 200, confidence: 0.999, min_inliers: 15, minimal_iterations: 8, seed: 7 }
    }
}

/// A pose estimate and which correspondences it explains.
#[derive(Debug, Clone, PartialEq)]
pub struct PoseEstimate {
    /// Estimated camera pose.
    pub world_from_camera: Se3,
    /// Inlier flag per correspondence.
    pub inliers: Vec<bool>,
    /// Number of inliers.
    pub n_inliers: usize,
}

/// Residual (whitened, predicted − measured) and its Jacobian w.r.t. the point in the camera frame.
/// Returns `None` behind the camera. The third row is zero without depth.
#[inline]
pub(crate) fn residual(
    camera: &PinholeCamera,
    bf: f64,
    p_in_camera: &Vector3<f64>,
    pixel: [f64; 2],
    depth_m: Option<f64>,
    sigma_px: f64,
) -> Option<(Vector3<f64>, Matrix3<f64>, bool)> {
    let z = p_in_camera.z;
    if z <= 1e-6 {
        return None;
    }
    let iz = 1.0 / z;
    let s = 1.0 / sigma_px.max(1e-9);
    let (x, y) = (p_in_camera.x, p_in_camera.y);
    let mut e = Vector3::new(
        (camera.fx * x * iz + camera.cx - pixel[0]) * s,
        (camera.fy * y * iz + camera.cy - pixel[1]) * s,
        0.0,
    );
    let mut j = Matrix3::new(
        camera.fx * iz * s,
        0.0,
        -camera.fx * x * iz * iz * s,
        0.0,
        camera.fy * iz * s,
        -camera.fy * y * iz * iz * s,
        0.0,
        0.0,
        0.0,
    );
    let has_depth = match depth_m {
        Some(d) if d > 1e-6 && bf > 0.0 => {
            e.z = (bf * iz - bf / d) * s;
            j[(2, 2)] = -bf * iz * iz * s;
            true
        }
        _ => false,
    };
    Some((e, j, has_depth))
}

/// χ² threshold for a residual with or without depth.
#[inline]
pub(crate) fn chi2_threshold(has_depth: bool) -> f64 {
    if has_depth {
        CHI2_3DOF
    } else {
        CHI2_2DOF
    }
}

/// Huber weight for a squared whitened residual `chi2` with width² `delta2`.
#[inline]
pub(crate) fn huber_weight(chi2: f64, delta2: f64) -> f64 {
    if chi2 <= delta2 {
        1.0
    } else {
        huber_down_weight(chi2, delta2)
    }
}

/// The weight of a residual beyond the Huber width. Out of line so that the common inlier case
/// is a branch, not a division and a square root computed and discarded.
#[cold]
#[inline(never)]
fn huber_down_weight(chi2: f64, delta2: f64) -> f64 {
    (delta2 / chi2).sqrt()
}

/// Left-multiply an increment `(ω, v)` onto `camera_from_world`.
pub(crate) fn apply_increment(camera_from_world: &Se3, delta: &Vector6<f64>) -> Se3 {
    let omega = Vector3::new(delta[0], delta[1], delta[2]);
    let v = Vector3::new(delta[3], delta[4], delta[5]);
    let inc = Se3::from_parts(nalgebra::Translation3::from(v), nalgebra::UnitQuaternion::from_scaled_axis(omega));
    inc * camera_from_world
}

/// Rows of `j · [−[x]×, I]`, the whitened residual's Jacobian w.r.t. a left increment `(ω, v)`
/// of the pose, for a [`residual`] Jacobian `j` (zero but for its entries (0, 0), (0, 2), (1, 1),
/// (1, 2), (2, 2)) at the camera-frame point `x`, written out; the third row is zero without depth.
#[inline]
pub(crate) fn pose_jacobian_rows(j: &Matrix3<f64>, x: &Vector3<f64>) -> [[f64; 6]; 3] {
    let (a, c, d, f, g) = (j[(0, 0)], j[(0, 2)], j[(1, 1)], j[(1, 2)], j[(2, 2)]);
    let (px, py, pz) = (x.x, x.y, x.z);
    [
        [c * py, a * pz - c * px, -a * py, a, 0.0, c],
        [f * py - d * pz, -f * px, d * px, 0.0, d, f],
        [g * py, -g * px, 0.0, 0.0, 0.0, g],
    ]
}

/// Gauss-Newton normal equations of a 6-DoF pose, accumulated upper triangle first
/// ([`NormalEquations6::add`]), then [`NormalEquations6::system`].
#[derive(Debug, Clone, Copy)]
pub(crate) struct NormalEquations6 {
    /// Row-major 6x6, upper triangle filled.
    h: [f64; 36],
    b: [f64; 6],
}

impl NormalEquations6 {
    pub(crate) fn new() -> Self {
        Self { h: [0.0; 36], b: [0.0; 6] }
    }

    /// Add `w Jᵀ J` and `−w Jᵀ e` for the first `n_rows` rows of `rows` (J) and `e`.
    #[inline]
    pub(crate) fn add(&mut self, rows: &[[f64; 6]; 3], e: &Vector3<f64>, w: f64, n_rows: usize) {
        for (r, &er) in rows.iter().zip(e.iter()).take(n_rows) {
            let wr: [f64; 6] = std::array::from_fn(|k| w * r[k]);
            for (i, (&wi, b)) in wr.iter().zip(self.b.iter_mut()).enumerate() {
                *b -= wi * er;
                for (h, &rk) in self.h[i * 6 + i..i * 6 + 6].iter_mut().zip(&r[i..]) {
                    *h += wi * rk;
                }
            }
        }
    }

    /// The full symmetric `H` and `b`.
    pub(crate) fn system(&self) -> (Matrix6<f64>, Vector6<f64>) {
        let h = Matrix6::from_fn(|i, k| if i <= k { self.h[i * 6 + k] } else { self.h[k * 6 + i] });
        (h, Vector6::from_column_slice(&self.b))
    }
}

/// `camera_from_world` as a rotation matrix and a translation (cheaper per point than the
/// quaternion).
#[inline]
pub(crate) fn rigid_parts(camera_from_world: &Se3) -> (Matrix3<f64>, Vector3<f64>) {
    (*camera_from_world.rotation.to_rotation_matrix().matrix(), camera_from_world.translation.vector)
}

/// Gauss-Newton on the selected correspondences (Huber if `robust`), from `camera_from_world`.
/// Returns the refined pose, or `None` if the normal equations are singular or the result is not
/// finite.
fn gauss_newton(
    corr: &[Correspondence],
    selected: &mut dyn Iterator<Item = usize>,
    camera: &PinholeCamera,
    bf: f64,
    camera_from_world: Se3,
    iterations: usize,
    robust: bool,
) -> Option<Se3> {
    let idx: Vec<usize> = selected.collect();
    let mut pose = camera_from_world;
    for _ in 0..iterations {
        let mut normal = NormalEquations6::new();
        let (rot, t) = rigid_parts(&pose);
        for &i in &idx {
            let Some(c) = corr.get(i) else { continue };
            let x = rot * c.p_in_world.coords + t;
            let Some((e, j, has_depth)) = residual(camera, bf, &x, c.pixel, c.depth_m, c.sigma_px) else {
                continue;
            };
            let w = if robust { huber_weight(e.norm_squared(), chi2_threshold(has_depth)) } else { 1.0 };
            normal.add(&pose_jacobian_rows(&j, &x), &e, w, if has_depth { 3 } else { 2 });
        }
        let (mut h, b) = normal.system();
        // Tiny Levenberg damping keeps near-degenerate minimal sets solvable.
        for k in 0..6 {
            h[(k, k)] += 1e-9 + 1e-6 * h[(k, k)];
        }
        let delta = h.cholesky()?.solve(&b);
        if !delta.iter().all(|v| v.is_finite()) {
            return None;
        }
        pose = apply_increment(&pose, &delta);
        if delta.norm() < 1e-10 {
            break;
        }
    }
    Some(pose)
}

/// Squared whitened residual of each correspondence under `camera_from_world` (∞ behind camera)
/// and whether it has depth.
fn chi2_all(corr: &[Correspondence], camera: &PinholeCamera, bf: f64, camera_from_world: &Se3) -> Vec<(f64, bool)> {
    chi2_iter(corr, camera, bf, camera_from_world).collect()
}

/// [`chi2_all`] as an iterator.
fn chi2_iter<'a>(
    corr: &'a [Correspondence],
    camera: &'a PinholeCamera,
    bf: f64,
    camera_from_world: &Se3,
) -> impl Iterator<Item = (f64, bool)> + 'a {
    let (rot, t) = rigid_parts(camera_from_world);
    corr.iter().map(move |c| {
        let x = rot * c.p_in_world.coords + t;
        match residual(camera, bf, &x, c.pixel, c.depth_m, c.sigma_px) {
            Some((e, _, d)) => (e.norm_squared(), d),
            None => (f64::INFINITY, c.depth_m.is_some()),
        }
    })
}

fn check_inputs(corr: &[Correspondence], prior: &Se3, required: usize) -> Result<(), SlamError> {
    if corr.len() < required {
        return Err(SlamError::TooFewCorrespondences { required, actual: corr.len() });
    }
    if !super::is_finite_pose(prior) {
        return Err(SlamError::NonFinitePose { field: "prior" });
    }
    if let Some(i) = corr.iter().position(|c| {
        !(c.p_in_world.coords.iter().all(|v| v.is_finite())
            && c.pixel.iter().all(|v| v.is_finite())
            && c.sigma_px.is_finite()
            && c.sigma_px > 0.0)
    }) {
        return Err(SlamError::BadCorrespondence { index: i });
    }
    Ok(())
}

/// Robust motion-only refinement (ORB-SLAM2 `PoseOptimization`): `config.rounds` rounds of
/// Huber Gauss-Newton over the current inliers, re-classifying every correspondence by χ² after
/// each round. Starts with all correspondences as inliers.
pub fn refine_pose(
    corr: &[Correspondence],
    camera: &PinholeCamera,
    world_from_camera: &Se3,
    config: &PoseRefineConfig,
) -> Result<PoseEstimate, SlamError> {
    check_inputs(corr, world_from_camera, 3)?;
    let bf = camera.fx * config.depth_baseline_m;
    let mut pose = world_from_camera.inverse();
    let mut inliers = vec![true; corr.len()];
    for _ in 0..config.rounds.max(1) {
        let mut sel = inliers.iter().enumerate().filter_map(|(i, &k)| k.then_some(i));
        pose = gauss_newton(corr, &mut sel, camera, bf, pose, config.iterations, true)
            .ok_or(SlamError::Degenerate { stage: "pose refinement" })?;
        for (flag, (chi2, has_depth)) in inliers.iter_mut().zip(chi2_all(corr, camera, bf, &pose)) {
            *flag = chi2 <= chi2_threshold(has_depth);
        }
    }
    let n_inliers = inliers.iter().filter(|&&k| k).count();
    Ok(PoseEstimate { world_from_camera: pose.inverse(), inliers, n_inliers })
}

/// RANSAC over prior-seeded minimal sets (see the module docs), then [`refine_pose`] on the best
/// consensus set. Errors: fewer than 3 correspondences, a non-finite prior or correspondence, or
/// fewer than `ransac.min_inliers` inliers.
pub fn solve_pnp_ransac(
    corr: &[Correspondence],
    camera: &PinholeCamera,
    prior_world_from_camera: &Se3,
    ransac: &RansacConfig,
    refine: &PoseRefineConfig,
) -> Result<PoseEstimate, SlamError> {
    check_inputs(corr, prior_world_from_camera, 3)?;
    let bf = camera.fx * refine.depth_baseline_m;
    let prior = prior_world_from_camera.inverse();
    let count = |pose: &Se3| chi2_iter(corr, camera, bf, pose).filter(|(c, d)| *c <= chi2_threshold(*d)).count();
    let n = corr.len();
    // Hypotheses needed for `confidence` that one was drawn from inliers only, at the inlier
    // share of the best pose so far (the prior counts as the first hypothesis).
    let needed_for = |k: usize| {
        let w = k as f64 / n as f64;
        let p_good = w * w * w;
        if p_good >= 1.0 - 1e-12 {
            0
        } else if p_good <= 0.0 {
            ransac.max_iterations
        } else {
            ((1.0 - ransac.confidence).ln() / (1.0 - p_good).ln()).ceil().max(1.0) as usize
        }
    };
    let mut best_pose = prior;
    let mut best_count = count(&prior);
    let mut rng = ChaCha8Rng::seed_from_u64(ransac.seed);
    let mut needed = needed_for(best_count);
    let mut it = 0;
    while it < needed.min(ransac.max_iterations) {
        it += 1;
        let a = rng.random_range(0..n);
        let mut b = rng.random_range(0..n);
        while b == a {
            b = rng.random_range(0..n);
        }
        let mut c = rng.random_range(0..n);
        while c == a || c == b {
            c = rng.random_range(0..n);
        }
        let mut sel = [a, b, c].into_iter();
        let Some(pose) = gauss_newton(corr, &mut sel, camera, bf, prior, ransac.minimal_iterations, false) else {
            continue;
        };
        let k = count(&pose);
        if k > best_count {
            best_count = k;
            best_pose = pose;
            needed = needed_for(k);
        }
    }
    if best_count < ransac.min_inliers.max(3) {
        return Err(SlamError::TooFewInliers { required: ransac.min_inliers, actual: best_count });
    }
    let inliers: Vec<bool> =
        chi2_all(corr, camera, bf, &best_pose).iter().map(|(c, d)| *c <= chi2_threshold(*d)).collect();
    let subset: Vec<Correspondence> = corr.iter().zip(&inliers).filter_map(|(c, &k)| k.then_some(*c)).collect();
    let refined = refine_pose(&subset, camera, &best_pose.inverse(), refine)?;
    let pose = refined.world_from_camera.inverse();
    let inliers: Vec<bool> = chi2_all(corr, camera, bf, &pose).iter().map(|(c, d)| *c <= chi2_threshold(*d)).collect();
    let n_inliers = inliers.iter().filter(|&&k| k).count();
    if n_inliers < ransac.min_inliers {
        return Err(SlamError::TooFewInliers { required: ransac.min_inliers, actual: n_inliers });
    }
    Ok(PoseEstimate { world_from_camera: refined.world_from_camera, inliers, n_inliers })
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion};

    fn camera() -> PinholeCamera {
        PinholeCamera::from_fovy(640, 480, 50f64.to_radians()).unwrap()
    }

    fn gauss(rng: &mut ChaCha8Rng) -> f64 {
        let u1: f64 = rng.random::<f64>().max(1e-300);
        let u2: f64 = rng.random();
        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
    }

    /// 300 points 0.3–1.2 m in front of the camera, 0.3 px pixel noise, 1 mm depth noise; the
    /// first `outlier_fraction` of them get uniformly random pixels (and depths).
    fn scene(seed: u64, outlier_fraction: f64, with_depth: bool) -> (Se3, Vec<Correspondence>) {
        let cam = camera();
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let world_from_camera =
            Se3::from_parts(Translation3::new(0.3, -0.2, 0.5), UnitQuaternion::from_euler_angles(2.8, 0.1, -0.4));
        let n = 300;
        let n_out = (outlier_fraction * n as f64) as usize;
        let corr = (0..n)
            .map(|i| {
                let (u, v) = (rng.random_range(0.0..640.0), rng.random_range(0.0..480.0));
                let z: f64 = rng.random_range(0.3..1.2);
                let p_in_camera = cam.unproject(u, v, z);
                let p_in_world = world_from_camera * p_in_camera;
                let (pixel, depth) = if i < n_out {
                    ([rng.random_range(0.0..640.0), rng.random_range(0.0..480.0)], rng.random_range(0.3..1.2))
                } else {
                    ([u + 0.3 * gauss(&mut rng), v + 0.3 * gauss(&mut rng)], z + 0.001 * gauss(&mut rng))
                };
                Correspondence { p_in_world, pixel, depth_m: with_depth.then_some(depth), sigma_px: 1.0 }
            })
            .collect();
        (world_from_camera, corr)
    }

    fn errors(a: &Se3, b: &Se3) -> (f64, f64) {
        let d = a.inverse() * b;
        (d.translation.vector.norm(), d.rotation.angle().to_degrees())
    }

    #[test]
    fn ransac_recovers_the_pose_with_30_percent_outliers() {
        for (seed, with_depth) in [(1, false), (2, true), (3, false), (4, true)] {
            let (truth, corr) = scene(seed, 0.3, with_depth);
            // Prior 3 cm / 3° off.
            let prior = truth
                * Se3::from_parts(
                    Translation3::new(0.02, -0.02, 0.01),
                    UnitQuaternion::from_euler_angles(0.03, -0.03, 0.03),
                );
            let est = solve_pnp_ransac(
                &corr,
                &camera(),
                &prior,
                &RansacConfig { seed, ..RansacConfig::default() },
                &PoseRefineConfig::default(),
            )
            .unwrap();
            let (dt, dr) = errors(&truth, &est.world_from_camera);
            assert!(dt < 0.001 && dr < 0.1, "seed {seed} depth {with_depth}: {dt} m, {dr}°");
            // Outliers are flagged: at most 3 % of them slip through, at least 95 % of inliers kept.
            let false_in = est.inliers[..90].iter().filter(|&&k| k).count();
            let true_in = est.inliers[90..].iter().filter(|&&k| k).count();
            assert!(false_in <= 3 && true_in >= 200, "{false_in} outliers accepted, {true_in} inliers kept");
        }
    }

    #[test]
    fn refinement_converges_from_the_prior_on_clean_data() {
        let (truth, corr) = scene(5, 0.0, true);
        let prior = truth * Se3::translation(0.01, 0.0, -0.01);
        let est = refine_pose(&corr, &camera(), &prior, &PoseRefineConfig::default()).unwrap();
        let (dt, dr) = errors(&truth, &est.world_from_camera);
        assert!(dt < 5e-4 && dr < 0.05, "{dt} m, {dr}°");
    }

    #[test]
    fn bad_correspondences_are_typed_errors() {
        let (truth, corr) = scene(6, 0.0, false);
        let cam = camera();
        let (r, p) = (RansacConfig::default(), PoseRefineConfig::default());
        assert!(matches!(
            solve_pnp_ransac(&corr[..2], &cam, &truth, &r, &p),
            Err(SlamError::TooFewCorrespondences { required: 3, actual: 2 })
        ));
        let mut bad = corr.clone();
        bad[4].pixel[0] = f64::NAN;
        assert_eq!(solve_pnp_ransac(&bad, &cam, &truth, &r, &p), Err(SlamError::BadCorrespondence { index: 4 }));
        let mut nan_prior = truth;
        nan_prior.translation.vector.y = f64::INFINITY;
        assert!(matches!(solve_pnp_ransac(&corr, &cam, &nan_prior, &r, &p), Err(SlamError::NonFinitePose { .. })));
        // Pure noise: no consensus.
        let (_, noise) = scene(7, 1.0, false);
        assert!(matches!(solve_pnp_ransac(&noise, &cam, &truth, &r, &p), Err(SlamError::TooFewInliers { .. })));
    }
}
