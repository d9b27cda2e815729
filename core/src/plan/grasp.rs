//! Top-down grasp synthesis from an estimated object ([`ObjectGeometry`] from the map, never
//! ground truth).
//!
//! The TCP (`panda_hand_tcp`, z = approach direction, y = finger closing direction) points straight
//! down over the object's centroid: `world_from_tcp = T(c) · Rz(yaw) · Rx(π)`, so the closing axis
//! is `(sin yaw, −cos yaw, 0)`. For a cuboid the fingers close across its shorter horizontal side
//! (two yaws, π apart); for a cylinder any yaw works and [`GraspConfig::cylinder_yaw_count`] yaws
//! are tried, starting at the current hand yaw. The TCP height is the centroid, raised so the
//! fingers reach at most [`GraspConfig::max_grasp_depth_m`] below the object's top and stay
//! above [`GraspConfig::min_tcp_height_m`]. Each candidate carries pre-grasp (above), grasp and
//! lift poses, the finger opening, its clearance from neighbouring objects and, when reachable, the
//! collision-free IK solutions.

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
    /// Lowest TCP height above the table, metres (finger tips reach ~1 cm below the TCP).
    /// Default 0.015.
    pub min_tcp_height_m: f64,
    /// Pre-grasp pose height above the grasp pose, metres. Default 0.10.
    pub pregrasp_height_m: f64,
    /// Lift height above the grasp pose, metres (the success test lifts ≥ 0.10). Default 0.15.
    pub lift_height_m: f64,
    /// Number of yaws tried for cylinders (evenly spaced over π, starting at the current hand yaw).
    /// Default 6.
    pub cylinder_yaw_count: usize,
}

impl Default for GraspConfig {
    fn default() -> Self {
        Self {
            max_opening_m: PANDA_MAX_OPENING_M,
            opening_clearance_m: 0.02,
            max_grasp_depth_m: 0.025,
            min_tcp_height_m: 0.015,
            pregrasp_height_m: 0.10,
            lift_height_m: 0.15,
            cylinder_yaw_count: 6,
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

/// A geometric grasp before reachability and clearance: (hand yaw, object width across the closing
/// axis).
pub(crate) fn grasp_yaws(
    object: &ObjectGeometry,
    current_yaw_rad: f64,
    config: &GraspConfig,
) -> Vec<(f64, f64)> {
    let h = object.half_extents;
    let mut out: Vec<(f64, f64)> = match object.shape {
        Shape::Cuboid => {
            // Close across the shorter horizontal side.
            let (yaw, width) = if h.x <= h.y {
                (object.yaw_rad + std::f64::consts::FRAC_PI_2, 2.0 * h.x)
            } else {
                (object.yaw_rad, 2.0 * h.y)
            };
            vec![
                (wrap_angle(yaw), width),
                (wrap_angle(yaw + std::f64::consts::PI), width),
            ]
        }
        Shape::Cylinder => {
            let n = config.cylinder_yaw_count.max(1);
            let width = 2.0 * object.radius();
            (0..n)
                .flat_map(|k| {
                    let yaw = current_yaw_rad + std::f64::consts::PI * k as f64 / n as f64;
                    // Symmetric gripper: each yaw also works flipped; keep both so joint 7 can choose.
                    [
                        (wrap_angle(yaw), width),
                        (wrap_angle(yaw + std::f64::consts::PI), width),
                    ]
                })
                .collect()
        }
    };
    // Closest to the current hand yaw first (stable for ties).
    out.sort_by(|a, b| {
        wrap_angle(a.0 - current_yaw_rad)
            .abs()
            .total_cmp(&wrap_angle(b.0 - current_yaw_rad).abs())
    });
    out
}

/// TCP grasp height for `object` (see the module docs).
pub(crate) fn grasp_height(object: &ObjectGeometry, config: &GraspConfig) -> f64 {
    let top = object.center.z + object.half_extents.z;
    object
        .center
        .z
        .max(top - config.max_grasp_depth_m)
        .max(config.min_tcp_height_m)
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
    fn top_down_pose_points_down_and_yaw_round_trips() {
        for yaw in [-3.0, -1.0, 0.0, 0.4, 2.5] {
            let t = top_down_pose(Vector3::new(0.1, 0.2, 0.3), yaw);
            assert!((t.rotation * Vector3::z() - Vector3::new(0.0, 0.0, -1.0)).norm() < 1e-12);
            assert!(wrap_angle(hand_yaw_of(&t) - yaw).abs() < 1e-12);
            // Closing axis (hand y) = (sin yaw, −cos yaw, 0).
            assert!(
                (t.rotation * Vector3::y() - Vector3::new(yaw.sin(), -yaw.cos(), 0.0)).norm()
                    < 1e-12
            );
        }
    }

    #[test]
    fn cuboid_closes_across_the_short_side() {
        let c = GraspConfig::default();
        for (yaw, hx, hy) in [(0.3, 0.02, 0.05), (0.3, 0.05, 0.02), (-1.2, 0.03, 0.03)] {
            let b = block(yaw, hx, hy, 0.03);
            let short = if hx <= hy {
                Vector3::new(yaw.cos(), yaw.sin(), 0.0)
            } else {
                Vector3::new(-yaw.sin(), yaw.cos(), 0.0)
            };
            let yaws = grasp_yaws(&b, 0.0, &c);
            assert_eq!(yaws.len(), 2);
            for (hand_yaw, width) in yaws {
                let closing = top_down_pose(Vector3::zeros(), hand_yaw).rotation * Vector3::y();
                assert!(closing.dot(&short).abs() > 1.0 - 1e-12);
                assert!((width - 2.0 * hx.min(hy)).abs() < 1e-12);
            }
        }
    }

    #[test]
    fn candidates_are_ordered_by_yaw_change_and_height_is_clamped() {
        let c = GraspConfig::default();
        let b = block(0.0, 0.02, 0.05, 0.03);
        let yaws = grasp_yaws(&b, 1.4, &c);
        // Short side along x → hand yaw π/2 or −π/2; from 1.4 rad the first is π/2.
        assert!((yaws[0].0 - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
        // 6 cm tall: TCP at the centroid (3 cm) since top − depth = 3.5 cm > 3 cm → 3.5 cm.
        assert!((grasp_height(&b, &c) - 0.035).abs() < 1e-12);
        // 2 cm tall: centroid 1 cm, raised to the minimum TCP height.
        assert!(
            (grasp_height(&block(0.0, 0.02, 0.02, 0.01), &c) - c.min_tcp_height_m).abs() < 1e-12
        );
        // 20 cm tall: TCP 2.5 cm below the top.
        assert!((grasp_height(&block(0.0, 0.02, 0.02, 0.1), &c) - 0.175).abs() < 1e-12);
    }
}
