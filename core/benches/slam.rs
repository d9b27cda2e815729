//! SLAM benchmarks. Frames: `shapes_texture(640, 480, seed)` for seeds 0..N_FRAMES, the same frames
//! `experiments/bench/slam_refs.py` feeds to `cv2.ORB_create(1000)` (it ports the generator
//! bit for bit), so `orb_extract_640x480` and `cv2_orb_640x480` time identical inputs.

use criterion::{criterion_group, criterion_main, Criterion};
use objslam_core::slam::synthetic::shapes_texture;
use objslam_core::slam::{OrbConfig, OrbExtractor};

/// Frames cycled through by the ORB benchmark (same count as the Python reference).
const N_FRAMES: u64 = 8;

fn orb_extract(c: &mut Criterion) {
    let frames: Vec<_> = (0..N_FRAMES).map(|s| shapes_texture(640, 480, s)).collect();
    let mut orb = OrbExtractor::new(OrbConfig::default()).unwrap_or_else(|e| panic!("{e}"));
    let mut i = 0usize;
    c.bench_function("orb_extract_640x480", |b| {
        b.iter(|| {
            i = (i + 1) % frames.len();
            let f = orb.extract(&frames[i]).unwrap_or_else(|e| panic!("{e}"));
            std::hint::black_box(f.keypoints.len())
        })
    });
}

criterion_group!(benches, orb_extract);
criterion_main!(benches);
