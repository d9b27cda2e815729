//! Ensemble object-level data association (paper, Section "Object-Level Data Association").
//!
//! A *local object* is one detection of the current frame together with the 3D points (world
//! frame) that fell inside its box; a *global object* lives in the map and accumulates points,
//! centroids and boxes over many frames. Per frame, [`Associator::associate_frame`] decides for
//! every local object whether it is a new sighting of a global object or a new object, then looks
//! for duplicates to merge.
//!
//! # Entry points
//! - [`Associator`]: owns the global objects; one [`Associator::associate_frame`] call per frame
//!   with the frame index, the [`PinholeCamera`], `world_from_camera` and the [`LocalObject`]s.
//!   Returns a [`FrameAssociation`]: per detection a [`DetectionOutcome`] (object id, new or
//!   existing, which tests passed) and the [`Merge`]s performed.
//! - [`GlobalObject`]: read access to each object's point cloud, centroid history, label votes and
//!   observations (for parameterization and for building [`MapObject`]s;
//!   [`GlobalObject::to_map_object_raw`] gives a raw axis-aligned estimate).
//! - [`AssociationConfig`] (all thresholds, with the values we use as defaults) and
//!   [`AssociationMode`] (the paper's Table I ablations).
//! - [`stats`]: Mann-Whitney U, one- and two-sample t-tests (checked against scipy).
//! - [`mapper::EnsembleMapper`]: frames in, [`crate::map::ObjectMap`] out (depth points inside
//!   each box as local clouds), shaped like [`crate::naive::NaiveMapper`] for the episode runner.
//! - [`metrics`]: association quality from ground-truth ids (for evaluation only: ground truth
//!   never enters the [`Associator`]).
//!
//! # The four tests (for a local object `P`, centroid `c`, and a global object `Q`, history `C`)
//! 1. **M-IoU** (motion IoU): the global object's box in frame t is predicted from its boxes at
//!    t−1 and t−2 by uniform motion, `B̂_t = B_{t−1} + (B_{t−1} − B_{t−2})`; passes when
//!    `IoU(B̂_t, detection) ≥ motion_iou_threshold`.
//! 2. **NP** (nonparametric): Wilcoxon rank-sum / Mann-Whitney U between `P` and `Q` on each of
//!    x, y, z, with the tie-corrected variance (Eq. 3 including its tie term, which the paper
//!    drops as small) and the normal approximation. The paper's acceptance rule
//!    `f(W) ≥ f(r_l) = α/2` with `W = min(W_P, W_Q)` says W lies inside the two-sided `1 − α`
//!    confidence region around `m(W) = |P||Q|/2`, i.e. the two-sided p-value is ≥ α. Passes when
//!    every axis has `p ≥ np_alpha`.
//! 3. **S-t** (single-sample t-test): `t = (m(C) − c) / (σ(C)/√|C|) ~ t(|C| − 1)` per axis;
//!    passes when every axis has two-sided `p ≥ t_alpha` (Eq. "condition of t-test":
//!    `|t| ≤ t_{α/2, |C|−1}`).
//! 4. **P-IoU** (projected IoU): the global object's points are projected with the frame's camera
//!    and pose, a box is fitted to them, clipped to the image, and compared with the detection;
//!    passes when `IoU ≥ projected_iou_threshold`.
//!
//! **Decision** (paper: "the successful case should satisfy the fourth item and any of the first
//! three"): a pair (local, global) is *acceptable* when the labels agree, P-IoU passes, and any of
//! the tests enabled by the [`AssociationMode`] among M-IoU, NP, S-t passes. The frame's
//! assignment is solved globally (Hungarian, `pathfinding::kuhn_munkres`, maximising the summed
//! score `1 + P-IoU + M-IoU` over acceptable pairs), so no detection or global object is used
//! twice. A local object without an acceptable partner becomes a new global object.
//!
//! **Duplicate merge** (D-t, [`AssociationMode::Ensemble`] only): two global objects with the same
//! majority label are merged when the pooled two-sample t-test on their centroid histories
//! (Eq. D-t, `t(|C1| + |C2| − 2)`) gives `p ≥ merge_alpha` on every axis. Candidates are pairs with
//! at least one object touched in this frame; they are merged greedily by decreasing smallest
//! per-axis p-value, each object at most once per frame; the younger id merges into the older.
//!
//! # Choices where the paper is vague (each is a config field)
//! - Thresholds: the paper gives no numbers; defaults are α = 0.05 for all tests (the confidence
//!   level the text names as `1 − α`), M-IoU ≥ 0.5, P-IoU ≥ 0.3.
//! - M-IoU when the object was seen at t−1 but not t−2: zero velocity (predict the t−1 box),
//!   [`AssociationConfig::motion_zero_velocity_fallback`]; frame gaps up to
//!   [`AssociationConfig::motion_max_gap_frames`] (default 1 = the paper's strict t−1, t−2) scale
//!   the velocity linearly. Not applicable (does not pass) otherwise.
//! - NP on big clouds is over-powered (any tiny shift rejects with thousands of points) and costs
//!   O(n log n); both clouds are reduced to at most [`AssociationConfig::np_max_points`] evenly
//!   spaced order statistics per axis (deterministic quantile subsample; default 30, the size of
//!   the paper's ORB clouds) before the rank-sum. The continuity correction is off by default
//!   (the paper's rule has none), [`AssociationConfig::np_use_continuity`].
//! - S-t follows the paper's statistic literally (standard error `σ(C)/√|C|`, so it tightens as
//!   the history grows); it needs `|C| ≥ t_min_history` (default 3) centroids, and the history's
//!   standard deviation is floored at [`AssociationConfig::t_min_std_m`] (default 5 mm: a partial
//!   cloud's centroid moves with the viewpoint) so a history from similar views does not reject
//!   the next view; with the floor at 0 a zero-variance history makes the test not applicable.
//! - D-t uses the same standard-deviation floor on each history; it also requires that the two
//!   objects were never seen in the same frame (two detections of one frame are two objects) and
//!   that their mean centroids lie within [`AssociationConfig::merge_max_distance_m`]; both guards
//!   can be disabled.
//! - P-IoU's box is the `[trim, 1 − trim]` quantile box of the projected points
//!   ([`AssociationConfig::projected_box_trim`]); points behind the camera are ignored; fewer than
//!   [`AssociationConfig::min_projected_points`] in front → not applicable (does not pass).
//! - Global clouds are kept on a voxel grid (first point per voxel, insertion order, so
//!   deterministic); when a cloud exceeds [`AssociationConfig::max_points_per_object`] its voxel
//!   size doubles and it is rebuilt. Histories keep the last
//!   [`AssociationConfig::max_history`] centroids.
//! - Label: a global object's label is the majority of its detections' labels (ties → lower
//!   [`Label::index`]).
//!
//! # Bad input (defined behaviour, no panic)
//! - Points with a NaN or infinite coordinate are dropped (counted in
//!   [`DetectionOutcome::dropped_non_finite`]).
//! - A local object with fewer than [`AssociationConfig::min_local_points`] finite points (empty,
//!   or single-point with the default 3) is skipped: [`Decision::Skipped`] with
//!   [`SkipReason::TooFewPoints`]; it neither updates nor creates an object.
//! - A detection box touching the image border (within
//!   [`AssociationConfig::border_margin_px`]) may update an object but never creates one
//!   ([`SkipReason::TruncatedAtBorder`]): a truncated view would seed an object whose cloud the
//!   next full view fails to match (our choice; the paper does not discuss truncation).
//! - A detection box is clipped to the image; if nothing is left (box entirely outside the image
//!   or non-finite) the detection is skipped with [`SkipReason::OutsideImage`].
//! - Tests that cannot be computed (too short or zero-variance history, object not projectable)
//!   are "not applicable" (`None` in [`TestOutcomes`]) and never count as a pass.
//! - Invalid camera intrinsics or a non-finite pose are a typed [`AssociationError`]; the state is
//!   unchanged.
//!
//! # Ids after merges
//! Ids in [`FrameAssociation::detections`] are those assigned before the frame's merges; apply
//! [`FrameAssociation::merges`] in order (`removed_id` → `kept_id`) to get the surviving id.

pub mod mapper;
pub mod metrics;
pub mod stats;

use std::collections::{BTreeMap, BTreeSet, HashSet};
use std::sync::OnceLock;

use nalgebra::{Point3, Vector3};
use pathfinding::prelude::{kuhn_munkres, Matrix};
use serde::{Deserialize, Serialize};

use crate::frame::Detection;
use crate::geometry::{se3_from_yaw, Box2, GeometryError, PinholeCamera, Se3};
use crate::map::{EstimateStage, Label, MapObject, Observation};

/// Errors of the association module.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum AssociationError {
    /// The camera intrinsics are invalid.
    #[error(transparent)]
    Camera(#[from] GeometryError),
    /// The frame is invalid (sizes, depth, detections).
    #[error(transparent)]
    Frame(#[from] crate::frame::FrameError),
    /// The camera pose has a non-finite entry.
    #[error("world_from_camera has a non-finite entry")]
    NonFinitePose,
    /// A configuration value is out of range.
    #[error("config.{field}: {reason}")]
    BadConfig {
        /// Field name.
        field: &'static str,
        /// What is wrong.
        reason: String,
    },
}

/// Which tests may make a pair acceptable (P-IoU and label agreement are always required).
/// The paper's Table I columns: IoU, IoU+NP, IoU+t-test, Ours.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum AssociationMode {
    /// P-IoU ∧ M-IoU (tracking by IoU only).
    Iou,
    /// P-IoU ∧ (M-IoU ∨ NP).
    IouNp,
    /// P-IoU ∧ (M-IoU ∨ S-t).
    IouT,
    /// P-IoU ∧ (M-IoU ∨ NP ∨ S-t), plus the D-t duplicate merge (the paper's method).
    #[default]
    Ensemble,
}

impl AssociationMode {
    /// Every mode, in the paper's table order.
    pub const ALL: [AssociationMode; 4] =
        [AssociationMode::Iou, AssociationMode::IouNp, AssociationMode::IouT, AssociationMode::Ensemble];

    /// The name used in configs and reports (`iou`, `iou_np`, `iou_t`, `ensemble`).
    pub fn as_str(self) -> &'static str {
        match self {
            AssociationMode::Iou => "iou",
            AssociationMode::IouNp => "iou_np",
            AssociationMode::IouT => "iou_t",
            AssociationMode::Ensemble => "ensemble",
        }
    }

    /// Whether the nonparametric test can make a pair acceptable.
    pub fn uses_np(self) -> bool {
        matches!(self, AssociationMode::IouNp | AssociationMode::Ensemble)
    }

    /// Whether the single-sample t-test can make a pair acceptable.
    pub fn uses_t(self) -> bool {
        matches!(self, AssociationMode::IouT | AssociationMode::Ensemble)
    }

    /// Whether duplicates are merged with the double-sample t-test.
    pub fn merges_duplicates(self) -> bool {
        self == AssociationMode::Ensemble
    }
}

/// Configuration of the association. Defaults are our choices where the paper gives no number
/// (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct AssociationConfig {
    /// Ablation mode (default [`AssociationMode::Ensemble`]).
    pub mode: AssociationMode,
    /// M-IoU passes when IoU(predicted box, detection) ≥ this (default 0.5; paper: "large enough").
    pub motion_iou_threshold: f64,
    /// Largest gap, in frames, between the current frame and the object's last sighting (and
    /// between its last two sightings) for M-IoU to apply (default 1 = the paper's t−1, t−2).
    pub motion_max_gap_frames: u32,
    /// When the object has only one recent sighting, predict that box unchanged (default true).
    /// False = the paper's strict rule (M-IoU not applicable without t−1 and t−2).
    pub motion_zero_velocity_fallback: bool,
    /// P-IoU passes when IoU(projected box, detection) ≥ this (default 0.3).
    pub projected_iou_threshold: f64,
    /// Fraction of projected points trimmed at each end of u and v before fitting the P-IoU box
    /// (default 0.02; 0 = min/max box). Robustness to stray points in the global cloud.
    pub projected_box_trim: f64,
    /// P-IoU is not applicable when fewer points project in front of the camera (default 3).
    pub min_projected_points: usize,
    /// Significance level α of the nonparametric test (default 0.05): pass when p ≥ α on all axes.
    pub np_alpha: f64,
    /// Use the continuity correction in the Mann-Whitney normal approximation (default false).
    pub np_use_continuity: bool,
    /// Each cloud is reduced to at most this many evenly spaced order statistics per axis before
    /// the rank-sum test (default 30, the order of the ORB points per object the paper's clouds
    /// hold; 0 = no reduction). Larger = more powerful, stricter test: with hundreds of depth
    /// points, views of one object from two sides already differ significantly.
    pub np_max_points: usize,
    /// Significance level α of the single-sample t-test (default 0.05).
    pub t_alpha: f64,
    /// Minimum centroid-history length for the single-sample t-test (default 3; at least 2).
    pub t_min_history: usize,
    /// Standard error of the single-sample t-test. False (the paper's statistic): `σ(C)/√|C|`, a
    /// test of the history's mean, which tightens as the history grows (with 100 centroids and
    /// the 5 mm floor it rejects a centroid 1 mm off the mean), so a well-observed object seen
    /// from a new side, where its partial cloud's centroid moves by centimetres, fails it. True
    /// (beyond the paper): `σ(C)·√(1 + 1/|C|)`, the prediction interval of one new centroid from
    /// the history's spread. Default false.
    pub t_prediction: bool,
    /// Floor on the history's per-axis standard deviation in the t-tests, metres (default 0.005:
    /// the centroid of a partial surface cloud moves by millimetres with the viewpoint, so a
    /// history from similar views understates the spread of the next view's centroid).
    pub t_min_std_m: f64,
    /// Significance level α of the double-sample t-test for duplicate merging (default 0.05).
    pub merge_alpha: f64,
    /// Minimum history length of both objects for the merge test (default 3; at least 2).
    pub merge_min_history: usize,
    /// Only merge objects whose mean centroids are closer than this, metres (default 0.10;
    /// infinity disables the guard).
    pub merge_max_distance_m: f64,
    /// Never merge two objects that were observed in the same frame (default true).
    pub merge_forbid_co_observed: bool,
    /// Local objects with fewer finite points are skipped (default 3).
    pub min_local_points: usize,
    /// A detection box closer than this to an image edge, pixels, is *truncated*: it may update an
    /// existing object but never starts a new one (its cloud shows only part of the object, so
    /// the next full view would fail NP and S-t against it). Default 2; 0 disables.
    pub border_margin_px: f64,
    /// Initial voxel size of global clouds, metres (default 0.005).
    pub voxel_m: f64,
    /// A global cloud holding more points doubles its voxel size (default 4000).
    pub max_points_per_object: usize,
    /// Centroid-history length kept per object (default 100; oldest dropped).
    pub max_history: usize,
    /// Evaluate every test for every same-label pair even when the decision is already known
    /// (diagnostics; default false: P-IoU first, then stop at the first passing test).
    pub evaluate_all_tests: bool,
}

impl Default for AssociationConfig {
    fn default() -> Self {
        Self {
            mode: AssociationMode::Ensemble,
            motion_iou_threshold: 0.5,
            motion_max_gap_frames: 1,
            motion_zero_velocity_fallback: true,
            projected_iou_threshold: 0.3,
            projected_box_trim: 0.02,
            min_projected_points: 3,
            np_alpha: 0.05,
            np_use_continuity: false,
            np_max_points: 30,
            t_alpha: 0.05,
            t_min_history: 3,
            t_prediction: false,
            t_min_std_m: 0.005,
            merge_alpha: 0.05,
            merge_min_history: 3,
            merge_max_distance_m: 0.10,
            merge_forbid_co_observed: true,
            min_local_points: 3,
            border_margin_px: 2.0,
            voxel_m: 0.005,
            max_points_per_object: 4000,
            max_history: 100,
            evaluate_all_tests: false,
        }
    }
}

impl AssociationConfig {
    /// Check ranges (probabilities in (0, 1), positive sizes).
    pub fn validate(&self) -> Result<(), AssociationError> {
        let unit = |field: &'static str, v: f64| {
            if v.is_finite() && (0.0..=1.0).contains(&v) {
                Ok(())
            } else {
                Err(AssociationError::BadConfig { field, reason: format!("{v} outside [0, 1]") })
            }
        };
        unit("motion_iou_threshold", self.motion_iou_threshold)?;
        unit("projected_iou_threshold", self.projected_iou_threshold)?;
        unit("np_alpha", self.np_alpha)?;
        unit("t_alpha", self.t_alpha)?;
        unit("merge_alpha", self.merge_alpha)?;
        if !(self.projected_box_trim.is_finite() && (0.0..0.5).contains(&self.projected_box_trim)) {
            return Err(AssociationError::BadConfig {
                field: "projected_box_trim",
                reason: format!("{} outside [0, 0.5)", self.projected_box_trim),
            });
        }
        if !(self.border_margin_px.is_finite() && self.border_margin_px >= 0.0) {
            return Err(AssociationError::BadConfig {
                field: "border_margin_px",
                reason: format!("{} is not a finite non-negative number", self.border_margin_px),
            });
        }
        if !(self.voxel_m.is_finite() && self.voxel_m > 0.0) {
            return Err(AssociationError::BadConfig { field: "voxel_m", reason: format!("{} ≤ 0", self.voxel_m) });
        }
        if !(self.t_min_std_m.is_finite() && self.t_min_std_m >= 0.0) {
            return Err(AssociationError::BadConfig { field: "t_min_std_m", reason: format!("{}", self.t_min_std_m) });
        }
        if self.merge_max_distance_m.is_nan() {
            return Err(AssociationError::BadConfig { field: "merge_max_distance_m", reason: "NaN".into() });
        }
        if self.t_min_history < 2 || self.merge_min_history < 2 {
            return Err(AssociationError::BadConfig {
                field: "t_min_history / merge_min_history",
                reason: "t-tests need at least 2 centroids".into(),
            });
        }
        if self.max_points_per_object == 0 || self.max_history == 0 {
            return Err(AssociationError::BadConfig {
                field: "max_points_per_object / max_history",
                reason: "must be positive".into(),
            });
        }
        Ok(())
    }
}

/// One detection of the current frame with its points (world frame). Ground truth never goes here.
#[derive(Debug, Clone, PartialEq)]
pub struct LocalObject {
    /// The detection (box in pixels, label, score).
    pub detection: Detection,
    /// Points that fell inside the detection box, world frame, metres (non-finite ones are dropped).
    pub points_in_world: Vec<Point3<f64>>,
}

/// Outcome of each test for one (local, global) pair: `Some(passed)`, or `None` when the test was
/// not applicable (or not evaluated because the decision was already known).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct TestOutcomes {
    /// Motion IoU.
    pub motion_iou: Option<bool>,
    /// Nonparametric (Mann-Whitney on x, y, z).
    pub nonparametric: Option<bool>,
    /// Single-sample t-test of the centroid.
    pub t_test: Option<bool>,
    /// Projected IoU.
    pub projected_iou: Option<bool>,
}

/// Why a detection was not used.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SkipReason {
    /// Fewer than `min_local_points` finite points.
    TooFewPoints,
    /// The detection box does not overlap the image (or is not finite).
    OutsideImage,
    /// The box touches the image border (within `border_margin_px`) and matched no object.
    TruncatedAtBorder,
}

/// What happened to one detection.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case", tag = "kind")]
pub enum Decision {
    /// Associated with an existing global object.
    Existing {
        /// Its id.
        object_id: u32,
    },
    /// Started a new global object.
    New {
        /// The new id.
        object_id: u32,
    },
    /// Not used.
    Skipped {
        /// Why.
        reason: SkipReason,
    },
}

impl Decision {
    /// The object id, unless skipped.
    pub fn object_id(&self) -> Option<u32> {
        match self {
            Decision::Existing { object_id } | Decision::New { object_id } => Some(*object_id),
            Decision::Skipped { .. } => None,
        }
    }
}

/// The association result for one detection.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct DetectionOutcome {
    /// Index of the detection in the frame's list of local objects.
    pub detection_index: usize,
    /// What happened.
    pub decision: Decision,
    /// The object the tests were run against: the associated one, or for a new object the
    /// same-label candidate with the best projected IoU (`None` if there was none).
    pub candidate: Option<u32>,
    /// Tests against `candidate` (all `None` without one).
    pub tests: TestOutcomes,
    /// Points dropped because a coordinate was NaN or infinite.
    pub dropped_non_finite: usize,
}

/// A duplicate merge performed at the end of a frame.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Merge {
    /// The surviving (older) object.
    pub kept_id: u32,
    /// The object folded into it (no longer exists).
    pub removed_id: u32,
    /// Smallest per-axis p-value of the double-sample t-test.
    pub p_value: f64,
}

/// Everything one [`Associator::associate_frame`] call did.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FrameAssociation {
    /// The frame index.
    pub frame: u32,
    /// One entry per local object, in input order.
    pub detections: Vec<DetectionOutcome>,
    /// Merges, in the order performed.
    pub merges: Vec<Merge>,
}

/// One centroid of a global object's history.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct CentroidSample {
    /// Frame index.
    pub frame: u32,
    /// Centroid of the local cloud in that frame, world frame, metres.
    pub centroid_in_world: Vector3<f64>,
}

/// One sighting of a global object: the map's [`Observation`] plus the detection's index in its
/// frame, so evaluation can look up the ground-truth id of that detection.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ObservationRecord {
    /// Frame, box, score, centroid.
    pub observation: Observation,
    /// Index of the detection among that frame's local objects.
    pub detection_index: usize,
    /// Label the detector gave.
    pub label: Label,
}

/// Per-axis sorted, subsampled coordinates (the NP test's view of a cloud), stored as
/// [`stats::order_key`]s (same order and ties as the values, faster to sort).
#[derive(Debug, Clone, PartialEq, Default)]
struct SortedAxes([Vec<u64>; 3]);

impl SortedAxes {
    fn new(points: &[Point3<f64>], max_points: usize) -> Self {
        let axis = |a: usize| {
            let mut v: Vec<u64> = points.iter().map(|p| stats::order_key(p[a])).collect();
            v.sort_unstable();
            quantile_subsample(v, max_points)
        };
        Self([axis(0), axis(1), axis(2)])
    }
}

/// Keep `max` evenly spaced order statistics of a sorted vector (`floor((i + 0.5) n / max)`).
fn quantile_subsample<T: Copy>(sorted: Vec<T>, max: usize) -> Vec<T> {
    let n = sorted.len();
    if max == 0 || n <= max {
        return sorted;
    }
    (0..max).filter_map(|i| sorted.get(((2 * i + 1) * n) / (2 * max)).copied()).collect()
}

/// A global object: an entity of the map built from many frames.
#[derive(Debug, Clone, PartialEq)]
pub struct GlobalObject {
    id: u32,
    label_votes: [u32; Label::ALL.len()],
    points: Vec<Point3<f64>>,
    voxel_keys: VoxelSet,
    voxel_m: f64,
    history: Vec<CentroidSample>,
    observations: Vec<ObservationRecord>,
    frames_seen: BTreeSet<u32>,
    np_cache: OnceLock<SortedAxes>,
}

impl GlobalObject {
    /// Id (unique within the associator, never reused).
    pub fn id(&self) -> u32 {
        self.id
    }

    /// Majority label of its detections (ties → lower [`Label::index`]).
    pub fn label(&self) -> Label {
        let mut best = 0;
        for (i, v) in self.label_votes.iter().enumerate() {
            if *v > self.label_votes[best] {
                best = i;
            }
        }
        Label::ALL.get(best).copied().unwrap_or(Label::Block)
    }

    /// Label votes, indexed like [`Label::ALL`].
    pub fn label_votes(&self) -> &[u32; Label::ALL.len()] {
        &self.label_votes
    }

    /// The accumulated point cloud, world frame (voxel-downsampled, deterministic order).
    pub fn points_in_world(&self) -> &[Point3<f64>] {
        &self.points
    }

    /// Current voxel size of the cloud, metres.
    pub fn voxel_m(&self) -> f64 {
        self.voxel_m
    }

    /// Centroid history (oldest first, at most `max_history`).
    pub fn centroid_history(&self) -> &[CentroidSample] {
        &self.history
    }

    /// Every sighting (oldest first; after a merge, both objects' sightings sorted by frame).
    pub fn observations(&self) -> &[ObservationRecord] {
        &self.observations
    }

    /// Frame of the latest sighting.
    pub fn last_seen_frame(&self) -> Option<u32> {
        self.observations.last().map(|o| o.observation.frame)
    }

    /// Mean of the centroid history (`None` when empty).
    pub fn mean_centroid(&self) -> Option<Vector3<f64>> {
        if self.history.is_empty() {
            return None;
        }
        Some(self.history.iter().fold(Vector3::zeros(), |a, s| a + s.centroid_in_world) / self.history.len() as f64)
    }

    /// A raw [`MapObject`]: per-axis 2 %–98 % extent of the cloud, yaw 0, majority label,
    /// stage [`EstimateStage::Raw`]. Parameterization refines this.
    pub fn to_map_object_raw(&self) -> MapObject {
        let (center, half) = match crate::geometry::trimmed_extent(&self.points, 0.02) {
            Some((lo, hi)) => ((lo + hi) / 2.0, (hi - lo) / 2.0),
            None => (self.mean_centroid().unwrap_or_else(Vector3::zeros), Vector3::zeros()),
        };
        MapObject {
            id: self.id,
            label: self.label(),
            world_from_object: se3_from_yaw(center, 0.0),
            half_extents: half,
            observations: self.observations.iter().map(|o| o.observation).collect(),
            points_in_world: self.points.clone(),
            stage: EstimateStage::Raw,
        }
    }

    /// [`Self::to_map_object_raw`] without the cloud, for callers that need only ids, labels and
    /// observations: no points, centre = mean centroid, zero extent (no copy, no quantiles).
    pub fn to_map_object_without_cloud(&self) -> MapObject {
        MapObject {
            id: self.id,
            label: self.label(),
            world_from_object: se3_from_yaw(self.mean_centroid().unwrap_or_else(Vector3::zeros), 0.0),
            half_extents: Vector3::zeros(),
            observations: self.observations.iter().map(|o| o.observation).collect(),
            points_in_world: Vec::new(),
            stage: EstimateStage::Raw,
        }
    }

    fn new(id: u32, voxel_m: f64) -> Self {
        Self {
            id,
            label_votes: [0; Label::ALL.len()],
            points: Vec::new(),
            voxel_keys: VoxelSet::default(),
            voxel_m,
            history: Vec::new(),
            observations: Vec::new(),
            frames_seen: BTreeSet::new(),
            np_cache: OnceLock::new(),
        }
    }

    /// Move every world-frame quantity by `delta` (see [`Associator::transform_world`]).
    fn transform(&mut self, delta: &Se3) {
        let mv = |v: &mut Vector3<f64>| *v = (delta * Point3::from(*v)).coords;
        for p in &mut self.points {
            *p = delta * *p;
        }
        self.voxel_keys.clear();
        for p in &self.points {
            self.voxel_keys.insert(voxel_key(p, self.voxel_m));
        }
        for h in &mut self.history {
            mv(&mut h.centroid_in_world);
        }
        for o in &mut self.observations {
            mv(&mut o.observation.centroid_in_world);
        }
        self.np_cache = OnceLock::new();
    }

    fn add_points(&mut self, new_points: &[Point3<f64>], max_points: usize) {
        self.voxel_keys.reserve(new_points.len());
        for p in new_points {
            if self.voxel_keys.insert(voxel_key(p, self.voxel_m)) {
                self.points.push(*p);
            }
        }
        // Bounded: double the voxel size until the cloud fits (deterministic rebuild).
        let mut guard = 0;
        while self.points.len() > max_points && guard < 64 {
            self.voxel_m *= 2.0;
            let old = std::mem::take(&mut self.points);
            self.voxel_keys.clear();
            for p in old {
                if self.voxel_keys.insert(voxel_key(&p, self.voxel_m)) {
                    self.points.push(p);
                }
            }
            guard += 1;
        }
        self.np_cache = OnceLock::new();
    }

    fn push_history(&mut self, sample: CentroidSample, max_history: usize) {
        self.history.push(sample);
        if self.history.len() > max_history {
            let excess = self.history.len() - max_history;
            self.history.drain(..excess);
        }
    }

    /// The last two sightings' (frame, box), most recent last.
    fn last_two_boxes(&self) -> (Option<FrameBox>, Option<FrameBox>) {
        let n = self.observations.len();
        let get = |i: usize| self.observations.get(i).map(|o| (o.observation.frame, o.observation.bbox));
        let last = n.checked_sub(1).and_then(get);
        let prev = n.checked_sub(2).and_then(get);
        (prev, last)
    }
}

/// Membership set of occupied voxels (packed keys, [`voxel_key`]); only queried, never iterated.
type VoxelSet = HashSet<u64, crate::IntKeyBuild>;

/// A sighting's frame index and box.
type FrameBox = (u32, Box2);

/// The voxel of a point, its three integer indices packed into 21 bits each (two's complement,
/// so unique within ±2²⁰ voxels of the origin: ±5 km at 5 mm; farther points may share a voxel
/// with another far point, which only thins absurd input).
fn voxel_key(p: &Point3<f64>, voxel_m: f64) -> u64 {
    const MASK: u64 = (1 << 21) - 1;
    let idx = |v: f64| ((v / voxel_m).floor() as i64 as u64) & MASK;
    (idx(p.x) << 42) | (idx(p.y) << 21) | idx(p.z)
}

/// A prepared local object (finite points, clipped box, centroid).
struct PreparedLocal {
    bbox: Box2,
    truncated: bool,
    label: Label,
    score: f64,
    points: Vec<Point3<f64>>,
    centroid: Vector3<f64>,
    np: Option<SortedAxes>,
}

/// Tests and score of one acceptable pair.
#[derive(Debug, Clone, Copy)]
struct PairEval {
    tests: TestOutcomes,
    accepted: bool,
    score: f64,
}

/// Owns the global objects and associates each frame's local objects with them.
#[derive(Debug, Clone, PartialEq)]
pub struct Associator {
    config: AssociationConfig,
    objects: BTreeMap<u32, GlobalObject>,
    next_id: u32,
}

impl Associator {
    /// An associator with no objects (the config is validated).
    pub fn new(config: AssociationConfig) -> Result<Self, AssociationError> {
        config.validate()?;
        Ok(Self { config, objects: BTreeMap::new(), next_id: 0 })
    }

    /// The configuration.
    pub fn config(&self) -> &AssociationConfig {
        &self.config
    }

    /// Re-express the whole map in a moved world frame: every object's points, centroid history
    /// and observation centroids go through the rigid `delta` (`new_world ← old_world`). Used when
    /// the SLAM re-fits its world ← map gauge (each new view's kinematic prior moves it by a few
    /// millimetres): points fused under the old gauge stay consistent with those fused under the
    /// new one. Boxes (image space) are unchanged.
    pub fn transform_world(&mut self, delta: &Se3) {
        for obj in self.objects.values_mut() {
            obj.transform(delta);
        }
    }

    /// The global objects, by increasing id.
    pub fn objects(&self) -> impl Iterator<Item = &GlobalObject> {
        self.objects.values()
    }

    /// One global object.
    pub fn object(&self, id: u32) -> Option<&GlobalObject> {
        self.objects.get(&id)
    }

    /// Number of global objects.
    pub fn len(&self) -> usize {
        self.objects.len()
    }

    /// Whether there are no global objects.
    pub fn is_empty(&self) -> bool {
        self.objects.is_empty()
    }

    /// Raw [`MapObject`]s of every global object (see [`GlobalObject::to_map_object_raw`]).
    pub fn to_map_objects_raw(&self) -> Vec<MapObject> {
        self.objects.values().map(GlobalObject::to_map_object_raw).collect()
    }

    /// Associate one frame's local objects (see the module docs for the rule). `frame` should
    /// increase from call to call (M-IoU uses frame differences).
    pub fn associate_frame(
        &mut self,
        frame: u32,
        camera: &PinholeCamera,
        world_from_camera: &Se3,
        locals: &[LocalObject],
    ) -> Result<FrameAssociation, AssociationError> {
        camera.validate()?;
        let m = world_from_camera.to_homogeneous();
        if m.iter().any(|v| !v.is_finite()) {
            return Err(AssociationError::NonFinitePose);
        }
        let cfg = self.config;
        let image = camera.image_box();

        // 1. Prepare local objects.
        let mut outcomes: Vec<DetectionOutcome> = Vec::with_capacity(locals.len());
        let mut prepared: Vec<Option<PreparedLocal>> = Vec::with_capacity(locals.len());
        for (i, local) in locals.iter().enumerate() {
            let points: Vec<Point3<f64>> =
                local.points_in_world.iter().filter(|p| p.iter().all(|v| v.is_finite())).copied().collect();
            let dropped = local.points_in_world.len() - points.len();
            let clipped =
                if local.detection.bbox.is_finite() { local.detection.bbox.intersection(&image) } else { None };
            let skip = match clipped {
                None => Some(SkipReason::OutsideImage),
                Some(_) if points.len() < cfg.min_local_points.max(1) => Some(SkipReason::TooFewPoints),
                Some(_) => None,
            };
            outcomes.push(DetectionOutcome {
                detection_index: i,
                decision: Decision::Skipped { reason: skip.unwrap_or(SkipReason::TooFewPoints) },
                candidate: None,
                tests: TestOutcomes::default(),
                dropped_non_finite: dropped,
            });
            match (skip, clipped) {
                (None, Some(bbox)) => {
                    let centroid = points.iter().fold(Vector3::zeros(), |a, p| a + p.coords) / points.len() as f64;
                    let m = cfg.border_margin_px;
                    let truncated = bbox.min[0] < m
                        || bbox.min[1] < m
                        || bbox.max[0] > image.max[0] - m
                        || bbox.max[1] > image.max[1] - m;
                    prepared.push(Some(PreparedLocal {
                        bbox,
                        truncated,
                        label: local.detection.label,
                        score: local.detection.score,
                        points,
                        centroid,
                        np: None,
                    }));
                }
                _ => prepared.push(None),
            }
        }

        // 2. Evaluate every same-label pair against the state before this frame.
        let ids: Vec<u32> = self.objects.keys().copied().collect();
        let labels_present: BTreeSet<Label> = prepared.iter().flatten().map(|l| l.label).collect();
        let camera_from_world = world_from_camera.inverse();
        let mut projected: Vec<Option<Box2>> = Vec::with_capacity(ids.len());
        for id in &ids {
            // Only objects whose label some detection carries can be compared at all.
            let b = self.objects.get(id).filter(|o| labels_present.contains(&o.label()));
            projected.push(b.and_then(|o| projected_box(o.points_in_world(), camera, &camera_from_world, &cfg)));
        }
        let n_det = prepared.len();
        let n_obj = ids.len();
        let mut evals: Vec<Option<PairEval>> = vec![None; n_det * n_obj];
        for (di, local) in prepared.iter_mut().enumerate() {
            let Some(local) = local.as_mut() else { continue };
            for (oi, id) in ids.iter().enumerate() {
                let Some(obj) = self.objects.get(id) else { continue };
                if obj.label() != local.label {
                    continue;
                }
                let pb = projected.get(oi).copied().flatten();
                let e = evaluate_pair(&cfg, frame, local, obj, pb);
                if let Some(slot) = evals.get_mut(di * n_obj + oi) {
                    *slot = Some(e);
                }
            }
        }

        // 3. Global assignment: rows = detections, columns = objects + one "new" column per
        //    detection (weight 0); acceptable pairs weigh ≥ 1e6, others are forbidden.
        const SCALE: f64 = 1e6;
        const FORBIDDEN: i64 = -1_000_000_000_000;
        let mut assigned: Vec<Option<usize>> = vec![None; n_det];
        if n_det > 0 && evals.iter().flatten().any(|e| e.accepted) {
            let mut weights = Matrix::new(n_det, n_obj + n_det, 0i64);
            for di in 0..n_det {
                for oi in 0..n_obj {
                    let w = match evals.get(di * n_obj + oi).copied().flatten() {
                        Some(e) if e.accepted => ((1.0 + e.score) * SCALE).round() as i64,
                        _ => FORBIDDEN,
                    };
                    weights[(di, oi)] = w;
                }
            }
            let (_, cols) = kuhn_munkres(&weights);
            for (di, col) in cols.into_iter().enumerate() {
                if col < n_obj && weights[(di, col)] > 0 {
                    if let Some(a) = assigned.get_mut(di) {
                        *a = Some(col);
                    }
                }
            }
        }

        // 4. Apply: update associated objects, create new ones.
        let mut touched: BTreeSet<u32> = BTreeSet::new();
        for di in 0..n_det {
            let Some(Some(local)) = prepared.get(di) else { continue };
            if local.truncated && assigned.get(di).copied().flatten().is_none() {
                if let Some(o) = outcomes.get_mut(di) {
                    o.decision = Decision::Skipped { reason: SkipReason::TruncatedAtBorder };
                }
                continue;
            }
            let record = ObservationRecord {
                observation: Observation {
                    frame,
                    bbox: local.bbox,
                    score: local.score,
                    centroid_in_world: local.centroid,
                },
                detection_index: di,
                label: local.label,
            };
            let (object_id, decision, tests) = match assigned.get(di).copied().flatten() {
                Some(oi) => {
                    let id = ids.get(oi).copied().unwrap_or(u32::MAX);
                    let tests = evals.get(di * n_obj + oi).copied().flatten().map(|e| e.tests).unwrap_or_default();
                    (id, Decision::Existing { object_id: id }, tests)
                }
                None => {
                    let id = self.next_id;
                    self.next_id += 1;
                    self.objects.insert(id, GlobalObject::new(id, cfg.voxel_m));
                    (id, Decision::New { object_id: id }, TestOutcomes::default())
                }
            };
            let candidate = match assigned.get(di).copied().flatten() {
                Some(oi) => ids.get(oi).map(|id| (*id, tests)),
                None => {
                    // Best rejected candidate, for diagnostics (first on equal score: lower id).
                    let mut best: Option<(f64, u32, TestOutcomes)> = None;
                    for (oi, id) in ids.iter().enumerate() {
                        if let Some(e) = evals.get(di * n_obj + oi).copied().flatten() {
                            if best.is_none_or(|(s, _, _)| e.score > s) {
                                best = Some((e.score, *id, e.tests));
                            }
                        }
                    }
                    best.map(|(_, id, t)| (id, t))
                }
            };
            if let Some(obj) = self.objects.get_mut(&object_id) {
                obj.label_votes[local.label.index()] += 1;
                obj.add_points(&local.points, cfg.max_points_per_object);
                obj.push_history(CentroidSample { frame, centroid_in_world: local.centroid }, cfg.max_history);
                obj.observations.push(record);
                obj.frames_seen.insert(frame);
                touched.insert(object_id);
            }
            if let Some(o) = outcomes.get_mut(di) {
                o.decision = decision;
                o.candidate = candidate.map(|c| c.0);
                o.tests = candidate.map(|c| c.1).unwrap_or_default();
            }
        }

        // 5. Duplicate merge (D-t).
        let merges = if cfg.mode.merges_duplicates() { self.merge_duplicates(&touched) } else { Vec::new() };
        Ok(FrameAssociation { frame, detections: outcomes, merges })
    }

    fn merge_duplicates(&mut self, touched: &BTreeSet<u32>) -> Vec<Merge> {
        let cfg = self.config;
        let mut candidates: Vec<(f64, u32, u32)> = Vec::new();
        let ids: Vec<u32> = self.objects.keys().copied().collect();
        for (i, a) in ids.iter().enumerate() {
            for b in ids.iter().skip(i + 1) {
                if !touched.contains(a) && !touched.contains(b) {
                    continue;
                }
                let (Some(oa), Some(ob)) = (self.objects.get(a), self.objects.get(b)) else { continue };
                if let Some(p) = duplicate_p(&cfg, oa, ob) {
                    if p >= cfg.merge_alpha {
                        candidates.push((p, *a, *b));
                    }
                }
            }
        }
        candidates.sort_by(|x, y| y.0.total_cmp(&x.0).then(x.1.cmp(&y.1)).then(x.2.cmp(&y.2)));
        let mut used: BTreeSet<u32> = BTreeSet::new();
        let mut merges = Vec::new();
        for (p, a, b) in candidates {
            if used.contains(&a) || used.contains(&b) {
                continue;
            }
            let Some(removed) = self.objects.remove(&b) else { continue };
            if let Some(kept) = self.objects.get_mut(&a) {
                absorb(kept, removed, &cfg);
            }
            used.insert(a);
            used.insert(b);
            merges.push(Merge { kept_id: a, removed_id: b, p_value: p });
        }
        merges
    }
}

/// Fold `removed` into `kept`: votes add, clouds re-voxelised, histories and sightings interleaved
/// by frame (history truncated to the newest `max_history`).
fn absorb(kept: &mut GlobalObject, removed: GlobalObject, cfg: &AssociationConfig) {
    for (k, v) in kept.label_votes.iter_mut().zip(removed.label_votes.iter()) {
        *k += v;
    }
    kept.add_points(&removed.points, cfg.max_points_per_object);
    kept.history.extend(removed.history);
    kept.history.sort_by_key(|s| s.frame);
    if kept.history.len() > cfg.max_history {
        let excess = kept.history.len() - cfg.max_history;
        kept.history.drain(..excess);
    }
    kept.observations.extend(removed.observations);
    kept.observations.sort_by_key(|o| (o.observation.frame, o.detection_index));
    kept.frames_seen.extend(removed.frames_seen);
}

/// Smallest per-axis p-value of the D-t test between two objects, or `None` when the merge is not
/// applicable (labels differ, short histories, guards, zero variance).
fn duplicate_p(cfg: &AssociationConfig, a: &GlobalObject, b: &GlobalObject) -> Option<f64> {
    if a.label() != b.label() {
        return None;
    }
    if a.history.len() < cfg.merge_min_history || b.history.len() < cfg.merge_min_history {
        return None;
    }
    if cfg.merge_forbid_co_observed && a.frames_seen.intersection(&b.frames_seen).next().is_some() {
        return None;
    }
    let (ma, mb) = (a.mean_centroid()?, b.mean_centroid()?);
    if (ma - mb).norm() > cfg.merge_max_distance_m {
        return None;
    }
    let mut p_min = 1.0f64;
    for axis in 0..3 {
        let va: Vec<f64> = a.history.iter().map(|s| s.centroid_in_world[axis]).collect();
        let vb: Vec<f64> = b.history.iter().map(|s| s.centroid_in_world[axis]).collect();
        let (mean_a, var_a) = stats::mean_var(&va);
        let (mean_b, var_b) = stats::mean_var(&vb);
        let floor = cfg.t_min_std_m * cfg.t_min_std_m;
        let r = stats::pooled_t(mean_a, var_a.max(floor), va.len(), mean_b, var_b.max(floor), vb.len()).ok()?;
        p_min = p_min.min(r.p_value);
    }
    Some(p_min)
}

/// Fit the P-IoU box: project the points, keep those in front of the camera, take the
/// `[trim, 1 − trim]` quantiles of u and v, clip to the image. `None` when too few points project
/// or the box misses the image.
fn projected_box(
    points_in_world: &[Point3<f64>],
    camera: &PinholeCamera,
    camera_from_world: &Se3,
    cfg: &AssociationConfig,
) -> Option<Box2> {
    let mut us = Vec::with_capacity(points_in_world.len());
    let mut vs = Vec::with_capacity(points_in_world.len());
    for p in points_in_world {
        if let Some([u, v]) = camera.project(&(camera_from_world * p)) {
            us.push(u);
            vs.push(v);
        }
    }
    let n = us.len();
    if n < cfg.min_projected_points.max(1) {
        return None;
    }
    let k = ((cfg.projected_box_trim * n as f64).floor() as usize).min((n - 1) / 2);
    let (u0, u1) = select_pair(&mut us, k)?;
    let (v0, v1) = select_pair(&mut vs, k)?;
    Box2::new(u0, v0, u1, v1).intersection(&camera.image_box())
}

/// The k-th smallest and k-th largest values (O(n) selection).
fn select_pair(v: &mut [f64], k: usize) -> Option<(f64, f64)> {
    let n = v.len();
    if n == 0 || k >= n {
        return None;
    }
    let lo = *v.select_nth_unstable_by(k, f64::total_cmp).1;
    let hi = *v.select_nth_unstable_by(n - 1 - k, f64::total_cmp).1;
    Some((lo, hi))
}

/// Predict the object's box in `frame` by uniform motion from its last two sightings.
fn predicted_box(cfg: &AssociationConfig, frame: u32, obj: &GlobalObject) -> Option<Box2> {
    let (prev, last) = obj.last_two_boxes();
    let (fb, bb) = last?;
    let gap = frame.checked_sub(fb)?;
    if gap == 0 || gap > cfg.motion_max_gap_frames {
        return None;
    }
    match prev {
        Some((fa, ba)) if fb > fa && fb - fa <= cfg.motion_max_gap_frames => {
            let k = f64::from(gap) / f64::from(fb - fa);
            Some(Box2::new(
                bb.min[0] + k * (bb.min[0] - ba.min[0]),
                bb.min[1] + k * (bb.min[1] - ba.min[1]),
                bb.max[0] + k * (bb.max[0] - ba.max[0]),
                bb.max[1] + k * (bb.max[1] - ba.max[1]),
            ))
        }
        _ => cfg.motion_zero_velocity_fallback.then_some(bb),
    }
}

/// NP test: every axis p ≥ α. `None` when either cloud is empty.
fn np_test(cfg: &AssociationConfig, local: &SortedAxes, global: &SortedAxes) -> Option<bool> {
    let mut all = true;
    for axis in 0..3 {
        let (x, y) = (&local.0[axis], &global.0[axis]);
        if x.is_empty() || y.is_empty() {
            return None;
        }
        let (u1, ties) = stats::rank_sum_sorted(x, y);
        let p = stats::mann_whitney_p(u1, x.len(), y.len(), ties, cfg.np_use_continuity);
        if p < cfg.np_alpha {
            all = false;
            break;
        }
    }
    Some(all)
}

/// S-t test of the local centroid against the object's centroid history: every axis p ≥ α.
/// `None` when the history is too short (or has zero spread with a zero floor).
fn t_test(cfg: &AssociationConfig, centroid: &Vector3<f64>, obj: &GlobalObject) -> Option<bool> {
    let n = obj.history.len();
    if n < cfg.t_min_history.max(2) {
        return None;
    }
    let nf = n as f64;
    let mut all = true;
    for axis in 0..3 {
        let mean = obj.history.iter().map(|s| s.centroid_in_world[axis]).sum::<f64>() / nf;
        let ss = obj.history.iter().map(|s| (s.centroid_in_world[axis] - mean).powi(2)).sum::<f64>();
        let sd = (ss / (nf - 1.0)).sqrt().max(cfg.t_min_std_m);
        if sd.is_nan() || sd <= 0.0 {
            return None;
        }
        let se = if cfg.t_prediction { sd * (1.0 + 1.0 / nf).sqrt() } else { sd / nf.sqrt() };
        let t = (mean - centroid[axis]) / se;
        if stats::student_t_two_sided_p(t, nf - 1.0) < cfg.t_alpha {
            all = false;
            break;
        }
    }
    Some(all)
}

fn evaluate_pair(
    cfg: &AssociationConfig,
    frame: u32,
    local: &mut PreparedLocal,
    obj: &GlobalObject,
    projected: Option<Box2>,
) -> PairEval {
    let mut tests = TestOutcomes::default();
    let piou = projected.map(|b| b.iou(&local.bbox));
    tests.projected_iou = piou.map(|v| v >= cfg.projected_iou_threshold);
    let p_ok = tests.projected_iou == Some(true);
    let mut score = piou.unwrap_or(0.0);
    if !p_ok && !cfg.evaluate_all_tests {
        return PairEval { tests, accepted: false, score };
    }
    let mut any = false;
    if let Some(pred) = predicted_box(cfg, frame, obj) {
        let miou = pred.iou(&local.bbox);
        let pass = miou >= cfg.motion_iou_threshold;
        tests.motion_iou = Some(pass);
        any |= pass;
        if pass {
            score += miou;
        }
    }
    if cfg.mode.uses_t() && (!any || cfg.evaluate_all_tests) {
        tests.t_test = t_test(cfg, &local.centroid, obj);
        any |= tests.t_test == Some(true);
    }
    if cfg.mode.uses_np() && (!any || cfg.evaluate_all_tests) {
        if local.np.is_none() {
            local.np = Some(SortedAxes::new(&local.points, cfg.np_max_points));
        }
        let g = obj.np_cache.get_or_init(|| SortedAxes::new(&obj.points, cfg.np_max_points));
        tests.nonparametric = local.np.as_ref().and_then(|l| np_test(cfg, l, g));
        any |= tests.nonparametric == Some(true);
    }
    PairEval { tests, accepted: p_ok && any, score }
}

#[cfg(test)]
mod tests;
