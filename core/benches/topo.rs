//! Scene-matching speed (paper Table IV sizes): descriptor generation for both maps + matching +
//! pose solve, i.e. one `match_maps` call, for map pairs of 6+4, 10+8 and 14+14 objects.
//!
//! Inputs are generated from fixed seeds: a union layout on a 0.8 × 1.2 m table (labels drawn from
//! all eight classes, sizes from a per-class catalogue ±20 %), about 60 % of the smaller map shared,
//! 1 cm / 5 % noise per map, and a random yaw similarity (scale 1.6) on the query.
//! Run: `cargo bench --bench topo -- --warm-up-time 1 --measurement-time 3`.

// `criterion_group!` generates an undocumented public function.
#![allow(missing_docs)]

use criterion::{criterion_group, criterion_main, Criterion};
use nalgebra::{Similarity3, Translation3, UnitQuaternion, Vector3};
use objslam_core::map::Label;
use objslam_core::topo::{match_maps, MatchConfig, TopoNode};
use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::hint::black_box;

/// Nominal half-extents per class (m).
fn nominal_half(label: Label) -> Vector3<f64> {
    match label {
        Label::Block => Vector3::new(0.025, 0.025, 0.025),
        Label::Book => Vector3::new(0.1, 0.07, 0.015),
        Label::Keyboard => Vector3::new(0.2, 0.065, 0.01),
        Label::Cup => Vector3::new(0.04, 0.04, 0.05),
        Label::Can => Vector3::new(0.033, 0.033, 0.06),
        Label::Bottle => Vector3::new(0.035, 0.035, 0.11),
        Label::Bowl => Vector3::new(0.08, 0.08, 0.03),
        Label::Ball => Vector3::new(0.035, 0.035, 0.035),
    }
}

fn pair(n_prior: usize, n_query: usize, seed: u64) -> (Vec<TopoNode>, Vec<TopoNode>) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let shared = (0.6 * n_prior.min(n_query) as f64).ceil() as usize;
    let union = n_prior + n_query - shared;
    let mut objects: Vec<TopoNode> = Vec::new();
    while objects.len() < union {
        let label = Label::ALL[rng.random_range(0..Label::ALL.len())];
        let half = nominal_half(label).map(|e| e * rng.random_range(0.8..1.2));
        let center = Vector3::new(rng.random_range(0.15..0.85), rng.random_range(-0.55..0.55), half.z);
        if objects.iter().all(|o| (o.center.xy() - center.xy()).norm() > 0.1) {
            objects.push(TopoNode { label, center, yaw_rad: rng.random_range(-1.5..1.5), half_extents: half });
        }
    }
    objects.shuffle(&mut rng);
    let truth = Similarity3::from_parts(
        Translation3::new(0.3, -0.8, 0.1),
        UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 1.1),
        1.6,
    );
    let mut noisy = |n: &TopoNode| TopoNode {
        center: n.center
            + Vector3::new(
                rng.random_range(-0.017..0.017),
                rng.random_range(-0.017..0.017),
                rng.random_range(-0.017..0.017),
            ),
        half_extents: n.half_extents.map(|e| e * rng.random_range(0.92..1.08)),
        ..*n
    };
    let prior: Vec<TopoNode> = objects[..n_prior].iter().map(&mut noisy).collect();
    let query: Vec<TopoNode> = objects[n_prior - shared..union]
        .iter()
        .map(|n| {
            let m = noisy(n);
            TopoNode {
                center: truth.transform_point(&m.center.into()).coords,
                half_extents: m.half_extents * 1.6,
                yaw_rad: m.yaw_rad + 1.1,
                ..m
            }
        })
        .collect();
    (prior, query)
}

fn bench_match(c: &mut Criterion) {
    let config = MatchConfig::default();
    for (name, np, nq) in [("match_6_4", 6, 4), ("match_10_8", 10, 8), ("match_14_14", 14, 14)] {
        let (prior, query) = pair(np, nq, 7);
        assert!(match_maps(&prior, &query, &config).as_match().is_some(), "{name}: bench input must match");
        c.bench_function(name, |b| b.iter(|| match_maps(black_box(&prior), black_box(&query), black_box(&config))));
    }
}

criterion_group!(benches, bench_match);
criterion_main!(benches);
