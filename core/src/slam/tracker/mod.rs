//! The RGB-D tracker: one [`Tracker::track`] call per frame does feature extraction, pose
//! estimation (or takes the configured pose source), keyframe insertion, local BA and culling.
//!
//! Files by concern: this file holds the configuration, the per-frame input and output and the
//! [`Tracker`] with its per-frame loop; `tracking` estimates the frame's pose (projection search,
//! PnP RANSAC, refinement); `local_map` keeps keyframes and map points (insertion, local bundle
//! adjustment, culling, reset and extension); `gauge` fits the world ← map transform to the
//! kinematic prior; `gates` reject poses that disagree with the prior or with its motion.

mod gates;
mod gauge;
mod local_map;
mod tracking;

use std::collections::{BTreeMap, VecDeque};

use nalgebra::Point3;
use serde::{Deserialize, Serialize};

use self::gauge::Anchor;
use self::local_map::{KeyFrame, MapPoint};
use self::tracking::FrameData;
use super::ba::BundleConfig;
use super::features::{OrbConfig, OrbExtractor};
use super::matcher::KeypointGrid;
use super::noise::PriorNoiseConfig;
use super::pnp::{PoseRefineConfig, RansacConfig};
use super::SlamError;
use crate::frame::{DepthImage, GreyImage};
use crate::geometry::{Box2, PinholeCamera, Se3};

/// Where the output camera pose comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PoseSource {
    /// Visual tracking seeded by the kinematic prior (default; the paper's system).
    #[default]
    Slam,
    /// The kinematic prior as given, no visual correction.
    Kinematics,
    /// The oracle pose given with the frame ([`TrackInput::world_from_camera_oracle`]; an
    /// ablation, the only source that accepts one).
    GroundTruth,
}

/// Configuration of the tracker.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TrackerConfig {
    /// Pose source (`slam`, `kinematics`, `ground_truth`).
    pub pose_source: PoseSource,
    /// Feature extraction (default: [`OrbConfig`]'s with half of each level's features spread
    /// over the grid, `spread_share` 0.5: tracking and the object points want keypoints on every
    /// surface, not only the most textured).
    pub orb: OrbConfig,
    /// The estimator's assumed error of the kinematic prior (gauge-fit weights, prior and motion
    /// gates); its own tuning, independent of the robot's actual error (default 1 cm / 1° per
    /// view, 0.5 mm / 0.05° per frame).
    pub prior_noise: PriorNoiseConfig,
    /// RANSAC of the coarse pose.
    pub ransac: RansacConfig,
    /// Motion-only refinement.
    pub refine: PoseRefineConfig,
    /// Local bundle adjustment.
    pub bundle: BundleConfig,
    /// Defer a tracked keyframe's local bundle adjustment (and the culling after it): it runs on
    /// a worker thread from [`Tracker::start_bundle`] and is applied when the next frame's
    /// [`Tracker::track`] starts or at [`Tracker::settle`] (solved there if it was not started),
    /// as ORB-SLAM2's local mapping runs behind its tracking. The keyframe's frame is then output
    /// at its tracked (motion-only refined) pose with its observed points at their positions
    /// before the adjustment, instead of the adjusted ones; every later frame is tracked against
    /// the same adjusted map, seeded from the same adjusted pose, and the trajectory
    /// ([`Tracker::trajectory`]) is the same, whatever the timing. Extension keyframes are
    /// adjusted at once. It moves the adjustment's time out of the frame into the caller's (on
    /// scene01 the system's median frame is 6-20 % shorter, the episode's wall time per frame the
    /// same; `studies/core_frame_profile/`). Default false.
    pub defer_local_bundle: bool,
    /// Depth readings outside `[min_depth_m, max_depth_m]` are ignored, metres.
    pub min_depth_m: f64,
    /// See `min_depth_m` (ORB-SLAM2 RGB-D "close point" threshold is 40 baselines ≈ 3.2 m).
    pub max_depth_m: f64,
    /// Search radius of the first (coarse) projection search around the seed pose, level-0
    /// pixels (not scaled by level: it covers pose error, not keypoint noise). Must cover the
    /// prior's error (1° ≈ 10 px at fx = 600, 1 cm at 0.5 m ≈ 12 px).
    pub coarse_radius_px: f64,
    /// Search radius of the second projection search around the RANSAC pose, pixels × scale.
    pub fine_radius_px: f64,
    /// Largest Hamming distance for a map point ↔ keypoint match (ORB-SLAM2 `TH_HIGH` = 100).
    pub match_max_distance: u32,
    /// Ratio test of the projection search (best < ratio × second best; ORB-SLAM2: 0.8–0.9).
    pub match_ratio: f32,
    /// A keypoint's level may differ from its map point's creation level by at most this.
    pub max_level_difference: u8,
    /// Fewer keypoints with valid depth than this on an empty map: lost (cannot initialise).
    pub min_init_points: usize,
    /// Fewer pose inliers than this: lost (ORB-SLAM2: 30).
    pub min_tracked_inliers: usize,
    /// Insert a keyframe when the inliers drop below this fraction of the last keyframe's tracked
    /// points (ORB-SLAM2: 0.75 for RGB-D).
    pub keyframe_inlier_ratio: f64,
    /// Insert a keyframe at least every this many tracked frames.
    pub keyframe_max_interval: usize,
    /// Keyframes in the local bundle adjustment window (ORB-SLAM2: covisible ones; here the
    /// most recent N).
    pub local_keyframes: usize,
    /// New map points created per keyframe at most (closest depth first).
    pub max_new_points: usize,
    /// Cull a point whose found / visible ratio falls below this (ORB-SLAM2: 0.25) once it has
    /// been visible `cull_min_visible` times.
    pub cull_found_ratio: f64,
    /// See `cull_found_ratio`.
    pub cull_min_visible: u32,
    /// Cull a point observed by fewer than 2 keyframes once this many keyframes have been added
    /// after its creation (ORB-SLAM2: 2; 0 disables).
    pub cull_after_keyframes: usize,
    /// Express the SLAM map in the world by the rigid transform that best explains all kinematic
    /// priors so far, so that per-view biases average out: one residual per view (the view's mean
    /// prior camera centre and rotation against the SLAM's), whitened by the stated noise of
    /// [`Self::prior_noise`] and Huber-weighted ([`Self::anchor_huber`]), solved by
    /// Gauss-Newton from the chordal mean. If false, the map frame is the first frame's prior.
    pub anchor_to_prior_mean: bool,
    /// Huber width of the gauge fit, on a view's whitened 6-DoF residual norm (a view whose
    /// SLAM poses disagree with its prior by more than the stated noise counts less; a typical
    /// view has norm ≈ √6 ≈ 2.45).
    pub anchor_huber: f64,
    /// Reject a tracked pose whose world pose differs from the kinematic prior by more than this
    /// many times the prior's stated size (translation: bias + 3 jitter sigmas, at least 2 mm;
    /// rotation: likewise, at least 0.2°): the prior is never that far off, so such a pose is a
    /// false consensus; the frame is lost instead of corrupting the map. 0 disables.
    pub prior_gate_sigmas: f64,
    /// Within a view the kinematic prior's bias is constant, so the prior's motion since the
    /// last tracked frame of the same view predicts the SLAM pose far better than the prior
    /// itself: it differs from the true motion only by the jitter and by the bias conjugating the
    /// motion (at most θ·|bias translation| + |bias rotation|·d for a motion of angle θ and length
    /// d). Reject a tracked pose farther from that prediction than
    /// `motion_gate_floor_m` + θ·|bias translation| + |bias rotation|·d (rotation:
    /// `motion_gate_floor_deg` + θ·|bias rotation|): the frame is lost (reason
    /// `motion_disagreement`) and dead-reckoned from the last tracked frame instead. This catches
    /// what the prior gate is too wide for: a frame that shows little of the scene (the camera
    /// facing the robot's own link, a sliver of table left) and tracks to a consensus 2 cm off,
    /// then corrupts the map as a keyframe. Default 0.01 m and 2°; 0 disables; the first frame of a view is never gated
    /// (the bias changes between views). The prediction is made from each of the last
    /// [`Self::motion_gate_references`] tracked frames of the view and the pose passes when it
    /// agrees with any of them.
    pub motion_gate_floor_m: f64,
    /// See [`Self::motion_gate_floor_m`]; degrees.
    pub motion_gate_floor_deg: f64,
    /// How many of the last tracked frames of the view the motion gate predicts from (at least
    /// 1); a pose passes when it agrees with any prediction. With 1, a reference frame that was
    /// itself accepted slightly off (within the gate, e.g. 13 mm off the truth after a 7 mm
    /// frame) gets the next, correct frame rejected and the view dead-reckoned from the bad pose;
    /// with 2 a single off reference is outvoted by the one before it, while a frame off from
    /// both is still rejected.
    pub motion_gate_references: usize,
    /// After this many consecutive lost frames *that contradict the map* (at least
    /// [`Self::min_init_points`] keypoints with depth and at least [`Self::min_tracked_inliers`]
    /// map points predicted in view, yet no pose consensus, or a pose the prior or motion gate
    /// rejects: the map is likely wrong) the map's points and keyframes are dropped and a new map
    /// starts at the next frame's pose estimate, in the same map frame and world ← map gauge
    /// ([`Tracker::n_resets`]). Frames that show too little of the scene (e.g. the camera facing the robot's own
    /// links, whose pixels have no depth) are lost but keep the map, so tracking resumes against
    /// it when the scene reappears; frames that show a scene the map does not cover count towards
    /// [`Self::extend_after_unmapped`] instead.
    pub reset_after_lost: usize,
    /// After this many consecutive lost frames that show the scene (enough keypoints with depth)
    /// but little of the map (fewer than [`Self::min_tracked_inliers`] map points predicted in
    /// view, see [`LostReason::TooFewInliers`]: the camera looks where the map has no points), the map is *extended*: a keyframe is inserted at the
    /// frame's output pose (dead-reckoned from the last tracked frame within its view, else the
    /// prior) with new points from its keypoints, held fixed in bundle adjustment (nothing ties it
    /// to the rest of the map), and tracking goes on from it. The old map is kept, so tracking
    /// returns to it when the camera does. Default 3; 0 disables (such frames then count towards
    /// [`Self::reset_after_lost`]). Measurements: `studies/narrow_fov/`.
    pub extend_after_unmapped: usize,
}

impl Default for TrackerConfig {
    fn default() -> Self {
        Self {
            pose_source: PoseSource::Slam,
            orb: OrbConfig { spread_share: 0.5, ..OrbConfig::default() },
            prior_noise: PriorNoiseConfig::default(),
            ransac: RansacConfig::default(),
            refine: PoseRefineConfig::default(),
            bundle: BundleConfig::default(),
            defer_local_bundle: false,
            min_depth_m: 0.05,
            max_depth_m: 3.0,
            coarse_radius_px: 40.0,
            fine_radius_px: 6.0,
            match_max_distance: 80,
            match_ratio: 0.9,
            max_level_difference: 2,
            min_init_points: 50,
            min_tracked_inliers: 30,
            keyframe_inlier_ratio: 0.75,
            keyframe_max_interval: 10,
            local_keyframes: 5,
            max_new_points: 500,
            cull_found_ratio: 0.25,
            cull_min_visible: 4,
            cull_after_keyframes: 3,
            anchor_to_prior_mean: true,
            anchor_huber: 3.5,
            prior_gate_sigmas: 3.0,
            motion_gate_floor_m: 0.01,
            motion_gate_floor_deg: 2.0,
            motion_gate_references: 2,
            reset_after_lost: 10,
            extend_after_unmapped: 3,
        }
    }
}

/// One frame's input.
#[derive(Debug, Clone, Copy)]
pub struct TrackInput<'a> {
    /// Grey image, same size as the camera.
    pub grey: &'a GreyImage,
    /// Depth in metres (0 / non-finite / negative = no return), same size as the camera.
    pub depth: &'a DepthImage,
    /// Intrinsics.
    pub camera: &'a PinholeCamera,
    /// The kinematic prior (OpenCV axes): forward kinematics of the robot's nominal model (URDF
    /// and hand-eye calibration) on the joint readings paired with the image. Used as given: its
    /// error is the robot's (calibration, joint offsets, timing), never added here.
    pub world_from_camera_prior: Se3,
    /// Index of the view (one arm move) this frame belongs to: the gauge fit has one term per
    /// view and the motion gate predicts within a view.
    pub view_index: u64,
    /// The oracle pose, only for [`PoseSource::GroundTruth`] (required there); any other pose
    /// source rejects it ([`SlamError::OracleNotAllowed`]), so a true pose cannot reach an estimate.
    pub world_from_camera_oracle: Option<Se3>,
}

/// Why a frame was lost.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case", tag = "reason")]
pub enum LostReason {
    /// Too few keypoints (textureless image).
    TooFewFeatures {
        /// Keypoints found.
        found: usize,
        /// Needed.
        required: usize,
    },
    /// Too few keypoints with valid depth to initialise the map.
    NoDepth {
        /// Keypoints with depth.
        valid: usize,
        /// Needed.
        required: usize,
    },
    /// Pose estimation failed: too few matches or inliers (counts towards a map reset when
    /// `in_view` reaches [`TrackerConfig::min_tracked_inliers`], else towards an extension).
    TooFewInliers {
        /// Best inlier count reached.
        inliers: usize,
        /// Needed.
        required: usize,
        /// Most map points any seed pose predicts visible (in front of the camera, inside the
        /// image, where the measured depth agrees with the predicted one): how much of the map
        /// the frame should show (few: the camera sees what the map does not cover; many: the
        /// map and the image disagree).
        in_view: usize,
    },
    /// A pose was found but disagrees with the kinematic prior by more than
    /// [`TrackerConfig::prior_gate_sigmas`] times its stated noise (a false consensus, e.g. on
    /// repeated texture or on a wrongly placed part of the map).
    PriorDisagreement {
        /// Translation difference to the prior, millimetres (rounded).
        trans_mm: u32,
        /// Rotation difference to the prior, centidegrees (rounded).
        rot_cdeg: u32,
    },
    /// A pose was found but disagrees with the prior's motion since the last tracked frame of
    /// the same view by more than [`TrackerConfig::motion_gate_floor_m`] plus the bias's
    /// conjugation bound (a weakly constrained consensus).
    MotionDisagreement {
        /// Translation difference to the predicted pose, millimetres (rounded).
        trans_mm: u32,
        /// Rotation difference to the predicted pose, centidegrees (rounded).
        rot_cdeg: u32,
    },
}

/// Tracking state of a frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case", tag = "state")]
pub enum TrackingState {
    /// Pose estimated (or taken from the configured pose source).
    Ok,
    /// Lost: the output pose is the kinematic prior (or dead-reckoned from it).
    Lost {
        /// Why.
        reason: LostReason,
    },
}

/// A map point observed in the current frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ObservedPoint {
    /// Stable map point id.
    pub point_id: u64,
    /// Pixel of the observing keypoint (level-0 pixels).
    pub pixel: [f64; 2],
    /// Position in the world, metres.
    pub p_in_world: Point3<f64>,
}

/// The result of one [`Tracker::track`] call.
#[derive(Debug, Clone, PartialEq)]
pub struct TrackOutput {
    /// Frame counter of this tracker (0-based).
    pub frame_index: u64,
    /// Output camera pose (depends on the pose source; the prior when lost).
    pub world_from_camera: Se3,
    /// The kinematic prior given with this frame.
    pub world_from_camera_prior: Se3,
    /// Ok or lost (with reason).
    pub state: TrackingState,
    /// Map points observed in this frame (pose inliers and points created by it).
    pub observed: Vec<ObservedPoint>,
    /// Keypoints extracted.
    pub n_features: usize,
    /// Pose inliers (0 when lost or not estimated).
    pub n_inliers: usize,
    /// Whether this frame became a keyframe.
    pub keyframe_inserted: bool,
    /// Map points after this frame.
    pub n_map_points: usize,
}

impl TrackOutput {
    /// The "local object" point cloud of the paper (Sec. III-B): the observed map points whose
    /// pixel lies inside `bbox`.
    pub fn points_in_box(&self, bbox: &Box2) -> Vec<ObservedPoint> {
        self.observed.iter().filter(|p| bbox.contains(p.pixel[0], p.pixel[1])).copied().collect()
    }

    /// Whether the frame was tracked.
    pub fn is_ok(&self) -> bool {
        self.state == TrackingState::Ok
    }
}
#[derive(Debug, Clone, Copy)]
struct FrameRecord {
    map_from_camera: Option<Se3>,
    world_from_camera: Se3,
}

/// The RGB-D tracker (see the module docs).
#[derive(Debug)]
pub struct Tracker {
    config: TrackerConfig,
    orb: OrbExtractor,
    points: BTreeMap<u64, MapPoint>,
    keyframes: Vec<KeyFrame>,
    next_point_id: u64,
    frame_index: u64,
    n_resets: u32,
    anchor: Anchor,
    /// Last tracked frame: map ← camera, its prior, its view index.
    last: Option<(Se3, Se3, u64)>,
    /// The last tracked frames of the current view (map ← camera, prior), newest last, at most
    /// [`TrackerConfig::motion_gate_references`]: the motion gate's references.
    view_tracked: VecDeque<(Se3, Se3)>,
    frames_since_keyframe: usize,
    last_keyframe_tracked: usize,
    lost_streak: usize,
    /// Consecutive lost frames showing a scene the map does not cover
    /// ([`TrackerConfig::extend_after_unmapped`]).
    unmapped_streak: usize,
    /// Keyframes inserted at an estimated pose ([`TrackerConfig::extend_after_unmapped`]).
    n_extensions: usize,
    n_lost: usize,
    /// Lost frames that showed too little of the scene (see [`TrackerConfig::reset_after_lost`]).
    n_lost_hidden: usize,
    /// Lost frames by reason (`too_few_features`, `no_depth`, `too_few_inliers`, `prior_disagreement`,
    /// `motion_disagreement`).
    lost_by_reason: BTreeMap<&'static str, usize>,
    records: Vec<FrameRecord>,
    /// Threads a frame's tracking may use ([`Self::set_threads`], [`Self::thread_budget`]).
    threads: std::sync::Arc<crate::ThreadBudget>,
    /// The last keyframe's local bundle adjustment, running
    /// ([`TrackerConfig::defer_local_bundle`]).
    pending_bundle: Option<local_map::PendingBundle>,
}

impl Tracker {
    /// Check the configuration and build the tracker.
    pub fn new(config: TrackerConfig) -> Result<Self, SlamError> {
        let positive = [
            ("min_depth_m", config.min_depth_m),
            ("coarse_radius_px", config.coarse_radius_px),
            ("fine_radius_px", config.fine_radius_px),
            ("anchor_huber", config.anchor_huber),
        ];
        for (field, v) in [
            ("prior_gate_sigmas", config.prior_gate_sigmas),
            ("motion_gate_floor_m", config.motion_gate_floor_m),
            ("motion_gate_floor_deg", config.motion_gate_floor_deg),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(SlamError::Config { field, reason: format!("{v} must be finite and ≥ 0") });
            }
        }
        for (field, v) in positive {
            if !(v.is_finite() && v > 0.0) {
                return Err(SlamError::Config { field, reason: format!("{v} must be finite and > 0") });
            }
        }
        if config.max_depth_m.partial_cmp(&config.min_depth_m) != Some(std::cmp::Ordering::Greater) {
            return Err(SlamError::Config { field: "max_depth_m", reason: "must exceed min_depth_m".into() });
        }
        if let Err((field, v)) = config.prior_noise.validate() {
            return Err(SlamError::Config { field, reason: format!("{v} must be finite and ≥ 0") });
        }
        for (field, v) in [
            ("refine.depth_baseline_m", config.refine.depth_baseline_m),
            ("bundle.depth_baseline_m", config.bundle.depth_baseline_m),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(SlamError::Config { field, reason: format!("{v} must be finite and ≥ 0") });
            }
        }
        if config.local_keyframes == 0 {
            return Err(SlamError::Config { field: "local_keyframes", reason: "must be ≥ 1".into() });
        }
        if config.motion_gate_references == 0 {
            return Err(SlamError::Config { field: "motion_gate_references", reason: "must be ≥ 1".into() });
        }
        let orb = OrbExtractor::new(config.orb)?;
        Ok(Self {
            config,
            orb,
            points: BTreeMap::new(),
            keyframes: Vec::new(),
            next_point_id: 0,
            frame_index: 0,
            n_resets: 0,
            anchor: Anchor::new(&config.prior_noise, config.anchor_huber),
            last: None,
            view_tracked: VecDeque::new(),
            frames_since_keyframe: 0,
            last_keyframe_tracked: 0,
            lost_streak: 0,
            unmapped_streak: 0,
            n_extensions: 0,
            n_lost: 0,
            n_lost_hidden: 0,
            lost_by_reason: BTreeMap::new(),
            records: Vec::new(),
            threads: std::sync::Arc::new(crate::ThreadBudget::new(crate::worker_threads())),
            pending_bundle: None,
        })
    }

    /// The configuration.
    pub fn config(&self) -> &TrackerConfig {
        &self.config
    }

    /// Threads the following frames' tracking may use (ORB levels, projection search, local
    /// bundle adjustment): at least one, at most `crate::worker_threads()` (the default). The
    /// results do not depend on it; the system lowers it to one while a frame's line segments
    /// take the second core.
    pub fn set_threads(&mut self, threads: usize) {
        self.threads.set(threads);
    }

    /// The tracker's thread budget, which its parallel stages read when they start: others may
    /// change it during [`Self::track`] (the system lowers it when the frame's line segments
    /// start, from [`Self::track_then`]'s hook, and raises it when they are done).
    pub fn thread_budget(&self) -> std::sync::Arc<crate::ThreadBudget> {
        std::sync::Arc::clone(&self.threads)
    }

    /// Start the last keyframe's deferred local bundle adjustment
    /// ([`TrackerConfig::defer_local_bundle`]), if one waits, on a worker thread (one thread),
    /// to run beside what the caller does until the next frame. Its result does not depend on
    /// when, or whether, it is started.
    pub fn start_bundle(&mut self) {
        self.start_pending_bundle();
    }

    /// Apply the last keyframe's deferred local bundle adjustment, if any: wait for its thread,
    /// or solve it here when it was not started. [`Self::track`] does so first; the readers of
    /// the map and the trajectory see it only after one of the two.
    pub fn settle(&mut self) {
        self.settle_bundle();
    }

    /// Number of map points.
    pub fn n_map_points(&self) -> usize {
        self.points.len()
    }

    /// Number of keyframes.
    pub fn n_keyframes(&self) -> usize {
        self.keyframes.len()
    }

    /// How many times the tracker gave up its map and started a new one
    /// ([`TrackerConfig::reset_after_lost`]). The new map continues the old map's frame and world
    /// ← map gauge (it starts at the frame's pose estimate in that frame), so one gauge relates
    /// every frame's SLAM pose to the world across resets.
    pub fn n_resets(&self) -> u32 {
        self.n_resets
    }

    /// Number of lost frames so far.
    pub fn n_lost(&self) -> usize {
        self.n_lost
    }

    /// Lost frames that showed too little of the scene to track (fewer than
    /// [`TrackerConfig::min_init_points`] keypoints with depth: e.g. the camera facing the robot's
    /// own links, whose pixels carry no depth). A subset of [`Self::n_lost`].
    pub fn n_lost_scene_hidden(&self) -> usize {
        self.n_lost_hidden
    }

    /// Keyframes inserted at an estimated pose where the camera saw what the map did not cover
    /// ([`TrackerConfig::extend_after_unmapped`]).
    pub fn n_extensions(&self) -> usize {
        self.n_extensions
    }

    /// Lost frames by reason: `too_few_features`, `no_depth`, `too_few_inliers`,
    /// `prior_disagreement`.
    pub fn lost_by_reason(&self) -> &BTreeMap<&'static str, usize> {
        &self.lost_by_reason
    }

    /// The current world ← map transform (identity for non-`slam` sources).
    pub fn world_from_map(&self) -> Se3 {
        if self.config.pose_source == PoseSource::Slam && self.config.anchor_to_prior_mean {
            self.anchor.world_from_map()
        } else {
            Se3::identity()
        }
    }

    /// All map points in the world frame, by id.
    pub fn map_points_in_world(&self) -> Vec<(u64, Point3<f64>)> {
        let w = self.world_from_map();
        self.points.iter().map(|(id, p)| (*id, w * p.p_in_map)).collect()
    }

    /// The trajectory so far, one pose per tracked call, re-expressed with the latest world ← map
    /// anchor for tracked frames (the SLAM's best estimate of the whole trajectory at
    /// this time; the online poses are the `world_from_camera` of each [`TrackOutput`]).
    pub fn trajectory(&self) -> Vec<Se3> {
        let w = self.world_from_map();
        self.records
            .iter()
            .map(|r| match r.map_from_camera {
                Some(m) => w * m,
                _ => r.world_from_camera,
            })
            .collect()
    }

    /// Track one frame. Errors only for malformed input (sizes, buffers, intrinsics, a
    /// non-finite or non-rigid prior, a missing ground-truth pose); anything the images do not
    /// support (no texture, no depth, no consensus) is a reported lost frame.
    pub fn track(&mut self, input: &TrackInput<'_>) -> Result<TrackOutput, SlamError> {
        self.track_then(input, || {})
    }

    /// [`Self::track`], calling `after_features` once the frame's ORB features are extracted
    /// (not at all when the input is rejected first): a caller that shares the cores with the
    /// tracker starts its own work there, after the extraction had both
    /// ([`Self::thread_budget`]). The output does not depend on what it does.
    pub fn track_then(
        &mut self,
        input: &TrackInput<'_>,
        after_features: impl FnOnce(),
    ) -> Result<TrackOutput, SlamError> {
        self.settle_bundle();
        validate(input)?;
        match (self.config.pose_source, input.world_from_camera_oracle) {
            (PoseSource::GroundTruth, Some(oracle)) => check_pose(&oracle, "world_from_camera_oracle")?,
            (PoseSource::GroundTruth, None) => return Err(SlamError::MissingGroundTruth),
            (source, Some(_)) => return Err(SlamError::OracleNotAllowed { pose_source: source }),
            (_, None) => {}
        }
        let frame_index = self.frame_index;
        self.frame_index += 1;
        let prior = input.world_from_camera_prior;
        // ORB on the threads one frame may use (the same features on any number of them).
        let features = self.orb.extract_with_threads(input.grey, self.threads.get())?;
        after_features();
        let depth_m: Vec<Option<f64>> = features
            .keypoints
            .iter()
            .map(|k| {
                let (u, v) = (k.x.round() as u32, k.y.round() as u32);
                input
                    .depth
                    .at(u, v)
                    .map(f64::from)
                    .filter(|d| (self.config.min_depth_m..=self.config.max_depth_m).contains(d))
            })
            .collect();
        let grid = KeypointGrid::new(&features.keypoints, input.camera.width, input.camera.height, 16.0);
        let frame = FrameData { features, depth_m, grid };
        let camera = input.camera;
        let mut out = TrackOutput {
            frame_index,
            world_from_camera: prior,
            world_from_camera_prior: prior,
            state: TrackingState::Ok,
            observed: Vec::new(),
            n_features: frame.features.keypoints.len(),
            n_inliers: 0,
            keyframe_inserted: false,
            n_map_points: 0,
        };
        let known = match self.config.pose_source {
            PoseSource::Slam => None,
            PoseSource::Kinematics => Some(prior),
            PoseSource::GroundTruth => input.world_from_camera_oracle,
        };
        let min_features = self.config.min_tracked_inliers.max(self.config.ransac.min_inliers);
        let result = if frame.features.keypoints.len() < min_features {
            Err(LostReason::TooFewFeatures { found: frame.features.keypoints.len(), required: min_features })
        } else if let Some(pose) = known {
            Ok(self.step_known_pose(&frame, camera, pose))
        } else {
            self.step_slam(&frame, input.depth, camera, &prior, input.view_index)
        };
        match result {
            Ok((map_from_camera, matches, n_inliers)) => {
                self.lost_streak = 0;
                self.unmapped_streak = 0;
                if self.config.pose_source == PoseSource::Slam {
                    self.anchor.add(&prior, &map_from_camera, input.view_index);
                }
                let (map_from_camera, observed_ids, kf) =
                    self.after_tracking(&frame, camera, map_from_camera, &matches);
                let world_from_map = self.world_from_map();
                out.world_from_camera = world_from_map * map_from_camera;
                out.n_inliers = n_inliers;
                out.keyframe_inserted = kf;
                out.observed = observed_ids
                    .iter()
                    .filter_map(|m| {
                        let p = self.points.get(&m.point_id)?;
                        let k = frame.features.keypoints.get(m.keypoint)?;
                        Some(ObservedPoint {
                            point_id: m.point_id,
                            pixel: k.image_point(),
                            p_in_world: world_from_map * p.p_in_map,
                        })
                    })
                    .collect();
                if self.last.is_some_and(|(_, _, v)| v != input.view_index) {
                    self.view_tracked.clear();
                }
                self.view_tracked.push_back((map_from_camera, prior));
                while self.view_tracked.len() > self.config.motion_gate_references.max(1) {
                    self.view_tracked.pop_front();
                }
                self.last = Some((map_from_camera, prior, input.view_index));
                self.records.push(FrameRecord {
                    map_from_camera: Some(map_from_camera),
                    world_from_camera: out.world_from_camera,
                });
            }
            Err(reason) => {
                self.n_lost += 1;
                let shows_scene = frame.depth_m.iter().flatten().count() >= self.config.min_init_points;
                let unmapped = self.config.extend_after_unmapped > 0
                    && matches!(reason, LostReason::TooFewInliers { in_view, .. }
                        if in_view < self.config.min_tracked_inliers);
                if !shows_scene {
                    self.n_lost_hidden += 1;
                } else if unmapped {
                    self.unmapped_streak += 1;
                } else {
                    self.lost_streak += 1;
                }
                let key = match reason {
                    LostReason::TooFewFeatures { .. } => "too_few_features",
                    LostReason::NoDepth { .. } => "no_depth",
                    LostReason::TooFewInliers { .. } => "too_few_inliers",
                    LostReason::PriorDisagreement { .. } => "prior_disagreement",
                    LostReason::MotionDisagreement { .. } => "motion_disagreement",
                };
                *self.lost_by_reason.entry(key).or_insert(0) += 1;
                out.state = TrackingState::Lost { reason };
                out.world_from_camera = known.unwrap_or(prior);
                // Within the view of the last tracked frame the prior's bias is constant, so the
                // prior's motion since then carries the SLAM pose forward (dead reckoning; only
                // the jitter accumulates). Across views the bias changes: the prior itself.
                if let (PoseSource::Slam, Some((last_map, last_prior, last_view))) =
                    (self.config.pose_source, self.last)
                {
                    if last_view == input.view_index {
                        out.world_from_camera = self.world_from_map() * last_map * (last_prior.inverse() * prior);
                    }
                }
                if self.lost_streak >= self.config.reset_after_lost.max(1)
                    && self.config.pose_source == PoseSource::Slam
                {
                    self.reset_map();
                } else if shows_scene
                    && unmapped
                    && self.unmapped_streak >= self.config.extend_after_unmapped
                    && self.config.pose_source == PoseSource::Slam
                {
                    self.extend_map(&frame, camera, &out.world_from_camera, &prior, input.view_index);
                }
                self.records.push(FrameRecord { map_from_camera: None, world_from_camera: out.world_from_camera });
            }
        }
        out.n_map_points = self.points.len();
        Ok(out)
    }
}

fn check_pose(pose: &Se3, field: &'static str) -> Result<(), SlamError> {
    if !super::is_finite_pose(pose) {
        return Err(SlamError::NonFinitePose { field });
    }
    let qn = pose.rotation.quaternion().norm();
    if (qn - 1.0).abs() > 1e-6 {
        return Err(SlamError::NotRigid { field, reason: format!("rotation quaternion has norm {qn}") });
    }
    Ok(())
}

fn validate(input: &TrackInput<'_>) -> Result<(), SlamError> {
    input.camera.validate()?;
    let (w, h) = (input.camera.width, input.camera.height);
    for (field, iw, ih, len) in [
        ("grey", input.grey.width, input.grey.height, input.grey.data.len()),
        ("depth", input.depth.width, input.depth.height, input.depth.data.len()),
    ] {
        if iw != w || ih != h {
            return Err(SlamError::ImageSize { field, width: w, height: h, actual_width: iw, actual_height: ih });
        }
        let expected = w as usize * h as usize;
        if len != expected {
            return Err(SlamError::BufferLength { field, expected, actual: len });
        }
    }
    check_pose(&input.world_from_camera_prior, "world_from_camera_prior")
}
