//! SLAM benchmarks.
//!
//! `track_frame`: one full `Tracker::track` call (features, projection search, RANSAC, robust
//! refinement, keyframe insertion + local BA when due) on 640x480 frames ray-cast from
//! `TabletopScene::tabletop(3)` along a smooth arc, played back and forth so the motion stays
//! smooth; the map is warmed up over the first pass. Default `TrackerConfig` (1 cm / 1° prior
//! bias per view of two frames).
//!
//! `orb_extract_640x480` frames: `shapes_texture(640, 480, seed)` for seeds 0..N_FRAMES, the same frames
//! `experiments/bench/slam_refs.py` feeds to `cv2.ORB_create(1000)` (it ports the generator
//! bit for bit), so `orb_extract_640x480` and `cv2_orb_640x480` time identical inputs.

// `criterion_group!` generates an undocumented public function.
#![allow(missing_docs)]

use criterion::{criterion_group, criterion_main, Criterion};
use nalgebra::Point3;
use objslam_core::geometry::PinholeCamera;
use objslam_core::slam::synthetic::{look_at, shapes_texture, TabletopScene};
use objslam_core::slam::{
    OrbConfig, OrbExtractor, PriorNoiseConfig, SyntheticPriorError, TrackInput, Tracker, TrackerConfig,
};

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
    let cam = PinholeCamera::from_fovy(640, 480, 50f64.to_radians()).unwrap_or_else(|e| panic!("{e}"));
    let scene = TabletopScene::tabletop(3);
    let poses: Vec<_> = (0..20)
        .map(|i| {
            let theta = -0.2 + 0.02 * f64::from(i);
            look_at(Point3::new(0.5 - 0.25 * theta.cos(), 0.25 * theta.sin(), 0.45), Point3::new(0.5, 0.0, 0.0))
        })
        .collect();
    let frames: Vec<_> = poses.iter().map(|p| scene.render(&cam, p)).collect();
    // Back-and-forth playback order.
    let order: Vec<usize> = (0..frames.len()).chain((1..frames.len() - 1).rev()).collect();
    // The prior of a robot with an independent 1 cm / 1° error per view.
    let robot = SyntheticPriorError::new(PriorNoiseConfig::default(), 1);
    let mut tracker = Tracker::new(TrackerConfig::default()).unwrap_or_else(|e| panic!("{e}"));
    let mut step = 0usize;
    let run = |tracker: &mut Tracker, step: usize| {
        let i = order[step % order.len()];
        let (grey, depth) = &frames[i];
        let input = TrackInput {
            grey,
            depth,
            camera: &cam,
            world_from_camera_prior: robot.perturb(&poses[i], (step / 2) as u64, step as u64),
            view_index: (step / 2) as u64,
            world_from_camera_oracle: None,
        };
        tracker.track(&input).unwrap_or_else(|e| panic!("{e}"))
    };
    for _ in 0..order.len() {
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

criterion_group!(benches, orb_extract, track_frame);
criterion_main!(benches);
