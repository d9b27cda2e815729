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
//! - a weak prior `(p − p₀) · prior_px_per_m` on centre and scale so directions the segments do not
//!   constrain (e.g. the height in a top-down view) stay at the Alg. 1 values.
//!
//! Jacobians are forward differences; the damped normal equations `(JᵀJ + λ diag(JᵀJ) + λ ε I) δ =
//! −Jᵀr` are solved by Cholesky; λ is divided by 3 after an accepted step and multiplied by 4
//! after a rejected one.

use nalgebra::{SMatrix, SVector, Vector3};

use super::yaw::{angle_difference, cuboid, project_edges, LineFrame, ProjectedEdge};
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
        }
    }
}

/// Result of the refinement.
#[derive(Debug, Clone, PartialEq)]
pub struct Refinement {
    /// Refined geometry (yaw wrapped to `[−π/2, π/2)`).
    pub geometry: ObjectGeometry,
    /// Root-mean-square residual before and after, pixels.
    pub rms_before_px: f64,
    /// See `rms_before_px`.
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

fn associate(g: &ObjectGeometry, frames: &[LineFrame], gate_px: f64, config: &RefineConfig) -> Assoc {
    let mut out = Vec::new();
    for (fi, f) in frames.iter().enumerate() {
        let edges = project_edges(g, &f.camera, &f.world_from_camera);
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

fn signed_angle_deg(edge: &ProjectedEdge, seg_angle: f64) -> f64 {
    let mut d = (edge.angle_rad() - seg_angle).rem_euclid(std::f64::consts::PI);
    if d > std::f64::consts::FRAC_PI_2 {
        d -= std::f64::consts::PI;
    }
    d.to_degrees()
}

fn residuals(p: &Params, p0: &Params, frames: &[LineFrame], assoc: &Assoc, config: &RefineConfig) -> Vec<f64> {
    let g = to_geometry(p, config.min_half_extent_m);
    let mut r = Vec::with_capacity(assoc.len() * 3 + 6);
    let mut cached: Option<(usize, Vec<ProjectedEdge>)> = None;
    for &(fi, si, ei) in assoc {
        let (Some(f), true) = (frames.get(fi), true) else {
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
                r.push(config.angle_weight_px_per_deg * signed_angle_deg(e, s.angle_rad()));
                r.push(e.line_distance(s.a));
                r.push(e.line_distance(s.b));
            }
            // The edge went behind the camera: a constant, large residual keeps sizes consistent.
            None => r.extend([config.gate_px; 3]),
        }
    }
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

/// Refine yaw, scale (and centre) of a cuboid against the window's line segments. Returns `None`
/// when fewer than [`RefineConfig::min_segments`] segments associate with the initial cube.
pub fn refine_yaw_scale(initial: &ObjectGeometry, frames: &[LineFrame], config: &RefineConfig) -> Option<Refinement> {
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
    let n_data = |a: &Assoc| (3 * a.len()).max(1) as f64;
    let data_cost = |r: &[f64], a: &Assoc| r.iter().take(3 * a.len()).map(|v| v * v).sum::<f64>();
    let r_init = residuals(&p, &p0, frames, &assoc, config);
    let rms_before_px = (data_cost(&r_init, &assoc) / n_data(&assoc)).sqrt();
    let mut lambda = 1e-3;
    for outer in 0..config.outer_iterations {
        if outer > 0 {
            let a = associate(&to_geometry(&p, config.min_half_extent_m), frames, gate(outer), config);
            if a.len() < config.min_segments {
                break;
            }
            assoc = a;
        }
        let mut r = residuals(&p, &p0, frames, &assoc, config);
        let mut c = cost(&r);
        for _ in 0..config.lm_iterations {
            // Forward-difference Jacobian (steps 1e-6 rad / 1e-7 m: residuals are smooth and
            // well scaled in pixels), then JᵀJ and Jᵀr.
            let mut jac: Vec<Vec<f64>> = Vec::with_capacity(NP);
            for k in 0..NP {
                let h = if k == 0 { 1e-6 } else { 1e-7 };
                let mut pp = p;
                pp[k] += h;
                let rp = residuals(&pp, &p0, frames, &assoc, config);
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
                let rc = residuals(&candidate, &p0, frames, &assoc, config);
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
    let r_final = residuals(&p, &p0, frames, &assoc, config);
    let rms_after_px = (data_cost(&r_final, &assoc) / n_data(&assoc)).sqrt();
    Some(Refinement { geometry, rms_before_px, rms_after_px, associated: assoc.len() })
}
