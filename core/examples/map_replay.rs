//! The object map of recorded episodes under a changed pipeline config, judged against their
//! ground truth: association and consolidation studies without rendering.
//!
//! `cargo run --release -p objslam-core --example map_replay -- [--objects] [--dump DIR] '<json patch>' <capture dir>...`
//!
//! Each capture (`experiments/capture.py`) is replayed once through a fresh system whose
//! `mapper_config` is the capture's with the JSON object `patch` merged in (nested objects merge
//! key by key; `{}` = the capture's own config). Per capture it prints the map's object count
//! against the truth, recall and precision at 3D IoU 0.25, and the mean 3D IoU; then the totals:
//! captures whose count is within one of the truth, captures with recall at least 0.9, mean IoU.
//! With `--objects` it also lists every true object under 3D IoU 0.25 (its estimate and the true
//! objects that estimate covers, or the estimates covering a missed one, with their label votes,
//! and the objects held back from the map that cover it, with their existence evidence), every map
//! object's label votes and shape-fit costs (`ObjectPipeline::shape_fit_costs`, millimetres:
//! cuboid, cylinder), and every estimate matched to no true object (its observations and the two
//! nearest true objects). With `--dump DIR` it writes each replayed map, clouds included, to
//! `DIR/<capture>.map.json`.
//! The views are the capture's (the strategy's choices under the recorded map), so this ranks
//! mapping changes on fixed inputs; the exploration benchmark judges them in closed loop.

use std::path::Path;

use anyhow::{anyhow, Result};
use objslam_core::eval::{estimates_from_map, evaluate, EvalConfig};
use objslam_core::pipeline::PipelineConfig;
use objslam_core::system::capture::Capture;
use serde_json::Value;

/// Merge `patch` into `base`, objects key by key.
fn merge(base: &mut Value, patch: &Value) {
    match (base, patch) {
        (Value::Object(b), Value::Object(p)) => {
            for (k, v) in p {
                merge(b.entry(k.clone()).or_insert(Value::Null), v);
            }
        }
        (b, p) => *b = p.clone(),
    }
}

fn main() -> Result<()> {
    let mut args: Vec<String> = std::env::args().skip(1).collect();
    let objects = args.first().is_some_and(|a| a == "--objects");
    if objects {
        args.remove(0);
    }
    // Optional: write each replayed map (with the objects' clouds) to DIR/<capture>.map.json.
    let dump = if args.first().is_some_and(|a| a == "--dump") && args.len() > 1 {
        args.remove(0);
        Some(std::path::PathBuf::from(args.remove(0)))
    } else {
        None
    };
    let usage = || anyhow!("usage: map_replay [--objects] [--dump DIR] '<json patch>' <capture dir>...");
    let patch: Value = serde_json::from_str(args.first().ok_or_else(usage)?)?;
    if args.len() < 2 {
        return Err(usage());
    }
    let (mut within, mut recalled, mut iou_sum, mut n) = (0, 0, 0.0, 0);
    for dir in &args[1..] {
        let capture = Capture::open(Path::new(dir))?;
        let mut cfg = serde_json::to_value(&capture.header.mapper_config)?;
        merge(&mut cfg, &patch);
        let cfg: PipelineConfig = serde_json::from_value(cfg)?;
        let mut system = capture.system_with(cfg)?;
        capture.replay(&mut system)?;
        let map = system.map();
        if let Some(out) = &dump {
            let name = Path::new(dir).file_name().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
            std::fs::write(out.join(format!("{name}.map.json")), serde_json::to_string(&map)?)?;
        }
        let ev = evaluate(&capture.header.ground_truth, &estimates_from_map(&map), &EvalConfig::default());
        if objects {
            for o in &ev.objects {
                if o.iou3d < 0.25 {
                    let g = capture.header.ground_truth.iter().find(|g| g.id == o.gt_id);
                    println!(
                        "   gt {} {:?} est {:?} iou {:.2} c {:?} h {:?}",
                        o.gt_id,
                        o.label,
                        o.est_id,
                        o.iou3d,
                        g.map(|g| g.geometry.center.as_slice().to_vec()),
                        g.map(|g| g.geometry.half_extents.as_slice().to_vec())
                    );
                    if o.est_id.is_none() {
                        // Which estimate covers the missing object, and how much of it.
                        if let Some(g) = g {
                            for m in &map.objects {
                                let f = objslam_core::geometry::intersection_volume(&m.geometry(), &g.geometry)
                                    / g.geometry.volume();
                                if f > 0.1 {
                                    let votes = system.pipeline().label_votes(m.id);
                                    println!("      covered by est {} ({:?}) {:.2} votes {votes:?}", m.id, m.label, f);
                                }
                            }
                            // Objects held back from the map (existence evidence, too few observations).
                            for (m, n, unseen) in system.pipeline().existence_evidence() {
                                if map.get(m.id).is_some() {
                                    continue;
                                }
                                let f = objslam_core::geometry::intersection_volume(&m.geometry(), &g.geometry)
                                    / g.geometry.volume();
                                if f > 0.1 {
                                    println!(
                                        "      held back est {} ({:?}) {:.2} observations {n} unseen {unseen}",
                                        m.id, m.label, f
                                    );
                                }
                            }
                        }
                    }
                    if let Some(e) = o.est_id.and_then(|id| map.get(id).map(|m| m.geometry())) {
                        let covers: Vec<String> = capture
                            .header
                            .ground_truth
                            .iter()
                            .map(|g| {
                                (
                                    g.id,
                                    objslam_core::geometry::intersection_volume(&e, &g.geometry) / g.geometry.volume(),
                                )
                            })
                            .filter(|(_, f)| *f > 0.1)
                            .map(|(id, f)| format!("gt{id}:{f:.2}"))
                            .collect();
                        println!(
                            "      est c {:?} h {:?} covers {}",
                            e.center.as_slice(),
                            e.half_extents.as_slice(),
                            covers.join(" ")
                        );
                    }
                }
            }
            // Every map object: its label votes, the true object it matches and both shapes' fit costs.
            for m in &map.objects {
                let gt = ev.objects.iter().find(|o| o.est_id == Some(m.id)).map(|o| format!("{:?}", o.label));
                let votes = system.pipeline().label_votes(m.id);
                let costs = system.pipeline().shape_fit_costs(m.id);
                println!(
                    "   shape est {} {:?} gt {} votes {:?} costs {:?}",
                    m.id,
                    m.label,
                    gt.unwrap_or_else(|| "-".into()),
                    votes.map(|v| v.to_vec()),
                    costs.map(|c| [(c[0] * 1e4).round() / 10.0, (c[1] * 1e4).round() / 10.0])
                );
            }
            let matched: Vec<u32> = ev.objects.iter().filter_map(|o| o.est_id).collect();
            for m in &map.objects {
                if matched.contains(&m.id) {
                    continue;
                }
                let e = m.geometry();
                let mut near: Vec<(f64, u32, f64)> = capture
                    .header
                    .ground_truth
                    .iter()
                    .map(|g| {
                        let d = (g.geometry.center.xy() - e.center.xy()).norm();
                        (d, g.id, objslam_core::geometry::intersection_volume(&e, &g.geometry) / e.volume().max(1e-12))
                    })
                    .collect();
                near.sort_by(|a, b| a.0.total_cmp(&b.0));
                let near: Vec<String> =
                    near.iter().take(2).map(|(d, id, f)| format!("gt{id} {:.1}cm in {f:.2}", d * 100.0)).collect();
                println!(
                    "   extra est {} {:?} obs {} c {:?} h {:?} near {}",
                    m.id,
                    m.label,
                    m.observations.len(),
                    e.center.as_slice(),
                    e.half_extents.as_slice(),
                    near.join(", ")
                );
            }
        }
        let recall = ev.mean.recall_iou25.unwrap_or(0.0);
        let ok = ev.n_objects_est.abs_diff(ev.n_objects_gt) <= 1;
        within += usize::from(ok);
        recalled += usize::from(recall >= 0.9);
        iou_sum += ev.mean.iou3d;
        n += 1;
        let name = Path::new(dir).file_name().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
        println!(
            "{name:>8}: {:>2} for {:>2}{} recall {:.2} precision {:.2} IoU {:.3}",
            ev.n_objects_est,
            ev.n_objects_gt,
            if ok { " " } else { "*" },
            recall,
            ev.mean.precision_iou25.unwrap_or(0.0),
            ev.mean.iou3d,
        );
    }
    println!("within one {within}/{n}, recall >= 0.9 {recalled}/{n}, mean IoU {:.3}", iou_sum / n.max(1) as f64);
    Ok(())
}
