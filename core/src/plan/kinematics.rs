//! Serial-chain kinematics read from a URDF: forward kinematics of every chain link and
//! damped-least-squares inverse kinematics with joint limits and seeded restarts.
//!
//! [`ArmChain::from_urdf`] walks the URDF from a root link (`panda_link0`) to a tip link
//! (`panda_hand` or `panda_hand_tcp`) and keeps the revolute joints in order; fixed joints are
//! folded into the chain. [`ArmChain::forward_all`] returns `world_from_link` for every child link
//! of the chain (the root is the world: the robot base sits at the world origin);
//! [`ArmChain::inverse`] solves for a `world_from_tip` target.

use nalgebra::{Matrix6, Matrix6xX, Translation3, Unit, UnitQuaternion, Vector3, Vector6};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::PlanError;
use crate::geometry::Se3;

/// Number of actuated arm joints of the Panda.
pub const ARM_DOF: usize = 7;

/// A joint configuration of the arm, radians, joint 1 first.
pub type JointVector = [f64; ARM_DOF];

/// Limits and name of one actuated joint, as read from the URDF.
#[derive(Debug, Clone, PartialEq)]
pub struct JointInfo {
    /// URDF joint name (e.g. `panda_joint4`).
    pub name: String,
    /// Lower position limit, radians.
    pub lower_rad: f64,
    /// Upper position limit, radians.
    pub upper_rad: f64,
    /// Velocity limit from the URDF, rad/s.
    pub velocity_limit_rad_s: f64,
}

/// One element of the chain: a fixed transform, then (optionally) a rotation about `axis`.
#[derive(Debug, Clone)]
struct ChainElement {
    /// Name of the link this element ends in.
    child_link: String,
    /// `parent_from_joint` (the URDF `<origin>`).
    parent_from_joint: Se3,
    /// Rotation axis in the joint frame, with the index of the actuated joint; `None` for fixed.
    axis: Option<(Unit<Vector3<f64>>, usize)>,
}

/// Settings of the damped-least-squares IK ([`ArmChain::inverse`]).
#[derive(Debug, Clone, PartialEq)]
pub struct IkConfig {
    /// Accepted position error of the tip, metres. Default 1e-4 (the bar is 1 mm).
    pub position_tolerance_m: f64,
    /// Accepted orientation error of the tip, radians. Default 5e-4 (0.03°; the bar is 0.1°).
    pub orientation_tolerance_rad: f64,
    /// Damping λ of `Δq = Jᵀ (J Jᵀ + λ² I)⁻¹ e`. Default 0.05; larger is steadier near
    /// singularities but slower.
    pub damping: f64,
    /// Largest joint step per iteration, radians (the step is scaled down to it). Default 0.3.
    pub max_step_rad: f64,
    /// Iterations per seed. Default 150.
    pub max_iterations: usize,
    /// Random restarts after the caller's seed, drawn uniformly within the joint limits.
    /// Default 12.
    pub random_restarts: usize,
    /// Seed of the restart RNG (ChaCha8): the same inputs give the same answer. Default 7.
    pub rng_seed: u64,
    /// Margin kept from the joint limits, radians. Default 1e-3.
    pub limit_margin_rad: f64,
}

impl Default for IkConfig {
    fn default() -> Self {
        Self {
            position_tolerance_m: 1e-4,
            orientation_tolerance_rad: 5e-4,
            damping: 0.05,
            max_step_rad: 0.3,
            max_iterations: 150,
            random_restarts: 12,
            rng_seed: 7,
            limit_margin_rad: 1e-3,
        }
    }
}

/// A converged IK solution.
#[derive(Debug, Clone, PartialEq)]
pub struct IkSolution {
    /// Joint configuration, radians.
    pub q: JointVector,
    /// Remaining tip position error, metres.
    pub position_error_m: f64,
    /// Remaining tip orientation error, radians.
    pub orientation_error_rad: f64,
    /// Which seed converged: 0 = the caller's seed, k ≥ 1 = the k-th random restart.
    pub seed_index: usize,
    /// Iterations used on that seed.
    pub iterations: usize,
}

/// A serial chain of revolute joints from a root link to a tip link, read from a URDF.
#[derive(Debug, Clone)]
pub struct ArmChain {
    elements: Vec<ChainElement>,
    joints: Vec<JointInfo>,
    root_link: String,
    tip_link: String,
}

fn rpy_to_quaternion(rpy: [f64; 3]) -> UnitQuaternion<f64> {
    // URDF: fixed-axis roll about x, then pitch about y, then yaw about z = Rz * Ry * Rx.
    UnitQuaternion::from_euler_angles(rpy[0], rpy[1], rpy[2])
}

impl ArmChain {
    /// Reads the URDF at `urdf_path` and builds the chain `root_link → tip_link`. The chain must
    /// contain exactly [`ARM_DOF`] revolute joints (fixed joints are folded in).
    pub fn from_urdf(urdf_path: &std::path::Path, root_link: &str, tip_link: &str) -> Result<Self, PlanError> {
        let robot = urdf_rs::read_file(urdf_path)
            .map_err(|e| PlanError::Urdf { path: urdf_path.display().to_string(), reason: e.to_string() })?;
        Self::from_robot(&robot, root_link, tip_link)
    }

    /// Builds the chain from an already parsed URDF (see [`ArmChain::from_urdf`]).
    pub fn from_robot(robot: &urdf_rs::Robot, root_link: &str, tip_link: &str) -> Result<Self, PlanError> {
        // Walk from the tip up to the root through each link's parent joint.
        let mut reversed: Vec<&urdf_rs::Joint> = Vec::new();
        let mut link = tip_link.to_string();
        while link != root_link {
            let joint = robot
                .joints
                .iter()
                .find(|j| j.child.link == link)
                .ok_or_else(|| PlanError::NoChain { root: root_link.to_string(), tip: tip_link.to_string() })?;
            reversed.push(joint);
            link = joint.parent.link.clone();
            if reversed.len() > robot.joints.len() {
                return Err(PlanError::NoChain { root: root_link.to_string(), tip: tip_link.to_string() });
            }
        }
        let mut elements = Vec::new();
        let mut joints = Vec::new();
        for joint in reversed.iter().rev() {
            let o = &joint.origin;
            let parent_from_joint =
                Se3::from_parts(Translation3::new(o.xyz[0], o.xyz[1], o.xyz[2]), rpy_to_quaternion(*o.rpy));
            let axis = match joint.joint_type {
                urdf_rs::JointType::Fixed => None,
                urdf_rs::JointType::Revolute => {
                    let a = Vector3::new(joint.axis.xyz[0], joint.axis.xyz[1], joint.axis.xyz[2]);
                    let axis = Unit::try_new(a, 1e-9).ok_or_else(|| PlanError::UnsupportedJoint {
                        joint: joint.name.clone(),
                        kind: "zero axis".into(),
                    })?;
                    joints.push(JointInfo {
                        name: joint.name.clone(),
                        lower_rad: joint.limit.lower,
                        upper_rad: joint.limit.upper,
                        velocity_limit_rad_s: joint.limit.velocity,
                    });
                    Some((axis, joints.len() - 1))
                }
                ref other => {
                    return Err(PlanError::UnsupportedJoint { joint: joint.name.clone(), kind: format!("{other:?}") })
                }
            };
            elements.push(ChainElement { child_link: joint.child.link.clone(), parent_from_joint, axis });
        }
        if joints.len() != ARM_DOF {
            return Err(PlanError::WrongDof { expected: ARM_DOF, actual: joints.len() });
        }
        Ok(Self { elements, joints, root_link: root_link.to_string(), tip_link: tip_link.to_string() })
    }

    /// The actuated joints in chain order.
    pub fn joints(&self) -> &[JointInfo] {
        &self.joints
    }

    /// Root link name.
    pub fn root_link(&self) -> &str {
        &self.root_link
    }

    /// Tip link name.
    pub fn tip_link(&self) -> &str {
        &self.tip_link
    }

    /// Names of the links whose poses [`ArmChain::forward_all`] returns, in order.
    pub fn link_names(&self) -> Vec<&str> {
        self.elements.iter().map(|e| e.child_link.as_str()).collect()
    }

    /// Index into [`ArmChain::forward_all`]'s output of the link called `name`.
    pub fn link_index(&self, name: &str) -> Option<usize> {
        self.elements.iter().position(|e| e.child_link == name)
    }

    /// `world_from_link` for every child link of the chain, root first and tip last.
    pub fn forward_all(&self, q: &JointVector) -> Vec<Se3> {
        let mut out = Vec::with_capacity(self.elements.len());
        let mut world_from_link = Se3::identity();
        for e in &self.elements {
            world_from_link *= e.parent_from_joint;
            if let Some((axis, i)) = &e.axis {
                world_from_link *= UnitQuaternion::from_axis_angle(axis, q[*i]);
            }
            out.push(world_from_link);
        }
        out
    }

    /// `world_from_tip`.
    pub fn forward(&self, q: &JointVector) -> Se3 {
        let mut world_from_link = Se3::identity();
        for e in &self.elements {
            world_from_link *= e.parent_from_joint;
            if let Some((axis, i)) = &e.axis {
                world_from_link *= UnitQuaternion::from_axis_angle(axis, q[*i]);
            }
        }
        world_from_link
    }

    /// `world_from_tip` and the 6×7 geometric Jacobian (rows: linear velocity, angular velocity,
    /// both in the world frame).
    pub fn forward_with_jacobian(&self, q: &JointVector) -> (Se3, Matrix6xX<f64>) {
        let mut world_from_link = Se3::identity();
        let mut axes = [(Vector3::zeros(), Vector3::zeros()); ARM_DOF];
        for e in &self.elements {
            world_from_link *= e.parent_from_joint;
            if let Some((axis, i)) = &e.axis {
                if let Some(slot) = axes.get_mut(*i) {
                    *slot = (world_from_link.rotation * axis.into_inner(), world_from_link.translation.vector);
                }
                world_from_link *= UnitQuaternion::from_axis_angle(axis, q[*i]);
            }
        }
        let p_tip = world_from_link.translation.vector;
        let mut jac = Matrix6xX::zeros(ARM_DOF);
        for (i, (z, p)) in axes.iter().enumerate() {
            let lin = z.cross(&(p_tip - p));
            jac.fixed_view_mut::<3, 1>(0, i).copy_from(&lin);
            jac.fixed_view_mut::<3, 1>(3, i).copy_from(z);
        }
        (world_from_link, jac)
    }

    /// Whether `q` is within the joint limits (inclusive).
    pub fn within_limits(&self, q: &JointVector) -> bool {
        self.joints.iter().zip(q.iter()).all(|(j, v)| *v >= j.lower_rad && *v <= j.upper_rad)
    }

    /// Clamps `q` into the joint limits shrunk by `margin_rad`.
    pub fn clamp(&self, q: &mut JointVector, margin_rad: f64) {
        for (v, j) in q.iter_mut().zip(self.joints.iter()) {
            let lo = j.lower_rad + margin_rad;
            let hi = j.upper_rad - margin_rad;
            *v = if lo <= hi { v.clamp(lo, hi) } else { (j.lower_rad + j.upper_rad) / 2.0 };
        }
    }

    /// A configuration drawn uniformly within the joint limits.
    pub fn random_configuration(&self, rng: &mut impl Rng) -> JointVector {
        let mut q = [0.0; ARM_DOF];
        for (v, j) in q.iter_mut().zip(self.joints.iter()) {
            *v = if j.upper_rad > j.lower_rad { rng.random_range(j.lower_rad..j.upper_rad) } else { j.lower_rad };
        }
        q
    }

    /// Damped-least-squares IK for `world_from_tip_target`, first from `seed` then from
    /// `config.random_restarts` seeded random configurations; returns the first converged
    /// solution. Solutions always respect the joint limits.
    ///
    /// Errors: [`PlanError::NonFinite`] for a non-finite target or seed,
    /// [`PlanError::IkNotConverged`] when no seed converges (unreachable target).
    pub fn inverse(
        &self,
        world_from_tip_target: &Se3,
        seed: &JointVector,
        config: &IkConfig,
    ) -> Result<IkSolution, PlanError> {
        self.inverse_filtered(world_from_tip_target, seed, config, |_| true)
    }

    /// Like [`ArmChain::inverse`] but a converged solution must also pass `accept` (e.g. be
    /// collision-free); rejected solutions count as failures and the next seed is tried. When
    /// solutions were found but all rejected the error is [`PlanError::IkRejected`].
    pub fn inverse_filtered(
        &self,
        world_from_tip_target: &Se3,
        seed: &JointVector,
        config: &IkConfig,
        mut accept: impl FnMut(&JointVector) -> bool,
    ) -> Result<IkSolution, PlanError> {
        let t = world_from_tip_target.translation.vector;
        let r = world_from_tip_target.rotation;
        if !(t.iter().all(|v| v.is_finite()) && r.coords.iter().all(|v| v.is_finite())) {
            return Err(PlanError::NonFinite { what: "IK target" });
        }
        if !seed.iter().all(|v| v.is_finite()) {
            return Err(PlanError::NonFinite { what: "IK seed" });
        }
        let mut rng = ChaCha8Rng::seed_from_u64(config.rng_seed);
        let mut best = (f64::INFINITY, f64::INFINITY);
        let mut rejected = 0;
        for seed_index in 0..=config.random_restarts {
            let start = if seed_index == 0 { *seed } else { self.random_configuration(&mut rng) };
            let (sol, pos_err, rot_err) = self.solve_from(world_from_tip_target, start, seed_index, config);
            if pos_err + rot_err < best.0 + best.1 {
                best = (pos_err, rot_err);
            }
            if let Some(sol) = sol {
                if accept(&sol.q) {
                    return Ok(sol);
                }
                rejected += 1;
            }
        }
        if rejected > 0 {
            return Err(PlanError::IkRejected { seeds: config.random_restarts + 1, rejected });
        }
        Err(PlanError::IkNotConverged {
            seeds: config.random_restarts + 1,
            best_position_error_m: best.0,
            best_orientation_error_rad: best.1,
        })
    }

    fn pose_error(target: &Se3, current: &Se3) -> Vector6<f64> {
        let dp = target.translation.vector - current.translation.vector;
        let dr = (target.rotation * current.rotation.inverse()).scaled_axis();
        Vector6::new(dp.x, dp.y, dp.z, dr.x, dr.y, dr.z)
    }

    fn solve_from(
        &self,
        target: &Se3,
        mut q: JointVector,
        seed_index: usize,
        config: &IkConfig,
    ) -> (Option<IkSolution>, f64, f64) {
        self.clamp(&mut q, config.limit_margin_rad);
        let lambda2 = config.damping * config.damping;
        let mut pos_err = f64::INFINITY;
        let mut rot_err = f64::INFINITY;
        for iteration in 0..=config.max_iterations {
            let (current, jac) = self.forward_with_jacobian(&q);
            let e = Self::pose_error(target, &current);
            pos_err = e.fixed_rows::<3>(0).norm();
            rot_err = e.fixed_rows::<3>(3).norm();
            if pos_err <= config.position_tolerance_m && rot_err <= config.orientation_tolerance_rad {
                let sol = IkSolution {
                    q,
                    position_error_m: pos_err,
                    orientation_error_rad: rot_err,
                    seed_index,
                    iterations: iteration,
                };
                return (Some(sol), pos_err, rot_err);
            }
            if iteration == config.max_iterations {
                break;
            }
            let jjt: Matrix6<f64> = &jac * jac.transpose() + Matrix6::identity() * lambda2;
            let Some(chol) = jjt.cholesky() else { break };
            let dq = jac.transpose() * chol.solve(&e);
            let norm = dq.amax();
            let scale = if norm > config.max_step_rad { config.max_step_rad / norm } else { 1.0 };
            for (v, d) in q.iter_mut().zip(dq.iter()) {
                *v += scale * d;
            }
            self.clamp(&mut q, config.limit_margin_rad);
        }
        (None, pos_err, rot_err)
    }
}

/// Rotation angle between two orientations, radians.
pub fn rotation_distance_rad(a: &Se3, b: &Se3) -> f64 {
    a.rotation.angle_to(&b.rotation)
}
