//! SLAM benchmarks.
//!
//! `track_frame`: one full `Tracker::track` call (features, projection search, RANSAC, robust
//! refinement, keyframe insertion + local BA when due) on 640x480 frames ray-cast from
//! `TabletopScene::tabletop(3)` along a smooth arc, played back and forth so the motion stays
//! smooth; the map is warmed up over the first pass. Default `TrackerConfig` (1 cm / 1° prior
//! bias per view of two frames). The tracker uses the core's worker threads (two on a machine
//! with two cores or more: ORB levels, projection searches and the local bundle adjustment's
//! linearisation and cost in parallel). The frames are played back and forth, so keyframes keep
//! adding observations of the same points: a later frame's bundle adjustment holds more fixed
//! keyframes, and the entry grows with the run's length (criterion's default run ends near
//! frame 1200).
//!
//! `orb_extract_640x480`: `OrbExtractor::extract`, one thread (as the OpenCV reference).
//!
//! `grey_from_rgb_640x480`: `GreyImage::from_rgb`, the BT.601 luma the tracker's grey image is
//! made of when the simulator hands the core its RGB frame (`shapes_texture` grey levels spread
//! over three channels).
//!
//! `orb_extract_640x480` frames: `shapes_texture(640, 480, seed)` for seeds 0..N_FRAMES, the same frames
//! `experiments/bench/slam_refs.py` feeds to `cv2.ORB_create(1000)` (it ports the generator
//! bit for bit), so `orb_extract_640x480` and `cv2_orb_640x480` time identical inputs.

// `criterion_group!` generates an undocumented public function.
#![allow(missing_docs)]

use criterion::{criterion_group, criterion_main, Criterion};
use objslam_core::frame::GreyImage;
use objslam_core::slam::synthetic::{shapes_texture, TrackSequence};
use objslam_core::slam::{OrbConfig, OrbExtractor, Tracker, TrackerConfig};

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

fn track_frame(c: &mut Criterion) {
    let seq = TrackSequence::new().unwrap_or_else(|e| panic!("{e}"));
    let mut tracker = Tracker::new(TrackerConfig::default()).unwrap_or_else(|e| panic!("{e}"));
    let mut step = 0usize;
    let run = |tracker: &mut Tracker, step: usize| tracker.track(&seq.input(step)).unwrap_or_else(|e| panic!("{e}"));
    // The map is warmed up over the first pass.
    for _ in 0..seq.order.len() {
        run(&mut tracker, step);
        step += 1;
    }
    c.bench_function("track_frame", |b| {
        b.iter(|| {
            let out = run(&mut tracker, step);
            step += 1;
            std::hint::black_box(out.n_inliers)
        })
    });
}

fn grey_from_rgb(c: &mut Criterion) {
    let grey = shapes_texture(640, 480, 0);
    let rgb: Vec<u8> =
        grey.data.iter().enumerate().flat_map(|(i, &v)| [v, v.wrapping_add(i as u8), v.wrapping_mul(3)]).collect();
    c.bench_function("grey_from_rgb_640x480", |b| {
        b.iter(|| GreyImage::from_rgb(640, 480, std::hint::black_box(&rgb)).unwrap_or_else(|e| panic!("{e}")))
    });
}

criterion_group!(benches, orb_extract, track_frame, grey_from_rgb);
criterion_main!(benches);
