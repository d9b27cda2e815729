//! `ActiveMapper`: the core's [`System`] (tracking, object pipeline, exploration session) behind one
//! Python object: one call per frame, one per decision. Conversions only; the wiring is the core's.

use numpy::PyArray2;
use objslam_core::active::ActiveConfig;
use objslam_core::explore::TableRect;
use objslam_core::frame::GreyImage;
use objslam_core::geometry::Se3;
use objslam_core::map::EstimateStage;
use objslam_core::pipeline::PipelineConfig;
use objslam_core::slam::TrackerConfig;
use objslam_core::system::{Decision, FrameInput, Query, StepContext, System};
use pyo3::prelude::*;

use crate::{
    array, camera, choice, frame_from_py, input_err, matrix_py, parse_json, points_py, pose, to_json, to_py_arrays,
};

/// A Python reachability callback (a function of a 4x4 `world_from_camera` returning a bool) for
/// the core. Its first error is kept, every later view counts as unreachable, and [`Self::finish`]
/// raises it after the core returns.
struct Reachable<'a, 'py> {
    callback: &'a Bound<'py, PyAny>,
    error: std::cell::Cell<Option<PyErr>>,
}

impl<'a, 'py> Reachable<'a, 'py> {
    fn new(callback: &'a Bound<'py, PyAny>) -> PyResult<Self> {
        if !callback.is_callable() {
            return Err(pyo3::exceptions::PyTypeError::new_err(format!(
                "reachable: expected a callable taking a 4x4 world_from_camera and returning a bool, got {}",
                callback.get_type()
            )));
        }
        Ok(Self { callback, error: std::cell::Cell::new(None) })
    }

    fn check(&self, p: &Se3) -> bool {
        let answer = match self.error.take() {
            Some(e) => Err(e),
            None => self.callback.call1((matrix_py(self.callback.py(), p),)).and_then(|r| r.extract::<bool>()),
        };
        answer.unwrap_or_else(|e| {
            self.error.set(Some(e));
            false
        })
    }

    /// `value`, or the callback's first error.
    fn finish<T>(self, value: T) -> PyResult<T> {
        self.error.into_inner().map_or(Ok(value), Err)
    }
}

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
            tracker_config_json.map(|t| parse_json("tracker_config", t)).transpose()?;
        let mc: PipelineConfig = parse_json("mapper_config", mapper_config_json)?;
        let ac: ActiveConfig = parse_json("active_config", active_config_json)?;
        let rect = TableRect { center_m: [table.0, table.1], size_m: [table.2, table.3], height_m: 0.0 };
        Ok(Self { system: System::new(mc, ac, tracker, rect).map_err(input_err)? })
    }

    /// Fuse one frame into the map and the surface grids; returns per-detection object ids.
    /// With a tracker, `world_from_camera` is the forward-kinematics prior and the tracked pose is
    /// used (`grey` required: uint8 (H, W), or the (H, W, 3) RGB image, whose BT.601 luma the core
    /// takes); `world_from_camera_gt` (evaluation only: ATE / RPE, and the
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
        // Grey levels (H, W), or an RGB image (H, W, 3) whose luma the core takes.
        let grey = match grey {
            Some(g) if g.getattr("ndim").and_then(|n| n.extract::<usize>()).ok() == Some(3) => {
                let (rgb, [h, w, _]) = array::<u8, 3>(g, "grey", [None, None, Some(3)], "(H, W, 3)")?;
                Some(GreyImage::from_rgb(w as u32, h as u32, &rgb))
            }
            g => g
                .map(|g| array::<u8, 2>(g, "grey", [None, None], "(H, W)"))
                .transpose()?
                .map(|(data, [h, w])| GreyImage::new(w as u32, h as u32, data)),
        };
        let grey = grey.transpose().map_err(input_err)?;
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

    /// The next view (`objslam_core::system::Decision`): a dict {"action": "move",
    /// "world_from_camera", "utility" (None for baselines), "candidates": [{"world_from_camera",
    /// "utility", "reachable"}]} or {"action": "stop", "reason"}, poses as 4x4 arrays. `reachable`
    /// is called with a 4x4 `world_from_camera` and returns a bool.
    #[pyo3(signature = (*, intrinsics, width, height, world_from_camera, reachable))]
    fn next_view<'py>(
        &mut self,
        py: Python<'py>,
        intrinsics: &Bound<'py, PyAny>,
        width: u32,
        height: u32,
        world_from_camera: &Bound<'py, PyAny>,
        reachable: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, PyAny>> {
        let cam = camera(intrinsics, width, height)?;
        let current = pose(world_from_camera, "world_from_camera")?;
        let reachable = Reachable::new(reachable)?;
        let decision = self.system.next_view(&cam, &current, &|p: &Se3| reachable.check(p)).map_err(input_err);
        let decision = Decision::from(reachable.finish(decision)??);
        to_py_arrays(py, &decision, "decision", &["world_from_camera"])
    }

    /// Answers one question about the system (`objslam_core::system::Query` as JSON):
    /// `{"query": "initial_views" | "progress" | "last_pose" | "pose_metrics"}`, or at a decision
    /// step of a strategy outside the core (`objslam.strategy`; these need `intrinsics`, `width`,
    /// `height`) `"object_features" | "candidate_views" (+ "around": [ids]) | "score_views" (+
    /// "utility", "explore_every_object") | "paper_stop" | "table_candidate_views" | "table_gain" |
    /// "table_views_needed" (+ "limit")`. `views`: the 4x4 views scored (`score_views`,
    /// `table_gain`); `world_from_camera`: the current pose (`score_views`); `reachable`: a function
    /// of a 4x4 `world_from_camera` returning a bool (`table_views_needed`). Returns the `Answer`'s
    /// Python values, poses as 4x4 arrays: view dicts {"world_from_camera", "target_object"}, the
    /// progress dict, {"world_from_camera"} (None before a frame), pose metrics or None, feature,
    /// score or table-gain dicts, the stop reason or None, or a count.
    #[pyo3(signature = (query_json, *, intrinsics = None, width = 0, height = 0, views = Vec::new(),
                        world_from_camera = None, reachable = None))]
    #[allow(clippy::too_many_arguments)]
    fn query<'py>(
        &self,
        py: Python<'py>,
        query_json: &str,
        intrinsics: Option<&Bound<'py, PyAny>>,
        width: u32,
        height: u32,
        views: Vec<Bound<'py, PyAny>>,
        world_from_camera: Option<&Bound<'py, PyAny>>,
        reachable: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<Bound<'py, PyAny>> {
        let query: Query = parse_json("query_json", query_json)?;
        let views: Vec<Se3> = views
            .iter()
            .enumerate()
            .map(|(i, v)| pose(v, "views").map_err(|e| input_err(format!("views[{i}]: {e}"))))
            .collect::<PyResult<_>>()?;
        let current =
            world_from_camera.map(|p| pose(p, "world_from_camera")).transpose()?.unwrap_or_else(Se3::identity);
        let reachable = reachable.map(Reachable::new).transpose()?;
        let check = |p: &Se3| reachable.as_ref().is_none_or(|r| r.check(p));
        let camera = intrinsics.map(|k| camera(k, width, height)).transpose()?;
        let step =
            StepContext { camera: camera.as_ref(), world_from_camera: &current, views: &views, reachable: &check };
        let answer = self.system.query(&query, &step).map_err(input_err);
        let answer = match reachable {
            Some(r) => r.finish(answer)??,
            None => answer?,
        };
        to_py_arrays(py, &answer, "answer", &["world_from_camera"])
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

    /// The SLAM map points in the world frame, (N, 3) float64; None without a tracker.
    fn map_points<'py>(&self, py: Python<'py>) -> Option<Bound<'py, PyArray2<f64>>> {
        let pts: Vec<_> = self.system.tracker()?.map_points_in_world().into_iter().map(|(_, p)| p).collect();
        Some(points_py(py, &pts))
    }

    /// The map as versioned JSON; with `stage` (raw | iforest | lines | refined), the map after that
    /// parameterization stage.
    #[pyo3(signature = (stage = None))]
    fn map_json(&self, stage: Option<&str>) -> PyResult<String> {
        let Some(stage) = stage else { return Ok(self.system.map().to_json()) };
        Ok(self.system.pipeline().stage_map(choice::<EstimateStage>("stage", stage)?).to_json())
    }

    /// Every confirmed object's estimator inputs (points, line frames) as JSON, for offline replay.
    fn estimator_inputs_json(&self) -> PyResult<String> {
        to_json(&self.system.pipeline().estimator_inputs(), "estimator_inputs")
    }

    /// Re-run parameterization for objects observed since the last refresh.
    fn refresh_estimates(&mut self) {
        self.system.pipeline_mut().refresh_estimates();
    }

    /// The surviving object id of any id returned by `update` (follows duplicate merges).
    fn resolve_id(&self, id: i64) -> PyResult<u32> {
        let id =
            u32::try_from(id).map_err(|_| input_err(format!("id: an object id is in 0..={}, got {id}", u32::MAX)))?;
        Ok(self.system.pipeline().resolve_id(id))
    }

    /// Association metrics (JSON) from (object id, GT id or None) pairs of every assigned detection;
    /// ids are resolved through merges and only objects still in the map count.
    fn association_metrics_json(&self, pairs: Vec<(u32, Option<u32>)>, gt_ids: Vec<u32>) -> PyResult<String> {
        to_json(&self.system.association_metrics(&pairs, &gt_ids), "association")
    }

    /// The map's objects as JSON records.
    fn objects_json(&self) -> PyResult<String> {
        to_json(&self.system.object_records(), "objects")
    }

    /// The pose the last frame was mapped with (the `last_pose` query's 4x4 `world_from_camera`,
    /// without its JSON); None before a frame.
    fn last_pose<'py>(&self, py: Python<'py>) -> Option<Bound<'py, PyArray2<f64>>> {
        self.system.last_pose().map(|p| matrix_py(py, &p))
    }

    /// Surface grid cells of every object: (N, 3) centres in the world and (N,) states
    /// (0 unknown, 1 free, 2 occupied), for recording.
    fn grid_cells<'py>(&self, py: Python<'py>) -> (Bound<'py, PyArray2<f64>>, Vec<u8>) {
        let cells = self.system.grid_cells();
        (points_py(py, &cells.p_in_world), cells.state_codes())
    }

    /// Table-top cells not known yet (neither seen nor under a mapped object), for recording:
    /// (N, 3) world centres and, per cell, whether it is unexplained (object evidence no map
    /// object explains).
    fn table_unknown_cells<'py>(&self, py: Python<'py>) -> (Bound<'py, PyArray2<f64>>, Vec<bool>) {
        let (pts, unexplained) = self.system.session().table_unknown_cells_with_evidence(&self.system.map());
        (points_py(py, &pts), unexplained)
    }

    fn __len__(&self) -> usize {
        self.system.map().len()
    }
}
