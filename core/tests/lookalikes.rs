//! Look-alikes side by side (seed 5): rows of identical cans and pairs of identical blocks a few
//! millimetres apart, rendered exactly (ray-cast depth with 1 mm noise, 640 x 480, 58° vertical
//! field of view like the simulator's hand camera) from a handful of oblique views, detected by
//! their visible masks (one tight box per object with at least 150 visible pixels, as the
//! simulator's detector), fused by the default [`ObjectPipeline`] (ensemble association, then
//! consolidation) with a refresh after every view.
//!
//! Envelopes pinned: 10 cans of radius 3.3 cm in a row with 3 mm gaps give 10 map objects, each
//! can matched by one with 3D IoU ≥ 0.7 (with neither the look-alike split nor the co-observation
//! guard: 4 objects); two 5 cm blocks 2 mm apart give 2 objects, one at each block. Counter-tests: one can seen from views all around (each view shows another side) and
//! a single block seen in several partial views (parts hidden by the image border) stay one map
//! object. Label errors: a can called a cup from 6 of 16 views around it stays one object (with
//! `relabel_co_observed_share` = 0.25, or with the default overlap fold; two with neither), and a false-positive box over a bottle in 3
//! views leaves no second object (with `consolidate_covered_share` = 0.9; one more without). Both
//! folds are off by default (studies/mesh_oversplit).

// Test code may unwrap (clippy.toml allows it in #[test] functions; this covers their helpers).
#![allow(clippy::unwrap_used, clippy::expect_used)]

use nalgebra::{Matrix3, Rotation3, UnitQuaternion, Vector3};
use objslam_core::frame::{DepthImage, Detection, Frame};
use objslam_core::geometry::{iou3d, Box2, ObjectGeometry, PinholeCamera, Se3, Shape};
use objslam_core::map::{Label, ObjectMap};
use objslam_core::pipeline::{ObjectPipeline, PipelineConfig};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Visible pixels an object needs to be detected (the simulator's `min_pixels`).
const MIN_PIXELS: usize = 150;

/// A ground-truth object standing on the table (z = 0).
#[derive(Debug, Clone, Copy)]
struct Truth {
    label: Label,
    geometry: ObjectGeometry,
}

fn can(x: f64, y: f64, radius: f64, height: f64) -> Truth {
    Truth {
        label: Label::Can,
        geometry: ObjectGeometry {
            shape: Shape::Cylinder,
            center: Vector3::new(x, y, height / 2.0),
            yaw_rad: 0.0,
            half_extents: Vector3::new(radius, radius, height / 2.0),
        },
    }
}

fn block(x: f64, y: f64, side: f64) -> Truth {
    Truth {
        label: Label::Block,
        geometry: ObjectGeometry {
            shape: Shape::Cuboid,
            center: Vector3::new(x, y, side / 2.0),
            yaw_rad: 0.0,
            half_extents: Vector3::new(side / 2.0, side / 2.0, side / 2.0),
        },
    }
}

/// A camera at `eye` looking at `target` (OpenCV axes: x right, y down, z forward; world z up).
fn look_at(eye: Vector3<f64>, target: Vector3<f64>) -> Se3 {
    let forward = (target - eye).normalize();
    let right = forward.cross(&Vector3::z()).normalize();
    let down = forward.cross(&right);
    let rotation = Rotation3::from_matrix_unchecked(Matrix3::from_columns(&[right, down, forward]));
    Se3::from_parts(eye.into(), UnitQuaternion::from_rotation_matrix(&rotation))
}

/// Ray parameter of the first hit of `origin + t dir` with an object (axis-aligned boxes and
/// upright cylinders), if any.
fn hit(t: &Truth, origin: &Vector3<f64>, dir: &Vector3<f64>) -> Option<f64> {
    let g = &t.geometry;
    let (c, h) = (g.center, g.half_extents);
    match g.shape {
        Shape::Cuboid => {
            let (mut t0, mut t1) = (0.0f64, f64::INFINITY);
            for a in 0..3 {
                let lo = (c[a] - h[a] - origin[a]) / dir[a];
                let hi = (c[a] + h[a] - origin[a]) / dir[a];
                t0 = t0.max(lo.min(hi));
                t1 = t1.min(lo.max(hi));
            }
            (t0 <= t1 && t0 > 0.0).then_some(t0)
        }
        Shape::Cylinder => {
            let r = h.x;
            let (z0, z1) = (c.z - h.z, c.z + h.z);
            let mut best = f64::INFINITY;
            // Side: (o + t d - c)_xy² = r².
            let (ox, oy) = (origin.x - c.x, origin.y - c.y);
            let a = dir.x * dir.x + dir.y * dir.y;
            let b = 2.0 * (ox * dir.x + oy * dir.y);
            let cc = ox * ox + oy * oy - r * r;
            let disc = b * b - 4.0 * a * cc;
            if a > 0.0 && disc >= 0.0 {
                let s = (-b - disc.sqrt()) / (2.0 * a);
                let z = origin.z + s * dir.z;
                if s > 0.0 && (z0..=z1).contains(&z) {
                    best = s;
                }
            }
            // Top cap.
            if dir.z.abs() > 0.0 {
                let s = (z1 - origin.z) / dir.z;
                let p = origin + dir * s;
                if s > 0.0 && (p.x - c.x).powi(2) + (p.y - c.y).powi(2) <= r * r {
                    best = best.min(s);
                }
            }
            best.is_finite().then_some(best)
        }
    }
}

/// Render one frame: depth (optical-axis depth, 1 mm noise) and one detection per object with
/// at least [`MIN_PIXELS`] visible pixels (the tight box of its visible mask).
fn render(index: u32, camera: &PinholeCamera, pose: &Se3, scene: &[Truth], rng: &mut ChaCha8Rng) -> Frame {
    let (w, h) = (camera.width, camera.height);
    let mut data = vec![0.0f32; (w * h) as usize];
    let mut masks: Vec<(usize, [f64; 4])> = vec![(0, [f64::INFINITY, f64::INFINITY, 0.0, 0.0]); scene.len()];
    let origin = pose.translation.vector;
    for v in 0..h {
        for u in 0..w {
            let dir = pose.rotation * camera.unproject_pixel(u, v, 1.0).coords;
            let mut best = if dir.z < 0.0 { -origin.z / dir.z } else { f64::INFINITY };
            let mut who = None;
            for (i, t) in scene.iter().enumerate() {
                if let Some(s) = hit(t, &origin, &dir) {
                    if s < best {
                        best = s;
                        who = Some(i);
                    }
                }
            }
            if best.is_finite() {
                let noise: f64 = (0..4).map(|_| rng.random_range(-0.001..0.001)).sum::<f64>() / 2.0;
                data[(v * w + u) as usize] = (best + noise) as f32;
            }
            if let Some(i) = who {
                let m = &mut masks[i];
                m.0 += 1;
                let (fu, fv) = (f64::from(u), f64::from(v));
                m.1 = [m.1[0].min(fu), m.1[1].min(fv), m.1[2].max(fu + 1.0), m.1[3].max(fv + 1.0)];
            }
        }
    }
    let detections = scene
        .iter()
        .zip(&masks)
        .filter(|(_, m)| m.0 >= MIN_PIXELS)
        .map(|(t, m)| Detection { bbox: Box2::new(m.1[0], m.1[1], m.1[2], m.1[3]), label: t.label, score: 0.9 })
        .collect();
    Frame { index, camera: *camera, depth: DepthImage::new(w, h, data).unwrap(), world_from_camera: *pose, detections }
}

/// Fuse the views with the default pipeline (refresh after each view) and return the map.
fn map_of(scene: &[Truth], views: &[Se3], config: PipelineConfig) -> ObjectMap {
    map_with(scene, views, config, |_| {})
}

/// [`map_of`] with each rendered frame passed through `detector` first (label errors, false
/// positives).
fn map_with(scene: &[Truth], views: &[Se3], config: PipelineConfig, detector: impl Fn(&mut Frame)) -> ObjectMap {
    let camera = PinholeCamera::from_fovy(640, 480, 58f64.to_radians()).unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let mut pipeline = ObjectPipeline::new(config).unwrap();
    for (i, pose) in views.iter().enumerate() {
        let mut frame = render(i as u32, &camera, pose, scene, &mut rng);
        detector(&mut frame);
        pipeline.update(&frame, None).unwrap();
        pipeline.refresh_estimates();
    }
    pipeline.map()
}

/// Per truth object, the best 3D IoU of a same-label map object.
fn best_ious(scene: &[Truth], map: &ObjectMap) -> Vec<f64> {
    scene
        .iter()
        .map(|t| {
            map.objects
                .iter()
                .filter(|o| o.label == t.label)
                .map(|o| iou3d(&o.geometry(), &t.geometry))
                .fold(0.0, f64::max)
        })
        .collect()
}

/// Views from the robot's side of the table and from above its sides, all aimed at `target`.
fn views_around(target: Vector3<f64>) -> Vec<Se3> {
    [
        [0.05, -0.25, 0.45],
        [0.05, 0.0, 0.50],
        [0.05, 0.25, 0.45],
        [0.20, -0.40, 0.40],
        [0.20, 0.40, 0.40],
        [0.30, 0.0, 0.65],
    ]
    .iter()
    .map(|e| look_at(Vector3::new(e[0], e[1], e[2]), target))
    .collect()
}

fn report(name: &str, scene: &[Truth], map: &ObjectMap) -> Vec<f64> {
    let ious = best_ious(scene, map);
    eprintln!("{name}: {} map objects for {}; IoU {:.2?}", map.len(), scene.len(), ious);
    for o in &map.objects {
        let g = o.geometry();
        eprintln!(
            "  id {} {:?} c=({:.3},{:.3},{:.3}) half=({:.3},{:.3},{:.3}) obs {}",
            o.id,
            o.label,
            g.center.x,
            g.center.y,
            g.center.z,
            g.half_extents.x,
            g.half_extents.y,
            g.half_extents.z,
            o.observations.len()
        );
    }
    ious
}

/// The row test's pipeline: the size estimate with four iForest passes (a single pass, the
/// default, leaves one can's cloud with its neighbours' points: IoU 0.22).
fn config_row() -> PipelineConfig {
    let mut config = PipelineConfig::default();
    config.param.iforest.passes = 4;
    config.param.iforest.readmit_rings = 0;
    config
}

fn row_of_cans(gap_m: f64) -> Vec<Truth> {
    let r = 0.033;
    (0..10).map(|i| can(0.45, (f64::from(i) - 4.5) * (2.0 * r + gap_m), r, 0.11)).collect()
}

#[test]
fn a_row_of_ten_cans_3_mm_apart_is_ten_objects() {
    let scene = row_of_cans(0.003);
    let views = views_around(Vector3::new(0.45, 0.0, 0.05));
    // The look-alike separation under test.
    let map = map_of(&scene, &views, config_row());
    let ious = report("row", &scene, &map);
    // Without the detector's per-object boxes as evidence (no look-alike split of the local
    // clouds, no co-observation guard), consolidation folds neighbours: 4 objects for 10.
    let mut blind = PipelineConfig { consolidate_co_observed_frames: 0, ..PipelineConfig::default() };
    blind.local.lookalike_split = false;
    let merged = map_of(&scene, &views, blind);
    report("row, co-observation guard off", &scene, &merged);
    assert!(merged.len() < 10);
    assert_eq!(map.len(), 10);
    // Every can is boxed in the frames that see it whole (hidden ones do not count against it).
    let mut evidence = config_row();
    evidence.existence_ratio = 0.3;
    assert_eq!(map_of(&scene, &views, evidence).len(), 10);
    assert!(ious.iter().all(|v| *v >= 0.7), "{ious:?}");
}

#[test]
fn two_blocks_2_mm_apart_are_two_objects() {
    let scene = [block(0.5, -0.026, 0.05), block(0.5, 0.026, 0.05)];
    let map = map_of(&scene, &views_around(Vector3::new(0.5, 0.0, 0.025)), PipelineConfig::default());
    let ious = report("pair", &scene, &map);
    assert_eq!(map.len(), 2);
    // Each block has its own estimate (the cuboid estimates without line segments stop at the
    // iForest stage, about 2 cm high in z here: IoU 0.33; two merged blocks would score under 0.2).
    assert!(ious.iter().all(|v| *v >= 0.25), "{ious:?}");
    let ys: Vec<f64> = map.objects.iter().map(|o| o.geometry().center.y).collect();
    assert!(ys.iter().any(|y| (y + 0.026).abs() < 0.01) && ys.iter().any(|y| (y - 0.026).abs() < 0.01), "{ys:?}");
}

#[test]
fn one_can_seen_from_all_sides_stays_one_object() {
    let scene = [can(0.5, 0.0, 0.033, 0.11)];
    let target = Vector3::new(0.5, 0.0, 0.05);
    let views: Vec<Se3> = (0..8)
        .map(|k| {
            let a = f64::from(k) * std::f64::consts::TAU / 8.0;
            look_at(target + Vector3::new(0.35 * a.cos(), 0.35 * a.sin(), 0.25 + 0.05 * f64::from(k % 2)), target)
        })
        .collect();
    let map = map_of(&scene, &views, PipelineConfig::default());
    let ious = report("one can", &scene, &map);
    assert_eq!(map.len(), 1);
    assert!(ious[0] >= 0.7, "{ious:?}");
}

#[test]
fn one_block_in_partial_views_stays_one_object() {
    // Close views aimed beside the block: each shows a different part, cut by the image border.
    let scene = [block(0.5, 0.0, 0.06)];
    let views: Vec<Se3> =
        [[0.30, -0.12, 0.22, 0.03], [0.30, 0.12, 0.22, -0.03], [0.5, -0.25, 0.25, 0.0], [0.30, 0.0, 0.30, 0.0]]
            .iter()
            .chain([[0.70, 0.15, 0.25, 0.02], [0.32, -0.05, 0.20, 0.04]].iter())
            .map(|e| look_at(Vector3::new(e[0], e[1], e[2]), Vector3::new(0.5, e[3], 0.03)))
            .collect();
    let map = map_of(&scene, &views, PipelineConfig::default());
    let ious = report("partial block", &scene, &map);
    assert_eq!(map.len(), 1);
    assert!(ious[0] >= 0.4, "{ious:?}");
}

/// Views on a ring around `target` (radius 0.35 m, alternating heights), `n` of them.
fn ring(target: Vector3<f64>, n: u32) -> Vec<Se3> {
    (0..n)
        .map(|k| {
            let a = f64::from(k) * std::f64::consts::TAU / f64::from(n);
            look_at(target + Vector3::new(0.35 * a.cos(), 0.35 * a.sin(), 0.25 + 0.05 * f64::from(k % 2)), target)
        })
        .collect()
}

#[test]
fn a_can_labelled_cup_from_a_range_of_directions_is_one_object() {
    // A learned detector's label error persists over a range of viewing directions: here 6 of 16
    // views around the can call it a cup. Too many for the vote ratio (10 / 6 < 4), yet the two
    // labels are never boxed in one frame: one object seen under two labels.
    let scene = [can(0.5, 0.0, 0.033, 0.11)];
    let views = ring(Vector3::new(0.5, 0.0, 0.05), 16);
    let confuse = |f: &mut Frame| {
        if (3..9).contains(&f.index) {
            for d in &mut f.detections {
                d.label = Label::Cup;
            }
        }
    };
    let fold = PipelineConfig { relabel_co_observed_share: 0.25, ..PipelineConfig::default() };
    let map = map_with(&scene, &views, fold, confuse);
    let ious = report("can labelled cup from 6 of 16 views", &scene, &map);
    let split = map_with(
        &scene,
        &views,
        PipelineConfig { relabel_co_observed_share: 0.0, consolidate_overlap_iou: 2.0, ..PipelineConfig::default() },
        confuse,
    );
    report("same, co-observation share and overlap fold off", &scene, &split);
    // The overlap fold alone (the default) also sees one object: the two labels' estimates
    // occupy the same volume.
    let overlap = map_with(&scene, &views, PipelineConfig::default(), confuse);
    let overlap_ious = report("same, defaults (overlap fold)", &scene, &overlap);
    assert_eq!(split.len(), 2);
    assert_eq!(map.len(), 1);
    assert_eq!(overlap.len(), 1);
    assert!(ious[0] >= 0.7, "{ious:?}");
    assert!(overlap_ious[0] >= 0.7, "{overlap_ious:?}");
}

#[test]
fn a_false_positive_over_a_bottle_stays_out_of_the_map() {
    // A false-positive box (labelled can) over a bottle in 3 of 16 views: its depth samples are
    // the bottle's own, boxed in the same frames, so the co-observation guard alone keeps it
    // as a second object once it has `min_observations`.
    let bottle = Truth {
        label: Label::Bottle,
        geometry: ObjectGeometry {
            shape: Shape::Cylinder,
            center: Vector3::new(0.5, 0.0, 0.085),
            yaw_rad: 0.0,
            half_extents: Vector3::new(0.028, 0.028, 0.085),
        },
    };
    let scene = [bottle];
    let views = ring(Vector3::new(0.5, 0.0, 0.08), 16);
    let phantom = |f: &mut Frame| {
        if (5..8).contains(&f.index) {
            // A false positive over the bottle (its box a little larger than the bottle's): its
            // samples are the bottle's surface, which no occluder test removes.
            let b = f.detections[0].bbox;
            let over =
                Box2::new((b.min[0] - 10.0).max(0.0), (b.min[1] - 10.0).max(0.0), b.max[0] + 10.0, b.max[1] + 10.0);
            f.detections.push(Detection { bbox: over, label: Label::Can, score: 0.4 });
        }
    };
    let fold = PipelineConfig { consolidate_covered_share: 0.9, ..PipelineConfig::default() };
    let map = map_with(&scene, &views, fold, phantom);
    let ious = report("bottle under a can box in 3 of 16 views", &scene, &map);
    let kept = map_with(
        &scene,
        &views,
        PipelineConfig { consolidate_covered_share: 2.0, ..PipelineConfig::default() },
        phantom,
    );
    report("same, covered-phantom fold off", &scene, &kept);
    // Existence evidence does not replace the fold here: a box of another label over the whole
    // bottle is what a label confusion looks like, so its frames do not count as the phantom's
    // absence (the rule itself: `pipeline::tests::existence_ratio_*`).
    let evidence = map_with(
        &scene,
        &views,
        PipelineConfig { consolidate_covered_share: 2.0, existence_ratio: 0.3, ..PipelineConfig::default() },
        phantom,
    );
    report("same, existence ratio 0.3", &scene, &evidence);
    assert_eq!(evidence.len(), 2);
    assert_eq!(kept.len(), 2);
    assert_eq!(map.len(), 1);
    assert_eq!(map.objects[0].label, Label::Bottle);
    assert!(ious[0] >= 0.7, "{ious:?}");
}
