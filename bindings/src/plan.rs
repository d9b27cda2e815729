//! `Planner`: the core's Panda motion planner (`objslam_core::plan`) for Python.
//!
//! Joint vectors cross as float64 arrays of 7 (the arm; the gripper is the caller's), poses as 4x4
//! float64 matrices, obstacles as JSON lists of `ObjectGeometry` (the `"geometry"` of the map's
//! object records). Bad input raises `InputError`, a URDF that cannot be loaded `PlanningError`;
//! per-attempt failures are returned (`objslam_core::plan::report::Attempt`).

use numpy::{PyArray1, PyArray2};
use objslam_core::geometry::ObjectGeometry;
use objslam_core::plan::report::{Attempt, GraspPlan, PlannerOverrides, ARRAY_FIELDS};
use objslam_core::plan::{HeldObject, JointTrajectory, JointVector, PlanError, Planner, ARM_DOF};
use pyo3::create_exception;
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::{finite, input_err, matrix_py, parse_json, parse_or_default, pose, rows_py, to_py_arrays, ObjslamError};

create_exception!(_native, PlanningError, ObjslamError, "The planner cannot be built (URDF, chain, collision model).");

fn plan_err(e: PlanError) -> PyErr {
    if e.is_setup() {
        PlanningError::new_err(e.to_string())
    } else {
        input_err(e)
    }
}

/// A planning attempt as a dict: `{"ok": True, ...}`, `{"ok": False, "cause", "message"}`, or a
/// raised error for bad input.
fn attempt<'py, T: serde::Serialize>(py: Python<'py>, result: Result<T, PlanError>) -> PyResult<Bound<'py, PyAny>> {
    to_py_arrays(py, &Attempt::from_result(result).map_err(plan_err)?, "plan", &ARRAY_FIELDS)
}

fn joints(obj: &Bound<'_, PyAny>, field: &str) -> PyResult<JointVector> {
    let (q, _) = finite::<1>(obj, field, [Some(ARM_DOF)], "(7,)")?;
    Ok(std::array::from_fn(|i| q[i]))
}

/// A (k ≥ 1, 7) float64 array of joint vectors.
fn joint_rows(obj: &Bound<'_, PyAny>, field: &str) -> PyResult<Vec<JointVector>> {
    let (q, [k, _]) = finite::<2>(obj, field, [None, Some(ARM_DOF)], "(k >= 1, 7)")?;
    if k == 0 {
        return Err(input_err(format!("{field}: expected shape (k >= 1, 7), got (0, 7)")));
    }
    Ok(q.chunks_exact(ARM_DOF).map(|r| std::array::from_fn(|i| r[i])).collect())
}

/// The Panda planner (see `objslam_core::plan`).
#[pyclass(module = "objslam._native", name = "Planner")]
pub struct PlannerPy {
    inner: Planner,
}

impl PlannerPy {
    /// Runs `motion` (without the GIL) from `q_start` among `obstacles_json`, on the planner
    /// carrying the held object when one is given (both `held_*` arguments or neither).
    fn motion<'py>(
        &self,
        py: Python<'py>,
        q_start: &Bound<'py, PyAny>,
        obstacles_json: &str,
        held: (Option<&str>, Option<&Bound<'py, PyAny>>),
        motion: impl Fn(&Planner, &JointVector, &[ObjectGeometry]) -> Result<JointTrajectory, PlanError> + Send + Sync,
    ) -> PyResult<Bound<'py, PyAny>> {
        let q = joints(q_start, "q_start")?;
        let obstacles: Vec<ObjectGeometry> = parse_json("obstacles_json", obstacles_json)?;
        let holding = match held {
            (None, None) => None,
            (Some(g), Some(t)) => {
                let held = HeldObject {
                    geometry: parse_json("held_json", g)?,
                    world_from_tcp_at_grasp: pose(t, "held_world_from_tcp")?,
                };
                Some(self.inner.holding(&held).map_err(plan_err)?)
            }
            _ => return Err(input_err("held_json and held_world_from_tcp: give both or neither")),
        };
        let planner = holding.as_ref().unwrap_or(&self.inner);
        attempt(py, py.detach(|| motion(planner, &q, &obstacles)))
    }
}

#[pymethods]
impl PlannerPy {
    /// `urdf_path`: the Panda URDF; `config_json`: optional JSON of settings by name
    /// (`objslam_core::plan::report::PlannerOverrides`, see the stubs).
    #[new]
    #[pyo3(signature = (urdf_path, config_json = None))]
    fn new(urdf_path: &str, config_json: Option<&str>) -> PyResult<Self> {
        let overrides: PlannerOverrides = parse_or_default("config", config_json)?;
        let inner = Planner::new(urdf_path, overrides.config().map_err(plan_err)?).map_err(plan_err)?;
        Ok(Self { inner })
    }

    /// `world_from_tcp` (4x4) at arm joints `q` (7,).
    fn forward_tcp<'py>(&self, py: Python<'py>, q: &Bound<'py, PyAny>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        Ok(matrix_py(py, &self.inner.forward_tcp(&joints(q, "q")?)))
    }

    /// The TCP's geometric Jacobian (6, 7) at arm joints `q` (7,): rows linear then angular
    /// velocity, world frame.
    fn tcp_jacobian<'py>(&self, py: Python<'py>, q: &Bound<'py, PyAny>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let j = self.inner.tcp_jacobian(&joints(q, "q")?);
        let rows: Vec<JointVector> = (0..6).map(|r| std::array::from_fn(|c| j[(r, c)])).collect();
        Ok(rows_py(py, &rows))
    }

    /// `world_from_link` (4x4) of every chain link at `q`, by link name.
    fn link_poses<'py>(&self, py: Python<'py>, q: &Bound<'py, PyAny>) -> PyResult<Bound<'py, PyDict>> {
        let d = PyDict::new(py);
        for (name, t) in self.inner.link_poses(&joints(q, "q")?) {
            d.set_item(name, matrix_py(py, &t))?;
        }
        Ok(d)
    }

    /// Lower and upper limits (7, 2) of the arm joints from the URDF, radians.
    fn joint_limits<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        let limits: Vec<[f64; 2]> = self.inner.chain().joints().iter().map(|j| [j.lower_rad, j.upper_rad]).collect();
        rows_py(py, &limits)
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
    ) -> PyResult<Bound<'py, PyAny>> {
        let goal = joints(q_goal, "q_goal")?;
        self.motion(py, q_start, obstacles_json, (held_json, held_world_from_tcp), |p, q, obstacles| {
            p.plan_to_joints(q, &goal, obstacles)
        })
    }

    /// Collision-free motion from `q_start` to a TCP pose (4x4), same result and `held_*` arguments
    /// as `plan_to_joints`. `linear=True`: a straight-line TCP motion (e.g. a descent to put an
    /// object down, a retreat); a line that cannot be followed (collision, joint jump) is
    /// `{"ok": False, "cause": "no_path"}`.
    #[pyo3(signature = (q_start, world_from_tcp, obstacles_json, held_json = None, held_world_from_tcp = None, *,
                        linear = false))]
    #[allow(clippy::too_many_arguments)]
    fn plan_to_pose<'py>(
        &self,
        py: Python<'py>,
        q_start: &Bound<'py, PyAny>,
        world_from_tcp: &Bound<'py, PyAny>,
        obstacles_json: &str,
        held_json: Option<&str>,
        held_world_from_tcp: Option<&Bound<'py, PyAny>>,
        linear: bool,
    ) -> PyResult<Bound<'py, PyAny>> {
        let target = pose(world_from_tcp, "world_from_tcp")?;
        self.motion(py, q_start, obstacles_json, (held_json, held_world_from_tcp), |p, q, obstacles| match linear {
            true => p.plan_linear(q, &target, obstacles),
            false => p.plan_to_pose(q, &target, obstacles),
        })
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
        let obstacles: Vec<ObjectGeometry> = parse_json("obstacles_json", obstacles_json)?;
        let scene = self.inner.scene(&obstacles).map_err(plan_err)?;
        let r = py.detach(|| match restarts {
            true => self.inner.inverse_tcp_free(&target, &q0, &scene),
            false => self.inner.inverse_tcp_free_seeded(&target, &q0, &scene),
        });
        Ok(Attempt::from_result(r).map_err(plan_err)?.value.map(|sol| PyArray1::from_slice(py, &sol.q)))
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
    ) -> PyResult<Bound<'py, PyAny>> {
        let rows = joint_rows(positions, "positions")?;
        if let Some(v) = max_joint_speed.filter(|v| !(v.is_finite() && *v > 0.0)) {
            return Err(input_err(format!("max_joint_speed: expected a finite number > 0, got {v}")));
        }
        attempt(py, self.inner.time_parameterize_path(&rows, max_joint_speed))
    }

    /// Whether a joint path (k, 7) is collision-free among `obstacles_json` (table and self
    /// included), every segment checked at the configured resolution.
    fn path_is_free(&self, py: Python<'_>, positions: &Bound<'_, PyAny>, obstacles_json: &str) -> PyResult<bool> {
        let rows = joint_rows(positions, "positions")?;
        let obstacles: Vec<ObjectGeometry> = parse_json("obstacles_json", obstacles_json)?;
        let scene = self.inner.scene(&obstacles).map_err(plan_err)?;
        Ok(py.detach(|| self.inner.path_is_free(&rows, &scene)))
    }

    /// Plans a top-down grasp of `target_json` (one ObjectGeometry from the map) among
    /// `neighbours_json` (the other map objects) from arm joints `q_start`: `{"ok": True, ...}` with
    /// the fields of `objslam_core::plan::report::GraspPlan` (poses 4x4, trajectories as in
    /// `plan_to_joints`) or `{"ok": False, "cause", "message"}`.
    fn plan_grasp<'py>(
        &self,
        py: Python<'py>,
        q_start: &Bound<'py, PyAny>,
        target_json: &str,
        neighbours_json: &str,
    ) -> PyResult<Bound<'py, PyAny>> {
        let q = joints(q_start, "q_start")?;
        let target: ObjectGeometry = parse_json("target_json", target_json)?;
        let neighbours: Vec<ObjectGeometry> = parse_json("neighbours_json", neighbours_json)?;
        attempt(py, py.detach(|| self.inner.plan_grasp(&q, &target, &neighbours)).map(GraspPlan::from))
    }
}
