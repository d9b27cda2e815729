//! Benchmarks of the explore module. `utility_100x12` is the speed bar (≤ 50 ms): build
//! the utility context and score 100 candidate views on a map of 12 objects with partly observed
//! grids (object-driven utility). Also: the same with `expected-gain` (ray casting per cell) and
//! one per-frame grid update of all 12 objects, and the discovery gain (unseen table cells in
//! view, ray cast against the 12 objects) of the same 100 views with the whole table unseen (its
//! worst case: 2400 cells of 2 cm).

#![allow(missing_docs)] // criterion_group! generates undocumented items.

use criterion::{criterion_group, criterion_main, Criterion};
use nalgebra::{Point3, Vector3};
use objslam_core::explore::{
    init_views, sample_candidates, visible_unknown_cells, AlwaysReachable, CandidateConfig, ExplorationGrids,
    ExploreConfig, HistoryBook, Occluders, Strategy, TableCoverage, TableRect, UtilityContext,
};
use objslam_core::geometry::{se3_from_yaw, PinholeCamera, Se3};
use objslam_core::map::{EstimateStage, Label, MapObject, ObjectMap};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Twelve objects of mixed classes on a 3 × 4 lattice over x ∈ [0.3, 0.7], y ∈ [−0.35, 0.35] with
/// seeded jitter, yaw and size (seed 12).
fn twelve_objects() -> ObjectMap {
    let mut rng = ChaCha8Rng::seed_from_u64(12);
    let mut map = ObjectMap::new();
    for i in 0..12 {
        let label = Label::ALL[i % Label::ALL.len()];
        let (gx, gy) = ((i % 3) as f64, (i / 3) as f64);
        let half = match label {
            Label::Keyboard => Vector3::new(0.12, 0.05, 0.015),
            Label::Book => Vector3::new(0.08, 0.06, 0.02),
            Label::Bowl => Vector3::new(0.06, 0.06, 0.03),
            Label::Bottle => Vector3::new(0.035, 0.035, 0.1),
            _ => Vector3::new(0.03 + 0.02 * rng.random::<f64>(), 0.03 + 0.02 * rng.random::<f64>(), 0.04),
        };
        let c = Vector3::new(
            0.3 + 0.2 * gx + rng.random_range(-0.02..0.02),
            -0.35 + 0.233 * gy + rng.random_range(-0.02..0.02),
            half.z,
        );
        map.insert(MapObject {
            id: 0,
            label,
            world_from_object: se3_from_yaw(c, rng.random_range(-1.5..1.5)),
            half_extents: half,
            observations: Vec::new(),
            points_in_world: Vec::new(),
            stage: EstimateStage::Raw,
        });
    }
    map
}

fn setup() -> (ObjectMap, ExplorationGrids, PinholeCamera, ExploreConfig, Vec<Se3>) {
    let map = twelve_objects();
    let camera = PinholeCamera::from_fovy(640, 480, 1.0).unwrap_or_else(|e| panic!("{e}"));
    let cfg = ExploreConfig::default();
    let table = TableRect { center_m: [0.5, 0.0], size_m: [0.8, 1.2], height_m: 0.0 };
    let mut grids = ExplorationGrids::new();
    for v in init_views(&table, &CandidateConfig::default()).unwrap_or_else(|e| panic!("{e}")) {
        grids.integrate_frame(&map, &camera, &v, &[], None, &cfg.grid).unwrap_or_else(|e| panic!("{e}"));
    }
    let cands = sample_candidates(&map, &CandidateConfig::default(), &cfg.grid, &AlwaysReachable, 1)
        .unwrap_or_else(|e| panic!("{e}"));
    let views: Vec<Se3> = cands.iter().take(100).map(|c| c.world_from_camera).collect();
    assert_eq!(views.len(), 100, "need 100 candidates");
    (map, grids, camera, cfg, views)
}

fn bench(c: &mut Criterion) {
    let (map, grids, camera, cfg, views) = setup();
    let hist = HistoryBook::default();
    c.bench_function("utility_100x12", |b| {
        b.iter(|| {
            let ctx = UtilityContext::new(&map, &grids, &hist, &camera, &cfg).unwrap_or_else(|e| panic!("{e}"));
            ctx.score_all(&views, Strategy::ObjectDriven, None).unwrap_or_else(|e| panic!("{e}"))
        })
    });
    c.bench_function("utility_expected_gain_100x12", |b| {
        b.iter(|| {
            let ctx = UtilityContext::new(&map, &grids, &hist, &camera, &cfg).unwrap_or_else(|e| panic!("{e}"));
            ctx.score_all(&views, Strategy::ExpectedGain, Some(&views[0])).unwrap_or_else(|e| panic!("{e}"))
        })
    });
    let eye = Point3::new(0.5, 0.0, 0.5);
    let pose = objslam_core::geometry::look_at(&eye, &Point3::new(0.5, 0.0, 0.0)).unwrap_or_else(|e| panic!("{e}"));
    let table = TableRect { center_m: [0.5, 0.0], size_m: [0.8, 1.2], height_m: 0.0 };
    let coverage = TableCoverage::new(&table, &cfg.discovery).unwrap_or_else(|e| panic!("{e}"));
    c.bench_function("discovery_100x12", |b| {
        b.iter(|| {
            let occ = Occluders::from_map(&map, &cfg.grid);
            let unknown = coverage.unknown_cells(&occ);
            views
                .iter()
                .map(|v| visible_unknown_cells(&unknown, &camera, v, &occ, &cfg.grid, &cfg.discovery))
                .sum::<usize>()
        })
    });
    c.bench_function("grid_integrate_frame_12", |b| {
        b.iter(|| {
            let mut g = grids.clone();
            g.integrate_frame(&map, &camera, &pose, &[], None, &cfg.grid).unwrap_or_else(|e| panic!("{e}"))
        })
    });
}

criterion_group!(benches, bench);
criterion_main!(benches);
