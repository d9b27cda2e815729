//! Time the whole per-frame system (tracking → gauge → object pipeline → grids) on the recorded
//! inputs of an episode (`experiments/capture.py`, format in `objslam_core::system::capture`).
//!
//! `cargo run --release -p objslam-core --example system_replay -- <capture dir> [repeats] [caller work]`
//!
//! Replays the capture `repeats` times (default 3), each time on a fresh system, timing every
//! `process_frame` (the core's per-frame work; loading the frame's images is not timed), the
//! `last_pose` query the simulator's loop asks after each frame, and every `view_done` (the
//! per-view refresh of the estimates). Prints the median, mean and 90th percentile of each over
//! all repeats, the map's object count and mean 3D IoU against the capture's ground truth and the
//! pose metrics and keyframe count (so a faster variant that changes the map or the poses shows
//! it), and a digest of everything the system gave out: each frame's object ids and pose, each
//! view's progress, the final map file, grid cells and pose metrics (two builds that print the
//! same digest produced the same outputs bit for bit).
//! With `caller work` (units of a million hash steps, on each of two threads) the replay stands in
//! for the simulator's render between frames, timed too (work the system leaves running after a
//! frame slows it: compare the mean of frame plus caller).

use std::path::Path;
use std::time::Instant;

use anyhow::{anyhow, Result};
use objslam_core::eval::{estimates_from_map, evaluate, EvalConfig};
use objslam_core::explore::AlwaysReachable;
use objslam_core::geometry::Se3;
use objslam_core::system::capture::{Capture, CaptureEvent};
use objslam_core::system::{FrameInput, Query, StepContext};

/// FNV-1a over the bytes of each output, in order.
struct Digest(u64);

impl Digest {
    fn add(&mut self, bytes: &[u8]) {
        for b in bytes {
            self.0 = (self.0 ^ u64::from(*b)).wrapping_mul(0x0100_0000_01b3);
        }
    }

    fn add_json(&mut self, value: &impl serde::Serialize) -> Result<()> {
        self.add(serde_json::to_string(value)?.as_bytes());
        Ok(())
    }
}

/// The caller's work between frames, as a simulator's render on two cores: `units` million
/// steps of an integer hash on each of two threads.
fn caller(units: u64) -> u64 {
    let work = |seed: u64| {
        let mut x = seed;
        for _ in 0..units * 1_000_000 {
            x = x.wrapping_mul(0x9E37_79B9_7F4A_7C15).rotate_left(17) ^ 0x5851_F42D;
        }
        x
    };
    std::thread::scope(|s| {
        let other = s.spawn(|| work(1));
        work(2) ^ other.join().unwrap_or(0)
    })
}

/// (median, mean, 90th percentile) of `v`, ms.
fn summary(v: &mut [f64]) -> (f64, f64, f64) {
    if v.is_empty() {
        return (f64::NAN, f64::NAN, f64::NAN);
    }
    v.sort_by(f64::total_cmp);
    let at = |q: f64| v[((v.len() - 1) as f64 * q).round() as usize];
    (at(0.5), v.iter().sum::<f64>() / v.len() as f64, at(0.9))
}

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let dir = Path::new(args.get(1).ok_or_else(|| anyhow!("usage: system_replay <capture dir> [repeats]"))?);
    let repeats: usize = match args.get(2) {
        Some(s) => s.parse().map_err(|_| anyhow!("repeats: not a count: {s}"))?,
        None => 3,
    };
    let caller_work: u64 = match args.get(3) {
        Some(s) => s.parse().map_err(|_| anyhow!("caller work: not a count: {s}"))?,
        None => 0,
    };
    let mut caller_ms = Vec::new();
    let capture = Capture::open(dir)?;
    let (mut frame_ms, mut pose_ms, mut view_ms) = (Vec::new(), Vec::new(), Vec::new());
    let current = Se3::identity();
    let step = StepContext { camera: None, world_from_camera: &current, views: &[], reachable: &AlwaysReachable };
    let mut last = None;
    let mut digests = Vec::new();
    for _ in 0..repeats {
        let mut system = capture.system()?;
        let mut digest = Digest(0xcbf2_9ce4_8422_2325);
        for event in &capture.events {
            match event {
                CaptureEvent::Frame(f) => {
                    let (frame, grey) = capture.load_frame(f)?;
                    let gt = f.true_pose()?;
                    let t = Instant::now();
                    let ids = system.process_frame(FrameInput {
                        frame,
                        grey: Some(&grey),
                        view_index: f.view_index,
                        world_from_camera_gt: Some(gt),
                    })?;
                    frame_ms.push(t.elapsed().as_secs_f64() * 1e3);
                    let t = Instant::now();
                    let pose = system.query(&Query::LastPose, &step)?;
                    pose_ms.push(t.elapsed().as_secs_f64() * 1e3);
                    if caller_work > 0 {
                        let t = Instant::now();
                        std::hint::black_box(caller(caller_work));
                        caller_ms.push(t.elapsed().as_secs_f64() * 1e3);
                    }
                    digest.add_json(&ids)?;
                    digest.add_json(&pose)?;
                }
                CaptureEvent::ViewDone { counts_as_view } => {
                    let t = Instant::now();
                    system.view_done(*counts_as_view);
                    view_ms.push(t.elapsed().as_secs_f64() * 1e3);
                    digest.add_json(&system.progress())?;
                }
            }
        }
        digest.add(system.map().to_json().as_bytes());
        let cells = system.grid_cells();
        digest.add_json(&cells.p_in_world)?;
        digest.add(&cells.state_codes());
        digest.add_json(&system.pose_metrics()?)?;
        digests.push(digest.0);
        last = Some(system);
    }
    let (fm, fa, f90) = summary(&mut frame_ms);
    let (pm, pa, p90) = summary(&mut pose_ms);
    let (vm, va, v90) = summary(&mut view_ms);
    println!("process_frame: {} frames, median {fm:.2} ms, mean {fa:.2} ms, p90 {f90:.2} ms", frame_ms.len());
    println!("last_pose:     {} queries, median {pm:.3} ms, mean {pa:.3} ms, p90 {p90:.3} ms", pose_ms.len());
    println!("view_done:     {} views, median {vm:.2} ms, mean {va:.2} ms, p90 {v90:.2} ms", view_ms.len());
    if !caller_ms.is_empty() {
        let total: f64 = caller_ms.iter().sum::<f64>() + frame_ms.iter().sum::<f64>();
        let (cm, ca, c90) = summary(&mut caller_ms);
        println!("caller work:   median {cm:.2} ms, mean {ca:.2} ms, p90 {c90:.2} ms");
        println!("frame + caller, mean per frame: {:.2} ms", total / frame_ms.len() as f64);
    }
    let same = digests.windows(2).all(|w| w[0] == w[1]);
    let digests: Vec<String> = digests.iter().map(|d| format!("{d:016x}")).collect();
    println!("digest: {} ({})", digests.join(" "), if same { "every repeat the same" } else { "REPEATS DIFFER" });
    if let Some(system) = last {
        let ev = evaluate(&capture.header.ground_truth, &estimates_from_map(&system.map()), &EvalConfig::default());
        println!("map: {} objects for {} true, mean 3D IoU {:.3}", ev.n_objects_est, ev.n_objects_gt, ev.mean.iou3d);
        if let Some(m) = system.pose_metrics()? {
            println!(
                "poses: ATE {:.2} mm (final trajectory {:.2} mm), RPE {:.3} mm / {:.4} deg, {} lost",
                m.ate_rmse_m * 1e3,
                m.ate_final_rmse_m.unwrap_or(f64::NAN) * 1e3,
                m.rpe_trans_m * 1e3,
                m.rpe_rot_deg,
                m.lost_frames,
            );
        }
        if let Some(t) = system.tracker() {
            println!("tracker: {} keyframes, {} map points", t.n_keyframes(), t.n_map_points());
        }
    }
    Ok(())
}
