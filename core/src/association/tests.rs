//! Tests of the associator on synthetic scenes (seeded): blocks on a table seen by a top-down
//! camera; each local cloud is a fresh uniform sample of the block's volume plus Gaussian-free
//! jitter, each detection the projected box of the block.

use super::*;
use crate::geometry::project_geometry;
use crate::geometry::{ObjectGeometry, Shape};
use nalgebra::{Isometry3, Translation3, UnitQuaternion};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn camera() -> PinholeCamera {
    PinholeCamera::from_fovy(320, 240, 1.0).unwrap()
}

/// Camera `height` above (x, y) looking straight down (OpenCV z forward = world −z).
fn top_down(x: f64, y: f64, height: f64) -> Se3 {
    let rot = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI);
    Isometry3::from_parts(Translation3::new(x, y, height), rot)
}

struct Block {
    center: Vector3<f64>,
    half: Vector3<f64>,
    label: Label,
}

impl Block {
    fn new(x: f64, y: f64, half: f64, label: Label) -> Self {
        Self { center: Vector3::new(x, y, half), half: Vector3::new(half, half, half), label }
    }

    fn local(&self, rng: &mut ChaCha8Rng, pose: &Se3, n: usize) -> Option<LocalObject> {
        let g = ObjectGeometry { shape: Shape::Cuboid, center: self.center, yaw_rad: 0.0, half_extents: self.half };
        let bbox = project_geometry(&g, &camera(), pose)?;
        let points = (0..n)
            .map(|_| {
                let d = Vector3::new(
                    rng.random_range(-1.0..1.0) * self.half.x,
                    rng.random_range(-1.0..1.0) * self.half.y,
                    rng.random_range(-1.0..1.0) * self.half.z,
                );
                Point3::from(self.center + d)
            })
            .collect();
        Some(LocalObject { detection: Detection { bbox, label: self.label, score: 0.9 }, points_in_world: points })
    }
}

fn run(assoc: &mut Associator, blocks: &[Block], frames: &[(u32, Se3)], rng: &mut ChaCha8Rng) -> Vec<FrameAssociation> {
    frames
        .iter()
        .map(|(f, pose)| {
            let locals: Vec<LocalObject> = blocks.iter().filter_map(|b| b.local(rng, pose, 150)).collect();
            assoc.associate_frame(*f, &camera(), pose, &locals).unwrap()
        })
        .collect()
}

fn associator(mode: AssociationMode) -> Associator {
    Associator::new(AssociationConfig { mode, ..AssociationConfig::default() }).unwrap()
}

#[test]
fn single_object_is_tracked_in_every_mode() {
    for mode in AssociationMode::ALL {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let mut a = associator(mode);
        let blocks = [Block::new(0.5, 0.0, 0.03, Label::Block)];
        let frames: Vec<(u32, Se3)> = (0..6).map(|i| (i, top_down(0.48 + 0.01 * f64::from(i), 0.0, 0.5))).collect();
        let out = run(&mut a, &blocks, &frames, &mut rng);
        assert_eq!(out[0].detections[0].decision, Decision::New { object_id: 0 }, "{mode:?}");
        for f in &out[1..] {
            assert_eq!(f.detections[0].decision, Decision::Existing { object_id: 0 }, "{mode:?} frame {}", f.frame);
            assert_eq!(f.detections[0].tests.projected_iou, Some(true));
        }
        assert_eq!(a.len(), 1, "{mode:?}");
        let o = a.object(0).expect("object 0");
        assert_eq!(o.centroid_history().len(), 6);
        assert_eq!(o.observations().len(), 6);
        assert_eq!(o.label(), Label::Block);
        let c = o.mean_centroid().unwrap_or_else(Vector3::zeros);
        assert!((c - blocks[0].center).norm() < 0.005, "{c:?}");
    }
}

#[test]
fn nearby_objects_stay_separate_and_labels_must_agree() {
    let mut rng = ChaCha8Rng::seed_from_u64(2);
    let mut a = associator(AssociationMode::Ensemble);
    let blocks = [
        Block::new(0.45, -0.06, 0.025, Label::Block),
        Block::new(0.45, 0.06, 0.025, Label::Block),
        Block::new(0.55, 0.0, 0.025, Label::Book),
    ];
    let frames: Vec<(u32, Se3)> = (0..8).map(|i| (i, top_down(0.5, -0.02 + 0.005 * f64::from(i), 0.5))).collect();
    let out = run(&mut a, &blocks, &frames, &mut rng);
    assert_eq!(a.len(), 3);
    for f in &out[1..] {
        let ids: Vec<Option<u32>> = f.detections.iter().map(|d| d.decision.object_id()).collect();
        assert_eq!(ids, vec![Some(0), Some(1), Some(2)], "frame {}", f.frame);
        assert!(f.merges.is_empty());
    }
    // A detection with another label over object 0 cannot join it.
    let pose = top_down(0.5, 0.0, 0.5);
    let mut cup = blocks[0].local(&mut rng, &pose, 150).expect("visible");
    cup.detection.label = Label::Cup;
    let r = a.associate_frame(20, &camera(), &pose, &[cup]).unwrap();
    assert_eq!(r.detections[0].decision, Decision::New { object_id: 3 });
}

#[test]
fn iou_alone_loses_an_object_after_a_gap_the_ensemble_does_not() {
    let blocks = [Block::new(0.5, 0.05, 0.03, Label::Block)];
    let mut frames: Vec<(u32, Se3)> = (0..4).map(|i| (i, top_down(0.5, 0.0, 0.5))).collect();
    // Unseen for frames 4..11, then seen from elsewhere.
    frames.push((12, top_down(0.42, 0.1, 0.45)));
    let mut counts = BTreeMap::new();
    for mode in AssociationMode::ALL {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let mut a = associator(mode);
        let out = run(&mut a, &blocks, &frames, &mut rng);
        let last = out.last().map(|f| f.detections[0]).expect("frames");
        counts.insert(mode.as_str(), (a.len(), last.tests));
    }
    assert_eq!(counts["iou"].0, 2, "{counts:?}");
    for m in ["iou_np", "iou_t", "ensemble"] {
        assert_eq!(counts[m].0, 1, "{m}: {counts:?}");
    }
    let e = counts["ensemble"].1;
    assert_eq!(e.motion_iou, None, "no recent sighting: M-IoU not applicable");
    assert_eq!(e.projected_iou, Some(true));
    assert_eq!(counts["iou_t"].1.t_test, Some(true));
    assert_eq!(counts["iou_np"].1.nonparametric, Some(true));
}

#[test]
fn a_detection_is_used_once_and_an_object_once_per_frame() {
    let mut rng = ChaCha8Rng::seed_from_u64(4);
    let mut a = associator(AssociationMode::Ensemble);
    let b = Block::new(0.5, 0.0, 0.03, Label::Block);
    let pose = top_down(0.5, 0.0, 0.5);
    for f in 0..3 {
        let l = b.local(&mut rng, &pose, 150).expect("visible");
        a.associate_frame(f, &camera(), &pose, &[l]).unwrap();
    }
    // Two detections of the same object in one frame: one updates it, the other starts a new one.
    let l1 = b.local(&mut rng, &pose, 150).expect("visible");
    let l2 = b.local(&mut rng, &pose, 150).expect("visible");
    let r = a.associate_frame(3, &camera(), &pose, &[l1, l2]).unwrap();
    let decisions: Vec<Decision> = r.detections.iter().map(|d| d.decision).collect();
    assert_eq!(decisions, vec![Decision::Existing { object_id: 0 }, Decision::New { object_id: 1 }]);
    // Seen in the same frame: never merged, even though their centroids agree.
    for f in 4..8 {
        let l1 = b.local(&mut rng, &pose, 150).expect("visible");
        let l2 = b.local(&mut rng, &pose, 150).expect("visible");
        let r = a.associate_frame(f, &camera(), &pose, &[l1, l2]).unwrap();
        assert!(r.merges.is_empty());
        let mut ids: Vec<Option<u32>> = r.detections.iter().map(|d| d.decision.object_id()).collect();
        ids.sort();
        assert_eq!(ids, vec![Some(0), Some(1)], "frame {f}");
    }
}

/// Insert an object with a given centroid history directly (white-box).
fn insert(a: &mut Associator, id: u32, label: Label, centroids: &[Vector3<f64>], frames: std::ops::Range<u32>) {
    let mut o = GlobalObject::new(id, a.config.voxel_m);
    o.label_votes[label.index()] = centroids.len() as u32;
    for (f, c) in frames.zip(centroids) {
        o.push_history(CentroidSample { frame: f, centroid_in_world: *c }, 100);
        o.frames_seen.insert(f);
        o.observations.push(ObservationRecord {
            observation: Observation {
                frame: f,
                bbox: Box2::new(0.0, 0.0, 1.0, 1.0),
                score: 1.0,
                centroid_in_world: *c,
            },
            detection_index: 0,
            label,
        });
        o.add_points(&[Point3::from(*c)], 4000);
    }
    a.objects.insert(id, o);
    a.next_id = a.next_id.max(id + 1);
}

fn cloud(rng: &mut ChaCha8Rng, c: Vector3<f64>, sd: f64, n: usize) -> Vec<Vector3<f64>> {
    (0..n)
        .map(|_| c + Vector3::new(rng.random_range(-sd..sd), rng.random_range(-sd..sd), rng.random_range(-sd..sd)))
        .collect()
}

#[test]
fn duplicates_merge_by_two_sample_t_test() {
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let mut a = associator(AssociationMode::Ensemble);
    let c = Vector3::new(0.5, 0.0, 0.03);
    insert(&mut a, 0, Label::Cup, &cloud(&mut rng, c, 0.004, 8), 0..8);
    insert(&mut a, 1, Label::Cup, &cloud(&mut rng, c, 0.004, 5), 10..15);
    // Different object 6 cm away, and a same-place object with another label.
    insert(&mut a, 2, Label::Cup, &cloud(&mut rng, c + Vector3::new(0.06, 0.0, 0.0), 0.004, 6), 20..26);
    insert(&mut a, 3, Label::Can, &cloud(&mut rng, c, 0.004, 6), 30..36);
    let touched: BTreeSet<u32> = [1, 2, 3].into_iter().collect();
    let merges = a.merge_duplicates(&touched);
    assert_eq!(merges.len(), 1, "{merges:?}");
    assert_eq!((merges[0].kept_id, merges[0].removed_id), (0, 1));
    assert!(merges[0].p_value >= 0.05);
    let ids: Vec<u32> = a.objects().map(GlobalObject::id).collect();
    assert_eq!(ids, vec![0, 2, 3]);
    let o = a.object(0).expect("kept");
    assert_eq!(o.centroid_history().len(), 13);
    assert_eq!(o.observations().len(), 13);
    assert!(o.observations().windows(2).all(|w| w[0].observation.frame <= w[1].observation.frame));
    assert_eq!(o.label_votes()[Label::Cup.index()], 13);
    // Other modes never merge.
    let mut b = associator(AssociationMode::IouT);
    insert(&mut b, 0, Label::Cup, &cloud(&mut rng, c, 0.004, 8), 0..8);
    insert(&mut b, 1, Label::Cup, &cloud(&mut rng, c, 0.004, 5), 10..15);
    let r = b.associate_frame(40, &camera(), &top_down(0.5, 0.0, 0.5), &[]).unwrap();
    assert!(r.merges.is_empty());
    assert_eq!(b.len(), 2);
}

#[test]
fn motion_prediction_is_uniform_motion() {
    let cfg = AssociationConfig { motion_max_gap_frames: 2, ..AssociationConfig::default() };
    let mut o = GlobalObject::new(0, 0.005);
    let rec = |frame: u32, u: f64| ObservationRecord {
        observation: Observation {
            frame,
            bbox: Box2::new(u, 10.0, u + 20.0, 30.0),
            score: 1.0,
            centroid_in_world: Vector3::zeros(),
        },
        detection_index: 0,
        label: Label::Block,
    };
    assert_eq!(predicted_box(&cfg, 5, &o), None);
    o.observations.push(rec(4, 100.0));
    // One sighting: zero velocity (or nothing with the paper's strict rule).
    assert_eq!(predicted_box(&cfg, 5, &o), Some(Box2::new(100.0, 10.0, 120.0, 30.0)));
    let strict = AssociationConfig { motion_zero_velocity_fallback: false, ..cfg };
    assert_eq!(predicted_box(&strict, 5, &o), None);
    o.observations.push(rec(5, 104.0));
    assert_eq!(predicted_box(&cfg, 6, &o), Some(Box2::new(108.0, 10.0, 128.0, 30.0)));
    assert_eq!(predicted_box(&cfg, 7, &o), Some(Box2::new(112.0, 10.0, 132.0, 30.0)));
    assert_eq!(predicted_box(&cfg, 8, &o), None, "gap 3 > 2");
    assert_eq!(predicted_box(&cfg, 5, &o), None, "same frame");
    // Sightings 2 frames apart: velocity per frame halves.
    o.observations.push(rec(7, 112.0));
    assert_eq!(predicted_box(&cfg, 8, &o), Some(Box2::new(116.0, 10.0, 136.0, 30.0)));
}

#[test]
fn projected_box_trims_ignores_points_behind_and_clips() {
    let cam = camera();
    let pose = top_down(0.5, 0.0, 0.5);
    let cfw = pose.inverse();
    let cfg = AssociationConfig { projected_box_trim: 0.0, ..AssociationConfig::default() };
    let pts: Vec<Point3<f64>> =
        [(-0.02, -0.02), (0.02, 0.02), (0.0, 0.0)].iter().map(|(x, y)| Point3::new(0.5 + x, *y, 0.0)).collect();
    let b = projected_box(&pts, &cam, &cfw, &cfg).expect("box");
    let f = cam.fx;
    assert!((b.width() - f * 0.04 / 0.5).abs() < 1e-9, "{b:?}");
    // A point above the camera (behind it) is ignored.
    let mut with_behind = pts.clone();
    with_behind.push(Point3::new(0.9, 0.3, 1.0));
    assert_eq!(projected_box(&with_behind, &cam, &cfw, &cfg), Some(b));
    // Too few points in front → not applicable; a far-away cloud misses the image.
    assert_eq!(projected_box(&pts[..2], &cam, &cfw, &cfg), None);
    let far: Vec<Point3<f64>> = pts.iter().map(|p| p + Vector3::new(5.0, 0.0, 0.0)).collect();
    assert_eq!(projected_box(&far, &cam, &cfw, &cfg), None);
    // Trim drops a stray point.
    let mut stray: Vec<Point3<f64>> =
        (0..100).map(|i| Point3::new(0.5 + 0.0004 * f64::from(i - 50), 0.001 * f64::from(i % 10), 0.0)).collect();
    stray.push(Point3::new(0.6, 0.0, 0.0));
    let trimmed = AssociationConfig { projected_box_trim: 0.02, ..cfg };
    let bt = projected_box(&stray, &cam, &cfw, &trimmed).expect("box");
    assert!(bt.max[0] < cam.cx + f * 0.03 / 0.5, "{bt:?}");
}

#[test]
fn np_and_t_tests_accept_same_and_reject_shifted() {
    let mut rng = ChaCha8Rng::seed_from_u64(6);
    let cfg = AssociationConfig { np_max_points: 100, t_min_std_m: 0.002, ..AssociationConfig::default() };
    let pts = |rng: &mut ChaCha8Rng, dx: f64| -> Vec<Point3<f64>> {
        cloud(rng, Vector3::new(0.5 + dx, 0.0, 0.03), 0.03, 300).into_iter().map(Point3::from).collect()
    };
    let a = SortedAxes::new(&pts(&mut rng, 0.0), cfg.np_max_points);
    assert!(a.0.iter().all(|v| v.len() == 100 && v.windows(2).all(|w| w[0] <= w[1])));
    let b = SortedAxes::new(&pts(&mut rng, 0.0), cfg.np_max_points);
    let c = SortedAxes::new(&pts(&mut rng, 0.02), cfg.np_max_points);
    assert_eq!(np_test(&cfg, &a, &b), Some(true));
    assert_eq!(np_test(&cfg, &a, &c), Some(false));
    assert_eq!(np_test(&cfg, &a, &SortedAxes::default()), None);
    assert_eq!(quantile_subsample(vec![0.0, 1.0, 2.0, 3.0], 2), vec![1.0, 3.0]);
    assert_eq!(quantile_subsample(vec![5, 6, 7, 8, 9, 10], 3), vec![6, 8, 10]);
    assert_eq!(quantile_subsample(vec![5, 6], 3), vec![5, 6]);

    let mut o = GlobalObject::new(0, 0.005);
    let base = Vector3::new(0.5, 0.0, 0.03);
    for (f, c) in cloud(&mut rng, base, 0.003, 10).into_iter().enumerate() {
        o.push_history(CentroidSample { frame: f as u32, centroid_in_world: c }, 100);
    }
    assert_eq!(t_test(&cfg, &base, &o), Some(true));
    assert_eq!(t_test(&cfg, &(base + Vector3::new(0.02, 0.0, 0.0)), &o), Some(false));
    // Zero-variance history: the floor decides; without a floor the test is not applicable.
    let mut z = GlobalObject::new(1, 0.005);
    for f in 0..4 {
        z.push_history(CentroidSample { frame: f, centroid_in_world: base }, 100);
    }
    assert_eq!(t_test(&cfg, &(base + Vector3::new(0.001, 0.0, 0.0)), &z), Some(true));
    assert_eq!(t_test(&cfg, &(base + Vector3::new(0.02, 0.0, 0.0)), &z), Some(false));
    let no_floor = AssociationConfig { t_min_std_m: 0.0, ..cfg };
    assert_eq!(t_test(&no_floor, &base, &z), None);
    // Too short a history: not applicable.
    z.history.truncate(2);
    assert_eq!(t_test(&cfg, &base, &z), None);
}

#[test]
fn bad_input_is_defined() {
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let mut a = associator(AssociationMode::Ensemble);
    let pose = top_down(0.5, 0.0, 0.5);
    let b = Block::new(0.5, 0.0, 0.03, Label::Block);
    let good = b.local(&mut rng, &pose, 50).expect("visible");
    let mut empty = good.clone();
    empty.points_in_world.clear();
    let mut single = good.clone();
    single.points_in_world.truncate(1);
    let mut nan = good.clone();
    nan.points_in_world.push(Point3::new(f64::NAN, 0.0, 0.0));
    nan.points_in_world.push(Point3::new(0.0, f64::INFINITY, 0.0));
    let mut outside = good.clone();
    outside.detection.bbox = Box2::new(-50.0, -50.0, -10.0, -10.0);
    let mut nan_box = good.clone();
    nan_box.detection.bbox = Box2 { min: [f64::NAN, 0.0], max: [10.0, 10.0] };
    let r = a.associate_frame(0, &camera(), &pose, &[empty, single.clone(), nan, outside, nan_box]).unwrap();
    let d: Vec<Decision> = r.detections.iter().map(|o| o.decision).collect();
    assert_eq!(
        d,
        vec![
            Decision::Skipped { reason: SkipReason::TooFewPoints },
            Decision::Skipped { reason: SkipReason::TooFewPoints },
            Decision::New { object_id: 0 },
            Decision::Skipped { reason: SkipReason::OutsideImage },
            Decision::Skipped { reason: SkipReason::OutsideImage },
        ]
    );
    assert_eq!(r.detections[2].dropped_non_finite, 2);
    assert!(a.objects().all(|o| o.points_in_world().iter().all(|p| p.iter().all(|v| v.is_finite()))));
    // A single point is enough when the config allows it.
    let mut one = Associator::new(AssociationConfig { min_local_points: 1, ..AssociationConfig::default() }).unwrap();
    let r = one.associate_frame(0, &camera(), &pose, &[single]).unwrap();
    assert_eq!(r.detections[0].decision, Decision::New { object_id: 0 });
    // A box partly outside the image is clipped, not rejected; it matches nothing here and, being
    // truncated at the border, does not start an object.
    let mut partly = good.clone();
    partly.detection.bbox.min[0] = -40.0;
    let r = one.associate_frame(1, &camera(), &pose, &[partly]).unwrap();
    assert_eq!(r.detections[0].decision, Decision::Skipped { reason: SkipReason::TruncatedAtBorder });
    // Invalid camera or pose: typed error, state unchanged.
    let before = a.clone();
    let bad_cam = PinholeCamera { fx: -1.0, ..camera() };
    assert!(matches!(
        a.associate_frame(1, &bad_cam, &pose, std::slice::from_ref(&good)),
        Err(AssociationError::Camera(_))
    ));
    let mut bad_pose = pose;
    bad_pose.translation.vector.x = f64::NAN;
    assert_eq!(a.associate_frame(1, &camera(), &bad_pose, &[good]), Err(AssociationError::NonFinitePose));
    assert_eq!(a, before);
    // Bad config.
    assert!(matches!(
        Associator::new(AssociationConfig { np_alpha: 1.5, ..AssociationConfig::default() }),
        Err(AssociationError::BadConfig { field: "np_alpha", .. })
    ));
    assert!(matches!(
        Associator::new(AssociationConfig { t_min_history: 1, ..AssociationConfig::default() }),
        Err(AssociationError::BadConfig { .. })
    ));
}

#[test]
fn clouds_are_bounded_and_runs_are_deterministic() {
    let mut o = GlobalObject::new(0, 0.001);
    let mut rng = ChaCha8Rng::seed_from_u64(8);
    let pts: Vec<Point3<f64>> =
        cloud(&mut rng, Vector3::new(0.5, 0.0, 0.05), 0.05, 5000).into_iter().map(Point3::from).collect();
    o.add_points(&pts, 500);
    assert!(o.points_in_world().len() <= 500 && o.points_in_world().len() > 50, "{}", o.points_in_world().len());
    assert!(o.voxel_m() > 0.001);

    let go = || {
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        let mut a = associator(AssociationMode::Ensemble);
        let blocks = [Block::new(0.45, -0.05, 0.025, Label::Block), Block::new(0.5, 0.08, 0.03, Label::Cup)];
        let frames: Vec<(u32, Se3)> = (0..5).map(|i| (i, top_down(0.47, 0.01 * f64::from(i), 0.5))).collect();
        let out = run(&mut a, &blocks, &frames, &mut rng);
        (a, out)
    };
    let (a1, o1) = go();
    let (a2, o2) = go();
    assert_eq!(o1, o2);
    assert_eq!(a1, a2);
    let maps = a1.to_map_objects_raw();
    assert_eq!(maps.len(), 2);
    assert_eq!(maps[1].label, Label::Cup);
    assert_eq!(maps[1].observations.len(), 5);
    assert!((maps[0].geometry().center - Vector3::new(0.45, -0.05, 0.025)).norm() < 0.01);
}

#[test]
fn truncated_detections_update_but_never_create() {
    let mut rng = ChaCha8Rng::seed_from_u64(10);
    let mut a = associator(AssociationMode::Ensemble);
    let block = Block::new(0.5, 0.0, 0.03, Label::Block);
    let book = Block::new(0.5, 0.1, 0.02, Label::Book);
    let centre = top_down(0.5, 0.0, 0.5);
    let l = block.local(&mut rng, &centre, 150).expect("visible");
    let r = a.associate_frame(0, &camera(), &centre, &[l]).unwrap();
    assert_eq!(r.detections[0].decision, Decision::New { object_id: 0 });
    // Camera moved so both blocks sit on the right image border (u up to 320, clipped).
    let edge = top_down(0.15, 0.0, 0.5);
    let l = block.local(&mut rng, &edge, 150).expect("visible");
    assert!(l.detection.bbox.max[0] > 319.0, "{:?}", l.detection.bbox);
    let b = book.local(&mut rng, &edge, 150).expect("visible");
    let r = a.associate_frame(1, &camera(), &edge, &[l, b]).unwrap();
    assert_eq!(r.detections[0].decision, Decision::Existing { object_id: 0 });
    assert_eq!(r.detections[1].decision, Decision::Skipped { reason: SkipReason::TruncatedAtBorder });
    assert_eq!(a.len(), 1);
    // With the margin at 0 the truncated book starts an object.
    let mut z = Associator::new(AssociationConfig { border_margin_px: 0.0, ..AssociationConfig::default() }).unwrap();
    let b = book.local(&mut rng, &edge, 150).expect("visible");
    let r = z.associate_frame(0, &camera(), &edge, &[b]).unwrap();
    assert_eq!(r.detections[0].decision, Decision::New { object_id: 0 });
}

#[test]
fn modes_and_configs_round_trip_through_json() {
    for mode in AssociationMode::ALL {
        let json = serde_json::to_string(&mode).unwrap();
        assert_eq!(json, format!("\"{}\"", mode.as_str()));
    }
    let cfg: AssociationConfig = serde_json::from_str(r#"{"mode": "iou_np", "np_alpha": 0.01}"#).unwrap();
    assert_eq!(cfg.mode, AssociationMode::IouNp);
    assert_eq!(cfg.np_alpha, 0.01);
    assert_eq!(cfg.t_alpha, AssociationConfig::default().t_alpha);
    assert!(serde_json::from_str::<AssociationConfig>(r#"{"np_alpah": 0.01}"#).is_err(), "typos are rejected");
    let m: super::mapper::EnsembleMapperConfig =
        serde_json::from_str(r#"{"association": {"mode": "iou"}, "local": {"pixel_stride": 2}}"#).unwrap();
    assert_eq!((m.association.mode, m.local.pixel_stride), (AssociationMode::Iou, 2));
}

/// The single-sample t-test's two statistics on a well-observed object: a history of 100
/// centroids spread 1 cm along x (views from several sides). The paper's standard error of the
/// mean (1 mm) rejects the next view's centroid 1.5 cm off the mean; the prediction interval of
/// one new centroid (`t_prediction`) accepts it and still rejects a neighbour 6 cm away.
#[test]
fn t_prediction_accepts_a_new_side_and_rejects_a_neighbour() {
    let cfg = AssociationConfig::default();
    let pred = AssociationConfig { t_prediction: true, ..cfg };
    let base = Vector3::new(0.5, 0.0, 0.03);
    let mut o = GlobalObject::new(0, 0.005);
    for f in 0..100u32 {
        let dx = if f % 2 == 0 { 0.01 } else { -0.01 };
        o.push_history(CentroidSample { frame: f, centroid_in_world: base + Vector3::new(dx, 0.0, 0.0) }, 100);
    }
    let side = base + Vector3::new(0.015, 0.0, 0.0);
    let neighbour = base + Vector3::new(0.06, 0.0, 0.0);
    assert_eq!(t_test(&cfg, &side, &o), Some(false));
    assert_eq!(t_test(&pred, &side, &o), Some(true));
    assert_eq!(t_test(&cfg, &neighbour, &o), Some(false));
    assert_eq!(t_test(&pred, &neighbour, &o), Some(false));
    // On y and z the history has no spread: the 5 mm floor decides for both statistics.
    let off_y = base + Vector3::new(0.0, 0.02, 0.0);
    assert_eq!(t_test(&pred, &off_y, &o), Some(false));
}
