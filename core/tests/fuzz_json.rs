//! Fuzz harness of the core's JSON readers: seeded random mutations of valid documents (byte
//! edits of the text, and impossible values put into the parsed tree) must give `Ok` or a typed
//! error, never a panic or an abort; whatever is accepted satisfies the reader's invariants.
//!
//! Brief in `make test` (proptest's default, 256 cases per property); at length with
//! `PROPTEST_CASES=20000 cargo test --release -p objslam-core --test fuzz_json` (`make fuzz`).
//! Proptest keeps failing seeds in `core/tests/fuzz_json.proptest-regressions`; cases found by
//! hand are the regression tests at the end.

// Test code may unwrap (clippy.toml allows it in #[test] functions; this covers their helpers).
#![allow(clippy::unwrap_used, clippy::expect_used)]

use nalgebra::{Point3, Vector3};
use objslam_core::active::{ActiveConfig, ActiveSession};
use objslam_core::eval::{config_from_json, ground_truth_from_json};
use objslam_core::explore::TableRect;
use objslam_core::geometry::{se3_from_yaw, Box2};
use objslam_core::map::validate::parse_json;
use objslam_core::map::{EstimateStage, Label, MapObject, ObjectMap, Observation};
use objslam_core::pipeline::{ObjectPipeline, PipelineConfig};
use objslam_core::slam::{Tracker, TrackerConfig};
use objslam_core::topo::MatchConfig;
use proptest::prelude::*;
use serde_json::Value;

fn valid_map() -> ObjectMap {
    let mut m = ObjectMap::new();
    for (i, label) in [Label::Book, Label::Cup, Label::Block].into_iter().enumerate() {
        let c = Vector3::new(0.4 + 0.1 * i as f64, -0.1, 0.03);
        m.insert(MapObject {
            id: 0,
            label,
            world_from_object: se3_from_yaw(c, 0.3 * i as f64),
            half_extents: Vector3::new(0.05, 0.04, 0.03),
            observations: vec![Observation {
                frame: i as u32,
                bbox: Box2::new(10.0, 20.0, 110.0, 90.0),
                score: 0.9,
                centroid_in_world: c,
            }],
            points_in_world: vec![Point3::from(c)],
            stage: EstimateStage::Refined,
        });
    }
    m
}

const GT: &str = r#"[
  {"id": 0, "label": "cup", "geometry": {"shape": "cylinder", "center": [0.5, 0.0, 0.05], "yaw_rad": 0.0, "half_extents": [0.04, 0.04, 0.05]}},
  {"id": 1, "label": "book", "geometry": {"shape": "cuboid", "center": [0.4, 0.2, 0.02], "yaw_rad": 0.5, "half_extents": [0.09, 0.06, 0.02]}}
]"#;

/// One byte edit of `text`: replace, insert or delete at a position.
fn mutate_bytes(text: &str, edits: &[(u8, usize, u8)]) -> Vec<u8> {
    let mut b = text.as_bytes().to_vec();
    for &(kind, pos, byte) in edits {
        if b.is_empty() {
            b.push(byte);
            continue;
        }
        let i = pos % b.len();
        match kind % 3 {
            0 => b[i] = byte,
            1 => b.insert(i, byte),
            _ => {
                b.remove(i);
            }
        }
    }
    b
}

/// Replace the `k`-th scalar of a JSON tree (depth-first) by `v`.
fn replace_scalar(tree: &mut Value, k: &mut usize, v: &Value) -> bool {
    match tree {
        Value::Array(items) => items.iter_mut().any(|x| replace_scalar(x, k, v)),
        Value::Object(map) => map.values_mut().any(|x| replace_scalar(x, k, v)),
        _ => {
            if *k == 0 {
                *tree = v.clone();
                return true;
            }
            *k -= 1;
            false
        }
    }
}

/// Values a careless or hostile document puts in a numeric field.
fn odd_value() -> impl Strategy<Value = Value> {
    prop_oneof![
        Just(serde_json::json!(0)),
        Just(serde_json::json!(-1)),
        Just(serde_json::json!(-0.0)),
        Just(serde_json::json!(1e308)),
        Just(serde_json::json!(-1e308)),
        Just(serde_json::json!(1e-300)),
        Just(serde_json::json!(4294967296u64)),
        Just(serde_json::json!(u64::MAX)),
        Just(serde_json::json!(i64::MIN)),
        Just(serde_json::json!("x")),
        Just(serde_json::json!(null)),
        Just(serde_json::json!(true)),
        Just(serde_json::json!([])),
        Just(serde_json::json!({})),
        any::<f64>().prop_filter("finite", |v| v.is_finite()).prop_map(|v| serde_json::json!(v)),
        any::<i64>().prop_map(|v| serde_json::json!(v)),
    ]
}

fn edits() -> impl Strategy<Value = Vec<(u8, usize, u8)>> {
    proptest::collection::vec((any::<u8>(), any::<usize>(), any::<u8>()), 1..6)
}

fn check_map_text(text: &str) {
    if let Ok(m) = ObjectMap::from_json(text, "fuzz") {
        assert!(m.validate().is_ok(), "accepted a map that fails validation: {text}");
        assert_eq!(ObjectMap::from_json(&m.to_json(), "fuzz").ok(), Some(m), "accepted map does not round-trip");
    }
}

fn tree_mutations<'a>(doc: &'a str) -> impl Strategy<Value = String> + 'a {
    (any::<usize>(), odd_value()).prop_map(move |(k, v)| {
        let mut tree: Value = serde_json::from_str(doc).unwrap_or(Value::Null);
        let mut k = k % 200;
        replace_scalar(&mut tree, &mut k, &v);
        tree.to_string()
    })
}

proptest! {
    #[test]
    fn map_reader_survives_byte_edits(e in edits()) {
        let b = mutate_bytes(&valid_map().to_json(), &e);
        if let Ok(text) = std::str::from_utf8(&b) {
            check_map_text(text);
        }
    }

    #[test]
    fn map_reader_refuses_impossible_values(text in tree_mutations(Box::leak(valid_map().to_json().into_boxed_str()))) {
        check_map_text(&text);
    }

    #[test]
    fn ground_truth_reader_survives(e in edits(), text in tree_mutations(GT)) {
        for t in [String::from_utf8_lossy(&mutate_bytes(GT, &e)).into_owned(), text] {
            if let Ok(gt) = ground_truth_from_json(&t) {
                for o in &gt {
                    prop_assert!(o.geometry.half_extents.iter().all(|h| *h > 0.0 && h.is_finite()));
                }
            }
        }
    }

    #[test]
    fn eval_config_reader_survives(text in tree_mutations(r#"{"max_match_distance_m": 0.1, "square_tolerance": 0.05}"#)) {
        if let Ok(c) = config_from_json(&text) {
            prop_assert!(c.max_match_distance_m > 0.0);
        }
    }

    /// The mapper, exploration session and tracker configs as the bindings read them, and the
    /// constructors that validate them (an oversized table or grid must be refused, not
    /// allocated).
    #[test]
    fn native_configs_survive(
        mapper in tree_mutations(Box::leak(serde_json::to_string(&PipelineConfig::default()).unwrap_or_default().into_boxed_str())),
        active in tree_mutations(Box::leak(serde_json::to_string(&ActiveConfig::default()).unwrap_or_default().into_boxed_str())),
        tracker in tree_mutations(Box::leak(serde_json::to_string(&TrackerConfig::default()).unwrap_or_default().into_boxed_str())),
        topo in tree_mutations(Box::leak(serde_json::to_string(&MatchConfig::default()).unwrap_or_default().into_boxed_str())),
        table in proptest::array::uniform4(prop_oneof![Just(0.0), Just(-1.0), Just(1e4), Just(1e12), Just(f64::NAN), 0.1f64..3.0]),
    ) {
        if let Ok(c) = parse_json::<PipelineConfig>(&mapper) {
            if ObjectPipeline::new(c.clone()).is_ok() {
                prop_assert!(c.min_observations >= 1 && c.param.iforest.passes >= 1);
            }
        }
        if let Ok(c) = parse_json::<ActiveConfig>(&active) {
            let rect = TableRect { center_m: [table[0], table[1]], size_m: [table[2], table[3]], height_m: 0.0 };
            let _ = ActiveSession::new(c, rect).map(|s| s.initial_views().map(|v| v.len()));
        }
        if let Ok(c) = parse_json::<TrackerConfig>(&tracker) {
            let _ = Tracker::new(c);
        }
        let _ = parse_json::<MatchConfig>(&topo);
    }
}

/// Regression: a table of 1e4 m made the session allocate a 2.5e11-cell coverage grid.
#[test]
fn a_huge_table_is_refused_before_allocating() {
    let rect = TableRect { center_m: [0.5, 0.0], size_m: [1e4, 1e4], height_m: 0.0 };
    assert!(ActiveSession::new(ActiveConfig::default(), rect).is_err());
}
