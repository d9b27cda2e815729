//! Object-driven active exploration: surface occupancy grids, visibility, the next-best-view
//! utility and candidate views (paper, section "Object-Driven Active exploration").
//!
//! # What it does
//! Each map object carries a five-face surface occupancy grid ("Observation Completeness
//! Measurement"): its points, moved into the object frame, land on the faces of its estimated
//! primitive (no bottom face), 1 cm cells, each unknown / occupied / free. Entropy over the cells
//! measures how incompletely the object has been seen. Candidate camera views sampled around the
//! objects are scored with the paper's utility ("Object-Driven Exploration")
//!
//! f = Σ_{x ∈ I} ((1 − R_o)·H_obj + λ·(H_IoU + H_V))·s(x),   λ = 0.2,
//!
//! and the view with the highest f is the next best view (NBV). Exploration stops when s(x) = 0
//! for every object or after 10 views.
//!
//! # Entry points
//! Per frame, after the object map was updated from the frame:
//! - [`ExplorationGrids::integrate_frame`]`(map, camera, world_from_camera, observed, depth,
//!   grid_config)`: syncs the grids with the map (new objects get all-unknown grids, merged or
//!   removed objects lose theirs, re-estimated objects are re-anchored) and updates every object's
//!   grid: `observed` = this frame's points per map object ([`ObservedPoints`], world frame: e.g.
//!   the depth points inside the detection box associated with that object), `depth` = the
//!   frame's depth image (optional, strongly recommended: it rejects cells hidden by unmodelled
//!   things and confirms surface hits).
//!
//! Per decision step (after a view was reached and its frames integrated):
//! 1. [`HistoryBook::record`]`(map)`: appends each object's current estimate (volume and IoU
//!    histories for H_V, s(x) and [`IouMode::EstimateHistory`]).
//! 2. `ctx = `[`UtilityContext::new`]`(map, grids, histories, camera, config)`;
//!    [`stop_reason`]`(&ctx.features(), views_taken, config)` → stop when `Some`.
//! 3. [`sample_candidates`]`(map, candidate_config, grid_config, reachable, seed)` (seeded, with
//!    a [`Reachability`] callback, e.g. an IK closure `|world_from_camera| -> bool`), then
//!    `ctx.`[`score_all`](UtilityContext::score_all)`(views, strategy, Some(current_pose))` with
//!    [`Strategy::ObjectDriven`] or [`Strategy::ExpectedGain`], then [`next_best_view`] (argmax).
//! - Baselines: [`init_views`] (four table corners, top view), [`coverage_views`]
//!   (Boustrophedon lanes), [`random_views`] (random reachable views); views are built by
//!   [`crate::geometry::look_at`].
//! - Recording and tests: [`SurfaceGrid::cells_in_world`] (cells with state and probability),
//!   [`ViewScore`] (per-object utility terms), [`Occluders::cast_ray`] (render synthetic depth
//!   and segmentation from a map).
//!
//! # Paper mapping and choices where the paper is vague
//! - **Entropy unit.** Bits (log₂), so a cell's H ∈ [0, 1], H̄_obj ∈ [0, 1] and the s(x) threshold
//!   H̄ < 0.5 means "half the maximum". Eq. `eq:grid`, `eq:obj`, `eq:ba_grid`, `eq:plogp`.
//! - **Sensor model** ([`GridConfig`]): log-odds from p₀ = 0.5; a hit adds logit(`p_hit` = 0.75),
//!   a miss adds logit(`p_miss` = 0.3); log-odds clamped to logit([0.03, 0.97]). One update per
//!   cell per frame (a cell hit by many points of a frame counts once, so dense clouds do not
//!   saturate it in one frame). State: unknown if never updated, else occupied if p > 0.5, else
//!   free.
//! - **Occupied** = a cell containing ≥ 1 of the frame's points of that object (points farther than
//!   `max_point_distance_m` from the surface are dropped; a point goes to the nearest face, none if
//!   the nearest is the bottom). With a depth image and `depth_confirms_hit`, a visible cell whose
//!   measured depth matches its own depth is a hit too (the surface is there even if the pipeline
//!   sub-sampled or missed its points).
//! - **Free** = visible (see [`visibility`]: facing, in image and range, the ray from the camera
//!   unblocked by the table plane and the other objects' primitives via parry3d-f64, and — with
//!   depth — the measured depth not in front of the cell) and not a hit. Never "merely in the
//!   frustum".
//! - **Grids follow the object**: cells are stored in object-normalised face coordinates, so pose
//!   changes move them implicitly; size changes resample each face by nearest neighbour in
//!   normalised coordinates ([`SurfaceGrid::sync`]).
//! - **Cylinders**: the lateral surface is cut into four quarter arcs facing ±x, ±y (each unrolled
//!   to arc length × height) plus the top disc (rasterised over its bounding square, cells outside
//!   the disc masked out): still five faces, every cell on the true surface so ray casting and
//!   depth checks are exact for the primitive.
//! - **R_o** is the paper's ratio of *occupied* cells (|O| / all); [`GridStats::observed_ratio`] gives
//!   the observed ratio too.
//! - **H_obj in the utility** is "the uncertainty of the object map under the predicted camera
//!   view": by default ([`EntropyScope::ViewCells`]) the entropy of the object's cells that face the
//!   candidate camera and project into its image (no ray casting: cheap; expected-gain does ray
//!   cast); [`EntropyScope::Object`] uses the whole H_obj (then all views that see an object score
//!   it equally).
//! - **Objects in view (I)**: the object centre projects into the image within range.
//! - **R_IoU** ([`IouMode::ViewOcclusion`], default): the mean 2D IoU of the object's projected box
//!   with the projected boxes of the other in-view objects that overlap it (0 if none) — "the 2D
//!   mean IoU with adjacent objects used for modelling occlusion under a specific camera view";
//!   H_IoU = −p log₂ p with p = R_IoU/2 as in the paper. [`IouMode::EstimateHistory`] uses the 3D IoU
//!   of the object's last two estimates instead.
//! - **H_V**: p = p(V̄⁽ᵗ⁾) from the normal fitted to the normalised volume history, rescaled to peak 1
//!   (see [`ObjectHistory::volume_convergence`]); with fewer than `min_history_len` estimates p = 0.
//! - **s(x)** = 0 iff (H̄ < 0.5 ∨ R_o > 0.5) ∧ p(V̄) > 0.8 (all config fields).
//! - **Stopping**: all objects s = 0 (non-empty map) or `max_views` = 10 views.
//!
//! # Strategy `expected-gain` (beyond the paper)
//! f_EG = Σ_{x ∈ I} (Σ_{c visible} ΔH(c) + λ·(H_IoU + H_V))·s(x) − μ·(‖t − t_now‖ + ρ·∠(R, R_now)),
//! where ΔH(c) = H(p) − [p·H(σ(l + k·L_hit)) + (1 − p)·H(σ(l + k·L_miss))] is the expected
//! entropy reduction of cell c (log-odds l, p = σ(l)) after k = `expected_measurements` more
//! measurements ([`expected_entropy_reduction`]); "visible" is the full ray-cast test against the
//! current map (occluded cells gain nothing, which is how occlusion enters beyond H_IoU); the
//! (1 − R_o) weight is dropped (the expected reduction already favours uncertain cells);
//! μ = `motion_cost_bits_per_m`, ρ = `motion_cost_m_per_rad` (rotation as equivalent metres);
//! R, t is the candidate pose and R_now, t_now the current camera pose.
//!
//! # Table discovery (beyond the paper; [`DiscoveryConfig`], off by default in the core)
//! The paper's f knows only mapped objects, so an object the Init views missed is never looked
//! for. [`TableCoverage`] records which 2 cm cells of the table top have had a depth return;
//! with weight w > 0 the session adds w·(bits per cm²)·(unseen cells a candidate would see) to f,
//! adds candidates aimed at unseen cells, and does not stop on "every object done" while a view
//! would still see `min_new_cells` unseen cells (`discovery` module docs).

mod discovery;
mod grid;
mod utility;
mod views;
pub mod visibility;

use std::collections::BTreeMap;

use nalgebra::Point3;

pub use discovery::{
    discovery_targets, greedy_discovery_views, greedy_discovery_views_weighted, truncated_boxes, visible_unknown_cells,
    visible_unknown_indices, DiscoveryConfig, TableCoverage,
};
pub use grid::{
    binary_entropy_bits, log_odds, plogp_bits, probability_from_log_odds, CellPose, CellRef, CellState, Face, FaceGrid,
    GridStats, SurfaceGrid, WorldCell,
};
pub use utility::{
    expected_entropy_reduction, needs_exploring, next_best_view, object_features, stop_reason, HistoryBook,
    ObjectFeatures, ObjectHistory, ObjectViewTerms, StopReason, UtilityContext, ViewScore,
};
pub use views::{
    camera_position_free, coverage_views, init_views, random_views, sample_candidates, sample_candidates_around,
    sample_candidates_at, AlwaysReachable, CandidateView, Reachability,
};
pub use visibility::{
    integrate_object, point_visibility, CellVisibility, ObjectFrameUpdate, ObservedPoints, Occluders, Viewpoint,
};

use crate::frame::DepthImage;
use crate::geometry::{GeometryError, PinholeCamera, Se3};
use crate::map::ObjectMap;

/// Errors of the explore module.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ExploreError {
    /// A config field is out of its valid range.
    #[error("config field {field}: {reason}")]
    InvalidConfig {
        /// Field name.
        field: &'static str,
        /// What is wrong.
        reason: String,
    },
    /// An input has a non-finite value.
    #[error("{field}: non-finite value")]
    NonFinite {
        /// Which input.
        field: &'static str,
    },
    /// A degenerate geometric input.
    #[error("degenerate input: {what}")]
    Degenerate {
        /// What was degenerate.
        what: String,
    },
    /// Observed points refer to an object that is not in the map.
    #[error("observed points for object {object_id}, which is not in the map")]
    UnknownObject {
        /// The id.
        object_id: u32,
    },
    /// Invalid camera intrinsics.
    #[error(transparent)]
    Geometry(#[from] GeometryError),
}

fn check_range(field: &'static str, v: f64, lo: f64, hi: f64) -> Result<(), ExploreError> {
    if v.is_finite() && v >= lo && v <= hi {
        Ok(())
    } else {
        Err(ExploreError::InvalidConfig { field, reason: format!("{v} outside [{lo}, {hi}]") })
    }
}

/// Surface grid and sensor-model settings.
#[derive(Debug, Clone, PartialEq)]
pub struct GridConfig {
    /// Cell side, metres. Paper: m = 1 cm.
    pub cell_size_m: f64,
    /// Inverse sensor model: P(occupied | hit). Larger = faster convergence to occupied.
    pub p_hit: f64,
    /// Inverse sensor model: P(occupied | seen, no hit), < 0.5. Smaller = faster to free.
    pub p_miss: f64,
    /// Lower clamp of the occupancy probability (keeps cells revisable).
    pub p_min: f64,
    /// Upper clamp of the occupancy probability.
    pub p_max: f64,
    /// Points farther than this from the estimated surface are not projected, metres.
    pub max_point_distance_m: f64,
    /// Size changes below this (any half-extent, metres) do not resample the grid.
    pub resample_tolerance_m: f64,
    /// A cell is visible only when the angle between its normal and the direction to the camera
    /// is at most this, degrees (grazing views are unreliable).
    pub max_incidence_deg: f64,
    /// Nearest visible depth along the optical axis, metres (depth sensor near limit).
    pub min_range_m: f64,
    /// Farthest visible distance, metres (depth sensor far limit).
    pub max_range_m: f64,
    /// Rays to cells start this far off the surface along the normal, metres (avoids grazing
    /// self-hits with touching neighbours).
    pub surface_offset_m: f64,
    /// Depth agreement tolerance, metres: measured depth more than this in front of a cell means
    /// it is occluded; within ± this means the surface is there.
    pub depth_tolerance_m: f64,
    /// With depth, a visible cell whose measured depth matches counts as a hit.
    pub depth_confirms_hit: bool,
    /// Height of the table top (world z), metres; the table plane occludes everything below it.
    pub table_height_m: f64,
}

impl Default for GridConfig {
    fn default() -> Self {
        Self {
            cell_size_m: 0.01,
            p_hit: 0.75,
            p_miss: 0.3,
            p_min: 0.03,
            p_max: 0.97,
            max_point_distance_m: 0.03,
            resample_tolerance_m: 1e-4,
            max_incidence_deg: 80.0,
            min_range_m: 0.1,
            max_range_m: 2.0,
            surface_offset_m: 0.002,
            depth_tolerance_m: 0.01,
            depth_confirms_hit: true,
            table_height_m: 0.0,
        }
    }
}

impl GridConfig {
    /// Check every field's range.
    pub fn validate(&self) -> Result<(), ExploreError> {
        check_range("cell_size_m", self.cell_size_m, 1e-4, 1.0)?;
        check_range("p_hit", self.p_hit, 0.5 + 1e-9, 1.0 - 1e-9)?;
        check_range("p_miss", self.p_miss, 1e-9, 0.5 - 1e-9)?;
        check_range("p_min", self.p_min, 1e-9, 0.5)?;
        check_range("p_max", self.p_max, 0.5, 1.0 - 1e-9)?;
        check_range("max_point_distance_m", self.max_point_distance_m, 0.0, 10.0)?;
        check_range("resample_tolerance_m", self.resample_tolerance_m, 0.0, 1.0)?;
        check_range("max_incidence_deg", self.max_incidence_deg, 0.0, 90.0)?;
        check_range("min_range_m", self.min_range_m, 0.0, 100.0)?;
        check_range("max_range_m", self.max_range_m, self.min_range_m, 1000.0)?;
        check_range("surface_offset_m", self.surface_offset_m, 0.0, 0.1)?;
        check_range("depth_tolerance_m", self.depth_tolerance_m, 0.0, 1.0)?;
        check_range("table_height_m", self.table_height_m, -100.0, 100.0)
    }
}

/// How R_IoU is obtained.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum IouMode {
    /// Paper: mean 2D IoU of the object's projected box with the overlapping projected boxes of
    /// the other objects in the candidate view (occlusion).
    #[default]
    ViewOcclusion,
    /// 3D IoU between the object's last two estimates (from [`ObjectHistory`]).
    EstimateHistory,
}

/// Which cells make up H in the utility's (1 − R_o)·H term.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum EntropyScope {
    /// Cells facing the candidate camera and projecting into its image ("under the predicted
    /// camera view").
    #[default]
    ViewCells,
    /// All cells of the object (H_obj as in Eq. `eq:obj`).
    Object,
}

/// Exploration strategies (names as in the benchmark report and the run config).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Strategy {
    /// The paper's rule exactly ("object-driven"): its utility with H_obj over all of an object's
    /// cells ([`EntropyScope::Object`]), its stop, no table discovery.
    ObjectDriven,
    /// The project's strategy ("object-driven-discovery"): the paper's utility with H over the
    /// cells the candidate sees (the run's `entropy_scope`), plus the table-discovery extension
    /// (`discovery_*` settings, [`discovery`] module docs).
    ObjectDrivenDiscovery,
    /// Random reachable views ("random").
    Random,
    /// Boustrophedon coverage ("coverage").
    Coverage,
    /// Only the four-corner initialisation ("init").
    Init,
    /// Expected entropy reduction with ray casting and motion cost ("expected-gain").
    ExpectedGain,
}

impl Strategy {
    /// All strategies, in report order.
    pub const ALL: [Strategy; 6] = [
        Strategy::ObjectDriven,
        Strategy::ObjectDrivenDiscovery,
        Strategy::Random,
        Strategy::Coverage,
        Strategy::Init,
        Strategy::ExpectedGain,
    ];

    /// The report name.
    pub fn as_str(self) -> &'static str {
        match self {
            Strategy::ObjectDriven => "object-driven",
            Strategy::ObjectDrivenDiscovery => "object-driven-discovery",
            Strategy::Random => "random",
            Strategy::Coverage => "coverage",
            Strategy::Init => "init",
            Strategy::ExpectedGain => "expected-gain",
        }
    }

    /// Parse a report name.
    pub fn parse(name: &str) -> Result<Self, ExploreError> {
        Strategy::ALL.iter().copied().find(|s| s.as_str() == name).ok_or_else(|| ExploreError::InvalidConfig {
            field: "strategy",
            reason: format!(
                "unknown strategy {name:?} ({})",
                Strategy::ALL.iter().map(|s| s.as_str()).collect::<Vec<_>>().join(", ")
            ),
        })
    }

    /// Whether the strategy scores candidate views with a utility (object-driven,
    /// object-driven-discovery, expected-gain) rather than generating them.
    pub fn is_utility(self) -> bool {
        matches!(self, Strategy::ObjectDriven | Strategy::ObjectDrivenDiscovery | Strategy::ExpectedGain)
    }

    /// Whether the run's table-discovery settings apply (object-driven-discovery and
    /// expected-gain; the paper's object-driven never looks for the table).
    pub fn uses_discovery(self) -> bool {
        matches!(self, Strategy::ObjectDrivenDiscovery | Strategy::ExpectedGain)
    }

    /// Which cells make up H in the utility: all of the object's for the paper's object-driven,
    /// the run's `configured` scope otherwise.
    pub fn entropy_scope(self, configured: EntropyScope) -> EntropyScope {
        if self == Strategy::ObjectDriven {
            EntropyScope::Object
        } else {
            configured
        }
    }
}

/// Utility, s(x) and stopping settings.
#[derive(Debug, Clone, PartialEq)]
pub struct ExploreConfig {
    /// Grid and sensor model.
    pub grid: GridConfig,
    /// λ, weight of H_IoU + H_V. Paper: 0.2.
    pub lambda: f64,
    /// s(x) = 0 needs H̄_obj below this (bits per cell) or R_o above `done_occupied_ratio`.
    /// Paper: 0.5.
    pub done_normalized_entropy: f64,
    /// s(x) = 0 needs R_o above this or H̄ below `done_normalized_entropy`. Paper: 0.5.
    pub done_occupied_ratio: f64,
    /// s(x) = 0 also needs p(V̄) above this. Paper: 0.8.
    pub done_volume_probability: f64,
    /// Maximum number of views (decision steps). Paper: 10.
    pub max_views: usize,
    /// Estimates needed before p(V̄) is computed (fewer: p = 0, not converged). At least 2 makes
    /// "converged" mean "stable over views".
    pub min_history_len: usize,
    /// Floor of the standard deviation of normalised volumes (relative): volume changes within
    /// a few percent count as converged.
    pub volume_sigma_floor: f64,
    /// R_IoU definition.
    pub iou_mode: IouMode,
    /// H scope in the object-driven utility.
    pub entropy_scope: EntropyScope,
    /// expected-gain: bits of utility lost per metre of camera travel (μ). At the default, a
    /// 0.5 m move costs about as much as seeing 14 unknown cells.
    pub motion_cost_bits_per_m: f64,
    /// expected-gain: measurements of each visible cell expected from one view (k ≥ 1; the move
    /// to a view streams several frames).
    pub expected_measurements: u32,
    /// expected-gain: metres of travel equivalent to one radian of camera rotation (ρ).
    pub motion_cost_m_per_rad: f64,
    /// Table discovery term and stopping extension (beyond the paper; off = weight 0, the core
    /// default; [`discovery`] module docs).
    pub discovery: DiscoveryConfig,
}

impl Default for ExploreConfig {
    fn default() -> Self {
        Self {
            grid: GridConfig::default(),
            lambda: 0.2,
            done_normalized_entropy: 0.5,
            done_occupied_ratio: 0.5,
            done_volume_probability: 0.8,
            max_views: 10,
            min_history_len: 2,
            volume_sigma_floor: 0.05,
            iou_mode: IouMode::default(),
            entropy_scope: EntropyScope::default(),
            motion_cost_bits_per_m: 20.0,
            expected_measurements: 3,
            motion_cost_m_per_rad: 0.1,
            discovery: DiscoveryConfig::default(),
        }
    }
}

impl ExploreConfig {
    /// Check every field's range.
    pub fn validate(&self) -> Result<(), ExploreError> {
        self.grid.validate()?;
        check_range("lambda", self.lambda, 0.0, 1e6)?;
        check_range("done_normalized_entropy", self.done_normalized_entropy, 0.0, 1.0)?;
        check_range("done_occupied_ratio", self.done_occupied_ratio, 0.0, 1.0)?;
        check_range("done_volume_probability", self.done_volume_probability, 0.0, 1.0)?;
        check_range("volume_sigma_floor", self.volume_sigma_floor, 1e-9, 1e3)?;
        check_range("motion_cost_bits_per_m", self.motion_cost_bits_per_m, 0.0, 1e9)?;
        check_range("motion_cost_m_per_rad", self.motion_cost_m_per_rad, 0.0, 1e3)?;
        self.discovery.validate()
    }
}

/// Largest table side, metres ([`TableRect::size_m`]): the grids over the table are sized from
/// it, so it is capped before anything is allocated (the scene files allow at most 3 m).
pub const MAX_TABLE_SIDE_M: f64 = 10.0;
/// Largest absolute table-centre coordinate, metres.
pub const MAX_TABLE_CENTER_M: f64 = 100.0;

/// The table top: a rectangle in the plane z = `height_m` (scene files' `[table]`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TableRect {
    /// Centre (x, y), metres; within ±[`MAX_TABLE_CENTER_M`].
    pub center_m: [f64; 2],
    /// Extent (x, y), metres; each side in (0, [`MAX_TABLE_SIDE_M`]].
    pub size_m: [f64; 2],
    /// Table-top height (world z), metres; 0 in the testbed.
    pub height_m: f64,
}

impl TableRect {
    /// Check the values are finite, the sides in (0, [`MAX_TABLE_SIDE_M`]] and the centre and
    /// height within ±[`MAX_TABLE_CENTER_M`].
    pub fn validate(&self) -> Result<(), ExploreError> {
        if self.center_m.iter().chain(self.size_m.iter()).any(|v| !v.is_finite()) || !self.height_m.is_finite() {
            return Err(ExploreError::NonFinite { field: "table" });
        }
        if self.size_m.iter().any(|v| !(*v > 0.0 && *v <= MAX_TABLE_SIDE_M)) {
            return Err(ExploreError::InvalidConfig {
                field: "table.size",
                reason: format!("{:?} m: each side must be in (0, {MAX_TABLE_SIDE_M}] m", self.size_m),
            });
        }
        if self.center_m.iter().chain([&self.height_m]).any(|v| v.abs() > MAX_TABLE_CENTER_M) {
            return Err(ExploreError::InvalidConfig {
                field: "table.center",
                reason: format!(
                    "centre {:?}, height {} m: must be within ±{MAX_TABLE_CENTER_M} m",
                    self.center_m, self.height_m
                ),
            });
        }
        Ok(())
    }
}

/// Candidate-view and baseline-generator settings.
#[derive(Debug, Clone, PartialEq)]
pub struct CandidateConfig {
    /// Views sampled around each object.
    pub views_per_object: usize,
    /// Camera distance from the object centre, [min, max] metres (a depth camera sees a whole
    /// tabletop object sharply at 0.35–0.6 m).
    pub distance_m: [f64; 2],
    /// Elevation of the camera above the object's horizontal plane, [min, max] degrees.
    pub elevation_deg: [f64; 2],
    /// Minimum camera height above the table, metres.
    pub min_camera_height_m: f64,
    /// Camera positions inside an object primitive inflated by this are rejected, metres.
    pub collision_margin_m: f64,
    /// Init: height of the four corner views above the table, metres.
    pub init_height_m: f64,
    /// Init: corner inset from the table edges, metres.
    pub init_inset_m: f64,
    /// Init: tilt towards the table centre, degrees (0 = straight down, the paper's "top view").
    pub init_tilt_deg: f64,
    /// Coverage: scan height above the table, metres.
    pub coverage_height_m: f64,
    /// Coverage: overlap between neighbouring footprints, [0, 1).
    pub coverage_overlap: f64,
    /// Coverage and random: inset of the scanned/sampled rectangle from the table edges, metres.
    pub coverage_inset_m: f64,
    /// Random: camera height above the table, [min, max] metres.
    pub random_height_m: [f64; 2],
    /// Random: draws allowed per requested view before giving up.
    pub max_attempts_per_view: usize,
}

impl Default for CandidateConfig {
    fn default() -> Self {
        Self {
            views_per_object: 12,
            distance_m: [0.35, 0.6],
            elevation_deg: [45.0, 80.0],
            min_camera_height_m: 0.1,
            collision_margin_m: 0.05,
            init_height_m: 0.5,
            init_inset_m: 0.3,
            init_tilt_deg: 20.0,
            coverage_height_m: 0.45,
            coverage_overlap: 0.3,
            coverage_inset_m: 0.15,
            random_height_m: [0.3, 0.6],
            max_attempts_per_view: 50,
        }
    }
}

impl CandidateConfig {
    /// Check every field's range.
    pub fn validate(&self) -> Result<(), ExploreError> {
        for (f, r, lo, hi) in [
            ("distance_m", self.distance_m, 0.01, 10.0),
            ("elevation_deg", self.elevation_deg, -90.0, 90.0),
            ("random_height_m", self.random_height_m, 0.0, 10.0),
        ] {
            check_range(f, r[0], lo, hi)?;
            check_range(f, r[1], r[0], hi)?;
        }
        check_range("min_camera_height_m", self.min_camera_height_m, -10.0, 10.0)?;
        check_range("collision_margin_m", self.collision_margin_m, 0.0, 1.0)?;
        check_range("init_height_m", self.init_height_m, 0.01, 10.0)?;
        check_range("init_inset_m", self.init_inset_m, 0.0, 10.0)?;
        check_range("init_tilt_deg", self.init_tilt_deg, 0.0, 80.0)?;
        check_range("coverage_height_m", self.coverage_height_m, 0.01, 10.0)?;
        check_range("coverage_overlap", self.coverage_overlap, 0.0, 0.95)?;
        check_range("coverage_inset_m", self.coverage_inset_m, 0.0, 10.0)?;
        if self.views_per_object == 0 {
            return Err(ExploreError::InvalidConfig { field: "views_per_object", reason: "must be ≥ 1".into() });
        }
        Ok(())
    }
}

/// Every map object's surface grid, by object id.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ExplorationGrids {
    /// Grids by object id.
    pub grids: BTreeMap<u32, SurfaceGrid>,
}

/// What one frame did to the grids.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct FrameUpdate {
    /// Per object, in id order.
    pub objects: Vec<ObjectFrameUpdate>,
    /// Objects whose grid was resampled for a new size this frame.
    pub resampled: Vec<u32>,
}

impl ExplorationGrids {
    /// No grids.
    pub fn new() -> Self {
        Self::default()
    }

    /// The grid of an object.
    pub fn get(&self, object_id: u32) -> Option<&SurfaceGrid> {
        self.grids.get(&object_id)
    }

    /// Mean of H̄_obj over all grids (the "mean normalised entropy" curve); `None` without grids.
    pub fn mean_normalized_entropy(&self) -> Option<f64> {
        if self.grids.is_empty() {
            return None;
        }
        let sum: f64 = self.grids.values().map(|g| g.stats().normalized_entropy()).sum();
        Some(sum / self.grids.len() as f64)
    }

    /// Follow the map: create all-unknown grids for new objects, drop grids of objects no longer
    /// in the map (merged duplicates), re-anchor the others ([`SurfaceGrid::sync`]). Returns the
    /// ids whose grids were resampled.
    pub fn sync(&mut self, map: &ObjectMap, config: &GridConfig) -> Result<Vec<u32>, ExploreError> {
        config.validate()?;
        self.grids.retain(|id, _| map.get(*id).is_some());
        let mut resampled = Vec::new();
        for o in &map.objects {
            match self.grids.get_mut(&o.id) {
                Some(g) => {
                    if g.sync(o, config)? {
                        resampled.push(o.id);
                    }
                }
                None => {
                    self.grids.insert(o.id, SurfaceGrid::new(o, config)?);
                }
            }
        }
        resampled.sort_unstable();
        Ok(resampled)
    }

    /// Per-frame update: [`Self::sync`] with the map, then update every object's grid from the
    /// frame (camera intrinsics and pose, this frame's observed points per object, optional
    /// depth image of the same camera). Objects of the map without observed points are still
    /// updated (their visible cells become free, or — with depth — occupied where the depth
    /// matches).
    pub fn integrate_frame(
        &mut self,
        map: &ObjectMap,
        camera: &PinholeCamera,
        world_from_camera: &Se3,
        observed: &[ObservedPoints],
        depth: Option<&DepthImage>,
        config: &GridConfig,
    ) -> Result<FrameUpdate, ExploreError> {
        camera.validate()?;
        visibility::check_pose(world_from_camera, "world_from_camera")?;
        if let Some(d) = depth {
            if d.width != camera.width || d.height != camera.height {
                return Err(ExploreError::Degenerate {
                    what: format!("depth {}x{} vs camera {}x{}", d.width, d.height, camera.width, camera.height),
                });
            }
        }
        let mut points: BTreeMap<u32, Vec<Point3<f64>>> = BTreeMap::new();
        for ob in observed {
            if map.get(ob.object_id).is_none() {
                return Err(ExploreError::UnknownObject { object_id: ob.object_id });
            }
            points.entry(ob.object_id).or_default().extend(ob.points_in_world.iter().copied());
        }
        let resampled = self.sync(map, config)?;
        let occluders = Occluders::from_map(map, config);
        let mut objects = Vec::with_capacity(map.objects.len());
        let mut ordered: Vec<&crate::map::MapObject> = map.objects.iter().collect();
        ordered.sort_by_key(|o| o.id);
        for o in ordered {
            let Some(grid) = self.grids.get_mut(&o.id) else {
                continue;
            };
            let pts = points.get(&o.id).map_or(&[][..], |v| v.as_slice());
            objects.push(integrate_object(grid, o, pts, camera, world_from_camera, depth, &occluders, config));
        }
        Ok(FrameUpdate { objects, resampled })
    }
}
#[cfg(test)]
mod tests;
