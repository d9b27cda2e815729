//! Time-optimal, jerk-limited trajectories through joint-space waypoints (Ruckig).
//!
//! Each pair of consecutive waypoints becomes one rest-to-rest Ruckig move with phase
//! synchronisation, so every joint's profile is a scaled copy of the others and the arm follows
//! the straight joint-space segment the planner checked for collisions. Moves are chained (the arm
//! stops at each waypoint). Ruckig's own intermediate-waypoint mode is never used (it calls a
//! network service). The result is sampled at a fixed rate into positions and velocities.

use ruckig::{InputParameter, Result as RuckigResult, Ruckig, Synchronization, Trajectory};

use super::kinematics::{JointVector, ARM_DOF};
use super::PlanError;

/// Franka Panda joint velocity limits (datasheet), rad/s.
pub const PANDA_MAX_VELOCITY_RAD_S: JointVector = [2.175, 2.175, 2.175, 2.175, 2.61, 2.61, 2.61];
/// Franka Panda joint acceleration limits (datasheet), rad/s².
pub const PANDA_MAX_ACCELERATION_RAD_S2: JointVector = [15.0, 7.5, 10.0, 12.5, 15.0, 20.0, 20.0];
/// Franka Panda joint jerk limits (datasheet), rad/s³.
pub const PANDA_MAX_JERK_RAD_S3: JointVector = [7500.0, 3750.0, 5000.0, 6250.0, 7500.0, 10000.0, 10000.0];

/// Kinematic limits the trajectory respects (per joint).
#[derive(Debug, Clone, PartialEq)]
pub struct MotionLimits {
    /// Velocity limits, rad/s.
    pub max_velocity_rad_s: JointVector,
    /// Acceleration limits, rad/s².
    pub max_acceleration_rad_s2: JointVector,
    /// Jerk limits, rad/s³.
    pub max_jerk_rad_s3: JointVector,
}

impl MotionLimits {
    /// The Panda datasheet limits scaled by `velocity`, `acceleration` and `jerk` factors in (0, 1].
    pub fn panda_scaled(velocity: f64, acceleration: f64, jerk: f64) -> Self {
        Self {
            max_velocity_rad_s: PANDA_MAX_VELOCITY_RAD_S.map(|v| v * velocity),
            max_acceleration_rad_s2: PANDA_MAX_ACCELERATION_RAD_S2.map(|v| v * acceleration),
            max_jerk_rad_s3: PANDA_MAX_JERK_RAD_S3.map(|v| v * jerk),
        }
    }

    fn valid(&self) -> bool {
        [self.max_velocity_rad_s, self.max_acceleration_rad_s2, self.max_jerk_rad_s3]
            .iter()
            .all(|l| l.iter().all(|v| v.is_finite() && *v > 0.0))
    }
}

impl Default for MotionLimits {
    /// Conservative limits for simulation and camera motion: 50 % of the datasheet velocity,
    /// 20 % of its acceleration and 2 % of its jerk.
    fn default() -> Self {
        Self::panda_scaled(0.5, 0.2, 0.02)
    }
}

/// A time-parameterised joint trajectory sampled at a fixed period.
#[derive(Debug, Clone, PartialEq)]
pub struct JointTrajectory {
    /// Sample period, seconds.
    pub dt_s: f64,
    /// Sample times, seconds (0, dt, 2 dt, …; the last sample is the goal at `duration_s`).
    pub times_s: Vec<f64>,
    /// Joint positions at the sample times, radians.
    pub positions: Vec<JointVector>,
    /// Joint velocities at the sample times, rad/s.
    pub velocities: Vec<JointVector>,
    /// The geometric waypoints the trajectory stops at (start first, goal last).
    pub waypoints: Vec<JointVector>,
    /// Total duration, seconds.
    pub duration_s: f64,
}

impl JointTrajectory {
    /// The last sampled configuration (the goal).
    pub fn goal(&self) -> Option<&JointVector> {
        self.positions.last()
    }
}

/// One solved Ruckig move between two waypoints.
struct Segment {
    trajectory: Trajectory,
    duration_s: f64,
}

fn solve_move(from: &JointVector, to: &JointVector, limits: &MotionLimits) -> Result<Segment, PlanError> {
    let mut input = InputParameter::new(ARM_DOF);
    input.synchronization = Synchronization::Phase;
    input.current_position = from.to_vec();
    input.target_position = to.to_vec();
    input.max_velocity = limits.max_velocity_rad_s.to_vec();
    input.max_acceleration = limits.max_acceleration_rad_s2.to_vec();
    input.max_jerk = limits.max_jerk_rad_s3.to_vec();
    let mut ruckig = Ruckig::new_direct_and_offline(ARM_DOF);
    let mut trajectory = Trajectory::new_direct(ARM_DOF);
    let result = ruckig.calculate(&mut input, &mut trajectory);
    match result {
        RuckigResult::Working | RuckigResult::Finished => {
            let duration_s = trajectory.get_duration();
            Ok(Segment { trajectory, duration_s })
        }
        other => Err(PlanError::Trajectory { reason: format!("ruckig: {other:?}") }),
    }
}

fn to_joint_vector(v: &[f64]) -> JointVector {
    let mut q = [0.0; ARM_DOF];
    for (d, s) in q.iter_mut().zip(v.iter()) {
        *d = *s;
    }
    q
}

/// Time-parameterises `waypoints` (chained rest-to-rest moves) and samples every `dt_s` seconds.
///
/// Errors: [`PlanError::Trajectory`] for fewer than one waypoint, non-finite input, bad limits or
/// a Ruckig failure.
pub fn time_parameterize(waypoints: &[JointVector], limits: &MotionLimits, dt_s: f64) -> Result<JointTrajectory, PlanError> {
    let Some(first) = waypoints.first() else {
        return Err(PlanError::Trajectory { reason: "no waypoints".into() });
    };
    if !(dt_s.is_finite() && dt_s > 0.0) || !limits.valid() {
        return Err(PlanError::Trajectory { reason: "sample period and limits must be finite and positive".into() });
    }
    if waypoints.iter().any(|q| q.iter().any(|v| !v.is_finite())) {
        return Err(PlanError::NonFinite { what: "trajectory waypoint" });
    }
    let mut segments = Vec::with_capacity(waypoints.len().saturating_sub(1));
    for pair in waypoints.windows(2) {
        if let [a, b] = pair {
            if a == b {
                continue;
            }
            segments.push(solve_move(a, b, limits)?);
        }
    }
    let duration_s: f64 = segments.iter().map(|s| s.duration_s).sum();
    let n = (duration_s / dt_s).ceil() as usize;
    let mut times_s = Vec::with_capacity(n + 1);
    let mut positions = Vec::with_capacity(n + 1);
    let mut velocities = Vec::with_capacity(n + 1);
    let mut seg_start = 0.0;
    let mut seg_index = 0;
    for k in 0..=n {
        let t = (k as f64 * dt_s).min(duration_s);
        while seg_index + 1 < segments.len() && segments.get(seg_index).is_some_and(|s| t > seg_start + s.duration_s) {
            seg_start += segments.get(seg_index).map_or(0.0, |s| s.duration_s);
            seg_index += 1;
        }
        let (p, v) = match segments.get(seg_index) {
            Some(s) => {
                let (p, v, _) = s.trajectory.at_time((t - seg_start).clamp(0.0, s.duration_s));
                (to_joint_vector(&p), to_joint_vector(&v))
            }
            None => (*first, [0.0; ARM_DOF]),
        };
        times_s.push(t);
        positions.push(p);
        velocities.push(v);
    }
    // Land exactly on the goal.
    if let (Some(last), Some(goal)) = (positions.last_mut(), waypoints.last()) {
        *last = *goal;
    }
    if let Some(last) = velocities.last_mut() {
        *last = [0.0; ARM_DOF];
    }
    Ok(JointTrajectory { dt_s, times_s, positions, velocities, waypoints: waypoints.to_vec(), duration_s })
}
