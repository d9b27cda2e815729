//! The core's settings of a run, one table per subsystem. These serde structs are the single
//! source of truth for the names, units, defaults and documentation of every core setting: the
//! run configuration (`experiments/configs/default.toml`) holds them as the tables `[slam]`,
//! `[map]`, `[explore]` and `[eval]`, and the simulator passes those tables to
//! [`SystemConfig::from_json`] untouched. The simulator's own settings (camera, detector, robot,
//! recording, ...) are not here.
//!
//! | table | struct | what |
//! |---|---|---|
//! | `[slam]` | [`TrackerConfig`] | visual tracking, the world gauge, the motion gates, the prior's assumed noise |
//! | `[map]` | [`PipelineConfig`] | association (`[map.association]`), consolidation, parameterization (`[map.param]`), the naive baseline (`[map.naive]`) |
//! | `[explore]` | [`ActiveConfig`] | the view strategies, the utility, table discovery |
//! | `[eval]` | [`EvalConfig`] | matching estimates to the truth (scoring only) |

use serde::{Deserialize, Serialize};
use thiserror::Error;

use crate::active::{ActiveConfig, ActiveSession};
use crate::eval::EvalConfig;
use crate::explore::TableRect;
use crate::map::validate::parse_json;
use crate::pipeline::PipelineConfig;
use crate::slam::{Tracker, TrackerConfig};

/// Every core setting of a run (see the module docs for the tables).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SystemConfig {
    /// Visual tracking (`[slam]`); used when the run's pose source has a tracker.
    pub slam: TrackerConfig,
    /// The object map: association, consolidation, parameterization (`[map]`).
    pub map: PipelineConfig,
    /// Exploration: strategies, utility, table discovery (`[explore]`).
    pub explore: ActiveConfig,
    /// Evaluation against the truth (`[eval]`); never used by the estimate.
    pub eval: EvalConfig,
}

/// A [`SystemConfig`] that does not parse or is out of range; the message names the field as
/// `table.key`.
#[derive(Debug, Clone, PartialEq, Error)]
#[error("{field}: {message}")]
pub struct ConfigError {
    /// The offending field, e.g. `map.param.iforest.passes`.
    pub field: String,
    /// What is wrong with it.
    pub message: String,
}

impl SystemConfig {
    /// Parse JSON (missing keys take their defaults, unknown keys are errors) and range-check
    /// every table.
    pub fn from_json(text: &str) -> Result<Self, ConfigError> {
        let c: Self = parse_json(text).map_err(|e| ConfigError { field: e.path, message: e.message })?;
        c.validate()?;
        Ok(c)
    }

    /// Range-check every table; the error names the field with its table.
    pub fn validate(&self) -> Result<(), ConfigError> {
        self.map.validate().map_err(|e| prefixed("map", &e.to_string()))?;
        let table = TableRect { center_m: [0.0, 0.0], size_m: [1.0, 1.0], height_m: 0.0 };
        if let Err(e) = ActiveSession::new(self.explore.clone(), table) {
            // The session's explore settings carry the grid and discovery parts under their own
            // names; the error is re-worded with the `[explore]` table's.
            let message = e.to_string().replace("cell_size_m", "cell_m").replace("discovery.", "discovery_");
            return Err(prefixed("explore", &message));
        }
        Tracker::new(self.slam).map_err(|e| prefixed("slam", &e.to_string()))?;
        self.eval.validate().map_err(|e| ConfigError { field: format!("eval.{}", e.field), message: e.reason })?;
        Ok(())
    }
}

/// `"[config [field]] <field>: reason"` from a subsystem's error → a [`ConfigError`] whose field
/// carries the table.
fn prefixed(table: &str, message: &str) -> ConfigError {
    let message = message.strip_prefix("config field ").or_else(|| message.strip_prefix("config ")).unwrap_or(message);
    match message.split_once(": ") {
        Some((field, reason)) if !field.contains(' ') => {
            ConfigError { field: format!("{table}.{field}"), message: reason.to_string() }
        }
        _ => ConfigError { field: table.to_string(), message: message.to_string() },
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_empty_table_gives_the_defaults() {
        assert_eq!(SystemConfig::from_json("{}"), Ok(SystemConfig::default()));
    }

    #[test]
    fn unknown_keys_are_named_with_their_table() {
        let e = SystemConfig::from_json(r#"{"map": {"param": {"iforest": {"pases": 2}}}}"#).unwrap_err();
        assert!(e.field.starts_with("map.param.iforest"), "{e}");
    }

    #[test]
    fn out_of_range_values_are_named_with_their_table() {
        let e = SystemConfig::from_json(r#"{"map": {"min_observations": 0}}"#).unwrap_err();
        assert_eq!(e.field, "map.min_observations", "{e}");
        let e = SystemConfig::from_json(r#"{"explore": {"lambda": -1.0}}"#).unwrap_err();
        assert!(e.field.starts_with("explore"), "{e}");
        let e = SystemConfig::from_json(r#"{"eval": {"max_match_distance_m": 0.0}}"#).unwrap_err();
        assert_eq!(e.field, "eval.max_match_distance_m", "{e}");
    }

    #[test]
    fn the_defaults_round_trip_through_json() {
        let text = serde_json::to_string(&SystemConfig::default()).unwrap();
        assert_eq!(SystemConfig::from_json(&text), Ok(SystemConfig::default()));
    }
}
