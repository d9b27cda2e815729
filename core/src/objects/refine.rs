//! Joint refinement of yaw and scale (paper, "Object pose optimization": the object terms
//! `e(θ) + e(s)`), by a small Levenberg–Marquardt on nalgebra fixed-size matrices with the camera
//! poses held fixed (the SLAM's bundle adjustment is not coupled in).
//!
//! Parameters: `[θ_y, s_x, s_y, s_z]`, plus the centre `[t_x, t_y, t_z]` when
//! [`RefineConfig::refine_center`] is set (default; the paper keeps `t` from Alg. 1, but the mean
//! of surface points is biased towards the faces the camera saw, so we let the edges move it).
//! Residuals, per frame and per LSD segment associated with a projected cube edge (nearest edge by
//! midpoint distance, within [`RefineConfig::gate_px`] and [`RefineConfig::gate_deg`]; the
//! association is redone at every outer iteration, ICP-style):
//! - `e(θ)`: the signed angle between the segment and the edge, degrees × [`RefineConfig::angle_weight_px_per_deg`];
//! - `e(s)`: the distances of the segment's two endpoints from the edge's line, pixels (the paper's
//!   "distance between the projected edges of a cube and their nearest parallel LSD segments");
//! - both Huber-robustified at [`RefineConfig::segment_huber_px`] (2 px): on the seven scenes the
//!   segments near a book's long top edges sit a median 3.4 px inside them (cover texture parallel
//!   to the edge, 1401 segments, 44 % within 3 px of the true edge), and plain least squares
//!   narrowed the books by 3–5 mm;
//! - beyond the paper, a point-to-surface term ([`RefineConfig::point_weight_px_per_m`]): the
//!   distance of each (subsampled) iForest inlier point to the cube's surface, Huber-robustified
//!   ([`RefineConfig::point_huber_m`]), in pixels per metre, scaled so the points weigh in total
//!   as many residuals as the segments of the window;
//! - a weak prior `(p − p₀) · prior_px_per_m` on centre and scale so directions the segments do not
//!   constrain stay at the Alg. 1 values.
//!
//! Hidden edges ([`RefineConfig::visible_edges_only`], default on): segments are associated only
//! with edges visible from the frame's camera ([`super::yaw::visible_edges`]). With all 12 edges,
//! the hidden far-bottom edge of a thin object projects a few pixels from its far-top edge; the
//! top edge's segments then pull the bottom edge onto it and the box grows in height while it
//! shrinks in width. On the seven scenes (Init, seed 0) the previous refinement (all edges,
//! segments only) lowered the mean 3D IoU from 0.541 (lines) to 0.514, mostly through books whose
//! height tripled while the box slid below the table (e.g. half-height 1.4 → 5.4 cm): in a
//! top-down view nothing in the segments pins the height. Hidden-edge removal alone did not fix it
//! (0.509); the point-to-surface term did (0.568), the extent bound stopped faces sliding outward
//! along covered faces (0.590), the Huber residuals stopped the narrowing (0.605). The point and
//! extent weights were set from pixel-per-metre reasoning and checked on seed 1 of the same scenes
//! before the Huber threshold was added (lines 0.516 → refined 0.579; previous refinement 0.503);
//! the threshold (2 px) was then picked among 1, 2 and 4 px on seeds 0 and 1 (seed 1: 0.593), so
//! seed 1 is no longer held out for it. The diagnosis
//! replays the runs' recorded estimator inputs: `cargo run --release -p objslam-core --example
//! param_replay` (see `core/examples/param_replay.rs`).
//!
//! # Acceptance
//! The refinement reports a data cost `J` of the initial and of the refined cube, computed the same
//! way for both and without any prior term: every segment of the window against its nearest
//! visible edge with the truncated squared residual `min(r², τ²)` (`τ² = 3 gate_px²`, also for
//! segments no edge is near), plus the point-to-surface term. The estimator keeps the refined cube
//! only if it lowers `J` ([`Refinement::rms_after_px`] `<` [`Refinement::rms_before_px`], with
//! `rms = sqrt(J / n)` over the same `n` residuals). The camera poses, segments and points are the
//! only inputs: ground truth never enters.
//!
//! Jacobians are forward differences; the damped normal equations `(JᵀJ + λ diag(JᵀJ) + λ ε I) δ =
//! −Jᵀr` are solved by Cholesky; λ is divided by 3 after an accepted step and multiplied by 4
//! after a rejected one.

use nalgebra::{Point3, SMatrix, SVector, Vector3};

use super::yaw::{angle_difference, cuboid, project_edges, project_visible_edges, LineFrame, ProjectedEdge};
use crate::geometry::ObjectGeometry;

const NP: usize = 7;
/// LM stops when an accepted step lowers the cost by less than this fraction.
const RELATIVE_TOLERANCE: f64 = 1e-6;
type Params = SVector<f64, NP>;

/// Configuration of the yaw/scale refinement.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RefineConfig {
    /// Outer iterations (re-association of segments to edges), default 6.
    pub outer_iterations: usize,
    /// Levenberg–Marquardt iterations per association, default 10.
    pub lm_iterations: usize,
    /// A segment is associated with its nearest projected edge only if its midpoint is within this
    /// distance of the edge, pixels (default 20).
    pub gate_px: f64,
    /// Gate of the first outer iteration, pixels (default 60); the gate shrinks geometrically to
    /// [`RefineConfig::gate_px`] by the last one, so a cube that starts too large (residual
    /// outliers in Alg. 1) can still reach its true edges.
    pub initial_gate_px: f64,
    /// … and its angle differs by less than this, degrees (default 10 = 2 ξ).
    pub gate_deg: f64,
    /// Weight of the angle residual: pixels per degree (default 2).
    pub angle_weight_px_per_deg: f64,
    /// Weight of the prior on centre and scale: pixels per metre (default 200: 1 cm costs 2 px).
    pub prior_px_per_m: f64,
    /// Also refine the centre (default true; the paper refines yaw and scale only).
    pub refine_center: bool,
    /// Half-extents are kept at least this, metres (default 0.005).
    pub min_half_extent_m: f64,
    /// Minimum number of associated segments to run at all (default 3).
    pub min_segments: usize,
    /// Associate segments only with edges visible from the camera (default true; false = all 12
    /// edges, the previous behaviour).
    pub visible_edges_only: bool,
    /// Weight of the point-to-surface residuals, pixels per metre (default 1000: 1 cm off the
    /// surface weighs like 10 px, about what 1 cm spans at 0.45 m with a 460 px focal length);
    /// 0 disables the term.
    pub point_weight_px_per_m: f64,
    /// Huber threshold of the point-to-surface distance, metres (default 0.005).
    pub point_huber_m: f64,
    /// At most this many points enter the point term (every k-th point, deterministic; default 300).
    pub max_points: usize,
    /// Huber threshold of the segment residuals, pixels (default 2; 0 = plain least squares).
    /// Book covers carry texture lines parallel to their long edges a few pixels inside them;
    /// under plain least squares they pull those edges in (the box narrows).
    pub segment_huber_px: f64,
    /// Weight of the extent bound, pixels per metre (default 1000; 0 disables): each face of the
    /// cube pays for lying more than [`RefineConfig::extent_margin_m`] beyond the points' extent
    /// along its axis (the [`RefineConfig::extent_quantile`] / `1 −` quantile of the points in the
    /// object frame). Surface distances alone cannot stop a face from sliding outward along a
    /// face the points cover (a top-face point stays on the top face).
    pub extent_weight_px_per_m: f64,
    /// Slack of the extent bound, metres (default 0.01): within it, the segments alone place the face.
    pub extent_margin_m: f64,
    /// Quantile of the points taken as their extent (default 0.01, robust to stray points).
    pub extent_quantile: f64,
    /// The estimator keeps the refined cube only if it lowers the acceptance cost `J` (default
    /// true; false = always keep it).
    pub accept_if_lower_cost: bool,
}

impl Default for RefineConfig {
    fn default() -> Self {
        Self {
            outer_iterations: 6,
            lm_iterations: 10,
            gate_px: 20.0,
            initial_gate_px: 60.0,
            gate_deg: 10.0,
            angle_weight_px_per_deg: 2.0,
            prior_px_per_m: 200.0,
            refine_center: true,
            min_half_extent_m: 0.005,
            min_segments: 3,
            visible_edges_only: true,
            point_weight_px_per_m: 1000.0,
            point_huber_m: 0.005,
            max_points: 300,
            segment_huber_px: 2.0,
            extent_weight_px_per_m: 1000.0,
            extent_margin_m: 0.01,
            extent_quantile: 0.01,
            accept_if_lower_cost: true,
        }
    }
}

/// Result of the refinement.
#[derive(Debug, Clone, PartialEq)]
pub struct Refinement {
    /// Refined geometry (yaw wrapped to `[−π/2, π/2)`).
    pub geometry: ObjectGeometry,
    /// `sqrt(J / n)` of the initial cube: the acceptance cost `J` (see the module docs) over its
    /// fixed number of residuals `n`, pixels.
    pub rms_before_px: f64,
    /// The same for the refined cube; the refinement helps iff it is below `rms_before_px`.
    pub rms_after_px: f64,
    /// Segments associated at the last outer iteration.
    pub associated: usize,
}

fn to_params(g: &ObjectGeometry) -> Params {
    Params::from_column_slice(&[
        g.yaw_rad,
        g.center.x,
        g.center.y,
        g.center.z,
        g.half_extents.x,
        g.half_extents.y,
        g.half_extents.z,
    ])
}

fn to_geometry(p: &Params, min_half: f64) -> ObjectGeometry {
    cuboid(
        Vector3::new(p[1], p[2], p[3]),
        p[0],
        Vector3::new(p[4].max(min_half), p[5].max(min_half), p[6].max(min_half)),
    )
}

/// Association: (frame index, segment index, cube edge index).
type Assoc = Vec<(usize, usize, usize)>;

fn edges_for_association(g: &ObjectGeometry, f: &LineFrame, config: &RefineConfig) -> Vec<ProjectedEdge> {
    if config.visible_edges_only {
        project_visible_edges(g, &f.camera, &f.world_from_camera)
    } else {
        project_edges(g, &f.camera, &f.world_from_camera)
    }
}

fn associate(g: &ObjectGeometry, frames: &[LineFrame], gate_px: f64, config: &RefineConfig) -> Assoc {
    let mut out = Vec::new();
    for (fi, f) in frames.iter().enumerate() {
        let edges = edges_for_association(g, f, config);
        for (si, s) in f.segments.iter().enumerate() {
            let m = s.midpoint();
            let best = edges.iter().map(|e| (e, e.distance_to(m))).min_by(|x, y| x.1.total_cmp(&y.1));
            if let Some((e, d)) = best {
                let ang = angle_difference(e.angle_rad(), s.angle_rad()).to_degrees();
                if d <= gate_px && ang <= config.gate_deg {
                    out.push((fi, si, e.edge));
                }
            }
        }
    }
    out
}

/// The three residuals of a segment against an edge: angle (weighted) and the two endpoint
/// distances to the edge's line, each Huber-robustified at [`RefineConfig::segment_huber_px`].
fn segment_residuals(e: &ProjectedEdge, s: &super::lsd::LineSegment, config: &RefineConfig) -> [f64; 3] {
    let h = config.segment_huber_px;
    [
        huber_residual(config.angle_weight_px_per_deg * signed_angle_deg(e, s.angle_rad()), h),
        huber_residual(e.line_distance(s.a), h),
        huber_residual(e.line_distance(s.b), h),
    ]
}

/// The points of the point term: every k-th point so at most `max_points` remain.
fn subsample(points: &[Point3<f64>], max_points: usize) -> Vec<Point3<f64>> {
    if max_points == 0 {
        return Vec::new();
    }
    let step = points.len().div_ceil(max_points).max(1);
    points.iter().step_by(step).copied().collect()
}

/// Signed distance of a world point to the surface of a cuboid (negative inside), metres.
fn surface_distance(g: &ObjectGeometry, p: &Point3<f64>) -> f64 {
    ObjectGeometry { shape: crate::geometry::Shape::Cuboid, ..*g }.surface_distance(p)
}

/// Huber-robustified residual: `ρ(x)² = huber(x)` (quadratic up to `delta`, linear beyond).
fn huber_residual(x: f64, delta: f64) -> f64 {
    let a = x.abs();
    if delta <= 0.0 || a <= delta {
        x
    } else {
        x.signum() * (2.0 * delta * a - delta * delta).sqrt()
    }
}

/// The data inputs of one refinement: frames, subsampled points and the point weight.
struct Data<'a> {
    frames: &'a [LineFrame],
    points: Vec<Point3<f64>>,
    /// Per-point weight, pixels per metre (already scaled by the residual count).
    point_w: f64,
    /// Weight of the six extent-bound residuals, pixels per metre (scaled like `point_w`).
    extent_w: f64,
    /// Segments in the window.
    n_segments: usize,
}

impl<'a> Data<'a> {
    fn new(frames: &'a [LineFrame], points: &[Point3<f64>], config: &RefineConfig) -> Self {
        let points = subsample(points, config.max_points);
        let n_segments: usize = frames.iter().map(|f| f.segments.len()).sum();
        let point_w = if points.is_empty() || config.point_weight_px_per_m <= 0.0 {
            0.0
        } else {
            config.point_weight_px_per_m * ((3 * n_segments.max(1)) as f64 / points.len() as f64).sqrt()
        };
        let extent_w = if points.is_empty() || config.extent_weight_px_per_m <= 0.0 {
            0.0
        } else {
            config.extent_weight_px_per_m * ((3 * n_segments.max(1)) as f64 / 6.0).sqrt()
        };
        Self { frames, points, point_w, extent_w, n_segments }
    }

    fn push_point_residuals(&self, g: &ObjectGeometry, config: &RefineConfig, r: &mut Vec<f64>) {
        if self.point_w > 0.0 {
            r.extend(
                self.points.iter().map(|p| self.point_w * huber_residual(surface_distance(g, p), config.point_huber_m)),
            );
        }
        if self.extent_w > 0.0 {
            let (s, c) = g.yaw_rad.sin_cos();
            let mut axes: [Vec<f64>; 3] = [Vec::new(), Vec::new(), Vec::new()];
            for p in &self.points {
                let d = p.coords - g.center;
                axes[0].push(c * d.x + s * d.y);
                axes[1].push(-s * d.x + c * d.y);
                axes[2].push(d.z);
            }
            for (k, v) in axes.iter_mut().enumerate() {
                v.sort_by(f64::total_cmp);
                let q = config.extent_quantile.clamp(0.0, 0.5);
                let at = |t: f64| v.get(((v.len() - 1) as f64 * t).round() as usize).copied().unwrap_or(0.0);
                let (lo, hi) = (at(q), at(1.0 - q));
                let h = g.half_extents[k];
                r.push(self.extent_w * (h - hi - config.extent_margin_m).max(0.0));
                r.push(self.extent_w * (-h - lo + config.extent_margin_m).min(0.0));
            }
        }
    }

    /// The acceptance cost `J` of a cube and its residual count (see the module docs).
    fn acceptance_cost(&self, g: &ObjectGeometry, config: &RefineConfig) -> (f64, usize) {
        let tau2 = 3.0 * config.gate_px * config.gate_px;
        let mut j = 0.0;
        for f in self.frames {
            let edges = edges_for_association(g, f, config);
            for s in &f.segments {
                let m = s.midpoint();
                let best = edges.iter().map(|e| (e, e.distance_to(m))).min_by(|x, y| x.1.total_cmp(&y.1));
                let c = match best {
                    Some((e, d))
                        if d <= config.gate_px
                            && angle_difference(e.angle_rad(), s.angle_rad()).to_degrees() <= config.gate_deg =>
                    {
                        segment_residuals(e, s, config).iter().map(|v| v * v).sum::<f64>().min(tau2)
                    }
                    _ => tau2,
                };
                j += c;
            }
        }
        let mut r = Vec::with_capacity(self.points.len());
        self.push_point_residuals(g, config, &mut r);
        j += cost(&r);
        (j, 3 * self.n_segments + r.len())
    }
}

fn signed_angle_deg(edge: &ProjectedEdge, seg_angle: f64) -> f64 {
    let mut d = (edge.angle_rad() - seg_angle).rem_euclid(std::f64::consts::PI);
    if d > std::f64::consts::FRAC_PI_2 {
        d -= std::f64::consts::PI;
    }
    d.to_degrees()
}

fn residuals(p: &Params, p0: &Params, data: &Data<'_>, assoc: &Assoc, config: &RefineConfig) -> Vec<f64> {
    let frames = data.frames;
    let g = to_geometry(p, config.min_half_extent_m);
    let mut r = Vec::with_capacity(assoc.len() * 3 + data.points.len() + 6);
    let mut cached: Option<(usize, Vec<ProjectedEdge>)> = None;
    for &(fi, si, ei) in assoc {
        let Some(f) = frames.get(fi) else {
            continue;
        };
        if cached.as_ref().map(|c| c.0) != Some(fi) {
            cached = Some((fi, project_edges(&g, &f.camera, &f.world_from_camera)));
        }
        let edge = cached.as_ref().and_then(|c| c.1.iter().find(|e| e.edge == ei));
        let Some(s) = f.segments.get(si) else {
            continue;
        };
        match edge {
            Some(e) => {
                r.extend(segment_residuals(e, s, config));
            }
            // The edge went behind the camera: a constant, large residual keeps sizes consistent.
            None => r.extend([config.gate_px; 3]),
        }
    }
    data.push_point_residuals(&g, config, &mut r);
    let k0 = if config.refine_center { 1 } else { 4 };
    for k in 1..NP {
        let w = if k < k0 { 1e4 } else { 1.0 };
        r.push(w * config.prior_px_per_m * (p[k] - p0[k]));
    }
    r
}

fn cost(r: &[f64]) -> f64 {
    r.iter().map(|v| v * v).sum()
}

/// Refine yaw, scale (and centre) of a cuboid against the window's line segments and the object's
/// (inlier) points (`points` may be empty: segments only). Returns `None` when fewer than
/// [`RefineConfig::min_segments`] segments associate with the initial cube.
pub fn refine_yaw_scale(
    initial: &ObjectGeometry,
    frames: &[LineFrame],
    points: &[Point3<f64>],
    config: &RefineConfig,
) -> Option<Refinement> {
    let data = Data::new(frames, points, config);
    let p0 = to_params(initial);
    let mut p = p0;
    let outer_n = config.outer_iterations.max(1);
    let gate = |k: usize| {
        if outer_n <= 1 {
            return config.gate_px;
        }
        let ratio = (config.gate_px / config.initial_gate_px.max(config.gate_px)).max(1e-9);
        config.initial_gate_px.max(config.gate_px) * ratio.powf(k as f64 / (outer_n - 1) as f64)
    };
    let mut assoc = associate(initial, frames, gate(0), config);
    if assoc.len() < config.min_segments {
        return None;
    }
    let (j_before, n_res) = data.acceptance_cost(initial, config);
    let mut lambda = 1e-3;
    for outer in 0..config.outer_iterations {
        if outer > 0 {
            let a = associate(&to_geometry(&p, config.min_half_extent_m), frames, gate(outer), config);
            if a.len() < config.min_segments {
                break;
            }
            assoc = a;
        }
        let mut r = residuals(&p, &p0, &data, &assoc, config);
        let mut c = cost(&r);
        for _ in 0..config.lm_iterations {
            // Forward-difference Jacobian (steps 1e-6 rad / 1e-7 m: residuals are smooth and
            // well scaled in pixels), then JᵀJ and Jᵀr.
            let mut jac: Vec<Vec<f64>> = Vec::with_capacity(NP);
            for k in 0..NP {
                let h = if k == 0 { 1e-6 } else { 1e-7 };
                let mut pp = p;
                pp[k] += h;
                let rp = residuals(&pp, &p0, &data, &assoc, config);
                jac.push(rp.iter().zip(&r).map(|(a, b)| (a - b) / h).collect());
            }
            let mut jtj = SMatrix::<f64, NP, NP>::zeros();
            let mut jtr = Params::zeros();
            for a in 0..NP {
                jtr[a] = jac[a].iter().zip(&r).map(|(x, y)| x * y).sum();
                for b in a..NP {
                    let v: f64 = jac[a].iter().zip(&jac[b]).map(|(x, y)| x * y).sum();
                    jtj[(a, b)] = v;
                    jtj[(b, a)] = v;
                }
            }
            let mut improved = false;
            let mut converged = false;
            for _ in 0..8 {
                let mut damped = jtj;
                for d in 0..NP {
                    damped[(d, d)] += lambda * (jtj[(d, d)] + 1e-6);
                }
                let Some(chol) = damped.cholesky() else {
                    lambda *= 4.0;
                    continue;
                };
                let delta = chol.solve(&(-jtr));
                let candidate = p + delta;
                let rc = residuals(&candidate, &p0, &data, &assoc, config);
                let cc = cost(&rc);
                if cc < c {
                    // Converged when a step gains less than RELATIVE_TOLERANCE of the cost.
                    converged = c - cc < RELATIVE_TOLERANCE * c;
                    p = candidate;
                    r = rc;
                    c = cc;
                    lambda = (lambda / 3.0).max(1e-9);
                    improved = true;
                    break;
                }
                lambda *= 4.0;
            }
            if !improved || converged {
                break;
            }
        }
    }
    let mut geometry = to_geometry(&p, config.min_half_extent_m);
    geometry.yaw_rad =
        (geometry.yaw_rad + std::f64::consts::FRAC_PI_2).rem_euclid(std::f64::consts::PI) - std::f64::consts::FRAC_PI_2;
    let (j_after, _) = data.acceptance_cost(&geometry, config);
    let n = n_res.max(1) as f64;
    Some(Refinement {
        geometry,
        rms_before_px: (j_before / n).sqrt(),
        rms_after_px: (j_after / n).sqrt(),
        associated: assoc.len(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn surface_distance_is_signed_and_follows_the_yaw() {
        let g = cuboid(Vector3::new(1.0, 2.0, 0.5), std::f64::consts::FRAC_PI_2, Vector3::new(0.3, 0.1, 0.5));
        // Yaw 90°: the object x axis is world y.
        let on_face = Point3::new(1.0, 2.3, 0.5);
        assert!(surface_distance(&g, &on_face).abs() < 1e-12);
        let outside = Point3::new(1.0, 2.5, 0.5);
        assert!((surface_distance(&g, &outside) - 0.2).abs() < 1e-12);
        // Centre: nearest face is the object-y face 0.1 away (world x).
        assert!((surface_distance(&g, &Point3::new(1.0, 2.0, 0.5)) + 0.1).abs() < 1e-12);
        // Beyond a corner: Euclidean distance to it.
        let corner = Point3::new(1.0 + 0.1 + 0.3, 2.0 + 0.3 + 0.4, 1.0);
        assert!((surface_distance(&g, &corner) - 0.5).abs() < 1e-12);
    }

    #[test]
    fn huber_residual_squares_to_the_huber_loss() {
        let d = 0.005;
        for x in [-0.02, -0.005, -0.001, 0.0, 0.003, 0.005, 0.012] {
            let r = huber_residual(x, d);
            let a: f64 = x.abs();
            let huber = if a <= d { a * a } else { 2.0 * d * a - d * d };
            assert!((r * r - huber).abs() < 1e-15, "{x}");
            assert!(r.signum() * x.signum() >= 0.0);
        }
        assert_eq!(huber_residual(0.3, 0.0), 0.3);
    }

    #[test]
    fn subsample_keeps_at_most_max_points_evenly() {
        let pts: Vec<Point3<f64>> = (0..1001).map(|i| Point3::new(f64::from(i), 0.0, 0.0)).collect();
        let s = subsample(&pts, 300);
        assert!(s.len() <= 300 && s.len() >= 250, "{}", s.len());
        assert_eq!(s[1].x - s[0].x, 4.0);
        assert_eq!(subsample(&pts[..10], 300).len(), 10);
        assert!(subsample(&pts, 0).is_empty());
    }

    #[test]
    fn config_defaults_fill_missing_fields() {
        let c: RefineConfig = serde_json::from_str(r#"{"point_weight_px_per_m": 0}"#).unwrap();
        assert_eq!(c.point_weight_px_per_m, 0.0);
        assert!(c.visible_edges_only && c.accept_if_lower_cost);
        assert_eq!(c.max_points, 300);
    }
}
