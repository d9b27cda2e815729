//! Checks at the boundary: JSON parsing that names the field, geometry and map invariants, and
//! the map files' content hash.
//!
//! One place per type: [`super::ObjectMap::validate`] (maps), [`check_geometry`] (any
//! [`ObjectGeometry`] read from outside, e.g. ground truth), [`parse_json`] (every JSON reader of
//! the core and the bindings, so a type error says `objects[2].half_extents` instead of
//! `line 1 column 19`), [`content_hash`] (map files).

use serde::de::DeserializeOwned;

use crate::geometry::ObjectGeometry;

/// A unit quaternion read from a file may differ from norm 1 by at most this much. Maps store
/// rotations written from `f64` unit quaternions (norm 1 to ~1e-15); 1e-6 also admits a rotation
/// written with 7 significant digits.
pub const UNIT_QUATERNION_TOLERANCE: f64 = 1e-6;
/// Largest half-extent of an object, metres (10 m: nothing on a table is larger; the scene files
/// cap full sizes at 0.5 m).
pub const MAX_HALF_EXTENT_M: f64 = 10.0;
/// Largest absolute coordinate of a position in the world, metres (1 km: the robot's workspace
/// is about a metre; the cap keeps every downstream sum finite).
pub const MAX_COORDINATE_M: f64 = 1e3;

/// A JSON document that does not fit the expected type, with the path of the offending field.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{path}: {message}")]
pub struct JsonError {
    /// Path of the field, e.g. `objects[2].half_extents` (`.` for the document itself).
    pub path: String,
    /// What is wrong (serde's message, with line and column).
    pub message: String,
}

/// A value that parsed but is impossible (non-finite, out of range, inconsistent).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{field}: {reason}")]
pub struct InvalidValue {
    /// Path of the field, e.g. `objects[0].world_from_object.rotation`.
    pub field: String,
    /// What is wrong, with the value.
    pub reason: String,
}

impl InvalidValue {
    /// An invalid value at `field`.
    pub fn new(field: impl Into<String>, reason: impl Into<String>) -> Self {
        Self { field: field.into(), reason: reason.into() }
    }
}

/// Parse JSON into `T`; a mismatch names the path of the field (`serde_path_to_error`).
pub fn parse_json<T: DeserializeOwned>(text: &str) -> Result<T, JsonError> {
    let de = &mut serde_json::Deserializer::from_str(text);
    serde_path_to_error::deserialize(de)
        .map_err(|e| JsonError { path: e.path().to_string(), message: e.inner().to_string() })
}

/// Every value finite, `field` naming the vector.
pub fn check_finite(values: &[f64], field: &str) -> Result<(), InvalidValue> {
    match values.iter().position(|v| !v.is_finite()) {
        Some(i) => Err(InvalidValue::new(format!("{field}[{i}]"), format!("must be finite, got {}", values[i]))),
        None => Ok(()),
    }
}

/// A position: finite, every coordinate within ±[`MAX_COORDINATE_M`].
pub fn check_position(p: &[f64], field: &str) -> Result<(), InvalidValue> {
    check_finite(p, field)?;
    match p.iter().position(|v| v.abs() > MAX_COORDINATE_M) {
        Some(i) => {
            Err(InvalidValue::new(format!("{field}[{i}]"), format!("{} m is beyond ±{MAX_COORDINATE_M} m", p[i])))
        }
        None => Ok(()),
    }
}

/// Half-extents: finite, positive, at most [`MAX_HALF_EXTENT_M`] (ground truth: a real object).
pub fn check_half_extents(h: &[f64], field: &str) -> Result<(), InvalidValue> {
    check_extents(h, field, false)
}

/// Half-extents of an estimate: as [`check_half_extents`] but 0 is allowed (an estimate from
/// points on one plane, e.g. the naive mapper's from a single depth layer, is flat).
pub fn check_estimated_half_extents(h: &[f64], field: &str) -> Result<(), InvalidValue> {
    check_extents(h, field, true)
}

fn check_extents(h: &[f64], field: &str, zero_ok: bool) -> Result<(), InvalidValue> {
    check_finite(h, field)?;
    let lo = if zero_ok { "[0" } else { "(0" };
    match h.iter().position(|v| !((*v > 0.0 || (zero_ok && *v == 0.0)) && *v <= MAX_HALF_EXTENT_M)) {
        Some(i) => Err(InvalidValue::new(
            format!("{field}[{i}]"),
            format!("half-extent must be in {lo}, {MAX_HALF_EXTENT_M}] m, got {}", h[i]),
        )),
        None => Ok(()),
    }
}

/// A quaternion `[i, j, k, w]` of norm 1 within [`UNIT_QUATERNION_TOLERANCE`].
pub fn check_unit_quaternion(q: &[f64], field: &str) -> Result<(), InvalidValue> {
    check_finite(q, field)?;
    let norm = q.iter().map(|v| v * v).sum::<f64>().sqrt();
    if (norm - 1.0).abs() > UNIT_QUATERNION_TOLERANCE {
        return Err(InvalidValue::new(
            field,
            format!("not a unit quaternion (norm {norm}, tolerance {UNIT_QUATERNION_TOLERANCE})"),
        ));
    }
    Ok(())
}

/// An object's geometry: finite centre within the coordinate cap, finite yaw, valid half-extents.
pub fn check_geometry(g: &ObjectGeometry, field: &str) -> Result<(), InvalidValue> {
    check_position(g.center.as_slice(), &format!("{field}.center"))?;
    check_finite(&[g.yaw_rad], &format!("{field}.yaw_rad"))?;
    check_half_extents(g.half_extents.as_slice(), &format!("{field}.half_extents"))
}

/// A map file's content hash: 64-bit FNV-1a of `text` (the file with the hash value written as
/// [`super::HASH_PLACEHOLDER`]), as `"fnv1a64:<16 hex digits>"`. It detects damage and edits (any
/// changed byte), not tampering.
pub fn content_hash(text: &str) -> String {
    const OFFSET: u64 = 0xcbf2_9ce4_8422_2325;
    const PRIME: u64 = 0x0000_0100_0000_01b3;
    let h = text.bytes().fold(OFFSET, |h, b| (h ^ u64::from(b)).wrapping_mul(PRIME));
    format!("fnv1a64:{h:016x}")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fnv1a64_matches_the_reference_vectors() {
        // Reference values of FNV-1a 64 (Fowler/Noll/Vo test suite).
        assert_eq!(content_hash(""), "fnv1a64:cbf29ce484222325");
        assert_eq!(content_hash("a"), "fnv1a64:af63dc4c8601ec8c");
        assert_eq!(content_hash("foobar"), "fnv1a64:85944171f73967e8");
    }

    #[test]
    fn json_errors_name_the_path() {
        #[derive(serde::Deserialize, Debug)]
        struct Inner {
            #[allow(dead_code)]
            x: f64,
        }
        #[derive(serde::Deserialize, Debug)]
        struct Outer {
            #[allow(dead_code)]
            items: Vec<Inner>,
        }
        let e = parse_json::<Outer>(r#"{"items": [{"x": 1}, {"x": "a"}]}"#).err().unwrap_or_else(|| panic!());
        assert_eq!(e.path, "items[1].x", "{e}");
    }

    #[test]
    fn quaternion_and_extent_checks() {
        assert!(check_unit_quaternion(&[0.0, 0.0, 0.0, 1.0], "q").is_ok());
        assert!(check_unit_quaternion(&[0.0, 0.0, 0.0, 0.0], "q").is_err());
        assert!(check_unit_quaternion(&[0.0, 0.0, 0.0, 1.01], "q").is_err());
        assert!(check_half_extents(&[0.1, 0.1, 0.1], "h").is_ok());
        for bad in [0.0, -0.1, 1e308, f64::NAN] {
            let e = check_half_extents(&[0.1, bad, 0.1], "h").err().unwrap_or_else(|| panic!("{bad}"));
            assert_eq!(e.field, "h[1]");
        }
        assert!(check_position(&[0.0, 1e4, 0.0], "p").is_err());
        assert!(check_estimated_half_extents(&[0.1, 0.0, 0.1], "h").is_ok());
        assert!(check_estimated_half_extents(&[0.1, -1e-9, 0.1], "h").is_err());
    }
}
