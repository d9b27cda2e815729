//! `ActiveMapper`: the mapper and the exploration session behind one Python object, so one call
//! per frame updates the map and the surface grids, and one call per decision gives the next view.

use nalgebra::Matrix4;
use numpy::PyReadonlyArray2;
use numpy::{PyArray2, ToPyArray};
use objslam_core::active::{ActiveConfig, ActiveSession, NextView};
use objslam_core::association::metrics::{association_metrics, MetricsConfig, ObjectGtIds};
use objslam_core::explore::{ExploreError, ObservedPoints, Strategy, TableRect};
use objslam_core::frame::GreyImage;
use objslam_core::geometry::Se3;
use objslam_core::map::EstimateStage;
use objslam_core::pipeline::{MapPointObservation, ObjectPipeline, PipelineConfig, PipelineError};
use objslam_core::slam::{ate_rmse_m, rpe, PoseSource, TrackInput, Tracker, TrackerConfig};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::{camera, frame_from_py, input_err, json_err, objects_json, pose};

fn explore_err(e: ExploreError) -> PyErr {
    input_err(e)
}

fn pipeline_err(e: PipelineError) -> PyErr {
    input_err(e)
}

fn grey_image(obj: &Bound<'_, PyAny>) -> PyResult<GreyImage> {
    let arr: PyReadonlyArray2<'_, u8> = obj
        .extract()
        .map_err(|_| pyo3::exceptions::PyTypeError::new_err("grey: expected a uint8 array of shape (H, W)"))?;
    let a = arr.as_array();
    let (h, w) = (a.shape()[0], a.shape()[1]);
    GreyImage::new(w as u32, h as u32, a.iter().copied().collect()).map_err(input_err)
}

fn matrix_py<'py>(py: Python<'py>, t: &Se3) -> Bound<'py, PyArray2<f64>> {
    let m: Matrix4<f64> = t.to_homogeneous();
    let rows: Vec<Vec<f64>> = (0..4).map(|r| (0..4).map(|c| m[(r, c)]).collect()).collect();
    let arr = numpy::ndarray::Array2::from_shape_fn((4, 4), |(r, c)| rows[r][c]);
    arr.to_pyarray(py)
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

/// A list of 4x4 views; the error names the index.
fn view_list(views: &[Bound<'_, PyAny>]) -> PyResult<Vec<Se3>> {
    views.iter().enumerate().map(|(i, v)| pose(v, "views").map_err(|e| input_err(format!("views[{i}]: {e}")))).collect()
}

/// A candidate view and the map object it was sampled around.
type TargetedView<'py> = (Bound<'py, PyArray2<f64>>, Option<u32>);

/// Mapper + exploration session (see `objslam_core::active`).
#[pyclass(module = "objslam._native", name = "ActiveMapper")]
pub struct ActiveMapperPy {
    mapper: ObjectPipeline,
    session: ActiveSession,
    /// Visual tracking (None: the caller's pose is used as is).
    tracker: Option<Tracker>,
    /// Pose used for each frame and the true pose, for ATE / RPE.
    poses_used: Vec<Se3>,
    poses_true: Vec<Se3>,
    /// The tracker's world ← map gauge when the object map was last moved with it.
    gauge: Option<Se3>,
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
        let tracker = match tracker_config_json {
            Some(t) => {
                let tc: TrackerConfig = serde_json::from_str(t).map_err(|e| json_err("tracker_config", e))?;
                Some(Tracker::new(tc).map_err(input_err)?)
            }
            None => None,
        };
        let mc: PipelineConfig = serde_json::from_str(mapper_config_json).map_err(|e| json_err("mapper_config", e))?;
        let ac: ActiveConfig = serde_json::from_str(active_config_json).map_err(|e| json_err("active_config", e))?;
        let rect = TableRect { center_m: [table.0, table.1], size_m: [table.2, table.3], height_m: 0.0 };
        let session = ActiveSession::new(ac, rect).map_err(explore_err)?;
        Ok(Self {
            mapper: ObjectPipeline::new(mc).map_err(pipeline_err)?,
            session,
            tracker,
            poses_used: Vec::new(),
            poses_true: Vec::new(),
            gauge: None,
        })
    }

    /// The Init views as a list of 4x4 `world_from_camera` matrices.
    fn initial_views<'py>(&self, py: Python<'py>) -> PyResult<Vec<Bound<'py, PyArray2<f64>>>> {
        let views = self.session.initial_views().map_err(explore_err)?;
        Ok(views.iter().map(|v| matrix_py(py, v)).collect())
    }

    /// Fuse one frame into the map and the surface grids; returns per-detection object ids.
    /// With a tracker, `world_from_camera` is the kinematic prior (used as given) and the tracked
    /// pose is used (`grey` required); `view_index` (one per arm move) feeds the tracker;
    /// `world_from_camera_gt` is for ATE / RPE and reaches the tracker only under the
    /// `ground_truth` pose source.
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
        let mut frame = frame_from_py(index, intrinsics, depth, world_from_camera, detections)?;
        let gt = world_from_camera_gt.map(|g| pose(g, "world_from_camera_gt")).transpose()?;
        let mut map_points: Option<Vec<MapPointObservation>> = None;
        if let Some(tracker) = self.tracker.as_mut() {
            let g = grey.as_ref().ok_or_else(|| input_err("grey: required when a tracker is configured"))?;
            let oracle = gt.filter(|_| tracker.config().pose_source == PoseSource::GroundTruth);
            let out = tracker
                .track(&TrackInput {
                    grey: g,
                    depth: &frame.depth,
                    camera: &frame.camera,
                    world_from_camera_prior: frame.world_from_camera,
                    view_index,
                    world_from_camera_oracle: oracle,
                })
                .map_err(input_err)?;
            frame.world_from_camera = out.world_from_camera;
            if self.mapper.config().follow_slam_gauge {
                // The gauge change is a change of the world frame (one map frame across the
                // tracker's resets).
                let now = tracker.world_from_map();
                if let Some(before) = self.gauge {
                    let delta = now * before.inverse();
                    if delta.translation.vector.norm() > 1e-9 || delta.rotation.angle() > 1e-9 {
                        self.mapper.transform_world(&delta);
                    }
                }
                self.gauge = Some(now);
            }
            map_points = Some(
                out.observed.iter().map(|p| MapPointObservation { pixel: p.pixel, p_in_world: p.p_in_world }).collect(),
            );
        }
        if let Some(g) = gt {
            self.poses_used.push(frame.world_from_camera);
            self.poses_true.push(g);
        }
        let summary =
            self.mapper.update_with_map_points(&frame, grey.as_ref(), map_points.as_deref()).map_err(pipeline_err)?;
        let map = self.mapper.map();
        let observed: Vec<ObservedPoints> = summary
            .observed
            .into_iter()
            .filter(|(id, _)| map.get(*id).is_some())
            .map(|(object_id, points_in_world)| ObservedPoints { object_id, points_in_world })
            .collect();
        self.session.integrate_frame(&map, &frame, &observed).map_err(explore_err)?;
        Ok(summary.assigned)
    }

    /// A view was reached and its frames fused (`counts_as_view` false for Init views).
    fn view_done(&mut self, counts_as_view: bool) {
        self.mapper.refresh_estimates();
        self.session.view_done(&self.mapper.map(), counts_as_view);
        self.session.mark_entropy();
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
        let callback_error: std::cell::RefCell<Option<PyErr>> = std::cell::RefCell::new(None);
        let check = |p: &Se3| -> bool { call_reachable(py, reachable, p, &callback_error) };
        let decision = self.session.next_view(&self.mapper.map(), &cam, &current, &check).map_err(explore_err)?;
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
                out.set_item(
                    "reason",
                    serde_json::to_value(reason).map_err(|e| json_err("reason", e))?.as_str().unwrap_or("?"),
                )?;
            }
        }
        Ok(out)
    }

    /// The paper's per-object features at this decision step, one dict per map object (map order):
    /// {"object_id", "entropy_bits" (H_obj), "normalized_entropy" (H̄_obj), "occupied_ratio" (R_o),
    /// "history_iou" (R_IoU from the estimate history, or None), "normalized_volume" (V̄_obj),
    /// "volume_probability" (p(V̄)), "explore" (s(x) = 1), "cells_occupied", "cells_free",
    /// "cells_unknown"}. For strategies outside the core (`objslam.strategy`).
    #[pyo3(signature = (*, intrinsics, width, height))]
    fn object_features<'py>(
        &self,
        py: Python<'py>,
        intrinsics: &Bound<'py, PyAny>,
        width: u32,
        height: u32,
    ) -> PyResult<Vec<Bound<'py, PyDict>>> {
        let cam = camera(intrinsics, width, height)?;
        let features = self.session.object_features(&self.mapper.map(), &cam).map_err(explore_err)?;
        features
            .iter()
            .map(|f| {
                let d = PyDict::new(py);
                d.set_item("object_id", f.object_id)?;
                d.set_item("entropy_bits", f.entropy_bits)?;
                d.set_item("normalized_entropy", f.normalized_entropy)?;
                d.set_item("occupied_ratio", f.occupied_ratio)?;
                d.set_item("history_iou", f.history_iou)?;
                d.set_item("normalized_volume", f.normalized_volume)?;
                d.set_item("volume_probability", f.volume_probability)?;
                d.set_item("explore", f.explore)?;
                d.set_item("cells_occupied", f.grid.occupied)?;
                d.set_item("cells_free", f.grid.free)?;
                d.set_item("cells_unknown", f.grid.unknown)?;
                Ok(d)
            })
            .collect()
    }

    /// The candidate views the utility strategies would sample at this step around the objects
    /// `around` (map object ids; None = every object), without the reachability filter: a list
    /// of (4x4 `world_from_camera`, target object id).
    #[pyo3(signature = (*, around = None))]
    fn candidate_views<'py>(&self, py: Python<'py>, around: Option<Vec<u32>>) -> PyResult<Vec<TargetedView<'py>>> {
        let views = self.session.candidate_views(&self.mapper.map(), around.as_deref()).map_err(explore_err)?;
        Ok(views.iter().map(|v| (matrix_py(py, &v.world_from_camera), v.target_object)).collect())
    }

    /// Score views with a utility: `utility` = "object-driven" (the paper's f) or
    /// "expected-gain" (with its motion cost from `world_from_camera`, the camera now). One dict
    /// per view: {"utility", "motion_cost", "objects": [{"object_id", "entropy_term", "r_iou",
    /// "h_iou", "h_v", "visible_cells", "s", "total"}]}. Objects whose s(x) = 0 add nothing
    /// unless `explore_every_object`.
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
    ) -> PyResult<Vec<Bound<'py, PyDict>>> {
        let cam = camera(intrinsics, width, height)?;
        let current = pose(world_from_camera, "world_from_camera")?;
        let strategy = match utility {
            "object-driven" => Strategy::ObjectDriven,
            "expected-gain" => Strategy::ExpectedGain,
            other => {
                return Err(input_err(format!(
                    "utility: expected \"object-driven\" or \"expected-gain\", got {other:?}"
                )))
            }
        };
        let poses = view_list(&views)?;
        let scores = self
            .session
            .score_views(&self.mapper.map(), &cam, &poses, strategy, &current, explore_every_object)
            .map_err(explore_err)?;
        scores
            .iter()
            .map(|s| {
                let d = PyDict::new(py);
                d.set_item("utility", s.utility)?;
                d.set_item("motion_cost", s.motion_cost)?;
                let objects: Vec<Bound<'py, PyDict>> = s
                    .objects
                    .iter()
                    .map(|o| {
                        let od = PyDict::new(py);
                        od.set_item("object_id", o.object_id)?;
                        od.set_item("entropy_term", o.entropy_term)?;
                        od.set_item("r_iou", o.r_iou)?;
                        od.set_item("h_iou", o.h_iou)?;
                        od.set_item("h_v", o.h_v)?;
                        od.set_item("visible_cells", o.visible_cells)?;
                        od.set_item("s", o.s)?;
                        od.set_item("total", o.total)?;
                        Ok(od)
                    })
                    .collect::<PyResult<_>>()?;
                d.set_item("objects", objects)?;
                Ok(d)
            })
            .collect()
    }

    /// The paper's stopping rule now: "all_explored" (every object's s(x) = 0), "max_views"
    /// (the budget after Init is spent) or None.
    #[pyo3(signature = (*, intrinsics, width, height))]
    fn paper_stop(&self, intrinsics: &Bound<'_, PyAny>, width: u32, height: u32) -> PyResult<Option<String>> {
        let cam = camera(intrinsics, width, height)?;
        let stop = self.session.paper_stop(&self.mapper.map(), &cam).map_err(explore_err)?;
        stop.map(|r| {
            serde_json::to_value(r).map_err(|e| json_err("reason", e)).map(|v| v.as_str().unwrap_or("?").to_string())
        })
        .transpose()
    }

    /// The view budget after Init (`explore.max_views`).
    fn max_views(&self) -> usize {
        self.session.max_views()
    }

    /// The discovery extension's candidate views at this step (table cells not known yet, the
    /// unexplained ones first), as the built-in utility strategies sample them; not filtered by
    /// reachability. A list of 4x4 `world_from_camera`.
    fn table_candidate_views<'py>(&self, py: Python<'py>) -> PyResult<Vec<Bound<'py, PyArray2<f64>>>> {
        let views = self.session.table_candidate_views(&self.mapper.map()).map_err(explore_err)?;
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
    ) -> PyResult<Vec<Bound<'py, PyDict>>> {
        let cam = camera(intrinsics, width, height)?;
        let poses = view_list(&views)?;
        self.session
            .table_gain(&self.mapper.map(), &cam, &poses)
            .iter()
            .map(|g| {
                let d = PyDict::new(py);
                d.set_item("cells", g.cells)?;
                d.set_item("unexplained", g.unexplained)?;
                d.set_item("bits", g.bits)?;
                Ok(d)
            })
            .collect()
    }

    /// The weighted count of table cells not known yet.
    fn table_unknown_weight(&self) -> f64 {
        self.session.table_unknown_weight(&self.mapper.map())
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
        let callback_error: std::cell::RefCell<Option<PyErr>> = std::cell::RefCell::new(None);
        let check = |p: &Se3| -> bool { call_reachable(py, reachable, p, &callback_error) };
        let n = self.session.table_views_needed(&self.mapper.map(), &cam, &check, limit).map_err(explore_err)?;
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
        self.session.note_chosen_view(&self.mapper.map(), &cam, &view);
        Ok(())
    }

    /// The camera pose used for the last frame (4x4), or None before the first frame.
    fn last_pose<'py>(&self, py: Python<'py>) -> Option<Bound<'py, PyArray2<f64>>> {
        self.poses_used.last().map(|p| matrix_py(py, p))
    }

    /// Pose accuracy over the frames given a true pose: {"ate_rmse_m", "rpe_trans_m",
    /// "rpe_rot_deg", "lost_frames"} and, with a tracker, "ate_final_rmse_m",
    /// "lost_frames_scene_hidden", "lost_by_reason" (ATE without alignment: both trajectories are
    /// in the robot base frame); None without true poses.
    fn pose_metrics<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyDict>>> {
        if self.poses_true.len() < 2 {
            return Ok(None);
        }
        let ate = ate_rmse_m(&self.poses_used, &self.poses_true).map_err(input_err)?;
        let r = rpe(&self.poses_used, &self.poses_true).map_err(input_err)?;
        let out = PyDict::new(py);
        out.set_item("ate_rmse_m", ate)?;
        out.set_item("rpe_trans_m", r.trans_m)?;
        out.set_item("rpe_rot_deg", r.rot_deg)?;
        out.set_item("lost_frames", self.tracker.as_ref().map_or(0, |t| t.n_lost()))?;
        if let Some(t) = self.tracker.as_ref() {
            // The SLAM's estimate of every frame's pose at the end of the run (re-expressed with
            // the final world ← map gauge), absolute in the robot base frame like `ate_rmse_m`
            // (which scores the pose each frame was mapped with, when it was tracked).
            let traj = t.trajectory();
            if traj.len() == self.poses_true.len() {
                out.set_item("ate_final_rmse_m", ate_rmse_m(&traj, &self.poses_true).map_err(input_err)?)?;
            }
            out.set_item("lost_frames_scene_hidden", t.n_lost_scene_hidden())?;
            let reasons = PyDict::new(py);
            for (k, v) in t.lost_by_reason() {
                reasons.set_item(*k, *v)?;
            }
            out.set_item("lost_by_reason", reasons)?;
            out.set_item("map_resets", t.n_resets())?;
            out.set_item("map_extensions", t.n_extensions())?;
        }
        Ok(Some(out))
    }

    /// The SLAM map points in the world frame, (N, 3) float64; None without a tracker.
    fn map_points<'py>(&self, py: Python<'py>) -> Option<Bound<'py, PyArray2<f64>>> {
        let t = self.tracker.as_ref()?;
        let pts = t.map_points_in_world();
        let arr = numpy::ndarray::Array2::from_shape_fn((pts.len(), 3), |(r, c)| pts[r].1[c]);
        Some(arr.to_pyarray(py))
    }

    /// Views taken after Init.
    fn views_taken(&self) -> usize {
        self.session.views_taken()
    }

    /// Mean normalised entropy after Init and after each view.
    fn entropy_curve(&self) -> Vec<f64> {
        self.session.entropy_curve().to_vec()
    }

    /// Fraction of the table top known (seen, or under a mapped object) after each view, Init
    /// views included.
    fn table_known_curve(&self) -> Vec<f64> {
        self.session.table_known_curve().to_vec()
    }

    /// The map as versioned JSON.
    fn map_json(&self) -> String {
        self.mapper.map().to_json()
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
        Ok(self.mapper.stage_map(s).to_json())
    }

    /// Every confirmed object's estimator inputs (points, line frames) as JSON, for offline replay.
    fn estimator_inputs_json(&self) -> PyResult<String> {
        serde_json::to_string(&self.mapper.estimator_inputs()).map_err(|e| json_err("estimator_inputs", e))
    }

    /// Re-run parameterization for objects observed since the last refresh.
    fn refresh_estimates(&mut self) {
        self.mapper.refresh_estimates();
    }

    /// The surviving object id of any id returned by `update` (follows duplicate merges).
    fn resolve_id(&self, id: u32) -> u32 {
        self.mapper.resolve_id(id)
    }

    /// Association metrics (JSON) from (object id, GT id or None) pairs of every assigned detection;
    /// ids are resolved through merges and only objects still in the map count.
    fn association_metrics_json(&self, pairs: Vec<(u32, Option<u32>)>, gt_ids: Vec<u32>) -> PyResult<String> {
        let map = self.mapper.map();
        let mut by_object: std::collections::BTreeMap<u32, Vec<Option<u32>>> = std::collections::BTreeMap::new();
        for o in &map.objects {
            by_object.insert(o.id, Vec::new());
        }
        for (id, gt) in pairs {
            if let Some(v) = by_object.get_mut(&self.mapper.resolve_id(id)) {
                v.push(gt);
            }
        }
        let objs: Vec<ObjectGtIds> =
            by_object.into_iter().map(|(object_id, gt_ids)| ObjectGtIds { object_id, gt_ids }).collect();
        let m = association_metrics(&objs, &gt_ids, &MetricsConfig::default());
        serde_json::to_string(&m).map_err(|e| json_err("association", e))
    }

    /// The map's objects as JSON records.
    fn objects_json(&self) -> PyResult<String> {
        objects_json(&self.mapper.map())
    }

    /// Surface grid cells of every object: (N, 3) centres in the world and (N,) states
    /// (0 unknown, 1 free, 2 occupied), for recording.
    fn grid_cells<'py>(&self, py: Python<'py>) -> (Bound<'py, PyArray2<f64>>, Vec<u8>) {
        let mut pts: Vec<[f64; 3]> = Vec::new();
        let mut states = Vec::new();
        let map = self.mapper.map();
        for (id, grid) in &self.session.grids().grids {
            if let Some(obj) = map.get(*id) {
                for c in grid.cells_in_world(&obj.world_from_object) {
                    pts.push([c.p_in_world.x, c.p_in_world.y, c.p_in_world.z]);
                    states.push(match c.state {
                        objslam_core::explore::CellState::Unknown => 0u8,
                        objslam_core::explore::CellState::Free => 1,
                        objslam_core::explore::CellState::Occupied => 2,
                    });
                }
            }
        }
        let arr = numpy::ndarray::Array2::from_shape_fn((pts.len(), 3), |(r, c)| pts[r][c]);
        (arr.to_pyarray(py), states)
    }

    /// Table-top cells not known yet (neither seen nor under a mapped object), for recording:
    /// (N, 3) world centres and, per cell, whether it is unexplained (object evidence no map
    /// object explains).
    fn table_unknown_cells<'py>(&self, py: Python<'py>) -> (Bound<'py, PyArray2<f64>>, Vec<bool>) {
        let (pts, unexplained) = self.session.table_unknown_cells_with_evidence(&self.mapper.map());
        (numpy::ndarray::Array2::from_shape_fn((pts.len(), 3), |(r, c)| pts[r][c]).to_pyarray(py), unexplained)
    }

    /// Unexplained table cells after each view (object evidence no map object explains).
    fn table_unexplained_curve(&self) -> Vec<usize> {
        self.session.table_unexplained_curve().to_vec()
    }

    fn __len__(&self) -> usize {
        self.mapper.map().len()
    }
}
