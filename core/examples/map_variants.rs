//! Replay captured episodes (`experiments/capture.py`) through the whole system with changed
//! pipeline settings, and score each map against the capture's ground truth.
//!
//! `cargo run --release -p objslam-core --example map_variants -- [--set key=value]... [--why] <capture dir>...`
//!
//! `--set` changes a field of the capture's pipeline config (`[map]` of a run config), dotted for
//! nested tables (`--set relabel_co_observed_share=0.25`, `--set param.support_snap_m=0.02`; the
//! value is JSON, else a string). The views are the recorded ones, so a setting that would have
//! changed the exploration's choices shows only its effect on the map. Prints one line per capture
//! (objects estimated / true, recall and precision at 3D IoU 0.25, mean 3D IoU) and the totals;
//! `--why` adds every unmatched map object and every missed true object beside its nearest
//! counterpart.

use std::path::Path;

use anyhow::{anyhow, bail, Result};
use objslam_core::eval::{estimates_from_map, evaluate, EvalConfig};
use objslam_core::pipeline::PipelineConfig;
use objslam_core::system::capture::Capture;
use serde_json::Value;

/// `config` with `key=value` applied (dotted keys into nested tables).
fn apply(config: &PipelineConfig, sets: &[String]) -> Result<PipelineConfig> {
    let mut v = serde_json::to_value(config)?;
    for s in sets {
        let (key, value) = s.split_once('=').ok_or_else(|| anyhow!("--set {s}: expected key=value"))?;
        let value = serde_json::from_str(value).unwrap_or_else(|_| Value::String(value.to_string()));
        let mut at = &mut v;
        let parts: Vec<&str> = key.split('.').collect();
        for p in &parts[..parts.len() - 1] {
            at = at.get_mut(*p).ok_or_else(|| anyhow!("--set {s}: no table {p}"))?;
        }
        let last = parts[parts.len() - 1];
        let slot = at.get_mut(last).ok_or_else(|| anyhow!("--set {s}: no field {last}"))?;
        *slot = value;
    }
    Ok(serde_json::from_value(v)?)
}

fn main() -> Result<()> {
    let (mut sets, mut dirs, mut why) = (Vec::new(), Vec::new(), false);
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        match a.as_str() {
            "--set" => sets.push(args.next().ok_or_else(|| anyhow!("--set needs key=value"))?),
            "--why" => why = true,
            _ => dirs.push(a),
        }
    }
    if dirs.is_empty() {
        bail!("usage: map_variants [--set key=value]... [--why] <capture dir>...");
    }
    let (mut within_one, mut recall_ok, mut iou_sum) = (0, 0, 0.0);
    for dir in &dirs {
        let mut capture = Capture::open(Path::new(dir))?;
        capture.header.mapper_config = apply(&capture.header.mapper_config, &sets)?;
        let mut system = capture.system()?;
        capture.replay(&mut system)?;
        let map = system.map();
        let est = estimates_from_map(&map);
        let gt = &capture.header.ground_truth;
        let ev = evaluate(gt, &est, &EvalConfig::default());
        let recall = ev.mean.recall_iou25.unwrap_or(0.0);
        let name = Path::new(dir).file_name().map_or(dir.clone(), |n| n.to_string_lossy().into_owned());
        println!(
            "{name:10} {:2}/{:2}  recall@0.25 {:.2}  precision@0.25 {:.2}  3D IoU {:.3}",
            ev.n_objects_est,
            ev.n_objects_gt,
            recall,
            ev.mean.precision_iou25.unwrap_or(0.0),
            ev.mean.iou3d
        );
        within_one += usize::from(ev.n_objects_est.abs_diff(ev.n_objects_gt) <= 1);
        recall_ok += usize::from(recall >= 0.9);
        iou_sum += ev.mean.iou3d;
        if why {
            let matched: Vec<u32> = ev.objects.iter().filter(|o| o.iou3d >= 0.25).filter_map(|o| o.est_id).collect();
            for o in map.objects.iter().filter(|o| !matched.contains(&o.id)) {
                let c = o.geometry().center;
                let near =
                    gt.iter().min_by(|a, b| (a.geometry.center - c).norm().total_cmp(&(b.geometry.center - c).norm()));
                let frames: std::collections::BTreeSet<u32> = o.observations.iter().map(|ob| ob.frame).collect();
                let Some(g) = near else { continue };
                let row = ev.objects.iter().find(|r| r.gt_id == g.id);
                let e = o.geometry().half_extents * 200.0;
                let t = g.geometry.half_extents * 200.0;
                println!(
                    "    extra  #{:<3} {:?} obs {:3} frames {:3} size {:.1}x{:.1}x{:.1} cm  nearest true {:?} #{} \
                     {:.1}x{:.1}x{:.1} cm at {:.1} cm, IoU {:.2}; it went to map #{:?} (IoU {:.2})",
                    o.id,
                    o.label,
                    o.observations.len(),
                    frames.len(),
                    e.x,
                    e.y,
                    e.z,
                    g.label,
                    g.id,
                    t.x,
                    t.y,
                    t.z,
                    (g.geometry.center - c).norm() * 100.0,
                    objslam_core::geometry::iou3d(&o.geometry(), &g.geometry),
                    row.and_then(|r| r.est_id),
                    row.map_or(0.0, |r| r.iou3d),
                );
                if let Some(other) = row.and_then(|r| r.est_id).and_then(|id| map.objects.iter().find(|m| m.id == id)) {
                    let theirs: std::collections::BTreeSet<u32> =
                        other.observations.iter().map(|ob| ob.frame).collect();
                    println!(
                        "           vs map #{} {:?} obs {}: boxed together in {} frames, mutual IoU {:.2}",
                        other.id,
                        other.label,
                        other.observations.len(),
                        frames.intersection(&theirs).count(),
                        objslam_core::geometry::iou3d(&o.geometry(), &other.geometry())
                    );
                }
            }
            for row in ev.objects.iter().filter(|o| o.iou3d < 0.25) {
                let Some(g) = gt.iter().find(|g| g.id == row.gt_id) else { continue };
                let c = g.geometry.center;
                let near = map
                    .objects
                    .iter()
                    .min_by(|a, b| (a.geometry().center - c).norm().total_cmp(&(b.geometry().center - c).norm()));
                println!(
                    "    missed #{:<3} {:?} (IoU {:.2})  nearest map {:?} #{} at {:.1} cm",
                    g.id,
                    g.label,
                    row.iou3d,
                    near.map(|o| o.label),
                    near.map_or(0, |o| o.id),
                    near.map_or(f64::NAN, |o| (o.geometry().center - c).norm() * 100.0)
                );
            }
        }
    }
    println!(
        "count within one {within_one}/{n}, recall@0.25 >= 0.9 {recall_ok}/{n}, mean 3D IoU {:.3}",
        iou_sum / dirs.len() as f64,
        n = dirs.len()
    );
    Ok(())
}
