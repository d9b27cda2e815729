//! The yaw/scale refinement on real simulator inputs and on a synthetic cube: hidden-edge removal,
//! the point-to-surface and extent terms, and the acceptance test (`core/src/objects/refine.rs`).
//!
//! The fixture `param_books.json` (`core/tests/fixtures/make_param_books.py`) holds the estimator
//! inputs of two books from Init episodes on scenes 2 and 5: the previous refinement (all 12 edges,
//! segments only) lost most of their 3D IoU (measured 0.675 → 0.228 and 0.717 → 0.267: the
//! box grew in height while it shrank in width). Ground truth is used for scoring only.

// Test code may unwrap (clippy.toml allows it in #[test] functions; this covers their helpers).
#![allow(clippy::unwrap_used, clippy::expect_used)]

use nalgebra::{Point3, Vector3};
use objslam_core::geometry::{iou3d, yaw_error_deg, Box2, ObjectGeometry, PinholeCamera, Se3, Shape};
use objslam_core::map::EstimateStage;
use objslam_core::objects::lsd::LineSegment;
use objslam_core::objects::refine::{refine_yaw_scale, RefineConfig};
use objslam_core::objects::yaw::{cuboid, project_edges, visible_edges, LineFrame, CUBE_EDGES};
use objslam_core::objects::{iforest::IForestConfig, ObjectEstimate, ObjectEstimator, ParamConfig};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

#[derive(serde::Deserialize)]
struct Record {
    scene: String,
    id: u32,
    shape: Shape,
    points_in_world: Vec<Point3<f64>>,
    frames: Vec<LineFrame>,
    ground_truth: ObjectGeometry,
}

fn records() -> Vec<Record> {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/fixtures/param_books.json");
    let text = std::fs::read_to_string(path).unwrap();
    serde_json::from_str(&text).unwrap()
}

/// The refinement as it was before hidden-edge removal, the robust segment residuals and the
/// point terms.
fn previous_refinement() -> RefineConfig {
    RefineConfig {
        visible_edges_only: false,
        segment_huber_px: 0.0,
        point_weight_px_per_m: 0.0,
        extent_weight_px_per_m: 0.0,
        accept_if_lower_cost: false,
        ..Default::default()
    }
}

fn run(r: &Record, refine: RefineConfig) -> ObjectEstimate {
    let mut est = ObjectEstimator::new(r.shape, ParamConfig { refine, ..Default::default() });
    for f in &r.frames {
        est.add_frame(f.clone());
    }
    est.estimate(&r.points_in_world).unwrap()
}

#[test]
fn real_books_refinement_no_longer_loses_iou() {
    let recs = records();
    assert_eq!(recs.len(), 2);
    for r in &recs {
        let t = &r.ground_truth;
        let old = run(r, previous_refinement());
        let new = run(r, RefineConfig::default());
        let lines = new.stages.lines.unwrap_or_else(|| panic!("{}: no lines stage", r.scene));
        assert_eq!(old.stages.lines, Some(lines), "{}: the lines stage does not depend on the refinement", r.scene);
        let old_refined = old.stages.refined.unwrap_or_else(|| panic!("{}: old refinement not run", r.scene));
        let (l, o) = (iou3d(&lines, t), iou3d(&old_refined, t));
        assert_eq!(new.stage, EstimateStage::Refined, "{} object {}", r.scene, r.id);
        let n = iou3d(&new.geometry, t);
        eprintln!("{} object {}: 3D IoU lines {l:.3}, previous refinement {o:.3}, refinement {n:.3}", r.scene, r.id);
        // The failure this fixture pins: the previous refinement lost > 0.3 of 3D IoU (measured 0.45).
        assert!(o < l - 0.3, "{}: previous refinement {o:.3} vs lines {l:.3}", r.scene);
        // Now: at least as good as the line alignment (measured 0.886 and 0.760), within 3.5 mm of
        // the true half-height and not worse in yaw than the 6°-sampled Alg. 2 answer.
        assert!(n >= l, "{}: refined {n:.3} < lines {l:.3}", r.scene);
        assert!((new.geometry.half_extents.z - t.half_extents.z).abs() < 0.0035, "{}: {:?}", r.scene, new.geometry);
        let yl = yaw_error_deg(&lines, t, 0.05).unwrap_or(f64::NAN);
        let yn = yaw_error_deg(&new.geometry, t, 0.05).unwrap_or(f64::NAN);
        assert!(yn <= yl.max(1.0), "{}: yaw error {yn:.2}° vs lines {yl:.2}°", r.scene);
    }
}

#[test]
fn estimator_keeps_the_refinement_only_when_it_lowers_the_cost() {
    for r in &records() {
        let new = run(r, RefineConfig::default());
        let lines = new.stages.lines.expect("no lines stage");
        let frames = r.frames.clone();
        // The estimator's inliers are not exposed; the refinement with all points agrees on the
        // decision here (the cost falls by more than 3 %).
        let res =
            refine_yaw_scale(&lines, &frames, &r.points_in_world, &RefineConfig::default()).expect("no refinement");
        assert!(res.rms_after_px < 0.97 * res.rms_before_px, "{:?}", (res.rms_before_px, res.rms_after_px));
        assert_eq!(new.stage, EstimateStage::Refined);
    }
    // The acceptance cost is a sensible data cost: with segments exactly on the true cube's visible
    // edges and points on its surface it is 0 at the truth and grows for every perturbed cube.
    let (cam, truth) = (camera(), truth());
    let frames: Vec<LineFrame> =
        eyes().iter().enumerate().map(|(i, e)| exact_frame(i as u32, *e, &cam, &truth)).collect();
    let pts = surface_points(&mut ChaCha8Rng::seed_from_u64(3), &truth, 0.0);
    let cost_of = |g: &ObjectGeometry| {
        refine_yaw_scale(g, &frames, &pts, &RefineConfig::default()).map_or(f64::INFINITY, |r| r.rms_before_px)
    };
    let at_truth = cost_of(&truth);
    assert!(at_truth < 1e-9, "{at_truth}");
    let perturbed = [
        ObjectGeometry { half_extents: truth.half_extents + Vector3::new(0.01, 0.0, 0.0), ..truth },
        ObjectGeometry { half_extents: truth.half_extents - Vector3::new(0.0, 0.005, 0.0), ..truth },
        ObjectGeometry { half_extents: truth.half_extents + Vector3::new(0.0, 0.0, 0.01), ..truth },
        ObjectGeometry { center: truth.center + Vector3::new(0.005, -0.005, 0.0), ..truth },
        ObjectGeometry { yaw_rad: truth.yaw_rad + 3f64.to_radians(), ..truth },
    ];
    for g in &perturbed {
        let c = cost_of(g);
        eprintln!("perturbed cost {c:.3} px");
        assert!(c > at_truth + 1.0, "{g:?}: cost {c:.3} px vs {at_truth:.3} at the truth");
    }
}

fn look_at(eye: Vector3<f64>, target: Vector3<f64>) -> Se3 {
    objslam_core::geometry::look_at_with_up(&eye.into(), &target.into(), &Vector3::z()).unwrap()
}

fn camera() -> PinholeCamera {
    PinholeCamera::from_fovy(640, 480, 55f64.to_radians()).unwrap()
}

/// A thin book on the table (top at 3 cm).
fn truth() -> ObjectGeometry {
    cuboid(Vector3::new(0.5, 0.05, 0.015), 20f64.to_radians(), Vector3::new(0.08, 0.03, 0.015))
}

fn eyes() -> Vec<Vector3<f64>> {
    vec![
        Vector3::new(0.30, -0.05, 0.40),
        Vector3::new(0.60, 0.30, 0.38),
        Vector3::new(0.28, 0.25, 0.35),
        Vector3::new(0.70, -0.10, 0.42),
    ]
}

/// Segments exactly on the visible projected edges of `g`.
fn exact_frame(index: u32, eye: Vector3<f64>, cam: &PinholeCamera, g: &ObjectGeometry) -> LineFrame {
    let pose = look_at(eye, g.center);
    let vis = visible_edges(g, &Point3::from(eye));
    let edges = project_edges(g, cam, &pose);
    let corners: Vec<[f64; 2]> = edges.iter().flat_map(|e| [e.a, e.b]).collect();
    let bbox = Box2::from_points(corners.iter()).expect("no box");
    let segments = edges.iter().filter(|e| vis[e.edge]).map(|e| LineSegment::new(e.a, e.b)).collect();
    LineFrame { frame: index, camera: *cam, world_from_camera: pose, bbox, segments }
}

/// Points on the top and the four side faces of `g`, with uniform noise of ± `noise` metres.
fn surface_points(rng: &mut ChaCha8Rng, g: &ObjectGeometry, noise: f64) -> Vec<Point3<f64>> {
    let h = g.half_extents;
    let pose = g.world_from_object();
    (0..600)
        .map(|_| {
            let mut l =
                Vector3::new(rng.random_range(-h.x..h.x), rng.random_range(-h.y..h.y), rng.random_range(-h.z..h.z));
            match rng.random_range(0..4) {
                0 | 1 => l.z = h.z,
                2 => l.x = if rng.random_bool(0.5) { h.x } else { -h.x },
                _ => l.y = if rng.random_bool(0.5) { h.y } else { -h.y },
            }
            if noise > 0.0 {
                l += Vector3::from_fn(|_, _| rng.random_range(-noise..noise));
            }
            pose * Point3::from(l)
        })
        .collect()
}

#[test]
fn visible_edges_of_a_box_seen_from_above_one_side() {
    let g = cuboid(Vector3::new(0.0, 0.0, 0.05), 0.0, Vector3::new(0.1, 0.05, 0.05));
    // Above the box, in front of its +x face: top and +x faces visible → 4 + 4 − 1 = 7 edges.
    let vis = visible_edges(&g, &Point3::new(0.5, 0.0, 0.5));
    assert_eq!(vis.iter().filter(|v| **v).count(), 7);
    // Every bottom-ring edge except the one under the +x face is hidden.
    let corners = g.corners();
    for (k, (i, j)) in CUBE_EDGES.iter().enumerate() {
        let (a, b) = (corners[*i], corners[*j]);
        let bottom = a.z < 0.05 && b.z < 0.05;
        let on_plus_x = a.x > 0.0 && b.x > 0.0;
        if bottom && !on_plus_x {
            assert!(!vis[k], "edge {k} should be hidden");
        }
        if a.z > 0.05 && b.z > 0.05 {
            assert!(vis[k], "top edge {k} should be visible");
        }
    }
    // Straight above: only the top face → its 4 edges.
    let vis = visible_edges(&g, &Point3::new(0.0, 0.0, 1.0));
    assert_eq!(vis.iter().filter(|v| **v).count(), 4);
    // From above a corner: top + two sides → 9.
    let vis = visible_edges(&g, &Point3::new(0.5, 0.5, 0.5));
    assert_eq!(vis.iter().filter(|v| **v).count(), 9);
}

/// Synthetic version of the real failure: a thin book whose frames hold, besides pieces of its
/// visible edges (jittered ± 0.8 px), four table streaks parallel to its lowest projected bottom
/// edge, 4–14 px below it. With all 12 edges and segments only, the streaks pull the bottom edges
/// and the box loses IoU (measured 0.72 → 0.67, 0.76 → 0.73, 0.75 → 0.71); with the visible
/// edges, robust residuals, the point-to-surface and the extent terms it gains (→ 0.86, 0.79, 0.80).
#[test]
fn synthetic_thin_book_with_streaks() {
    let cam = camera();
    let t = truth();
    for seed in [1u64, 2, 3] {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut frames = Vec::new();
        for (i, eye) in eyes().into_iter().enumerate() {
            let pose = look_at(eye, t.center);
            let exact = exact_frame(i as u32, eye, &cam, &t);
            let mut segments = Vec::new();
            for s in &exact.segments {
                let (t0, t1) = (rng.random_range(0.0..0.2), rng.random_range(0.8..1.0));
                let p = |u: f64| [s.a[0] + u * (s.b[0] - s.a[0]), s.a[1] + u * (s.b[1] - s.a[1])];
                let j = |rng: &mut ChaCha8Rng| rng.random_range(-0.8..0.8);
                let (a, b) = (p(t0), p(t1));
                segments.push(LineSegment::new(
                    [a[0] + j(&mut rng), a[1] + j(&mut rng)],
                    [b[0] + j(&mut rng), b[1] + j(&mut rng)],
                ));
            }
            // Streaks: parallel to the box's long side, 4–14 px below the lowest projected edge.
            let edges = project_edges(&t, &cam, &pose);
            if let Some(low) = edges
                .iter()
                .filter(|e| CUBE_EDGES[e.edge].0 < 4 && CUBE_EDGES[e.edge].1 < 4)
                .max_by(|a, b| (a.a[1] + a.b[1]).total_cmp(&(b.a[1] + b.b[1])))
            {
                for _ in 0..4 {
                    let off = rng.random_range(4.0..14.0);
                    segments.push(LineSegment::new([low.a[0], low.a[1] + off], [low.b[0], low.b[1] + off]));
                }
            }
            frames.push(LineFrame { segments, ..exact });
        }
        let pts = surface_points(&mut rng, &t, 0.002);
        let run_with = |refine: RefineConfig| {
            // Four iForest passes, no readmission: the refinement variants on one cleaned cloud.
            let iforest = IForestConfig { passes: 4, readmit_rings: 0, ..Default::default() };
            let mut est = ObjectEstimator::new(Shape::Cuboid, ParamConfig { refine, iforest, ..Default::default() });
            for f in &frames {
                est.add_frame(f.clone());
            }
            est.estimate(&pts).unwrap()
        };
        let old = run_with(previous_refinement());
        let new = run_with(RefineConfig::default());
        let l = new.stages.lines.map_or(0.0, |g| iou3d(&g, &t));
        let o = old.stages.refined.map_or(0.0, |g| iou3d(&g, &t));
        let n = iou3d(&new.geometry, &t);
        eprintln!("seed {seed}: lines {l:.3} previous {o:.3} new {n:.3} ({:?})", new.stage);
        assert!(n >= l, "seed {seed}: refined {n:.3} < lines {l:.3}");
        assert!(n > o, "seed {seed}: refined {n:.3} <= previous {o:.3}");
    }
}
