//! Tests of the matcher: exact recovery, first-iteration stop, noisy partial overlap, bad input.

use nalgebra::{Similarity3, Translation3, UnitQuaternion, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::report::{MatchReport, ReportDirection};
use super::*;
use crate::geometry::se3_from_yaw;
use crate::map::{EstimateStage, Label, MapObject};

/// A random tabletop layout: `n` objects with labels cycling through `labels`, at least 8 cm apart.
fn layout(seed: u64, n: usize, labels: &[Label]) -> Vec<TopoNode> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut nodes: Vec<TopoNode> = Vec::new();
    let mut attempts = 0;
    while nodes.len() < n && attempts < 10_000 {
        attempts += 1;
        let center = Vector3::new(rng.random_range(0.2..0.8), rng.random_range(-0.5..0.5), 0.0);
        if nodes.iter().any(|o| (o.center.xy() - center.xy()).norm() < 0.08) {
            continue;
        }
        let label = labels[nodes.len() % labels.len()];
        let half =
            Vector3::new(rng.random_range(0.02..0.06), rng.random_range(0.02..0.05), rng.random_range(0.02..0.08));
        nodes.push(TopoNode {
            label,
            center: Vector3::new(center.x, center.y, half.z),
            yaw_rad: rng.random_range(-3.0..3.0),
            half_extents: half,
        });
    }
    nodes
}

fn transformed(nodes: &[TopoNode], t: &Similarity3<f64>) -> Vec<TopoNode> {
    nodes
        .iter()
        .map(|n| TopoNode {
            center: t.transform_point(&n.center.into()).coords,
            half_extents: n.half_extents * t.scaling(),
            yaw_rad: n.yaw_rad + t.isometry.rotation.scaled_axis().z,
            ..*n
        })
        .collect()
}

fn noisy(nodes: &[TopoNode], seed: u64, pos_m: f64, size_rel: f64) -> Vec<TopoNode> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    // Sum of three uniforms on [-1, 1]: bounded, roughly Gaussian, unit variance.
    let mut g = move || (0..3).map(|_| rng.random_range(-1.0..1.0)).sum::<f64>();
    nodes
        .iter()
        .map(|n| {
            let center = n.center + Vector3::new(g(), g(), g()) * pos_m;
            let half_extents = Vector3::new(
                n.half_extents.x * (1.0 + size_rel * g()),
                n.half_extents.y * (1.0 + size_rel * g()),
                n.half_extents.z * (1.0 + size_rel * g()),
            );
            TopoNode { center, half_extents, ..*n }
        })
        .collect()
}

const MIXED: [Label; 4] = [Label::Cup, Label::Book, Label::Cup, Label::Block];

fn yaw_transform() -> Similarity3<f64> {
    Similarity3::from_parts(
        Translation3::new(-0.7, 1.3, 0.25),
        UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 2.1),
        1.7,
    )
}

fn expect_match(result: &MatchResult) -> &MapMatch {
    match result {
        MatchResult::Match(m) => m,
        MatchResult::NoMatch { reason, stats } => panic!("no match: {reason} ({stats:?})"),
    }
}

#[test]
fn exact_copy_under_yaw_similarity_is_recovered_to_1e_6() {
    let prior = layout(11, 9, &MIXED);
    let truth = yaw_transform();
    let query = transformed(&prior, &truth);
    let result = match_maps(&prior, &query, &MatchConfig::default());
    let m = expect_match(&result);
    assert!((m.query_from_prior.to_homogeneous() - truth.to_homogeneous()).abs().max() < 1e-6);
    assert!((m.scale() - 1.7).abs() < 1e-6);
    assert!((m.scale_distance_ratio.unwrap_or(0.0) - 1.7).abs() < 1e-6);
    assert_eq!(m.inliers.len(), 9);
    assert!(m.inliers.iter().all(|p| p.prior == p.query));
    assert!(m.rms_residual < 1e-6);
    // Sizes gate only gross mismatches by default, so hypotheses that pair look-alikes of one
    // primitive explain a few objects too and the distinctiveness stays below 1.
    assert!(m.confidence > 0.8, "{}", m.confidence);
}

#[test]
fn exact_copy_under_full_similarity_is_recovered_to_1e_6() {
    let prior = layout(12, 8, &MIXED);
    let truth = Similarity3::from_parts(
        Translation3::new(0.4, -2.0, 1.0),
        UnitQuaternion::from_euler_angles(0.8, -0.5, 2.5),
        0.6,
    );
    let query = transformed(&prior, &truth);
    let config = MatchConfig { model: TransformModel::Similarity3, ..MatchConfig::default() };
    let m = expect_match(&match_maps(&prior, &query, &config)).clone();
    assert!((m.query_from_prior.to_homogeneous() - truth.to_homogeneous()).abs().max() < 1e-6);
    assert_eq!(m.inliers.len(), 8);
    // The paper's scale source gives the same transform on exact data.
    let paper = MatchConfig { scale_source: ScaleSource::DistanceRatio, ..config };
    let mp = expect_match(&match_maps(&prior, &query, &paper)).clone();
    assert!((mp.query_from_prior.to_homogeneous() - truth.to_homogeneous()).abs().max() < 1e-6);
}

#[test]
fn all_distinct_labels_stop_after_the_first_iteration() {
    let prior = layout(13, 8, &Label::ALL);
    let truth = yaw_transform();
    // Query: a noisy subset (6 of 8) of the prior, transformed.
    let subset: Vec<TopoNode> = prior[1..7].to_vec();
    let query = transformed(&noisy(&subset, 5, 0.003, 0.02), &truth);
    // Distinct labels under the paper's exact label comparison (under the default shape comparison,
    // eight labels are two classes).
    let exact = DescriptorConfig { label_match: LabelMatch::Exact, ..DescriptorConfig::default() };
    let config = MatchConfig { descriptor: exact, ..MatchConfig::default() };
    let m = expect_match(&match_maps(&prior, &query, &config)).clone();
    assert_eq!(m.stats.iterations, 1, "{:?}", m.stats);
    assert_eq!(m.inliers.len(), 6);
    assert!(m.inliers.iter().all(|p| p.prior == p.query + 1));
    let angle = m.rotation().angle_to(&truth.isometry.rotation).to_degrees();
    assert!(angle < 2.0, "{angle}");
}

#[test]
fn noisy_partial_overlap_matches_with_distractors() {
    // Seeded envelope: 10 + 8 objects sharing 6, 1 cm-ish noise: rotation < 3°, scale within 3 %.
    let all = layout(21, 12, &MIXED);
    let prior: Vec<TopoNode> = all[0..10].to_vec();
    let query_true: Vec<TopoNode> = all[4..12].to_vec();
    let truth = yaw_transform();
    let prior_noisy = noisy(&prior, 1, 0.006, 0.0);
    let query = transformed(&noisy(&query_true, 2, 0.006, 0.0), &truth);
    let m = expect_match(&match_maps(&prior_noisy, &query, &MatchConfig::default())).clone();
    assert_eq!(m.inliers.len(), 6, "{:?}", m.inliers);
    assert!(m.inliers.iter().all(|p| p.prior == p.query + 4));
    assert!(m.rotation().angle_to(&truth.isometry.rotation).to_degrees() < 3.0);
    assert!((m.scale() / 1.7 - 1.0).abs() < 0.03);
    assert!((m.scale_distance_ratio.unwrap_or(0.0) / 1.7 - 1.0).abs() < 0.05);
    assert!(m.confidence > 0.2 && m.confidence <= 1.0);
}

#[test]
fn empty_single_and_non_finite_maps_are_no_match() {
    let map = layout(3, 5, &MIXED);
    let config = MatchConfig::default();
    let reason = |r: MatchResult| match r {
        MatchResult::NoMatch { reason, .. } => reason,
        MatchResult::Match(m) => panic!("unexpected match {m:?}"),
    };
    assert_eq!(reason(match_maps(&[], &map, &config)), TopoError::EmptyMap { which: MapSide::Prior });
    assert_eq!(reason(match_maps(&map, &[], &config)), TopoError::EmptyMap { which: MapSide::Query });
    assert_eq!(
        reason(match_maps(&map, &map[..1], &config)),
        TopoError::TooFewObjects { which: MapSide::Query, count: 1, required: 3 }
    );
    let mut bad = map.clone();
    bad[2].center.x = f64::NAN;
    assert_eq!(reason(match_maps(&map, &bad, &config)), TopoError::NonFinite { which: MapSide::Query, index: 2 });
    bad[2] = TopoNode { half_extents: Vector3::zeros(), ..map[2] };
    assert_eq!(reason(match_maps(&bad, &map, &config)), TopoError::NonFinite { which: MapSide::Prior, index: 2 });
    // Disjoint label sets: nothing to pair.
    let cups: Vec<TopoNode> = map.iter().map(|n| TopoNode { label: Label::Cup, ..*n }).collect();
    let books: Vec<TopoNode> = map.iter().map(|n| TopoNode { label: Label::Book, ..*n }).collect();
    assert_eq!(reason(match_maps(&cups, &books, &config)), TopoError::NoCandidates);
}

#[test]
fn duplicate_positions_do_not_panic_and_do_not_match() {
    let one = layout(4, 1, &MIXED)[0];
    let stacked = vec![one; 5];
    let truth = yaw_transform();
    for model in [TransformModel::YawSimilarity, TransformModel::Similarity3] {
        let config = MatchConfig { model, ..MatchConfig::default() };
        let result = match_maps(&stacked, &transformed(&stacked, &truth), &config);
        assert!(matches!(result, MatchResult::NoMatch { .. }), "{result:?}");
    }
    // Two duplicates among a regular layout: still matched, no NaN.
    let mut map = layout(5, 7, &MIXED);
    map[3] = TopoNode { center: map[2].center, ..map[3] };
    let m = expect_match(&match_maps(&map, &transformed(&map, &truth), &MatchConfig::default())).clone();
    assert!(m.inliers.len() >= 6);
    assert!(m.confidence.is_finite() && m.rms_residual.is_finite());
}

#[test]
fn symmetric_layout_of_identical_objects_has_zero_confidence() {
    // Four identical cups at the corners of a square: four rotations explain everything equally.
    let cup = |x: f64, y: f64| TopoNode {
        label: Label::Cup,
        center: Vector3::new(x, y, 0.05),
        yaw_rad: 0.0,
        half_extents: Vector3::new(0.04, 0.04, 0.05),
    };
    let square = vec![cup(0.4, -0.1), cup(0.6, -0.1), cup(0.6, 0.1), cup(0.4, 0.1)];
    let query = transformed(&square, &yaw_transform());
    match match_maps(&square, &query, &MatchConfig::default()) {
        MatchResult::Match(m) => {
            assert!(m.confidence < 0.05, "{}", m.confidence);
            assert!(m.stats.runner_up_inliers >= m.inliers.len());
        }
        MatchResult::NoMatch { .. } => {}
    }
    // One label but an asymmetric layout with distinct sizes is not ambiguous.
    let cups: Vec<TopoNode> = layout(6, 6, &[Label::Cup]);
    let m = expect_match(&match_maps(&cups, &transformed(&cups, &yaw_transform()), &MatchConfig::default())).clone();
    assert_eq!(m.inliers.len(), 6);
}

#[test]
fn relocalise_returns_prior_from_query_and_ids() {
    let nodes = layout(7, 6, &MIXED);
    let to_map = |nodes: &[TopoNode], first_id: u32| {
        let mut map = ObjectMap::new();
        map.next_id = first_id;
        for n in nodes {
            map.insert(MapObject {
                id: 0,
                label: n.label,
                world_from_object: se3_from_yaw(n.center, n.yaw_rad),
                half_extents: n.half_extents,
                observations: Vec::new(),
                points_in_world: Vec::new(),
                stage: EstimateStage::Raw,
            });
        }
        map
    };
    let truth = yaw_transform();
    let prior = to_map(&nodes, 0);
    let query = to_map(&transformed(&nodes, &truth), 100);
    let r = relocalise(&prior, &query, &MatchConfig::default()).unwrap();
    assert!((r.prior_from_query.to_homogeneous() - truth.inverse().to_homogeneous()).abs().max() < 1e-6);
    assert_eq!(r.matched_ids, (0..6).map(|i| (i, 100 + i)).collect::<Vec<_>>());
    let err = relocalise(&ObjectMap::new(), &query, &MatchConfig::default());
    assert_eq!(err.err(), Some(TopoError::EmptyMap { which: MapSide::Prior }));

    // The report states the same transform with ids, both ways.
    let result = match_object_maps(&prior, &query, &MatchConfig::default());
    let back = MatchReport::new(&result, &prior, &query, ReportDirection::PriorFromQuery);
    let matrix = nalgebra::Matrix4::from_fn(|i, j| back.matrix.unwrap()[i][j]);
    assert!((matrix - truth.inverse().to_homogeneous()).abs().max() < 1e-6);
    assert_eq!(back.matched_ids, Some(r.matched_ids.clone()));
    let forward = MatchReport::new(&result, &prior, &query, ReportDirection::QueryFromPrior);
    let rotation = nalgebra::Matrix3::from_fn(|i, j| forward.rotation.unwrap()[i][j]);
    assert!((rotation * forward.scale.unwrap() - truth.to_homogeneous().fixed_view::<3, 3>(0, 0)).abs().max() < 1e-6);
    assert_eq!(forward.matched_ids, None);
    assert!(forward.inliers.iter().all(|&(p, q, res)| q == p + 100 && res < 1e-6));
    let json = serde_json::to_value(&forward).unwrap();
    assert_eq!(json["matched"], true);
    assert!(json.get("matched_ids").is_none());

    // No match: a record naming the reason, no transform.
    let none = match_object_maps(&ObjectMap::new(), &query, &MatchConfig::default());
    let report = MatchReport::new(&none, &ObjectMap::new(), &query, ReportDirection::PriorFromQuery);
    assert!(!report.matched && report.matrix.is_none() && report.confidence == 0.0);
    assert_eq!(report.reason_kind, Some("empty_map"));
    assert_eq!(report.matched_ids, Some(Vec::new()));
}

#[test]
fn matching_is_deterministic() {
    let all = layout(31, 12, &MIXED);
    let prior = noisy(&all[0..8], 1, 0.01, 0.0);
    let query = transformed(&noisy(&all[3..12], 2, 0.01, 0.0), &yaw_transform());
    let a = match_maps(&prior, &query, &MatchConfig::default());
    let b = match_maps(&prior, &query, &MatchConfig::default());
    assert_eq!(a, b);
}

#[test]
fn a_cuboid_with_the_wrong_heading_is_not_an_inlier() {
    // Six objects; in the query, the (non-square) book at index 1 is turned by 90°.
    let prior = layout(41, 6, &[Label::Cup, Label::Book, Label::Can, Label::Block]);
    let mut query = transformed(&prior, &yaw_transform());
    query[1].half_extents = Vector3::new(0.08, 0.05, 0.02) * 1.7;
    let mut prior = prior;
    prior[1].half_extents = Vector3::new(0.08, 0.05, 0.02);
    let m = expect_match(&match_maps(&prior, &query, &MatchConfig::default())).clone();
    assert_eq!(m.inliers.len(), 6);
    query[1].yaw_rad += std::f64::consts::FRAC_PI_2;
    let m = expect_match(&match_maps(&prior, &query, &MatchConfig::default())).clone();
    assert_eq!(m.inliers.len(), 5, "{:?}", m.inliers);
    assert!(m.inliers.iter().all(|p| p.prior != 1));
    // Without the yaw cue the heading is ignored.
    let no_yaw = MatchConfig { yaw_cue: false, ..MatchConfig::default() };
    assert_eq!(expect_match(&match_maps(&prior, &query, &no_yaw)).inliers.len(), 6);
}

#[test]
fn swapped_footprint_sides_are_detected_after_the_scale() {
    let node = |x: f64, y: f64| TopoNode {
        label: Label::Book,
        center: Vector3::zeros(),
        yaw_rad: 0.0,
        half_extents: Vector3::new(x, y, 0.02),
    };
    let prior = node(0.08, 0.05);
    // Query long side / scale = 0.05: equal to the prior's short side, 1.6× off its long side.
    assert!(sides_swapped(&prior, &node(0.085, 0.03), 1.7));
    // The same query under scale 1: 0.085 is within 6 % of the long side 0.08.
    assert!(!sides_swapped(&prior, &node(0.085, 0.03), 1.0));
    // Same proportions on both sides: not swapped, whatever the axis order of the query.
    assert!(!sides_swapped(&prior, &node(0.136, 0.085), 1.7));
    assert!(!sides_swapped(&prior, &node(0.085, 0.136), 1.7));
    // The prior seen end-on: its long side 0.05 matches the query's short side 0.05 / 1.
    assert!(sides_swapped(&node(0.05, 0.02), &node(0.08, 0.05), 1.0));
    // Degenerate sides or scale: not swapped.
    assert!(!sides_swapped(&prior, &node(0.0, 0.03), 1.0));
    assert!(!sides_swapped(&prior, &node(0.085, 0.03), f64::NAN));
    assert!(!sides_swapped(&prior, &node(0.085, 0.03), 0.0));
}

#[test]
fn a_cuboid_seen_end_on_keeps_its_pair_when_swapped_sides_are_folded() {
    // The book at index 1 is seen end-on in the query: its long side (0.08) truncated to 0.02 along
    // the view, so the map's long axis is the true short one and its yaw is 90° off.
    let mut prior = layout(41, 6, &[Label::Cup, Label::Book, Label::Can, Label::Block]);
    prior[1].half_extents = Vector3::new(0.08, 0.05, 0.02);
    let truth = yaw_transform();
    let mut query = transformed(&prior, &truth);
    query[1].half_extents = Vector3::new(0.05, 0.03, 0.02) * truth.scaling();
    query[1].yaw_rad += std::f64::consts::FRAC_PI_2;
    let folded = MatchConfig {
        noise: NoiseModel { fold_swapped_sides: true, ..NoiseModel::default() },
        ..MatchConfig::default()
    };
    let m = expect_match(&match_maps(&prior, &query, &folded)).clone();
    assert_eq!(m.inliers.len(), 6, "{:?}", m.inliers);
    let rotation = (m.query_from_prior.isometry.rotation.angle_to(&truth.isometry.rotation)).to_degrees();
    assert!(rotation < 1e-6, "{rotation}");
    // The default (no folding): the end-on book's yaw is 90° off and it is not an inlier.
    let m = expect_match(&match_maps(&prior, &query, &MatchConfig::default())).clone();
    assert_eq!(m.inliers.len(), 5, "{:?}", m.inliers);
    assert!(m.inliers.iter().all(|p| p.prior != 1));
}

#[test]
fn fused_cues_are_exact_on_exact_data_and_sizes_pull_the_scale() {
    let nodes = layout(51, 5, &[Label::Book, Label::Block]);
    let truth = yaw_transform();
    let query = transformed(&nodes, &truth);
    let pairs: Vec<CuePair> = nodes
        .iter()
        .zip(&query)
        .map(|(a, b)| CuePair {
            prior_center: a.center,
            query_center: b.center,
            prior_extents: a.sorted_extents(),
            query_extents: b.sorted_extents(),
            prior_yaw: a.yaw_rad,
            query_yaw: b.yaw_rad,
            yaw_period: Some(std::f64::consts::PI),
        })
        .collect();
    let noise = NoiseModel::default();
    let fused = fuse_cues(&truth, &pairs, &noise, true).expect("degenerate");
    assert!((fused.to_homogeneous() - truth.to_homogeneous()).abs().max() < 1e-9);
    // Sizes all say 10 % larger while positions say 1.7: the fused scale lies strictly between,
    // closer to the cue with the smaller variance.
    let bigger: Vec<CuePair> =
        pairs.iter().map(|c| CuePair { query_extents: c.query_extents.map(|e| e * 1.1), ..*c }).collect();
    let s = fuse_cues(&truth, &bigger, &noise, false).map_or(0.0, |t| t.scaling());
    assert!(s > 1.7 && s < 1.7 * 1.1, "{s}");
    let no_sizes = NoiseModel { size_rel: 0.0, ..noise };
    let s0 = fuse_cues(&truth, &bigger, &no_sizes, false).map_or(0.0, |t| t.scaling());
    assert!((s0 - 1.7).abs() < 1e-9);
}

#[test]
fn odd_inputs_never_panic() {
    // Seeded sweep over degenerate layouts: collinear, coincident, huge/tiny coordinates, one label,
    // zero-height objects, both models. Every result is a NoMatch or a finite match.
    let mut rng = ChaCha8Rng::seed_from_u64(99);
    for case in 0..200 {
        let n = rng.random_range(0..9);
        let scale = [1e-6, 1.0, 1e6][case % 3];
        let nodes: Vec<TopoNode> = (0..n)
            .map(|i| {
                let x = if case % 5 == 0 { 0.3 } else { rng.random_range(0.0..1.0) * scale };
                let y = if case % 7 == 0 { 0.0 } else { rng.random_range(-1.0..1.0) * scale };
                TopoNode {
                    label: if case % 2 == 0 { Label::Cup } else { Label::ALL[i % 8] },
                    center: Vector3::new(x, y, 0.0),
                    yaw_rad: rng.random_range(-4.0..4.0),
                    half_extents: Vector3::new(0.03, 0.03, if case % 11 == 0 { 0.0 } else { 0.05 }) * scale,
                }
            })
            .collect();
        let query = transformed(&nodes, &yaw_transform());
        for model in [TransformModel::YawSimilarity, TransformModel::Similarity3] {
            let config = MatchConfig { model, ..MatchConfig::default() };
            if let MatchResult::Match(m) = match_maps(&nodes, &query, &config) {
                assert!(m.query_from_prior.to_homogeneous().iter().all(|v| v.is_finite()));
                assert!((0.0..=1.0).contains(&m.confidence));
            }
        }
    }
}

#[test]
fn fit_pairs_recovers_the_truth_and_rejects_bad_indices() {
    let prior = layout(61, 6, &MIXED);
    let truth = yaw_transform();
    let query = transformed(&prior, &truth);
    let pairs: Vec<(usize, usize)> = (0..prior.len()).map(|i| (i, i)).collect();
    for scale_source in [ScaleSource::Fused, ScaleSource::Umeyama, ScaleSource::DistanceRatio] {
        let config = MatchConfig { scale_source, ..MatchConfig::default() };
        let fit = fit_pairs(&prior, &query, &pairs, &config).expect("degenerate");
        assert!((fit.query_from_prior.to_homogeneous() - truth.to_homogeneous()).abs().max() < 1e-9);
        assert!((fit.scale_umeyama - 1.7).abs() < 1e-9);
    }
    assert!(fit_pairs(&prior, &query, &[(0, 0), (1, 99)], &MatchConfig::default()).is_none());
    assert!(fit_pairs(&prior, &query, &[(0, 0)], &MatchConfig::default()).is_none());
}

#[test]
fn robust_fuse_is_exact_on_exact_data_and_discounts_a_gross_outlier() {
    let nodes = layout(62, 8, &[Label::Cup, Label::Can]);
    let truth = yaw_transform();
    let mut query = transformed(&nodes, &truth);
    let cues = |query: &[TopoNode]| -> Vec<CuePair> {
        nodes
            .iter()
            .zip(query)
            .map(|(a, b)| CuePair {
                prior_center: a.center,
                query_center: b.center,
                prior_extents: a.sorted_extents(),
                query_extents: b.sorted_extents(),
                prior_yaw: a.yaw_rad,
                query_yaw: b.yaw_rad,
                yaw_period: None,
            })
            .collect()
    };
    let noise = NoiseModel::default();
    for kernel in [RobustKernel::None, RobustKernel::Huber, RobustKernel::Cauchy] {
        let t = robust_fuse(&truth, &cues(&query), &noise, true, kernel, 2.0, 5).expect("none");
        assert!((t.to_homogeneous() - truth.to_homogeneous()).abs().max() < 1e-9, "{kernel:?}");
    }
    // One centre 10 cm (prior units) off: the re-weighted fits land closer to the truth than least
    // squares.
    query[3].center += Vector3::new(0.1, 0.0, 0.0) * truth.scaling();
    let err = |kernel| {
        let t = robust_fuse(&truth, &cues(&query), &noise, false, kernel, 2.0, 10).expect("none");
        (t.isometry.translation.vector - truth.isometry.translation.vector).norm()
    };
    let (ls, huber, cauchy) = (err(RobustKernel::None), err(RobustKernel::Huber), err(RobustKernel::Cauchy));
    assert!(huber < 0.5 * ls && cauchy < 0.5 * ls, "ls {ls} huber {huber} cauchy {cauchy}");
}

#[test]
fn a_partial_config_json_keeps_the_defaults_and_unknown_fields_are_refused() {
    let config: MatchConfig =
        serde_json::from_str(r#"{"inlier_threshold": 0.08, "noise": {"yaw_rad": 0.1}, "robust_kernel": "huber"}"#)
            .unwrap();
    assert_eq!(config.inlier_threshold, 0.08);
    assert_eq!(config.noise.yaw_rad, 0.1);
    assert_eq!(config.noise.position, NoiseModel::default().position);
    assert_eq!(config.robust_kernel, RobustKernel::Huber);
    assert_eq!(config.min_inliers, MatchConfig::default().min_inliers);
    match serde_json::from_str::<MatchConfig>(r#"{"inlier_treshold": 0.08}"#) {
        Ok(_) => panic!("a misspelt field was accepted"),
        Err(err) => assert!(err.to_string().contains("inlier_treshold"), "{err}"),
    }
}

#[test]
fn robust_fuse_discounts_one_badly_estimated_extent() {
    // Exact centres up to 2 mm noise, exact sizes except one object's smallest extent 40 % too
    // large in the query: least squares pulls the scale by the pooled size cue, the robust
    // kernels (which now re-weight size residuals too) keep it near the truth.
    let nodes = layout(63, 8, &[Label::Cup, Label::Book]);
    let truth = yaw_transform();
    let mut query = transformed(&nodes, &truth);
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    for q in query.iter_mut() {
        q.center += Vector3::new(rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0), 0.0) * 0.002;
    }
    let cues: Vec<CuePair> = nodes
        .iter()
        .zip(&query)
        .enumerate()
        .map(|(i, (a, b))| {
            let mut qe = b.sorted_extents();
            if i == 2 {
                qe[0] *= 1.4;
            }
            CuePair {
                prior_center: a.center,
                query_center: b.center,
                prior_extents: a.sorted_extents(),
                query_extents: qe,
                prior_yaw: a.yaw_rad,
                query_yaw: b.yaw_rad,
                yaw_period: None,
            }
        })
        .collect();
    // Sizes trusted to 5 % (the default trusts them to 30 %, and one bad extent then barely moves
    // the scale at all).
    let noise = NoiseModel { size_rel: 0.05, ..NoiseModel::default() };
    let scale_err = |kernel| {
        let t = robust_fuse(&truth, &cues, &noise, false, kernel, 2.0, 10).expect("none");
        (t.scaling() / truth.scaling() - 1.0).abs()
    };
    let (ls, huber, cauchy) =
        (scale_err(RobustKernel::None), scale_err(RobustKernel::Huber), scale_err(RobustKernel::Cauchy));
    assert!(ls > 0.005, "the outlier extent biases least squares: {ls}");
    assert!(huber < 0.5 * ls && cauchy < 0.5 * ls, "ls {ls} huber {huber} cauchy {cauchy}");
}

#[test]
fn look_alike_labels_match_under_the_shape_comparison() {
    // The query's detector called two objects by a look-alike label of the same primitive (book ->
    // block, can -> bottle) and one by a label of another primitive (cup -> block).
    let prior = layout(21, 8, &Label::ALL);
    let truth = yaw_transform();
    let mut query = transformed(&noisy(&prior, 6, 0.003, 0.02), &truth);
    let relabel = |q: &mut Vec<TopoNode>, from: Label, to: Label| {
        if let Some(n) = q.iter_mut().find(|n| n.label == from) {
            n.label = to;
        }
    };
    relabel(&mut query, Label::Book, Label::Block);
    relabel(&mut query, Label::Can, Label::Bottle);
    relabel(&mut query, Label::Cup, Label::Block);
    let shape = expect_match(&match_maps(&prior, &query, &MatchConfig::default())).clone();
    let exact_desc = DescriptorConfig { label_match: LabelMatch::Exact, ..DescriptorConfig::default() };
    let exact = MatchConfig { descriptor: exact_desc, ..MatchConfig::default() };
    let paper = expect_match(&match_maps(&prior, &query, &exact)).clone();
    // Shape comparison: the look-alikes of one primitive are matched, the cup called a block is not.
    assert_eq!(shape.inliers.len(), 7, "{:?}", shape.inliers);
    assert!(shape.inliers.iter().all(|p| p.prior == p.query));
    // Exact comparison: only the five objects with their own label.
    assert_eq!(paper.inliers.len(), 5, "{:?}", paper.inliers);
    for m in [&shape, &paper] {
        let angle = m.rotation().angle_to(&truth.isometry.rotation).to_degrees();
        assert!(angle < 2.0, "{angle}");
    }
}
