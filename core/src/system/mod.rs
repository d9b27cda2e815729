//! The whole per-frame system behind one type: visual tracking → the world gauge → the object
//! pipeline (association + parameterization) → the exploration session's surface grids, and the
//! session's decisions. The simulator (or a replayed capture) feeds frames; the bindings only
//! convert types.
//!
//! Entry points:
//! - [`System::new`]: the pipeline, session and (optional) tracker from their configs.
//! - [`System::process_frame`]: one frame in, the detections' map object ids out.
//! - [`System::view_done`]: a view was reached and its frames fused.
//! - [`System::next_view`]: the session's next view for the strategy in its config.
//! - [`System::query`]: a strategy outside the core asks about candidate views, utilities and
//!   the table ([`Query`] → [`Answer`]).
//! - [`System::map`], [`System::progress`], [`System::pose_metrics`], [`System::grid_cells`]:
//!   what a run reports.
//! - [`capture::Capture`]: an episode's recorded inputs, replayed through a `System`.
//!
//! One frame (`process_frame`):
//! 1. With a tracker, the frame's camera pose is tracked from the grey image and depth, starting
//!    from the kinematic prior the frame carries (used as given: its error is the robot's); the
//!    tracked pose replaces it. On two cores ([`System::set_threads`]) the ORB features are
//!    extracted on both, then the frame's line segments (LSD, for the parameterization; they
//!    depend on the image alone) are found on a second thread through the rest of tracking and
//!    steps 2-4; the tracker takes the second core back when they are done
//!    ([`crate::ThreadBudget`]). They enter the estimators' line windows last.
//! 2. When the tracker's world ← map gauge moved since the last frame and
//!    `PipelineConfig::follow_slam_gauge` is set, the object map is moved with it (a change of
//!    world frame, not of the objects).
//! 3. The pipeline associates the frame's detections and updates the objects (with the tracker's
//!    observed map points when the pipeline takes its points from them).
//! 4. The session integrates the frame into the surface grids of the objects it observed.
//! 5. With `TrackerConfig::defer_local_bundle`, when the frame became a keyframe its local
//!    bundle adjustment starts on a worker thread now: it runs beside the caller's work and the
//!    next frame (or [`System::view_done`]) applies it first. The frame itself is mapped at its
//!    tracked pose.
//!
//! The true camera pose, when given, is used only to score the poses afterwards (ATE / RPE) and by
//! the tracker's `ground_truth` ablation pose source; it never reaches the estimate otherwise.

pub mod capture;
mod config;
mod query;

pub use config::{ConfigError, SystemConfig};
pub use query::{Answer, Decision, Query, ScoredView, StepContext, TargetedView};

use std::collections::BTreeMap;

use nalgebra::Point3;
use serde::Serialize;
use thiserror::Error;

use crate::active::{ActiveConfig, ActiveSession, NextView};
use crate::association::metrics::{association_metrics, AssociationMetrics, MetricsConfig, ObjectGtIds};
use crate::explore::{CellState, ExploreError, ObservedPoints, Reachability, TableRect};
use crate::frame::{Frame, GreyImage};
use crate::geometry::{PinholeCamera, Se3};
use crate::map::{ObjectMap, ObjectRecord};
use crate::objects::lsd::LineSegment;
use crate::pipeline::{frame_segments, MapPointObservation, ObjectPipeline, PipelineConfig, PipelineError};
use crate::slam::{ate_rmse_m, rpe, PoseSource, SlamError, TrackInput, TrackOutput, Tracker, TrackerConfig};

/// Errors of the system loop, by the subsystem that raised them.
#[derive(Debug, Error)]
pub enum SystemError {
    /// Tracking failed on bad input (a lost frame is not an error).
    #[error("slam: {0}")]
    Slam(#[from] SlamError),
    /// Association or parameterization refused the frame or its config.
    #[error("pipeline: {0}")]
    Pipeline(#[from] PipelineError),
    /// The exploration session refused the frame, a view or its config.
    #[error("explore: {0}")]
    Explore(#[from] ExploreError),
    /// A tracker is configured but the frame has no grey image.
    #[error("grey: required when a tracker is configured")]
    MissingGrey,
    /// A decision-step question was asked without the camera.
    #[error("intrinsics: the camera is required by this query")]
    MissingCamera,
    /// Views were to be scored with a strategy that has no utility.
    #[error("utility: expected object-driven or expected-gain, got {0:?}")]
    NotAUtility(crate::explore::Strategy),
}

/// One frame for [`System::process_frame`].
#[derive(Debug, Clone)]
pub struct FrameInput<'a> {
    /// Depth, intrinsics, detections and the kinematic prior `world_from_camera`.
    pub frame: Frame,
    /// Grey image, same size as the depth (required with a tracker).
    pub grey: Option<&'a GreyImage>,
    /// Index of the view (arm configuration) this frame belongs to.
    pub view_index: u64,
    /// The true camera pose, for pose metrics and the `ground_truth` pose source only.
    pub world_from_camera_gt: Option<Se3>,
}

/// Pose accuracy over the frames that carried a true pose.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PoseMetrics {
    /// ATE of the pose each frame was mapped with, metres (no alignment: both trajectories are in
    /// the robot base frame).
    pub ate_rmse_m: f64,
    /// RPE translation RMSE between consecutive frames, metres.
    pub rpe_trans_m: f64,
    /// RPE rotation RMSE between consecutive frames, degrees.
    pub rpe_rot_deg: f64,
    /// Frames the tracker lost (0 without a tracker).
    pub lost_frames: usize,
    /// ATE of the tracker's final trajectory (every frame re-expressed with the final gauge),
    /// metres; with a tracker only.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub ate_final_rmse_m: Option<f64>,
    /// Lost frames whose view showed too little of the scene; with a tracker only.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub lost_frames_scene_hidden: Option<usize>,
    /// Lost frames by reason; with a tracker only.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub lost_by_reason: Option<BTreeMap<&'static str, usize>>,
    /// Map resets; with a tracker only.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub map_resets: Option<u32>,
    /// Map extensions; with a tracker only.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub map_extensions: Option<usize>,
}

/// Surface-grid cells of every map object, for recording.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct GridCells {
    /// Cell centres in the world frame.
    pub p_in_world: Vec<Point3<f64>>,
    /// Each cell's state.
    pub states: Vec<CellState>,
}

impl GridCells {
    /// Each cell's state as a byte: 0 unknown, 1 free, 2 occupied.
    pub fn state_codes(&self) -> Vec<u8> {
        let code = |s: &CellState| match s {
            CellState::Unknown => 0,
            CellState::Free => 1,
            CellState::Occupied => 2,
        };
        self.states.iter().map(code).collect()
    }
}

/// How far exploration has come: the view count, the budget and the curves after each view.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Progress {
    /// Views taken after Init.
    pub views_taken: usize,
    /// The view budget after Init (`explore.max_views`).
    pub max_views: usize,
    /// Mean normalised entropy of the surface grids after Init and after each view.
    pub entropy_curve: Vec<f64>,
    /// Fraction of the table top known (seen, or under a mapped object) after each view, Init
    /// views included.
    pub table_known_curve: Vec<f64>,
    /// Unexplained table cells (object evidence no map object explains) after each view.
    pub table_unexplained_curve: Vec<usize>,
    /// The weighted count of table cells not known yet.
    pub table_unknown_weight: f64,
}

/// The tracker, the object pipeline and the exploration session, wired per frame.
pub struct System {
    pipeline: ObjectPipeline,
    session: ActiveSession,
    /// Visual tracking (None: each frame's prior pose is used as is).
    tracker: Option<Tracker>,
    /// The pose each frame was mapped with, and the true pose, for frames that had one.
    poses_used: Vec<Se3>,
    poses_true: Vec<Se3>,
    /// The pose the last frame was mapped with.
    last_pose: Option<Se3>,
    /// The tracker's world ← map gauge when the object map was last moved with it.
    gauge: Option<Se3>,
    /// Threads one frame may use ([`Self::set_threads`]).
    threads: usize,
}

impl System {
    /// A system from its subsystems' configs; `tracker` None maps every frame at its prior pose.
    /// The first one in a process keeps per-frame buffers from being unmapped between frames
    /// ([`crate::keep_frame_buffers`]).
    pub fn new(
        pipeline: PipelineConfig,
        active: ActiveConfig,
        tracker: Option<TrackerConfig>,
        table: TableRect,
    ) -> Result<Self, SystemError> {
        crate::keep_frame_buffers();
        Ok(Self {
            pipeline: ObjectPipeline::new(pipeline)?,
            session: ActiveSession::new(active, table)?,
            tracker: tracker.map(Tracker::new).transpose()?,
            poses_used: Vec::new(),
            poses_true: Vec::new(),
            last_pose: None,
            gauge: None,
            threads: crate::worker_threads(),
        })
    }

    /// Threads one frame may use: at least one, at most `crate::worker_threads()` (the default,
    /// two on two cores or more). With two, the frame's line segments are found beside tracking.
    /// The outputs do not depend on it.
    pub fn set_threads(&mut self, threads: usize) {
        self.threads = threads.clamp(1, crate::worker_threads());
    }

    /// Track, move the map with the gauge, associate and update the objects, integrate the grids.
    /// Returns each detection's map object id (None: not assigned).
    pub fn process_frame(&mut self, input: FrameInput<'_>) -> Result<Vec<Option<u32>>, SystemError> {
        let FrameInput { frame, grey, view_index, world_from_camera_gt } = input;
        let wanted = self.pipeline.wants_segments(&frame);
        let (lsd_config, camera) = (self.pipeline.config().lsd, frame.camera);
        let lsd = move || grey.map(|g| frame_segments(&lsd_config, wanted, &camera, g)).transpose();
        let Some(tracker) = self.tracker.as_mut() else {
            let segments = lsd()?.flatten();
            return self.map_frame(frame, None, world_from_camera_gt, segments.as_deref());
        };
        let grey = grey.ok_or(SystemError::MissingGrey)?;
        // The true pose reaches the tracker only as the oracle of the `ground_truth` ablation.
        let oracle = world_from_camera_gt.filter(|_| tracker.config().pose_source == PoseSource::GroundTruth);
        let threads = self.threads;
        tracker.set_threads(threads);
        if threads < 2 || !wanted {
            let tracked = (tracker.track(&track_input(&frame, grey, view_index, oracle))?, tracker.world_from_map());
            let segments = lsd()?.flatten();
            return self.map_frame(frame, Some(tracked), world_from_camera_gt, segments.as_deref()).inspect(|_| {
                self.start_bundle();
            });
        }
        // The line segments need only the grey image: on two cores the frame's ORB features are
        // extracted on both, then the segments are found on the second core while the frame is
        // tracked, associated and integrated into the grids (the segments enter only the
        // estimators' line windows, last). The tracker goes on with one thread and takes the
        // second core back when the segments are done (its results do not depend on its
        // threads).
        let budget = tracker.thread_budget();
        std::thread::scope(|s| {
            let mut second = None;
            let start_segments = || {
                budget.set(1);
                let budget = std::sync::Arc::clone(&budget);
                second = Some(s.spawn(move || {
                    let segments = lsd();
                    budget.set(threads);
                    segments
                }));
            };
            // (An early return joins the second thread too: the scope waits for it.)
            let tracked = self
                .tracker
                .as_mut()
                .map(|t| {
                    Ok::<_, SystemError>((
                        t.track_then(&track_input(&frame, grey, view_index, oracle), start_segments)?,
                        t.world_from_map(),
                    ))
                })
                .transpose()?;
            let (mapped_frame, assigned) = self.associate_frame(frame, tracked, world_from_camera_gt)?;
            let segments = match second {
                Some(h) => h.join().unwrap_or_else(|e| std::panic::resume_unwind(e)),
                None => lsd(),
            }?
            .flatten();
            self.pipeline.add_line_frames(&mapped_frame, &assigned, segments.as_deref());
            Ok(assigned)
        })
        .inspect(|_| self.start_bundle())
    }

    /// Start the tracker's deferred bundle adjustment when the frame's own work is done, so that
    /// it runs beside the caller's work until the next frame, not beside this frame's.
    fn start_bundle(&mut self) {
        if let Some(t) = self.tracker.as_mut() {
            t.start_bundle();
        }
    }

    /// The frame after tracking: poses, gauge, association, grids, then the line frames.
    fn map_frame(
        &mut self,
        frame: Frame,
        tracked: Option<(TrackOutput, Se3)>,
        world_from_camera_gt: Option<Se3>,
        segments: Option<&[LineSegment]>,
    ) -> Result<Vec<Option<u32>>, SystemError> {
        let (frame, assigned) = self.associate_frame(frame, tracked, world_from_camera_gt)?;
        self.pipeline.add_line_frames(&frame, &assigned, segments);
        Ok(assigned)
    }

    /// Steps 2-4 of the module docs but the line frames: the frame at its tracked pose, the map
    /// moved with the gauge, the detections associated, the grids integrated. Returns the frame
    /// as mapped and each detection's object id.
    fn associate_frame(
        &mut self,
        mut frame: Frame,
        tracked: Option<(TrackOutput, Se3)>,
        world_from_camera_gt: Option<Se3>,
    ) -> Result<(Frame, Vec<Option<u32>>), SystemError> {
        let mut map_points: Option<Vec<MapPointObservation>> = None;
        if let Some((out, now)) = tracked {
            frame.world_from_camera = out.world_from_camera;
            if self.pipeline.config().follow_slam_gauge {
                if let Some(before) = self.gauge {
                    let delta = now * before.inverse();
                    if delta.translation.vector.norm() > 1e-9 || delta.rotation.angle() > 1e-9 {
                        self.pipeline.transform_world(&delta);
                    }
                }
                self.gauge = Some(now);
            }
            map_points = Some(
                out.observed.iter().map(|p| MapPointObservation { pixel: p.pixel, p_in_world: p.p_in_world }).collect(),
            );
        }
        self.last_pose = Some(frame.world_from_camera);
        if let Some(g) = world_from_camera_gt {
            self.poses_used.push(frame.world_from_camera);
            self.poses_true.push(g);
        }
        let summary = self.pipeline.associate(&frame, map_points.as_deref())?;
        // The grids need the objects' geometry, not their clouds.
        let map = self.pipeline.map_without_clouds();
        let observed: Vec<ObservedPoints> = summary
            .observed
            .into_iter()
            .filter(|(id, _)| map.get(*id).is_some())
            .map(|(object_id, points_in_world)| ObservedPoints { object_id, points_in_world })
            .collect();
        self.session.integrate_frame(&map, &frame, &observed)?;
        Ok((frame, summary.assigned))
    }

    /// A view was reached and its frames fused (`counts_as_view` false for Init views): apply the
    /// tracker's pending bundle adjustment ([`Tracker::settle`]), refresh the estimates, update
    /// the objects' histories, note the entropy.
    pub fn view_done(&mut self, counts_as_view: bool) {
        if let Some(t) = self.tracker.as_mut() {
            t.settle();
        }
        self.pipeline.refresh_estimates();
        self.session.view_done(&self.pipeline.map(), counts_as_view);
        self.session.mark_entropy();
    }

    /// The session's next view from the camera at `current` (`reachable` filters candidates).
    pub fn next_view(
        &mut self,
        camera: &PinholeCamera,
        current: &Se3,
        reachable: &dyn Reachability,
    ) -> Result<NextView, SystemError> {
        let map = self.pipeline.map();
        Ok(self.session.next_view(&map, camera, current, reachable)?)
    }

    /// The object map now.
    pub fn map(&self) -> ObjectMap {
        self.pipeline.map()
    }

    /// The map's objects as records (id, label, geometry, observation count): those of
    /// [`Self::map`], read from the map without the objects' clouds (no point is copied).
    pub fn object_records(&self) -> Vec<ObjectRecord> {
        self.pipeline.map_without_clouds().object_records()
    }

    /// The object pipeline (association, parameterization).
    pub fn pipeline(&self) -> &ObjectPipeline {
        &self.pipeline
    }

    /// The object pipeline, mutable (e.g. to refresh estimates).
    pub fn pipeline_mut(&mut self) -> &mut ObjectPipeline {
        &mut self.pipeline
    }

    /// The exploration session.
    pub fn session(&self) -> &ActiveSession {
        &self.session
    }

    /// The exploration session, mutable (views chosen outside the core).
    pub fn session_mut(&mut self) -> &mut ActiveSession {
        &mut self.session
    }

    /// The tracker, when one is configured.
    pub fn tracker(&self) -> Option<&Tracker> {
        self.tracker.as_ref()
    }

    /// The pose the last frame was mapped with.
    pub fn last_pose(&self) -> Option<Se3> {
        self.last_pose
    }

    /// Pose accuracy over the frames that carried a true pose; None with fewer than two.
    pub fn pose_metrics(&self) -> Result<Option<PoseMetrics>, SystemError> {
        if self.poses_true.len() < 2 {
            return Ok(None);
        }
        let r = rpe(&self.poses_used, &self.poses_true)?;
        let mut m = PoseMetrics {
            ate_rmse_m: ate_rmse_m(&self.poses_used, &self.poses_true)?,
            rpe_trans_m: r.trans_m,
            rpe_rot_deg: r.rot_deg,
            lost_frames: self.tracker.as_ref().map_or(0, Tracker::n_lost),
            ate_final_rmse_m: None,
            lost_frames_scene_hidden: None,
            lost_by_reason: None,
            map_resets: None,
            map_extensions: None,
        };
        if let Some(t) = self.tracker.as_ref() {
            let traj = t.trajectory();
            if traj.len() == self.poses_true.len() {
                m.ate_final_rmse_m = Some(ate_rmse_m(&traj, &self.poses_true)?);
            }
            m.lost_frames_scene_hidden = Some(t.n_lost_scene_hidden());
            m.lost_by_reason = Some(t.lost_by_reason().clone());
            m.map_resets = Some(t.n_resets());
            m.map_extensions = Some(t.n_extensions());
        }
        Ok(Some(m))
    }

    /// Association metrics from (object id, true id or None) pairs of every assigned detection:
    /// ids are resolved through merges and only objects still in the map count.
    pub fn association_metrics(&self, pairs: &[(u32, Option<u32>)], gt_ids: &[u32]) -> AssociationMetrics {
        let map = self.pipeline.map();
        let mut by_object: BTreeMap<u32, Vec<Option<u32>>> = map.objects.iter().map(|o| (o.id, Vec::new())).collect();
        for &(id, gt) in pairs {
            if let Some(v) = by_object.get_mut(&self.pipeline.resolve_id(id)) {
                v.push(gt);
            }
        }
        let objects: Vec<ObjectGtIds> =
            by_object.into_iter().map(|(object_id, gt_ids)| ObjectGtIds { object_id, gt_ids }).collect();
        association_metrics(&objects, gt_ids, &MetricsConfig::default())
    }

    /// The exploration's [`Progress`] now.
    pub fn progress(&self) -> Progress {
        let s = &self.session;
        Progress {
            views_taken: s.views_taken(),
            max_views: s.max_views(),
            entropy_curve: s.entropy_curve().to_vec(),
            table_known_curve: s.table_known_curve().to_vec(),
            table_unexplained_curve: s.table_unexplained_curve().to_vec(),
            table_unknown_weight: s.table_unknown_weight(&self.pipeline.map()),
        }
    }

    /// Every map object's surface-grid cells in the world frame.
    pub fn grid_cells(&self) -> GridCells {
        let map = self.pipeline.map();
        let mut out = GridCells::default();
        for (id, grid) in &self.session.grids().grids {
            if let Some(obj) = map.get(*id) {
                for c in grid.cells_in_world(&obj.world_from_object) {
                    out.p_in_world.push(c.p_in_world);
                    out.states.push(c.state);
                }
            }
        }
        out
    }
}

/// The tracker's input for a frame.
fn track_input<'a>(
    frame: &'a Frame,
    grey: &'a GreyImage,
    view_index: u64,
    world_from_camera_oracle: Option<Se3>,
) -> TrackInput<'a> {
    TrackInput {
        grey,
        depth: &frame.depth,
        camera: &frame.camera,
        world_from_camera_prior: frame.world_from_camera,
        view_index,
        world_from_camera_oracle,
    }
}
