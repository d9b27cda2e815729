#![allow(missing_docs)] // criterion_group! generates undocumented items
//! Planning benchmarks (issue 8): `ik` (one TCP IK solve, ≤ 1 ms median) and `plan_query`
//! (IK + collision-free path + trajectory in a 12-object scene, ≤ 50 ms median).
//!
//! Needs the Panda URDF: `OBJSLAM_PANDA_URDF`, else the mani_skill package found by
//! `OBJSLAM_PYTHON` / `<workspace>/.venv/bin/python` / `python3`. The IK targets are the 16
//! top-down poses of [`ik_targets`], the same as `experiments/bench/plan_refs.py` gives pinocchio.

use std::path::PathBuf;

use criterion::{criterion_group, criterion_main, Criterion};
use nalgebra::Vector3;
use objslam_core::geometry::{ObjectGeometry, Shape};
use objslam_core::plan::grasp::top_down_pose;
use objslam_core::plan::{JointVector, Planner, PlannerConfig};

const Q_READY: JointVector = [0.0, -0.3, 0.0, -2.2, 0.0, 2.0, std::f64::consts::FRAC_PI_4];

fn panda_urdf() -> PathBuf {
    if let Ok(p) = std::env::var("OBJSLAM_PANDA_URDF") {
        return PathBuf::from(p);
    }
    let workspace = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..");
    let mut pythons: Vec<PathBuf> = Vec::new();
    if let Ok(p) = std::env::var("OBJSLAM_PYTHON") {
        pythons.push(PathBuf::from(p));
    }
    pythons.push(workspace.join(".venv/bin/python"));
    pythons.push(PathBuf::from("python3"));
    let code = "import importlib.util;print(importlib.util.find_spec('mani_skill').submodule_search_locations[0])";
    for py in &pythons {
        if let Ok(out) = std::process::Command::new(py).args(["-c", code]).output() {
            if out.status.success() {
                let urdf = PathBuf::from(String::from_utf8_lossy(&out.stdout).trim())
                    .join("assets/robots/panda/panda_v2.urdf");
                if urdf.exists() {
                    return urdf;
                }
            }
        }
    }
    panic!("Panda URDF not found: set OBJSLAM_PANDA_URDF or OBJSLAM_PYTHON (tried {pythons:?})");
}

/// 16 top-down TCP targets over the table (x 0.35–0.65, y −0.3–0.3, z 0.15, varying yaw).
fn ik_targets() -> Vec<objslam_core::geometry::Se3> {
    (0..16)
        .map(|k| {
            let p = Vector3::new(0.35 + 0.1 * (k % 4) as f64, -0.3 + 0.2 * (k / 4) as f64, 0.15);
            top_down_pose(p, -0.6 + 0.08 * k as f64)
        })
        .collect()
}

/// 12 objects on a 4 × 3 grid (cuboids and cylinders alternating).
fn twelve_objects() -> Vec<ObjectGeometry> {
    let mut out = Vec::new();
    for i in 0..4 {
        for j in 0..3 {
            let (x, y) = (0.32 + 0.13 * i as f64, -0.25 + 0.25 * j as f64);
            let h = 0.06 + 0.03 * ((i + 2 * j) % 4) as f64;
            let (shape, half) = if (i + j) % 2 == 0 {
                (Shape::Cuboid, Vector3::new(0.025, 0.04, h / 2.0))
            } else {
                (Shape::Cylinder, Vector3::new(0.035, 0.035, h / 2.0))
            };
            out.push(ObjectGeometry {
                shape,
                center: Vector3::new(x, y, h / 2.0),
                yaw_rad: 0.3 * (i + j) as f64,
                half_extents: half,
            });
        }
    }
    out
}

fn benches(c: &mut Criterion) {
    let planner = Planner::new(panda_urdf(), PlannerConfig::default()).unwrap_or_else(|e| panic!("{e}"));
    let targets = ik_targets();
    let mut k = 0usize;
    c.bench_function("ik", |b| {
        b.iter(|| {
            k = (k + 1) % targets.len();
            std::hint::black_box(planner.inverse_tcp(&targets[k], &Q_READY).map(|s| s.q))
        })
    });
    let objects = twelve_objects();
    // Queries: the TCP moves low (11 cm above the table) between gaps of the object grid, from one
    // gap's configuration to the next, so several straight lines are blocked and RRT-Connect runs.
    let gaps = [(0.385, -0.125), (0.645, 0.125), (0.385, 0.125), (0.645, -0.125), (0.515, 0.0), (0.3, 0.3)];
    let mut starts = Vec::new();
    let mut q = Q_READY;
    for &(x, y) in &gaps {
        let scene = planner.scene(&objects).unwrap_or_else(|e| panic!("{e}"));
        let pose = top_down_pose(Vector3::new(x, y, 0.11), 0.0);
        match planner.inverse_tcp_free(&pose, &q, &scene) {
            Ok(s) => {
                starts.push((q, pose));
                q = s.q;
            }
            Err(e) => eprintln!("gap ({x}, {y}): {e}"),
        }
    }
    for (q0, pose) in &starts {
        let scene = planner.scene(&objects).unwrap_or_else(|e| panic!("{e}"));
        let goal = planner.inverse_tcp_free(pose, q0, &scene).map(|s| s.q);
        match goal.and_then(|g| planner.plan_path(q0, &g, &scene)) {
            Ok(p) => eprintln!("plan_query to {:?}: {} waypoints", pose.translation.vector.as_slice(), p.len()),
            Err(e) => eprintln!("plan_query to {:?}: {e}", pose.translation.vector.as_slice()),
        }
    }
    let mut i = 0usize;
    c.bench_function("plan_query", |b| {
        b.iter(|| {
            i = (i + 1) % starts.len();
            let (q0, pose) = &starts[i];
            std::hint::black_box(planner.plan_to_pose(q0, pose, &objects).map(|t| t.positions.len()))
        })
    });
}

criterion_group!(plan, benches);
criterion_main!(plan);
