//! `ActiveMapper`: the core's [`System`] (tracking, object pipeline, exploration session) behind one
//! Python object: one call per frame, one per decision. Conversions only; the wiring is the core's.

use nalgebra::Matrix4;
use numpy::PyReadonlyArray2;
use numpy::{PyArray2, ToPyArray};
use objslam_core::active::{ActiveConfig, NextView};
use objslam_core::explore::{CellState, Strategy, TableRect};
use objslam_core::frame::GreyImage;
use objslam_core::geometry::Se3;
use objslam_core::map::EstimateStage;
use objslam_core::pipeline::PipelineConfig;
use objslam_core::slam::TrackerConfig;
use objslam_core::system::{FrameInput, System};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::{camera, frame_from_py, input_err, json_err, objects_json, pose, to_py};

fn grey_image(obj: &Bound<'_, PyAny>) -> PyResult<GreyImage> {
    let arr: PyReadonlyArray2<'_, u8> = obj
        .extract()
        .map_err(|_| pyo3::exceptions::PyTypeError::new_err("grey: expected a uint8 array of shape (H, W)"))?;
    let a = arr.as_array();
    crate::check_elements("grey", a.shape())?;
    let (h, w) = (a.shape()[0], a.shape()[1]);
    GreyImage::new(w as u32, h as u32, a.iter().copied().collect()).map_err(input_err)
}

fn matrix_py<'py>(py: Python<'py>, t: &Se3) -> Bound<'py, PyArray2<f64>> {
    let m: Matrix4<f64> = t.to_homogeneous();
    numpy::ndarray::Array2::from_shape_fn((4, 4), |(r, c)| m[(r, c)]).to_pyarray(py)
}

fn points_py<'py>(py: Python<'py>, pts: &[nalgebra::Point3<f64>]) -> Bound<'py, PyArray2<f64>> {
    numpy::ndarray::Array2::from_shape_fn((pts.len(), 3), |(r, c)| pts[r][c]).to_pyarray(py)
}

/// Ask a Python reachability callback about `p`; its first error is kept in `error` (and every
/// later view counts as unreachable) so that the caller raises it after the core returns.
fn call_reachable(
    py: Python<'_>,
    reachable: &Bound<'_, PyAny>,
    p: &Se3,
    error: &std::cell::RefCell<Option<PyErr>>,
) -> bool {
    if error.borrow().is_some() {
        return false;
    }
    match reachable.call1((matrix_py(py, p),)).and_then(|r| r.extract::<bool>()) {
        Ok(ok) => ok,
        Err(e) => {
            *error.borrow_mut() = Some(e);
            false
        }
    }
}

/// `reachable` must be callable (a function of a 4x4 `world_from_camera` returning a bool).
fn check_callable(reachable: &Bound<'_, PyAny>) -> PyResult<()> {
    if reachable.is_callable() {
        Ok(())
    } else {
        Err(pyo3::exceptions::PyTypeError::new_err(format!(
            "reachable: expected a callable taking a 4x4 world_from_camera and returning a bool, got {}",
            reachable.get_type()
        )))
    }
}

/// A list of 4x4 views; the error names the index.
fn view_list(views: &[Bound<'_, PyAny>]) -> PyResult<Vec<Se3>> {
    views.iter().enumerate().map(|(i, v)| pose(v, "views").map_err(|e| input_err(format!("views[{i}]: {e}")))).collect()
}

/// A map object id from Python; the error names the argument.
fn object_id(id: i64, field: &str) -> PyResult<u32> {
    u32::try_from(id).map_err(|_| input_err(format!("{field}: an object id is in 0..={}, got {id}", u32::MAX)))
}

/// A candidate view and the map object it was sampled around.
type TargetedView<'py> = (Bound<'py, PyArray2<f64>>, Option<u32>);

/// The core's per-frame system (see `objslam_core::system`).
#[pyclass(module = "objslam._native", name = "ActiveMapper")]
pub struct ActiveMapperPy {
    system: System,
}

#[pymethods]
impl ActiveMapperPy {
    /// `table` = (centre x, centre y, size x, size y) of the table top at z = 0.
    #[new]
    #[pyo3(signature = (*, mapper_config_json, active_config_json, table, tracker_config_json = None))]
    fn new(
        mapper_config_json: &str,
        active_config_json: &str,
        table: (f64, f64, f64, f64),
        tracker_config_json: Option<&str>,
    ) -> PyResult<Self> {
        let tracker: Option<TrackerConfig> =
            tracker_config_json.map(|t| crate::parse_json("tracker_config", t)).transpose()?;
        let mc: PipelineConfig = crate::parse_json("mapper_config", mapper_config_json)?;
        let ac: ActiveConfig = crate::parse_json("active_config", active_config_json)?;
        let rect = TableRect { center_m: [table.0, table.1], size_m: [table.2, table.3], height_m: 0.0 };
        Ok(Self { system: System::new(mc, ac, tracker, rect).map_err(input_err)? })
    }

    /// The Init views as a list of 4x4 `world_from_camera` matrices.
    fn initial_views<'py>(&self, py: Python<'py>) -> PyResult<Vec<Bound<'py, PyArray2<f64>>>> {
        let views = self.system.session().initial_views().map_err(input_err)?;
        Ok(views.iter().map(|v| matrix_py(py, v)).collect())
    }

    /// Fuse one frame into the map and the surface grids; returns per-detection object ids.
    /// With a tracker, `world_from_camera` is the forward-kinematics prior and the tracked pose is
    /// used (`grey` required); `world_from_camera_gt` (evaluation only: ATE / RPE, and the
    /// `ground_truth` pose source) and `view_index` (per-view calibration bias) feed the tracker.
    #[pyo3(signature = (*, index, intrinsics, depth, world_from_camera, detections, grey = None,
                        world_from_camera_gt = None, view_index = 0))]
    #[allow(clippy::too_many_arguments)]
    fn update(
        &mut self,
        index: u32,
        intrinsics: &Bound<'_, PyAny>,
        depth: &Bound<'_, PyAny>,
        world_from_camera: &Bound<'_, PyAny>,
        detections: &Bound<'_, PyAny>,
        grey: Option<&Bound<'_, PyAny>>,
        world_from_camera_gt: Option<&Bound<'_, PyAny>>,
        view_index: u64,
    ) -> PyResult<Vec<Option<u32>>> {
        let grey = grey.map(grey_image).transpose()?;
        let frame = frame_from_py(index, intrinsics, depth, world_from_camera, detections)?;
        let world_from_camera_gt = world_from_camera_gt.map(|g| pose(g, "world_from_camera_gt")).transpose()?;
        self.system
            .process_frame(FrameInput { frame, grey: grey.as_ref(), view_index, world_from_camera_gt })
            .map_err(input_err)
    }

    /// A view was reached and its frames fused (`counts_as_view` false for Init views).
    fn view_done(&mut self, counts_as_view: bool) {
        self.system.view_done(counts_as_view);
    }

    /// The next view: a dict {"action": "move", "world_from_camera", "utility", "candidates":
    /// [(pose, utility, reachable)]} or {"action": "stop", "reason"}. `reachable` is called with a
    /// 4x4 `world_from_camera` and returns a bool.
    #[pyo3(signature = (*, intrinsics, width, height, world_from_camera, reachable))]
    fn next_view<'py>(
        &mut self,
        py: Python<'py>,
        intrinsics: &Bound<'py, PyAny>,
        width: u32,
        height: u32,
        world_from_camera: &Bound<'py, PyAny>,
        reachable: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let cam = camera(intrinsics, width, height)?;
        let current = pose(world_from_camera, "world_from_camera")?;
        check_callable(reachable)?;
        let callback_error: std::cell::RefCell<Option<PyErr>> = std::cell::RefCell::new(None);
        let check = |p: &Se3| -> bool { call_reachable(py, reachable, p, &callback_error) };
        let decision = self.system.next_view(&cam, &current, &check).map_err(input_err)?;
        if let Some(e) = callback_error.into_inner() {
            return Err(e);
        }
        let out = PyDict::new(py);
        match decision {
            NextView::Move { world_from_camera, utility, candidates } => {
                out.set_item("action", "move")?;
                out.set_item("world_from_camera", matrix_py(py, &world_from_camera))?;
                out.set_item("utility", utility)?;
                let cands: Vec<(Bound<'py, PyArray2<f64>>, f64, Option<bool>)> =
                    candidates.iter().map(|c| (matrix_py(py, &c.world_from_camera), c.utility, c.reachable)).collect();
                out.set_item("candidates", cands)?;
            }
            NextView::Stop { reason } => {
                out.set_item("action", "stop")?;
                out.set_item("reason", to_py(py, &reason, "reason")?)?;
            }
        }
        Ok(out)
    }

    /// The paper's per-object features at this decision step (`objslam_core::explore::ObjectFeatures`
    /// as dicts, map order). For strategies outside the core (`objslam.strategy`).
    #[pyo3(signature = (*, intrinsics, width, height))]
    fn object_features<'py>(
        &self,
        py: Python<'py>,
        intrinsics: &Bound<'py, PyAny>,
        width: u32,
        height: u32,
    ) -> PyResult<Bound<'py, PyAny>> {
        let cam = camera(intrinsics, width, height)?;
        let s = &self.system;
        to_py(py, &s.session().object_features(&s.map(), &cam).map_err(input_err)?, "features")
    }

    /// The candidate views the utility strategies would sample at this step around the objects
    /// `around` (map object ids; None = every object), without the reachability filter: a list
    /// of (4x4 `world_from_camera`, target object id).
    #[pyo3(signature = (*, around = None))]
    fn candidate_views<'py>(&self, py: Python<'py>, around: Option<Vec<i64>>) -> PyResult<Vec<TargetedView<'py>>> {
        let around = around
            .map(|ids| ids.into_iter().map(|i| object_id(i, "around")).collect::<PyResult<Vec<_>>>())
            .transpose()?;
        let s = &self.system;
        let views = s.session().candidate_views(&s.map(), around.as_deref()).map_err(input_err)?;
        Ok(views.iter().map(|v| (matrix_py(py, &v.world_from_camera), v.target_object)).collect())
    }

    /// Score views with a utility ("object-driven", the paper's f; "object-driven-discovery", f with
    /// the run's entropy scope; or "expected-gain", with its
    /// motion cost from `world_from_camera`): `objslam_core::explore::ViewScore` as dicts, one per
    /// view. Objects whose s(x) = 0 add nothing unless `explore_every_object`.
    #[pyo3(signature = (*, intrinsics, width, height, views, utility, world_from_camera, explore_every_object = false))]
    #[allow(clippy::too_many_arguments)]
    fn score_views<'py>(
        &self,
        py: Python<'py>,
        intrinsics: &Bound<'py, PyAny>,
        width: u32,
        height: u32,
        views: Vec<Bound<'py, PyAny>>,
        utility: &str,
        world_from_camera: &Bound<'py, PyAny>,
        explore_every_object: bool,
    ) -> PyResult<Bound<'py, PyAny>> {
        let cam = camera(intrinsics, width, height)?;
        let current = pose(world_from_camera, "world_from_camera")?;
        let strategy = Strategy::parse(utility).ok().filter(|s| s.is_utility()).ok_or_else(|| {
            input_err(format!(
                "utility: expected \"object-driven\", \"object-driven-discovery\" or \"expected-gain\", got {utility:?}"
            ))
        })?;
        let poses = view_list(&views)?;
        let s = &self.system;
        let scores = s
            .session()
            .score_views(&s.map(), &cam, &poses, strategy, &current, explore_every_object)
            .map_err(input_err)?;
        to_py(py, &scores, "scores")
    }

    /// The paper's stopping rule now: "all_explored" (every object's s(x) = 0), "max_views"
    /// (the budget after Init is spent) or None.
    #[pyo3(signature = (*, intrinsics, width, height))]
    fn paper_stop<'py>(
        &self,
        py: Python<'py>,
        intrinsics: &Bound<'py, PyAny>,
        width: u32,
        height: u32,
    ) -> PyResult<Bound<'py, PyAny>> {
        let cam = camera(intrinsics, width, height)?;
        let s = &self.system;
        to_py(py, &s.session().paper_stop(&s.map(), &cam).map_err(input_err)?, "reason")
    }

    /// The view budget after Init (`explore.max_views`).
    fn max_views(&self) -> usize {
        self.system.session().max_views()
    }

    /// The discovery extension's candidate views at this step (table cells not known yet, the
    /// unexplained ones first), as the built-in utility strategies sample them; not filtered by
    /// reachability. A list of 4x4 `world_from_camera`.
    fn table_candidate_views<'py>(&self, py: Python<'py>) -> PyResult<Vec<Bound<'py, PyArray2<f64>>>> {
        let s = &self.system;
        let views = s.session().table_candidate_views(&s.map()).map_err(input_err)?;
        Ok(views.iter().map(|v| matrix_py(py, &v.world_from_camera)).collect())
    }

    /// What each view would show of the table not known yet: one dict per view {"cells" (weighted
    /// count), "unexplained" (favoured unexplained cells among them), "bits" (the discovery gain)}.
    #[pyo3(signature = (*, intrinsics, width, height, views))]
    fn table_gain<'py>(
        &self,
        py: Python<'py>,
        intrinsics: &Bound<'py, PyAny>,
        width: u32,
        height: u32,
        views: Vec<Bound<'py, PyAny>>,
    ) -> PyResult<Bound<'py, PyAny>> {
        let cam = camera(intrinsics, width, height)?;
        let poses = view_list(&views)?;
        let s = &self.system;
        to_py(py, &s.session().table_gain(&s.map(), &cam, &poses), "table_gain")
    }

    /// The weighted count of table cells not known yet.
    fn table_unknown_weight(&self) -> f64 {
        self.system.session().table_unknown_weight(&self.system.map())
    }

    /// The budget reserve's count: discovery views a greedy cover takes (each reachable, each
    /// revealing `discovery_min_new_cells` new weighted cells), at most `limit`. `reachable` is
    /// called with a 4x4 `world_from_camera` and returns a bool.
    #[pyo3(signature = (*, intrinsics, width, height, reachable, limit))]
    fn table_views_needed<'py>(
        &self,
        py: Python<'py>,
        intrinsics: &Bound<'py, PyAny>,
        width: u32,
        height: u32,
        reachable: &Bound<'py, PyAny>,
        limit: usize,
    ) -> PyResult<usize> {
        let cam = camera(intrinsics, width, height)?;
        check_callable(reachable)?;
        let callback_error: std::cell::RefCell<Option<PyErr>> = std::cell::RefCell::new(None);
        let check = |p: &Se3| -> bool { call_reachable(py, reachable, p, &callback_error) };
        let s = &self.system;
        let n = s.session().table_views_needed(&s.map(), &cam, &check, limit).map_err(input_err)?;
        match callback_error.into_inner() {
            Some(e) => Err(e),
            None => Ok(n),
        }
    }

    /// A strategy outside the core chose this view (call once per decision, before the move): it
    /// counts among the views spent on unexplained evidence when it would see such cells.
    #[pyo3(signature = (*, intrinsics, width, height, world_from_camera))]
    fn note_chosen_view(
        &mut self,
        intrinsics: &Bound<'_, PyAny>,
        width: u32,
        height: u32,
        world_from_camera: &Bound<'_, PyAny>,
    ) -> PyResult<()> {
        let cam = camera(intrinsics, width, height)?;
        let view = pose(world_from_camera, "world_from_camera")?;
        let map = self.system.map();
        self.system.session_mut().note_chosen_view(&map, &cam, &view);
        Ok(())
    }

    /// The camera pose used for the last frame (4x4), or None before the first frame.
    fn last_pose<'py>(&self, py: Python<'py>) -> Option<Bound<'py, PyArray2<f64>>> {
        self.system.last_pose().map(|p| matrix_py(py, &p))
    }

    /// Pose accuracy over the frames given a true pose (`objslam_core::system::PoseMetrics` as a
    /// dict); None without true poses.
    fn pose_metrics<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        to_py(py, &self.system.pose_metrics().map_err(input_err)?, "pose_metrics")
    }

    /// The SLAM map points in the world frame, (N, 3) float64; None without a tracker.
    fn map_points<'py>(&self, py: Python<'py>) -> Option<Bound<'py, PyArray2<f64>>> {
        let pts: Vec<_> = self.system.tracker()?.map_points_in_world().into_iter().map(|(_, p)| p).collect();
        Some(points_py(py, &pts))
    }

    /// Views taken after Init.
    fn views_taken(&self) -> usize {
        self.system.session().views_taken()
    }

    /// Mean normalised entropy after Init and after each view.
    fn entropy_curve(&self) -> Vec<f64> {
        self.system.session().entropy_curve().to_vec()
    }

    /// Fraction of the table top known (seen, or under a mapped object) after each view, Init
    /// views included.
    fn table_known_curve(&self) -> Vec<f64> {
        self.system.session().table_known_curve().to_vec()
    }

    /// The map as versioned JSON.
    fn map_json(&self) -> String {
        self.system.map().to_json()
    }

    /// The map after one parameterization stage (raw | iforest | lines | refined), versioned JSON.
    fn stage_map_json(&self, stage: &str) -> PyResult<String> {
        let s = match stage {
            "raw" => EstimateStage::Raw,
            "iforest" => EstimateStage::Iforest,
            "lines" => EstimateStage::Lines,
            "refined" => EstimateStage::Refined,
            other => return Err(input_err(format!("stage: unknown {other:?} (raw, iforest, lines, refined)"))),
        };
        Ok(self.system.pipeline().stage_map(s).to_json())
    }

    /// Every confirmed object's estimator inputs (points, line frames) as JSON, for offline replay.
    fn estimator_inputs_json(&self) -> PyResult<String> {
        serde_json::to_string(&self.system.pipeline().estimator_inputs()).map_err(|e| json_err("estimator_inputs", e))
    }

    /// Re-run parameterization for objects observed since the last refresh.
    fn refresh_estimates(&mut self) {
        self.system.pipeline_mut().refresh_estimates();
    }

    /// The surviving object id of any id returned by `update` (follows duplicate merges).
    fn resolve_id(&self, id: i64) -> PyResult<u32> {
        Ok(self.system.pipeline().resolve_id(object_id(id, "id")?))
    }

    /// Association metrics (JSON) from (object id, GT id or None) pairs of every assigned detection;
    /// ids are resolved through merges and only objects still in the map count.
    fn association_metrics_json(&self, pairs: Vec<(u32, Option<u32>)>, gt_ids: Vec<u32>) -> PyResult<String> {
        let m = self.system.association_metrics(&pairs, &gt_ids);
        serde_json::to_string(&m).map_err(|e| json_err("association", e))
    }

    /// The map's objects as JSON records.
    fn objects_json(&self) -> PyResult<String> {
        objects_json(&self.system.map())
    }

    /// Surface grid cells of every object: (N, 3) centres in the world and (N,) states
    /// (0 unknown, 1 free, 2 occupied), for recording.
    fn grid_cells<'py>(&self, py: Python<'py>) -> (Bound<'py, PyArray2<f64>>, Vec<u8>) {
        let cells = self.system.grid_cells();
        let states = cells
            .states
            .iter()
            .map(|s| match s {
                CellState::Unknown => 0u8,
                CellState::Free => 1,
                CellState::Occupied => 2,
            })
            .collect();
        (points_py(py, &cells.p_in_world), states)
    }

    /// Table-top cells not known yet (neither seen nor under a mapped object), for recording:
    /// (N, 3) world centres and, per cell, whether it is unexplained (object evidence no map
    /// object explains).
    fn table_unknown_cells<'py>(&self, py: Python<'py>) -> (Bound<'py, PyArray2<f64>>, Vec<bool>) {
        let (pts, unexplained) = self.system.session().table_unknown_cells_with_evidence(&self.system.map());
        (points_py(py, &pts), unexplained)
    }

    /// Unexplained table cells after each view (object evidence no map object explains).
    fn table_unexplained_curve(&self) -> Vec<usize> {
        self.system.session().table_unexplained_curve().to_vec()
    }

    fn __len__(&self) -> usize {
        self.system.map().len()
    }
}
