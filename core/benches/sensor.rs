//! RGB-D sensor model cost per frame at 640 × 480 (`objslam_core::sensor::simulate_frame`): the
//! D435-class depth model (shadow scan, grazing, silhouettes, correlated noise, registration) and
//! the colour model (shot + read noise, motion blur over a 15 ms exposure), on
//! `sensor::synthetic::TiltedTable`: a table plane 0.5 m away tilted 30°, with a box and a
//! cylinder-like bump standing on it, textured colour. `sensor_model_640x480`: the camera moving
//! 0.3 m/s and turning 0.5 rad/s (blur along the rows); `sensor_model_640x480_rolling`: the camera
//! rolling about its optical axis as the wrist turns in an episode (every row holds blur in every
//! direction). Target: ≤ 5 ms per frame (the model runs on two threads where the machine has two
//! cores).
//! Run: `cargo bench --bench sensor -- --warm-up-time 1 --measurement-time 3`.

// `criterion_group!` generates an undocumented public function.
#![allow(missing_docs)]

use criterion::{criterion_group, criterion_main, Criterion};
use objslam_core::sensor::synthetic::TiltedTable;
use objslam_core::sensor::{simulate_frame, SensorConfig, SensorUnit};
use std::hint::black_box;

fn bench(c: &mut Criterion) {
    let cfg = SensorConfig::default();
    let scene = TiltedTable::new();
    let unit = SensorUnit::draw(&cfg, scene.intrinsics, 3).unwrap_or_else(|e| panic!("{e}"));
    let frame = scene.frame();
    let mut i = 0u64;
    for (name, motion) in [
        ("sensor_model_640x480", TiltedTable::motion(cfg.colour.exposure_s)),
        ("sensor_model_640x480_rolling", TiltedTable::rolling_motion(cfg.colour.exposure_s)),
    ] {
        c.bench_function(name, |b| {
            b.iter(|| {
                i += 1;
                black_box(
                    simulate_frame(&cfg, &unit, black_box(&frame), Some(&motion), 7, i)
                        .unwrap_or_else(|e| panic!("{e}")),
                )
            })
        });
    }
}

criterion_group!(benches, bench);
criterion_main!(benches);
