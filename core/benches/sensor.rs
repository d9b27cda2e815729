//! RGB-D sensor model cost per frame at 640 × 480 (`objslam_core::sensor::simulate_frame`): the
//! D435-class depth model (shadow scan, grazing, silhouettes, correlated noise, registration) and
//! the colour model (shot + read noise, motion blur of a camera moving 0.3 m/s and 0.5 rad/s over
//! a 15 ms exposure), on a synthetic scene: a table plane 0.5 m away tilted 30°, with a box and a
//! cylinder-like bump standing on it, textured colour. Target: ≤ 5 ms per frame (the model runs
//! on two threads where the machine has two cores).
//! Run: `cargo bench --bench sensor -- --warm-up-time 1 --measurement-time 3`.

// `criterion_group!` generates an undocumented public function.
#![allow(missing_docs)]

use criterion::{criterion_group, criterion_main, Criterion};
use nalgebra::{Matrix4, Rotation3, Vector3};
use objslam_core::sensor::{simulate_frame, Intrinsics, RenderedFrame, SensorConfig, SensorUnit};
use std::hint::black_box;

const W: usize = 640;
const H: usize = 480;

fn scene() -> (Vec<f32>, Vec<f32>, Vec<u8>) {
    let k = Intrinsics { fx: 433.0, fy: 433.0, cx: 320.0, cy: 240.0 };
    let (mut p, mut n, mut rgb) = (vec![0.0f32; 3 * W * H], vec![0.0f32; 3 * W * H], vec![0u8; 3 * W * H]);
    let tilt = 30f64.to_radians();
    // Plane through (0, 0, 0.5) with normal (0, -sin, -cos) (facing the camera, tilted about x).
    let normal = Vector3::new(0.0, -tilt.sin(), -tilt.cos());
    for y in 0..H {
        for x in 0..W {
            let r = Vector3::new((x as f64 + 0.5 - k.cx) / k.fx, (y as f64 + 0.5 - k.cy) / k.fy, 1.0);
            let t_plane = 0.5 * normal.z / r.dot(&normal);
            let in_box = (250..390).contains(&x) && (180..300).contains(&y);
            let in_bump = ((x as f64 - 480.0).powi(2) + (y as f64 - 160.0).powi(2)).sqrt() < 50.0;
            let (t, nv) = if in_box {
                (0.42, Vector3::new(0.0, 0.0, -1.0))
            } else if in_bump {
                (0.40, Vector3::new((x as f64 - 480.0) / 50.0, 0.0, -1.0).normalize())
            } else {
                (t_plane, normal)
            };
            let i = y * W + x;
            for a in 0..3 {
                p[3 * i + a] = (r[a] * t) as f32;
                n[3 * i + a] = nv[a] as f32;
            }
            let checker = ((x / 7 + y / 5) % 2) as u8;
            rgb[3 * i] = 60 + 120 * checker;
            rgb[3 * i + 1] = 90 + (x % 50) as u8;
            rgb[3 * i + 2] = 140 - (y % 60) as u8;
        }
    }
    (p, n, rgb)
}

fn bench(c: &mut Criterion) {
    let cfg = SensorConfig::default();
    let k = Intrinsics { fx: 433.0, fy: 433.0, cx: 320.0, cy: 240.0 };
    let unit = SensorUnit::draw(&cfg, k, 3).unwrap_or_else(|e| panic!("{e}"));
    let (p, n, rgb) = scene();
    let frame = RenderedFrame { width: W, height: H, points_in_camera: &p, normals_in_camera: &n, rgb: &rgb };
    let mut motion = Matrix4::identity();
    let dt = cfg.colour.exposure_s;
    let r = Rotation3::new(Vector3::new(0.0, 0.5 * dt, 0.0));
    motion.fixed_view_mut::<3, 3>(0, 0).copy_from(r.matrix());
    motion[(0, 3)] = 0.3 * dt;
    let mut i = 0u64;
    c.bench_function("sensor_model_640x480", |b| {
        b.iter(|| {
            i += 1;
            black_box(
                simulate_frame(&cfg, &unit, black_box(&frame), Some(&motion), 7, i).unwrap_or_else(|e| panic!("{e}")),
            )
        })
    });
}

criterion_group!(benches, bench);
criterion_main!(benches);
