//! Local bundle adjustment: Levenberg-Marquardt over keyframe poses and point positions with the
//! points eliminated by the Schur complement (dense reduced camera system; fine for the ~5–10
//! keyframes of a local window). Same residuals and Huber widths as [`super::pnp`].

use std::ops::Range;

use nalgebra::{DMatrix, DVector, Matrix3, Matrix6x3, Point3, Vector3, Vector6};
use serde::{Deserialize, Serialize};

use super::pnp::{apply_increment, chi2_threshold, huber_weight, pose_jacobian_rows, residual, NormalEquations6};
use crate::geometry::{PinholeCamera, Se3};

/// Configuration of local bundle adjustment.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct BundleConfig {
    /// Largest number of LM iterations (ORB-SLAM2 local BA: 5 + 10); it stops earlier once a step
    /// lowers the cost by less than 0.01 %.
    pub iterations: usize,
    /// Initial LM damping (added to the Hessian diagonal).
    pub initial_lambda: f64,
    /// Virtual stereo baseline for the depth residual, metres (see [`super::PoseRefineConfig`]).
    pub depth_baseline_m: f64,
}

impl Default for BundleConfig {
    fn default() -> Self {
        Self { iterations: 10, initial_lambda: 1e-3, depth_baseline_m: 0.08 }
    }
}

/// One observation of a point by a pose in a bundle problem.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BundleObservation {
    /// Index of the observing pose.
    pub pose: usize,
    /// Index of the point.
    pub point: usize,
    /// Observed pixel.
    pub pixel: [f64; 2],
    /// Measured depth, metres.
    pub depth_m: Option<f64>,
    /// Pixel standard deviation.
    pub sigma_px: f64,
}

/// A bundle problem: poses are `camera_from_world`; `fixed[i]` poses are held constant.
#[derive(Debug, Clone, PartialEq)]
pub struct BundleProblem {
    /// Camera poses (`camera_from_world`).
    pub camera_from_world: Vec<Se3>,
    /// Which poses are fixed (gauge and out-of-window keyframes).
    pub fixed: Vec<bool>,
    /// Point positions, world frame.
    pub points: Vec<Point3<f64>>,
    /// Observations.
    pub observations: Vec<BundleObservation>,
}

impl BundleProblem {
    /// Total robust cost (Huber on whitened χ²).
    pub fn cost(&self, camera: &PinholeCamera, config: &BundleConfig) -> f64 {
        self.cost_with_threads(camera, config, 1)
    }

    /// [`Self::cost`] with the observations' terms found on up to `threads` threads (chunks of
    /// observations) and summed in observation order: the same sum for any `threads`.
    fn cost_with_threads(&self, camera: &PinholeCamera, config: &BundleConfig, threads: usize) -> f64 {
        let bf = camera.fx * config.depth_baseline_m;
        let term = |o: &BundleObservation| {
            let pose = self.camera_from_world.get(o.pose)?;
            let p = self.points.get(o.point)?;
            let x = pose * p;
            let (e, _, d) = residual(camera, bf, &x.coords, o.pixel, o.depth_m, o.sigma_px)?;
            Some(huber_cost(e.norm_squared(), chi2_threshold(d)))
        };
        if threads < 2 {
            return self.observations.iter().filter_map(term).sum();
        }
        let chunk = self.observations.len().div_ceil(PARALLEL_CHUNKS).max(1);
        let chunks: Vec<&[BundleObservation]> = self.observations.chunks(chunk).collect();
        let terms = crate::map_indices(threads, chunks.len(), |i| {
            chunks.get(i).map_or_else(Vec::new, |c| c.iter().filter_map(term).collect::<Vec<f64>>())
        });
        terms.into_iter().flatten().sum()
    }

    /// Whether each observation passes its χ² test at the current estimate.
    pub fn inlier_flags(&self, camera: &PinholeCamera, config: &BundleConfig) -> Vec<bool> {
        let bf = camera.fx * config.depth_baseline_m;
        self.observations
            .iter()
            .map(|o| {
                let (Some(pose), Some(p)) = (self.camera_from_world.get(o.pose), self.points.get(o.point)) else {
                    return false;
                };
                let x = pose * p;
                residual(camera, bf, &x.coords, o.pixel, o.depth_m, o.sigma_px)
                    .is_some_and(|(e, _, d)| e.norm_squared() <= chi2_threshold(d))
            })
            .collect()
    }

    /// Run LM; returns the number of accepted steps. Leaves the problem unchanged if nothing
    /// improves.
    pub fn optimize(&mut self, camera: &PinholeCamera, config: &BundleConfig) -> usize {
        self.optimize_with_threads(camera, config, 1)
    }

    /// [`Self::optimize`] with the linearisation (by chunks of points) and the cost (by chunks
    /// of observations) on up to `threads` threads; every sum keeps its order, so the result is
    /// the same for any `threads`.
    pub fn optimize_with_threads(&mut self, camera: &PinholeCamera, config: &BundleConfig, threads: usize) -> usize {
        self.optimize_with_budget(camera, config, &crate::ThreadBudget::new(threads))
    }

    /// [`Self::optimize_with_threads`] on the threads `budget` grants when each pass (a
    /// linearisation, a cost) starts: the same result whatever it grants when.
    pub fn optimize_with_budget(
        &mut self,
        camera: &PinholeCamera,
        config: &BundleConfig,
        budget: &crate::ThreadBudget,
    ) -> usize {
        let bf = camera.fx * config.depth_baseline_m;
        let n_poses = self.camera_from_world.len();
        let var_index: Vec<Option<usize>> = {
            let mut k = 0;
            (0..n_poses)
                .map(|i| {
                    if self.fixed.get(i).copied().unwrap_or(true) {
                        None
                    } else {
                        k += 1;
                        Some(k - 1)
                    }
                })
                .collect()
        };
        let n_var = var_index.iter().flatten().count();
        // Per point, its observations in observation order, each with (its rank among the
        // observations by variable poses, the variable) if its pose is variable; and per point
        // only those (rank, variable): they alone enter the reduced system and the
        // back-substitution (a point seen by many fixed keyframes has few of them).
        let n_points = self.points.len();
        let mut obs_by_point: Vec<Vec<PointObservation>> = vec![Vec::new(); n_points];
        let mut var_obs_by_point: Vec<Vec<(usize, usize)>> = vec![Vec::new(); n_points];
        let mut n_var_obs = 0;
        for (i, o) in self.observations.iter().enumerate() {
            let (Some(var), Some(list)) = (var_index.get(o.pose), obs_by_point.get_mut(o.point)) else {
                continue;
            };
            let ranked = var.map(|v| {
                n_var_obs += 1;
                (n_var_obs - 1, v)
            });
            list.push(PointObservation { obs: i, ranked });
            if let (Some(r), Some(vl)) = (ranked, var_obs_by_point.get_mut(o.point)) {
                vl.push(r);
            }
        }
        // Chunks of points with about equal numbers of observations for the linearisation.
        let point_chunks = point_chunks(&obs_by_point, if crate::worker_threads() > 1 { PARALLEL_CHUNKS } else { 1 });
        let mut lambda = config.initial_lambda;
        let mut cost = self.cost_with_threads(camera, config, budget.get());
        let mut accepted = 0;
        let mut hcc = vec![NormalEquations6::new(); n_var];
        let mut hpp = vec![Matrix3::<f64>::zeros(); n_points];
        let mut bp = vec![Vector3::<f64>::zeros(); n_points];
        // Camera-point blocks by rank of the observation among those by variable poses.
        let mut hcp = vec![Matrix6x3::<f64>::zeros(); n_var_obs];
        // The linearisation holds until a step is accepted (a rejected step only raises the damping).
        let mut linearised = false;
        for _ in 0..config.iterations {
            if !linearised {
                let rotations: Vec<Matrix3<f64>> =
                    self.camera_from_world.iter().map(|p| *p.rotation.to_rotation_matrix().matrix()).collect();
                let ctx = Linearisation { camera, bf, rotations: &rotations, obs_by_point: &obs_by_point };
                let parts = crate::map_indices(budget.get(), point_chunks.len(), |c| {
                    point_chunks
                        .get(c)
                        .map_or_else(PointsLinearised::default, |r| self.linearise_points(&ctx, r.clone()))
                });
                hcc.iter_mut().for_each(|m| *m = NormalEquations6::new());
                hcp.iter_mut().for_each(|m| *m = Matrix6x3::zeros());
                let mut pose_terms: Vec<Option<PoseTerm>> = vec![None; n_var_obs];
                for (range, part) in point_chunks.iter().zip(parts) {
                    if let (Some(h), Some(b)) = (hpp.get_mut(range.clone()), bp.get_mut(range.clone())) {
                        h.copy_from_slice(&part.hpp);
                        b.copy_from_slice(&part.bp);
                    }
                    for (rank, term, block) in part.pose_terms {
                        if let (Some(t), Some(c)) = (pose_terms.get_mut(rank), hcp.get_mut(rank)) {
                            *t = Some(term);
                            *c = block;
                        }
                    }
                }
                // Each pose's normal equations summed in observation order.
                for t in pose_terms.iter().flatten() {
                    if let Some(n) = hcc.get_mut(t.var) {
                        n.add(&t.rows, &t.e, t.w, t.n_rows);
                    }
                }
                linearised = true;
            }
            // Damped Schur complement.
            let mut s = DMatrix::<f64>::zeros(6 * n_var, 6 * n_var);
            let mut rhs = DVector::<f64>::zeros(6 * n_var);
            for (v, normal) in hcc.iter().enumerate() {
                let (mut block, bc) = normal.system();
                for k in 0..6 {
                    block[(k, k)] += lambda * (1.0 + block[(k, k)]);
                }
                s.fixed_view_mut::<6, 6>(6 * v, 6 * v).copy_from(&block);
                rhs.fixed_rows_mut::<6>(6 * v).copy_from(&bc);
            }
            let mut hpp_inv = vec![Matrix3::<f64>::zeros(); self.points.len()];
            for (pi, list) in var_obs_by_point.iter().enumerate() {
                let mut h = hpp[pi];
                for k in 0..3 {
                    h[(k, k)] += lambda * (1.0 + h[(k, k)]);
                }
                let Some(inv) = h.try_inverse() else { continue };
                hpp_inv[pi] = inv;
                // The symmetric reduced system: each pair of the point's observations once.
                for (a, &(oa, va)) in list.iter().enumerate() {
                    let wa = hcp[oa] * inv;
                    let r = wa * bp[pi];
                    let mut seg = rhs.fixed_rows_mut::<6>(6 * va);
                    seg -= r;
                    for &(ob, vb) in &list[a..] {
                        let blk = wa * hcp[ob].transpose();
                        let mut view = s.fixed_view_mut::<6, 6>(6 * va, 6 * vb);
                        view -= blk;
                        if ob != oa {
                            let mut mirror = s.fixed_view_mut::<6, 6>(6 * vb, 6 * va);
                            mirror -= blk.transpose();
                        }
                    }
                }
            }
            let dx = if n_var > 0 {
                match s.clone().cholesky() {
                    Some(ch) => ch.solve(&rhs),
                    None => {
                        lambda *= 10.0;
                        continue;
                    }
                }
            } else {
                DVector::zeros(0)
            };
            // Back-substitute the points and try the step.
            let old_poses = self.camera_from_world.clone();
            let old_points = self.points.clone();
            for (i, v) in var_index.iter().enumerate() {
                if let Some(v) = v {
                    let d = Vector6::from_iterator(dx.rows(6 * v, 6).iter().copied());
                    self.camera_from_world[i] = apply_increment(&self.camera_from_world[i], &d);
                }
            }
            for (pi, list) in var_obs_by_point.iter().enumerate() {
                let mut r = bp[pi];
                for &(oa, va) in list {
                    let d = Vector6::from_iterator(dx.rows(6 * va, 6).iter().copied());
                    r -= hcp[oa].transpose() * d;
                }
                let dp = hpp_inv[pi] * r;
                if dp.iter().all(|v| v.is_finite()) {
                    self.points[pi] += dp;
                }
            }
            let new_cost = self.cost_with_threads(camera, config, budget.get());
            if new_cost.is_finite() && new_cost < cost {
                let converged = cost - new_cost <= CONVERGED_RELATIVE_DECREASE * cost;
                cost = new_cost;
                lambda = (lambda / 3.0).max(1e-9);
                accepted += 1;
                linearised = false;
                if converged {
                    break;
                }
            } else {
                self.camera_from_world = old_poses;
                self.points = old_points;
                lambda *= 8.0;
            }
        }
        accepted
    }

    /// Gauss-Newton blocks at the current estimate of the points `range`: their Hessians and
    /// gradients (each point's observations summed in observation order) and, for each of
    /// their observations by a variable pose, its pose term and camera-point block.
    fn linearise_points(&self, ctx: &Linearisation<'_>, range: Range<usize>) -> PointsLinearised {
        let n = range.len();
        let mut out =
            PointsLinearised { hpp: vec![Matrix3::zeros(); n], bp: vec![Vector3::zeros(); n], pose_terms: Vec::new() };
        let lists = ctx.obs_by_point.get(range.clone()).unwrap_or_default();
        let points = self.points.get(range).unwrap_or_default();
        for ((list, p), (h, b)) in lists.iter().zip(points).zip(out.hpp.iter_mut().zip(out.bp.iter_mut())) {
            for po in list {
                let Some(o) = self.observations.get(po.obs) else {
                    continue;
                };
                let (Some(pose), Some(rot)) = (self.camera_from_world.get(o.pose), ctx.rotations.get(o.pose)) else {
                    continue;
                };
                let x = rot * p.coords + pose.translation.vector;
                let Some((e, j, d)) = residual(ctx.camera, ctx.bf, &x, o.pixel, o.depth_m, o.sigma_px) else {
                    continue;
                };
                let w = huber_weight(e.norm_squared(), chi2_threshold(d));
                let jp: Matrix3<f64> = j * rot;
                *h += jp.transpose() * jp * w;
                *b -= jp.transpose() * e * w;
                if let Some((rank, var)) = po.ranked {
                    let rows = pose_jacobian_rows(&j, &x);
                    let n_rows = if d { 3 } else { 2 };
                    let block =
                        Matrix6x3::from_fn(|i, k| (0..n_rows).map(|r| rows[r][i] * jp[(r, k)]).sum::<f64>() * w);
                    out.pose_terms.push((rank, PoseTerm { var, rows, e, w, n_rows }, block));
                }
            }
        }
        out
    }
}

/// Chunks of the observations (cost) and of the points (linearisation) a bundle problem is
/// split into on two threads (taken in turn from a shared counter, so a helper thread that
/// starts late takes fewer).
const PARALLEL_CHUNKS: usize = 8;

/// An observation of a point: its index, and (its rank among the observations by variable
/// poses, the variable) if its pose is variable.
#[derive(Debug, Clone, Copy)]
struct PointObservation {
    obs: usize,
    ranked: Option<(usize, usize)>,
}

/// What the linearisation of every chunk of points reads.
struct Linearisation<'a> {
    camera: &'a PinholeCamera,
    bf: f64,
    /// Each pose's rotation matrix.
    rotations: &'a [Matrix3<f64>],
    obs_by_point: &'a [Vec<PointObservation>],
}

/// An observation's term in its variable pose's normal equations: `w Jᵀ J` and `−w Jᵀ e` over
/// the first `n_rows` of `rows` (J) and `e`.
#[derive(Debug, Clone, Copy)]
struct PoseTerm {
    var: usize,
    rows: [[f64; 6]; 3],
    e: Vector3<f64>,
    w: f64,
    n_rows: usize,
}

/// The linearisation of a chunk of points: their Hessians and gradients, and (rank, pose term,
/// camera-point block) of each of their observations by a variable pose.
#[derive(Debug, Default)]
struct PointsLinearised {
    hpp: Vec<Matrix3<f64>>,
    bp: Vec<Vector3<f64>>,
    pose_terms: Vec<(usize, PoseTerm, Matrix6x3<f64>)>,
}

/// Split the points into at most `n` consecutive ranges of about equal observation counts.
fn point_chunks(obs_by_point: &[Vec<PointObservation>], n: usize) -> Vec<Range<usize>> {
    let total: usize = obs_by_point.iter().map(Vec::len).sum();
    let per_chunk = total.div_ceil(n.max(1)).max(1);
    let mut chunks = Vec::with_capacity(n + 1);
    let (mut start, mut count) = (0, 0);
    for (i, list) in obs_by_point.iter().enumerate() {
        count += list.len();
        if count >= per_chunk {
            chunks.push(start..i + 1);
            (start, count) = (i + 1, 0);
        }
    }
    if start < obs_by_point.len() {
        chunks.push(start..obs_by_point.len());
    }
    chunks
}

/// LM stops once an accepted step lowers the robust cost by less than this fraction of it.
const CONVERGED_RELATIVE_DECREASE: f64 = 1e-4;

fn huber_cost(chi2: f64, delta2: f64) -> f64 {
    if chi2 <= delta2 {
        chi2
    } else {
        2.0 * (delta2 * chi2).sqrt() - delta2
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// Three cameras 10 cm apart looking down +z at 150 points 0.5–1 m away, the first fixed,
    /// the others and the points perturbed; and the true poses and points.
    fn perturbed_problem() -> (BundleProblem, Vec<Se3>, Vec<Point3<f64>>) {
        let cam = PinholeCamera::from_fovy(640, 480, 50f64.to_radians()).unwrap();
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        // Three cameras 10 cm apart looking down +z at points 0.5–1 m away.
        let truth: Vec<Se3> = (0..3).map(|i| Se3::translation(0.1 * i as f64, 0.0, 0.0).inverse()).collect();
        let points: Vec<Point3<f64>> = (0..150)
            .map(|_| Point3::new(rng.random_range(-0.2..0.4), rng.random_range(-0.2..0.2), rng.random_range(0.5..1.0)))
            .collect();
        let mut observations = Vec::new();
        for (pi, pose) in truth.iter().enumerate() {
            for (pt, p) in points.iter().enumerate() {
                let x = pose * p;
                if let Some(uv) = cam.project(&x) {
                    observations.push(BundleObservation {
                        pose: pi,
                        point: pt,
                        pixel: uv,
                        depth_m: Some(x.z),
                        sigma_px: 1.0,
                    });
                }
            }
        }
        let perturb = Se3::from_parts(
            Translation3::new(0.01, -0.005, 0.008),
            UnitQuaternion::from_euler_angles(0.01, -0.01, 0.005),
        );
        let problem = BundleProblem {
            camera_from_world: vec![truth[0], perturb * truth[1], perturb.inverse() * truth[2]],
            fixed: vec![true, false, false],
            points: points.iter().map(|p| p + nalgebra::Vector3::new(0.003, -0.003, 0.004)).collect(),
            observations,
        };
        (problem, truth, points)
    }

    #[test]
    fn bundle_adjustment_recovers_perturbed_poses_and_points() {
        let cam = PinholeCamera::from_fovy(640, 480, 50f64.to_radians()).unwrap();
        let (mut problem, truth, points) = perturbed_problem();
        let cfg = BundleConfig { iterations: 20, ..BundleConfig::default() };
        let before = problem.cost(&cam, &cfg);
        assert!(problem.optimize(&cam, &cfg) > 0);
        let after = problem.cost(&cam, &cfg);
        assert!(after < 1e-6 * before.max(1.0), "cost {before} -> {after}");
        for (est, t) in problem.camera_from_world.iter().zip(&truth) {
            let d = est.inverse() * t;
            assert!(d.translation.vector.norm() < 1e-5 && d.rotation.angle() < 1e-6);
        }
        for (est, t) in problem.points.iter().zip(&points) {
            assert!((est - t).norm() < 1e-5);
        }
        assert!(problem.inlier_flags(&cam, &cfg).iter().all(|&k| k));
    }

    #[test]
    fn two_threads_give_the_one_thread_result() {
        let cam = PinholeCamera::from_fovy(640, 480, 50f64.to_radians()).unwrap();
        // A second fixed pose, and observations without depth, as in the tracker's windows.
        let (mut problem, _, _) = perturbed_problem();
        problem.fixed[2] = true;
        for o in problem.observations.iter_mut().step_by(3) {
            o.depth_m = None;
        }
        let cfg = BundleConfig::default();
        let mut one = problem.clone();
        let steps = one.optimize(&cam, &cfg);
        for threads in [2, 3] {
            let mut two = problem.clone();
            assert_eq!(two.optimize_with_threads(&cam, &cfg, threads), steps);
            assert_eq!(two, one);
            assert_eq!(two.cost_with_threads(&cam, &cfg, threads).to_bits(), one.cost(&cam, &cfg).to_bits());
        }
    }
}
