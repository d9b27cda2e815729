//! Yaw initialisation by line alignment: the paper's Alg. 2 with Eq. "costf" and "cost".
//!
//! For each of [`YawConfig::samples`] candidate yaws `θ_k = −π/2 + k π / samples` (the interval
//! `[−π/2, π/2)` covers a cuboid's 180° symmetry), the cube for `θ_k` (centre and half-extents from
//! a caller function, usually [`oriented_extent`] of the object's inlier points) is projected into
//! every frame of the window, and every LSD segment in the object's box is compared with its
//! projected edges. Per frame the paper's score is
//! `Score = N_p / N_a · (1 + 0.1 (ξ − E(e)))`, where `N_a` is the number of segments, `N_p` those
//! with angle error `e < ξ` and `E(e)` their mean error; scores are summed over the window and the
//! argmax is the initial yaw.
//!
//! Choices where the paper is vague (all config fields):
//! - Which projected edge a segment is compared with: the nearest one in the image (distance from
//!   the segment's midpoint to the projected edge as a finite segment). Comparing with the
//!   best-aligned of all 12 edges would make every yaw score well (12 edges span many angles).
//! - `e`: the paper writes `‖α(Ẑ(θ)) − α(Z_lsd)‖²` but thresholds it at ξ = 5 "degrees"; we use the
//!   absolute undirected angle difference in degrees (the squared reading would make ξ ≈ 2.2°).
//! - Alg. 2 does not remove hidden edges (all 12 cube edges are projected); an edge with an
//!   endpoint behind the camera is skipped. The refinement does remove them ([`visible_edges`],
//!   [`project_visible_edges`]; see [`super::refine`]).

use nalgebra::{Point3, Vector3};

use super::lsd::LineSegment;
use crate::geometry::{Box2, ObjectGeometry, PinholeCamera, Se3, Shape};

/// The 12 edges of [`ObjectGeometry::corners`] (bottom ring, top ring, verticals).
pub const CUBE_EDGES: [(usize, usize); 12] =
    [(0, 1), (1, 2), (2, 3), (3, 0), (4, 5), (5, 6), (6, 7), (7, 4), (0, 4), (1, 5), (2, 6), (3, 7)];

/// One frame's line evidence for one object.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct LineFrame {
    /// Frame index (for bookkeeping).
    pub frame: u32,
    /// Intrinsics of this frame.
    pub camera: PinholeCamera,
    /// Camera pose (held fixed by the refinement).
    pub world_from_camera: Se3,
    /// The object's detection box in this frame, pixels.
    pub bbox: Box2,
    /// LSD segments assigned to the object (see [`super::lsd::segments_in_box`]).
    pub segments: Vec<LineSegment>,
}

/// Configuration of the line-alignment yaw initialisation (Alg. 2).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct YawConfig {
    /// Number of yaw samples over `[−π/2, π/2)` (paper: 30, i.e. 6° apart).
    pub samples: usize,
    /// Angle-error threshold ξ, degrees (paper: 5).
    pub xi_deg: f64,
    /// Weight of the mean-error bonus in the score (paper: 0.1 per degree).
    pub bonus_per_deg: f64,
}

impl Default for YawConfig {
    fn default() -> Self {
        Self { samples: 30, xi_deg: 5.0, bonus_per_deg: 0.1 }
    }
}

/// A projected cube edge in the image.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ProjectedEdge {
    /// Index into [`CUBE_EDGES`].
    pub edge: usize,
    /// First endpoint, pixels.
    pub a: [f64; 2],
    /// Second endpoint, pixels.
    pub b: [f64; 2],
}

impl ProjectedEdge {
    /// Undirected angle in `[0, π)`.
    pub fn angle_rad(&self) -> f64 {
        (self.b[1] - self.a[1]).atan2(self.b[0] - self.a[0]).rem_euclid(std::f64::consts::PI)
    }

    /// Distance from a point to this edge as a finite segment, pixels.
    pub fn distance_to(&self, p: [f64; 2]) -> f64 {
        let d = [self.b[0] - self.a[0], self.b[1] - self.a[1]];
        let len2 = d[0] * d[0] + d[1] * d[1];
        let t = if len2 > 0.0 {
            (((p[0] - self.a[0]) * d[0] + (p[1] - self.a[1]) * d[1]) / len2).clamp(0.0, 1.0)
        } else {
            0.0
        };
        let q = [self.a[0] + t * d[0], self.a[1] + t * d[1]];
        (p[0] - q[0]).hypot(p[1] - q[1])
    }

    /// Signed distance from a point to this edge's infinite line, pixels (0 for a degenerate edge).
    pub fn line_distance(&self, p: [f64; 2]) -> f64 {
        let d = [self.b[0] - self.a[0], self.b[1] - self.a[1]];
        let len = d[0].hypot(d[1]);
        if len <= 0.0 {
            return 0.0;
        }
        ((p[0] - self.a[0]) * d[1] - (p[1] - self.a[1]) * d[0]) / len
    }
}

/// Project the 12 edges of a cuboid into a frame (edges with an endpoint behind the camera are
/// left out).
pub fn project_edges(geometry: &ObjectGeometry, camera: &PinholeCamera, world_from_camera: &Se3) -> Vec<ProjectedEdge> {
    let camera_from_world = world_from_camera.inverse();
    let corners = geometry.corners();
    let uv: Vec<Option<[f64; 2]>> = corners.iter().map(|c| camera.project(&(camera_from_world * c))).collect();
    CUBE_EDGES
        .iter()
        .enumerate()
        .filter_map(|(edge, &(i, j))| match (uv.get(i).copied().flatten(), uv.get(j).copied().flatten()) {
            (Some(a), Some(b)) => Some(ProjectedEdge { edge, a, b }),
            _ => None,
        })
        .collect()
}

/// The four corner indices of each face of [`ObjectGeometry::corners`]: bottom, top, then the
/// side faces `k` = corners `(k, k+1, k+5, k+4)` (indices mod 4 within each ring).
const CUBE_FACES: [[usize; 4]; 6] =
    [[0, 1, 2, 3], [4, 5, 6, 7], [0, 1, 5, 4], [1, 2, 6, 5], [2, 3, 7, 6], [3, 0, 4, 7]];

/// The two faces (indices into `CUBE_FACES`) adjacent to each edge of [`CUBE_EDGES`].
const EDGE_FACES: [(usize, usize); 12] =
    [(0, 2), (0, 3), (0, 4), (0, 5), (1, 2), (1, 3), (1, 4), (1, 5), (5, 2), (2, 3), (3, 4), (4, 5)];

/// Which of the 12 cube edges a camera at `eye` (world) can see, ignoring other objects: an edge
/// of a convex box is visible iff one of its two faces faces the camera (outward normal towards
/// the eye). Silhouette edges are visible; edges between two back faces are hidden.
pub fn visible_edges(geometry: &ObjectGeometry, eye: &Point3<f64>) -> [bool; 12] {
    let corners = geometry.corners();
    let centre = geometry.center;
    let front: Vec<bool> = CUBE_FACES
        .iter()
        .map(|f| {
            let fc = f.iter().map(|&i| corners[i].coords).sum::<Vector3<f64>>() / 4.0;
            (fc - centre).dot(&(eye.coords - fc)) > 0.0
        })
        .collect();
    let mut out = [false; 12];
    for (k, (a, b)) in EDGE_FACES.iter().enumerate() {
        out[k] = front[*a] || front[*b];
    }
    out
}

/// [`project_edges`] restricted to the edges visible from the camera ([`visible_edges`]).
pub fn project_visible_edges(
    geometry: &ObjectGeometry,
    camera: &PinholeCamera,
    world_from_camera: &Se3,
) -> Vec<ProjectedEdge> {
    let eye = Point3::from(world_from_camera.translation.vector);
    let visible = visible_edges(geometry, &eye);
    let mut edges = project_edges(geometry, camera, world_from_camera);
    edges.retain(|e| visible.get(e.edge).copied().unwrap_or(false));
    edges
}

/// Undirected angle difference of two line angles, in `[0, π/2]`.
pub fn angle_difference(a_rad: f64, b_rad: f64) -> f64 {
    let d = (a_rad - b_rad).rem_euclid(std::f64::consts::PI);
    d.min(std::f64::consts::PI - d)
}

/// The nearest projected edge to a segment (by midpoint distance) and the segment's angle error
/// against it, degrees.
pub fn nearest_edge(segment: &LineSegment, edges: &[ProjectedEdge]) -> Option<(usize, f64)> {
    let m = segment.midpoint();
    let (k, _) = edges.iter().enumerate().map(|(k, e)| (k, e.distance_to(m))).min_by(|x, y| x.1.total_cmp(&y.1))?;
    let e = edges.get(k)?;
    Some((k, angle_difference(e.angle_rad(), segment.angle_rad()).to_degrees()))
}

/// The paper's per-frame score (Eq. "cost") of a geometry against one frame's segments, and the
/// frame's accumulated error (sum of `e` over the segments with `e < ξ`). `(0, 0)` when the frame
/// has no segments or no edge projects.
pub fn frame_score(geometry: &ObjectGeometry, frame: &LineFrame, config: &YawConfig) -> (f64, f64) {
    let prepared: Vec<([f64; 2], f64)> = frame.segments.iter().map(|s| (s.midpoint(), s.angle_rad())).collect();
    prepared_frame_score(geometry, frame, &prepared, config)
}

/// [`frame_score`] with the segments' midpoints and angles computed once.
fn prepared_frame_score(
    geometry: &ObjectGeometry,
    frame: &LineFrame,
    segments: &[([f64; 2], f64)],
    config: &YawConfig,
) -> (f64, f64) {
    let n_a = segments.len();
    if n_a == 0 {
        return (0.0, 0.0);
    }
    let edges = project_edges(geometry, &frame.camera, &frame.world_from_camera);
    if edges.is_empty() {
        return (0.0, 0.0);
    }
    // Per edge: start, direction, 1 / |direction|², angle; squared distances avoid square roots.
    let pre: Vec<([f64; 2], [f64; 2], f64, f64)> = edges
        .iter()
        .map(|e| {
            let d = [e.b[0] - e.a[0], e.b[1] - e.a[1]];
            let len2 = d[0] * d[0] + d[1] * d[1];
            (e.a, d, if len2 > 0.0 { 1.0 / len2 } else { 0.0 }, e.angle_rad())
        })
        .collect();
    let (mut n_p, mut sum) = (0usize, 0.0);
    for (mid, angle) in segments {
        let mut best = (f64::INFINITY, 0.0);
        for (a, d, inv_len2, edge_angle) in &pre {
            let (px, py) = (mid[0] - a[0], mid[1] - a[1]);
            let t = ((px * d[0] + py * d[1]) * inv_len2).clamp(0.0, 1.0);
            let (qx, qy) = (px - t * d[0], py - t * d[1]);
            let dist2 = qx * qx + qy * qy;
            if dist2 < best.0 {
                best = (dist2, *edge_angle);
            }
        }
        if best.0.is_finite() {
            let e = angle_difference(best.1, *angle).to_degrees();
            if e < config.xi_deg {
                n_p += 1;
                sum += e;
            }
        }
    }
    if n_p == 0 {
        return (0.0, 0.0);
    }
    let mean = sum / n_p as f64;
    (n_p as f64 / n_a as f64 * (1.0 + config.bonus_per_deg * (config.xi_deg - mean)), sum)
}

/// Result of Alg. 2.
#[derive(Debug, Clone, PartialEq)]
pub struct YawAlignment {
    /// The best yaw θ*, radians in `[−π/2, π/2)`.
    pub yaw_rad: f64,
    /// Its accumulated score over the window (0 = no evidence).
    pub score: f64,
    /// Its accumulated angle error `e_θ*`, degrees.
    pub error_deg: f64,
    /// Every sample's `(yaw_rad, score)`, for inspection.
    pub samples: Vec<(f64, f64)>,
}

/// Alg. 2: score every sampled yaw over the frames and return the argmax (the first on ties).
/// `geometry_for_yaw(θ)` gives the cube for a candidate yaw (e.g. [`oriented_extent`] of the
/// inlier points). Returns `None` when no sample scores above zero (no segments, or none aligned).
pub fn align_yaw(
    frames: &[LineFrame],
    geometry_for_yaw: impl Fn(f64) -> ObjectGeometry,
    config: &YawConfig,
) -> Option<YawAlignment> {
    let n = config.samples.max(1);
    let mut samples = Vec::with_capacity(n);
    let mut best: Option<(f64, f64, f64)> = None;
    let prepared: Vec<Vec<([f64; 2], f64)>> =
        frames.iter().map(|f| f.segments.iter().map(|s| (s.midpoint(), s.angle_rad())).collect()).collect();
    for k in 0..n {
        let yaw = -std::f64::consts::FRAC_PI_2 + k as f64 * std::f64::consts::PI / n as f64;
        let g = geometry_for_yaw(yaw);
        let (mut s_theta, mut e_theta) = (0.0, 0.0);
        for (f, segs) in frames.iter().zip(&prepared) {
            let (s, e) = prepared_frame_score(&g, f, segs, config);
            s_theta += s;
            e_theta += e;
        }
        samples.push((yaw, s_theta));
        if s_theta > best.map_or(0.0, |b| b.1) {
            best = Some((yaw, s_theta, e_theta));
        }
    }
    best.map(|(yaw_rad, score, error_deg)| YawAlignment { yaw_rad, score, error_deg, samples })
}

/// Centre and half-extents of a point set in the frame rotated by `yaw_rad` about world z: the
/// points are rotated into that frame, their min/max taken per axis, and the mid-range centre
/// rotated back. `None` for an empty set.
pub fn oriented_extent(points: &[Point3<f64>], yaw_rad: f64) -> Option<(Vector3<f64>, Vector3<f64>)> {
    let (s, c) = yaw_rad.sin_cos();
    let mut lo = Vector3::repeat(f64::INFINITY);
    let mut hi = Vector3::repeat(f64::NEG_INFINITY);
    for p in points {
        let local = Vector3::new(c * p.x + s * p.y, -s * p.x + c * p.y, p.z);
        lo = lo.inf(&local);
        hi = hi.sup(&local);
    }
    if points.is_empty() {
        return None;
    }
    let mid = (lo + hi) / 2.0;
    let center = Vector3::new(c * mid.x - s * mid.y, s * mid.x + c * mid.y, mid.z);
    Some((center, (hi - lo) / 2.0))
}

/// A cuboid geometry from centre, yaw and half-extents.
pub fn cuboid(center: Vector3<f64>, yaw_rad: f64, half_extents: Vector3<f64>) -> ObjectGeometry {
    ObjectGeometry { shape: Shape::Cuboid, center, yaw_rad, half_extents }
}

/// The same cuboid written with its longer horizontal side along the object x axis and yaw in
/// `[−π/2, π/2)`. A box at yaw θ with half-extents `(a, b)` is the box at θ + 90° with `(b, a)`;
/// line alignment cannot tell them apart, so estimates are reported in this canonical form
/// (compare with ground truth written the same way, or modulo 90° when the sides are swapped).
pub fn canonical_cuboid(g: &ObjectGeometry) -> ObjectGeometry {
    let mut out = *g;
    if out.half_extents.y > out.half_extents.x {
        out.half_extents = Vector3::new(g.half_extents.y, g.half_extents.x, g.half_extents.z);
        out.yaw_rad += std::f64::consts::FRAC_PI_2;
    }
    out.yaw_rad =
        (out.yaw_rad + std::f64::consts::FRAC_PI_2).rem_euclid(std::f64::consts::PI) - std::f64::consts::FRAC_PI_2;
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Isometry3, Translation3, UnitQuaternion};

    #[test]
    fn angle_difference_is_undirected() {
        let d = |a: f64, b: f64| angle_difference(a.to_radians(), b.to_radians()).to_degrees();
        assert!((d(10.0, 170.0) - 20.0).abs() < 1e-9);
        assert!((d(0.0, 90.0) - 90.0).abs() < 1e-9);
        assert!((d(5.0, 185.0)).abs() < 1e-9);
        assert!((d(-30.0, 30.0) - 60.0).abs() < 1e-9);
    }

    #[test]
    fn canonical_cuboid_puts_the_long_side_on_x() {
        let g = cuboid(Vector3::new(0.5, 0.0, 0.05), 0.3, Vector3::new(0.02, 0.06, 0.05));
        let c = canonical_cuboid(&g);
        assert_eq!(c.half_extents, Vector3::new(0.06, 0.02, 0.05));
        assert!((c.yaw_rad - (0.3 + std::f64::consts::FRAC_PI_2 - std::f64::consts::PI)).abs() < 1e-12);
        // Same footprint.
        assert!(crate::geometry::iou3d(&g, &c) > 1.0 - 1e-9);
        let already = cuboid(Vector3::zeros(), 2.0, Vector3::new(0.06, 0.02, 0.05));
        assert!((canonical_cuboid(&already).yaw_rad - (2.0 - std::f64::consts::PI)).abs() < 1e-12);
    }

    #[test]
    fn edges_behind_the_camera_are_skipped_and_scores_vanish_without_segments() {
        let cam = PinholeCamera::from_fovy(640, 480, 1.0).unwrap();
        // Camera at the origin looking along world +x (OpenCV axes: z_c = +x_w, x_c = −y_w, y_c = −z_w).
        let r = nalgebra::Matrix3::new(0.0, 0.0, 1.0, -1.0, 0.0, 0.0, 0.0, -1.0, 0.0);
        let rot = UnitQuaternion::from_matrix(&r);
        let pose: Se3 = Isometry3::from_parts(Translation3::new(0.0, 0.0, 0.0), rot);
        let in_front = cuboid(Vector3::new(1.0, 0.0, 0.0), 0.0, Vector3::repeat(0.1));
        assert_eq!(project_edges(&in_front, &cam, &pose).len(), 12);
        let behind = cuboid(Vector3::new(-1.0, 0.0, 0.0), 0.0, Vector3::repeat(0.1));
        assert!(project_edges(&behind, &cam, &pose).is_empty());
        let straddling = cuboid(Vector3::new(0.0, 0.0, 0.0), 0.0, Vector3::repeat(0.1));
        assert_eq!(project_edges(&straddling, &cam, &pose).len(), 4); // the four edges at x = +0.1
        let frame = LineFrame {
            frame: 0,
            camera: cam,
            world_from_camera: pose,
            bbox: Box2::new(0.0, 0.0, 640.0, 480.0),
            segments: vec![],
        };
        assert_eq!(frame_score(&in_front, &frame, &YawConfig::default()), (0.0, 0.0));
        assert!(
            align_yaw(&[frame], |y| cuboid(in_front.center, y, in_front.half_extents), &YawConfig::default()).is_none()
        );
    }
}
