//! Association quality from simulator ground-truth ids (evaluation only: never fed back into the
//! [`super::Associator`]).
//!
//! Input: for each map object, the ground-truth id of each of its observations (`None` for a
//! detection of nothing: false positive or background); [`observation_gt_ids`] builds it from the
//! associator and a (frame, detection index) → GT id lookup (the simulator's per-detection GT
//! ids). The same function measures point purity when given one GT id per point instead (e.g.
//! the GT object whose geometry contains each point of [`super::GlobalObject::points_in_world`]).
//!
//! Definitions ([`association_metrics`]):
//! - **majority GT** of a map object: its most frequent non-`None` id (ties → lower id); its
//!   **share** = count of that id / number of all its entries (including `None`). An object with
//!   no non-`None` entry has no majority and share 0.
//! - `n_objects_est`: map objects with at least [`MetricsConfig::min_entries`] entries;
//!   `n_objects_gt`: given by the caller (objects in the scene). Only counted objects enter the
//!   other metrics.
//! - `fragmented`: number of GT objects that are the majority GT of two or more map objects
//!   (split into duplicates).
//! - `merged`: number of map objects holding at least two different GT ids each with share ≥
//!   [`MetricsConfig::merge_share`] (one map object covering several real ones).
//! - `purity`: mean share over counted map objects (1 = every object is one GT object only);
//!   `None` when no object is counted.
//! - `missed`: GT ids (from `gt_ids`) that are the majority of no map object.

use std::collections::{BTreeMap, BTreeSet};

use serde::{Deserialize, Serialize};

/// Options of [`association_metrics`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MetricsConfig {
    /// A GT id with at least this share of a map object's entries counts as covered by it for
    /// `merged` (default 0.2).
    pub merge_share: f64,
    /// Map objects with fewer entries are not counted (default 1: every object).
    pub min_entries: usize,
}

impl Default for MetricsConfig {
    fn default() -> Self {
        Self { merge_share: 0.2, min_entries: 1 }
    }
}

/// One map object's ground-truth ids (one per observation, or per point).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct ObjectGtIds {
    /// Map object id.
    pub object_id: u32,
    /// GT id of each entry; `None` = no GT object (false positive, background point).
    pub gt_ids: Vec<Option<u32>>,
}

/// The association metrics (`metrics.json` → `"association"`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AssociationMetrics {
    /// Map objects counted.
    pub n_objects_est: usize,
    /// GT objects in the scene.
    pub n_objects_gt: usize,
    /// GT objects that are the majority of ≥ 2 map objects.
    pub fragmented: usize,
    /// Map objects covering ≥ 2 GT objects above the share threshold.
    pub merged: usize,
    /// Mean majority share (`None` with no counted object).
    pub purity: Option<f64>,
    /// GT ids of `gt_ids` that are the majority of no map object, sorted.
    pub missed: Vec<u32>,
}

/// The GT ids of every map object's observations, given a lookup from (frame index, detection
/// index within that frame) to the GT id of that detection (`None` for a false positive). Objects
/// by increasing id, observations in the associator's order.
pub fn observation_gt_ids(
    associator: &super::Associator,
    gt_of_detection: impl Fn(u32, usize) -> Option<u32>,
) -> Vec<ObjectGtIds> {
    associator
        .objects()
        .map(|o| ObjectGtIds {
            object_id: o.id(),
            gt_ids: o.observations().iter().map(|r| gt_of_detection(r.observation.frame, r.detection_index)).collect(),
        })
        .collect()
}

/// Majority id and its share among all entries (see module docs).
pub fn majority(gt_ids: &[Option<u32>]) -> (Option<u32>, f64) {
    let mut counts: BTreeMap<u32, usize> = BTreeMap::new();
    for id in gt_ids.iter().flatten() {
        *counts.entry(*id).or_insert(0) += 1;
    }
    let mut best: Option<(u32, usize)> = None;
    for (id, c) in counts {
        // BTreeMap iterates ids ascending, so `>` keeps the lower id on ties.
        if best.is_none_or(|(_, bc)| c > bc) {
            best = Some((id, c));
        }
    }
    match best {
        Some((id, c)) if !gt_ids.is_empty() => (Some(id), c as f64 / gt_ids.len() as f64),
        _ => (None, 0.0),
    }
}

/// Compute the metrics (definitions in the module docs). `gt_ids` lists every GT object of the
/// scene; `n_objects_gt = gt_ids.len()` after deduplication.
pub fn association_metrics(objects: &[ObjectGtIds], gt_ids: &[u32], config: &MetricsConfig) -> AssociationMetrics {
    let gt: BTreeSet<u32> = gt_ids.iter().copied().collect();
    let counted: Vec<&ObjectGtIds> = objects.iter().filter(|o| o.gt_ids.len() >= config.min_entries.max(1)).collect();
    let mut majority_count: BTreeMap<u32, usize> = BTreeMap::new();
    let mut share_sum = 0.0;
    let mut merged = 0;
    for o in &counted {
        let (maj, share) = majority(&o.gt_ids);
        share_sum += share;
        if let Some(m) = maj {
            *majority_count.entry(m).or_insert(0) += 1;
        }
        let mut per: BTreeMap<u32, usize> = BTreeMap::new();
        for id in o.gt_ids.iter().flatten() {
            *per.entry(*id).or_insert(0) += 1;
        }
        let n = o.gt_ids.len() as f64;
        let covered = per.values().filter(|c| **c as f64 / n >= config.merge_share).count();
        if covered >= 2 {
            merged += 1;
        }
    }
    AssociationMetrics {
        n_objects_est: counted.len(),
        n_objects_gt: gt.len(),
        fragmented: majority_count.values().filter(|c| **c >= 2).count(),
        merged,
        purity: (!counted.is_empty()).then(|| share_sum / counted.len() as f64),
        missed: gt.iter().copied().filter(|id| !majority_count.contains_key(id)).collect(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn obj(object_id: u32, ids: &[Option<u32>]) -> ObjectGtIds {
        ObjectGtIds { object_id, gt_ids: ids.to_vec() }
    }

    #[test]
    fn perfect_map() {
        let objects = vec![obj(0, &[Some(1), Some(1)]), obj(1, &[Some(2)]), obj(2, &[Some(3); 5])];
        let m = association_metrics(&objects, &[1, 2, 3], &MetricsConfig::default());
        assert_eq!(
            m,
            AssociationMetrics {
                n_objects_est: 3,
                n_objects_gt: 3,
                fragmented: 0,
                merged: 0,
                purity: Some(1.0),
                missed: vec![]
            }
        );
    }

    #[test]
    fn fragments_merges_purity_and_misses() {
        // GT 1 split over objects 0 and 1; object 2 covers GT 2 (60 %) and GT 3 (40 %);
        // object 3 is a false positive; GT 4 is never seen.
        let objects = vec![
            obj(0, &[Some(1), Some(1), Some(1), None]),
            obj(1, &[Some(1)]),
            obj(2, &[Some(2), Some(2), Some(2), Some(3), Some(3)]),
            obj(3, &[None, None]),
        ];
        let m = association_metrics(&objects, &[1, 2, 3, 4, 4], &MetricsConfig::default());
        assert_eq!(m.n_objects_est, 4);
        assert_eq!(m.n_objects_gt, 4);
        assert_eq!(m.fragmented, 1);
        assert_eq!(m.merged, 1);
        let purity = m.purity.unwrap_or(f64::NAN);
        assert!((purity - (0.75 + 1.0 + 0.6 + 0.0) / 4.0).abs() < 1e-12, "{purity}");
        assert_eq!(m.missed, vec![3, 4]);
        // A stricter share threshold no longer calls object 2 merged.
        let strict = association_metrics(&objects, &[1, 2, 3, 4], &MetricsConfig { merge_share: 0.5, min_entries: 1 });
        assert_eq!(strict.merged, 0);
        // Objects with fewer than 2 entries are not counted.
        let counted = association_metrics(&objects, &[1, 2, 3, 4], &MetricsConfig { merge_share: 0.2, min_entries: 2 });
        assert_eq!(counted.n_objects_est, 3);
        assert_eq!(counted.fragmented, 0);
    }

    #[test]
    fn empty_inputs_are_defined() {
        let m = association_metrics(&[], &[], &MetricsConfig::default());
        assert_eq!(m.n_objects_est, 0);
        assert_eq!(m.purity, None);
        let m = association_metrics(&[obj(0, &[])], &[7], &MetricsConfig::default());
        assert_eq!(m.n_objects_est, 0);
        assert_eq!(m.missed, vec![7]);
        assert_eq!(majority(&[]), (None, 0.0));
        assert_eq!(majority(&[Some(5), Some(2), Some(5), Some(2)]), (Some(2), 0.5));
    }
}
