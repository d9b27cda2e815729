//! Per-object features, the paper's utility, the `expected-gain` utility, s(x) and the stopping
//! rule (paper, "Object-Driven Exploration").

use std::collections::BTreeMap;

use nalgebra::{Point3, Vector3};

use super::grid::{binary_entropy_bits, log_odds, plogp_bits, probability_from_log_odds, GridStats};
use super::visibility::{check_pose, point_visibility_cos, CellVisibility, Occluders, Viewpoint};
use super::{EntropyScope, ExplorationGrids, ExploreConfig, ExploreError, IouMode, Strategy};
use crate::geometry::project_geometry;
use crate::geometry::{iou3d, Box2, ObjectGeometry, PinholeCamera, Se3};
use crate::map::ObjectMap;

/// The estimates one object had at past decision steps, oldest first (pipeline input).
///
/// Push the object's current geometry once per view (decision step) — or use
/// [`HistoryBook::record`] for the whole map. Drives H_V (volume convergence) and, in
/// [`IouMode::EstimateHistory`], R_IoU.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ObjectHistory {
    /// Past estimates, oldest first.
    pub estimates: Vec<ObjectGeometry>,
}

impl ObjectHistory {
    /// The volume-convergence probability p(V̄⁽ᵗ⁾) ∈ [0, 1]: the volumes V⁽⁰⁾…V⁽ᵗ⁾ are normalised by
    /// their mean (V̄), a normal distribution is fitted to them (mean 1, standard deviation
    /// σ = max(sample σ, `volume_sigma_floor`)), and p = exp(−z²/2) with z = (V̄⁽ᵗ⁾ − 1)/σ: the
    /// fitted density at the latest volume, rescaled so that its peak is 1 (the raw standard
    /// normal density never exceeds 0.399, so the paper's `p > 0.8` test would never pass).
    /// Fewer than `min_len` estimates (or none with a positive finite volume): 0 (not converged).
    pub fn volume_convergence(&self, min_len: usize, volume_sigma_floor: f64) -> f64 {
        let v: Vec<f64> =
            self.estimates.iter().map(ObjectGeometry::volume).filter(|v| v.is_finite() && *v > 0.0).collect();
        if v.len() < min_len.max(1) {
            return 0.0;
        }
        let mean = v.iter().sum::<f64>() / v.len() as f64;
        let norm: Vec<f64> = v.iter().map(|x| x / mean).collect();
        let var = norm.iter().map(|x| (x - 1.0).powi(2)).sum::<f64>() / norm.len() as f64;
        let sigma = var.sqrt().max(volume_sigma_floor);
        let last = norm.last().copied().unwrap_or(1.0);
        let z = (last - 1.0) / sigma;
        (-0.5 * z * z).exp()
    }

    /// The latest volume normalised by the mean of all, V̄⁽ᵗ⁾ (1 without history).
    pub fn normalized_volume(&self) -> f64 {
        let v: Vec<f64> =
            self.estimates.iter().map(ObjectGeometry::volume).filter(|v| v.is_finite() && *v > 0.0).collect();
        match v.last() {
            Some(last) => last / (v.iter().sum::<f64>() / v.len() as f64),
            None => 1.0,
        }
    }

    /// 3D IoU between the last two estimates (`None` with fewer than two).
    pub fn consecutive_iou(&self) -> Option<f64> {
        let n = self.estimates.len();
        if n < 2 {
            return None;
        }
        Some(iou3d(self.estimates.get(n - 2)?, self.estimates.get(n - 1)?))
    }
}

/// Histories of every object, by id.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct HistoryBook {
    /// Per object id.
    pub objects: BTreeMap<u32, ObjectHistory>,
}

impl HistoryBook {
    /// Append every map object's current geometry to its history (call once per view / decision
    /// step, after the map was updated). Objects no longer in the map are dropped.
    pub fn record(&mut self, map: &ObjectMap) {
        self.objects.retain(|id, _| map.get(*id).is_some());
        for o in &map.objects {
            self.objects.entry(o.id).or_default().estimates.push(o.geometry());
        }
    }
}

/// The paper's per-object feature vector x = (H_obj, H̄_obj, R_o, R_IoU, V̄_obj, s), plus the
/// volume-convergence probability used by H_V and s.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct ObjectFeatures {
    /// Map object id.
    pub object_id: u32,
    /// Grid counts and H_obj.
    pub grid: GridStats,
    /// H_obj, bits.
    pub entropy_bits: f64,
    /// H̄_obj ∈ [0, 1], bits per cell.
    pub normalized_entropy: f64,
    /// R_o, ratio of occupied cells.
    pub occupied_ratio: f64,
    /// R_IoU from the estimate history (3D IoU of the last two estimates), when available; the
    /// view-dependent R_IoU of [`IouMode::ViewOcclusion`] is computed per view in [`ViewScore`].
    pub history_iou: Option<f64>,
    /// V̄_obj⁽ᵗ⁾, latest volume over the mean of the history.
    pub normalized_volume: f64,
    /// p(V̄_obj⁽ᵗ⁾) ∈ [0, 1] (see [`ObjectHistory::volume_convergence`]).
    pub volume_probability: f64,
    /// s: true while the object still needs exploring (the paper's s(x) = 1).
    pub explore: bool,
}

/// The paper's s(x) rule: s = 0 when (H̄ < `done_normalized_entropy` ∨ R_o > `done_occupied_ratio`)
/// ∧ p(V̄) > `done_volume_probability`; returns whether s = 1.
pub fn needs_exploring(
    normalized_entropy: f64,
    occupied_ratio: f64,
    volume_probability: f64,
    config: &ExploreConfig,
) -> bool {
    let complete = normalized_entropy < config.done_normalized_entropy || occupied_ratio > config.done_occupied_ratio;
    !(complete && volume_probability > config.done_volume_probability)
}

/// Features of every map object (map order). Objects without a grid get an all-unknown one's
/// statistics via `grids` (call [`ExplorationGrids::sync`] first); without history, p(V̄) = 0.
pub fn object_features(
    map: &ObjectMap,
    grids: &ExplorationGrids,
    histories: &HistoryBook,
    config: &ExploreConfig,
) -> Vec<ObjectFeatures> {
    map.objects
        .iter()
        .map(|o| {
            let grid = grids.get(o.id).map(|g| g.stats()).unwrap_or_default();
            let hist = histories.objects.get(&o.id);
            let pv = hist.map_or(0.0, |h| h.volume_convergence(config.min_history_len, config.volume_sigma_floor));
            let hn = grid.normalized_entropy();
            let ro = grid.occupied_ratio();
            ObjectFeatures {
                object_id: o.id,
                grid,
                entropy_bits: grid.entropy_bits,
                normalized_entropy: hn,
                occupied_ratio: ro,
                history_iou: hist.and_then(ObjectHistory::consecutive_iou),
                normalized_volume: hist.map_or(1.0, ObjectHistory::normalized_volume),
                volume_probability: pv,
                explore: needs_exploring(hn, ro, pv, config),
            }
        })
        .collect()
}

/// Why exploration stops (paper: all objects done, or the maximum number of views).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StopReason {
    /// s(x) = 0 for every object (and the map is not empty).
    AllExplored,
    /// `views_taken ≥ max_views`.
    MaxViews,
}

/// The stopping rule: `Some(reason)` when exploration should end. An empty map never counts as
/// "all explored" (there is nothing known yet); it stops only on the view budget.
pub fn stop_reason(features: &[ObjectFeatures], views_taken: usize, config: &ExploreConfig) -> Option<StopReason> {
    if views_taken >= config.max_views {
        return Some(StopReason::MaxViews);
    }
    if !features.is_empty() && features.iter().all(|f| !f.explore) {
        return Some(StopReason::AllExplored);
    }
    None
}

/// One object's contribution to a view's utility.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct ObjectViewTerms {
    /// Object id.
    pub object_id: u32,
    /// Entropy part: (1 − R_o)·H (object-driven) or the expected entropy reduction (expected-gain),
    /// bits.
    pub entropy_term: f64,
    /// R_IoU used for this view.
    pub r_iou: f64,
    /// H_IoU = −p log₂ p with p = R_IoU / 2.
    pub h_iou: f64,
    /// H_V = −p log₂ p with p = p(V̄).
    pub h_v: f64,
    /// Cells counted as visible from the view.
    pub visible_cells: usize,
    /// s(x) ∈ {0, 1}.
    pub s: f64,
    /// The object's total contribution.
    pub total: f64,
}

/// A candidate view's utility and its breakdown.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct ViewScore {
    /// The utility f (higher is better).
    pub utility: f64,
    /// Motion cost subtracted (expected-gain only; 0 otherwise).
    pub motion_cost: f64,
    /// Per visible object, in map order.
    pub objects: Vec<ObjectViewTerms>,
}

#[derive(Debug, Clone, Copy)]
struct CellSample {
    p_in_world: Point3<f64>,
    n_in_world: Vector3<f64>,
    entropy_bits: f64,
    expected_gain_bits: f64,
}

#[derive(Debug, Clone)]
struct PreparedObject {
    id: u32,
    geometry: ObjectGeometry,
    features: ObjectFeatures,
    cells: Vec<CellSample>,
    /// Largest distance of a cell centre from `geometry.center`, metres.
    cells_radius_m: f64,
}

/// Everything needed to score many candidate views against one map state; build once per
/// decision step, then call [`UtilityContext::score`] per candidate.
#[derive(Debug, Clone)]
pub struct UtilityContext {
    camera: PinholeCamera,
    config: ExploreConfig,
    objects: Vec<PreparedObject>,
    occluders: Occluders,
}

/// Expected entropy reduction (bits) of a cell at log-odds `l` after k = `expected_measurements`
/// more measurements of it (a view is reached by a move that streams several frames), with the
/// cell's true state drawn from its current belief (P(occupied) = p) and the k measurements all
/// agreeing with it: ΔH = H(p) − [p·H(σ(l + k·L_hit)) + (1 − p)·H(σ(l + k·L_miss))], clamped as
/// the updates are, floored at 0.
pub fn expected_entropy_reduction(l: f64, config: &ExploreConfig) -> f64 {
    let g = &config.grid;
    let k = f64::from(config.expected_measurements.max(1));
    let (lo, hi) = (log_odds(g.p_min), log_odds(g.p_max));
    let p = probability_from_log_odds(l);
    let lh = (l + k * log_odds(g.p_hit)).clamp(lo, hi);
    let lm = (l + k * log_odds(g.p_miss)).clamp(lo, hi);
    let after = p * binary_entropy_bits(probability_from_log_odds(lh))
        + (1.0 - p) * binary_entropy_bits(probability_from_log_odds(lm));
    (binary_entropy_bits(p) - after).max(0.0)
}

impl UtilityContext {
    /// Prepare the map state: features (from grids and histories), every valid cell in the world
    /// frame with its entropy and expected entropy reduction, and the occluders.
    pub fn new(
        map: &ObjectMap,
        grids: &ExplorationGrids,
        histories: &HistoryBook,
        camera: &PinholeCamera,
        config: &ExploreConfig,
    ) -> Result<Self, ExploreError> {
        config.validate()?;
        camera.validate().map_err(ExploreError::Geometry)?;
        let features = object_features(map, grids, histories, config);
        let mut objects = Vec::with_capacity(map.objects.len());
        for (o, f) in map.objects.iter().zip(features) {
            let mut cells = Vec::new();
            if let Some(g) = grids.get(o.id) {
                for c in g.cells() {
                    let Some(pose) = g.cell_pose(c) else { continue };
                    let l = g.log_odds(c);
                    cells.push(CellSample {
                        p_in_world: o.world_from_object * pose.p_in_object,
                        n_in_world: o.world_from_object.rotation * pose.normal_in_object,
                        entropy_bits: binary_entropy_bits(probability_from_log_odds(l)),
                        expected_gain_bits: expected_entropy_reduction(l, config),
                    });
                }
            }
            let geometry = o.geometry();
            let center = Point3::from(geometry.center);
            let cells_radius_m = cells.iter().map(|c| (c.p_in_world - center).norm()).fold(0.0, f64::max);
            objects.push(PreparedObject { id: o.id, geometry, features: f, cells, cells_radius_m });
        }
        Ok(Self { camera: *camera, config: config.clone(), objects, occluders: Occluders::from_map(map, &config.grid) })
    }

    /// The features of every object (map order).
    pub fn features(&self) -> Vec<ObjectFeatures> {
        self.objects.iter().map(|o| o.features).collect()
    }

    /// Count every object as still to explore (s(x) = 1), e.g. to keep refining the map after
    /// the stopping rule would end exploration.
    pub fn explore_every_object(&mut self) {
        for o in &mut self.objects {
            o.features.explore = true;
        }
    }

    /// Score one candidate `world_from_camera` with a utility strategy
    /// ([`Strategy::ObjectDriven`] or [`Strategy::ExpectedGain`]; the view-generator baselines
    /// are scored like object-driven). `current` is the camera pose now (motion cost of
    /// expected-gain; ignored otherwise).
    pub fn score(
        &self,
        world_from_camera: &Se3,
        strategy: Strategy,
        current: Option<&Se3>,
    ) -> Result<ViewScore, ExploreError> {
        check_pose(world_from_camera, "world_from_camera")?;
        let viewpoint = Viewpoint::new(&self.camera, world_from_camera);
        let camera_from_world = viewpoint.camera_from_world;
        let cfg = &self.config;
        let eye = Point3::from(world_from_camera.translation.vector);
        // Visible objects and their projected boxes.
        let mut visible: Vec<(usize, Option<Box2>)> = Vec::new();
        for (i, o) in self.objects.iter().enumerate() {
            let c = camera_from_world * Point3::from(o.geometry.center);
            let dist = (Point3::from(o.geometry.center) - eye).norm();
            let in_view = c.z >= cfg.grid.min_range_m
                && dist <= cfg.grid.max_range_m
                && self.camera.project(&c).is_some_and(|uv| self.camera.contains(uv));
            if in_view {
                visible.push((i, project_geometry(&o.geometry, &self.camera, world_from_camera)));
            }
        }
        let cos_max = cfg.grid.max_incidence_deg.to_radians().cos();
        let mut out = ViewScore { utility: 0.0, motion_cost: 0.0, objects: Vec::with_capacity(visible.len()) };
        for (k, (i, bbox)) in visible.iter().enumerate() {
            let Some(o) = self.objects.get(*i) else {
                continue;
            };
            let f = &o.features;
            let r_iou = match cfg.iou_mode {
                IouMode::ViewOcclusion => {
                    let mut sum = 0.0;
                    let mut n = 0usize;
                    if let Some(b) = bbox {
                        for (k2, (_, other)) in visible.iter().enumerate() {
                            if k2 == k {
                                continue;
                            }
                            let iou = other.map_or(0.0, |ob| b.iou(&ob));
                            if iou > 0.0 {
                                sum += iou;
                                n += 1;
                            }
                        }
                    }
                    if n == 0 {
                        0.0
                    } else {
                        sum / n as f64
                    }
                }
                IouMode::EstimateHistory => f.history_iou.unwrap_or(0.0),
            };
            let h_iou = plogp_bits(r_iou / 2.0);
            let h_v = plogp_bits(f.volume_probability);
            let s = if f.explore { 1.0 } else { 0.0 };
            let mut visible_cells = 0usize;
            let entropy_term = match strategy {
                Strategy::ExpectedGain => {
                    // The occluders that can hide any of this object's cells from the eye.
                    let among = self.occluders.near_segments_to(
                        &eye,
                        &Point3::from(o.geometry.center),
                        o.cells_radius_m + cfg.grid.surface_offset_m.abs(),
                        Some(o.id),
                    );
                    let mut g = 0.0;
                    for c in &o.cells {
                        if c.expected_gain_bits <= 0.0 {
                            continue;
                        }
                        let vis = point_visibility_cos(
                            &c.p_in_world,
                            &c.n_in_world,
                            o.id,
                            &viewpoint,
                            &self.occluders,
                            &cfg.grid,
                            cos_max,
                            Some(&among),
                        );
                        if matches!(vis, CellVisibility::Visible { .. }) {
                            g += c.expected_gain_bits;
                            visible_cells += 1;
                        }
                    }
                    g
                }
                _ => match strategy.entropy_scope(cfg.entropy_scope) {
                    EntropyScope::Object => (1.0 - f.occupied_ratio) * f.entropy_bits,
                    EntropyScope::ViewCells => {
                        let mut h = 0.0;
                        for c in &o.cells {
                            let to_eye = eye - c.p_in_world;
                            let dist = to_eye.norm();
                            if c.n_in_world.dot(&to_eye) < dist * cos_max || dist > cfg.grid.max_range_m {
                                continue;
                            }
                            let pc = camera_from_world * c.p_in_world;
                            if pc.z < cfg.grid.min_range_m {
                                continue;
                            }
                            if self.camera.project(&pc).is_some_and(|uv| self.camera.contains(uv)) {
                                h += c.entropy_bits;
                                visible_cells += 1;
                            }
                        }
                        (1.0 - f.occupied_ratio) * h
                    }
                },
            };
            let total = (entropy_term + cfg.lambda * (h_iou + h_v)) * s;
            out.utility += total;
            out.objects.push(ObjectViewTerms {
                object_id: o.id,
                entropy_term,
                r_iou,
                h_iou,
                h_v,
                visible_cells,
                s,
                total,
            });
        }
        if strategy == Strategy::ExpectedGain {
            if let Some(cur) = current {
                check_pose(cur, "current world_from_camera")?;
                let d = (cur.translation.vector - world_from_camera.translation.vector).norm();
                let angle = cur.rotation.angle_to(&world_from_camera.rotation);
                out.motion_cost = cfg.motion_cost_bits_per_m * (d + cfg.motion_cost_m_per_rad * angle);
                out.utility -= out.motion_cost;
            }
        }
        Ok(out)
    }

    /// Score every candidate; the result is aligned with `views`.
    pub fn score_all(
        &self,
        views: &[Se3],
        strategy: Strategy,
        current: Option<&Se3>,
    ) -> Result<Vec<ViewScore>, ExploreError> {
        views.iter().map(|v| self.score(v, strategy, current)).collect()
    }
}

/// The next best view: index of the highest finite utility (ties → lowest index); `None` when no
/// score is finite.
pub fn next_best_view(scores: &[ViewScore]) -> Option<usize> {
    let mut best: Option<(usize, f64)> = None;
    for (i, s) in scores.iter().enumerate() {
        if !s.utility.is_finite() {
            continue;
        }
        if best.is_none_or(|(_, b)| s.utility > b) {
            best = Some((i, s.utility));
        }
    }
    best.map(|(i, _)| i)
}
