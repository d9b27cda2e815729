//! Top-down grasp synthesis from an estimated object ([`ObjectGeometry`] from the map, never
//! ground truth).
//!
//! The TCP (`panda_hand_tcp`, z = approach direction, y = finger closing direction) points straight
//! down over the object's centroid: `world_from_tcp = T(c) · Rz(yaw) · Rx(π)`, so the closing axis
//! is `(sin yaw, −cos yaw, 0)`. For a cuboid the fingers close across its shorter horizontal side
//! (two yaws, π apart; the longer side is a fallback when it fits, [`GraspConfig::allow_long_side`]);
//! for a cylinder any yaw works and [`GraspConfig::cylinder_yaw_count`] yaws are tried, starting at
//! the current hand yaw. The TCP height is the centroid, raised so the finger pads reach at most
//! [`GraspConfig::max_grasp_depth_m`] below the object's top and stay above
//! [`GraspConfig::min_tcp_height_m`]; a shallower grasp ([`GraspConfig::shallow_grasp_depth_m`])
//! is the fallback that keeps the 20 cm wide hand body higher above neighbours. Each candidate carries pre-grasp (above), grasp and
//! lift poses, the finger opening, its clearance from neighbouring objects and, when reachable, the
//! collision-free IK solutions.
//!
//! Neighbours whose estimated footprint overlaps the target's are trimmed first
//! ([`trim_neighbours`]): solid objects do not overlap, so the overlap is map error (a bloated or
//! merged estimate), and an estimate reaching into the target would otherwise wall off every
//! finger position.
//!
//! When no candidate is reachable, fallback candidates of cuboids are tried
//! ([`GraspConfig::narrow_opening_fallback`]): the closing axis tilted from the face normal and the
//! TCP moved along the block towards a free end (`fallback_grasps`), the fingers opened only to the
//! chord plus [`GraspConfig::narrow_opening_clearance_m`] and modelled at that opening. A tilted
//! closing reaches past a neighbour that covers part of a side (a staggered row of touching blocks).

use nalgebra::{Translation3, UnitQuaternion, Vector3};

use crate::geometry::{wrap_angle, ObjectGeometry, Se3, Shape};

/// Panda gripper's largest finger opening, metres.
pub const PANDA_MAX_OPENING_M: f64 = 0.08;

/// Settings of the grasp synthesis.
#[derive(Debug, Clone, PartialEq)]
pub struct GraspConfig {
    /// Largest finger opening, metres. Default [`PANDA_MAX_OPENING_M`] (0.08).
    pub max_opening_m: f64,
    /// Extra opening beyond the object's width before closing, metres (split over both sides).
    /// Default 0.02; the opening is capped at `max_opening_m`.
    pub opening_clearance_m: f64,
    /// The finger pads' centre (the TCP) goes at most this far below the object's top, metres, so
    /// the hand body stays clear of tall objects. Default 0.025.
    pub max_grasp_depth_m: f64,
    /// Second, shallower grasp candidate: pads' centre this far below the top, metres (the pads are
    /// 1.85 cm tall). Default 0.012.
    pub shallow_grasp_depth_m: f64,
    /// Lowest TCP height above the table, metres (finger tips reach ~1 cm below the TCP).
    /// Default 0.015.
    pub min_tcp_height_m: f64,
    /// Pre-grasp pose height above the grasp pose, metres. Default 0.10.
    pub pregrasp_height_m: f64,
    /// Lift height above the grasp pose, metres (the success test lifts ≥ 0.10). Default 0.15.
    pub lift_height_m: f64,
    /// Smallest gap between object and fingers (sum of both sides) for a grasp to be admissible,
    /// metres: wider objects are [`TooWide`](super::PlanError::TooWide). Default 0.004.
    pub min_opening_clearance_m: f64,
    /// Also offer grasps across a cuboid's longer side when it fits (ranked after the short side
    /// unless only they are reachable or clear of neighbours). Default true.
    pub allow_long_side: bool,
    /// Clearance from neighbours beyond which candidates count as equally clear, metres; ranking
    /// compares `min(clearance, this)` before anything but reachability. Default 0.01.
    pub clearance_enough_m: f64,
    /// Number of yaws tried for cylinders (evenly spaced over π, starting at the current hand yaw).
    /// Default 6.
    pub cylinder_yaw_count: usize,
    /// Trim neighbours whose footprint overlaps the target's ([`trim_neighbours`]): two solid
    /// objects cannot overlap, so the overlap is map error, and while the target is grasped it is
    /// taken to be the target's. Default true.
    pub trim_overlapping_neighbours: bool,
    /// A trimmed neighbour keeps at least this horizontal half-extent (or radius), metres; one
    /// that would be thinner is left out of the grasp's obstacles. Default 0.01.
    pub min_trimmed_half_extent_m: f64,
    /// When no candidate at the configured opening is reachable, try fallback candidates whose
    /// fingers open only to the object's width plus [`Self::narrow_opening_clearance_m`], with
    /// the collision model's fingers placed at that opening (not at the full opening), and
    /// off-centre along the fingers' width ([`off_centre_offsets`]): the grasp of a block whose
    /// neighbours leave less room beside it than the open fingers need. Default true.
    pub narrow_opening_fallback: bool,
    /// Opening beyond the object's width of the fallback candidates, metres (split over both
    /// sides; a tilted pad's edge reaches `pad half-width · tan tilt` closer). Default 0.024.
    pub narrow_opening_clearance_m: f64,
    /// Off-centre fallback TCP positions per side along the cuboid's axis across the closing
    /// axis (`fallback_grasps`): `k / steps` of the largest offset, k = 1 … steps. 0 = centred
    /// only. Default 2.
    pub off_centre_steps: usize,
    /// The fallback grasps' contact points stay at least this far inside the cuboid's ends,
    /// metres (the finger pads are about 2 cm wide). Default 0.008.
    pub off_centre_inset_m: f64,
    /// Tilted fallback closing directions per side (`fallback_grasps`): `k / steps` of
    /// [`Self::max_tilt_rad`], k = 1 … steps. 0 = untilted only. Default 2.
    pub tilt_steps: usize,
    /// Largest turn of a fallback closing axis from the cuboid's face normal, radians: a tilted
    /// closing reaches past a neighbour that covers part of a side. Default 0.35 (about 20°).
    pub max_tilt_rad: f64,
}

impl Default for GraspConfig {
    fn default() -> Self {
        Self {
            max_opening_m: PANDA_MAX_OPENING_M,
            opening_clearance_m: 0.02,
            max_grasp_depth_m: 0.025,
            shallow_grasp_depth_m: 0.012,
            min_tcp_height_m: 0.015,
            pregrasp_height_m: 0.10,
            lift_height_m: 0.15,
            min_opening_clearance_m: 0.004,
            allow_long_side: true,
            clearance_enough_m: 0.01,
            cylinder_yaw_count: 6,
            trim_overlapping_neighbours: true,
            min_trimmed_half_extent_m: 0.01,
            narrow_opening_fallback: true,
            narrow_opening_clearance_m: 0.024,
            off_centre_steps: 2,
            off_centre_inset_m: 0.008,
            tilt_steps: 2,
            max_tilt_rad: 0.35,
        }
    }
}

/// One grasp candidate.
#[derive(Debug, Clone, PartialEq)]
pub struct GraspCandidate {
    /// TCP pose above the object, fingers open, metres / world frame.
    pub world_from_tcp_pregrasp: Se3,
    /// TCP pose where the fingers close.
    pub world_from_tcp_grasp: Se3,
    /// TCP pose after lifting.
    pub world_from_tcp_lift: Se3,
    /// Hand yaw about world z, radians (`world_from_tcp = Rz(yaw) · Rx(π)`).
    pub hand_yaw_rad: f64,
    /// Unit closing direction of the fingers in the world (horizontal).
    pub closing_axis_in_world: Vector3<f64>,
    /// Finger opening before closing (total gap between the fingers), metres.
    pub open_width_m: f64,
    /// Expected gap once the fingers close on the object (its estimated width across the
    /// closing axis), metres.
    pub expected_closed_width_m: f64,
    /// Distance from the open hand at the grasp pose to the nearest neighbour (grown by the object
    /// margin), metres; `INFINITY` without neighbours.
    pub clearance_m: f64,
    /// Whether the fingers close across the object's shorter horizontal side.
    pub short_side: bool,
    /// How far the TCP (pads' centre) is below the object's top, metres.
    pub depth_below_top_m: f64,
    /// Signed TCP offset from the object's centre along the cuboid's axis across the untilted
    /// closing axis, metres; 0 = centred (`fallback_grasps`).
    pub off_centre_m: f64,
    /// Turn of the closing axis from the cuboid's face normal, radians; 0 = untilted.
    pub tilt_rad: f64,
    /// Whether this is a fallback candidate ([`GraspConfig::narrow_opening_fallback`]): its
    /// collision tests place the fingers at `open_width_m` rather than at the full opening.
    pub fingers_at_opening: bool,
    /// Collision-free IK solution at the pre-grasp pose (None = unreachable).
    pub q_pregrasp: Option<super::JointVector>,
    /// Collision-free IK solution at the grasp pose, seeded from `q_pregrasp` (None = unreachable).
    pub q_grasp: Option<super::JointVector>,
    /// Collision-free IK solution at the lift pose, seeded from `q_grasp` (None = unreachable).
    pub q_lift: Option<super::JointVector>,
}

impl GraspCandidate {
    /// Whether all three poses have collision-free IK solutions.
    pub fn reachable(&self) -> bool {
        self.q_pregrasp.is_some() && self.q_grasp.is_some() && self.q_lift.is_some()
    }
}

/// `world_from_tcp` for a top-down grasp at `p` with hand yaw `yaw_rad`.
pub fn top_down_pose(p: Vector3<f64>, yaw_rad: f64) -> Se3 {
    let r = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw_rad)
        * UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI);
    Se3::from_parts(Translation3::from(p), r)
}

/// Yaw of a top-down TCP pose: the heading of its x axis in the world, radians.
pub fn hand_yaw_of(world_from_tcp: &Se3) -> f64 {
    let x = world_from_tcp.rotation * Vector3::x();
    x.y.atan2(x.x)
}

/// A closing direction before reachability and clearance.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct GraspDirection {
    /// Hand yaw, radians.
    pub yaw_rad: f64,
    /// Object width across the closing axis, metres.
    pub width_m: f64,
    /// Whether the fingers close across the object's shorter horizontal side (always for cylinders).
    pub short_side: bool,
}

/// Closing directions for `object`: across the short side (two yaws π apart) for cuboids, plus the
/// long side when [`GraspConfig::allow_long_side`] and it fits; `cylinder_yaw_count` yaws (and
/// their flips) for cylinders. Sorted by yaw change from `current_yaw_rad`. Directions wider than
/// the gripper allows are dropped.
pub(crate) fn grasp_directions(
    object: &ObjectGeometry,
    current_yaw_rad: f64,
    config: &GraspConfig,
) -> Vec<GraspDirection> {
    let h = object.half_extents;
    let pi = std::f64::consts::PI;
    let both = |yaw: f64, width_m: f64, short_side: bool| {
        [
            GraspDirection { yaw_rad: wrap_angle(yaw), width_m, short_side },
            GraspDirection { yaw_rad: wrap_angle(yaw + pi), width_m, short_side },
        ]
    };
    let mut out: Vec<GraspDirection> = match object.shape {
        Shape::Cuboid => {
            // Closing along the object's x axis needs hand yaw = object yaw + π/2; along y, = yaw.
            let across_x = both(object.yaw_rad + pi / 2.0, 2.0 * h.x, h.x <= h.y);
            let across_y = both(object.yaw_rad, 2.0 * h.y, h.x > h.y);
            let (short, long) = if h.x <= h.y { (across_x, across_y) } else { (across_y, across_x) };
            let mut v = short.to_vec();
            if config.allow_long_side {
                v.extend(long);
            }
            v
        }
        Shape::Cylinder => {
            let n = config.cylinder_yaw_count.max(1);
            let width = 2.0 * object.radius();
            (0..n).flat_map(|k| both(current_yaw_rad + pi * k as f64 / n as f64, width, true)).collect()
        }
    };
    out.retain(|d| d.width_m + config.min_opening_clearance_m <= config.max_opening_m);
    // Closest to the current hand yaw first (stable for ties).
    out.sort_by(|a, b| {
        wrap_angle(a.yaw_rad - current_yaw_rad).abs().total_cmp(&wrap_angle(b.yaw_rad - current_yaw_rad).abs())
    });
    out
}

/// A fallback grasp of a cuboid ([`GraspConfig::narrow_opening_fallback`]): a closing direction
/// turned by `tilt_rad` and a TCP shifted by `offset_m` along the cuboid's axis across the untilted
/// closing axis.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FallbackGrasp {
    /// Hand yaw, radians (the direction's yaw plus `tilt_rad`).
    pub yaw_rad: f64,
    /// Turn of the closing axis from the cuboid's face normal, radians.
    pub tilt_rad: f64,
    /// TCP offset from the centre along the cuboid's axis across the untilted closing axis, metres.
    pub offset_m: f64,
    /// Unit horizontal direction of that axis in the world.
    pub along: Vector3<f64>,
    /// Width of the object along the tilted closing axis through the TCP, metres.
    pub width_m: f64,
}

/// Fallback grasps of `object` for closing direction `d` (cuboids only; none for cylinders, where
/// any yaw is already tried and an off-centre closing on a disc pushes it sideways): tilts
/// `±k / tilt_steps · max_tilt_rad` (k = 0 … [`GraspConfig::tilt_steps`]) times offsets
/// `±k / off_centre_steps · m` (k = 0 … [`GraspConfig::off_centre_steps`]) along the cuboid's axis
/// `u` across the closing axis, where, with `L` and `W` the half-extents along `u` and across it,
/// `m = L − off_centre_inset_m − W · tan|tilt|` keeps both contact points (where the tilted closing
/// line meets the faces, `offset ± W · tan tilt` along `u`) at least the inset inside the ends.
/// The width across the tilted axis is `2W / cos tilt` and must fit the gripper. Order: smaller
/// offset first, then smaller tilt (the untilted centred grasp first).
pub(crate) fn fallback_grasps(object: &ObjectGeometry, d: &GraspDirection, config: &GraspConfig) -> Vec<FallbackGrasp> {
    if object.shape != Shape::Cuboid {
        return Vec::new();
    }
    let along = Vector3::new(d.yaw_rad.cos(), d.yaw_rad.sin(), 0.0);
    let half_l = footprint_support(object, &along);
    let half_w = 0.5 * d.width_m;
    let signed = |n: usize| -> Vec<f64> {
        let mut v = vec![0.0];
        for k in 1..=n {
            v.extend([k as f64 / n as f64, -(k as f64) / n as f64]);
        }
        v
    };
    let mut out = Vec::new();
    for t in signed(config.tilt_steps) {
        let tilt = t * config.max_tilt_rad;
        let width_m = d.width_m / tilt.cos();
        if width_m + config.min_opening_clearance_m > config.max_opening_m {
            continue;
        }
        let m = half_l - config.off_centre_inset_m - half_w * tilt.abs().tan();
        if m < 0.0 {
            continue;
        }
        for f in signed(config.off_centre_steps) {
            out.push(FallbackGrasp {
                yaw_rad: wrap_angle(d.yaw_rad + tilt),
                tilt_rad: tilt,
                offset_m: f * m,
                along,
                width_m,
            });
        }
    }
    out.sort_by(|a, b| {
        a.offset_m.abs().total_cmp(&b.offset_m.abs()).then(a.tilt_rad.abs().total_cmp(&b.tilt_rad.abs()))
    });
    out
}

/// Width of `object` across its narrowest admissible closing axis, metres (for error messages).
pub(crate) fn narrowest_width(object: &ObjectGeometry) -> f64 {
    match object.shape {
        Shape::Cuboid => 2.0 * object.half_extents.x.min(object.half_extents.y),
        Shape::Cylinder => 2.0 * object.radius(),
    }
}

/// TCP grasp heights for `object`, deepest first (see the module docs): the centroid raised so the
/// pads go at most `max_grasp_depth_m` below the top, then (if different by more than 1 mm) the
/// shallow grasp `shallow_grasp_depth_m` below the top, which keeps the hand body higher above
/// neighbours; both at least `min_tcp_height_m`.
pub(crate) fn grasp_heights(object: &ObjectGeometry, config: &GraspConfig) -> Vec<f64> {
    let top = object.center.z + object.half_extents.z;
    let deep = object.center.z.max(top - config.max_grasp_depth_m).max(config.min_tcp_height_m);
    let shallow = (top - config.shallow_grasp_depth_m).max(config.min_tcp_height_m);
    if shallow > deep + 1e-3 {
        vec![deep, shallow]
    } else {
        vec![deep]
    }
}

/// Half-width of `object`'s footprint along the horizontal unit direction `dir` (its support
/// function), metres.
fn footprint_support(object: &ObjectGeometry, dir: &Vector3<f64>) -> f64 {
    match object.shape {
        Shape::Cylinder => object.radius(),
        Shape::Cuboid => {
            let (s, c) = object.yaw_rad.sin_cos();
            let h = object.half_extents;
            h.x * (dir.x * c + dir.y * s).abs() + h.y * (-dir.x * s + dir.y * c).abs()
        }
    }
}

/// The horizontal axes that separate two footprints when their projections do not overlap.
fn footprint_axes(object: &ObjectGeometry) -> Vec<Vector3<f64>> {
    match object.shape {
        Shape::Cylinder => Vec::new(),
        Shape::Cuboid => {
            let (s, c) = object.yaw_rad.sin_cos();
            vec![Vector3::new(c, s, 0.0), Vector3::new(-s, c, 0.0)]
        }
    }
}

/// Horizontal distance from `p` to the footprint of `object` (0 inside), metres.
fn distance_to_footprint(object: &ObjectGeometry, p: &Vector3<f64>) -> f64 {
    let d = Vector3::new(p.x - object.center.x, p.y - object.center.y, 0.0);
    match object.shape {
        Shape::Cylinder => (d.norm() - object.radius()).max(0.0),
        Shape::Cuboid => {
            let (s, c) = object.yaw_rad.sin_cos();
            let (u, v) = (d.x * c + d.y * s, -d.x * s + d.y * c);
            let h = object.half_extents;
            (u.abs() - h.x).max(0.0).hypot((v.abs() - h.y).max(0.0))
        }
    }
}

/// Footprints that overlap by less than this count as touching, metres (rounding).
const OVERLAP_TOLERANCE_M: f64 = 1e-9;

/// Whether the footprints of `a` and `b` overlap by more than [`OVERLAP_TOLERANCE_M`] (separating
/// axes: the cuboids' edge normals, and for a cylinder the exact distance to the other footprint).
pub(crate) fn footprints_overlap(a: &ObjectGeometry, b: &ObjectGeometry) -> bool {
    match (a.shape, b.shape) {
        (Shape::Cylinder, _) => distance_to_footprint(b, &a.center) < a.radius() - OVERLAP_TOLERANCE_M,
        (_, Shape::Cylinder) => distance_to_footprint(a, &b.center) < b.radius() - OVERLAP_TOLERANCE_M,
        _ => {
            let d = Vector3::new(b.center.x - a.center.x, b.center.y - a.center.y, 0.0);
            footprint_axes(a)
                .iter()
                .chain(footprint_axes(b).iter())
                .all(|n| d.dot(n).abs() < footprint_support(a, n) + footprint_support(b, n) - OVERLAP_TOLERANCE_M)
        }
    }
}

/// `neighbour` cut back so its footprint no longer overlaps `target`'s, or None when too little
/// of it would be left (every horizontal half-extent at least `min_half_m`).
///
/// Two solid objects cannot overlap, so the overlap of their estimates is map error; while the
/// target is grasped it is given to the target, and the neighbour keeps the side away from it. A
/// cuboid is cut by a plane parallel to one of its faces, the cut that keeps most of it: along
/// its axis `n` (pointing towards the target) the kept slab ends where the target's footprint
/// begins. A cylinder keeps its centre and shrinks to the distance from its centre to the target's
/// footprint. Heights are unchanged. A neighbour that does not overlap is returned unchanged.
pub fn trim_neighbour(target: &ObjectGeometry, neighbour: &ObjectGeometry, min_half_m: f64) -> Option<ObjectGeometry> {
    if !footprints_overlap(target, neighbour) {
        return Some(*neighbour);
    }
    match neighbour.shape {
        Shape::Cylinder => {
            let r = distance_to_footprint(target, &neighbour.center);
            (r >= min_half_m)
                .then(|| ObjectGeometry { half_extents: Vector3::new(r, r, neighbour.half_extents.z), ..*neighbour })
        }
        Shape::Cuboid => {
            let d = Vector3::new(target.center.x - neighbour.center.x, target.center.y - neighbour.center.y, 0.0);
            let h = neighbour.half_extents;
            let axes = footprint_axes(neighbour);
            let mut best: Option<(f64, ObjectGeometry)> = None;
            for (k, axis) in axes.iter().enumerate() {
                let half = if k == 0 { h.x } else { h.y };
                for sign in [1.0, -1.0] {
                    let n = axis * sign;
                    // Where the target's footprint begins along n, from the neighbour's centre.
                    let near = d.dot(&n) - footprint_support(target, &n);
                    let kept_half = (near.min(half) + half) / 2.0;
                    if kept_half < min_half_m || best.is_some_and(|(b, _)| b >= kept_half / half) {
                        continue;
                    }
                    let mut half_extents = h;
                    half_extents[k] = kept_half;
                    let center = neighbour.center + n * (near.min(half) - half) / 2.0;
                    best = Some((kept_half / half, ObjectGeometry { center, half_extents, ..*neighbour }));
                }
            }
            best.map(|(_, g)| g)
        }
    }
}

/// The grasp's obstacles: `neighbours` trimmed by `target` ([`trim_neighbour`]) when
/// [`GraspConfig::trim_overlapping_neighbours`], else unchanged.
pub fn trim_neighbours(
    target: &ObjectGeometry,
    neighbours: &[ObjectGeometry],
    config: &GraspConfig,
) -> Vec<ObjectGeometry> {
    if !config.trim_overlapping_neighbours {
        return neighbours.to_vec();
    }
    neighbours.iter().filter_map(|n| trim_neighbour(target, n, config.min_trimmed_half_extent_m)).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn block(yaw: f64, hx: f64, hy: f64, hz: f64) -> ObjectGeometry {
        ObjectGeometry {
            shape: Shape::Cuboid,
            center: Vector3::new(0.5, 0.0, hz),
            yaw_rad: yaw,
            half_extents: Vector3::new(hx, hy, hz),
        }
    }

    #[test]
    fn fallback_grasps_keep_the_contacts_inside_the_block() {
        let c = GraspConfig::default();
        // 10 cm × 5 cm block along world x; short-side closing along y (hand yaw 0): u = x.
        let b = block(0.0, 0.05, 0.025, 0.012);
        let d = GraspDirection { yaw_rad: 0.0, width_m: 0.05, short_side: true };
        let f = fallback_grasps(&b, &d, &c);
        // 5 tilts (0, ±0.175, ±0.35) × 5 offsets; all fit (5 cm / cos 0.35 = 5.3 cm).
        assert_eq!(f.len(), 25);
        assert_eq!((f[0].offset_m, f[0].tilt_rad), (0.0, 0.0));
        for g in &f {
            assert!((g.yaw_rad - g.tilt_rad).abs() < 1e-12);
            assert!((g.width_m - 0.05 / g.tilt_rad.cos()).abs() < 1e-12);
            // The tilted closing line through the TCP meets the faces y = ±2.5 cm at
            // x = offset ± 2.5 cm · tan(tilt): both at least the inset inside x = ±5 cm.
            let reach = g.offset_m.abs() + 0.025 * g.tilt_rad.tan().abs();
            assert!(reach <= 0.05 - c.off_centre_inset_m + 1e-12);
        }
        // The largest untilted offset: 5 − 0.8 = 4.2 cm; at 0.35 rad: 4.2 − 2.5 · tan 0.35.
        let max_at =
            |t: f64| f.iter().filter(|g| (g.tilt_rad - t).abs() < 1e-12).map(|g| g.offset_m).fold(0.0, f64::max);
        assert!((max_at(0.0) - 0.042).abs() < 1e-12);
        assert!((max_at(0.35) - (0.042 - 0.025 * 0.35f64.tan())).abs() < 1e-12);
        // Tilts that make the chord too wide are dropped: a 7.5 cm block fits untilted only.
        let wide = GraspDirection { width_m: 0.075, ..d };
        assert!(fallback_grasps(&block(0.0, 0.05, 0.0375, 0.012), &wide, &c).iter().all(|g| g.tilt_rad == 0.0));
        // Cylinders get none.
        let can = ObjectGeometry { shape: Shape::Cylinder, ..b };
        assert!(fallback_grasps(&can, &d, &c).is_empty());
    }

    #[test]
    fn top_down_pose_points_down_and_yaw_round_trips() {
        for yaw in [-3.0, -1.0, 0.0, 0.4, 2.5] {
            let t = top_down_pose(Vector3::new(0.1, 0.2, 0.3), yaw);
            assert!((t.rotation * Vector3::z() - Vector3::new(0.0, 0.0, -1.0)).norm() < 1e-12);
            assert!(wrap_angle(hand_yaw_of(&t) - yaw).abs() < 1e-12);
            // Closing axis (hand y) = (sin yaw, −cos yaw, 0).
            assert!((t.rotation * Vector3::y() - Vector3::new(yaw.sin(), -yaw.cos(), 0.0)).norm() < 1e-12);
        }
    }

    #[test]
    fn cuboid_closes_across_the_short_side() {
        let c = GraspConfig::default();
        for (yaw, hx, hy) in [(0.3, 0.02, 0.03), (0.3, 0.03, 0.02), (-1.2, 0.03, 0.03)] {
            let b = block(yaw, hx, hy, 0.03);
            let short = if hx <= hy {
                Vector3::new(yaw.cos(), yaw.sin(), 0.0)
            } else {
                Vector3::new(-yaw.sin(), yaw.cos(), 0.0)
            };
            let dirs = grasp_directions(&b, 0.0, &c);
            assert_eq!(dirs.len(), 4);
            for d in dirs {
                let closing = top_down_pose(Vector3::zeros(), d.yaw_rad).rotation * Vector3::y();
                let expected = if d.short_side { 2.0 * hx.min(hy) } else { 2.0 * hx.max(hy) };
                assert!((d.width_m - expected).abs() < 1e-12);
                // Short-side grasps close along the short axis, long-side ones across it.
                let along = closing.dot(&short).abs();
                assert!(if d.short_side { along > 1.0 - 1e-12 } else { along < 1e-12 });
            }
            let only_short = GraspConfig { allow_long_side: false, ..GraspConfig::default() };
            assert!(grasp_directions(&b, 0.0, &only_short).iter().all(|d| d.short_side));
        }
    }

    #[test]
    fn candidates_are_ordered_by_yaw_change_and_height_is_clamped() {
        let c = GraspConfig::default();
        let b = block(0.0, 0.02, 0.05, 0.03);
        let only_short = GraspConfig { allow_long_side: false, ..GraspConfig::default() };
        let dirs = grasp_directions(&b, 1.4, &only_short);
        // Short side along x → hand yaw π/2 or −π/2; from 1.4 rad the first is π/2.
        assert!((dirs[0].yaw_rad - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
        // 6 cm tall: top − depth = 3.5 cm > centroid 3 cm → 3.5 cm; shallow 6 − 1.2 = 4.8 cm.
        let hs = grasp_heights(&b, &c);
        assert!((hs[0] - 0.035).abs() < 1e-12 && (hs[1] - 0.048).abs() < 1e-12);
        // 2 cm tall: centroid 1 cm, raised to the minimum TCP height; no distinct shallow grasp.
        assert_eq!(grasp_heights(&block(0.0, 0.02, 0.02, 0.01), &c), vec![c.min_tcp_height_m]);
        // 20 cm tall: TCP 2.5 cm below the top.
        assert!((grasp_heights(&block(0.0, 0.02, 0.02, 0.1), &c)[0] - 0.175).abs() < 1e-12);
        // 7.8 cm wide on both sides: too wide with the 4 mm minimum clearance.
        assert!(grasp_directions(&block(0.0, 0.039, 0.039, 0.03), 0.0, &c).is_empty());
    }

    fn at(shape: Shape, x: f64, y: f64, yaw: f64, hx: f64, hy: f64) -> ObjectGeometry {
        ObjectGeometry {
            shape,
            center: Vector3::new(x, y, 0.05),
            yaw_rad: yaw,
            half_extents: Vector3::new(hx, hy, 0.05),
        }
    }

    #[test]
    fn an_overlapping_cuboid_keeps_its_far_side() {
        // Target 6 cm square at the origin; neighbour 12 cm × 6 cm centred 5 cm along +x: it reaches
        // 3 cm into the target. Cut at the target's face x = 0.03: kept x ∈ [0.03, 0.11].
        let target = at(Shape::Cuboid, 0.0, 0.0, 0.0, 0.03, 0.03);
        let bloated = at(Shape::Cuboid, 0.05, 0.0, 0.0, 0.06, 0.03);
        assert!(footprints_overlap(&target, &bloated));
        let t = trim_neighbour(&target, &bloated, 0.01).unwrap();
        assert!((t.center.x - 0.07).abs() < 1e-12 && t.center.y.abs() < 1e-12);
        assert!((t.half_extents.x - 0.04).abs() < 1e-12 && (t.half_extents.y - 0.03).abs() < 1e-12);
        assert!(!footprints_overlap(&target, &t));
        // The same neighbour turned by 90° (its x axis along world y) is cut along its own y axis.
        let turned = at(Shape::Cuboid, 0.05, 0.0, std::f64::consts::FRAC_PI_2, 0.03, 0.06);
        let t = trim_neighbour(&target, &turned, 0.01).unwrap();
        assert!((t.center.x - 0.07).abs() < 1e-12 && (t.half_extents.y - 0.04).abs() < 1e-12);
        // Rotated target (45°): its footprint reaches 3√2 cm along x, and the cut follows it.
        let diamond = at(Shape::Cuboid, 0.0, 0.0, std::f64::consts::FRAC_PI_4, 0.03, 0.03);
        let t = trim_neighbour(&diamond, &bloated, 0.01).unwrap();
        let near_face = t.center.x - t.half_extents.x;
        assert!((near_face - 0.03 * 2f64.sqrt()).abs() < 1e-12);
        assert!((t.center.x + t.half_extents.x - 0.11).abs() < 1e-12);
        assert!(!footprints_overlap(&diamond, &t));
    }

    #[test]
    fn touching_or_distant_neighbours_are_kept_and_swallowed_ones_dropped() {
        let target = at(Shape::Cuboid, 0.0, 0.0, 0.3, 0.03, 0.03);
        // Exactly touching along the target's x axis: unchanged.
        let (s, c) = 0.3f64.sin_cos();
        let touching = at(Shape::Cuboid, 0.06 * c, 0.06 * s, 0.3, 0.03, 0.03);
        assert_eq!(trim_neighbour(&target, &touching, 0.01), Some(touching));
        let far = at(Shape::Cylinder, 0.2, 0.0, 0.0, 0.03, 0.03);
        assert_eq!(trim_neighbour(&target, &far, 0.01), Some(far));
        // Centre inside the target: nothing of it is left outside the target → dropped.
        let inside = at(Shape::Cuboid, 0.01, 0.0, 0.0, 0.03, 0.03);
        assert_eq!(trim_neighbour(&target, &inside, 0.01), None);
        let cfg = GraspConfig::default();
        assert_eq!(trim_neighbours(&target, &[inside, far], &cfg), vec![far]);
        let off = GraspConfig { trim_overlapping_neighbours: false, ..GraspConfig::default() };
        assert_eq!(trim_neighbours(&target, &[inside, far], &off), vec![inside, far]);
    }

    #[test]
    fn an_overlapping_cylinder_shrinks_to_the_target() {
        // A 7 cm can centred 8 cm from a 6 cm square: its radius becomes the 5 cm gap to the face.
        let target = at(Shape::Cuboid, 0.0, 0.0, 0.0, 0.03, 0.03);
        let blob = at(Shape::Cylinder, 0.08, 0.0, 0.0, 0.07, 0.07);
        let t = trim_neighbour(&target, &blob, 0.01).unwrap();
        assert!((t.radius() - 0.05).abs() < 1e-12 && t.center == blob.center);
        assert!(!footprints_overlap(&target, &t));
        // Towards a corner the distance is to the corner: (0.06, 0.06) → √2·3 cm.
        let diag = at(Shape::Cylinder, 0.06, 0.06, 0.0, 0.07, 0.07);
        let t = trim_neighbour(&target, &diag, 0.01).unwrap();
        assert!((t.radius() - 0.03 * 2f64.sqrt()).abs() < 1e-12);
        // Cylinder target, cuboid neighbour: cut at the disc's support.
        let can = at(Shape::Cylinder, 0.0, 0.0, 0.0, 0.03, 0.03);
        let t = trim_neighbour(&can, &at(Shape::Cuboid, 0.05, 0.0, 0.0, 0.06, 0.03), 0.01).unwrap();
        assert!((t.center.x - t.half_extents.x - 0.03).abs() < 1e-12);
    }
}
