//! Motion planning for the Panda: kinematics, collision checking, joint-space path planning,
//! time-optimal trajectories and grasp synthesis from the estimated object map (issue 8, items
//! 1–4; the paper's grasping / placement experiments act on its map, Sec. "Experiments").
//!
//! # Entry point
//! [`Planner`] bundles everything; the Python side calls only it:
//! - [`Planner::new`]`(urdf_path, PlannerConfig)`: reads the URDF (e.g. mani-skill's
//!   `assets/robots/panda/panda_v2.urdf`; the path is the caller's, nothing is hard-coded);
//! - [`Planner::plan_to_joints`]`(q_start, q_goal, obstacles)` and
//!   [`Planner::plan_to_pose`]`(q_start, world_from_tcp_target, obstacles)` →
//!   [`JointTrajectory`] sampled every [`PlannerConfig::sample_dt_s`];
//! - [`Planner::grasp_candidates`]`(object, neighbours, q_current)` → ranked [`GraspCandidate`]s,
//!   and [`Planner::plan_grasp`] → the pre-grasp / approach / lift trajectories of one candidate.
//!
//! Obstacles are map estimates ([`ObjectGeometry`]); the table top is z = 0 and the robot base is
//! the world origin. All joint vectors are the 7 arm joints (radians); the gripper is the caller's.
//!
//! # Pieces (one file each)
//! - [`kinematics`]: URDF chain (urdf-rs), forward kinematics of every link, damped-least-squares
//!   IK `Δq = Jᵀ(JJᵀ + λ²I)⁻¹e` with joint-limit clamping and seeded random restarts.
//! - [`collision`]: capsule model of the arm (sizes documented in [`collision::panda_capsules`])
//!   against the table, the map objects grown by a margin, and itself (parry3d-f64).
//! - `rrt`: straight line when free, else RRT-Connect (seeded) + random shortcutting; edges are
//!   checked every [`PlannerConfig::edge_resolution_rad`] of the largest joint motion.
//! - [`trajectory`]: chained rest-to-rest, time-optimal Ruckig moves along the checked straight
//!   segments under per-joint velocity / acceleration / jerk limits.
//! - [`report`]: the results as records for the bindings ([`report::Attempt`], [`report::GraspPlan`])
//!   and the settings by name ([`report::PlannerOverrides`]).
//! - [`grasp`]: top-down grasps (short side for cuboids, any yaw for cylinders), opening from the
//!   estimated size, ranked by reachability, clearance, side, depth and yaw change.
//!
//! # Typical use (per grasp attempt)
//! 1. `planner.plan_grasp(q_now, &target_estimate, &other_estimates)` → [`GraspMotion`] or a typed
//!    per-attempt failure ([`PlanError::TooWide`], [`PlanError::NoReachableGrasp`], …).
//! 2. Open the fingers to `candidate.open_width_m` (each finger joint = width / 2), execute
//!    `to_pregrasp`, then `approach`, close, execute `lift`.
//! 3. Views and other arm moves: `plan_to_pose(q_now, world_from_tcp, &all_estimates)`; with
//!    a camera on the hand, `world_from_tcp = world_from_camera · tcp_from_camera⁻¹`.
//!
//! # Choices where the issue / paper is vague (all config fields)
//! - Capsules fitted to the URDF's collision meshes (they cover them up to 5 mm, see
//!   [`collision::panda_capsules`]); self-collision pairs from the Panda SRDF.
//! - Object margin 1 cm, table margin 5 mm, edge resolution 0.01 rad (≤ 9 mm at the TCP).
//! - Trajectories stop at every waypoint (chained single moves; Ruckig's waypoint mode needs a
//!   web service and is never used); each move is time-optimal along its straight segment.
//! - The planner is deterministic: all randomness comes from `rng_seed`; the optional wall-clock
//!   time-out is off by default (an iteration limit bounds the work instead).
//! - Grasps are top-down only; tall objects are grasped near their top (`max_grasp_depth_m`);
//!   fallbacks are the cuboid's long side when it fits and a shallower grasp
//!   (`shallow_grasp_depth_m`) that lifts the 20 cm wide hand body above close neighbours.
//! - When no top-down candidate is reachable, cuboids get fallback candidates: closing axis tilted,
//!   TCP off-centre, fingers opened to the chord plus `narrow_opening_clearance_m` and modelled at
//!   that opening (`narrow_opening_fallback`).
//! - A neighbour's estimate that overlaps the target's footprint is cut back to it for that grasp
//!   (`trim_overlapping_neighbours`); one that would keep less than `min_trimmed_half_extent_m`
//!   is left out.
//! - The approach (pre-grasp → grasp) is a straight joint-space segment between IK solutions
//!   seeded from each other; the TCP stays within 1 cm of the vertical line (tested).

pub mod collision;
pub mod grasp;
pub mod kinematics;
pub mod report;
mod rrt;
pub mod trajectory;

use std::path::Path;

use thiserror::Error;

pub use collision::{ArmCapsule, ArmCollisionModel, CollisionScene, Contact};
pub use grasp::{GraspCandidate, GraspConfig};
pub use kinematics::{ArmChain, IkConfig, IkSolution, JointInfo, JointVector, ARM_DOF};
pub use rrt::{joint_distance, joint_max_abs_diff};
pub use trajectory::{time_parameterize_path, JointTrajectory, MotionLimits};

use crate::geometry::{ObjectGeometry, Se3};

/// Errors of the planning module.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum PlanError {
    /// The URDF could not be read or parsed.
    #[error("cannot read URDF {path}: {reason}")]
    Urdf {
        /// Path given.
        path: String,
        /// Parser message.
        reason: String,
    },
    /// No joint path leads from the root link to the tip link.
    #[error("no kinematic chain from {root} to {tip}")]
    NoChain {
        /// Root link.
        root: String,
        /// Tip link.
        tip: String,
    },
    /// A joint type the chain does not support (only revolute and fixed).
    #[error("joint {joint}: unsupported ({kind})")]
    UnsupportedJoint {
        /// Joint name.
        joint: String,
        /// What is wrong.
        kind: String,
    },
    /// The chain does not have the expected number of actuated joints.
    #[error("chain has {actual} actuated joints, expected {expected}")]
    WrongDof {
        /// Expected.
        expected: usize,
        /// Found.
        actual: usize,
    },
    /// A [`PlannerConfig`] value is out of its range ([`PlannerConfig::validate`]).
    #[error("config.{field}: {reason}")]
    InvalidConfig {
        /// The [`PlannerConfig`] field.
        field: &'static str,
        /// The value and its valid range.
        reason: String,
    },
    /// A collision capsule or self-collision pair names a link not in the chain.
    #[error("unknown link {link}")]
    UnknownLink {
        /// Link name.
        link: String,
    },
    /// A non-finite number in an input.
    #[error("non-finite {what}")]
    NonFinite {
        /// Which input.
        what: &'static str,
    },
    /// A joint configuration outside the joint limits.
    #[error("{what} outside the joint limits (joint {joint}: {value_rad} rad)")]
    OutsideLimits {
        /// Which input.
        what: &'static str,
        /// Joint index (0-based).
        joint: usize,
        /// Offending value.
        value_rad: f64,
    },
    /// A map object with non-finite or non-positive size.
    #[error("obstacle {index} has an invalid geometry")]
    InvalidObject {
        /// Index into the obstacle list.
        index: usize,
    },
    /// A straight-line (Cartesian) TCP motion cannot be followed: no collision-free IK solution
    /// continuing the previous one, or the joints would jump.
    #[error("straight-line motion broken at {fraction:.2} of the way: {reason}")]
    LinearPathBroken {
        /// Fraction of the line reached (0 = start).
        fraction: f64,
        /// What failed.
        reason: String,
    },
    /// A held object with a non-finite or non-positive size or a non-finite grasp pose.
    #[error("held object: invalid geometry or grasp pose")]
    InvalidHeldObject,
    /// IK did not converge from any seed (target unreachable, or every solution collides).
    #[error("IK failed from {seeds} seeds (best error {best_position_error_m} m, {best_orientation_error_rad} rad)")]
    IkNotConverged {
        /// Seeds tried.
        seeds: usize,
        /// Best position error reached, metres.
        best_position_error_m: f64,
        /// Best orientation error reached, radians.
        best_orientation_error_rad: f64,
    },
    /// IK converged but every solution was rejected (collides with the table, an object or the arm).
    #[error("IK found {rejected} solutions from {seeds} seeds, all in collision")]
    IkRejected {
        /// Seeds tried.
        seeds: usize,
        /// Converged solutions rejected.
        rejected: usize,
    },
    /// The start configuration collides.
    #[error("start configuration in collision: {contact:?}")]
    StartInCollision {
        /// First contact found.
        contact: Contact,
    },
    /// The goal configuration collides.
    #[error("goal configuration in collision: {contact:?}")]
    GoalInCollision {
        /// First contact found.
        contact: Contact,
    },
    /// RRT-Connect used its iteration budget without connecting.
    #[error("no collision-free path within {iterations} RRT-Connect iterations")]
    PlannerExhausted {
        /// Iterations used.
        iterations: usize,
    },
    /// The optional wall-clock time-out expired.
    #[error("planner time-out after {seconds} s ({iterations} iterations)")]
    Timeout {
        /// Time-out, seconds.
        seconds: f64,
        /// Iterations done.
        iterations: usize,
    },
    /// Trajectory generation failed.
    #[error("trajectory: {reason}")]
    Trajectory {
        /// Why.
        reason: String,
    },
    /// No grasp candidate is geometrically possible (e.g. the object is wider than the gripper).
    #[error("object {width_m} m wide exceeds the gripper opening {max_opening_m} m")]
    TooWide {
        /// Object width across the closing axis, metres.
        width_m: f64,
        /// Largest opening, metres.
        max_opening_m: f64,
    },
    /// Grasp candidates exist but none is reachable without collision.
    #[error("none of {candidates} grasp candidates is reachable")]
    NoReachableGrasp {
        /// Candidates tried.
        candidates: usize,
    },
    /// Some grasp candidates have collision-free IK solutions, but no collision-free path leads to
    /// (or through) any of them.
    #[error("{reachable} of {candidates} grasp candidates are reachable, but no collision-free path leads to them")]
    NoGraspPath {
        /// Candidates tried.
        candidates: usize,
        /// Candidates with IK solutions for all three poses.
        reachable: usize,
    },
}

/// Settings of the [`Planner`].
#[derive(Debug, Clone, PartialEq)]
pub struct PlannerConfig {
    /// Root link of the arm chain (the world frame). Default `panda_link0`.
    pub root_link: String,
    /// Tool-centre-point link that targets refer to. Default `panda_hand_tcp` (between the finger
    /// pads; z = approach, y = finger closing direction).
    pub tcp_link: String,
    /// Hand link the hand / finger capsules hang on. Default `panda_hand`.
    pub hand_link: String,
    /// IK settings.
    pub ik: IkConfig,
    /// Growth of every map object in all directions, metres. Default 0.01 (map estimates are
    /// off by about a centimetre; the paper's CDE is a few cm).
    pub object_margin_m: f64,
    /// Links (except the base) must stay this far above the table top z = 0, metres. Default 0.005.
    pub table_margin_m: f64,
    /// Collision checks along a segment every this much of the largest joint motion, radians.
    /// Default 0.01 (about 1 cm at the TCP at full reach). In [1e-4, 1] (at most ~6e4 checks
    /// per segment across the joint range).
    pub edge_resolution_rad: f64,
    /// RRT-Connect extension step (joint-space Euclidean), radians. Default 0.3.
    pub rrt_step_rad: f64,
    /// Probability of sampling the other tree's root. Default 0.1.
    pub rrt_goal_bias: f64,
    /// RRT-Connect iteration budget; exhausted → [`PlanError::PlannerExhausted`]. Default 2000.
    pub rrt_max_iterations: usize,
    /// Random shortcut attempts after RRT-Connect. Default 60.
    pub shortcut_iterations: usize,
    /// Optional wall-clock time-out of RRT-Connect, seconds → [`PlanError::Timeout`]. Default None
    /// (keeps results deterministic).
    pub timeout_s: Option<f64>,
    /// Seed of the planner's RNG (ChaCha8). Default 1.
    pub rng_seed: u64,
    /// Trajectory sample period, seconds. Default 0.01 (100 Hz; the sim steps at 1/240 s and can
    /// interpolate or hold). In [1e-4, 1]; a trajectory has at most
    /// [`trajectory::MAX_TRAJECTORY_SAMPLES`] samples.
    pub sample_dt_s: f64,
    /// Joint velocity / acceleration / jerk limits of the trajectories.
    pub limits: MotionLimits,
    /// The arm's collision capsules. Default [`collision::panda_capsules`].
    pub capsules: Vec<ArmCapsule>,
    /// Link pairs checked for self-collision. Default [`collision::panda_self_collision_pairs`].
    pub self_collision_pairs: Vec<(String, String)>,
    /// Grasp synthesis settings.
    pub grasp: GraspConfig,
    /// Straight-line TCP motions ([`Planner::plan_linear`]): IK every this much of the line,
    /// metres. Default 0.01.
    pub linear_step_m: f64,
    /// ... and every this much rotation, radians. Default 0.05.
    pub linear_step_rad: f64,
    /// Largest joint change between two IK steps of a straight line, radians: more means the
    /// solution jumped to another branch and the line is broken. Default 0.15.
    pub linear_max_joint_step_rad: f64,
    /// Every this many IK steps becomes a trajectory waypoint (the joint-space segments between
    /// them stay within a fraction of a millimetre of the line over 3 cm). Default 3.
    pub linear_waypoint_every: usize,
}

impl Default for PlannerConfig {
    fn default() -> Self {
        Self {
            root_link: "panda_link0".into(),
            tcp_link: "panda_hand_tcp".into(),
            hand_link: "panda_hand".into(),
            ik: IkConfig::default(),
            object_margin_m: 0.01,
            table_margin_m: 0.005,
            edge_resolution_rad: 0.01,
            rrt_step_rad: 0.3,
            rrt_goal_bias: 0.1,
            rrt_max_iterations: 2000,
            shortcut_iterations: 60,
            timeout_s: None,
            rng_seed: 1,
            sample_dt_s: 0.01,
            limits: MotionLimits::default(),
            capsules: collision::panda_capsules(),
            self_collision_pairs: collision::panda_self_collision_pairs(),
            grasp: GraspConfig::default(),
            linear_step_m: 0.01,
            linear_step_rad: 0.05,
            linear_max_joint_step_rad: 0.15,
            linear_waypoint_every: 3,
        }
    }
}

/// The three trajectories of one grasp: to the pre-grasp pose (avoiding every object), the
/// approach down to the grasp pose and the lift (both avoiding the neighbours only).
#[derive(Debug, Clone, PartialEq)]
pub struct GraspMotion {
    /// The candidate executed.
    pub candidate: GraspCandidate,
    /// Start → pre-grasp (fingers open at `candidate.open_width_m`).
    pub to_pregrasp: JointTrajectory,
    /// Pre-grasp → grasp (then close the fingers).
    pub approach: JointTrajectory,
    /// Grasp → lift.
    pub lift: JointTrajectory,
}

/// An object held in the gripper: the hand carries it, so motions must keep it clear of the map
/// objects too ([`Planner::holding`]).
#[derive(Debug, Clone, PartialEq)]
pub struct HeldObject {
    /// Its geometry (the map estimate grasped) in the world at the grasp.
    pub geometry: ObjectGeometry,
    /// The TCP pose at the grasp (the object moves rigidly with it afterwards).
    pub world_from_tcp_at_grasp: Se3,
}

impl HeldObject {
    /// The capsule around the object's vertical axis, in the hand frame: radius = the footprint's
    /// circumradius (cylinder radius, cuboid half-diagonal), segment inset by the radius at both ends
    /// so the capsule spans the object's height along its axis (a sphere of that radius at the
    /// centre when the object is lower than it is wide).
    fn capsule(&self, hand_link: &str, hand_from_tcp: &Se3) -> Result<ArmCapsule, PlanError> {
        let g = &self.geometry;
        let h = g.half_extents;
        let ok = g.center.iter().all(|v| v.is_finite())
            && h.iter().all(|v| v.is_finite() && *v > 0.0)
            && self.world_from_tcp_at_grasp.translation.vector.iter().all(|v| v.is_finite())
            && self.world_from_tcp_at_grasp.rotation.coords.iter().all(|v| v.is_finite());
        if !ok {
            return Err(PlanError::InvalidHeldObject);
        }
        let r = match g.shape {
            crate::geometry::Shape::Cylinder => g.radius(),
            crate::geometry::Shape::Cuboid => h.x.hypot(h.y),
        };
        let inset = (h.z - r).max(0.0);
        let up = nalgebra::Vector3::z() * inset;
        let hand_from_world = (self.world_from_tcp_at_grasp * hand_from_tcp.inverse()).inverse();
        let a = hand_from_world * nalgebra::Point3::from(g.center + up);
        let b = hand_from_world * nalgebra::Point3::from(g.center - up);
        Ok(ArmCapsule {
            link: hand_link.to_string(),
            a_in_link: a.coords.into(),
            b_in_link: b.coords.into(),
            radius_m: r,
        })
    }
}

/// The planning facade: kinematics + collision model + planner settings.
#[derive(Debug, Clone)]
pub struct Planner {
    chain: ArmChain,
    model: ArmCollisionModel,
    config: PlannerConfig,
    hand_index: usize,
    hand_from_tcp: Se3,
}

impl PlannerConfig {
    /// Check every numeric field's range (before anything is sized from it); the error names the
    /// field: `edge_resolution_rad` and `sample_dt_s` in [1e-4, 1], `rrt_step_rad` in [1e-3, π],
    /// `rrt_goal_bias` in [0, 1], margins in [0, 1] m, `linear_step_m` and `linear_step_rad` in
    /// [1e-4, 1], `linear_max_joint_step_rad` in (0, π], `linear_waypoint_every` ≥ 1,
    /// `timeout_s` ≥ 0, iteration counts at most 10⁷, finite positive motion limits.
    pub fn validate(&self) -> Result<(), PlanError> {
        let range = |field: &'static str, v: f64, lo: f64, hi: f64, lo_open: bool| {
            let above = if lo_open { v > lo } else { v >= lo };
            if v.is_finite() && above && v <= hi {
                Ok(())
            } else {
                let open = if lo_open { "(" } else { "[" };
                Err(PlanError::InvalidConfig { field, reason: format!("{v} outside {open}{lo}, {hi}]") })
            }
        };
        let pi = std::f64::consts::PI;
        range("edge_resolution_rad", self.edge_resolution_rad, 1e-4, 1.0, false)?;
        range("sample_dt_s", self.sample_dt_s, 1e-4, 1.0, false)?;
        range("rrt_step_rad", self.rrt_step_rad, 1e-3, pi, false)?;
        range("rrt_goal_bias", self.rrt_goal_bias, 0.0, 1.0, false)?;
        range("object_margin_m", self.object_margin_m, 0.0, 1.0, false)?;
        range("table_margin_m", self.table_margin_m, 0.0, 1.0, false)?;
        range("min_trimmed_half_extent_m", self.grasp.min_trimmed_half_extent_m, 0.0, 1.0, false)?;
        range("narrow_opening_clearance_m", self.grasp.narrow_opening_clearance_m, 0.0, 1.0, false)?;
        range("off_centre_inset_m", self.grasp.off_centre_inset_m, 0.0, 1.0, false)?;
        range("max_tilt_rad", self.grasp.max_tilt_rad, 0.0, 1.2, false)?;
        range("linear_step_m", self.linear_step_m, 1e-4, 1.0, false)?;
        range("linear_step_rad", self.linear_step_rad, 1e-4, 1.0, false)?;
        range("linear_max_joint_step_rad", self.linear_max_joint_step_rad, 0.0, pi, true)?;
        if let Some(t) = self.timeout_s.filter(|t| !(t.is_finite() && *t >= 0.0)) {
            return Err(PlanError::InvalidConfig {
                field: "timeout_s", reason: format!("{t} must be finite and ≥ 0")
            });
        }
        const MAX_ITERATIONS: usize = 10_000_000;
        for (field, n, min) in [
            ("rrt_max_iterations", self.rrt_max_iterations, 0),
            ("shortcut_iterations", self.shortcut_iterations, 0),
            ("linear_waypoint_every", self.linear_waypoint_every, 1),
            ("ik_random_restarts", self.ik.random_restarts, 0),
            ("cylinder_yaw_count", self.grasp.cylinder_yaw_count, 0),
            ("off_centre_steps", self.grasp.off_centre_steps, 0),
            ("tilt_steps", self.grasp.tilt_steps, 0),
        ] {
            if n < min || n > MAX_ITERATIONS {
                return Err(PlanError::InvalidConfig {
                    field,
                    reason: format!("{n} outside [{min}, {MAX_ITERATIONS}]"),
                });
            }
        }
        if !self.limits.valid() {
            return Err(PlanError::InvalidConfig { field: "limits", reason: "must be finite and positive".into() });
        }
        Ok(())
    }
}

impl Planner {
    /// Loads the URDF at `urdf_path` and builds the chain `root_link → tcp_link` and the collision
    /// model, after [`PlannerConfig::validate`].
    pub fn new(urdf_path: impl AsRef<Path>, config: PlannerConfig) -> Result<Self, PlanError> {
        config.validate()?;
        let chain = ArmChain::from_urdf(urdf_path.as_ref(), &config.root_link, &config.tcp_link)?;
        let model = ArmCollisionModel::new(&chain, config.capsules.clone(), &config.self_collision_pairs)?;
        let hand_index = chain
            .link_index(&config.hand_link)
            .ok_or_else(|| PlanError::UnknownLink { link: config.hand_link.clone() })?;
        let q0 = [0.0; ARM_DOF];
        let links = chain.forward_all(&q0);
        let world_from_hand = links.get(hand_index).copied().unwrap_or_else(Se3::identity);
        let hand_from_tcp = world_from_hand.inverse() * chain.forward(&q0);
        Ok(Self { chain, model, config, hand_index, hand_from_tcp })
    }

    /// This planner with `held` in the hand: every collision test (IK filtering, paths) also keeps
    /// the held object clear of the map objects (not of the table, where it is put down).
    ///
    /// Errors: [`PlanError::InvalidHeldObject`].
    pub fn holding(&self, held: &HeldObject) -> Result<Self, PlanError> {
        let capsule = held.capsule(&self.config.hand_link, &self.hand_from_tcp)?;
        let model = self.model.with_attached(&self.chain, capsule)?;
        Ok(Self { model, ..self.clone() })
    }

    /// This planner with the fingers modelled at opening `open_width_m` (metres, total gap) instead
    /// of the full [`grasp::GraspConfig::max_opening_m`]
    /// ([`ArmCollisionModel::with_fingers_closed_by`] on the hand link); unchanged when the opening
    /// is the full one or wider.
    pub fn with_fingers_open(&self, open_width_m: f64) -> Self {
        let by = 0.5 * (self.config.grasp.max_opening_m - open_width_m);
        if by <= 0.0 {
            return self.clone();
        }
        Self { model: self.model.with_fingers_closed_by(&self.config.hand_link, by), ..self.clone() }
    }

    /// The kinematic chain (to the TCP).
    pub fn chain(&self) -> &ArmChain {
        &self.chain
    }

    /// The settings.
    pub fn config(&self) -> &PlannerConfig {
        &self.config
    }

    /// The collision model.
    pub fn collision_model(&self) -> &ArmCollisionModel {
        &self.model
    }

    /// `world_from_tcp` at `q`.
    pub fn forward_tcp(&self, q: &JointVector) -> Se3 {
        self.chain.forward(q)
    }

    /// The TCP's 6×7 geometric Jacobian at `q` (rows: linear, angular velocity; world frame).
    pub fn tcp_jacobian(&self, q: &JointVector) -> nalgebra::Matrix6xX<f64> {
        self.chain.forward_with_jacobian(q).1
    }

    /// `world_from_link` of every chain link at `q` with their names (for recording).
    pub fn link_poses(&self, q: &JointVector) -> Vec<(String, Se3)> {
        self.chain.link_names().into_iter().map(String::from).zip(self.chain.forward_all(q)).collect()
    }

    /// `world_from_hand` at `q`.
    pub fn forward_hand(&self, q: &JointVector) -> Se3 {
        self.chain.forward_all(q).get(self.hand_index).copied().unwrap_or_else(Se3::identity)
    }

    /// A collision scene of `obstacles` with the configured margins.
    pub fn scene(&self, obstacles: &[ObjectGeometry]) -> Result<CollisionScene, PlanError> {
        CollisionScene::new(obstacles, self.config.object_margin_m, self.config.table_margin_m)
    }

    /// The first contact of `q` in `scene` (None = free).
    pub fn first_contact(&self, q: &JointVector, scene: &CollisionScene) -> Option<Contact> {
        self.model.first_contact(&self.chain, q, scene)
    }

    /// IK for the TCP (no collision test), first from `seed`.
    pub fn inverse_tcp(&self, world_from_tcp: &Se3, seed: &JointVector) -> Result<IkSolution, PlanError> {
        self.chain.inverse(world_from_tcp, seed, &self.config.ik)
    }

    /// IK for the TCP whose solution is also collision-free in `scene`.
    pub fn inverse_tcp_free(
        &self,
        world_from_tcp: &Se3,
        seed: &JointVector,
        scene: &CollisionScene,
    ) -> Result<IkSolution, PlanError> {
        self.chain
            .inverse_filtered(world_from_tcp, seed, &self.config.ik, |q| self.model.is_free(&self.chain, q, scene))
    }

    /// IK for the TCP from `seed` only (no random restarts, and steps of at most 0.1 rad so the
    /// iteration does not wander off the seed's branch), collision-free in `scene`: for following
    /// a path waypoint by waypoint.
    pub fn inverse_tcp_free_seeded(
        &self,
        world_from_tcp: &Se3,
        seed: &JointVector,
        scene: &CollisionScene,
    ) -> Result<IkSolution, PlanError> {
        let base = &self.config.ik;
        let ik = IkConfig {
            random_restarts: 0,
            max_step_rad: base.max_step_rad.min(0.1),
            max_iterations: base.max_iterations.max(300),
            ..base.clone()
        };
        self.chain.inverse_filtered(world_from_tcp, seed, &ik, |q| self.model.is_free(&self.chain, q, scene))
    }

    fn check_input(&self, q: &JointVector, what: &'static str) -> Result<(), PlanError> {
        if q.iter().any(|v| !v.is_finite()) {
            return Err(PlanError::NonFinite { what });
        }
        for (joint, (v, j)) in q.iter().zip(self.chain.joints()).enumerate() {
            // Small tolerance: simulators report positions a hair past the limits.
            if *v < j.lower_rad - 1e-3 || *v > j.upper_rad + 1e-3 {
                return Err(PlanError::OutsideLimits { what, joint, value_rad: *v });
            }
        }
        Ok(())
    }

    fn checker<'a>(&'a self, scene: &'a CollisionScene) -> rrt::Checker<'a> {
        rrt::Checker { chain: &self.chain, model: &self.model, scene, resolution_rad: self.config.edge_resolution_rad }
    }

    /// A collision-free geometric path (joint waypoints, start first) in `scene`.
    pub fn plan_path(
        &self,
        q_start: &JointVector,
        q_goal: &JointVector,
        scene: &CollisionScene,
    ) -> Result<Vec<JointVector>, PlanError> {
        self.check_input(q_start, "start configuration")?;
        self.check_input(q_goal, "goal configuration")?;
        let mut start = *q_start;
        let mut goal = *q_goal;
        self.chain.clamp(&mut start, 0.0);
        self.chain.clamp(&mut goal, 0.0);
        if let Some(contact) = self.first_contact(&start, scene) {
            return Err(PlanError::StartInCollision { contact });
        }
        if let Some(contact) = self.first_contact(&goal, scene) {
            return Err(PlanError::GoalInCollision { contact });
        }
        rrt::plan_path(&start, &goal, &self.checker(scene), &self.config)
    }

    /// Whether every sample of `positions` is collision-free in `scene`.
    pub fn path_is_free(&self, positions: &[JointVector], scene: &CollisionScene) -> bool {
        let checker = self.checker(scene);
        positions.windows(2).all(|w| match w {
            [a, b] => checker.config_free(a) && checker.segment_free(a, b),
            _ => true,
        }) && positions.last().is_none_or(|q| checker.config_free(q))
    }

    /// Time-parameterises joint waypoints with the configured limits and sample period.
    pub fn time_parameterize(&self, waypoints: &[JointVector]) -> Result<JointTrajectory, PlanError> {
        trajectory::time_parameterize(waypoints, &self.config.limits, self.config.sample_dt_s)
    }

    /// Times a dense joint path through its waypoints without stopping
    /// ([`trajectory::time_parameterize_path`]) with the configured limits and sample period;
    /// `max_joint_speed` (rad/s) caps every joint's velocity limit (a slower camera motion).
    ///
    /// Errors: as [`trajectory::time_parameterize_path`]; a cap that is not finite and positive is
    /// a [`PlanError::Trajectory`].
    pub fn time_parameterize_path(
        &self,
        waypoints: &[JointVector],
        max_joint_speed: Option<f64>,
    ) -> Result<JointTrajectory, PlanError> {
        let mut limits = self.config.limits.clone();
        if let Some(cap) = max_joint_speed {
            if !(cap.is_finite() && cap > 0.0) {
                return Err(PlanError::Trajectory {
                    reason: format!("max_joint_speed must be finite and > 0, got {cap}"),
                });
            }
            for v in &mut limits.max_velocity_rad_s {
                *v = v.min(cap);
            }
        }
        trajectory::time_parameterize_path(waypoints, &limits, self.config.sample_dt_s)
    }

    /// Plans a collision-free, time-parameterised motion `q_start → q_goal` among `obstacles`.
    pub fn plan_to_joints(
        &self,
        q_start: &JointVector,
        q_goal: &JointVector,
        obstacles: &[ObjectGeometry],
    ) -> Result<JointTrajectory, PlanError> {
        let scene = self.scene(obstacles)?;
        let path = self.plan_path(q_start, q_goal, &scene)?;
        self.time_parameterize(&path)
    }

    /// Plans a collision-free motion from `q_start` to a configuration whose TCP is at
    /// `world_from_tcp_target` (collision-free IK seeded from `q_start`, then [`Planner::plan_path`]).
    pub fn plan_to_pose(
        &self,
        q_start: &JointVector,
        world_from_tcp_target: &Se3,
        obstacles: &[ObjectGeometry],
    ) -> Result<JointTrajectory, PlanError> {
        let scene = self.scene(obstacles)?;
        self.check_input(q_start, "start configuration")?;
        let goal = self.inverse_tcp_free(world_from_tcp_target, q_start, &scene)?;
        let path = self.plan_path(q_start, &goal.q, &scene)?;
        self.time_parameterize(&path)
    }

    /// A straight-line motion of the TCP from where it is at `q_start` to `world_from_tcp_target`
    /// (position along the segment, orientation by slerp), e.g. putting an object down or
    /// retreating from it: IK every [`PlannerConfig::linear_step_m`] seeded by the previous step (no
    /// random restarts, so the arm never changes branch), each solution collision-free among
    /// `obstacles` and within [`PlannerConfig::linear_max_joint_step_rad`] of the previous one,
    /// every segment checked; then time-parameterised.
    ///
    /// Errors: [`PlanError::LinearPathBroken`] (with how far it got), input and trajectory errors.
    pub fn plan_linear(
        &self,
        q_start: &JointVector,
        world_from_tcp_target: &Se3,
        obstacles: &[ObjectGeometry],
    ) -> Result<JointTrajectory, PlanError> {
        let scene = self.scene(obstacles)?;
        self.check_input(q_start, "start configuration")?;
        let t = world_from_tcp_target.translation.vector;
        let r = world_from_tcp_target.rotation;
        if !(t.iter().all(|v| v.is_finite()) && r.coords.iter().all(|v| v.is_finite())) {
            return Err(PlanError::NonFinite { what: "linear target" });
        }
        let mut q = *q_start;
        self.chain.clamp(&mut q, 0.0);
        if let Some(contact) = self.first_contact(&q, &scene) {
            return Err(PlanError::StartInCollision { contact });
        }
        let from = self.forward_tcp(&q);
        let c = &self.config;
        let dist = (t - from.translation.vector).norm();
        let angle = from.rotation.angle_to(&r);
        let n = ((dist / c.linear_step_m.max(1e-4)).max(angle / c.linear_step_rad.max(1e-4))).ceil().max(1.0) as usize;
        let checker = self.checker(&scene);
        let mut waypoints = vec![q];
        for k in 1..=n {
            let f = k as f64 / n as f64;
            let pose = Se3::from_parts(
                nalgebra::Translation3::from(from.translation.vector.lerp(&t, f)),
                from.rotation.slerp(&r, f),
            );
            let broken = |reason: String| PlanError::LinearPathBroken { fraction: (k - 1) as f64 / n as f64, reason };
            let next = self.inverse_tcp_free_seeded(&pose, &q, &scene).map_err(|e| broken(e.to_string()))?.q;
            let jump = joint_max_abs_diff(&q, &next);
            if jump > c.linear_max_joint_step_rad {
                return Err(broken(format!("joints jump by {jump:.3} rad")));
            }
            if !checker.segment_free(&q, &next) {
                return Err(broken("segment in collision".into()));
            }
            q = next;
            if k % c.linear_waypoint_every.max(1) == 0 || k == n {
                waypoints.push(q);
            }
        }
        self.time_parameterize(&waypoints)
    }

    /// Grasp candidates for `object` (a map estimate) among `neighbours` (the other map objects,
    /// trimmed where they overlap the object: [`grasp::trim_neighbours`]), ranked: reachable first, then
    /// smaller off-centre offset and tilt (fallback candidates, only when no regular one is
    /// reachable: [`GraspConfig::narrow_opening_fallback`]), then clearance (capped at `clearance_enough_m`), then short side
    /// before long side, deep before shallow, then smaller hand-yaw change from `q_current`.
    ///
    /// Errors: [`PlanError::InvalidObject`] for a degenerate object, [`PlanError::TooWide`] when the
    /// object is wider than the gripper across every admissible closing axis.
    pub fn grasp_candidates(
        &self,
        object: &ObjectGeometry,
        neighbours: &[ObjectGeometry],
        q_current: &JointVector,
    ) -> Result<Vec<GraspCandidate>, PlanError> {
        self.check_input(q_current, "current configuration")?;
        // Validates the object too.
        CollisionScene::new(std::slice::from_ref(object), 0.0, 0.0)?;
        let g = &self.config.grasp;
        let scene = self.scene(&grasp::trim_neighbours(object, neighbours, g))?;
        let current_yaw = grasp::hand_yaw_of(&self.forward_tcp(q_current));
        let directions = grasp::grasp_directions(object, current_yaw, g);
        if directions.is_empty() {
            return Err(PlanError::TooWide {
                width_m: grasp::narrowest_width(object),
                max_opening_m: g.max_opening_m - g.min_opening_clearance_m,
            });
        }
        let top = object.center.z + object.half_extents.z;
        let candidate = |planner: &Planner,
                         scene: &CollisionScene,
                         z: f64,
                         d: &grasp::GraspDirection,
                         f: &grasp::FallbackGrasp,
                         open_width_m: f64,
                         fingers_at_opening: bool| {
            let p = nalgebra::Vector3::new(object.center.x, object.center.y, z) + f.along * f.offset_m;
            let grasp_pose = grasp::top_down_pose(p, f.yaw_rad);
            let up = |h: f64| grasp::top_down_pose(p + nalgebra::Vector3::new(0.0, 0.0, h), f.yaw_rad);
            let pregrasp = up(g.pregrasp_height_m);
            let lift = up(g.lift_height_m);
            let world_from_hand = grasp_pose * self.hand_from_tcp.inverse();
            let clearance_m = planner.model.hand_clearance(&world_from_hand, &self.config.hand_link, scene);
            let q_pregrasp = planner.inverse_tcp_free(&pregrasp, q_current, scene).ok().map(|s| s.q);
            let q_grasp = q_pregrasp.and_then(|qp| planner.inverse_tcp_free(&grasp_pose, &qp, scene).ok().map(|s| s.q));
            let q_lift = q_grasp.and_then(|qg| planner.inverse_tcp_free(&lift, &qg, scene).ok().map(|s| s.q));
            GraspCandidate {
                world_from_tcp_pregrasp: pregrasp,
                world_from_tcp_grasp: grasp_pose,
                world_from_tcp_lift: lift,
                hand_yaw_rad: f.yaw_rad,
                closing_axis_in_world: grasp_pose.rotation * nalgebra::Vector3::y(),
                open_width_m,
                expected_closed_width_m: f.width_m,
                clearance_m,
                short_side: d.short_side,
                depth_below_top_m: top - z,
                off_centre_m: f.offset_m,
                tilt_rad: f.tilt_rad,
                fingers_at_opening,
                q_pregrasp,
                q_grasp,
                q_lift,
            }
        };
        let heights = grasp::grasp_heights(object, g);
        let mut out = Vec::new();
        for &z in &heights {
            for d in &directions {
                let open = (d.width_m + g.opening_clearance_m).min(g.max_opening_m);
                let centred = grasp::FallbackGrasp {
                    yaw_rad: d.yaw_rad,
                    tilt_rad: 0.0,
                    offset_m: 0.0,
                    along: nalgebra::Vector3::zeros(),
                    width_m: d.width_m,
                };
                out.push(candidate(self, &scene, z, d, &centred, open, false));
            }
        }
        if g.narrow_opening_fallback && !out.iter().any(GraspCandidate::reachable) {
            for &z in &heights {
                for d in &directions {
                    for f in grasp::fallback_grasps(object, d, g) {
                        let open = (f.width_m + g.narrow_opening_clearance_m).min(g.max_opening_m);
                        let full = (d.width_m + g.opening_clearance_m).min(g.max_opening_m);
                        if f.offset_m == 0.0 && f.tilt_rad == 0.0 && open >= full - 1e-9 {
                            continue; // the candidate above
                        }
                        let narrowed = self.with_fingers_open(open);
                        out.push(candidate(&narrowed, &scene, z, d, &f, open, true));
                    }
                }
            }
        }
        let yaw_change = |c: &GraspCandidate| crate::geometry::wrap_angle(c.hand_yaw_rad - current_yaw).abs();
        // Clearance beyond `clearance_enough_m` does not matter: compare capped values.
        let capped = |c: &GraspCandidate| c.clearance_m.min(g.clearance_enough_m);
        out.sort_by(|a, b| {
            b.reachable()
                .cmp(&a.reachable())
                .then(a.off_centre_m.abs().total_cmp(&b.off_centre_m.abs()))
                .then(a.tilt_rad.abs().total_cmp(&b.tilt_rad.abs()))
                .then(capped(b).total_cmp(&capped(a)))
                .then(b.short_side.cmp(&a.short_side))
                .then(b.depth_below_top_m.total_cmp(&a.depth_below_top_m))
                .then(yaw_change(a).total_cmp(&yaw_change(b)))
        });
        Ok(out)
    }

    /// Plans the motions of the best reachable grasp of `object`: start → pre-grasp among all
    /// objects, pre-grasp → grasp and grasp → lift among the neighbours only (the fingers straddle
    /// the target); the neighbours are trimmed where they overlap the object
    /// ([`grasp::trim_neighbours`]), both straight lines ([`Planner::plan_linear`]; a joint-space path when the line
    /// cannot be followed). Tries the ranked candidates in order.
    ///
    /// Errors: those of [`Planner::grasp_candidates`], [`PlanError::NoReachableGrasp`] when no
    /// candidate has collision-free IK solutions, [`PlanError::NoGraspPath`] when some have but no
    /// path to them is found.
    pub fn plan_grasp(
        &self,
        q_start: &JointVector,
        object: &ObjectGeometry,
        neighbours: &[ObjectGeometry],
    ) -> Result<GraspMotion, PlanError> {
        let candidates = self.grasp_candidates(object, neighbours, q_start)?;
        let neighbours = &grasp::trim_neighbours(object, neighbours, &self.config.grasp);
        let n = candidates.len();
        let mut all: Vec<ObjectGeometry> = neighbours.to_vec();
        all.push(*object);
        let scene_all = self.scene(&all)?;
        let scene_neigh = self.scene(neighbours)?;
        let reachable = candidates.iter().filter(|c| c.reachable()).count();
        for c in candidates {
            let (Some(qp), Some(qg), Some(ql)) = (c.q_pregrasp, c.q_grasp, c.q_lift) else {
                continue;
            };
            // The pre-grasp must also clear the target itself.
            if self.first_contact(&qp, &scene_all).is_some() {
                continue;
            }
            let Ok(path) = self.plan_path(q_start, &qp, &scene_all) else {
                continue;
            };
            // Approach and lift along the straight vertical line (the fingers straddle the target
            // with a few millimetres to spare; a joint-space line between the two IK solutions can
            // stray by a centimetre); the joint-space line is the fallback.
            // Fallback candidates: the fingers at their planned opening from the pre-grasp on.
            let narrowed;
            let hand: &Planner = if c.fingers_at_opening {
                narrowed = self.with_fingers_open(c.open_width_m);
                &narrowed
            } else {
                self
            };
            let straight_or_path = |from: &JointVector, pose: &Se3, to: &JointVector| -> Option<JointTrajectory> {
                hand.plan_linear(from, pose, neighbours).ok().or_else(|| {
                    hand.plan_path(from, to, &scene_neigh).ok().and_then(|path| hand.time_parameterize(&path).ok())
                })
            };
            let Some(approach) = straight_or_path(&qp, &c.world_from_tcp_grasp, &qg) else {
                continue;
            };
            let q_grasp = approach.goal().copied().unwrap_or(qg);
            let Some(lift) = straight_or_path(&q_grasp, &c.world_from_tcp_lift, &ql) else {
                continue;
            };
            return Ok(GraspMotion { to_pregrasp: self.time_parameterize(&path)?, approach, lift, candidate: c });
        }
        if reachable == 0 {
            Err(PlanError::NoReachableGrasp { candidates: n })
        } else {
            Err(PlanError::NoGraspPath { candidates: n, reachable })
        }
    }
}
