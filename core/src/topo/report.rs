//! A match of two object maps as the Python API reports it: object ids instead of indices, the
//! transform as matrices, a failed match as a record with its reason (`matched` false).

use nalgebra::Similarity3;
use serde::Serialize;

use super::{MatchResult, MatchStats, TopoError};
use crate::geometry::rows;
use crate::map::ObjectMap;

impl TopoError {
    /// A short, stable name of this no-match reason (`too_few_objects`, `no_candidates`, …).
    pub fn kind(&self) -> &'static str {
        match self {
            TopoError::EmptyMap { .. } => "empty_map",
            TopoError::TooFewObjects { .. } => "too_few_objects",
            TopoError::NonFinite { .. } => "non_finite",
            TopoError::NoCandidates => "no_candidates",
            TopoError::NoConsistentSample { .. } => "no_consistent_sample",
            TopoError::TooFewInliers { .. } => "too_few_inliers",
        }
    }
}

/// The fields of a [`MatchReport`] that are numeric arrays, for bindings that return them as
/// arrays.
pub const ARRAY_FIELDS: [&str; 3] = ["rotation", "translation", "matrix"];

/// Which way a [`MatchReport`] states the transform.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ReportDirection {
    /// `query_from_prior` (q = s R p + t), as [`super::match_maps`] finds it.
    QueryFromPrior,
    /// `prior_from_query` (p = s R q + t) and the matched ids: a relocalisation.
    PriorFromQuery,
}

/// The report of one map match (all transform fields None and the lists empty without a match).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct MatchReport {
    /// Whether the maps match.
    pub matched: bool,
    /// Why not (text), without a match.
    pub reason: Option<String>,
    /// Why not ([`TopoError::kind`]), without a match.
    pub reason_kind: Option<&'static str>,
    /// The transform's rotation (3x3, rows).
    pub rotation: Option<[[f64; 3]; 3]>,
    /// The transform's translation.
    pub translation: Option<[f64; 3]>,
    /// The transform's scale.
    pub scale: Option<f64>,
    /// The transform as a 4x4 matrix `[s R | t]` (rows).
    pub matrix: Option<[[f64; 4]; 4]>,
    /// Inlier pairs (prior id, query id, residual in prior units), by prior index.
    pub inliers: Vec<(u32, u32, f64)>,
    /// The paper's best pair per prior object (prior id, query id, descriptor score).
    pub matched_pairs: Vec<(u32, u32, f64)>,
    /// Confidence in [0, 1] (0 without a match).
    pub confidence: f64,
    /// Inliers / objects of the smaller map.
    pub coverage: Option<f64>,
    /// 1 − runner-up excess / best excess.
    pub distinctiveness: Option<f64>,
    /// Fit quality of the inliers in [0, 1].
    pub fit: Option<f64>,
    /// Root-mean-square inlier residual, prior units.
    pub rms_residual: Option<f64>,
    /// Umeyama's least-squares scale on the inliers.
    pub scale_umeyama: Option<f64>,
    /// The paper's scale (mean distance ratio over inlier pairs).
    pub scale_distance_ratio: Option<f64>,
    /// Counters, also on failure.
    pub stats: MatchStats,
    /// Relocalisation only: matched (prior id, query id), sorted.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub matched_ids: Option<Vec<(u32, u32)>>,
}

impl MatchReport {
    /// The report of `result`, the match of `prior` against `query`, stated in `direction`.
    pub fn new(result: &MatchResult, prior: &ObjectMap, query: &ObjectMap, direction: ReportDirection) -> Self {
        let id = |map: &ObjectMap, index: usize| map.objects.get(index).map_or(u32::MAX, |o| o.id);
        let relocalise = direction == ReportDirection::PriorFromQuery;
        let stats = result.stats();
        let m = match result {
            MatchResult::Match(m) => m,
            MatchResult::NoMatch { reason, .. } => return Self::no_match(reason, stats, relocalise),
        };
        let t: Similarity3<f64> = if relocalise { m.prior_from_query() } else { m.query_from_prior };
        let inliers: Vec<(u32, u32, f64)> =
            m.inliers.iter().map(|p| (id(prior, p.prior), id(query, p.query), p.residual)).collect();
        let mut ids: Vec<(u32, u32)> = inliers.iter().map(|&(p, q, _)| (p, q)).collect();
        ids.sort_unstable();
        let v = t.isometry.translation.vector;
        Self {
            matched: true,
            reason: None,
            reason_kind: None,
            rotation: Some(rows(&t.isometry.rotation.to_rotation_matrix().into_inner())),
            translation: Some([v.x, v.y, v.z]),
            scale: Some(t.scaling()),
            matrix: Some(rows(&t.to_homogeneous())),
            inliers,
            matched_pairs: m.best_pairs.iter().map(|p| (id(prior, p.prior), id(query, p.query), p.score)).collect(),
            confidence: m.confidence,
            coverage: Some(m.coverage),
            distinctiveness: Some(m.distinctiveness),
            fit: Some(m.fit),
            rms_residual: Some(m.rms_residual),
            scale_umeyama: Some(m.scale_umeyama),
            scale_distance_ratio: m.scale_distance_ratio,
            stats,
            matched_ids: relocalise.then_some(ids),
        }
    }

    fn no_match(reason: &TopoError, stats: MatchStats, relocalise: bool) -> Self {
        Self {
            matched: false,
            reason: Some(reason.to_string()),
            reason_kind: Some(reason.kind()),
            rotation: None,
            translation: None,
            scale: None,
            matrix: None,
            inliers: Vec::new(),
            matched_pairs: Vec::new(),
            confidence: 0.0,
            coverage: None,
            distinctiveness: None,
            fit: None,
            rms_residual: None,
            scale_umeyama: None,
            scale_distance_ratio: None,
            stats,
            matched_ids: relocalise.then(Vec::new),
        }
    }
}
