//! Pipeline test of the `topo` module: two object maps of the same table, built in different
//! frames and scales, saved and loaded as JSON, then relocalised.
//!
//! Seed 2024; envelope pinned: rotation < 2°, translation (prior units) < 3 cm, scale within 3 %,
//! all shared objects matched, no false pair.

// Test code may unwrap (clippy.toml allows it in #[test] functions; this covers their helpers).
#![allow(clippy::unwrap_used, clippy::expect_used)]

use nalgebra::{Similarity3, Translation3, UnitQuaternion, Vector3};
use objslam_core::geometry::se3_from_yaw;
use objslam_core::map::{EstimateStage, Label, MapObject, ObjectMap};
use objslam_core::topo::{relocalise, MatchConfig};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

struct Truth {
    label: Label,
    center: Vector3<f64>,
    yaw_rad: f64,
    half_extents: Vector3<f64>,
}

fn table(rng: &mut ChaCha8Rng) -> Vec<Truth> {
    let kinds = [
        (Label::Book, Vector3::new(0.1, 0.07, 0.015)),
        (Label::Cup, Vector3::new(0.04, 0.04, 0.05)),
        (Label::Block, Vector3::new(0.03, 0.02, 0.025)),
        (Label::Can, Vector3::new(0.033, 0.033, 0.06)),
        (Label::Cup, Vector3::new(0.045, 0.045, 0.055)),
        (Label::Bottle, Vector3::new(0.035, 0.035, 0.11)),
        (Label::Book, Vector3::new(0.12, 0.08, 0.02)),
        (Label::Block, Vector3::new(0.04, 0.025, 0.03)),
        (Label::Bowl, Vector3::new(0.08, 0.08, 0.03)),
        (Label::Can, Vector3::new(0.03, 0.03, 0.065)),
    ];
    let mut out: Vec<Truth> = Vec::new();
    for (label, half) in kinds {
        loop {
            let c = Vector3::new(rng.random_range(0.25..0.75), rng.random_range(-0.4..0.4), half.z);
            if out.iter().all(|o| (o.center.xy() - c.xy()).norm() > 0.15) {
                out.push(Truth { label, center: c, yaw_rad: rng.random_range(-1.5..1.5), half_extents: half });
                break;
            }
        }
    }
    out
}

fn map_of(objects: &[&Truth], frame_from_world: &Similarity3<f64>, rng: &mut ChaCha8Rng, first_id: u32) -> ObjectMap {
    let mut map = ObjectMap::new();
    map.next_id = first_id;
    let yaw_offset = frame_from_world.isometry.rotation.scaled_axis().z;
    for o in objects {
        let noisy = o.center + Vector3::new(rng.random_range(-0.01..0.01), rng.random_range(-0.01..0.01), 0.0);
        let center = frame_from_world.transform_point(&noisy.into()).coords;
        map.insert(MapObject {
            id: 0,
            label: o.label,
            world_from_object: se3_from_yaw(center, o.yaw_rad + yaw_offset + rng.random_range(-0.03..0.03)),
            half_extents: o.half_extents * frame_from_world.scaling() * rng.random_range(0.97..1.03),
            observations: Vec::new(),
            points_in_world: Vec::new(),
            stage: EstimateStage::Refined,
        });
    }
    map
}

#[test]
fn relocalise_a_second_session_through_saved_maps() {
    let mut rng = ChaCha8Rng::seed_from_u64(2024);
    let world = table(&mut rng);
    // Session 1 (prior) sees objects 0..7 in the world frame; session 2 sees 3..10 in its own frame.
    let prior_objects: Vec<&Truth> = world[0..7].iter().collect();
    let query_objects: Vec<&Truth> = world[3..10].iter().collect();
    let query_from_world = Similarity3::from_parts(
        Translation3::new(-0.4, 0.9, 0.05),
        UnitQuaternion::from_axis_angle(&Vector3::z_axis(), -2.3),
        0.7,
    );
    let prior = map_of(&prior_objects, &Similarity3::identity(), &mut rng, 0);
    let query = map_of(&query_objects, &query_from_world, &mut rng, 50);

    let dir = std::env::temp_dir().join(format!("objslam-topo-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let (prior_path, query_path) = (dir.join("prior.json"), dir.join("query.json"));
    prior.save(&prior_path).unwrap();
    query.save(&query_path).unwrap();
    let prior = ObjectMap::load(&prior_path).unwrap();
    let query = ObjectMap::load(&query_path).unwrap();
    let _ = std::fs::remove_dir_all(&dir);

    let r = relocalise(&prior, &query, &MatchConfig::default()).unwrap();
    let truth = query_from_world.inverse();
    let rot_deg = r.prior_from_query.isometry.rotation.angle_to(&truth.isometry.rotation).to_degrees();
    let trans_m = (r.prior_from_query.isometry.translation.vector - truth.isometry.translation.vector).norm();
    assert!(rot_deg < 2.0, "{rot_deg}");
    assert!(trans_m < 0.03, "{trans_m}");
    assert!((r.prior_from_query.scaling() / truth.scaling() - 1.0).abs() < 0.03);
    // Shared objects are world 3..7: prior ids 3..7, query ids 50..54.
    assert_eq!(r.matched_ids, vec![(3, 50), (4, 51), (5, 52), (6, 53)]);
    assert!(r.confidence > 0.2, "{}", r.confidence);
}
