//! The active-mapping session: the brain's side of an exploration episode.
//!
//! It owns the exploration state ([`ExplorationGrids`], [`HistoryBook`], views taken) and decides
//! where the camera goes next; the simulator executes the moves and streams frames. One call per
//! frame, one per decision:
//!
//! - [`ActiveSession::initial_views`]: the Init step every strategy starts with (paper: the four
//!   table corners from a top view; [`explore::init_views`]).
//! - [`ActiveSession::integrate_frame`]: after the object map was updated from a frame, update the
//!   surface grids with that frame's observed points per object and its depth image.
//! - [`ActiveSession::view_done`]: after a view was reached and its frames integrated (records the
//!   estimate history used by H_V and s(x)).
//! - [`ActiveSession::next_view`]: the next camera pose or a stop reason, for the configured
//!   [`Strategy`]:
//!   - `init`: stop after the Init step;
//!   - `coverage`: the Boustrophedon scan views in order (unreachable ones skipped), then stop;
//!   - `random`: one random reachable view per step (seeded by `seed` and the step);
//!   - `object-driven` / `expected-gain`: the paper's stopping rule, candidate views sampled around
//!     the objects still to explore, the utility's argmax among the reachable ones. Beyond the
//!     paper ([`explore::TableCoverage`]): with `discovery_before_stop`, no stop on "all explored"
//!     while a reachable view aimed at unseen table cells would still see
//!     `discovery_min_new_cells` of them; with `discovery_weight` > 0, those views join the
//!     candidates throughout and the discovery gain is added to every candidate's utility; with
//!     `discovery_reserve`, a discovery view replaces the object NBV once the views left are no
//!     more than the discovery views still worth taking.
//!
//! Every strategy stops at `explore.max_views` views after Init (paper: 10), so the comparison is
//! at an equal or smaller view budget ([`ActiveConfig::stop_when_explored`] `= false` makes it
//! equal). Reachability is a callback (the simulator side or the
//! `plan` module's IK decides); candidates that are unreachable are skipped in utility order.

use serde::{Deserialize, Serialize};

use crate::explore::{
    self, coverage_views, discovery_targets, greedy_discovery_views_weighted, random_views, sample_candidates_around,
    sample_candidates_at, stop_reason, visible_unknown_indices, CandidateConfig, CandidateView, EntropyScope,
    ExplorationGrids, ExploreConfig, ExploreError, HistoryBook, ObservedPoints, Occluders, Reachability, StopReason,
    Strategy, TableCoverage, TableRect, UtilityContext,
};
use crate::frame::Frame;
use crate::geometry::{PinholeCamera, Se3};
use crate::map::ObjectMap;
use nalgebra::Point3;

/// Settings of a session. The fields mirror the explore module's configs that a run usually
/// changes; everything else keeps the explore defaults (documented there).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ActiveConfig {
    /// Strategy name: object-driven (the paper's rule) | object-driven-discovery (the project's) |
    /// expected-gain | random | coverage | init.
    pub strategy: Strategy,
    /// Seeds candidate sampling and random views.
    pub seed: u64,
    /// Views after Init, at most (paper: 10).
    pub max_views: usize,
    /// λ of the utility (paper: 0.2).
    pub lambda: f64,
    /// Grid cell size, metres (paper: 1 cm).
    pub cell_m: f64,
    /// Candidate views sampled around each object still to explore.
    pub views_per_object: usize,
    /// Camera distance from the object centre, [min, max] metres.
    pub distance_m: [f64; 2],
    /// Elevation of candidate views, [min, max] degrees.
    pub elevation_deg: [f64; 2],
    /// Init: camera height above the table, metres.
    pub init_height_m: f64,
    /// Init: corner inset from the table edges, metres.
    pub init_inset_m: f64,
    /// Init: tilt towards the table centre, degrees (0 = straight down, the paper's top view).
    pub init_tilt_deg: f64,
    /// Coverage: scan height, metres.
    pub coverage_height_m: f64,
    /// Coverage and random: inset of the scanned rectangle from the table edges, metres.
    pub coverage_inset_m: f64,
    /// s(x): R_o threshold (paper 0.5).
    pub done_occupied_ratio: f64,
    /// s(x): H̄ threshold (paper 0.5).
    pub done_normalized_entropy: f64,
    /// expected-gain: motion cost, bits per metre.
    pub motion_cost_bits_per_m: f64,
    /// object-driven-discovery: the cells that make up H in the utility's (1 − R_o)·H term:
    /// `view_cells` (default; the object's cells the candidate camera sees, "under the predicted
    /// camera view") or `object` (all of them, H_obj of Eq. `eq:obj`). object-driven always uses
    /// `object`, the paper's definition.
    pub entropy_scope: EntropyScope,
    /// object-driven / expected-gain: stop once s(x) = 0 for every object (the paper's rule;
    /// default). `false` keeps choosing views by the same utility with s(x) = 1 for every object
    /// until `max_views` — an equal-budget comparison with random and coverage, which always spend
    /// the budget (stop reason `max_views`).
    pub stop_when_explored: bool,
    /// object-driven-discovery / expected-gain: weight w of the table discovery gain added to every
    /// candidate's utility (beyond the paper; 0 = the paper's utility; `explore::discovery`).
    pub discovery_weight: f64,
    /// object-driven-discovery / expected-gain: look at the unseen table before stopping on "all explored"
    /// (beyond the paper; false = the paper's stopping rule).
    pub discovery_before_stop: bool,
    /// Table coverage cell, metres.
    pub discovery_cell_m: f64,
    /// After every object is done, keep looking while a candidate sees at least this many unseen
    /// table cells.
    pub discovery_min_new_cells: usize,
    /// object-driven-discovery / expected-gain: the budget reserve — take a discovery view when the views
    /// left are no more than the discovery views still worth taking (beyond the paper;
    /// `explore::discovery`).
    pub discovery_reserve: bool,
    /// A table cell counts as seen after returns in this many frames (the map's confirmation
    /// count, `pipeline.min_observations`).
    pub discovery_min_frames: u32,
    /// Image border, fraction of width / height, whose returns do not mark table cells.
    pub discovery_margin_frac: f64,
    /// Truncated detections (within this many pixels of the image edge) do not mark table cells;
    /// 0 = off (`explore::discovery`).
    pub discovery_exclude_truncated_px: f64,
    /// Returns more than this above the table are object evidence and do not mark table cells;
    /// unexplained evidence draws discovery views (`explore::discovery`); 0 = off.
    pub discovery_evidence_height_m: f64,
    /// An unexplained cell counts as this many unseen cells.
    pub discovery_evidence_weight: f64,
    /// Evidence within this distance of a mapped object is explained by it, metres.
    pub discovery_evidence_explained_m: f64,
    /// Views taken for unexplained cells after which they count as plain unseen cells.
    pub discovery_evidence_max_views: usize,
}

impl Default for ActiveConfig {
    fn default() -> Self {
        let e = ExploreConfig::default();
        let c = CandidateConfig::default();
        Self {
            strategy: Strategy::ObjectDriven,
            seed: 0,
            max_views: e.max_views,
            lambda: e.lambda,
            cell_m: e.grid.cell_size_m,
            views_per_object: c.views_per_object,
            distance_m: c.distance_m,
            elevation_deg: c.elevation_deg,
            init_height_m: c.init_height_m,
            init_inset_m: c.init_inset_m,
            init_tilt_deg: c.init_tilt_deg,
            coverage_height_m: c.coverage_height_m,
            coverage_inset_m: c.coverage_inset_m,
            done_occupied_ratio: e.done_occupied_ratio,
            done_normalized_entropy: e.done_normalized_entropy,
            motion_cost_bits_per_m: e.motion_cost_bits_per_m,
            entropy_scope: e.entropy_scope,
            stop_when_explored: true,
            discovery_weight: e.discovery.weight,
            discovery_before_stop: e.discovery.before_stop,
            discovery_cell_m: e.discovery.cell_m,
            discovery_min_new_cells: e.discovery.min_new_cells,
            discovery_reserve: e.discovery.reserve,
            discovery_min_frames: e.discovery.min_frames,
            discovery_margin_frac: e.discovery.margin_frac,
            discovery_exclude_truncated_px: e.discovery.exclude_truncated_px,
            discovery_evidence_height_m: e.discovery.evidence_height_m,
            discovery_evidence_weight: e.discovery.evidence_weight,
            discovery_evidence_explained_m: e.discovery.evidence_explained_m,
            discovery_evidence_max_views: e.discovery.evidence_max_views,
        }
    }
}

/// Mixed into the step seed for the candidates aimed at unseen table cells.
const TABLE_CANDIDATE_SEED: u64 = 0x7AB1_E5EE;

/// What the session decided.
#[derive(Debug, Clone, PartialEq)]
pub enum NextView {
    /// Move the camera here.
    Move {
        /// Target `world_from_camera` (OpenCV axes).
        world_from_camera: Se3,
        /// Its utility (NaN for strategies without one).
        utility: f64,
        /// Every scored candidate (pose, utility, reachable), for recording; empty for baselines.
        candidates: Vec<ScoredCandidate>,
    },
    /// Stop exploring.
    Stop {
        /// Why.
        reason: SessionStop,
    },
}

/// A scored candidate view.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScoredCandidate {
    /// Candidate pose.
    pub world_from_camera: Se3,
    /// Utility.
    pub utility: f64,
    /// Whether the reachability callback accepted it (only asked in utility order until one is).
    pub reachable: Option<bool>,
}

/// What a view would show of the table top not known yet (the discovery extension, beyond the
/// paper; `explore::discovery`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct TableGain {
    /// Weighted count of the cells it would see (unexplained cells weigh
    /// `discovery_evidence_weight` while favoured).
    pub cells: f64,
    /// Whether favoured unexplained cells are among them.
    pub unexplained: bool,
    /// The discovery gain in bits: `cells` × (table cell / object cell)², the term the built-in
    /// strategies add to the utility times `discovery_weight` (times 1 on a table-only step).
    pub bits: f64,
}

/// Why a session stopped.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SessionStop {
    /// Every object's s(x) = 0 (paper's rule).
    AllExplored,
    /// The view budget is spent.
    MaxViews,
    /// The strategy has no more views (init, end of the coverage scan).
    StrategyDone,
    /// No candidate view was reachable.
    NoReachableView,
}

impl From<StopReason> for SessionStop {
    fn from(r: StopReason) -> Self {
        match r {
            StopReason::AllExplored => SessionStop::AllExplored,
            StopReason::MaxViews => SessionStop::MaxViews,
        }
    }
}

/// The exploration state of one episode.
#[derive(Debug, Clone)]
pub struct ActiveSession {
    config: ActiveConfig,
    strategy: Strategy,
    explore: ExploreConfig,
    candidates: CandidateConfig,
    table: TableRect,
    grids: ExplorationGrids,
    history: HistoryBook,
    views_taken: usize,
    coverage_queue: Option<Vec<Se3>>,
    entropy_curve: Vec<f64>,
    table_coverage: TableCoverage,
    table_curve: Vec<f64>,
    /// Unexplained table cells (object evidence no map object explains) after each view.
    unexplained_curve: Vec<usize>,
    /// Views taken that saw unexplained object evidence (`explore::discovery`).
    evidence_views: usize,
}

impl ActiveSession {
    /// A session for a table; validates the config.
    pub fn new(config: ActiveConfig, table: TableRect) -> Result<Self, ExploreError> {
        let strategy = config.strategy;
        let mut explore =
            ExploreConfig { lambda: config.lambda, max_views: config.max_views, ..ExploreConfig::default() };
        explore.grid.cell_size_m = config.cell_m;
        explore.done_occupied_ratio = config.done_occupied_ratio;
        explore.done_normalized_entropy = config.done_normalized_entropy;
        explore.motion_cost_bits_per_m = config.motion_cost_bits_per_m;
        explore.entropy_scope = config.entropy_scope;
        explore.discovery.weight = config.discovery_weight;
        explore.discovery.before_stop = config.discovery_before_stop;
        explore.discovery.cell_m = config.discovery_cell_m;
        explore.discovery.min_new_cells = config.discovery_min_new_cells;
        explore.discovery.reserve = config.discovery_reserve;
        explore.discovery.min_frames = config.discovery_min_frames;
        explore.discovery.margin_frac = config.discovery_margin_frac;
        explore.discovery.exclude_truncated_px = config.discovery_exclude_truncated_px;
        explore.discovery.evidence_height_m = config.discovery_evidence_height_m;
        explore.discovery.evidence_weight = config.discovery_evidence_weight;
        explore.discovery.evidence_explained_m = config.discovery_evidence_explained_m;
        explore.discovery.evidence_max_views = config.discovery_evidence_max_views;
        explore.validate()?;
        let candidates = CandidateConfig {
            views_per_object: config.views_per_object,
            distance_m: config.distance_m,
            elevation_deg: config.elevation_deg,
            init_height_m: config.init_height_m,
            init_inset_m: config.init_inset_m,
            init_tilt_deg: config.init_tilt_deg,
            coverage_height_m: config.coverage_height_m,
            coverage_inset_m: config.coverage_inset_m,
            ..CandidateConfig::default()
        };
        candidates.validate()?;
        table.validate()?;
        let table_coverage = TableCoverage::new(&table, &explore.discovery)?;
        Ok(Self {
            config,
            strategy,
            explore,
            candidates,
            table,
            grids: ExplorationGrids::new(),
            history: HistoryBook::default(),
            views_taken: 0,
            coverage_queue: None,
            entropy_curve: Vec::new(),
            table_coverage,
            table_curve: Vec::new(),
            unexplained_curve: Vec::new(),
            evidence_views: 0,
        })
    }

    /// The strategy.
    pub fn strategy(&self) -> Strategy {
        self.strategy
    }

    /// Views taken after Init.
    pub fn views_taken(&self) -> usize {
        self.views_taken
    }

    /// The surface grids (for recording).
    pub fn grids(&self) -> &ExplorationGrids {
        &self.grids
    }

    /// Mean normalised entropy H̄ after Init and after each view (the report's entropy curve).
    pub fn entropy_curve(&self) -> &[f64] {
        &self.entropy_curve
    }

    /// Fraction of the table top known (seen, or under a mapped object) after each view, Init
    /// views included (every strategy; `explore::discovery`).
    pub fn table_known_curve(&self) -> &[f64] {
        &self.table_curve
    }

    /// Unexplained table cells (object evidence that no map object explains: an object the depth
    /// shows and the map lacks; `explore::discovery`) after each view, Init views included;
    /// zeros with object evidence off.
    pub fn table_unexplained_curve(&self) -> &[usize] {
        &self.unexplained_curve
    }

    /// Table cells not known yet (neither seen nor under an object of `map`), world points just
    /// above the table top (for recording).
    pub fn table_unknown_cells(&self, map: &ObjectMap) -> Vec<nalgebra::Point3<f64>> {
        self.table_coverage.unknown_cells(&Occluders::from_map(map, &self.explore.grid))
    }

    /// [`Self::table_unknown_cells`] with, per cell, whether it is unexplained (for recording).
    pub fn table_unknown_cells_with_evidence(&self, map: &ObjectMap) -> (Vec<nalgebra::Point3<f64>>, Vec<bool>) {
        self.table_coverage.unknown_cells_with_evidence(&Occluders::from_map(map, &self.explore.grid))
    }

    /// The table-top coverage grid (diagnostics: which cells are seen, unexplained).
    pub fn table_coverage(&self) -> &TableCoverage {
        &self.table_coverage
    }

    /// The Init views (four table corners), shared by every strategy.
    pub fn initial_views(&self) -> Result<Vec<Se3>, ExploreError> {
        explore::init_views(&self.table, &self.candidates)
    }

    /// Update the grids from a frame (after the map was updated from it).
    pub fn integrate_frame(
        &mut self,
        map: &ObjectMap,
        frame: &Frame,
        observed: &[ObservedPoints],
    ) -> Result<(), ExploreError> {
        let truncated = explore::truncated_boxes(
            frame.detections.iter().map(|d| d.bbox),
            frame.camera.width,
            frame.camera.height,
            self.explore.discovery.exclude_truncated_px,
        );
        self.table_coverage.integrate_depth_excluding(
            &frame.camera,
            &frame.world_from_camera,
            &frame.depth,
            &truncated,
            &self.explore.discovery,
        )?;
        self.grids
            .integrate_frame(
                map,
                &frame.camera,
                &frame.world_from_camera,
                observed,
                Some(&frame.depth),
                &self.explore.grid,
            )
            .map(|_| ())
    }

    /// Call when a view has been reached and its frames integrated; `counts_as_view` is false for
    /// the Init views (they do not use the budget).
    pub fn view_done(&mut self, map: &ObjectMap, counts_as_view: bool) {
        self.history.record(map);
        let (unknown, unexplained) =
            self.table_coverage.unknown_cells_with_evidence(&Occluders::from_map(map, &self.explore.grid));
        let cells = self.table_coverage.len().max(1) as f64;
        self.table_curve.push(1.0 - unknown.len() as f64 / cells);
        self.unexplained_curve.push(unexplained.iter().filter(|&&u| u).count());
        if counts_as_view {
            self.views_taken += 1;
        }
    }

    /// Record the current mean normalised entropy on the curve (call after Init and each view).
    pub fn mark_entropy(&mut self) {
        self.entropy_curve.push(self.grids.mean_normalized_entropy().unwrap_or(1.0));
    }

    /// Decide the next view (see the module docs). `step_seed` mixes into the seed per step.
    pub fn next_view(
        &mut self,
        map: &ObjectMap,
        camera: &PinholeCamera,
        current: &Se3,
        reachable: &dyn Reachability,
    ) -> Result<NextView, ExploreError> {
        if self.views_taken >= self.explore.max_views {
            return Ok(NextView::Stop { reason: SessionStop::MaxViews });
        }
        let step_seed = self.step_seed();
        match self.strategy {
            Strategy::Init => Ok(NextView::Stop { reason: SessionStop::StrategyDone }),
            Strategy::Coverage => {
                if self.coverage_queue.is_none() {
                    let mut q = coverage_views(&self.table, camera, &self.candidates)?;
                    q.reverse(); // pop() from the end gives scan order
                    self.coverage_queue = Some(q);
                }
                let queue = self.coverage_queue.get_or_insert_with(Vec::new);
                while let Some(pose) = queue.pop() {
                    if reachable.reachable(&pose) {
                        return Ok(NextView::Move {
                            world_from_camera: pose,
                            utility: f64::NAN,
                            candidates: Vec::new(),
                        });
                    }
                }
                Ok(NextView::Stop { reason: SessionStop::StrategyDone })
            }
            Strategy::Random => {
                let views =
                    random_views(&self.table, map, &self.candidates, &self.explore.grid, reachable, 1, step_seed)?;
                Ok(match views.first() {
                    Some(p) => NextView::Move { world_from_camera: *p, utility: f64::NAN, candidates: Vec::new() },
                    None => NextView::Stop { reason: SessionStop::NoReachableView },
                })
            }
            Strategy::ObjectDriven | Strategy::ObjectDrivenDiscovery | Strategy::ExpectedGain => {
                let mut ctx = UtilityContext::new(map, &self.grids, &self.history, camera, &self.explore)?;
                // The paper's object-driven never looks for the table.
                let paper = explore::DiscoveryConfig {
                    weight: 0.0,
                    before_stop: false,
                    reserve: false,
                    ..self.explore.discovery
                };
                let disc = if self.strategy.uses_discovery() { &self.explore.discovery } else { &paper };
                let occluders = Occluders::from_map(map, &self.explore.grid);
                let (mut unknown, mut weights) =
                    if disc.enabled() { self.weighted_unknown(&occluders) } else { (Vec::new(), Vec::new()) };
                let min_new = disc.min_new_cells as f64;
                let mut unknown_weight: f64 = weights.iter().sum();
                if unknown_weight < min_new && disc.weight <= 0.0 {
                    unknown.clear();
                    weights.clear();
                    unknown_weight = 0.0;
                }
                // With `before_stop`, "every object done" still looks at the unseen table first.
                let mut table_only = false;
                match stop_reason(&ctx.features(), self.views_taken, &self.explore) {
                    Some(StopReason::AllExplored) if !self.config.stop_when_explored => ctx.explore_every_object(),
                    Some(StopReason::AllExplored) if disc.before_stop && unknown_weight >= min_new => {
                        table_only = true;
                    }
                    Some(r) => return Ok(NextView::Stop { reason: r.into() }),
                    None => {}
                }
                // Candidates aimed at the unseen table (the same for every use below).
                let table_views = if !(table_only || disc.reserve || disc.weight > 0.0) {
                    Vec::new()
                } else {
                    self.table_views_at(map, &unknown, &weights, step_seed)?
                };
                // The budget reserve: the table's share of the views left, taken last.
                if !table_only && disc.reserve && unknown_weight >= min_new {
                    let left = self.explore.max_views - self.views_taken;
                    let needed =
                        self.greedy_table_views(camera, &occluders, &unknown, &weights, &table_views, left, reachable);
                    table_only = needed >= left;
                }
                if !table_only && disc.weight <= 0.0 {
                    unknown.clear(); // the paper's candidates and utility until every object is done
                    weights.clear();
                }
                let features = ctx.features();
                let around: Vec<u32> = features.iter().filter(|f| f.explore).map(|f| f.object_id).collect();
                // The argmax rule over reachable views: sample without the reachability filter,
                // score all, then ask reachability in utility order, so IK runs only for the best.
                let always = |_: &Se3| true;
                let mut views: Vec<CandidateView> = if table_only {
                    Vec::new()
                } else {
                    sample_candidates_around(
                        map,
                        Some(&around),
                        &self.candidates,
                        &self.explore.grid,
                        &always,
                        step_seed,
                    )?
                };
                if !unknown.is_empty() {
                    views.extend(table_views);
                }
                let poses: Vec<Se3> = views.iter().map(|v| v.world_from_camera).collect();
                let scores = ctx.score_all(&poses, self.strategy, Some(current))?;
                // Per candidate: the weighted count of unseen cells it would see, and whether
                // unexplained ones are among them.
                let new_cells: Vec<(f64, bool)> =
                    poses.iter().map(|p| self.table_new_cells(camera, &occluders, &unknown, &weights, p)).collect();
                let weight = if table_only { 1.0 } else { disc.weight };
                let bits_per_cell = weight * self.table_coverage.bits_per_cell(self.explore.grid.cell_size_m);
                let mut scored: Vec<ScoredCandidate> = poses
                    .iter()
                    .zip(scores.iter().zip(&new_cells))
                    .map(|(p, (s, n))| ScoredCandidate {
                        world_from_camera: *p,
                        utility: s.utility + bits_per_cell * n.0,
                        reachable: None,
                    })
                    .collect();
                let mut order: Vec<usize> = (0..scored.len())
                    .filter(|i| scored[*i].utility.is_finite() && (!table_only || new_cells[*i].0 >= min_new))
                    .collect();
                order.sort_by(|a, b| scored[*b].utility.total_cmp(&scored[*a].utility).then(a.cmp(b)));
                for i in order {
                    let ok = reachable.reachable(&scored[i].world_from_camera);
                    scored[i].reachable = Some(ok);
                    if ok {
                        let (pose, utility) = (scored[i].world_from_camera, scored[i].utility);
                        self.evidence_views += usize::from(new_cells[i].1);
                        return Ok(NextView::Move { world_from_camera: pose, utility, candidates: scored });
                    }
                }
                Ok(NextView::Stop {
                    reason: if table_only { SessionStop::AllExplored } else { SessionStop::NoReachableView },
                })
            }
        }
    }

    /// The seed of this decision step (the run seed mixed with the number of views taken): the
    /// random strategy's view and every candidate sample of the step draw from it.
    fn step_seed(&self) -> u64 {
        self.config.seed.wrapping_mul(0x9E37_79B9_7F4A_7C15).wrapping_add(self.views_taken as u64 + 1)
    }

    /// The paper's per-object features x = (H_obj, H̄_obj, R_o, R_IoU, V̄_obj, s) of every map
    /// object (map order) at this step, as the utility strategies see them: the decision-step
    /// view for a strategy outside the core (`objslam.strategy`, Python).
    pub fn object_features(
        &self,
        map: &ObjectMap,
        camera: &PinholeCamera,
    ) -> Result<Vec<explore::ObjectFeatures>, ExploreError> {
        Ok(UtilityContext::new(map, &self.grids, &self.history, camera, &self.explore)?.features())
    }

    /// The candidate views the utility strategies would sample at this step around the objects
    /// `around` (`None` = every object): the same sampler, configuration and step seed, no
    /// reachability filter (ask it per view, as the built-in strategies do in utility order).
    pub fn candidate_views(&self, map: &ObjectMap, around: Option<&[u32]>) -> Result<Vec<CandidateView>, ExploreError> {
        let always = |_: &Se3| true;
        sample_candidates_around(map, around, &self.candidates, &self.explore.grid, &always, self.step_seed())
    }

    /// Score views with a utility strategy's utility at this step ([`Strategy::ObjectDriven`]:
    /// the paper's f; [`Strategy::ExpectedGain`]: expected entropy reduction with the occlusion
    /// and pose-convergence terms, minus the motion cost from `current`). Objects whose s(x) = 0
    /// add nothing, as in the built-in strategies; `explore_every_object` counts them all (the
    /// built-in strategies' behaviour once `stop_when_explored` is off). The discovery gain of
    /// unseen table cells is not included.
    pub fn score_views(
        &self,
        map: &ObjectMap,
        camera: &PinholeCamera,
        views: &[Se3],
        strategy: Strategy,
        current: &Se3,
        explore_every_object: bool,
    ) -> Result<Vec<explore::ViewScore>, ExploreError> {
        let mut ctx = UtilityContext::new(map, &self.grids, &self.history, camera, &self.explore)?;
        if explore_every_object {
            ctx.explore_every_object();
        }
        ctx.score_all(views, strategy, Some(current))
    }

    /// Whether the paper's stopping rule ends exploration now: every object's s(x) = 0
    /// ([`StopReason::AllExplored`]) or the view budget is spent ([`StopReason::MaxViews`]).
    pub fn paper_stop(&self, map: &ObjectMap, camera: &PinholeCamera) -> Result<Option<SessionStop>, ExploreError> {
        let features = self.object_features(map, camera)?;
        Ok(stop_reason(&features, self.views_taken, &self.explore).map(SessionStop::from))
    }

    /// The view budget after Init (`explore.max_views`).
    pub fn max_views(&self) -> usize {
        self.explore.max_views
    }

    /// The discovery extension's candidate views at this step (beyond the paper;
    /// `explore::discovery`): sampled at targets among the table cells not known yet, the
    /// unexplained cells' targets first, as the built-in utility strategies sample them (same
    /// configuration and step seed); none when every cell is known. Not filtered by reachability.
    pub fn table_candidate_views(&self, map: &ObjectMap) -> Result<Vec<CandidateView>, ExploreError> {
        let (unknown, weights) = self.weighted_unknown(&Occluders::from_map(map, &self.explore.grid));
        self.table_views_at(map, &unknown, &weights, self.step_seed())
    }

    /// What each view would show of the table not known yet ([`TableGain`]), with the cells
    /// weighted as the built-in strategies weigh them (an unexplained cell counts
    /// `discovery_evidence_weight` until `discovery_evidence_max_views` views were spent on such
    /// cells).
    pub fn table_gain(&self, map: &ObjectMap, camera: &PinholeCamera, views: &[Se3]) -> Vec<TableGain> {
        let occluders = Occluders::from_map(map, &self.explore.grid);
        let (unknown, weights) = self.weighted_unknown(&occluders);
        let bits_per_cell = self.table_coverage.bits_per_cell(self.explore.grid.cell_size_m);
        views
            .iter()
            .map(|p| {
                let (cells, unexplained) = self.table_new_cells(camera, &occluders, &unknown, &weights, p);
                TableGain { cells, unexplained, bits: bits_per_cell * cells }
            })
            .collect()
    }

    /// The weighted count of table cells not known yet (the built-in strategies compare it with
    /// `discovery_min_new_cells`).
    pub fn table_unknown_weight(&self, map: &ObjectMap) -> f64 {
        self.weighted_unknown(&Occluders::from_map(map, &self.explore.grid)).1.iter().sum()
    }

    /// The budget reserve's count: how many of [`Self::table_candidate_views`] a greedy cover
    /// takes, each reachable and revealing at least `discovery_min_new_cells` weighted cells not
    /// revealed by the ones before, at most `limit`. The built-in strategies take a discovery view
    /// once it is no less than the views left.
    pub fn table_views_needed(
        &self,
        map: &ObjectMap,
        camera: &PinholeCamera,
        reachable: &dyn Reachability,
        limit: usize,
    ) -> Result<usize, ExploreError> {
        let occluders = Occluders::from_map(map, &self.explore.grid);
        let (unknown, weights) = self.weighted_unknown(&occluders);
        let views = self.table_views_at(map, &unknown, &weights, self.step_seed())?;
        Ok(self.greedy_table_views(camera, &occluders, &unknown, &weights, &views, limit, reachable))
    }

    /// A strategy outside the core chose `view`: it counts among the views spent on unexplained
    /// evidence when it would see such a cell, as the built-in strategies count their own choices
    /// (call it once per decision, before the move).
    pub fn note_chosen_view(&mut self, map: &ObjectMap, camera: &PinholeCamera, view: &Se3) {
        let occluders = Occluders::from_map(map, &self.explore.grid);
        let (unknown, weights) = self.weighted_unknown(&occluders);
        let (_, unexplained) = self.table_new_cells(camera, &occluders, &unknown, &weights, view);
        self.evidence_views += usize::from(unexplained);
    }

    /// The table cells not known yet and their weights: an unexplained cell stands for
    /// `evidence_weight` unseen cells until the session has spent `evidence_max_views` views on
    /// such cells, every other cell for one.
    fn weighted_unknown(&self, occluders: &Occluders) -> (Vec<Point3<f64>>, Vec<f64>) {
        let disc = &self.explore.discovery;
        let (unknown, evidence) = self.table_coverage.unknown_cells_with_evidence(occluders);
        let favour = disc.evidence_height_m > 0.0 && self.evidence_views < disc.evidence_max_views;
        let weights = evidence.iter().map(|e| if *e && favour { disc.evidence_weight } else { 1.0 }).collect();
        (unknown, weights)
    }

    /// Candidates aimed at `unknown` cells, the favoured (weight > 1) cells' targets first.
    fn table_views_at(
        &self,
        map: &ObjectMap,
        unknown: &[Point3<f64>],
        weights: &[f64],
        step_seed: u64,
    ) -> Result<Vec<CandidateView>, ExploreError> {
        if unknown.is_empty() {
            return Ok(Vec::new());
        }
        let n = self.explore.discovery.targets;
        let favoured: Vec<Point3<f64>> =
            unknown.iter().zip(weights).filter(|(_, w)| **w > 1.0).map(|(p, _)| *p).collect();
        let mut targets = discovery_targets(&favoured, n, step_seed);
        targets.extend(discovery_targets(unknown, n, step_seed));
        let always = |_: &Se3| true;
        sample_candidates_at(
            &targets,
            map,
            &self.candidates,
            &self.explore.grid,
            &always,
            step_seed ^ TABLE_CANDIDATE_SEED,
        )
    }

    /// The indices of the `unknown` cells a camera at `view` would see.
    fn table_seen(
        &self,
        camera: &PinholeCamera,
        occluders: &Occluders,
        unknown: &[Point3<f64>],
        view: &Se3,
    ) -> Vec<usize> {
        if unknown.is_empty() {
            return Vec::new();
        }
        visible_unknown_indices(unknown, camera, view, occluders, &self.explore.grid, &self.explore.discovery)
    }

    /// The weighted count of `unknown` cells a camera at `view` would see, and whether favoured
    /// (unexplained) ones are among them.
    fn table_new_cells(
        &self,
        camera: &PinholeCamera,
        occluders: &Occluders,
        unknown: &[Point3<f64>],
        weights: &[f64],
        view: &Se3,
    ) -> (f64, bool) {
        let idx = self.table_seen(camera, occluders, unknown, view);
        (idx.iter().map(|i| weights[*i]).sum(), idx.iter().any(|i| weights[*i] > 1.0))
    }

    /// The greedy cover of the unseen table by `views` (see [`Self::table_views_needed`]).
    #[allow(clippy::too_many_arguments)]
    fn greedy_table_views(
        &self,
        camera: &PinholeCamera,
        occluders: &Occluders,
        unknown: &[Point3<f64>],
        weights: &[f64],
        views: &[CandidateView],
        limit: usize,
        reachable: &dyn Reachability,
    ) -> usize {
        let seen: Vec<Vec<usize>> =
            views.iter().map(|v| self.table_seen(camera, occluders, unknown, &v.world_from_camera)).collect();
        let min_new = self.explore.discovery.min_new_cells as f64;
        greedy_discovery_views_weighted(&seen, weights, min_new, limit, |i| {
            reachable.reachable(&views[i].world_from_camera)
        })
        .len()
    }
}
