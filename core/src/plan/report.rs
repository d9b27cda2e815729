//! The planner's results as plain records (what the Python API returns) and its settings by name.
//!
//! A planning attempt that fails for a reason that is part of an experiment (no IK solution, no
//! collision-free path, an object too wide for the gripper) is an [`Attempt`] with a
//! [`FailureCause`], so one failed attempt never aborts a sweep; every other [`PlanError`] (bad
//! input, a planner that cannot be built) stays an error.

use serde::{Deserialize, Serialize};

use super::{GraspMotion, JointTrajectory, MotionLimits, PlanError, PlannerConfig};
use crate::geometry::{rows, Se3};

/// The fields of the records here that are numeric arrays (joint rows, times, 4x4 poses), for
/// bindings that return them as arrays.
pub const ARRAY_FIELDS: [&str; 7] = [
    "times_s",
    "positions",
    "velocities",
    "waypoints",
    "world_from_tcp_pregrasp",
    "world_from_tcp_grasp",
    "world_from_tcp_lift",
];

/// Why one planning attempt failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum FailureCause {
    /// No collision-free IK solution (including no reachable grasp candidate).
    NoIk,
    /// IK found, no collision-free path: a start or goal in collision, RRT exhaustion or time-out,
    /// no path to any reachable grasp, a straight line that cannot be followed.
    NoPath,
    /// The object is wider than the gripper opening.
    TooWide,
    /// Trajectory generation failed.
    Trajectory,
}

impl PlanError {
    /// The per-attempt cause of this error, or None when it is bad input or a setup error.
    pub fn cause(&self) -> Option<FailureCause> {
        match self {
            PlanError::IkNotConverged { .. } | PlanError::IkRejected { .. } | PlanError::NoReachableGrasp { .. } => {
                Some(FailureCause::NoIk)
            }
            PlanError::StartInCollision { .. }
            | PlanError::GoalInCollision { .. }
            | PlanError::PlannerExhausted { .. }
            | PlanError::Timeout { .. }
            | PlanError::NoGraspPath { .. }
            | PlanError::LinearPathBroken { .. } => Some(FailureCause::NoPath),
            PlanError::TooWide { .. } => Some(FailureCause::TooWide),
            PlanError::Trajectory { .. } => Some(FailureCause::Trajectory),
            _ => None,
        }
    }

    /// Whether the planner itself cannot be built (URDF, kinematic chain, collision model), as
    /// opposed to bad input or a per-attempt failure.
    pub fn is_setup(&self) -> bool {
        matches!(
            self,
            PlanError::Urdf { .. }
                | PlanError::NoChain { .. }
                | PlanError::UnsupportedJoint { .. }
                | PlanError::WrongDof { .. }
                | PlanError::UnknownLink { .. }
        )
    }
}

/// One planning attempt's outcome: `{"ok": true, ..the value's fields}` or `{"ok": false, "cause",
/// "message"}` in JSON.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Attempt<T> {
    /// Whether the attempt succeeded.
    pub ok: bool,
    /// The result, on success (its fields sit beside `ok`).
    #[serde(flatten)]
    pub value: Option<T>,
    /// Why it failed, on failure.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub cause: Option<FailureCause>,
    /// The error's text, on failure.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub message: Option<String>,
}

impl<T> Attempt<T> {
    /// The outcome of `result`; an error without a per-attempt [`PlanError::cause`] is returned.
    pub fn from_result(result: Result<T, PlanError>) -> Result<Self, PlanError> {
        match result {
            Ok(value) => Ok(Self { ok: true, value: Some(value), cause: None, message: None }),
            Err(e) => match e.cause() {
                Some(cause) => Ok(Self { ok: false, value: None, cause: Some(cause), message: Some(e.to_string()) }),
                None => Err(e),
            },
        }
    }
}

/// A planned grasp: the chosen candidate's poses and sizes and its three trajectories.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct GraspPlan {
    /// TCP pose above the object (4x4, rows).
    pub world_from_tcp_pregrasp: [[f64; 4]; 4],
    /// TCP pose where the fingers close (4x4, rows).
    pub world_from_tcp_grasp: [[f64; 4]; 4],
    /// TCP pose after lifting (4x4, rows).
    pub world_from_tcp_lift: [[f64; 4]; 4],
    /// Hand yaw about world z, radians.
    pub hand_yaw_rad: f64,
    /// Finger opening before closing, metres.
    pub open_width_m: f64,
    /// Expected gap once the fingers close on the object, metres.
    pub expected_closed_width_m: f64,
    /// Distance to the nearest neighbour, metres; `f64::MAX` without neighbours (JSON has no
    /// infinity).
    pub clearance_m: f64,
    /// Whether the fingers close across the object's shorter horizontal side.
    pub short_side: bool,
    /// How far the TCP is below the object's top, metres.
    pub depth_below_top_m: f64,
    /// TCP offset from the object's centre along the fingers' width, metres (0 = centred).
    pub off_centre_m: f64,
    /// Turn of the closing axis from the cuboid's face normal, radians.
    pub tilt_rad: f64,
    /// Whether the fingers were modelled at `open_width_m` (a fallback candidate).
    pub fingers_at_opening: bool,
    /// Start → pre-grasp.
    pub to_pregrasp: JointTrajectory,
    /// Pre-grasp → grasp.
    pub approach: JointTrajectory,
    /// Grasp → lift.
    pub lift: JointTrajectory,
}

impl From<GraspMotion> for GraspPlan {
    fn from(g: GraspMotion) -> Self {
        let c = &g.candidate;
        let matrix = |t: &Se3| rows(&t.to_homogeneous());
        Self {
            world_from_tcp_pregrasp: matrix(&c.world_from_tcp_pregrasp),
            world_from_tcp_grasp: matrix(&c.world_from_tcp_grasp),
            world_from_tcp_lift: matrix(&c.world_from_tcp_lift),
            hand_yaw_rad: c.hand_yaw_rad,
            open_width_m: c.open_width_m,
            expected_closed_width_m: c.expected_closed_width_m,
            clearance_m: if c.clearance_m.is_finite() { c.clearance_m } else { f64::MAX },
            short_side: c.short_side,
            depth_below_top_m: c.depth_below_top_m,
            off_centre_m: c.off_centre_m,
            tilt_rad: c.tilt_rad,
            fingers_at_opening: c.fingers_at_opening,
            to_pregrasp: g.to_pregrasp,
            approach: g.approach,
            lift: g.lift,
        }
    }
}

/// [`PlannerConfig`] settings by name (the Python API's `config_json`); a missing key keeps the
/// default, an unknown key is an error.
#[derive(Debug, Clone, Default, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlannerOverrides {
    /// [`PlannerConfig::object_margin_m`].
    pub object_margin_m: Option<f64>,
    /// [`PlannerConfig::table_margin_m`].
    pub table_margin_m: Option<f64>,
    /// [`PlannerConfig::edge_resolution_rad`].
    pub edge_resolution_rad: Option<f64>,
    /// [`PlannerConfig::rrt_max_iterations`].
    pub rrt_max_iterations: Option<usize>,
    /// [`PlannerConfig::shortcut_iterations`].
    pub shortcut_iterations: Option<usize>,
    /// [`PlannerConfig::rng_seed`].
    pub rng_seed: Option<u64>,
    /// The IK's `rng_seed`.
    pub ik_seed: Option<u64>,
    /// The IK's `random_restarts`.
    pub ik_random_restarts: Option<usize>,
    /// [`PlannerConfig::sample_dt_s`].
    pub sample_dt_s: Option<f64>,
    /// Fraction in (0, 1] of the Panda's datasheet joint velocity limits. Default 0.5.
    pub velocity_scale: Option<f64>,
    /// Fraction in (0, 1] of the datasheet acceleration limits. Default 0.2.
    pub acceleration_scale: Option<f64>,
    /// Fraction in (0, 1] of the datasheet jerk limits. Default 0.02.
    pub jerk_scale: Option<f64>,
    /// The grasp's `opening_clearance_m`.
    pub opening_clearance_m: Option<f64>,
    /// The grasp's `max_grasp_depth_m`.
    pub max_grasp_depth_m: Option<f64>,
    /// The grasp's `shallow_grasp_depth_m`.
    pub shallow_grasp_depth_m: Option<f64>,
    /// The grasp's `min_tcp_height_m`.
    pub min_tcp_height_m: Option<f64>,
    /// The grasp's `pregrasp_height_m`.
    pub pregrasp_height_m: Option<f64>,
    /// The grasp's `lift_height_m`.
    pub lift_height_m: Option<f64>,
    /// The grasp's `allow_long_side`.
    pub allow_long_side: Option<bool>,
    /// The grasp's `cylinder_yaw_count`.
    pub cylinder_yaw_count: Option<usize>,
    /// The grasp's `trim_overlapping_neighbours`.
    pub trim_overlapping_neighbours: Option<bool>,
    /// The grasp's `min_trimmed_half_extent_m`.
    pub min_trimmed_half_extent_m: Option<f64>,
    /// The grasp's `narrow_opening_fallback`.
    pub narrow_opening_fallback: Option<bool>,
    /// The grasp's `narrow_opening_clearance_m`.
    pub narrow_opening_clearance_m: Option<f64>,
    /// The grasp's `off_centre_steps`.
    pub off_centre_steps: Option<usize>,
    /// The grasp's `off_centre_inset_m`.
    pub off_centre_inset_m: Option<f64>,
    /// The grasp's `tilt_steps`.
    pub tilt_steps: Option<usize>,
    /// The grasp's `max_tilt_rad`.
    pub max_tilt_rad: Option<f64>,
    /// [`PlannerConfig::linear_step_m`].
    pub linear_step_m: Option<f64>,
    /// [`PlannerConfig::linear_max_joint_step_rad`].
    pub linear_max_joint_step_rad: Option<f64>,
}

impl PlannerOverrides {
    /// The default [`PlannerConfig`] with these settings; the limit scales must lie in (0, 1] (the
    /// other ranges are checked by [`PlannerConfig::validate`]).
    pub fn config(&self) -> Result<PlannerConfig, PlanError> {
        let mut c = PlannerConfig::default();
        let set = |target: &mut f64, value: Option<f64>| *target = value.unwrap_or(*target);
        let count = |target: &mut usize, value: Option<usize>| *target = value.unwrap_or(*target);
        set(&mut c.object_margin_m, self.object_margin_m);
        set(&mut c.table_margin_m, self.table_margin_m);
        set(&mut c.edge_resolution_rad, self.edge_resolution_rad);
        count(&mut c.rrt_max_iterations, self.rrt_max_iterations);
        count(&mut c.shortcut_iterations, self.shortcut_iterations);
        c.rng_seed = self.rng_seed.unwrap_or(c.rng_seed);
        c.ik.rng_seed = self.ik_seed.unwrap_or(c.ik.rng_seed);
        count(&mut c.ik.random_restarts, self.ik_random_restarts);
        set(&mut c.sample_dt_s, self.sample_dt_s);
        set(&mut c.grasp.opening_clearance_m, self.opening_clearance_m);
        set(&mut c.grasp.max_grasp_depth_m, self.max_grasp_depth_m);
        set(&mut c.grasp.shallow_grasp_depth_m, self.shallow_grasp_depth_m);
        set(&mut c.grasp.min_tcp_height_m, self.min_tcp_height_m);
        set(&mut c.grasp.pregrasp_height_m, self.pregrasp_height_m);
        set(&mut c.grasp.lift_height_m, self.lift_height_m);
        c.grasp.allow_long_side = self.allow_long_side.unwrap_or(c.grasp.allow_long_side);
        count(&mut c.grasp.cylinder_yaw_count, self.cylinder_yaw_count);
        c.grasp.trim_overlapping_neighbours =
            self.trim_overlapping_neighbours.unwrap_or(c.grasp.trim_overlapping_neighbours);
        set(&mut c.grasp.min_trimmed_half_extent_m, self.min_trimmed_half_extent_m);
        c.grasp.narrow_opening_fallback = self.narrow_opening_fallback.unwrap_or(c.grasp.narrow_opening_fallback);
        set(&mut c.grasp.narrow_opening_clearance_m, self.narrow_opening_clearance_m);
        count(&mut c.grasp.off_centre_steps, self.off_centre_steps);
        set(&mut c.grasp.off_centre_inset_m, self.off_centre_inset_m);
        count(&mut c.grasp.tilt_steps, self.tilt_steps);
        set(&mut c.grasp.max_tilt_rad, self.max_tilt_rad);
        set(&mut c.linear_step_m, self.linear_step_m);
        set(&mut c.linear_max_joint_step_rad, self.linear_max_joint_step_rad);
        let scales = [
            ("velocity_scale", self.velocity_scale.unwrap_or(0.5)),
            ("acceleration_scale", self.acceleration_scale.unwrap_or(0.2)),
            ("jerk_scale", self.jerk_scale.unwrap_or(0.02)),
        ];
        for (field, s) in scales {
            if !(s > 0.0 && s <= 1.0) {
                return Err(PlanError::InvalidConfig { field, reason: format!("{s} outside (0, 1]") });
            }
        }
        c.limits = MotionLimits::panda_scaled(scales[0].1, scales[1].1, scales[2].1);
        Ok(c)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn overrides_set_their_fields_and_keep_the_other_defaults() {
        let o: PlannerOverrides =
            serde_json::from_str(r#"{"object_margin_m": 0.02, "ik_seed": 9, "velocity_scale": 0.25}"#).unwrap();
        let c = o.config().unwrap();
        let d = PlannerConfig::default();
        assert_eq!(c.object_margin_m, 0.02);
        assert_eq!(c.ik.rng_seed, 9);
        assert_eq!(c.table_margin_m, d.table_margin_m);
        assert_eq!(c.limits, MotionLimits::panda_scaled(0.25, 0.2, 0.02));
        assert_eq!(PlannerOverrides::default().config().unwrap(), d);
    }

    #[test]
    fn unknown_keys_and_scales_outside_the_unit_interval_are_refused() {
        assert!(serde_json::from_str::<PlannerOverrides>(r#"{"bogus": 1}"#).is_err());
        let o = PlannerOverrides { jerk_scale: Some(0.0), ..Default::default() };
        assert!(matches!(o.config(), Err(PlanError::InvalidConfig { field: "jerk_scale", .. })));
    }

    #[test]
    fn a_per_attempt_failure_is_an_outcome_and_bad_input_stays_an_error() {
        let failed = Attempt::<f64>::from_result(Err(PlanError::PlannerExhausted { iterations: 5 })).unwrap();
        let json = serde_json::to_value(&failed).unwrap();
        assert_eq!(json["ok"], false);
        assert_eq!(json["cause"], "no_path");
        assert!(json["message"].as_str().unwrap().contains("5 RRT-Connect iterations"));
        let bad = Attempt::<f64>::from_result(Err(PlanError::NonFinite { what: "q_start" }));
        assert_eq!(bad, Err(PlanError::NonFinite { what: "q_start" }));
        assert!(PlanError::Urdf { path: "x".into(), reason: "y".into() }.is_setup());
        assert!(!PlanError::NonFinite { what: "q" }.is_setup());
    }

    #[test]
    fn a_successful_attempt_puts_its_fields_beside_ok() {
        let t = JointTrajectory {
            dt_s: 0.01,
            times_s: vec![0.0],
            positions: vec![[0.0; 7]],
            velocities: vec![[0.0; 7]],
            waypoints: vec![[0.0; 7]],
            duration_s: 0.0,
        };
        let json = serde_json::to_value(Attempt::from_result(Ok(t)).unwrap()).unwrap();
        assert_eq!(json["ok"], true);
        assert_eq!(json["positions"][0].as_array().unwrap().len(), 7);
        assert!(json.get("cause").is_none());
    }
}
