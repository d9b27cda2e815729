//! Object parameterization: centroid, size and yaw of each map object from its accumulated world
//! points and the line segments seen inside its detection boxes (paper, Sec. "Object
//! parameterization": Alg. 1, Alg. 2, Eqs. "cube para", "quadric para", "score", "costf", "cost",
//! and "Object pose optimization").
//!
//! # Stages
//! The estimate of an object goes through four stages (recorded as [`EstimateStage`]):
//! 1. `raw`: mean and `(max − min) / 2` of all points, yaw 0 (the paper's Fig. "keyboard" (a)).
//! 2. `iforest`: the same after removing outliers with the isolation forest ([`iforest`], Alg. 1).
//! 3. `lines`: yaw from line alignment ([`yaw::align_yaw`], Alg. 2) over the last `t` frames; the
//!    box is re-fitted to the inlier points in the object frame of that yaw
//!    ([`yaw::oriented_extent`]: mid-range centre, half-extents along the object axes).
//! 4. `refined`: joint Levenberg–Marquardt refinement of yaw and scale (and centre) against the
//!    segments (visible cube edges only, Huber residuals) and the inlier points (point-to-surface
//!    distance, extent bound) ([`refine`]); kept only if it lowers a data cost computed the same
//!    way for the `lines` and the refined cube (no ground truth, no prior term), else `lines` stays.
//!
//! Cuboids are reported in a canonical form ([`yaw::canonical_cuboid`]): the longer horizontal
//! side along the object x axis, yaw in `[−π/2, π/2)`. A box at θ with sides `(a, b)` is the box
//! at θ + 90° with `(b, a)`; evaluation against ground truth written the other way round must
//! compare yaw modulo 90° (or canonicalise the truth the same way).
//!
//! Cylinders (cups, cans, bottles, bowls, balls; [`crate::map::Label::shape`]) have no yaw (the
//! paper ignores their orientation) and no `lines` stage. The paper stops them after stage 2, with
//! radius = mean of the two horizontal half-extents; beyond the paper their `refined` stage is a
//! circle fitted to the side-wall points ([`cylinder`]: the mean of the points of a partly seen
//! cylinder lies off its axis, towards the cameras), kept when it covers a long enough arc and
//! fits well ([`ParamConfig::cylinder`]; `enabled = false` gives the paper's behaviour). A
//! cylinder can also be written as a dual quadric ([`dual_quadric_world`], Eq.
//! "quadric para": `Q_w = T Q_o Tᵀ`, `Q_o = diag(s_l², s_w², s_h², −1)`).
//!
//! # Entry points
//! - [`ObjectEstimator`] (one per map object) with [`ParamConfig`]: per frame call
//!   [`ObjectEstimator::add_frame`] with the segments in the object's box, camera and pose, then
//!   [`ObjectEstimator::estimate`] with the object's accumulated world points. It returns an
//!   [`ObjectEstimate`]: the geometry, the stage used, a confidence flag and every stage's estimate.
//! - Building blocks: [`iforest::robust_centroid_scale`], [`lsd::detect_segments`],
//!   [`lsd::segments_in_box`], [`yaw::align_yaw`], [`refine::refine_yaw_scale`].
//!
//! Per frame, for a pipeline (camera poses from the SLAM or kinematics, held fixed here):
//! ```text
//! let segments = lsd::detect_segments(&grey, &LsdConfig::default())?;      // once per frame
//! for each associated (detection, map object):
//!     estimator[object].add_frame(LineFrame { frame, camera, world_from_camera, bbox,
//!                                             segments: lsd::segments_in_box(&segments, &bbox, 4.0) });
//!     let est = estimator[object].estimate(&object.points_in_world)?;
//!     object.world_from_object = est.geometry.world_from_object();
//!     object.half_extents = est.geometry.half_extents; object.stage = est.stage;
//! ```
//!
//! # Fallbacks (bad input)
//! - No points: [`ObjectsError::TooFewPoints`] unless a previous estimate exists, which is kept
//!   (confidence `Low`).
//! - Fewer points than ψ (256): every tree uses all points (scikit-learn's rule). Fewer than
//!   [`iforest::IForestConfig::min_points`]: no forest; the raw extent is used, confidence `Low`.
//! - All points identical (zero extent after Alg. 1): the previous estimate is kept if any, else
//!   the raw (degenerate) one, confidence `Low`.
//! - No segments in the window, or no yaw sample with an aligned segment: the `iforest` stage is
//!   final (yaw 0, or the previous yaw if one was found before: [`ParamConfig::keep_previous_yaw`]).
//! - A box partly off the image (within [`ParamConfig::border_margin_px`] of the border): the
//!   frame's segments are not added (a truncated box cuts the object's outline, and the image
//!   border itself yields segments); [`ObjectEstimator::add_frame`] reports it.
//! - Non-finite points: [`ObjectsError::NonFinitePoint`]; non-finite or zero-length segments are
//!   dropped by `add_frame`.
//! - Whenever an error occurs and a previous estimate exists, [`ObjectEstimator::estimate`] returns
//!   the previous estimate with confidence `Low` instead of the error.
//! - Table points (a dense cluster the forest keeps): optional pre-filter
//!   [`ParamConfig::table_z_m`] (off by default, as in the paper).
//! - Pieces of neighbours (an occluder or a surface behind the object that entered through a
//!   few frames' boxes): a separate cluster of 10-20 % of the cloud, which the forest does not
//!   isolate; [`ParamConfig::components_voxel_m`] keeps the cloud's main body
//!   ([`crate::geometry::main_components`]) before the forest (beyond the paper; 0 disables).
//!
//! # Choices where the paper is vague
//! Documented in the submodules and configurable:
//! - iForest score: the paper prints `s = 2 exp(−E(h)/C)` with `C` normalised by `|X|`; that is a
//!   typesetting slip of Liu et al.'s `s = 2^(−E(h)/c(ψ))`, `c(n) = 2H(n − 1) − 2(n − 1)/n`, which
//!   we implement (checked against scikit-learn: mean |Δs| 0.002 on 500 points).
//! - iForest passes ([`iforest::IForestConfig::passes`], default 1 = the paper): one pass at 0.6
//!   removes only ~60 % of a 20 % uniform contamination (masking, scikit-learn alike); more
//!   passes suit heavily contaminated clouds.
//! - Segment-to-edge association and the meaning of `e` and ξ ([`yaw`]); cube extents per
//!   candidate yaw from the inlier points ([`yaw::oriented_extent`]).
//! - The refinement's residual weights, gates, robust kernels, hidden-edge removal, the point terms
//!   and the acceptance cost ([`refine`]).
//! - Window length `t` ([`ParamConfig::window_frames`], default 10), and which frames it keeps:
//!   by default Alg. 2 samples the yaw on the `t` frames with the most segments, the refinement
//!   uses the latest `t` ([`WindowKeep::MostSegmentsYaw`]); the paper's "t consecutive images" for
//!   both is [`WindowKeep::Latest`].

pub mod cylinder;
pub mod iforest;
pub mod lsd;
pub mod refine;
pub mod yaw;

use std::collections::VecDeque;

use nalgebra::{Matrix4, Point3, Vector3};

use crate::geometry::{ObjectGeometry, Shape};
use crate::map::EstimateStage;

use cylinder::{fit_cylinder, CylinderFitConfig};
use iforest::{mean_and_half_extent, robust_centroid_scale, IForestConfig};
use refine::{refine_yaw_scale, RefineConfig};
use yaw::{align_yaw, canonical_cuboid, cuboid, oriented_extent, LineFrame, YawConfig};

/// Errors of the objects module.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ObjectsError {
    /// An image buffer does not match its size.
    #[error("image buffer holds {actual} samples, expected {expected}")]
    BadImage {
        /// width × height.
        expected: usize,
        /// Buffer length.
        actual: usize,
    },
    /// Too few points for the estimator.
    #[error("too few points: {actual} < {required}")]
    TooFewPoints {
        /// Minimum count.
        required: usize,
        /// Count given.
        actual: usize,
    },
    /// A point has a non-finite coordinate.
    #[error("point {index} has a non-finite coordinate")]
    NonFinitePoint {
        /// Index in the input.
        index: usize,
    },
    /// A configuration field is out of range.
    #[error("config {field}: {reason}")]
    BadConfig {
        /// Field name.
        field: &'static str,
        /// What is wrong.
        reason: String,
    },
}

/// Configuration of the per-object estimator.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ParamConfig {
    /// Isolation forest (Alg. 1).
    pub iforest: IForestConfig,
    /// Line-alignment yaw (Alg. 2).
    pub yaw: YawConfig,
    /// Joint yaw/scale refinement.
    pub refine: RefineConfig,
    /// Cylinder fit: the `refined` stage of cylinders ([`cylinder`], beyond the paper).
    pub cylinder: CylinderFitConfig,
    /// Window `t`: frames of segments kept (ring buffer), default 10 (the paper's "t consecutive
    /// images" is not given a value).
    pub window_frames: usize,
    /// Which frames the window keeps when it is full (default
    /// [`WindowKeep::MostSegmentsYaw`], beyond the paper; [`WindowKeep::Latest`] is the paper's).
    pub window_keep: WindowKeep,
    /// Boxes closer than this to the image border are "partly off the image", pixels (default 2).
    pub border_margin_px: f64,
    /// Run the refinement stage (default true).
    pub refine_enabled: bool,
    /// When a later call finds no line evidence, keep the last line-based yaw (default true).
    pub keep_previous_yaw: bool,
    /// Optional support plane (table top) height, metres: when set, points below
    /// `table_z_m + table_margin_m` are dropped before the isolation forest (the raw stage keeps
    /// them). Default `None` (the paper has no such step); depth points inside a detection box
    /// include the table around the object, a dense cluster the forest does not isolate.
    pub table_z_m: Option<f64>,
    /// Margin above the support plane, metres (default 0.005).
    pub table_margin_m: f64,
    /// Beyond the paper: height of the surface the objects stand on (the table top, world z),
    /// metres. Default `None` (off). Depth points within a few millimetres of the table are cut
    /// from every local cloud (they cannot be told from the table), so an estimate's bottom sits
    /// ~3 mm above the table and its height is short by as much (exploration benchmark, 9 seeds:
    /// bottom +3.0 mm, height −2.2 mm, every strategy). When set, an estimate whose bottom is
    /// within [`ParamConfig::support_snap_m`] of this height is extended down to it, its top kept
    /// (every stage from `iforest` on; `raw` stays the points' extent). With
    /// [`ParamConfig::support_slope`] this is the plane's height at x = y = 0.
    pub support_z_m: Option<f64>,
    /// Slope `[a, b]` of the support plane `z = a·x + b·y + support_z_m` (a table known only up to
    /// its calibration's tilt), evaluated at the estimate's centre; default `[0, 0]` (level).
    pub support_slope: [f64; 2],
    /// Largest gap between an estimate's bottom and the support surface that is closed, metres
    /// (default 0.015; an object resting on another one stays where its points are).
    pub support_snap_m: f64,
    /// Extents below this on every axis count as degenerate ("all points identical"), metres
    /// (default 1e-4).
    pub degenerate_extent_m: f64,
    /// Beyond the paper: before the isolation forest, keep only the cloud's main body
    /// ([`crate::geometry::main_components`]): a piece of a neighbour that entered through a few
    /// frames' boxes (an occluder, a surface behind the object) is a separate cluster centimetres
    /// away, too large a share of the cloud (10-20 %) for the forest to isolate. Voxel size,
    /// metres; 0 disables (default 0.01).
    pub components_voxel_m: f64,
    /// Cells of reach between connected voxels (default 2: gaps up to 2-5 cm are bridged).
    pub components_reach: i64,
    /// Components with at least this share of the largest one's points are kept too (default 0.5).
    pub components_keep_share: f64,
}

impl Default for ParamConfig {
    fn default() -> Self {
        Self {
            iforest: IForestConfig::default(),
            yaw: YawConfig::default(),
            refine: RefineConfig::default(),
            cylinder: CylinderFitConfig::default(),
            window_frames: 10,
            window_keep: WindowKeep::MostSegmentsYaw,
            border_margin_px: 2.0,
            refine_enabled: true,
            keep_previous_yaw: true,
            degenerate_extent_m: 1e-4,
            table_z_m: None,
            table_margin_m: 0.005,
            support_z_m: None,
            support_slope: [0.0, 0.0],
            support_snap_m: 0.015,
            components_voxel_m: 0.01,
            components_reach: 2,
            components_keep_share: 0.5,
        }
    }
}

/// Which frames the line window keeps once it holds [`ParamConfig::window_frames`].
///
/// Alg. 2 scores every frame by its share of aligned segments, `N_p / N_a`, so a frame with two
/// segments votes as much as one with twenty. When an object's last frames see it small (far
/// away, or at the edge of a pass), the paper's window of the latest frames fills with frames of
/// 2-5 segments whose votes are noise, and the yaw can end tens of degrees off although earlier
/// close frames saw the object well.
/// - [`WindowKeep::MostSegmentsYaw`] (the default): Alg. 2's yaw sampling uses the frames with the
///   most segments, the refinement the latest ones.
/// - [`WindowKeep::MostSegments`]: both stages on the most-segment frames; the refinement then
///   reprojects into old frames with old poses, which costs 3D IoU.
/// - [`WindowKeep::Latest`]: the paper's window.
///
/// The measurements behind the default: `studies/window_keep/README.md`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum WindowKeep {
    /// The last `t` frames for both stages (the paper's "t consecutive images").
    Latest,
    /// The `t` frames with the most segments: a full window drops the frame with the fewest
    /// (the oldest of those on ties), which may be the frame just added.
    MostSegments,
    /// Alg. 2 (yaw sampling) on the `t` frames with the most segments, the refinement on the
    /// latest `t`: the yaw is voted by the frames that saw the object's edges best, and the
    /// refinement's reprojection still uses the newest poses (the default).
    #[default]
    MostSegmentsYaw,
}

/// How much to trust an estimate.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Confidence {
    /// Produced by the stage chain from enough data.
    #[default]
    Normal,
    /// A fallback produced it (see the module docs); callers may weigh it less.
    Low,
}

/// Every stage's estimate from one [`ObjectEstimator::estimate`] call (`None` = stage not reached).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct StageEstimates {
    /// Raw extent of all points.
    pub raw: Option<ObjectGeometry>,
    /// After the isolation forest.
    pub iforest: Option<ObjectGeometry>,
    /// After line-alignment yaw.
    pub lines: Option<ObjectGeometry>,
    /// After refinement.
    pub refined: Option<ObjectGeometry>,
}

impl StageEstimates {
    /// The estimate of a given stage.
    pub fn get(&self, stage: EstimateStage) -> Option<ObjectGeometry> {
        match stage {
            EstimateStage::Raw => self.raw,
            EstimateStage::Iforest => self.iforest,
            EstimateStage::Lines => self.lines,
            EstimateStage::Refined => self.refined,
        }
    }
}

/// The estimator's answer.
#[derive(Debug, Clone, PartialEq)]
pub struct ObjectEstimate {
    /// The current geometry (the last stage reached, or a fallback).
    pub geometry: ObjectGeometry,
    /// The stage that produced `geometry`.
    pub stage: EstimateStage,
    /// `Low` when a fallback produced it.
    pub confidence: Confidence,
    /// Each stage's estimate from this call.
    pub stages: StageEstimates,
    /// Points kept by the isolation forest (all points for the raw fallback).
    pub inliers: usize,
}

impl ObjectEstimate {
    /// This estimate (every stage) in a world frame moved by the rigid `delta`.
    pub fn transform_world(&mut self, delta: &crate::geometry::Se3) {
        self.geometry = self.geometry.transformed(delta);
        for g in [&mut self.stages.raw, &mut self.stages.iforest, &mut self.stages.lines, &mut self.stages.refined]
            .into_iter()
            .flatten()
        {
            *g = g.transformed(delta);
        }
    }
}

/// What [`ObjectEstimator::add_frame`] did with a frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FrameUse {
    /// Added to the window with this many (finite) segments.
    Added {
        /// Segments kept.
        segments: usize,
    },
    /// Not added: the box is partly off the image.
    Truncated,
}

/// Incremental estimator for one object: a window of line frames and the last estimate.
#[derive(Debug, Clone)]
pub struct ObjectEstimator {
    shape: Shape,
    config: ParamConfig,
    /// The latest `t` frames ([`WindowKeep::Latest`] and the refinement of
    /// [`WindowKeep::MostSegmentsYaw`]) or the `t` with most segments ([`WindowKeep::MostSegments`]).
    window: VecDeque<LineFrame>,
    /// The `t` frames with most segments, kept only for [`WindowKeep::MostSegmentsYaw`] (Alg. 2's
    /// frames).
    yaw_window: VecDeque<LineFrame>,
    last: Option<ObjectEstimate>,
    last_line_yaw: Option<f64>,
}

impl ObjectEstimator {
    /// An estimator for an object modelled by `shape` (from [`crate::map::Label::shape`]).
    pub fn new(shape: Shape, config: ParamConfig) -> Self {
        Self { shape, config, window: VecDeque::new(), yaw_window: VecDeque::new(), last: None, last_line_yaw: None }
    }

    /// Re-express the window's camera poses and the last estimate in a world frame moved by the
    /// rigid `delta` (`new_world ← old_world`; see [`crate::pipeline::ObjectPipeline::transform_world`]).
    pub fn transform_world(&mut self, delta: &crate::geometry::Se3) {
        for f in self.window.iter_mut().chain(self.yaw_window.iter_mut()) {
            f.world_from_camera = delta * f.world_from_camera;
        }
        if let Some(last) = &mut self.last {
            last.transform_world(delta);
        }
        if let Some(yaw) = &mut self.last_line_yaw {
            let x = delta.rotation * Vector3::new(yaw.cos(), yaw.sin(), 0.0);
            *yaw = x.y.atan2(x.x);
        }
    }

    /// The last estimate, if any.
    pub fn last(&self) -> Option<&ObjectEstimate> {
        self.last.as_ref()
    }

    /// Frames currently in the window.
    pub fn window_len(&self) -> usize {
        self.window.len()
    }

    /// The frames currently in the window, oldest first.
    pub fn window(&self) -> impl Iterator<Item = &LineFrame> {
        self.window.iter()
    }

    /// Whether Alg. 2 has its own window ([`WindowKeep::MostSegmentsYaw`]).
    fn separate_yaw_window(&self) -> bool {
        self.config.window_keep == WindowKeep::MostSegmentsYaw
    }

    /// The frames Alg. 2 samples the yaw on, oldest first (the window, or for
    /// [`WindowKeep::MostSegmentsYaw`] the frames with the most segments).
    pub fn yaw_frames(&self) -> impl Iterator<Item = &LineFrame> {
        if self.separate_yaw_window() { &self.yaw_window } else { &self.window }.iter()
    }

    /// Every frame the estimator holds (the window and, for [`WindowKeep::MostSegmentsYaw`], Alg. 2's
    /// frames), each once, oldest first: adding them in this order to a fresh estimator with the
    /// same config rebuilds both windows (used to record estimator inputs for replay).
    pub fn held_frames(&self) -> Vec<LineFrame> {
        let mut all: Vec<LineFrame> = self.window.iter().chain(self.yaw_window.iter()).cloned().collect();
        all.sort_by_key(|f| f.frame);
        all.dedup_by_key(|f| f.frame);
        all
    }

    /// The shape this estimator models.
    pub fn shape(&self) -> Shape {
        self.shape
    }

    /// Model another shape from now on (the object's majority label moved to a class of the
    /// other primitive): the line frames stay, the last estimate and its yaw are dropped, so the
    /// next [`Self::estimate`] starts over in the new shape.
    pub fn set_shape(&mut self, shape: Shape) {
        if shape != self.shape {
            self.shape = shape;
            self.last = None;
            self.last_line_yaw = None;
        }
    }

    /// Add one frame's line evidence (segments already restricted to the object's box, e.g. by
    /// [`lsd::segments_in_box`]). When the window is full a frame leaves it, chosen by
    /// [`ParamConfig::window_keep`] (by default the oldest leaves the window and the one with the
    /// fewest segments leaves Alg. 2's frames).
    pub fn add_frame(&mut self, mut frame: LineFrame) -> FrameUse {
        let m = self.config.border_margin_px;
        let (w, h) = (f64::from(frame.camera.width), f64::from(frame.camera.height));
        let b = &frame.bbox;
        if !b.is_finite() || b.min[0] < m || b.min[1] < m || b.max[0] > w - m || b.max[1] > h - m {
            return FrameUse::Truncated;
        }
        frame.segments.retain(|s| s.is_finite() && s.length_px() > 0.0);
        let segments = frame.segments.len();
        let t = self.config.window_frames.max(1);
        // `min_by_key` returns the first minimum: the oldest of the frames with fewest segments.
        let fewest =
            |w: &VecDeque<LineFrame>| w.iter().enumerate().min_by_key(|(_, f)| f.segments.len()).map_or(0, |(k, _)| k);
        if self.separate_yaw_window() {
            self.yaw_window.push_back(frame.clone());
            while self.yaw_window.len() > t {
                let drop = fewest(&self.yaw_window);
                self.yaw_window.remove(drop);
            }
        }
        self.window.push_back(frame);
        while self.window.len() > t {
            let drop = match self.config.window_keep {
                WindowKeep::Latest | WindowKeep::MostSegmentsYaw => 0,
                WindowKeep::MostSegments => fewest(&self.window),
            };
            self.window.remove(drop);
        }
        FrameUse::Added { segments }
    }

    /// Re-estimate from the object's accumulated world points and the frames in the window.
    pub fn estimate(&mut self, points_in_world: &[Point3<f64>]) -> Result<ObjectEstimate, ObjectsError> {
        let result = self.estimate_inner(points_in_world);
        match result {
            Ok(mut est) => {
                if let Some(z0) = self.config.support_z_m {
                    let [a, b] = self.config.support_slope;
                    let snap = |g: &mut ObjectGeometry| {
                        let z = z0 + a * g.center.x + b * g.center.y;
                        snap_to_support(g, z, self.config.support_snap_m)
                    };
                    snap(&mut est.geometry);
                    for g in
                        [&mut est.stages.iforest, &mut est.stages.lines, &mut est.stages.refined].into_iter().flatten()
                    {
                        snap(g);
                    }
                }
                self.last = Some(est.clone());
                Ok(est)
            }
            Err(e) => match &self.last {
                Some(prev) => Ok(ObjectEstimate { confidence: Confidence::Low, ..prev.clone() }),
                None => Err(e),
            },
        }
    }

    fn finish(&self, g: ObjectGeometry) -> ObjectGeometry {
        match self.shape {
            Shape::Cuboid => ObjectGeometry { shape: Shape::Cuboid, ..g },
            Shape::Cylinder => {
                let r = (g.half_extents.x + g.half_extents.y) / 2.0;
                ObjectGeometry {
                    shape: Shape::Cylinder,
                    center: g.center,
                    yaw_rad: 0.0,
                    half_extents: Vector3::new(r, r, g.half_extents.z),
                }
            }
        }
    }

    fn estimate_inner(&mut self, points: &[Point3<f64>]) -> Result<ObjectEstimate, ObjectsError> {
        if let Some(index) = points.iter().position(|p| !p.coords.iter().all(|v| v.is_finite())) {
            return Err(ObjectsError::NonFinitePoint { index });
        }
        let (raw_c, raw_s) =
            mean_and_half_extent(points).ok_or(ObjectsError::TooFewPoints { required: 1, actual: 0 })?;
        let raw = self.finish(cuboid(raw_c, 0.0, raw_s));
        let mut stages = StageEstimates { raw: Some(raw), ..Default::default() };
        let degenerate = |s: &Vector3<f64>| s.iter().all(|v| *v < self.config.degenerate_extent_m);
        let low = |g: ObjectGeometry, stage, stages, inliers| ObjectEstimate {
            geometry: g,
            stage,
            confidence: Confidence::Low,
            stages,
            inliers,
        };
        let above_table: Vec<Point3<f64>>;
        let points = match self.config.table_z_m {
            Some(z) => {
                above_table = points.iter().filter(|p| p.z >= z + self.config.table_margin_m).copied().collect();
                &above_table[..]
            }
            None => points,
        };
        let main_body: Vec<Point3<f64>>;
        let points = if self.config.components_voxel_m > 0.0 {
            let keep = crate::geometry::main_components(
                points,
                self.config.components_voxel_m,
                self.config.components_reach,
                self.config.components_keep_share,
            );
            main_body = points.iter().zip(&keep).filter(|(_, k)| **k).map(|(p, _)| *p).collect();
            &main_body[..]
        } else {
            points
        };
        let robust = match robust_centroid_scale(points, &self.config.iforest) {
            Ok(r) => r,
            Err(ObjectsError::TooFewPoints { .. }) => {
                if degenerate(&raw_s) {
                    if let Some(prev) = &self.last {
                        return Ok(ObjectEstimate { confidence: Confidence::Low, ..prev.clone() });
                    }
                }
                return Ok(low(raw, EstimateStage::Raw, stages, points.len()));
            }
            Err(e) => return Err(e),
        };
        let inliers: Vec<Point3<f64>> =
            points.iter().zip(&robust.inlier).filter(|(_, k)| **k).map(|(p, _)| *p).collect();
        let n_in = inliers.len();
        if degenerate(&robust.half_extents) {
            if let Some(prev) = &self.last {
                return Ok(ObjectEstimate { confidence: Confidence::Low, ..prev.clone() });
            }
            let g = self.finish(cuboid(robust.center, 0.0, robust.half_extents));
            stages.iforest = Some(g);
            return Ok(low(g, EstimateStage::Iforest, stages, n_in));
        }
        let prev_yaw = if self.config.keep_previous_yaw { self.last_line_yaw } else { None };
        let ifo = self.finish(cuboid(robust.center, 0.0, robust.half_extents));
        stages.iforest = Some(ifo);
        let iforest_final = |stages: StageEstimates| -> ObjectEstimate {
            let geometry = match (self.shape, prev_yaw) {
                (Shape::Cuboid, Some(yaw)) => {
                    oriented_extent(&inliers, yaw).map_or(ifo, |(c, s)| canonical_cuboid(&cuboid(c, yaw, s)))
                }
                _ => ifo,
            };
            ObjectEstimate {
                geometry,
                stage: EstimateStage::Iforest,
                confidence: Confidence::Normal,
                stages,
                inliers: n_in,
            }
        };
        if self.shape == Shape::Cylinder {
            let mut out = iforest_final(stages);
            if let Some(g) = fit_cylinder(&inliers, &self.config.cylinder) {
                out.stages.refined = Some(g);
                out.geometry = g;
                out.stage = EstimateStage::Refined;
            }
            return Ok(out);
        }
        // Both windows as slices, without copying the frames (this runs per object per frame).
        self.window.make_contiguous();
        self.yaw_window.make_contiguous();
        let frames: &[LineFrame] = self.window.as_slices().0;
        let yaw_frames: &[LineFrame] = if self.separate_yaw_window() { self.yaw_window.as_slices().0 } else { frames };
        let geometry_for_yaw = |yaw: f64| {
            oriented_extent(&inliers, yaw)
                .map_or(cuboid(robust.center, yaw, robust.half_extents), |(c, s)| cuboid(c, yaw, s))
        };
        let Some(alignment) = align_yaw(yaw_frames, geometry_for_yaw, &self.config.yaw) else {
            return Ok(iforest_final(stages));
        };
        let lines = canonical_cuboid(&geometry_for_yaw(alignment.yaw_rad));
        stages.lines = Some(lines);
        self.last_line_yaw = Some(lines.yaw_rad);
        let mut out = ObjectEstimate {
            geometry: lines,
            stage: EstimateStage::Lines,
            confidence: Confidence::Normal,
            stages,
            inliers: n_in,
        };
        if self.config.refine_enabled {
            if let Some(r) = refine_yaw_scale(&lines, frames, &inliers, &self.config.refine) {
                if !self.config.refine.accept_if_lower_cost || r.rms_after_px < r.rms_before_px {
                    let refined = canonical_cuboid(&r.geometry);
                    out.stages.refined = Some(refined);
                    out.geometry = refined;
                    out.stage = EstimateStage::Refined;
                    self.last_line_yaw = Some(refined.yaw_rad);
                }
            }
        }
        Ok(out)
    }
}

/// `g` extended down to the support height `z` when its bottom lies within `snap` of it (above or
/// below), its top kept; otherwise unchanged.
pub fn snap_to_support(g: &mut ObjectGeometry, z: f64, snap: f64) {
    let (top, bottom) = (g.center.z + g.half_extents.z, g.center.z - g.half_extents.z);
    if (bottom - z).abs() <= snap && top > z {
        g.center.z = (top + z) / 2.0;
        g.half_extents.z = (top - z) / 2.0;
    }
}

/// The dual quadric of an object in the world (Eq. "quadric para"): `Q_w = T Q_o Tᵀ` with
/// `Q_o = diag(s_x², s_y², s_z², −1)` (the ellipsoid with semi-axes = half-extents) and `T` the
/// homogeneous `world_from_object` (yaw 0 for cylinders). A plane `π` (homogeneous 4-vector) is
/// tangent to the ellipsoid iff `πᵀ Q_w π = 0`.
pub fn dual_quadric_world(geometry: &ObjectGeometry) -> Matrix4<f64> {
    let s = geometry.half_extents;
    let q_o = Matrix4::from_diagonal(&nalgebra::Vector4::new(s.x * s.x, s.y * s.y, s.z * s.z, -1.0));
    let t = geometry.world_from_object().to_homogeneous();
    t * q_o * t.transpose()
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector4;

    #[test]
    fn dual_quadric_tangent_planes() {
        let g = cuboid(Vector3::new(0.5, -0.1, 0.04), 0.5, Vector3::new(0.06, 0.03, 0.04));
        let q = dual_quadric_world(&g);
        assert!((q - q.transpose()).abs().max() < 1e-12);
        // Tangent planes: z = cz ± sz, and the object-x planes x' = ±sx after yaw.
        let top = Vector4::new(0.0, 0.0, 1.0, -(0.04 + 0.04));
        let (s, c) = 0.5f64.sin_cos();
        let n = Vector3::new(c, s, 0.0);
        let side = Vector4::new(n.x, n.y, 0.0, -(n.dot(&g.center) + 0.06));
        let inner = Vector4::new(n.x, n.y, 0.0, -(n.dot(&g.center) + 0.03));
        assert!((top.transpose() * q * top)[0].abs() < 1e-12);
        assert!((side.transpose() * q * side)[0].abs() < 1e-12);
        // A plane cutting the ellipsoid gives s_x² − 0.03² > 0; one missing it gives < 0.
        assert!(((inner.transpose() * q * inner)[0] - (0.06f64.powi(2) - 0.03f64.powi(2))).abs() < 1e-12);
        let away = Vector4::new(0.0, 0.0, 1.0, -0.5);
        assert!((away.transpose() * q * away)[0] < 0.0);
        // Q_o recovered at the origin with yaw 0.
        let g0 = cuboid(Vector3::zeros(), 0.0, Vector3::new(1.0, 2.0, 3.0));
        let q0 = dual_quadric_world(&g0);
        assert_eq!(q0, Matrix4::from_diagonal(&Vector4::new(1.0, 4.0, 9.0, -1.0)));
    }
}

#[cfg(test)]
mod config_tests {
    use super::*;

    #[test]
    fn config_round_trips_and_fills_defaults() {
        let cfg = ParamConfig::default();
        let text = serde_json::to_string(&cfg).unwrap();
        let back: ParamConfig = serde_json::from_str(&text).unwrap();
        assert_eq!(back, cfg);
        let partial: ParamConfig = serde_json::from_str(r#"{"window_frames": 5, "iforest": {"passes": 1}}"#).unwrap();
        assert_eq!(partial.window_frames, 5);
        assert_eq!(partial.iforest.passes, 1);
        assert_eq!(partial.iforest.n_trees, 100);
        assert!(serde_json::from_str::<ParamConfig>(r#"{"typo": 1}"#).is_err());
    }
}

#[cfg(test)]
mod support_tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// A can (r 3.3 cm, 10 cm tall, standing at z = 0) whose points below 5 mm were cut, as the
    /// local clouds cut them: side wall all round plus the top disc, 1 mm noise.
    fn cut_can(seed: u64) -> Vec<Point3<f64>> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut pts = Vec::new();
        for _ in 0..600 {
            let (a, z, e) = (
                rng.random_range(0.0..std::f64::consts::TAU),
                rng.random_range(0.005..0.1),
                rng.random_range(-0.001..0.001),
            );
            pts.push(Point3::new(0.5 + (0.033 + e) * a.cos(), 0.1 + (0.033 + e) * a.sin(), z));
        }
        for _ in 0..200 {
            let (a, rr) = (rng.random_range(0.0..std::f64::consts::TAU), 0.033 * rng.random_range(0.0f64..1.0).sqrt());
            pts.push(Point3::new(0.5 + rr * a.cos(), 0.1 + rr * a.sin(), 0.1 + rng.random_range(-0.001..0.001)));
        }
        pts
    }

    #[test]
    fn a_new_shape_is_estimated_in_that_shape() {
        let pts = cut_can(2);
        let mut est = ObjectEstimator::new(Shape::Cuboid, ParamConfig::default());
        assert_eq!(est.estimate(&pts).unwrap().geometry.shape, Shape::Cuboid);
        est.set_shape(Shape::Cylinder);
        assert_eq!(est.shape(), Shape::Cylinder);
        assert!(est.last().is_none(), "the cuboid estimate is dropped");
        let g = est.estimate(&pts).unwrap().geometry;
        assert_eq!(g.shape, Shape::Cylinder);
        assert!((g.half_extents.x - g.half_extents.y).abs() < 1e-12);
        assert!((g.half_extents.x - 0.033).abs() < 0.004, "radius {}", g.half_extents.x);
    }

    #[test]
    fn standing_object_reaches_the_support() {
        let pts = cut_can(1);
        let mut plain = ObjectEstimator::new(Shape::Cylinder, ParamConfig::default());
        let g = plain.estimate(&pts).unwrap().geometry;
        // Without the support: the bottom is where the points stop.
        assert!((g.center.z - g.half_extents.z - 0.005).abs() < 0.0015, "{g:?}");
        let config = ParamConfig { support_z_m: Some(0.0), ..ParamConfig::default() };
        let mut est = ObjectEstimator::new(Shape::Cylinder, config);
        let e = est.estimate(&pts).unwrap();
        let s = e.geometry;
        assert!((s.center.z - s.half_extents.z).abs() < 1e-12, "bottom {}", s.center.z - s.half_extents.z);
        assert!((s.center.z + s.half_extents.z - (g.center.z + g.half_extents.z)).abs() < 1e-12, "top moved");
        assert!((s.half_extents.z - 0.05).abs() < 0.0015, "{s:?}");
        // Not the raw stage (the points' extent).
        let raw = e.stages.raw.expect("no raw stage");
        assert!(raw.center.z - raw.half_extents.z > 0.004);
    }

    #[test]
    fn snap_only_closes_small_gaps() {
        let g0 = ObjectGeometry {
            shape: Shape::Cuboid,
            center: Vector3::new(0.0, 0.0, 0.06),
            yaw_rad: 0.3,
            half_extents: Vector3::new(0.02, 0.03, 0.04),
        };
        // Bottom 2 cm above the support (an object on another one): unchanged.
        let mut g = g0;
        snap_to_support(&mut g, 0.0, 0.015);
        assert_eq!(g, g0);
        // Bottom 1 cm above: extended to z = 0, top 0.10 kept.
        let mut g = g0;
        snap_to_support(&mut g, 0.01, 0.015);
        assert!((g.center.z - 0.055).abs() < 1e-12 && (g.half_extents.z - 0.045).abs() < 1e-12, "{g:?}");
        // Bottom 5 mm below the support (a map offset): raised to it.
        let mut g = g0;
        snap_to_support(&mut g, 0.025, 0.015);
        assert!((g.center.z - 0.0625).abs() < 1e-12 && (g.half_extents.z - 0.0375).abs() < 1e-12, "{g:?}");
        assert_eq!((g.yaw_rad, g.half_extents.x), (g0.yaw_rad, g0.half_extents.x));
    }
}
