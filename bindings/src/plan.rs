//! `Planner`: the core's Panda motion planner (`objslam_core::plan`) for Python.
//!
//! Joint vectors cross as float64 arrays of 7 (the arm; the gripper is the caller's), poses as 4x4
//! float64 matrices, obstacles as JSON lists of `ObjectGeometry` (the `"geometry"` of the map's
//! object records). Bad input (wrong shapes, non-finite values, joints outside the limits, invalid
//! obstacles, unknown config keys) raises `InputError`; a URDF that cannot be loaded raises
//! `PlanningError`. Planning outcomes that are part of an experiment — no IK solution, no
//! collision-free path, an object too wide for the gripper — are *returned* as
//! `{"ok": False, "cause": ..., "message": ...}` so one failed attempt never aborts a sweep.
//! Causes: `no_ik` (no collision-free IK), `no_path` (IK found, no collision-free path; includes a
//! start or goal in collision and RRT exhaustion / time-out), `too_wide`, `trajectory`.

use numpy::ndarray::Array2;
use numpy::{PyArray1, PyArray2, PyReadonlyArray1, ToPyArray};
use objslam_core::geometry::{ObjectGeometry, Se3};
use objslam_core::plan::{
    GraspMotion, HeldObject, JointTrajectory, JointVector, MotionLimits, PlanError, Planner, PlannerConfig, ARM_DOF,
};
use pyo3::create_exception;
use pyo3::exceptions::PyTypeError;
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::{input_err, json_err, pose, ObjslamError};

create_exception!(_native, PlanningError, ObjslamError, "The planner cannot be built (URDF, chain, collision model).");

/// Which per-attempt cause a planning error is, or None when it is bad input.
fn cause_of(e: &PlanError) -> Option<&'static str> {
    match e {
        PlanError::IkNotConverged { .. } | PlanError::IkRejected { .. } | PlanError::NoReachableGrasp { .. } => {
            Some("no_ik")
        }
        PlanError::StartInCollision { .. }
        | PlanError::GoalInCollision { .. }
        | PlanError::PlannerExhausted { .. }
        | PlanError::Timeout { .. }
        | PlanError::NoGraspPath { .. }
        | PlanError::LinearPathBroken { .. } => Some("no_path"),
        PlanError::TooWide { .. } => Some("too_wide"),
        PlanError::Trajectory { .. } => Some("trajectory"),
        _ => None,
    }
}

/// A per-attempt failure dict, or a raised error for bad input / setup errors.
fn failure<'py>(py: Python<'py>, e: PlanError) -> PyResult<Bound<'py, PyDict>> {
    match cause_of(&e) {
        Some(cause) => {
            let d = PyDict::new(py);
            d.set_item("ok", false)?;
            d.set_item("cause", cause)?;
            d.set_item("message", e.to_string())?;
            Ok(d)
        }
        None => Err(plan_input_err(e)),
    }
}

fn plan_input_err(e: PlanError) -> PyErr {
    match e {
        PlanError::Urdf { .. }
        | PlanError::NoChain { .. }
        | PlanError::UnsupportedJoint { .. }
        | PlanError::WrongDof { .. }
        | PlanError::UnknownLink { .. } => PlanningError::new_err(e.to_string()),
        _ => input_err(e),
    }
}

fn joints(obj: &Bound<'_, PyAny>, field: &str) -> PyResult<JointVector> {
    let arr: PyReadonlyArray1<'_, f64> = obj
        .extract()
        .map_err(|_| PyTypeError::new_err(format!("{field}: expected a float64 array of shape ({ARM_DOF},)")))?;
    let a = arr.as_array();
    if a.len() != ARM_DOF {
        return Err(input_err(format!("{field}: expected {ARM_DOF} arm joints, got {}", a.len())));
    }
    let mut q = [0.0; ARM_DOF];
    for (i, v) in a.iter().enumerate() {
        if !v.is_finite() {
            return Err(input_err(format!("{field}: non-finite value at [{i}]")));
        }
        q[i] = *v;
    }
    Ok(q)
}

/// A (k ≥ 1, 7) float64 array of joint vectors.
fn joint_rows(obj: &Bound<'_, PyAny>, field: &str) -> PyResult<Vec<JointVector>> {
    let arr: numpy::PyReadonlyArray2<'_, f64> = obj
        .extract()
        .map_err(|_| PyTypeError::new_err(format!("{field}: expected a float64 array of shape (k, {ARM_DOF})")))?;
    let a = arr.as_array();
    if a.ncols() != ARM_DOF || a.nrows() == 0 {
        return Err(input_err(format!("{field}: expected shape (k >= 1, {ARM_DOF}), got {:?}", a.shape())));
    }
    let mut rows = Vec::with_capacity(a.nrows());
    for r in a.rows() {
        let mut q = [0.0; ARM_DOF];
        for (d, v) in q.iter_mut().zip(r.iter()) {
            if !v.is_finite() {
                return Err(input_err(format!("{field}: non-finite value")));
            }
            *d = *v;
        }
        rows.push(q);
    }
    Ok(rows)
}

fn geometries(json: &str, field: &str) -> PyResult<Vec<ObjectGeometry>> {
    serde_json::from_str(json).map_err(|e| json_err(field, e))
}

fn geometry(json: &str, field: &str) -> PyResult<ObjectGeometry> {
    serde_json::from_str(json).map_err(|e| json_err(field, e))
}

fn matrix_py<'py>(py: Python<'py>, t: &Se3) -> Bound<'py, PyArray2<f64>> {
    let m = t.to_homogeneous();
    Array2::from_shape_fn((4, 4), |(r, c)| m[(r, c)]).to_pyarray(py)
}

fn rows_py<'py>(py: Python<'py>, rows: &[JointVector]) -> Bound<'py, PyArray2<f64>> {
    Array2::from_shape_fn((rows.len(), ARM_DOF), |(r, c)| rows[r][c]).to_pyarray(py)
}

fn trajectory_py<'py>(py: Python<'py>, t: &JointTrajectory) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("dt_s", t.dt_s)?;
    d.set_item("duration_s", t.duration_s)?;
    d.set_item("times_s", PyArray1::from_slice(py, &t.times_s))?;
    d.set_item("positions", rows_py(py, &t.positions))?;
    d.set_item("velocities", rows_py(py, &t.velocities))?;
    d.set_item("waypoints", rows_py(py, &t.waypoints))?;
    Ok(d)
}

fn grasp_py<'py>(py: Python<'py>, g: &GraspMotion) -> PyResult<Bound<'py, PyDict>> {
    let c = &g.candidate;
    let d = PyDict::new(py);
    d.set_item("ok", true)?;
    d.set_item("world_from_tcp_pregrasp", matrix_py(py, &c.world_from_tcp_pregrasp))?;
    d.set_item("world_from_tcp_grasp", matrix_py(py, &c.world_from_tcp_grasp))?;
    d.set_item("world_from_tcp_lift", matrix_py(py, &c.world_from_tcp_lift))?;
    d.set_item("hand_yaw_rad", c.hand_yaw_rad)?;
    d.set_item("open_width_m", c.open_width_m)?;
    d.set_item("expected_closed_width_m", c.expected_closed_width_m)?;
    d.set_item("clearance_m", if c.clearance_m.is_finite() { c.clearance_m } else { f64::MAX })?;
    d.set_item("short_side", c.short_side)?;
    d.set_item("depth_below_top_m", c.depth_below_top_m)?;
    d.set_item("to_pregrasp", trajectory_py(py, &g.to_pregrasp)?)?;
    d.set_item("approach", trajectory_py(py, &g.approach)?)?;
    d.set_item("lift", trajectory_py(py, &g.lift)?)?;
    Ok(d)
}

fn ok_trajectory<'py>(py: Python<'py>, t: &JointTrajectory) -> PyResult<Bound<'py, PyDict>> {
    let d = trajectory_py(py, t)?;
    d.set_item("ok", true)?;
    Ok(d)
}

/// Applies the JSON config overrides (a flat object; unknown keys are errors naming the key).
fn config_from_json(json: Option<&str>) -> PyResult<PlannerConfig> {
    let mut c = PlannerConfig::default();
    let Some(s) = json else {
        return Ok(c);
    };
    let v: serde_json::Map<String, serde_json::Value> = serde_json::from_str(s).map_err(|e| json_err("config", e))?;
    let (mut vel, mut acc, mut jerk) = (0.5, 0.2, 0.02);
    for (k, val) in &v {
        let num = || {
            val.as_f64()
                .filter(|x| x.is_finite())
                .ok_or_else(|| input_err(format!("config.{k}: expected a finite number, got {val}")))
        };
        let count =
            || val.as_u64().ok_or_else(|| input_err(format!("config.{k}: expected a non-negative integer, got {val}")));
        match k.as_str() {
            "object_margin_m" => c.object_margin_m = num()?,
            "table_margin_m" => c.table_margin_m = num()?,
            "edge_resolution_rad" => c.edge_resolution_rad = num()?,
            "rrt_max_iterations" => c.rrt_max_iterations = count()? as usize,
            "shortcut_iterations" => c.shortcut_iterations = count()? as usize,
            "rng_seed" => c.rng_seed = count()?,
            "ik_seed" => c.ik.rng_seed = count()?,
            "ik_random_restarts" => c.ik.random_restarts = count()? as usize,
            "sample_dt_s" => c.sample_dt_s = num()?,
            "velocity_scale" => vel = num()?,
            "acceleration_scale" => acc = num()?,
            "jerk_scale" => jerk = num()?,
            "opening_clearance_m" => c.grasp.opening_clearance_m = num()?,
            "max_grasp_depth_m" => c.grasp.max_grasp_depth_m = num()?,
            "shallow_grasp_depth_m" => c.grasp.shallow_grasp_depth_m = num()?,
            "min_tcp_height_m" => c.grasp.min_tcp_height_m = num()?,
            "pregrasp_height_m" => c.grasp.pregrasp_height_m = num()?,
            "lift_height_m" => c.grasp.lift_height_m = num()?,
            "allow_long_side" => {
                c.grasp.allow_long_side =
                    val.as_bool().ok_or_else(|| input_err(format!("config.{k}: expected a boolean, got {val}")))?
            }
            "cylinder_yaw_count" => c.grasp.cylinder_yaw_count = count()? as usize,
            "linear_step_m" => c.linear_step_m = num()?,
            "linear_max_joint_step_rad" => c.linear_max_joint_step_rad = num()?,
            _ => return Err(input_err(format!("config: unknown key {k:?}"))),
        }
    }
    for (name, s) in [("velocity_scale", vel), ("acceleration_scale", acc), ("jerk_scale", jerk)] {
        if !(s > 0.0 && s <= 1.0) {
            return Err(input_err(format!("config.{name}: expected a value in (0, 1], got {s}")));
        }
    }
    if c.sample_dt_s.is_nan() || c.sample_dt_s <= 0.0 {
        return Err(input_err(format!("config.sample_dt_s: expected > 0, got {}", c.sample_dt_s)));
    }
    if c.edge_resolution_rad.is_nan() || c.edge_resolution_rad <= 0.0 {
        return Err(input_err(format!("config.edge_resolution_rad: expected > 0, got {}", c.edge_resolution_rad)));
    }
    if c.object_margin_m < 0.0 || c.table_margin_m < 0.0 {
        return Err(input_err("config.object_margin_m / table_margin_m: expected ≥ 0"));
    }
    c.limits = MotionLimits::panda_scaled(vel, acc, jerk);
    Ok(c)
}

/// The Panda planner (see `objslam_core::plan`).
#[pyclass(module = "objslam._native", name = "Planner")]
pub struct PlannerPy {
    inner: Planner,
}

/// The parsed arguments of a motion to a TCP pose (`plan_to_pose`, `plan_linear`).
struct PoseMotion {
    q_start: JointVector,
    target: Se3,
    obstacles: Vec<ObjectGeometry>,
    /// The planner with the held object, if one was given.
    holding: Option<Planner>,
}

impl PoseMotion {
    fn parse(
        planner: &PlannerPy,
        q_start: &Bound<'_, PyAny>,
        world_from_tcp: &Bound<'_, PyAny>,
        obstacles_json: &str,
        held_json: Option<&str>,
        held_world_from_tcp: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<Self> {
        Ok(Self {
            q_start: joints(q_start, "q_start")?,
            target: pose(world_from_tcp, "world_from_tcp")?,
            obstacles: geometries(obstacles_json, "obstacles_json")?,
            holding: planner.holding(held_json, held_world_from_tcp)?,
        })
    }

    /// Runs `motion` (without the GIL) on the holding planner or the plain one.
    fn run<'py>(
        &self,
        py: Python<'py>,
        planner: &PlannerPy,
        motion: impl Fn(&Planner, &JointVector, &Se3, &[ObjectGeometry]) -> Result<JointTrajectory, PlanError> + Send + Sync,
    ) -> PyResult<Bound<'py, PyDict>> {
        let p = self.holding.as_ref().unwrap_or(&planner.inner);
        match py.detach(|| motion(p, &self.q_start, &self.target, &self.obstacles)) {
            Ok(t) => ok_trajectory(py, &t),
            Err(e) => failure(py, e),
        }
    }
}

impl PlannerPy {
    /// The planner carrying the held object, when one is given (both arguments or neither).
    fn holding(
        &self,
        held_json: Option<&str>,
        held_world_from_tcp: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<Option<Planner>> {
        match (held_json, held_world_from_tcp) {
            (None, None) => Ok(None),
            (Some(g), Some(t)) => {
                let held = HeldObject {
                    geometry: geometry(g, "held_json")?,
                    world_from_tcp_at_grasp: pose(t, "held_world_from_tcp")?,
                };
                self.inner.holding(&held).map(Some).map_err(plan_input_err)
            }
            _ => Err(input_err("held_json and held_world_from_tcp: give both or neither")),
        }
    }
}

#[pymethods]
impl PlannerPy {
    /// `urdf_path`: the Panda URDF; `config_json`: optional flat JSON of overrides (see the stubs).
    #[new]
    #[pyo3(signature = (urdf_path, config_json = None))]
    fn new(urdf_path: &str, config_json: Option<&str>) -> PyResult<Self> {
        let config = config_from_json(config_json)?;
        let inner = Planner::new(urdf_path, config).map_err(plan_input_err)?;
        Ok(Self { inner })
    }

    /// `world_from_tcp` (4x4) at arm joints `q` (7,).
    fn forward_tcp<'py>(&self, py: Python<'py>, q: &Bound<'py, PyAny>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let q = joints(q, "q")?;
        Ok(matrix_py(py, &self.inner.forward_tcp(&q)))
    }

    /// The TCP's geometric Jacobian (6, 7) at arm joints `q` (7,): rows linear then angular
    /// velocity, world frame.
    fn tcp_jacobian<'py>(&self, py: Python<'py>, q: &Bound<'py, PyAny>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let q = joints(q, "q")?;
        let j = self.inner.tcp_jacobian(&q);
        Ok(Array2::from_shape_fn((6, j.ncols()), |(r, c)| j[(r, c)]).to_pyarray(py))
    }

    /// `world_from_link` (4x4) of every chain link at `q`, by link name.
    fn link_poses<'py>(&self, py: Python<'py>, q: &Bound<'py, PyAny>) -> PyResult<Bound<'py, PyDict>> {
        let q = joints(q, "q")?;
        let d = PyDict::new(py);
        for (name, t) in self.inner.link_poses(&q) {
            d.set_item(name, matrix_py(py, &t))?;
        }
        Ok(d)
    }

    /// Lower and upper limits (7, 2) of the arm joints from the URDF, radians.
    fn joint_limits<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        let j = self.inner.chain().joints();
        Array2::from_shape_fn((j.len(), 2), |(r, c)| if c == 0 { j[r].lower_rad } else { j[r].upper_rad })
            .to_pyarray(py)
    }

    /// Collision-free, time-parameterised motion `q_start → q_goal` among `obstacles_json`:
    /// `{"ok": True, "times_s", "positions", "velocities", "waypoints", "dt_s", "duration_s"}` or
    /// `{"ok": False, "cause", "message"}`. With `held_json` (the ObjectGeometry of the object in the
    /// hand, where it stood when grasped) and `held_world_from_tcp` (the TCP pose of that grasp,
    /// 4x4), the held object is carried along and kept clear of the obstacles too.
    #[pyo3(signature = (q_start, q_goal, obstacles_json, held_json = None, held_world_from_tcp = None))]
    fn plan_to_joints<'py>(
        &self,
        py: Python<'py>,
        q_start: &Bound<'py, PyAny>,
        q_goal: &Bound<'py, PyAny>,
        obstacles_json: &str,
        held_json: Option<&str>,
        held_world_from_tcp: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let (a, b) = (joints(q_start, "q_start")?, joints(q_goal, "q_goal")?);
        let obstacles = geometries(obstacles_json, "obstacles_json")?;
        let planner = self.holding(held_json, held_world_from_tcp)?;
        match py.detach(|| planner.as_ref().unwrap_or(&self.inner).plan_to_joints(&a, &b, &obstacles)) {
            Ok(t) => ok_trajectory(py, &t),
            Err(e) => failure(py, e),
        }
    }

    /// Collision-free motion from `q_start` to a TCP pose (4x4), same result and `held_*` arguments
    /// as `plan_to_joints`.
    #[pyo3(signature = (q_start, world_from_tcp, obstacles_json, held_json = None, held_world_from_tcp = None))]
    fn plan_to_pose<'py>(
        &self,
        py: Python<'py>,
        q_start: &Bound<'py, PyAny>,
        world_from_tcp: &Bound<'py, PyAny>,
        obstacles_json: &str,
        held_json: Option<&str>,
        held_world_from_tcp: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let args = PoseMotion::parse(self, q_start, world_from_tcp, obstacles_json, held_json, held_world_from_tcp)?;
        args.run(py, self, Planner::plan_to_pose)
    }

    /// Collision-free IK (table, `obstacles_json`, self) for a TCP pose (4x4) from `seed` (7,):
    /// the joints (7,), or None when no solution is found. `restarts=False`: from the seed only
    /// (stays on its branch, for following a path); else also from the configured random restarts.
    #[pyo3(signature = (world_from_tcp, seed, obstacles_json = "[]", restarts = true))]
    fn inverse_tcp<'py>(
        &self,
        py: Python<'py>,
        world_from_tcp: &Bound<'py, PyAny>,
        seed: &Bound<'py, PyAny>,
        obstacles_json: &str,
        restarts: bool,
    ) -> PyResult<Option<Bound<'py, PyArray1<f64>>>> {
        let target = pose(world_from_tcp, "world_from_tcp")?;
        let q0 = joints(seed, "seed")?;
        let obstacles = geometries(obstacles_json, "obstacles_json")?;
        let scene = self.inner.scene(&obstacles).map_err(plan_input_err)?;
        let r = py.detach(|| {
            if restarts {
                self.inner.inverse_tcp_free(&target, &q0, &scene)
            } else {
                self.inner.inverse_tcp_free_seeded(&target, &q0, &scene)
            }
        });
        match r {
            Ok(sol) => Ok(Some(PyArray1::from_slice(py, &sol.q))),
            Err(e) if cause_of(&e).is_some() => Ok(None),
            Err(e) => Err(plan_input_err(e)),
        }
    }

    /// Times a joint path (k, 7) through its waypoints without stopping: one time-optimal,
    /// jerk-limited Ruckig move of the path parameter (cumulative max-joint distance) under the
    /// configured limits, every joint's velocity capped at `max_joint_speed` (rad/s) when given;
    /// same result as `plan_to_joints` (no collision check: see `path_is_free`).
    #[pyo3(signature = (positions, max_joint_speed=None))]
    fn time_parameterize_path<'py>(
        &self,
        py: Python<'py>,
        positions: &Bound<'py, PyAny>,
        max_joint_speed: Option<f64>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let rows = joint_rows(positions, "positions")?;
        if let Some(v) = max_joint_speed.filter(|v| !(v.is_finite() && *v > 0.0)) {
            return Err(input_err(format!("max_joint_speed: expected a finite number > 0, got {v}")));
        }
        match self.inner.time_parameterize_path(&rows, max_joint_speed) {
            Ok(t) => ok_trajectory(py, &t),
            Err(e) => failure(py, e),
        }
    }

    /// Whether a joint path (k, 7) is collision-free among `obstacles_json` (table and self
    /// included), every segment checked at the configured resolution.
    fn path_is_free<'py>(
        &self,
        py: Python<'py>,
        positions: &Bound<'py, PyAny>,
        obstacles_json: &str,
    ) -> PyResult<bool> {
        let rows = joint_rows(positions, "positions")?;
        let obstacles = geometries(obstacles_json, "obstacles_json")?;
        let scene = self.inner.scene(&obstacles).map_err(plan_input_err)?;
        Ok(py.detach(|| self.inner.path_is_free(&rows, &scene)))
    }

    /// Straight-line TCP motion from `q_start` to `world_from_tcp` (4x4; e.g. a descent to put an
    /// object down, a retreat), same result and `held_*` arguments as `plan_to_joints`; a line that
    /// cannot be followed (collision, joint jump) is `{"ok": False, "cause": "no_path"}`.
    #[pyo3(signature = (q_start, world_from_tcp, obstacles_json, held_json = None, held_world_from_tcp = None))]
    fn plan_linear<'py>(
        &self,
        py: Python<'py>,
        q_start: &Bound<'py, PyAny>,
        world_from_tcp: &Bound<'py, PyAny>,
        obstacles_json: &str,
        held_json: Option<&str>,
        held_world_from_tcp: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let args = PoseMotion::parse(self, q_start, world_from_tcp, obstacles_json, held_json, held_world_from_tcp)?;
        args.run(py, self, Planner::plan_linear)
    }

    /// Plans a top-down grasp of `target_json` (one ObjectGeometry from the map) among
    /// `neighbours_json` (the other map objects) from arm joints `q_start`: `{"ok": True,
    /// "to_pregrasp", "approach", "lift" (trajectories as in `plan_to_joints`), "open_width_m",
    /// "expected_closed_width_m", "world_from_tcp_pregrasp|grasp|lift", "hand_yaw_rad",
    /// "clearance_m", "short_side", "depth_below_top_m"}` or `{"ok": False, "cause", "message"}`.
    fn plan_grasp<'py>(
        &self,
        py: Python<'py>,
        q_start: &Bound<'py, PyAny>,
        target_json: &str,
        neighbours_json: &str,
    ) -> PyResult<Bound<'py, PyDict>> {
        let q = joints(q_start, "q_start")?;
        let target = geometry(target_json, "target_json")?;
        let neighbours = geometries(neighbours_json, "neighbours_json")?;
        match py.detach(|| self.inner.plan_grasp(&q, &target, &neighbours)) {
            Ok(g) => grasp_py(py, &g),
            Err(e) => failure(py, e),
        }
    }
}
