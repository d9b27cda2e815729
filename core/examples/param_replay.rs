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
//! half-extents) next to the truth; `--yaw ID` prints, for map object `ID`, Alg. 2's score of every
//! yaw sample and, per frame of the window, the segments and the score at the chosen yaw and at
//! the truth's (the cube for a yaw is the oriented extent of the object's points above the lowest
//! 5 mm, an approximation of the estimator's isolation-forest inliers). Diagnosis only: reports
//! are made by `experiments/ablations.py`.

use std::path::PathBuf;

use nalgebra::{Point3, Vector3};
use objslam_core::eval::{evaluate, EstObject, EvalConfig, GtObject};
use objslam_core::geometry::{iou3d, yaw_error_deg, ObjectGeometry, Shape};
use objslam_core::map::{EstimateStage, Label};
use objslam_core::objects::yaw::{align_yaw, canonical_cuboid, cuboid, frame_score, oriented_extent, LineFrame};
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
    let mut yaw_of: Option<u32> = None;
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        match a.as_str() {
            "--config" => {
                let text = args.next().ok_or("--config needs a JSON value")?;
                config = serde_json::from_str(&text)?;
            }
            "--objects" => per_object = true,
            "--yaw" => yaw_of = Some(args.next().ok_or("--yaw needs a map object id")?.parse()?),
            _ => files.push(PathBuf::from(a)),
        }
    }
    let eval_cfg = EvalConfig::default();
    let mut sums = [[0.0f64; 4]; 4];
    let mut counts = [[0usize; 4]; 4];
    let (mut changed, mut refined_n, mut lines_n) = (0usize, 0usize, 0usize);
    for file in &files {
        let dump: Dump = serde_json::from_str(&std::fs::read_to_string(file)?)?;
        if let Some(id) = yaw_of {
            print_yaw_scores(&dump, id, &config);
        }
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

/// `--yaw ID`: Alg. 2's scores for one object, per sample and per frame (see the module docs).
fn print_yaw_scores(dump: &Dump, id: u32, config: &ParamConfig) {
    let Some(o) = dump.objects.iter().find(|o| o.id == id) else {
        println!("  no object {id} in the dump");
        return;
    };
    let z0 = o.points_in_world.iter().map(|p| p.z).fold(f64::INFINITY, f64::min);
    let pts: Vec<Point3<f64>> = o.points_in_world.iter().copied().filter(|p| p.z > z0 + 0.005).collect();
    let cube = |yaw: f64| {
        let (c, h) = oriented_extent(&pts, yaw).unwrap_or((Vector3::zeros(), Vector3::repeat(0.01)));
        cuboid(c, yaw, h)
    };
    let center = cube(0.0).center;
    let truth = dump
        .ground_truth
        .iter()
        .filter(|g| g.label == o.label)
        .min_by(|a, b| (a.geometry.center - center).norm().total_cmp(&(b.geometry.center - center).norm()));
    // The frames Alg. 2 uses under this config (the dump holds every frame the estimator held).
    let mut est = ObjectEstimator::new(o.shape, *config);
    for f in &o.frames {
        est.add_frame(f.clone());
    }
    let frames: Vec<LineFrame> = est.yaw_frames().cloned().collect();
    let Some(alignment) = align_yaw(&frames, cube, &config.yaw) else {
        println!("  object {id}: no yaw sample scores above zero");
        return;
    };
    let truth_yaw = truth.map(|t| canonical_cuboid(&t.geometry).yaw_rad);
    println!(
        "  object {id} {:?}: {} points above z0 + 5 mm, chosen yaw {:.1} deg, truth {}",
        o.label,
        pts.len(),
        alignment.yaw_rad.to_degrees(),
        truth_yaw.map_or("-".into(), |y| format!("{:.1} deg", y.to_degrees()))
    );
    let row: Vec<String> = alignment.samples.iter().map(|(y, s)| format!("{:.0}:{s:.2}", y.to_degrees())).collect();
    println!("  samples (deg:score) {}", row.join(" "));
    for f in &frames {
        let (s_chosen, _) = frame_score(&cube(alignment.yaw_rad), f, &config.yaw);
        let s_truth = truth_yaw.map(|y| frame_score(&cube(y), f, &config.yaw).0);
        println!(
            "  frame {:4} segments {:3} box ({:.0} {:.0})-({:.0} {:.0}) score chosen {s_chosen:.2} truth {}",
            f.frame,
            f.segments.len(),
            f.bbox.min[0],
            f.bbox.min[1],
            f.bbox.max[0],
            f.bbox.max[1],
            s_truth.map_or("-".into(), |s| format!("{s:.2}"))
        );
    }
}
