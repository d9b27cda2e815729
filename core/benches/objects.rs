//! Benchmarks of the `objects` module. Ids are the report entry names of issue 5:
//! - `iforest_500`: isolation forest (100 trees, ψ = 256) fit + score of 500 points
//!   (`bench_points`, the same splitmix64 stream as `experiments/bench/objects_refs.py`, whose
//!   `sklearn_iforest_500` is scikit-learn's IsolationForest on the same points).
//! - `lsd_640x480`: line segments of `core/tests/fixtures/lsd/frame0.pgm` (reference:
//!   `cv2_lsd_640x480`, OpenCV's LSD on the same frame).
//! - `yaw_align_object`: Alg. 2 line-alignment yaw for one object over 5 frames of segments
//!   (30 samples, the cube re-fitted to 600 points per sample).
//! - `yaw_refine_object` (extra): the joint yaw/scale/centre Levenberg–Marquardt on the same input.

#![allow(missing_docs)] // criterion_group! generates an undocumented `pub fn benches`.

use std::hint::black_box;
use std::path::PathBuf;

use criterion::{criterion_group, criterion_main, Criterion};
use nalgebra::{Point3, Vector3};
use objslam_core::frame::GreyImage;
use objslam_core::geometry::{Box2, PinholeCamera, Se3};
use objslam_core::objects::iforest::{IForestConfig, IsolationForest};
use objslam_core::objects::lsd::LineSegment;
use objslam_core::objects::lsd::{detect_segments, LsdConfig};
use objslam_core::objects::refine::{refine_yaw_scale, RefineConfig};
use objslam_core::objects::yaw::{align_yaw, cuboid, oriented_extent, project_edges, LineFrame, YawConfig};

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
    let mut uniform =
        |lo: f64, hi: f64| lo + (hi - lo) * ((splitmix64(&mut state) >> 11) as f64 * (1.0 / (1u64 << 53) as f64));
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
    let header: Vec<String> =
        String::from_utf8_lossy(&bytes[..20.min(bytes.len())]).split_whitespace().take(3).map(str::to_string).collect();
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

fn look_at(eye: Vector3<f64>, target: Vector3<f64>) -> Se3 {
    objslam_core::geometry::look_at_with_up(&eye.into(), &target.into(), &Vector3::z())
        .unwrap_or_else(|e| panic!("{e}"))
}

/// One object (14 x 7 x 8 cm box, yaw 35°) seen in 5 frames: each projected edge longer than 15 px
/// gives a segment (its middle 80 %), plus 30 % clutter segments; 600 surface points.
fn yaw_inputs() -> (Vec<LineFrame>, Vec<Point3<f64>>) {
    let mut state = 77u64;
    let mut uniform =
        move |lo: f64, hi: f64| lo + (hi - lo) * ((splitmix64(&mut state) >> 11) as f64 * (1.0 / (1u64 << 53) as f64));
    let truth = cuboid(Vector3::new(0.5, 0.1, 0.04), 35f64.to_radians(), Vector3::new(0.07, 0.035, 0.04));
    let camera = PinholeCamera::from_fovy(640, 480, 55f64.to_radians()).unwrap_or_else(|e| panic!("{e}"));
    let eyes = [[0.35, 0.0, 0.45], [0.65, 0.25, 0.40], [0.30, 0.30, 0.35], [0.55, -0.15, 0.45], [0.70, 0.05, 0.35]];
    let mut frames = Vec::new();
    for (i, e) in eyes.iter().enumerate() {
        let pose = look_at(Vector3::new(e[0], e[1], e[2]), truth.center);
        let edges = project_edges(&truth, &camera, &pose);
        let corners: Vec<[f64; 2]> = edges.iter().flat_map(|e| [e.a, e.b]).collect();
        let bbox = Box2::from_points(corners.iter()).unwrap_or_else(|| panic!("no box"));
        let mut segments = Vec::new();
        for e in &edges {
            let p = |t: f64| [e.a[0] + t * (e.b[0] - e.a[0]), e.a[1] + t * (e.b[1] - e.a[1])];
            if (e.b[0] - e.a[0]).hypot(e.b[1] - e.a[1]) >= 15.0 {
                segments.push(LineSegment::new(p(0.1), p(0.9)));
            }
        }
        for _ in 0..(segments.len() * 3 / 7) {
            let m = [uniform(bbox.min[0], bbox.max[0]), uniform(bbox.min[1], bbox.max[1])];
            let a = uniform(0.0, std::f64::consts::PI);
            segments.push(LineSegment::new(
                [m[0] - 10.0 * a.cos(), m[1] - 10.0 * a.sin()],
                [m[0] + 10.0 * a.cos(), m[1] + 10.0 * a.sin()],
            ));
        }
        frames.push(LineFrame { frame: i as u32, camera, world_from_camera: pose, bbox, segments });
    }
    let pose = truth.world_from_object();
    let h = truth.half_extents;
    let points = (0..600)
        .map(|_| {
            let l = Vector3::new(uniform(-h.x, h.x), uniform(-h.y, h.y), h.z);
            pose * Point3::from(l)
        })
        .collect();
    (frames, points)
}

fn bench_yaw(c: &mut Criterion) {
    let (frames, points) = yaw_inputs();
    let config = YawConfig::default();
    let geometry_for_yaw = |yaw: f64| {
        let (center, half) = oriented_extent(&points, yaw).unwrap_or_else(|| panic!("empty"));
        cuboid(center, yaw, half)
    };
    c.bench_function("yaw_align_object", |b| {
        b.iter(|| black_box(align_yaw(black_box(&frames), geometry_for_yaw, &config).map(|a| a.yaw_rad)))
    });
    let initial = align_yaw(&frames, geometry_for_yaw, &config).map(|a| geometry_for_yaw(a.yaw_rad));
    let initial = initial.unwrap_or_else(|| panic!("no alignment"));
    let refine = RefineConfig::default();
    c.bench_function("yaw_refine_object", |b| {
        b.iter(|| black_box(refine_yaw_scale(black_box(&initial), &frames, &points, &refine).map(|r| r.rms_after_px)))
    });
}

criterion_group!(benches, bench_iforest, bench_lsd, bench_yaw);
criterion_main!(benches);
