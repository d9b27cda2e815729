//! The RGB-D tracker: one [`Tracker::track`] call per frame does feature extraction, pose
//! estimation (or takes the configured pose source), keyframe insertion, local BA and culling.

use std::collections::{BTreeMap, VecDeque};

use nalgebra::{Matrix3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

use super::ba::{BundleConfig, BundleObservation, BundleProblem};
use super::features::{hamming, Descriptor, Features, OrbConfig, OrbExtractor};
use super::matcher::KeypointGrid;
use super::noise::PriorNoiseConfig;
use super::pnp::{refine_pose, solve_pnp_ransac, Correspondence, PoseRefineConfig, RansacConfig};
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
    /// Feature extraction.
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
            orb: OrbConfig::default(),
            prior_noise: PriorNoiseConfig::default(),
            ransac: RansacConfig::default(),
            refine: PoseRefineConfig::default(),
            bundle: BundleConfig::default(),
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

#[derive(Debug, Clone)]
struct MapPoint {
    p_in_map: Point3<f64>,
    descriptor: Descriptor,
    level: u8,
    keyframes: Vec<usize>,
    created_kf: usize,
    n_visible: u32,
    n_found: u32,
}

#[derive(Debug, Clone, Copy)]
struct KfObservation {
    point_id: u64,
    pixel: [f64; 2],
    depth_m: Option<f64>,
    sigma_px: f64,
}

#[derive(Debug, Clone)]
struct KeyFrame {
    map_from_camera: Se3,
    observations: Vec<KfObservation>,
    /// Inserted at an estimated pose without tracking ([`TrackerConfig::extend_after_unmapped`]):
    /// held fixed in bundle adjustment.
    fixed: bool,
}

#[derive(Debug, Clone, Copy)]
struct FrameRecord {
    map_from_camera: Option<Se3>,
    world_from_camera: Se3,
}

/// Per-view running sums of the world ← map gauge (see [`TrackerConfig::anchor_to_prior_mean`]).
#[derive(Debug, Clone, Copy)]
struct ViewSums {
    /// Σ R(prior_i) R(map_from_camera_i)ᵀ over the view's tracked frames.
    rotation_sum: Matrix3<f64>,
    /// Σ prior camera centres.
    prior_center_sum: Vector3<f64>,
    /// Σ SLAM (map-frame) camera centres.
    map_center_sum: Vector3<f64>,
    n: f64,
    /// The rotation closest to `rotation_sum / n` (updated on add).
    mean_rotation: Option<UnitQuaternion<f64>>,
}

/// The world ← map gauge: a weighted robust least-squares fit of one rigid transform to every
/// view's mean kinematic prior (one term per view, since the bias is per view).
#[derive(Debug, Clone)]
struct Anchor {
    views: BTreeMap<u64, ViewSums>,
    /// Per-axis standard deviation of a view's mean camera-centre prior, metres.
    sigma_t: f64,
    /// Per-axis standard deviation of a view's mean rotation prior, radians.
    sigma_r: f64,
    /// Huber width on a view's whitened 6-DoF residual norm.
    huber: f64,
    /// Cached estimate (also the warm start of the next fit).
    world_from_map: Se3,
    /// Whether `world_from_map` holds a fit.
    solved: bool,
}

impl Anchor {
    fn new(noise: &PriorNoiseConfig, huber: f64) -> Self {
        // A view's mean prior is off by the view's bias (uniform direction, fixed size: per-axis
        // variance size² / 3) plus averaged jitter; the floor keeps the weights finite.
        let sigma_t = (noise.bias_trans_m.powi(2) / 3.0 + noise.jitter_trans_m.powi(2)).sqrt().max(1e-5);
        let sigma_r = (noise.bias_rot_deg.to_radians().powi(2) / 3.0 + noise.jitter_rot_deg.to_radians().powi(2))
            .sqrt()
            .max(1e-5);
        Self { views: BTreeMap::new(), sigma_t, sigma_r, huber, world_from_map: Se3::identity(), solved: false }
    }

    fn add(&mut self, world_from_camera_prior: &Se3, map_from_camera: &Se3, view_index: u64) {
        let d = world_from_camera_prior.rotation * map_from_camera.rotation.inverse();
        let v = self.views.entry(view_index).or_insert(ViewSums {
            rotation_sum: Matrix3::zeros(),
            prior_center_sum: Vector3::zeros(),
            map_center_sum: Vector3::zeros(),
            n: 0.0,
            mean_rotation: None,
        });
        v.rotation_sum += d.to_rotation_matrix().matrix();
        v.prior_center_sum += world_from_camera_prior.translation.vector;
        v.map_center_sum += map_from_camera.translation.vector;
        v.n += 1.0;
        v.mean_rotation = project_rotation(&(v.rotation_sum / v.n));
        self.world_from_map = self.solve();
        self.solved = true;
    }

    fn world_from_map(&self) -> Se3 {
        self.world_from_map
    }

    /// Per view: (mean rotation residual target R̄_v, mean prior centre, mean map centre).
    fn view_means(&self) -> Vec<(UnitQuaternion<f64>, Vector3<f64>, Vector3<f64>)> {
        self.views
            .values()
            .filter(|v| v.n > 0.0)
            .filter_map(|v| Some((v.mean_rotation?, v.prior_center_sum / v.n, v.map_center_sum / v.n)))
            .collect()
    }

    fn solve(&self) -> Se3 {
        let means = self.view_means();
        if means.is_empty() {
            return Se3::identity();
        }
        // Start: the previous fit (one frame moves it little), else the chordal mean of the view
        // rotations and the centroid of the view centres.
        let (mut rot, mut t) = if self.solved {
            (self.world_from_map.rotation, self.world_from_map.translation.vector)
        } else {
            let mut rsum = Matrix3::zeros();
            for (r, _, _) in &means {
                rsum += r.to_rotation_matrix().matrix();
            }
            let Some(rot) = project_rotation(&rsum) else {
                return Se3::identity();
            };
            let n = means.len() as f64;
            let cp: Vector3<f64> = means.iter().map(|m| m.1).sum::<Vector3<f64>>() / n;
            let cm: Vector3<f64> = means.iter().map(|m| m.2).sum::<Vector3<f64>>() / n;
            (rot, cp - rot * cm)
        };
        // Gauss-Newton with Huber weights per view. Unknowns: δθ (left rotation increment), δt.
        // Residuals per view: e_t = c̄P − (R c̄M + t), e_r = log(R̄_v Rᵀ), whitened by σ_t, σ_r.
        for _ in 0..8 {
            let mut h = nalgebra::Matrix6::<f64>::zeros();
            let mut b = nalgebra::Vector6::<f64>::zeros();
            for (rv, pc, mc) in &means {
                let rm = rot * mc;
                let et = (pc - rm - t) / self.sigma_t;
                let er = (rv * rot.inverse()).scaled_axis() / self.sigma_r;
                let norm = (et.norm_squared() + er.norm_squared()).sqrt();
                let w = if norm <= self.huber { 1.0 } else { self.huber / norm };
                // d e_t / d δθ = [R c̄M]ₓ / σ_t, d e_t / d δt = −I / σ_t; d e_r / d δθ ≈ −I / σ_r.
                let mut j = nalgebra::Matrix6::<f64>::zeros();
                j.fixed_view_mut::<3, 3>(0, 0).copy_from(&(rm.cross_matrix() / self.sigma_t));
                j.fixed_view_mut::<3, 3>(0, 3).copy_from(&(-Matrix3::identity() / self.sigma_t));
                j.fixed_view_mut::<3, 3>(3, 0).copy_from(&(-Matrix3::identity() / self.sigma_r));
                let mut e = nalgebra::Vector6::<f64>::zeros();
                e.fixed_rows_mut::<3>(0).copy_from(&et);
                e.fixed_rows_mut::<3>(3).copy_from(&er);
                h += j.transpose() * j * w;
                b -= j.transpose() * e * w;
            }
            let Some(dx) = h.cholesky().map(|c| c.solve(&b)) else {
                break;
            };
            let dth = Vector3::new(dx[0], dx[1], dx[2]);
            let dt = Vector3::new(dx[3], dx[4], dx[5]);
            let dr = UnitQuaternion::from_scaled_axis(dth);
            // Left increment of the rotation: R ← exp(δθ) R, t ← t + δt (the residual model
            // above linearises exp(δθ) R c̄M ≈ R c̄M + δθ × R c̄M).
            rot = dr * rot;
            t += dt;
            if dth.norm() < 1e-9 && dt.norm() < 1e-9 {
                break;
            }
        }
        Se3::from_parts(Translation3::from(t), rot)
    }
}

/// The rotation closest (Frobenius) to a 3x3 matrix, or None if it is degenerate.
fn project_rotation(m: &Matrix3<f64>) -> Option<UnitQuaternion<f64>> {
    let svd = m.svd(true, true);
    let (u, v_t) = (svd.u?, svd.v_t?);
    let mut fix = Matrix3::identity();
    fix[(2, 2)] = (u * v_t).determinant().signum();
    let r = u * fix * v_t;
    Some(UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r)))
}

/// Per-frame working data.
struct FrameData {
    features: Features,
    depth_m: Vec<Option<f64>>,
    grid: KeypointGrid,
}

/// A match from the projection search.
#[derive(Debug, Clone, Copy)]
struct PointMatch {
    point_id: u64,
    keypoint: usize,
}

/// The RGB-D tracker (see the module docs).
#[derive(Debug, Clone)]
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
        })
    }

    /// The configuration.
    pub fn config(&self) -> &TrackerConfig {
        &self.config
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
        let features = self.orb.extract(input.grey)?;
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

    /// Insert a fixed keyframe at `world_from_camera` (the frame's output pose) so tracking goes
    /// on where the map has no points ([`TrackerConfig::extend_after_unmapped`]).
    fn extend_map(
        &mut self,
        frame: &FrameData,
        camera: &PinholeCamera,
        world_from_camera: &Se3,
        prior: &Se3,
        view_index: u64,
    ) {
        let map_from_camera = self.world_from_map().inverse() * world_from_camera;
        let (map_from_camera, _) = self.insert_keyframe_with(frame, camera, map_from_camera, &[], true);
        self.n_extensions += 1;
        self.unmapped_streak = 0;
        // The next frame is seeded from here by the prior's motion, as from a tracked frame; the
        // motion gate predicts from it too (within the view the estimate's error is the last
        // tracked frame's plus the jitter).
        if self.last.is_some_and(|(_, _, v)| v != view_index) {
            self.view_tracked.clear();
        }
        self.view_tracked.push_back((map_from_camera, *prior));
        while self.view_tracked.len() > self.config.motion_gate_references.max(1) {
            self.view_tracked.pop_front();
        }
        self.last = Some((map_from_camera, *prior, view_index));
    }

    /// Drop the map's points and keyframes. The map frame, the world ← map gauge (with every view
    /// it was fitted to) and the last tracked frame stay: the next frame with depth starts the new
    /// map at its pose estimate in the same frame (dead-reckoned from the last tracked frame
    /// within its view, else the prior through the gauge), so the object map, placed with the
    /// gauge, stays where it is.
    fn reset_map(&mut self) {
        self.points.clear();
        self.keyframes.clear();
        self.view_tracked.clear();
        self.n_resets += 1;
        self.lost_streak = 0;
        self.unmapped_streak = 0;
    }

    /// Known pose: just associate to the map (no pose estimation). Returns map ← camera.
    fn step_known_pose(
        &self,
        frame: &FrameData,
        camera: &PinholeCamera,
        world_from_camera: Se3,
    ) -> (Se3, Vec<PointMatch>, usize) {
        let map_from_camera = world_from_camera; // map frame = world for non-slam sources
        let matches = self.search_by_projection(
            frame,
            camera,
            &map_from_camera.inverse(),
            2.0 * self.config.fine_radius_px,
            true,
        );
        let n = matches.len();
        (map_from_camera, matches, n)
    }

    fn step_slam(
        &self,
        frame: &FrameData,
        depth: &DepthImage,
        camera: &PinholeCamera,
        prior: &Se3,
        view_index: u64,
    ) -> Result<(Se3, Vec<PointMatch>, usize), LostReason> {
        let anchored = self.world_from_map().inverse() * prior;
        if self.points.is_empty() {
            let valid = frame.depth_m.iter().flatten().count();
            if valid < self.config.min_init_points {
                return Err(LostReason::NoDepth { valid, required: self.config.min_init_points });
            }
            // After a reset: dead-reckoned from the last tracked frame within its view.
            let start = match self.last {
                Some((last_map_from_camera, last_prior, last_view)) if last_view == view_index => {
                    last_map_from_camera * (last_prior.inverse() * prior)
                }
                _ => anchored,
            };
            return Ok((start, Vec::new(), 0));
        }
        let mut seeds = Vec::with_capacity(2);
        // The prior's motion since the last tracked frames of this view (same bias): the gate's
        // predictions (newest first); since the last one, the first seed.
        let mut predicted = Vec::new();
        if let Some((last_map_from_camera, last_prior, last_view)) = self.last {
            seeds.push(last_map_from_camera * (last_prior.inverse() * prior));
            if last_view == view_index {
                predicted = self
                    .view_tracked
                    .iter()
                    .rev()
                    .map(|(m, p)| {
                        let motion = p.inverse() * prior;
                        (m * motion, motion)
                    })
                    .collect();
            }
        }
        seeds.push(anchored);
        let (mut best_inliers, mut in_view) = (0, 0);
        let mut disagreement = None;
        for seed in seeds {
            match self.estimate_from_seed(frame, camera, &seed) {
                Ok(r) => {
                    match self.prior_disagreement(&r.0, &anchored).or_else(|| self.motion_gate(&r.0, &predicted)) {
                        None => return Ok(r),
                        Some(d) => disagreement = Some(d),
                    }
                }
                Err(n) => {
                    best_inliers = best_inliers.max(n);
                    in_view = in_view.max(self.points_in_view(camera, &seed.inverse(), depth));
                }
            }
        }
        if let Some(d) = disagreement {
            return Err(d);
        }
        Err(LostReason::TooFewInliers { inliers: best_inliers, required: self.config.min_tracked_inliers, in_view })
    }

    /// `Some(reason)` if `map_from_camera` is implausibly far from the prior (both in the map
    /// frame) by [`TrackerConfig::prior_gate_sigmas`].
    fn prior_disagreement(&self, map_from_camera: &Se3, prior_in_map: &Se3) -> Option<LostReason> {
        let k = self.config.prior_gate_sigmas;
        if k <= 0.0 {
            return None;
        }
        let n = &self.config.prior_noise;
        let gate_t = k * (n.bias_trans_m + 3.0 * n.jitter_trans_m).max(0.002);
        let gate_r = k * (n.bias_rot_deg + 3.0 * n.jitter_rot_deg).max(0.2);
        let dt = (map_from_camera.translation.vector - prior_in_map.translation.vector).norm();
        let dr = (map_from_camera.rotation.inverse() * prior_in_map.rotation).angle().to_degrees();
        (dt > gate_t || dr > gate_r).then(|| LostReason::PriorDisagreement {
            trans_mm: (dt * 1e3).round().min(f64::from(u32::MAX)) as u32,
            rot_cdeg: (dr * 100.0).round().min(f64::from(u32::MAX)) as u32,
        })
    }

    /// `Some(reason)` (against the newest reference) if `map_from_camera` disagrees with every
    /// prediction of the motion gate; `None` when it agrees with one or there are none.
    fn motion_gate(&self, map_from_camera: &Se3, predicted: &[(Se3, Se3)]) -> Option<LostReason> {
        let mut reasons = predicted.iter().map(|(p, m)| self.motion_disagreement(map_from_camera, p, m));
        let first = reasons.next()??;
        reasons.all(|r| r.is_some()).then_some(first)
    }

    /// `Some(reason)` if `map_from_camera` is farther from `predicted` (the last tracked pose of
    /// this view moved by the prior's `motion` since then) than the motion gate
    /// ([`TrackerConfig::motion_gate_floor_m`]).
    fn motion_disagreement(&self, map_from_camera: &Se3, predicted: &Se3, motion: &Se3) -> Option<LostReason> {
        let (floor_t, floor_r) = (self.config.motion_gate_floor_m, self.config.motion_gate_floor_deg);
        if floor_t <= 0.0 && floor_r <= 0.0 {
            return None;
        }
        let n = &self.config.prior_noise;
        let (theta, d) = (motion.rotation.angle(), motion.translation.vector.norm());
        let bias_rot = n.bias_rot_deg.to_radians();
        let gate_t = floor_t + theta * n.bias_trans_m + bias_rot * d;
        let gate_r = floor_r + (theta * bias_rot).to_degrees();
        let dt = (map_from_camera.translation.vector - predicted.translation.vector).norm();
        let dr = (map_from_camera.rotation.inverse() * predicted.rotation).angle().to_degrees();
        ((floor_t > 0.0 && dt > gate_t) || (floor_r > 0.0 && dr > gate_r)).then(|| LostReason::MotionDisagreement {
            trans_mm: (dt * 1e3).round().min(f64::from(u32::MAX)) as u32,
            rot_cdeg: (dr * 100.0).round().min(f64::from(u32::MAX)) as u32,
        })
    }

    /// Map points `camera_from_map` predicts visible: in front of the camera, inside the image,
    /// and where the image has depth, within 5 cm or 5 % of it (a point behind what the camera
    /// sees, or where it sees nothing, does not count).
    fn points_in_view(&self, camera: &PinholeCamera, camera_from_map: &Se3, depth: &DepthImage) -> usize {
        self.points
            .values()
            .filter(|p| {
                let x = camera_from_map * p.p_in_map;
                if x.z < self.config.min_depth_m {
                    return false;
                }
                let Some(uv) = camera.project(&x).filter(|uv| camera.contains(*uv)) else {
                    return false;
                };
                let (col, row) = (uv[0].floor() as usize, uv[1].floor() as usize);
                let d = depth.data.get(row * depth.width as usize + col).copied().unwrap_or(0.0);
                let d = f64::from(d);
                d.is_finite() && d > 0.0 && (d - x.z).abs() <= 0.05f64.max(0.05 * x.z)
            })
            .count()
    }

    /// Coarse projection search + RANSAC, then fine search + robust refinement. `Err(inliers)`.
    fn estimate_from_seed(
        &self,
        frame: &FrameData,
        camera: &PinholeCamera,
        seed: &Se3,
    ) -> Result<(Se3, Vec<PointMatch>, usize), usize> {
        let coarse = self.search_by_projection(frame, camera, &seed.inverse(), self.config.coarse_radius_px, false);
        let corr = self.correspondences(frame, &coarse);
        let mut ransac = self.config.ransac;
        ransac.seed ^= self.frame_index.wrapping_mul(0x9E37_79B9_7F4A_7C15);
        let est = solve_pnp_ransac(&corr, camera, seed, &ransac, &self.config.refine).map_err(|_| 0usize)?;
        let fine = self.search_by_projection(
            frame,
            camera,
            &est.world_from_camera.inverse(),
            self.config.fine_radius_px,
            true,
        );
        let corr = self.correspondences(frame, &fine);
        let refined =
            refine_pose(&corr, camera, &est.world_from_camera, &self.config.refine).map_err(|_| est.n_inliers)?;
        if refined.n_inliers < self.config.min_tracked_inliers {
            return Err(refined.n_inliers);
        }
        let inlier_matches: Vec<PointMatch> =
            fine.iter().zip(&refined.inliers).filter_map(|(m, &k)| k.then_some(*m)).collect();
        Ok((refined.world_from_camera, inlier_matches, refined.n_inliers))
    }

    fn correspondences(&self, frame: &FrameData, matches: &[PointMatch]) -> Vec<Correspondence> {
        matches
            .iter()
            .filter_map(|m| {
                let p = self.points.get(&m.point_id)?;
                let k = frame.features.keypoints.get(m.keypoint)?;
                Some(Correspondence {
                    p_in_world: p.p_in_map,
                    pixel: k.image_point(),
                    depth_m: frame.depth_m.get(m.keypoint).copied().flatten(),
                    sigma_px: f64::from(k.scale),
                })
            })
            .collect()
    }

    /// Project every map point with `camera_from_map` and match it to the best keypoint within
    /// `radius_px × scale` (ratio test; each keypoint keeps its closest point).
    fn search_by_projection(
        &self,
        frame: &FrameData,
        camera: &PinholeCamera,
        camera_from_map: &Se3,
        radius_px: f64,
        scale_radius: bool,
    ) -> Vec<PointMatch> {
        let kps = &frame.features.keypoints;
        let mut best_for_kp: Vec<Option<(u32, u64)>> = vec![None; kps.len()];
        let mut cand = Vec::new();
        let scale_factor = self.config.orb.scale_factor;
        for (&id, p) in &self.points {
            let x = camera_from_map * p.p_in_map;
            if x.z < self.config.min_depth_m {
                continue;
            }
            let Some(uv) = camera.project(&x) else {
                continue;
            };
            if !camera.contains(uv) {
                continue;
            }
            let r = if scale_radius { radius_px * scale_factor.powi(i32::from(p.level)) } else { radius_px };
            // The grid holds keypoint indices (pixel centre at the index): image point − 0.5.
            frame.grid.within(kps, (uv[0] - 0.5) as f32, (uv[1] - 0.5) as f32, r as f32, &mut cand);
            let (mut best, mut second, mut best_i) = (u32::MAX, u32::MAX, usize::MAX);
            for &i in &cand {
                let i = i as usize;
                let (Some(k), Some(d)) = (kps.get(i), frame.features.descriptors.get(i)) else {
                    continue;
                };
                if k.level.abs_diff(p.level) > self.config.max_level_difference {
                    continue;
                }
                let dist = hamming(&p.descriptor, d);
                if dist < best {
                    second = best;
                    best = dist;
                    best_i = i;
                } else if dist < second {
                    second = dist;
                }
            }
            if best > self.config.match_max_distance
                || (second != u32::MAX && best as f32 >= self.config.match_ratio * second as f32)
            {
                continue;
            }
            if let Some(slot) = best_for_kp.get_mut(best_i) {
                if slot.is_none_or(|(d, _)| best < d) {
                    *slot = Some((best, id));
                }
            }
        }
        best_for_kp
            .iter()
            .enumerate()
            .filter_map(|(i, s)| s.map(|(_, id)| PointMatch { point_id: id, keypoint: i }))
            .collect()
    }

    /// Bookkeeping after a successful pose: visibility counts, keyframe insertion (new points,
    /// local BA, culling). Returns the (possibly BA-refined) pose, the observed points and whether
    /// a keyframe was inserted.
    fn after_tracking(
        &mut self,
        frame: &FrameData,
        camera: &PinholeCamera,
        map_from_camera: Se3,
        matches: &[PointMatch],
    ) -> (Se3, Vec<PointMatch>, bool) {
        let camera_from_map = map_from_camera.inverse();
        for p in self.points.values_mut() {
            let x = camera_from_map * p.p_in_map;
            if camera.project(&x).is_some_and(|uv| camera.contains(uv)) {
                p.n_visible += 1;
            }
        }
        for m in matches {
            if let Some(p) = self.points.get_mut(&m.point_id) {
                p.n_found += 1;
            }
        }
        self.frames_since_keyframe += 1;
        let need_kf = self.keyframes.is_empty()
            || self.frames_since_keyframe >= self.config.keyframe_max_interval
            || (matches.len() as f64) < self.config.keyframe_inlier_ratio * self.last_keyframe_tracked as f64;
        if !need_kf {
            return (map_from_camera, matches.to_vec(), false);
        }
        let (pose, observed) = self.insert_keyframe_with(frame, camera, map_from_camera, matches, false);
        (pose, observed, true)
    }

    /// Insert a keyframe (`fixed`: held fixed in bundle adjustment) with new points from the
    /// unmatched keypoints with depth, then bundle-adjust and cull.
    fn insert_keyframe_with(
        &mut self,
        frame: &FrameData,
        camera: &PinholeCamera,
        map_from_camera: Se3,
        matches: &[PointMatch],
        fixed: bool,
    ) -> (Se3, Vec<PointMatch>) {
        let kf_index = self.keyframes.len();
        let kps = &frame.features.keypoints;
        let mut observations = Vec::with_capacity(matches.len() + self.config.max_new_points);
        let mut observed = matches.to_vec();
        let mut used = vec![false; kps.len()];
        for m in matches {
            let Some(k) = kps.get(m.keypoint) else {
                continue;
            };
            if let Some(u) = used.get_mut(m.keypoint) {
                *u = true;
            }
            if let Some(p) = self.points.get_mut(&m.point_id) {
                p.keyframes.push(kf_index);
            }
            observations.push(KfObservation {
                point_id: m.point_id,
                pixel: k.image_point(),
                depth_m: frame.depth_m.get(m.keypoint).copied().flatten(),
                sigma_px: f64::from(k.scale),
            });
        }
        // New points from unmatched keypoints with depth, closest first.
        let mut fresh: Vec<(usize, f64)> = (0..kps.len())
            .filter(|&i| !used.get(i).copied().unwrap_or(true))
            .filter_map(|i| Some((i, frame.depth_m.get(i).copied().flatten()?)))
            .collect();
        fresh.sort_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)));
        for &(i, d) in fresh.iter().take(self.config.max_new_points) {
            let (Some(k), Some(desc)) = (kps.get(i), frame.features.descriptors.get(i)) else {
                continue;
            };
            let [ku, kv] = k.image_point();
            let p_in_camera = camera.unproject(ku, kv, d);
            let id = self.next_point_id;
            self.next_point_id += 1;
            self.points.insert(
                id,
                MapPoint {
                    p_in_map: map_from_camera * p_in_camera,
                    descriptor: *desc,
                    level: k.level,
                    keyframes: vec![kf_index],
                    created_kf: kf_index,
                    n_visible: 1,
                    n_found: 1,
                },
            );
            observations.push(KfObservation {
                point_id: id,
                pixel: k.image_point(),
                depth_m: Some(d),
                sigma_px: f64::from(k.scale),
            });
            observed.push(PointMatch { point_id: id, keypoint: i });
        }
        self.keyframes.push(KeyFrame { map_from_camera, observations, fixed });
        self.frames_since_keyframe = 0;
        self.last_keyframe_tracked = matches.len().max(
            self.keyframes.last().map_or(0, |k| k.observations.len()).min(matches.len() + self.config.max_new_points),
        );
        if self.config.pose_source == PoseSource::Slam && self.keyframes.len() > 1 {
            self.local_bundle_adjustment(camera);
        }
        self.cull();
        observed.retain(|m| self.points.contains_key(&m.point_id));
        let pose = self.keyframes.last().map_or(map_from_camera, |k| k.map_from_camera);
        (pose, observed)
    }

    fn local_bundle_adjustment(&mut self, camera: &PinholeCamera) {
        let n_kf = self.keyframes.len();
        let first_local = n_kf.saturating_sub(self.config.local_keyframes);
        // Points seen by the local window.
        let mut point_index: BTreeMap<u64, usize> = BTreeMap::new();
        for kf in &self.keyframes[first_local..] {
            for o in &kf.observations {
                if self.points.contains_key(&o.point_id) {
                    let n = point_index.len();
                    point_index.entry(o.point_id).or_insert(n);
                }
            }
        }
        // Keyframes involved: the window plus fixed ones observing its points.
        let mut kf_set: BTreeMap<usize, usize> = BTreeMap::new();
        for id in point_index.keys() {
            if let Some(p) = self.points.get(id) {
                for &k in &p.keyframes {
                    let n = kf_set.len();
                    kf_set.entry(k).or_insert(n);
                }
            }
        }
        for k in first_local..n_kf {
            let n = kf_set.len();
            kf_set.entry(k).or_insert(n);
        }
        let kf_list: Vec<usize> = {
            let mut v: Vec<(usize, usize)> = kf_set.iter().map(|(k, i)| (*i, *k)).collect();
            v.sort_unstable();
            v.into_iter().map(|(_, k)| k).collect()
        };
        let mut fixed: Vec<bool> = kf_list
            .iter()
            .map(|&k| k < first_local || k == 0 || self.keyframes.get(k).is_some_and(|kf| kf.fixed))
            .collect();
        if !fixed.iter().any(|&f| f) {
            if let Some(f) = kf_list.iter().position(|&k| k == first_local) {
                fixed[f] = true;
            }
        }
        let mut observations = Vec::new();
        let mut obs_src = Vec::new();
        for (pi, &k) in kf_list.iter().enumerate() {
            let Some(kf) = self.keyframes.get(k) else {
                continue;
            };
            for (oi, o) in kf.observations.iter().enumerate() {
                if let Some(&pt) = point_index.get(&o.point_id) {
                    observations.push(BundleObservation {
                        pose: pi,
                        point: pt,
                        pixel: o.pixel,
                        depth_m: o.depth_m,
                        sigma_px: o.sigma_px,
                    });
                    obs_src.push((k, oi));
                }
            }
        }
        let mut points = vec![Point3::origin(); point_index.len()];
        for (id, &i) in &point_index {
            if let Some(p) = self.points.get(id) {
                points[i] = p.p_in_map;
            }
        }
        let mut problem = BundleProblem {
            camera_from_world: kf_list
                .iter()
                .filter_map(|&k| self.keyframes.get(k).map(|kf| kf.map_from_camera.inverse()))
                .collect(),
            fixed,
            points,
            observations,
        };
        if problem.camera_from_world.len() != kf_list.len() {
            return;
        }
        problem.optimize(camera, &self.config.bundle);
        for (pi, &k) in kf_list.iter().enumerate() {
            if !problem.fixed[pi] {
                if let (Some(kf), Some(p)) = (self.keyframes.get_mut(k), problem.camera_from_world.get(pi)) {
                    kf.map_from_camera = p.inverse();
                }
            }
        }
        for (id, &i) in &point_index {
            if let (Some(p), Some(q)) = (self.points.get_mut(id), problem.points.get(i)) {
                p.p_in_map = *q;
            }
        }
        // Drop outlier observations.
        let flags = problem.inlier_flags(camera, &self.config.bundle);
        let mut drop: BTreeMap<usize, Vec<usize>> = BTreeMap::new();
        for (flag, &(k, oi)) in flags.iter().zip(&obs_src) {
            if !flag {
                drop.entry(k).or_default().push(oi);
            }
        }
        for (k, list) in drop {
            let Some(kf) = self.keyframes.get_mut(k) else {
                continue;
            };
            for &oi in list.iter().rev() {
                if oi < kf.observations.len() {
                    let o = kf.observations.remove(oi);
                    if let Some(p) = self.points.get_mut(&o.point_id) {
                        p.keyframes.retain(|&x| x != k);
                    }
                }
            }
        }
    }

    fn cull(&mut self) {
        let n_kf = self.keyframes.len();
        let c = &self.config;
        self.points.retain(|_, p| {
            if p.keyframes.is_empty() {
                return false;
            }
            if p.n_visible >= c.cull_min_visible && f64::from(p.n_found) < c.cull_found_ratio * f64::from(p.n_visible) {
                return false;
            }
            !(c.cull_after_keyframes > 0 && n_kf >= p.created_kf + 1 + c.cull_after_keyframes && p.keyframes.len() < 2)
        });
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::se3_from_yaw;

    /// A perfectly consistent SLAM map (`map_from_camera = map_from_world · gt`) seen through
    /// per-view biased priors, views with very unequal frame counts.
    fn fit(n_views: u64, outlier: Option<u64>) -> (Se3, Se3, Vec<(Se3, u64)>) {
        let noise = PriorNoiseConfig::default(); // 1 cm / 1° per view
        let robot = super::super::noise::SyntheticPriorError::new(noise, 1);
        let mut anchor = Anchor::new(&noise, TrackerConfig::default().anchor_huber);
        let map_from_world = se3_from_yaw(Vector3::new(0.3, -0.2, 0.1), 0.7);
        let mut frames = Vec::new();
        for v in 0..n_views {
            // Views of 1..=25 frames on an arc over the table.
            for f in 0..(1 + (v * 7) % 25) {
                let a = 0.3 * v as f64 + 0.01 * f as f64;
                let eye = nalgebra::Point3::new(0.45 + 0.25 * a.cos(), 0.25 * a.sin(), 0.4 + 0.05 * (a * 3.0).sin());
                let gt = super::super::synthetic::look_at(eye, nalgebra::Point3::new(0.5, 0.0, 0.0));
                let mut prior = robot.perturb(&gt, v, v * 100 + f);
                if outlier == Some(v) {
                    // A view whose SLAM poses are 8 cm off its prior (e.g. a bad re-localisation).
                    prior = Se3::translation(0.08, 0.0, 0.0) * prior;
                }
                anchor.add(&prior, &(map_from_world * gt), v);
                frames.push((gt, v));
            }
        }
        (anchor.world_from_map(), map_from_world.inverse(), frames)
    }

    /// ATE of the camera centres expressed with the estimated world ← map.
    fn ate(est: &Se3, frames: &[(Se3, u64)], map_from_world: &Se3) -> f64 {
        let s: f64 = frames
            .iter()
            .map(|(gt, _)| ((est * map_from_world * gt).translation.vector - gt.translation.vector).norm_squared())
            .sum();
        (s / frames.len() as f64).sqrt()
    }

    #[test]
    fn the_gauge_averages_per_view_biases_below_the_bias() {
        for n_views in [4u64, 9, 16] {
            let (est, truth, frames) = fit(n_views, None);
            let map_from_world = truth.inverse();
            let e = ate(&est, &frames, &map_from_world);
            // Independent 1 cm biases: the mean of n views is off by ≈ 1 cm / √n (RMS); allow 2x.
            let bound = 0.01 * 2.0 / (n_views as f64).sqrt();
            eprintln!("{n_views} views: ATE {:.2} mm (bound {:.2} mm)", e * 1e3, bound * 1e3);
            assert!(e < bound.min(0.008), "{n_views} views: ATE {e}");
        }
        // Many views: well below the 1 cm bias (≈ 2.5 mm expected).
        let (est, truth, frames) = fit(16, None);
        assert!(ate(&est, &frames, &truth.inverse()) < 0.005);
    }

    #[test]
    fn one_wrong_view_is_down_weighted() {
        let (clean, truth, frames) = fit(12, None);
        let (robust, _, _) = fit(12, Some(3));
        let mfw = truth.inverse();
        let (e_clean, e_robust) = (ate(&clean, &frames, &mfw), ate(&robust, &frames, &mfw));
        eprintln!("ATE clean {:.2} mm, with an 8 cm outlier view {:.2} mm", e_clean * 1e3, e_robust * 1e3);
        // Unweighted, the outlier would move the gauge by 8 cm / 12 ≈ 6.7 mm.
        assert!(e_robust < e_clean + 0.004, "{e_clean} -> {e_robust}");
    }
}
