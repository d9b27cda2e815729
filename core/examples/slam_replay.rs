//! Replay the frames of a capture (`experiments/capture.py`, format in
//! `objslam_core::system::capture`) through the tracker alone (SLAM diagnosis).
//!
//! `cargo run --release -p objslam-core --example slam_replay -- <capture dir> [tracker config JSON] [-v]`
//!
//! The tracker config is the capture's own (from `system.json`, so a capture of every frame
//! reproduces the episode's poses) with the keys of the optional JSON argument merged over it
//! (objects merged key by key), e.g. `'{"motion_gate_floor_m": 0, "motion_gate_floor_deg": 0}'`.
//!
//! Prints the online ATE (each frame's pose as output when it was tracked), the final-trajectory
//! ATE ([`Tracker::trajectory`]), the ATE after the best rigid alignment (consistency only), RPE,
//! lost frames, and with `-v` one line per frame (features, features with depth, inliers, state,
//! position error of the online pose).

use std::path::Path;

use anyhow::{anyhow, Context, Result};
use nalgebra::{Matrix3, Vector3};
use objslam_core::geometry::Se3;
use objslam_core::slam::{ate_rmse_m, rpe, PoseSource, TrackInput, Tracker, TrackerConfig};
use objslam_core::system::capture::{Capture, CaptureEvent};

/// ATE after the best rigid alignment (Horn / Umeyama without scale) of the estimate to the truth.
fn aligned_ate(est: &[Se3], gt: &[Se3]) -> f64 {
    let n = est.len() as f64;
    let ce: Vector3<f64> = est.iter().map(|p| p.translation.vector).sum::<Vector3<f64>>() / n;
    let cg: Vector3<f64> = gt.iter().map(|p| p.translation.vector).sum::<Vector3<f64>>() / n;
    let mut h = Matrix3::zeros();
    for (e, g) in est.iter().zip(gt) {
        h += (g.translation.vector - cg) * (e.translation.vector - ce).transpose();
    }
    let svd = h.svd(true, true);
    let (Some(u), Some(vt)) = (svd.u, svd.v_t) else { return f64::NAN };
    let mut d = Matrix3::identity();
    d[(2, 2)] = (u * vt).determinant().signum();
    let r = u * d * vt;
    let s: f64 = est
        .iter()
        .zip(gt)
        .map(|(e, g)| (r * (e.translation.vector - ce) + cg - g.translation.vector).norm_squared())
        .sum();
    (s / n).sqrt()
}

/// Merge `over` into `base`: objects key by key (recursively), anything else replaced.
fn merge(base: &mut serde_json::Value, over: &serde_json::Value) {
    match (base, over) {
        (serde_json::Value::Object(b), serde_json::Value::Object(o)) => {
            for (k, v) in o {
                merge(b.entry(k.clone()).or_insert(serde_json::Value::Null), v);
            }
        }
        (b, o) => *b = o.clone(),
    }
}

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let dir = Path::new(args.get(1).ok_or_else(|| anyhow!("usage: slam_replay <capture dir> [config JSON] [-v]"))?);
    let verbose = args.iter().any(|a| a == "-v");
    let overrides: serde_json::Value = match args.get(2).filter(|a| *a != "-v") {
        Some(s) => serde_json::from_str(s).context("tracker config argument")?,
        None => serde_json::json!({}),
    };
    let capture = Capture::open(dir)?;
    let mut cfg_json = serde_json::to_value(capture.header.tracker_config.unwrap_or_default())?;
    merge(&mut cfg_json, &overrides);
    let config: TrackerConfig = serde_json::from_value(cfg_json).context("tracker config")?;
    let mut tracker = Tracker::new(config)?;
    let (mut online, mut gts) = (Vec::new(), Vec::new());
    let t0 = std::time::Instant::now();
    for event in &capture.events {
        let CaptureEvent::Frame(f) = event else { continue };
        let (frame, grey) = capture.load_frame(f)?;
        let gt = f.true_pose()?;
        let out = tracker.track(&TrackInput {
            grey: &grey,
            depth: &frame.depth,
            camera: &frame.camera,
            world_from_camera_prior: frame.world_from_camera,
            view_index: f.view_index,
            world_from_camera_oracle: (tracker.config().pose_source == PoseSource::GroundTruth).then_some(gt),
        })?;
        if verbose {
            let err = (out.world_from_camera.translation.vector - gt.translation.vector).norm() * 1e3;
            let perr = (out.world_from_camera_prior.translation.vector - gt.translation.vector).norm() * 1e3;
            println!(
                "frame {:4} view {:2} feat {:4} inl {:4} kf {} pts {:5} err {err:6.2} mm prior {perr:6.2} mm {:?}",
                f.index,
                f.view_index,
                out.n_features,
                out.n_inliers,
                u8::from(out.keyframe_inserted),
                out.n_map_points,
                out.state
            );
        }
        online.push(out.world_from_camera);
        gts.push(gt);
    }
    let dt = t0.elapsed().as_secs_f64() / online.len().max(1) as f64;
    let traj = tracker.trajectory();
    let r = rpe(&online, &gts)?;
    println!(
        "frames {} lost {} | ATE online {:.2} mm, trajectory {:.2} mm, aligned online {:.2} mm, aligned trajectory {:.2} mm | RPE {:.2} mm {:.3} deg | {:.1} ms/frame",
        online.len(),
        tracker.n_lost(),
        ate_rmse_m(&online, &gts)? * 1e3,
        ate_rmse_m(&traj, &gts)? * 1e3,
        aligned_ate(&online, &gts) * 1e3,
        aligned_ate(&traj, &gts) * 1e3,
        r.trans_m * 1e3,
        r.rot_deg,
        dt * 1e3
    );
    Ok(())
}
