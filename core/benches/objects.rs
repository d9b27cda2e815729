//! Benchmarks of the `objects` module. Ids are the report entry names of issue 5:
//! - `iforest_500`: isolation forest (100 trees, ψ = 256) fit + score of 500 points
//!   (`bench_points`, the same splitmix64 stream as `experiments/bench/objects_refs.py`, whose
//!   `sklearn_iforest_500` is scikit-learn's IsolationForest on the same points).
//! - `lsd_640x480`: line segments of `core/tests/fixtures/lsd/frame0.pgm` (reference:
//!   `cv2_lsd_640x480`, OpenCV's LSD on the same frame).
//! - `yaw_align_object`: Alg. 2 line-alignment yaw for one object over 5 frames of segments.

use std::hint::black_box;
use std::path::PathBuf;

use criterion::{criterion_group, criterion_main, Criterion};
use nalgebra::Point3;
use objslam_core::frame::GreyImage;
use objslam_core::objects::iforest::{IForestConfig, IsolationForest};
use objslam_core::objects::lsd::{detect_segments, LsdConfig};

fn splitmix64(state: &mut u64) -> u64 {
    *state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
    let mut z = *state;
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// 400 points uniform in a 10 x 6 x 8 cm box + 100 uniform outliers in a 40 cm cube around it.
fn bench_points(seed: u64) -> Vec<Point3<f64>> {
    let mut state = seed;
    let mut uniform = |lo: f64, hi: f64| lo + (hi - lo) * ((splitmix64(&mut state) >> 11) as f64 * (1.0 / (1u64 << 53) as f64));
    let mut out = Vec::with_capacity(500);
    for _ in 0..400 {
        let (x, y, z) = (uniform(0.45, 0.55), uniform(0.07, 0.13), uniform(0.0, 0.08));
        out.push(Point3::new(x, y, z));
    }
    for _ in 0..100 {
        let (x, y, z) = (uniform(0.3, 0.7), uniform(-0.1, 0.3), uniform(-0.16, 0.24));
        out.push(Point3::new(x, y, z));
    }
    out
}

fn read_pgm(path: &std::path::Path) -> GreyImage {
    let bytes = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let header: Vec<String> = String::from_utf8_lossy(&bytes[..20.min(bytes.len())])
        .split_whitespace()
        .take(3)
        .map(str::to_string)
        .collect();
    let w: u32 = header[1].parse().unwrap_or_else(|e| panic!("{e}"));
    let h: u32 = header[2].parse().unwrap_or_else(|e| panic!("{e}"));
    let n = (w * h) as usize;
    GreyImage::new(w, h, bytes[bytes.len() - n..].to_vec()).unwrap_or_else(|e| panic!("{e}"))
}

fn bench_iforest(c: &mut Criterion) {
    let points = bench_points(2024);
    let config = IForestConfig { passes: 1, ..Default::default() };
    c.bench_function("iforest_500", |b| {
        b.iter(|| {
            let forest = IsolationForest::fit(black_box(&points), &config).unwrap_or_else(|e| panic!("{e}"));
            let s: f64 = points.iter().map(|p| forest.score(p)).sum();
            black_box(s)
        })
    });
}

fn bench_lsd(c: &mut Criterion) {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/lsd/frame0.pgm");
    let image = read_pgm(&path);
    let config = LsdConfig::default();
    c.bench_function("lsd_640x480", |b| {
        b.iter(|| black_box(detect_segments(black_box(&image), &config).unwrap_or_else(|e| panic!("{e}")).len()))
    });
}

criterion_group!(benches, bench_iforest, bench_lsd);
criterion_main!(benches);
