//! Fixed-work timing of the tracker and the ORB extractor, for whole-process CPU comparisons
//! of two builds (criterion runs for a time budget, not a fixed amount of work).
//!
//! Copy into `core/examples/fixed_work.rs`, then
//! `cargo build --release -p objslam-core --example fixed_work` and time
//! `target/release/examples/fixed_work track 400` (400 `Tracker::track` calls on the frames and
//! priors of the `track_frame` criterion bench, after ray-casting its 20 frames, about 0.4 s) or
//! `... orb 600` (600 extractions of the `orb_extract_640x480` bench frames).
#![allow(missing_docs, clippy::unwrap_used)]
use nalgebra::Point3;
use objslam_core::geometry::PinholeCamera;
use objslam_core::slam::synthetic::{look_at, shapes_texture, TabletopScene};
use objslam_core::slam::{
    OrbConfig, OrbExtractor, PriorNoiseConfig, SyntheticPriorError, TrackInput, Tracker, TrackerConfig,
};

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let n: usize = args[2].parse().unwrap();
    if args[1] == "orb" {
        let frames: Vec<_> = (0..8).map(|s| shapes_texture(640, 480, s)).collect();
        let mut orb = OrbExtractor::new(OrbConfig::default()).unwrap();
        let mut acc = 0;
        for i in 0..n {
            acc += orb.extract(&frames[i % 8]).unwrap().keypoints.len();
        }
        println!("{acc}");
        return;
    }
    let cam = PinholeCamera::from_fovy(640, 480, 50f64.to_radians()).unwrap();
    let scene = TabletopScene::tabletop(3);
    let poses: Vec<_> = (0..20)
        .map(|i| {
            let theta = -0.2 + 0.02 * f64::from(i);
            look_at(Point3::new(0.5 - 0.25 * theta.cos(), 0.25 * theta.sin(), 0.45), Point3::new(0.5, 0.0, 0.0))
        })
        .collect();
    let frames: Vec<_> = poses.iter().map(|p| scene.render(&cam, p)).collect();
    let robot = SyntheticPriorError::new(PriorNoiseConfig::default(), 1);
    let mut tracker = Tracker::new(TrackerConfig::default()).unwrap();
    let order: Vec<usize> = (0..frames.len()).chain((1..frames.len() - 1).rev()).collect();
    let t0 = std::time::Instant::now();
    let mut acc = 0;
    for step in 0..n {
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
        acc += tracker.track(&input).unwrap().n_inliers;
    }
    eprintln!("{acc} {:.3} ms/frame", t0.elapsed().as_secs_f64() * 1e3 / n as f64);
}
