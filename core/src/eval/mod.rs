//! Evaluation of an estimated object map against simulator ground truth.
//!
//! Entry points: [`evaluate`] → [`Evaluation`] (per-GT-object rows and the means), driven by
//! [`EvalConfig`].
//! Inputs read from outside are checked by [`ground_truth_from_json`] and [`config_from_json`].
//!
//! Matching: estimates and GT objects are paired by the Hungarian algorithm on centre distance,
//! only within the same class and only closer than [`EvalConfig::max_match_distance_m`]; every GT
//! object gets at most one estimate and vice versa.
//!
//! Metrics (the paper's Table VI, section "Evaluation of Active Mapping"):
//! - `iou3d`: 3D IoU of the yaw-oriented box / cylinder ([`crate::geometry::iou3d`]);
//! - `iou2d`: top-view 2D IoU of the footprints ([`crate::geometry::iou_top`]);
//! - `cde_cm`: centre distance error, centimetres;
//! - `yae_deg`: yaw error, degrees, modulo the shape's symmetry; `None` for cylinders.
//!
//! Means: IoUs average over *all* GT objects, an unmatched GT object counting 0 (a missed object is
//! a mapping failure); CDE averages over matched objects, YAE over matched cuboids. Both choices are
//! stated in [`Means`] so a reader of `metrics.json` knows what was averaged. Beside them:
//! - `cde_all_cm` / `yae_all_deg`: over *all* GT objects (cuboids for yaw), a miss counting as the
//!   worst a match can be ([`MISS_CDE`]: `max_match_distance_m`; [`MISS_YAE`]: the largest yaw
//!   error under the object's symmetry, 90° for a rectangle, 45° for a square);
//! - precision and recall at 3D IoU 0.25 and 0.5: a GT object is found when its matched estimate
//!   overlaps it by at least the threshold; precision divides the found objects by *every* map
//!   object (phantoms, duplicates and poorly placed estimates count against it), recall by every GT
//!   object. `None` when the denominator is 0.
//!
//! [`MISS_CDE`]: EvalConfig::max_match_distance_m
//! [`MISS_YAE`]: miss_yaw_error_deg

mod input;

pub use input::{config_from_json, ground_truth_from_json, EvalError, MAX_MATCH_DISTANCE_M};
use pathfinding::prelude::{kuhn_munkres, Matrix};
use serde::{Deserialize, Serialize};

use crate::geometry::{iou3d, iou_top, yaw_error_deg, ObjectGeometry, Shape};
use crate::map::{Label, ObjectMap};

/// Configuration of the evaluation.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct EvalConfig {
    /// Estimates farther than this from a GT centre are not matched to it (metres). Default 0.10:
    /// about the size of the smallest benchmark objects' footprint; the paper gives no value.
    /// Must be in (0, [`MAX_MATCH_DISTANCE_M`] = 10] m.
    pub max_match_distance_m: f64,
    /// Relative difference of the GT horizontal sides under which a cuboid counts as square, so its
    /// yaw is symmetric under 90° (default 0.05; in [0, 1]).
    pub square_tolerance: f64,
}

impl Default for EvalConfig {
    fn default() -> Self {
        Self { max_match_distance_m: 0.10, square_tolerance: 0.05 }
    }
}

/// A ground-truth object, from the simulator (never seen by the estimator).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct GtObject {
    /// Simulator id.
    pub id: u32,
    /// Class label.
    pub label: Label,
    /// True geometry.
    pub geometry: ObjectGeometry,
}

/// An estimate to evaluate: id, label and geometry (from a map or any other source).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct EstObject {
    /// Estimate id.
    pub id: u32,
    /// Class label.
    pub label: Label,
    /// Estimated geometry.
    pub geometry: ObjectGeometry,
}

/// One GT object's evaluation row.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ObjectScore {
    /// GT id.
    pub gt_id: u32,
    /// GT label.
    pub label: Label,
    /// Matched estimate, if any.
    pub est_id: Option<u32>,
    /// 3D IoU (0 when unmatched).
    pub iou3d: f64,
    /// Top-view 2D IoU (0 when unmatched).
    pub iou2d: f64,
    /// Centre distance error in cm (`None` when unmatched).
    pub cde_cm: Option<f64>,
    /// Yaw error in degrees (`None` when unmatched or for cylinders).
    pub yae_deg: Option<f64>,
}

/// Means over a map (see the module docs for what each averages over).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Means {
    /// Mean 3D IoU over all GT objects.
    pub iou3d: f64,
    /// Mean top-view IoU over all GT objects.
    pub iou2d: f64,
    /// Mean CDE (cm) over matched objects; `None` if none matched.
    pub cde_cm: Option<f64>,
    /// Mean YAE (deg) over matched cuboids; `None` if none.
    pub yae_deg: Option<f64>,
    /// Mean CDE (cm) over all GT objects, a miss counting `max_match_distance_m`; `None` without
    /// GT objects.
    pub cde_all_cm: Option<f64>,
    /// Mean YAE (deg) over all GT cuboids, a miss counting [`miss_yaw_error_deg`]; `None` without
    /// GT cuboids.
    pub yae_all_deg: Option<f64>,
    /// Found GT objects (matched, 3D IoU ≥ 0.25) over all map objects; `None` for an empty map.
    pub precision_iou25: Option<f64>,
    /// Found GT objects (3D IoU ≥ 0.25) over all GT objects; `None` without GT objects.
    pub recall_iou25: Option<f64>,
    /// As `precision_iou25` at 3D IoU ≥ 0.5.
    pub precision_iou50: Option<f64>,
    /// As `recall_iou25` at 3D IoU ≥ 0.5.
    pub recall_iou50: Option<f64>,
}

/// The yaw error a missed cuboid counts in `yae_all_deg`: the largest yaw error under its
/// symmetry (45° when its horizontal sides differ by less than `square_tolerance`, else 90°).
pub fn miss_yaw_error_deg(geometry: &ObjectGeometry, square_tolerance: f64) -> f64 {
    let (a, b) = (geometry.half_extents.x, geometry.half_extents.y);
    if (a - b).abs() <= square_tolerance * a.max(b) {
        45.0
    } else {
        90.0
    }
}

/// The evaluation of one map.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Evaluation {
    /// One row per GT object, in GT order.
    pub objects: Vec<ObjectScore>,
    /// Means.
    pub mean: Means,
    /// Number of GT objects.
    pub n_objects_gt: usize,
    /// Number of estimated objects.
    pub n_objects_est: usize,
    /// Number of matched pairs.
    pub n_matched: usize,
}

/// Estimates from an object map.
pub fn estimates_from_map(map: &ObjectMap) -> Vec<EstObject> {
    map.objects.iter().map(|o| EstObject { id: o.id, label: o.label, geometry: o.geometry() }).collect()
}

const DISTANCE_SCALE: f64 = 1e6; // micrometres: integer weights for the Hungarian solver

/// Match estimates to GT objects (Hungarian on centre distance within class, gated), returning for
/// each GT object the index of its estimate.
pub fn match_to_gt(gt: &[GtObject], est: &[EstObject], config: &EvalConfig) -> Vec<Option<usize>> {
    let n = gt.len().max(est.len());
    if gt.is_empty() || est.is_empty() {
        return vec![None; gt.len()];
    }
    // Weights to maximise: −distance for admissible pairs, a large penalty otherwise.
    let forbidden: i64 = -(10.0 * config.max_match_distance_m * DISTANCE_SCALE) as i64 - 1;
    let mut weights = Matrix::new(n, n, 0i64);
    for (i, g) in gt.iter().enumerate() {
        for (j, e) in est.iter().enumerate() {
            let d = (g.geometry.center - e.geometry.center).norm();
            let admissible = g.label == e.label && d.is_finite() && d <= config.max_match_distance_m;
            weights[(i, j)] = if admissible { -(d * DISTANCE_SCALE).round() as i64 } else { forbidden };
        }
    }
    let (_, assignment) = kuhn_munkres(&weights);
    gt.iter()
        .enumerate()
        .map(|(i, _)| {
            let j = assignment[i];
            (j < est.len() && weights[(i, j)] != forbidden).then_some(j)
        })
        .collect()
}

/// Evaluate estimates against ground truth.
pub fn evaluate(gt: &[GtObject], est: &[EstObject], config: &EvalConfig) -> Evaluation {
    let matches = match_to_gt(gt, est, config);
    let objects: Vec<ObjectScore> = gt
        .iter()
        .zip(&matches)
        .map(|(g, m)| match m {
            Some(j) => {
                let e = &est[*j];
                ObjectScore {
                    gt_id: g.id,
                    label: g.label,
                    est_id: Some(e.id),
                    iou3d: iou3d(&e.geometry, &g.geometry),
                    iou2d: iou_top(&e.geometry, &g.geometry),
                    cde_cm: Some((e.geometry.center - g.geometry.center).norm() * 100.0),
                    yae_deg: yaw_error_deg(&e.geometry, &g.geometry, config.square_tolerance),
                }
            }
            None => ObjectScore {
                gt_id: g.id,
                label: g.label,
                est_id: None,
                iou3d: 0.0,
                iou2d: 0.0,
                cde_cm: None,
                yae_deg: None,
            },
        })
        .collect();
    let mean_of = |v: Vec<f64>| (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64);
    let miss_cde_cm = config.max_match_distance_m * 100.0;
    let yaw_all: Vec<f64> = gt
        .iter()
        .zip(&objects)
        .filter(|(g, _)| g.geometry.shape == Shape::Cuboid)
        .map(|(g, o)| match o.est_id {
            Some(_) => o.yae_deg.unwrap_or(0.0),
            None => miss_yaw_error_deg(&g.geometry, config.square_tolerance),
        })
        .collect();
    let found = |t: f64| objects.iter().filter(|o| o.est_id.is_some() && o.iou3d >= t).count() as f64;
    let ratio = |n: f64, d: usize| (d > 0).then(|| n / d as f64);
    let mean = Means {
        iou3d: mean_of(objects.iter().map(|o| o.iou3d).collect()).unwrap_or(0.0),
        iou2d: mean_of(objects.iter().map(|o| o.iou2d).collect()).unwrap_or(0.0),
        cde_cm: mean_of(objects.iter().filter_map(|o| o.cde_cm).collect()),
        yae_deg: mean_of(objects.iter().filter_map(|o| o.yae_deg).collect()),
        cde_all_cm: mean_of(objects.iter().map(|o| o.cde_cm.unwrap_or(miss_cde_cm)).collect()),
        yae_all_deg: mean_of(yaw_all),
        precision_iou25: ratio(found(0.25), est.len()),
        recall_iou25: ratio(found(0.25), gt.len()),
        precision_iou50: ratio(found(0.5), est.len()),
        recall_iou50: ratio(found(0.5), gt.len()),
    };
    Evaluation {
        n_matched: matches.iter().filter(|m| m.is_some()).count(),
        objects,
        mean,
        n_objects_gt: gt.len(),
        n_objects_est: est.len(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    fn obj(id: u32, label: Label, c: [f64; 3], yaw: f64) -> (GtObject, EstObject) {
        let geometry = ObjectGeometry {
            shape: label.shape(),
            center: Vector3::from(c),
            yaw_rad: yaw,
            half_extents: Vector3::new(0.04, 0.03, 0.05),
        };
        (GtObject { id, label, geometry }, EstObject { id, label, geometry })
    }

    #[test]
    fn perfect_map_scores_one() {
        let (g0, e0) = obj(0, Label::Block, [0.3, 0.0, 0.05], 0.2);
        let (g1, e1) = obj(1, Label::Cup, [0.5, 0.1, 0.05], 0.0);
        let ev = evaluate(&[g0, g1], &[e1, e0], &EvalConfig::default());
        assert_eq!(ev.n_matched, 2);
        assert!((ev.mean.iou3d - 1.0).abs() < 1e-12);
        assert!(ev.mean.cde_cm.unwrap_or(f64::NAN).abs() < 1e-12);
        assert_eq!(ev.objects[0].est_id, Some(0));
        assert_eq!(ev.objects[1].yae_deg, None); // cylinder
        assert_eq!(ev.mean.yae_deg, Some(0.0));
        assert_eq!(Label::Cup.shape(), Shape::Cylinder);
    }

    #[test]
    fn hungarian_prefers_global_optimum_and_respects_class() {
        // Two blocks at x = 0 and x = 0.06; estimates at 0.05 and 0.11. Greedy nearest for GT 1
        // would take the estimate at 0.05 (1 cm) and leave GT 0 at 5 cm; optimum pairs 0↔0.05
        // and 0.06↔0.11 (total 10 cm vs 5 + 5).
        let (g0, _) = obj(0, Label::Block, [0.0, 0.0, 0.0], 0.0);
        let (g1, _) = obj(1, Label::Block, [0.06, 0.0, 0.0], 0.0);
        let (_, e0) = obj(10, Label::Block, [0.05, 0.0, 0.0], 0.0);
        let (_, e1) = obj(11, Label::Block, [0.11, 0.0, 0.0], 0.0);
        let (_, e2) = obj(12, Label::Cup, [0.0, 0.0, 0.0], 0.0);
        let ev = evaluate(&[g0, g1], &[e2, e0, e1], &EvalConfig::default());
        assert_eq!(ev.objects[0].est_id, Some(10));
        assert_eq!(ev.objects[1].est_id, Some(11));
        assert!((ev.mean.cde_cm.unwrap_or(f64::NAN) - 5.0).abs() < 1e-9);
    }

    #[test]
    fn unmatched_gt_counts_zero_in_iou_mean() {
        let (g0, e0) = obj(0, Label::Block, [0.0, 0.0, 0.0], 0.0);
        let (g1, _) = obj(1, Label::Book, [0.5, 0.0, 0.0], 0.0);
        let ev = evaluate(&[g0, g1], &[e0], &EvalConfig::default());
        assert!((ev.mean.iou3d - 0.5).abs() < 1e-12);
        assert_eq!(ev.objects[1].est_id, None);
        assert_eq!(ev.mean.cde_cm, Some(0.0));
        let empty = evaluate(&[g0], &[], &EvalConfig::default());
        assert_eq!(empty.mean.iou3d, 0.0);
        assert_eq!(empty.mean.cde_cm, None);
    }

    #[test]
    fn far_estimate_is_not_matched() {
        let (g0, _) = obj(0, Label::Block, [0.0, 0.0, 0.0], 0.0);
        let (_, e0) = obj(1, Label::Block, [0.5, 0.0, 0.0], 0.0);
        assert_eq!(evaluate(&[g0], &[e0], &EvalConfig::default()).n_matched, 0);
    }

    #[test]
    fn precision_recall_and_all_object_errors_by_hand() {
        // GT: block A at the origin, block B at x = 0.5 (rectangular 8 x 6 cm), cup C at y = 0.5.
        // Map: A exactly (IoU 1); B shifted 2 cm along x (IoU = (8 - 2) / (8 + 2) = 0.6 with equal
        // y and z extents: 0.06·0.06·0.1 over 2·0.08·0.06·0.1 − 0.06·0.06·0.1); a duplicate of A
        // 5 mm off (unmatched: A has its estimate); a phantom block far away. C is missed.
        let (ga, ea) = obj(0, Label::Block, [0.0, 0.0, 0.05], 0.0);
        let (gb, mut eb) = obj(1, Label::Block, [0.5, 0.0, 0.05], 0.0);
        let (gc, _) = obj(2, Label::Cup, [0.0, 0.5, 0.05], 0.0);
        eb.id = 11;
        eb.geometry.center.x += 0.02;
        let (_, mut dup) = obj(12, Label::Block, [0.005, 0.0, 0.05], 0.0);
        dup.id = 12;
        let (_, phantom) = obj(13, Label::Block, [2.0, 2.0, 0.05], 0.0);
        let cfg = EvalConfig::default();
        let ev = evaluate(&[ga, gb, gc], &[ea, eb, dup, phantom], &cfg);
        let iou_b = ev.objects[1].iou3d;
        assert!((iou_b - 0.6).abs() < 1e-9, "IoU {iou_b}");
        let m = ev.mean;
        let close = |a: Option<f64>, b: f64| a.is_some_and(|a| (a - b).abs() < 1e-9);
        // Found at 0.25 and 0.5: A and B (2 of 4 map objects, 2 of 3 GT objects).
        assert!(close(m.precision_iou25, 0.5) && close(m.recall_iou25, 2.0 / 3.0), "{m:?}");
        assert!(close(m.precision_iou50, 0.5) && close(m.recall_iou50, 2.0 / 3.0), "{m:?}");
        // Matched-only CDE: (0 + 2) / 2 cm; all objects: (0 + 2 + 10) / 3 cm (the miss counts 10).
        assert!(close(m.cde_cm, 1.0) && close(m.cde_all_cm, 4.0), "{m:?}");
        // Yaw: cuboids A and B matched at 0°; the cup has no yaw: 0 either way.
        assert!(close(m.yae_deg, 0.0) && close(m.yae_all_deg, 0.0), "{m:?}");
        // Missing B instead: it counts 90° (rectangle); a square block would count 45°.
        let ev = evaluate(&[ga, gb], &[ea], &cfg);
        assert!(close(ev.mean.yae_all_deg, 45.0) && close(ev.mean.yae_deg, 0.0), "{:?}", ev.mean);
        let mut square = ga.geometry;
        square.half_extents.y = square.half_extents.x;
        assert_eq!(miss_yaw_error_deg(&square, cfg.square_tolerance), 45.0);
        // At IoU 0.5 a 0.4-overlap estimate is not found: B shifted 3.43 cm → IoU ≈ 0.4.
        eb.geometry.center.x = 0.5 + 0.08 * (1.0 - 0.4) / 1.4;
        let ev = evaluate(&[ga, gb], &[ea, eb], &cfg);
        assert!((ev.objects[1].iou3d - 0.4).abs() < 1e-9);
        assert!(close(ev.mean.precision_iou25, 1.0) && close(ev.mean.precision_iou50, 0.5), "{:?}", ev.mean);
        // Empty map: precision undefined, recall 0; no GT: recall undefined.
        let empty = evaluate(&[ga], &[], &cfg);
        assert_eq!(empty.mean.precision_iou50, None);
        assert!(close(empty.mean.recall_iou50, 0.0) && close(empty.mean.cde_all_cm, 10.0));
        let no_gt = evaluate(&[], &[ea], &cfg);
        assert!(no_gt.mean.recall_iou25.is_none() && close(no_gt.mean.precision_iou25, 0.0));
    }
}
