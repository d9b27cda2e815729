//! Time-optimal, jerk-limited trajectories through joint-space waypoints (Ruckig).
//!
//! Each pair of consecutive waypoints becomes one rest-to-rest, time-optimal Ruckig move along the
//! straight joint-space segment the planner checked for collisions (a 1-DOF problem in the arc
//! length with the joint limits projected on the segment, see `solve_move`), so every joint
//! respects its limits and the arm never leaves the segment. Moves are chained (the arm
//! stops at each waypoint). Ruckig's own intermediate-waypoint mode is never used (it calls a
//! network service). The result is sampled at a fixed rate into positions and velocities.

use ruckig::{InputParameter, Result as RuckigResult, Ruckig, Trajectory};

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

    pub(crate) fn valid(&self) -> bool {
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
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
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

/// One solved Ruckig move between two waypoints, as a 1-DOF motion along the segment.
struct Segment {
    trajectory: Trajectory,
    duration_s: f64,
    from: JointVector,
    /// Unit direction of the segment in joint space.
    direction: JointVector,
}

impl Segment {
    /// Position and velocity `t` seconds into the move.
    fn at(&self, t: f64) -> (JointVector, JointVector) {
        let (s, ds, _) = self.trajectory.at_time(t.clamp(0.0, self.duration_s));
        let s = s.first().copied().unwrap_or(0.0);
        let ds = ds.first().copied().unwrap_or(0.0);
        let mut q = self.from;
        let mut v = [0.0; ARM_DOF];
        for ((qi, vi), ui) in q.iter_mut().zip(v.iter_mut()).zip(self.direction.iter()) {
            *qi += ui * s;
            *vi = ui * ds;
        }
        (q, v)
    }
}

/// The time-optimal rest-to-rest move along the straight segment `from → to`: a 1-DOF Ruckig
/// problem in the arc length `s` whose limits are the tightest joint limits projected on the
/// segment direction `u` (`min_i limit_i / |u_i|`), so every joint respects its own limits and the
/// arm never leaves the segment. (Equivalent to Ruckig's phase synchronisation, which may fall back
/// to time synchronisation and leave the line.)
fn solve_move(from: &JointVector, to: &JointVector, limits: &MotionLimits) -> Result<Segment, PlanError> {
    let mut direction = [0.0; ARM_DOF];
    let mut length = 0.0;
    for ((d, a), b) in direction.iter_mut().zip(from.iter()).zip(to.iter()) {
        *d = b - a;
        length += *d * *d;
    }
    let length = length.sqrt();
    for d in direction.iter_mut() {
        *d /= length;
    }
    let project = |l: &JointVector| {
        l.iter()
            .zip(direction.iter())
            .filter(|(_, u)| u.abs() > 1e-12)
            .map(|(l, u)| l / u.abs())
            .fold(f64::INFINITY, f64::min)
    };
    let limits = [&limits.max_velocity_rad_s, &limits.max_acceleration_rad_s2, &limits.max_jerk_rad_s3].map(project);
    let (trajectory, duration_s) = rest_to_rest(length, limits)?;
    Ok(Segment { trajectory, duration_s, from: *from, direction })
}

/// The time-optimal rest-to-rest 1-DOF Ruckig move from 0 to `length` under `[velocity,
/// acceleration, jerk]` limits, and its duration.
fn rest_to_rest(length: f64, limits: [f64; 3]) -> Result<(Trajectory, f64), PlanError> {
    let [v, a, j] = limits;
    let mut input = InputParameter::new(1);
    input.current_position = vec![0.0];
    input.target_position = vec![length];
    input.max_velocity = vec![v];
    input.max_acceleration = vec![a];
    input.max_jerk = vec![j];
    let mut ruckig = Ruckig::new_direct_and_offline(1);
    let mut trajectory = Trajectory::new_direct(1);
    match ruckig.calculate(&mut input, &mut trajectory) {
        RuckigResult::Working | RuckigResult::Finished => {
            let duration_s = trajectory.get_duration();
            Ok((trajectory, duration_s))
        }
        other => Err(PlanError::Trajectory { reason: format!("ruckig: {other:?}") }),
    }
}

/// Most samples of one trajectory (10⁶: about 3 hours at the default 100 Hz), checked before the
/// sample buffers are allocated.
pub const MAX_TRAJECTORY_SAMPLES: usize = 1_000_000;

/// The sample count of a trajectory of `duration_s` sampled every `dt_s`, within
/// [`MAX_TRAJECTORY_SAMPLES`].
fn sample_count(duration_s: f64, dt_s: f64) -> Result<usize, PlanError> {
    let n = (duration_s / dt_s).ceil();
    if !(n.is_finite() && n <= MAX_TRAJECTORY_SAMPLES as f64) {
        return Err(PlanError::Trajectory {
            reason: format!(
                "{duration_s} s sampled every {dt_s} s is more than {MAX_TRAJECTORY_SAMPLES} samples (limits too low?)"
            ),
        });
    }
    Ok(n as usize)
}

/// The first waypoint, after checking the inputs every time parameterisation shares.
fn check_inputs<'a>(
    waypoints: &'a [JointVector],
    limits: &MotionLimits,
    dt_s: f64,
) -> Result<&'a JointVector, PlanError> {
    let Some(first) = waypoints.first() else {
        return Err(PlanError::Trajectory { reason: "no waypoints".into() });
    };
    if !(dt_s.is_finite() && dt_s > 0.0 && limits.valid()) {
        return Err(PlanError::Trajectory { reason: "sample period and limits must be finite and positive".into() });
    }
    if waypoints.iter().any(|q| q.iter().any(|v| !v.is_finite())) {
        return Err(PlanError::NonFinite { what: "trajectory waypoint" });
    }
    Ok(first)
}

/// The sampled trajectory, landing exactly on the goal at rest.
fn finish(
    dt_s: f64,
    times_s: Vec<f64>,
    mut positions: Vec<JointVector>,
    mut velocities: Vec<JointVector>,
    waypoints: &[JointVector],
    duration_s: f64,
) -> JointTrajectory {
    if let (Some(last), Some(goal)) = (positions.last_mut(), waypoints.last()) {
        *last = *goal;
    }
    if let Some(last) = velocities.last_mut() {
        *last = [0.0; ARM_DOF];
    }
    JointTrajectory { dt_s, times_s, positions, velocities, waypoints: waypoints.to_vec(), duration_s }
}

/// Time-parameterises `waypoints` (chained rest-to-rest moves) and samples every `dt_s` seconds.
///
/// Errors: [`PlanError::Trajectory`] for fewer than one waypoint, non-finite input, bad limits or
/// a Ruckig failure.
pub fn time_parameterize(
    waypoints: &[JointVector],
    limits: &MotionLimits,
    dt_s: f64,
) -> Result<JointTrajectory, PlanError> {
    let first = check_inputs(waypoints, limits, dt_s)?;
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
    let n = sample_count(duration_s, dt_s)?;
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
            Some(s) => s.at(t - seg_start),
            None => (*first, [0.0; ARM_DOF]),
        };
        times_s.push(t);
        positions.push(p);
        velocities.push(v);
    }
    Ok(finish(dt_s, times_s, positions, velocities, waypoints, duration_s))
}

/// Time-optimal, jerk-limited timing of a dense joint path *through* its waypoints (no stops):
/// one rest-to-rest 1-DOF Ruckig move of the path parameter `s` = cumulative max-joint distance
/// (`|dq_i/ds| ≤ 1` on every segment), with the tightest joint limits as the limits of `s`, so
/// every joint respects its velocity limit and, within each segment, its acceleration and jerk
/// limits; at a waypoint the path's direction change gives a small velocity step (for paths sampled
/// densely, e.g. a Cartesian camera path every 2 cm). The samples follow the piecewise-linear path.
/// For paths whose corners matter use [`time_parameterize`] (stops at every waypoint).
///
/// Errors: as [`time_parameterize`].
pub fn time_parameterize_path(
    waypoints: &[JointVector],
    limits: &MotionLimits,
    dt_s: f64,
) -> Result<JointTrajectory, PlanError> {
    let first = check_inputs(waypoints, limits, dt_s)?;
    let mut cum = vec![0.0];
    for w in waypoints.windows(2) {
        if let [a, b] = w {
            let d = a.iter().zip(b.iter()).map(|(x, y)| (y - x).abs()).fold(0.0, f64::max);
            cum.push(cum.last().copied().unwrap_or(0.0) + d);
        }
    }
    let length = cum.last().copied().unwrap_or(0.0);
    if length <= 0.0 {
        return Ok(JointTrajectory {
            dt_s,
            times_s: vec![0.0],
            positions: vec![*first],
            velocities: vec![[0.0; ARM_DOF]],
            waypoints: waypoints.to_vec(),
            duration_s: 0.0,
        });
    }
    let tightest = |l: &JointVector| l.iter().copied().fold(f64::INFINITY, f64::min);
    let (trajectory, duration_s) = rest_to_rest(
        length,
        [&limits.max_velocity_rad_s, &limits.max_acceleration_rad_s2, &limits.max_jerk_rad_s3].map(tightest),
    )?;
    let n = sample_count(duration_s, dt_s)?;
    let mut times_s = Vec::with_capacity(n + 1);
    let mut positions = Vec::with_capacity(n + 1);
    let mut velocities = Vec::with_capacity(n + 1);
    let mut seg = 0;
    for k in 0..=n {
        let t = (k as f64 * dt_s).min(duration_s);
        let (s, ds, _) = trajectory.at_time(t);
        let (s, ds) = (s.first().copied().unwrap_or(0.0).clamp(0.0, length), ds.first().copied().unwrap_or(0.0));
        while seg + 2 < cum.len() && cum.get(seg + 1).is_some_and(|c| s > *c) {
            seg += 1;
        }
        let (Some(a), Some(b), Some(c0), Some(c1)) =
            (waypoints.get(seg), waypoints.get(seg + 1), cum.get(seg), cum.get(seg + 1))
        else {
            break;
        };
        let span = c1 - c0;
        let u = if span > 0.0 { ((s - c0) / span).clamp(0.0, 1.0) } else { 1.0 };
        let mut q = *a;
        let mut v = [0.0; ARM_DOF];
        for i in 0..ARM_DOF {
            q[i] = a[i] + u * (b[i] - a[i]);
            v[i] = if span > 0.0 { (b[i] - a[i]) / span * ds } else { 0.0 };
        }
        times_s.push(t);
        positions.push(q);
        velocities.push(v);
    }
    Ok(finish(dt_s, times_s, positions, velocities, waypoints, duration_s))
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// Samples a move finely and checks velocity, acceleration (Ruckig's own) and jerk (finite
    /// differences of the continuous, piecewise-linear acceleration) against every joint's limit.
    #[test]
    fn moves_respect_every_joint_limit_and_stay_on_the_segment() {
        let limits = MotionLimits::default();
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        for _ in 0..20 {
            let a: JointVector = std::array::from_fn(|_| rng.random_range(-2.0..2.0));
            let b: JointVector = std::array::from_fn(|_| rng.random_range(-2.0..2.0));
            let seg = solve_move(&a, &b, &limits).unwrap();
            assert!(seg.duration_s > 0.0);
            let dt = 1e-4;
            let n = (seg.duration_s / dt) as usize;
            let mut prev_acc: Option<f64> = None;
            for k in 0..=n {
                let (_, ds, dds) = seg.trajectory.at_time(k as f64 * dt);
                let (ds, dds) = (ds[0], dds[0]);
                for i in 0..ARM_DOF {
                    let u = seg.direction[i].abs();
                    assert!(u * ds.abs() <= limits.max_velocity_rad_s[i] * (1.0 + 1e-9) + 1e-12);
                    assert!(u * dds.abs() <= limits.max_acceleration_rad_s2[i] * (1.0 + 1e-9) + 1e-12);
                    if let Some(pa) = prev_acc {
                        assert!(u * ((dds - pa) / dt).abs() <= limits.max_jerk_rad_s3[i] * (1.0 + 1e-6) + 1e-9);
                    }
                }
                prev_acc = Some(dds);
            }
            // Ends at the goal at rest.
            let (q, v) = seg.at(seg.duration_s);
            for i in 0..ARM_DOF {
                assert!((q[i] - b[i]).abs() < 1e-9, "goal missed by {}", q[i] - b[i]);
                assert!(v[i].abs() < 1e-9);
            }
            // Time-optimal along the line: some joint reaches a limit (velocity, or else the move is
            // too short to reach it and acceleration or jerk binds).
            let peak = (0..=n).map(|k| seg.trajectory.at_time(k as f64 * dt).1[0].abs()).fold(0.0, f64::max);
            let v_line = seg
                .direction
                .iter()
                .zip(limits.max_velocity_rad_s.iter())
                .filter(|(u, _)| u.abs() > 1e-12)
                .map(|(u, l)| l / u.abs())
                .fold(f64::INFINITY, f64::min);
            assert!(peak <= v_line * (1.0 + 1e-9));
        }
    }

    #[test]
    fn chained_trajectory_hits_waypoints_and_goal() {
        let limits = MotionLimits::default();
        let w: Vec<JointVector> = vec![
            [0.0; ARM_DOF],
            [0.5, -0.3, 0.2, -1.0, 0.1, 1.0, 0.3],
            [0.5, -0.3, 0.2, -1.0, 0.1, 1.0, 0.3],
            [-0.2; ARM_DOF],
        ];
        let t = time_parameterize(&w, &limits, 0.01).unwrap();
        assert_eq!(t.positions.len(), t.times_s.len());
        assert_eq!(t.positions.first(), Some(&w[0]));
        assert_eq!(t.goal(), Some(&w[3]));
        assert!((t.times_s.last().copied().unwrap_or(0.0) - t.duration_s).abs() < 1e-12);
        // Sampled velocities within limits; the middle waypoint is visited (near-zero velocity there).
        for v in &t.velocities {
            for (vi, li) in v.iter().zip(limits.max_velocity_rad_s.iter()) {
                assert!(vi.abs() <= li * (1.0 + 1e-9));
            }
        }
        let closest = t
            .positions
            .iter()
            .map(|q| q.iter().zip(w[1].iter()).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max))
            .fold(f64::INFINITY, f64::min);
        assert!(closest < 1e-3, "waypoint missed by {closest}");
        // A single waypoint is a zero-length trajectory.
        let still = time_parameterize(&w[..1], &limits, 0.01).unwrap();
        assert_eq!(still.positions, vec![w[0]]);
        assert_eq!(still.duration_s, 0.0);
    }

    #[test]
    fn path_timing_passes_through_the_waypoints_within_the_velocity_limits() {
        let limits = MotionLimits::default();
        // A dense curved path (a quarter circle in joints 0 and 1, 40 waypoints).
        let w: Vec<JointVector> = (0..=40)
            .map(|k| {
                let a = std::f64::consts::FRAC_PI_2 * k as f64 / 40.0;
                [a.sin(), 1.0 - a.cos(), 0.0, -1.5, 0.0, 1.5, 0.3 * a]
            })
            .collect();
        let t = time_parameterize_path(&w, &limits, 0.005).unwrap();
        let chained = time_parameterize(&w, &limits, 0.005).unwrap();
        assert_eq!(t.positions.first(), Some(&w[0]));
        assert_eq!(t.goal(), w.last());
        // No stops: much faster than the rest-to-rest chain, and the speed stays up mid-path.
        assert!(t.duration_s < 0.5 * chained.duration_s, "{} vs {}", t.duration_s, chained.duration_s);
        let mid = t.velocities.get(t.velocities.len() / 2).copied().unwrap_or([0.0; ARM_DOF]);
        assert!(mid.iter().map(|v| v.abs()).fold(0.0, f64::max) > 0.5 * limits.max_velocity_rad_s[0]);
        for v in &t.velocities {
            for (vi, li) in v.iter().zip(limits.max_velocity_rad_s.iter()) {
                assert!(vi.abs() <= li * (1.0 + 1e-9), "{vi} > {li}");
            }
        }
        // Every sample lies on the piecewise-linear path (within the sampling of the segments).
        for q in &t.positions {
            let off = w
                .windows(2)
                .map(|p| {
                    let (a, b) =
                        (nalgebra::SVector::<f64, ARM_DOF>::from(p[0]), nalgebra::SVector::<f64, ARM_DOF>::from(p[1]));
                    let x = nalgebra::SVector::<f64, ARM_DOF>::from(*q);
                    let ab = b - a;
                    let u = ((x - a).dot(&ab) / ab.norm_squared()).clamp(0.0, 1.0);
                    (a + ab * u - x).norm()
                })
                .fold(f64::INFINITY, f64::min);
            assert!(off < 1e-9, "sample off the path by {off}");
        }
        // Time-monotone and finishes at rest.
        assert!(t.times_s.windows(2).all(|p| p[1] > p[0]));
        assert_eq!(t.velocities.last(), Some(&[0.0; ARM_DOF]));
    }

    #[test]
    fn bad_trajectory_inputs_are_typed_errors() {
        let limits = MotionLimits::default();
        assert!(matches!(time_parameterize(&[], &limits, 0.01), Err(PlanError::Trajectory { .. })));
        assert!(matches!(time_parameterize(&[[0.0; ARM_DOF]], &limits, 0.0), Err(PlanError::Trajectory { .. })));
        let nan = [[f64::NAN; ARM_DOF], [0.0; ARM_DOF]];
        assert!(matches!(time_parameterize(&nan, &limits, 0.01), Err(PlanError::NonFinite { .. })));
        let zero = MotionLimits { max_jerk_rad_s3: [0.0; ARM_DOF], ..MotionLimits::default() };
        assert!(matches!(
            time_parameterize(&[[0.0; ARM_DOF], [1.0; ARM_DOF]], &zero, 0.01),
            Err(PlanError::Trajectory { .. })
        ));
    }
}
