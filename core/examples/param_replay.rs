//! Offline replay of object parameterization: re-runs [`ObjectEstimator`] on the inputs a run
//! recorded (`experiments/run.py --set record.estimator_inputs=true` writes
//! `estimator_inputs.json` to the run folder) and scores every stage against the ground truth
//! stored next to them. Ground truth is used for scoring only; the estimator never sees it.
//!
//! ```text
//! cargo run --release -p objslam-core --example param_replay -- runs/.../estimator_inputs.json ... \
//!     [--config '{"refine": {"refine_center": false}}'] [--objects]
//! ```
//! `--config` is a JSON [`ParamConfig`] (missing fields take their defaults); `--objects` prints,
//! per cuboid that reached the `refined` stage, the lines → refined change (IoU, yaw, centre,
//! half-extents) next to the truth. Diagnosis only: reports are made by `experiments/ablations.py`.

use std::path::PathBuf;

use nalgebra::{Point3, Vector3};
use objslam_core::eval::{evaluate, EstObject, EvalConfig, GtObject};
use objslam_core::geometry::{iou3d, yaw_error_deg, ObjectGeometry, Shape};
use objslam_core::map::{EstimateStage, Label};
use objslam_core::objects::yaw::{canonical_cuboid, LineFrame};
use objslam_core::objects::{ObjectEstimate, ObjectEstimator, ParamConfig};

#[derive(serde::Deserialize)]
struct Input {
    id: u32,
    label: Label,
    shape: Shape,
    points_in_world: Vec<Point3<f64>>,
    frames: Vec<LineFrame>,
}

#[derive(serde::Deserialize)]
struct Dump {
    objects: Vec<Input>,
    ground_truth: Vec<GtObject>,
}

const STAGES: [EstimateStage; 4] =
    [EstimateStage::Raw, EstimateStage::Iforest, EstimateStage::Lines, EstimateStage::Refined];

fn stage_geometry(e: &ObjectEstimate, stage: EstimateStage) -> Option<ObjectGeometry> {
    let upto = STAGES.iter().position(|s| *s == stage).unwrap_or(0);
    STAGES[..=upto].iter().rev().find_map(|s| e.stages.get(*s))
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut files: Vec<PathBuf> = Vec::new();
    let mut config = ParamConfig::default();
    let mut per_object = false;
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        match a.as_str() {
            "--config" => {
                let text = args.next().ok_or("--config needs a JSON value")?;
                config = serde_json::from_str(&text)?;
            }
            "--objects" => per_object = true,
            _ => files.push(PathBuf::from(a)),
        }
    }
    let eval_cfg = EvalConfig::default();
    let mut sums = [[0.0f64; 4]; 4];
    let mut counts = [[0usize; 4]; 4];
    let (mut changed, mut refined_n, mut lines_n) = (0usize, 0usize, 0usize);
    for file in &files {
        let dump: Dump = serde_json::from_str(&std::fs::read_to_string(file)?)?;
        let mut estimates: Vec<(u32, Label, ObjectEstimate)> = Vec::new();
        for o in &dump.objects {
            let mut est = ObjectEstimator::new(o.shape, config);
            for f in &o.frames {
                est.add_frame(f.clone());
            }
            if let Ok(e) = est.estimate(&o.points_in_world) {
                estimates.push((o.id, o.label, e));
            }
        }
        let mut line = format!("{}:", file.display());
        for (k, stage) in STAGES.iter().enumerate() {
            let est: Vec<EstObject> = estimates
                .iter()
                .filter_map(|(id, label, e)| {
                    stage_geometry(e, *stage).map(|geometry| EstObject { id: *id, label: *label, geometry })
                })
                .collect();
            let ev = evaluate(&dump.ground_truth, &est, &eval_cfg);
            let vals = [Some(ev.mean.iou3d), Some(ev.mean.iou2d), ev.mean.cde_cm, ev.mean.yae_deg];
            for (m, v) in vals.iter().enumerate() {
                if let Some(v) = v {
                    sums[k][m] += v;
                    counts[k][m] += 1;
                }
            }
            line += &format!(" {stage:?} {:.3}", ev.mean.iou3d);
        }
        println!("{line}");
        for (id, label, e) in &estimates {
            lines_n += usize::from(e.stages.lines.is_some());
            let (Some(l), Some(r)) = (e.stages.lines, e.stages.refined) else { continue };
            refined_n += 1;
            let moved = (l.center - r.center).norm() > 1e-4
                || (l.half_extents - r.half_extents).abs().max() > 1e-4
                || (l.yaw_rad - r.yaw_rad).abs() > 1e-4;
            changed += usize::from(moved);
            if !per_object {
                continue;
            }
            let gt =
                dump.ground_truth.iter().filter(|g| g.label == *label).min_by(|a, b| {
                    (a.geometry.center - l.center).norm().total_cmp(&(b.geometry.center - l.center).norm())
                });
            let Some(gt) = gt else { continue };
            let t = canonical_cuboid(&gt.geometry);
            let yl = yaw_error_deg(&l, &t, 0.05).unwrap_or(f64::NAN);
            let yr = yaw_error_deg(&r, &t, 0.05).unwrap_or(f64::NAN);
            let d = |g: &ObjectGeometry| (g.center - t.center).norm() * 100.0;
            let cm = |v: Vector3<f64>| format!("({:.1} {:.1} {:.1})", v.x * 100.0, v.y * 100.0, v.z * 100.0);
            println!(
                "  obj {id} {label:?} n_frames {} iou {:.3} -> {:.3} | yae {yl:.1} -> {yr:.1} | cde {:.1} -> {:.1} cm | \
                 half lines {} refined {} gt {} | dz lines {:.1} refined {:.1} cm",
                dump.objects.iter().find(|o| o.id == *id).map_or(0, |o| o.frames.len()),
                iou3d(&l, &t),
                iou3d(&r, &t),
                d(&l),
                d(&r),
                cm(l.half_extents),
                cm(r.half_extents),
                cm(t.half_extents),
                (l.center.z - t.center.z) * 100.0,
                (r.center.z - t.center.z) * 100.0,
            );
        }
    }
    let names = ["iou3d", "iou2d", "cde_cm", "yae_deg"];
    println!("stage   {}", names.join("  "));
    for (k, stage) in STAGES.iter().enumerate() {
        let cells: Vec<String> = (0..4)
            .map(|m| if counts[k][m] > 0 { format!("{:.3}", sums[k][m] / counts[k][m] as f64) } else { "-".into() })
            .collect();
        println!("{stage:?} {}", cells.join(" "));
    }
    println!("objects with a lines stage: {lines_n}, refinement kept: {refined_n}, changed by it: {changed}");
    Ok(())
}
