//! The evaluation's inputs read from outside (ground truth, config), checked once here.

use super::{EvalConfig, GtObject};
use crate::map::validate::{check_geometry, parse_json, InvalidValue, JsonError};

/// Largest [`EvalConfig::max_match_distance_m`], metres: beyond 10 m every estimate on a table
/// would match every ground-truth object of its class.
pub const MAX_MATCH_DISTANCE_M: f64 = 10.0;

/// Errors reading the evaluation's inputs; each names the input and the field.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum EvalError {
    /// The JSON does not fit the expected type.
    #[error("{what}: {source}")]
    Json {
        /// Which input (`gt`, `config`).
        what: &'static str,
        /// The field path and serde's message.
        source: JsonError,
    },
    /// A value is impossible.
    #[error("{what}: {source}")]
    Invalid {
        /// Which input.
        what: &'static str,
        /// The field and the reason.
        source: InvalidValue,
    },
}

impl EvalConfig {
    /// Check the ranges: `max_match_distance_m` in (0, [`MAX_MATCH_DISTANCE_M`]],
    /// `square_tolerance` in [0, 1].
    pub fn validate(&self) -> Result<(), InvalidValue> {
        let d = self.max_match_distance_m;
        if !(d.is_finite() && d > 0.0 && d <= MAX_MATCH_DISTANCE_M) {
            return Err(InvalidValue::new(
                "max_match_distance_m",
                format!("must be in (0, {MAX_MATCH_DISTANCE_M}] m, got {d}"),
            ));
        }
        let t = self.square_tolerance;
        if !(t.is_finite() && (0.0..=1.0).contains(&t)) {
            return Err(InvalidValue::new("square_tolerance", format!("must be in [0, 1], got {t}")));
        }
        Ok(())
    }
}

/// Ground truth from JSON (a list of [`GtObject`]): every geometry checked
/// ([`check_geometry`]), ids unique.
pub fn ground_truth_from_json(text: &str) -> Result<Vec<GtObject>, EvalError> {
    let gt: Vec<GtObject> = parse_json(text).map_err(|source| EvalError::Json { what: "gt", source })?;
    let mut ids = std::collections::BTreeSet::new();
    for (i, o) in gt.iter().enumerate() {
        if !ids.insert(o.id) {
            return Err(EvalError::Invalid {
                what: "gt",
                source: InvalidValue::new(format!("[{i}].id"), format!("duplicate id {}", o.id)),
            });
        }
        check_geometry(&o.geometry, &format!("[{i}].geometry"))
            .map_err(|source| EvalError::Invalid { what: "gt", source })?;
    }
    Ok(gt)
}

/// An [`EvalConfig`] from JSON, range-checked.
pub fn config_from_json(text: &str) -> Result<EvalConfig, EvalError> {
    let c: EvalConfig = parse_json(text).map_err(|source| EvalError::Json { what: "config", source })?;
    c.validate().map_err(|source| EvalError::Invalid { what: "config", source })?;
    Ok(c)
}

#[cfg(test)]
mod tests {
    use super::*;

    const GT: &str = r#"[{"id": 0, "label": "cup", "geometry": {"shape": "cylinder", "center": [0.5, 0.0, 0.05],
        "yaw_rad": 0.0, "half_extents": [0.04, 0.04, 0.05]}}]"#;

    #[test]
    fn valid_ground_truth_reads() {
        assert_eq!(ground_truth_from_json(GT).map(|g| g.len()), Ok(1));
    }

    #[test]
    fn impossible_ground_truth_is_refused_with_the_field() {
        for (bad, field) in [
            (GT.replace("[0.04, 0.04, 0.05]", "[0.04, -0.04, 0.05]"), "[0].geometry.half_extents[1]"),
            (GT.replace("[0.04, 0.04, 0.05]", "[0.04, 0.04, 1e308]"), "[0].geometry.half_extents[2]"),
            (GT.replace("[0.5, 0.0, 0.05]", "[0.5, 1e9, 0.05]"), "[0].geometry.center[1]"),
        ] {
            match ground_truth_from_json(&bad) {
                Err(EvalError::Invalid { source, .. }) => assert_eq!(source.field, field),
                other => panic!("{other:?}"),
            }
        }
        let two = format!("[{}, {}]", &GT[1..GT.len() - 1], &GT[1..GT.len() - 1]);
        assert!(
            matches!(ground_truth_from_json(&two), Err(EvalError::Invalid { source, .. }) if source.field == "[1].id")
        );
        match ground_truth_from_json(&GT.replace("\"id\": 0", "\"id\": -1")) {
            Err(EvalError::Json { source, .. }) => assert_eq!(source.path, "[0].id"),
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn a_negative_match_distance_is_refused() {
        assert!(config_from_json(r#"{"max_match_distance_m": 0.1, "square_tolerance": 0.05}"#).is_ok());
        let e = config_from_json(r#"{"max_match_distance_m": -0.1, "square_tolerance": 0.05}"#);
        assert!(matches!(e, Err(EvalError::Invalid { source, .. }) if source.field == "max_match_distance_m"));
    }
}
