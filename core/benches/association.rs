//! Benchmarks of the association module (criterion ids = report entry names):
//! - `associate_frame_20x10`: one `Associator::associate_frame` call, default config, with 20 map
//!   objects (4 labels, each seen in frames 0–2 with 200 points per sighting) and 10 detections of
//!   200 points each in frame 10 from another viewpoint: a revisit, so M-IoU is not applicable
//!   and the statistical tests decide. Includes the frame's updates and the duplicate check.
//! - `associate_frame_20x10_tracking`: the same in frame 3 (consecutive; M-IoU decides).
//! - `associate_frame_20x10_all_tests`: frame 10 with `evaluate_all_tests = true` (every test on
//!   every same-label pair: the worst case).
//! - `mannwhitney_500`: `mann_whitney_u` on 2 × 500 values (copy, sort, rank-sum, p-value). The
//!   values come from SplitMix64 (seed 42): `x_i = 0.45 + 0.1 u`, `y_i = 0.46 + 0.1 u` with
//!   `u = (next >> 11) · 2⁻⁵³`, x drawn first; `experiments/bench/association_refs.py` generates
//!   the identical data for `scipy_mannwhitney_500`.

#![allow(missing_docs)] // criterion_group! generates an undocumented pub fn

use criterion::{criterion_group, criterion_main, BatchSize, Criterion};
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use objslam_core::association::stats::mann_whitney_u;
use objslam_core::association::{AssociationConfig, Associator, Decision, LocalObject};
use objslam_core::frame::Detection;
use objslam_core::geometry::project_geometry;
use objslam_core::geometry::{ObjectGeometry, PinholeCamera, Se3, Shape};
use objslam_core::map::Label;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// SplitMix64, shared with `experiments/bench/association_refs.py`.
struct SplitMix64(u64);

impl SplitMix64 {
    fn next_f64(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^= z >> 31;
        (z >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }
}

/// The Mann-Whitney benchmark data (see the file docs).
fn mw_data() -> (Vec<f64>, Vec<f64>) {
    let mut g = SplitMix64(42);
    let x: Vec<f64> = (0..500).map(|_| 0.45 + 0.1 * g.next_f64()).collect();
    let y: Vec<f64> = (0..500).map(|_| 0.46 + 0.1 * g.next_f64()).collect();
    (x, y)
}

fn camera() -> PinholeCamera {
    PinholeCamera::from_fovy(640, 480, 1.0).unwrap_or_else(|e| panic!("{e}"))
}

fn top_down(x: f64, y: f64, z: f64) -> Se3 {
    let rot = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI);
    Isometry3::from_parts(Translation3::new(x, y, z), rot)
}

const LABELS: [Label; 4] = [Label::Block, Label::Cup, Label::Book, Label::Can];

/// 20 objects on a 5 × 4 grid, 3 cm half-size.
fn centers() -> Vec<Vector3<f64>> {
    let mut v = Vec::new();
    for i in 0..5 {
        for j in 0..4 {
            v.push(Vector3::new(0.3 + 0.1 * f64::from(i), -0.27 + 0.18 * f64::from(j), 0.03));
        }
    }
    v
}

fn local(rng: &mut ChaCha8Rng, k: usize, c: &Vector3<f64>, pose: &Se3) -> LocalObject {
    let half = Vector3::new(0.03, 0.03, 0.03);
    let g = ObjectGeometry { shape: Shape::Cuboid, center: *c, yaw_rad: 0.0, half_extents: half };
    let bbox = project_geometry(&g, &camera(), pose).unwrap_or_else(|| panic!("object {k} not visible"));
    let points = (0..200)
        .map(|_| {
            Point3::from(
                c + Vector3::new(
                    rng.random_range(-0.03..0.03),
                    rng.random_range(-0.03..0.03),
                    rng.random_range(-0.03..0.03),
                ),
            )
        })
        .collect();
    LocalObject { detection: Detection { bbox, label: LABELS[k % 4], score: 0.9 }, points_in_world: points }
}

/// An associator after three frames seeing all 20 objects, and the 10 local objects of the
/// benchmarked frame (every other object), seen from `pose`.
fn setup(config: AssociationConfig, pose: &Se3) -> (Associator, Vec<LocalObject>) {
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let cs = centers();
    let mut a = Associator::new(config).unwrap_or_else(|e| panic!("{e}"));
    for f in 0..3u32 {
        let p = top_down(0.5 + 0.005 * f64::from(f), 0.0, 0.9);
        let locals: Vec<LocalObject> = cs.iter().enumerate().map(|(k, c)| local(&mut rng, k, c, &p)).collect();
        a.associate_frame(f, &camera(), &p, &locals).unwrap_or_else(|e| panic!("{e}"));
    }
    assert_eq!(a.len(), 20, "setup must track 20 objects");
    let locals: Vec<LocalObject> =
        cs.iter().enumerate().filter(|(k, _)| k % 2 == 0).map(|(k, c)| local(&mut rng, k, c, pose)).collect();
    (a, locals)
}

fn bench_association(c: &mut Criterion) {
    let (x, y) = mw_data();
    // Same data as scipy in association_refs.py (it prints U1 = 112444, p = 0.005968492198626155).
    let r = mann_whitney_u(&x, &y, false).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(r.statistic, 112_444.0);
    assert!((r.p_value - 0.005_968_492_198_626_155).abs() < 1e-12, "{}", r.p_value);
    c.bench_function("mannwhitney_500", |b| b.iter(|| mann_whitney_u(std::hint::black_box(&x), &y, false)));

    let all_tests = AssociationConfig { evaluate_all_tests: true, ..AssociationConfig::default() };
    // (id, config, frame index, camera pose): frame 10 after frame 2 is a revisit (M-IoU not
    // applicable, the statistical tests decide); frame 3 is plain tracking (M-IoU decides).
    let cases = [
        ("associate_frame_20x10", AssociationConfig::default(), 10u32, top_down(0.45, 0.03, 0.85)),
        ("associate_frame_20x10_tracking", AssociationConfig::default(), 3, top_down(0.515, 0.0, 0.9)),
        ("associate_frame_20x10_all_tests", all_tests, 10, top_down(0.45, 0.03, 0.85)),
    ];
    for (id, cfg, frame, pose) in cases {
        let (a, locals) = setup(cfg, &pose);
        // Sanity: every detection joins its object.
        let r = a.clone().associate_frame(frame, &camera(), &pose, &locals).unwrap_or_else(|e| panic!("{e}"));
        assert!(
            r.detections.iter().all(|d| matches!(d.decision, Decision::Existing { .. })),
            "{id}: {:?}",
            r.detections
        );
        c.bench_function(id, |b| {
            b.iter_batched(
                || a.clone(),
                |mut a| {
                    let r = a.associate_frame(frame, &camera(), &pose, &locals);
                    (a, r) // dropped outside the timed section
                },
                BatchSize::SmallInput,
            )
        });
    }
}

criterion_group!(benches, bench_association);
criterion_main!(benches);
