//! The object map: what the robot believes is on the table.
//!
//! Entry points:
//! - [`Label`]: object classes and their model ([`Label::shape`], the paper's "class → model").
//! - [`MapObject`]: label, `world_from_object`, half-extents, observation history and a bounded
//!   point cloud.
//! - [`ObjectMap`]: the collection, with versioned JSON [`ObjectMap::save`] / [`ObjectMap::load`].
//!
//! The file format is JSON with a top-level `"format"` = [`MAP_FORMAT`], `"version"` =
//! [`MAP_VERSION`] and `"content_hash"`: [`validate::content_hash`] of the file's bytes with the
//! hash's own value written as [`HASH_PLACEHOLDER`]. Loading a file of another format or a newer
//! version is an error, never a guess.
//!
//! Every map read from outside is checked ([`ObjectMap::validate`]): finite numbers, unit
//! quaternions, half-extents in [0, [`validate::MAX_HALF_EXTENT_M`]], unique ids, `next_id` above
//! every id. A file must also match its content hash ([`ObjectMap::load`]), so any changed byte
//! (a flipped digit, an edit by hand) is refused; version-1 files, written before the hash, are
//! refused with the way to re-save them. Map JSON passed in memory ([`ObjectMap::from_json`]) is
//! checked value by value only: callers transform maps in memory (e.g. `objslam.topo`).

use std::io::Write;
use std::path::Path;

use nalgebra::{Point3, Vector3};
use serde::{Deserialize, Serialize};

use crate::geometry::{yaw_of, Box2, ObjectGeometry, Se3, Shape};

pub mod validate;

use validate::{
    check_estimated_half_extents, check_finite, check_position, check_unit_quaternion, content_hash, parse_json,
    InvalidValue,
};

/// The `"format"` field of a saved map.
pub const MAP_FORMAT: &str = "objslam-map";
/// The current map file version (2: with `"content_hash"`). Bump on any incompatible change.
pub const MAP_VERSION: u32 = 2;
/// What the `"content_hash"` value is replaced with before the file's bytes are hashed.
pub const HASH_PLACEHOLDER: &str = "fnv1a64:0000000000000000";

/// Errors of the map module.
#[derive(Debug, thiserror::Error)]
pub enum MapError {
    /// Reading or writing the file failed.
    #[error("{path}: {source}")]
    Io {
        /// File path.
        path: String,
        /// Underlying error.
        source: std::io::Error,
    },
    /// The file is not valid JSON for a map.
    #[error("{path}: malformed map file: {reason}")]
    Malformed {
        /// File path.
        path: String,
        /// Parser message (names the field).
        reason: String,
    },
    /// The file has another format or an unsupported version.
    #[error("{path}: unsupported map file (format {format:?}, version {version}; this build reads {MAP_FORMAT:?} ≤ {MAP_VERSION})")]
    Version {
        /// File path.
        path: String,
        /// Format found.
        format: String,
        /// Version found.
        version: u32,
    },
    /// A value parsed but is impossible (non-finite, zero quaternion, negative extent, duplicate
    /// id, `next_id` not above every id).
    #[error("{path}: invalid map: {source}")]
    Invalid {
        /// File path.
        path: String,
        /// The field and what is wrong.
        source: InvalidValue,
    },
    /// The file's content hash is missing or does not match its content (a damaged or edited
    /// file).
    #[error("{path}: content_hash: {reason}")]
    Checksum {
        /// File path.
        path: String,
        /// Missing, or the expected and found hashes.
        reason: String,
    },
    /// An unknown class label.
    #[error("unknown label {0:?} (known: block, book, keyboard, cup, can, bottle, bowl, ball)")]
    UnknownLabel(String),
}

impl MapError {
    /// Whether the caller gave a bad value (an unknown label) rather than a bad or unreadable file.
    pub fn is_input(&self) -> bool {
        matches!(self, MapError::UnknownLabel(_))
    }
}

/// One map object as the bindings list it (`objects_json`): id, label, geometry and how often it
/// was observed.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ObjectRecord {
    /// Map id.
    pub id: u32,
    /// Class.
    pub label: Label,
    /// Box or cylinder in the world frame.
    pub geometry: ObjectGeometry,
    /// Detections fused into it.
    pub n_observations: usize,
}

/// Object classes. The detector's labels, the scene files' `class` field and the map all use these.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Label {
    /// A block or box (cuboid).
    Block,
    /// A book (flat cuboid).
    Book,
    /// A keyboard (long flat cuboid).
    Keyboard,
    /// A cup or mug (cylinder).
    Cup,
    /// A can (cylinder).
    Can,
    /// A bottle (tall cylinder).
    Bottle,
    /// A bowl (wide flat cylinder).
    Bowl,
    /// A ball (modelled as a cylinder / quadric without yaw).
    Ball,
}

impl Label {
    /// Every label, in a fixed order (index = [`Label::index`]).
    pub const ALL: [Label; 8] =
        [Label::Block, Label::Book, Label::Keyboard, Label::Cup, Label::Can, Label::Bottle, Label::Bowl, Label::Ball];

    /// The primitive this class is modelled with (the paper: cubes for boxes, books, keyboards;
    /// cylinders / quadrics without yaw for cups, bottles, cans, balls).
    pub fn shape(self) -> Shape {
        match self {
            Label::Block | Label::Book | Label::Keyboard => Shape::Cuboid,
            Label::Cup | Label::Can | Label::Bottle | Label::Bowl | Label::Ball => Shape::Cylinder,
        }
    }

    /// The lowercase name used in files.
    pub fn as_str(self) -> &'static str {
        match self {
            Label::Block => "block",
            Label::Book => "book",
            Label::Keyboard => "keyboard",
            Label::Cup => "cup",
            Label::Can => "can",
            Label::Bottle => "bottle",
            Label::Bowl => "bowl",
            Label::Ball => "ball",
        }
    }

    /// Position in [`Label::ALL`].
    pub fn index(self) -> usize {
        Label::ALL.iter().position(|l| *l == self).unwrap_or(0)
    }

    /// Parse a lowercase name.
    pub fn parse(name: &str) -> Result<Self, MapError> {
        Label::ALL.iter().copied().find(|l| l.as_str() == name).ok_or_else(|| MapError::UnknownLabel(name.to_string()))
    }
}

impl std::fmt::Display for Label {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// One sighting of an object: the frame, the detection box and its score.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Observation {
    /// Frame index within the run.
    pub frame: u32,
    /// Detection box in that frame.
    pub bbox: Box2,
    /// Detector score in [0, 1].
    pub score: f64,
    /// Centroid of the local point cloud seen in that frame, world frame.
    pub centroid_in_world: Vector3<f64>,
}

/// How an object's current estimate was produced (recorded per object).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum EstimateStage {
    /// Extent of the raw points (foundation baseline).
    #[default]
    Raw,
    /// After isolation-forest outlier removal.
    Iforest,
    /// After line-alignment yaw.
    Lines,
    /// After joint yaw/scale refinement.
    Refined,
}

/// An object in the map.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MapObject {
    /// Identifier, unique within the map, never reused.
    pub id: u32,
    /// Class label (majority over observations).
    pub label: Label,
    /// Object pose: centre and yaw about world z.
    pub world_from_object: Se3,
    /// Half-extents along the object axes, metres.
    pub half_extents: Vector3<f64>,
    /// Sightings, oldest first.
    pub observations: Vec<Observation>,
    /// Object point cloud in the world frame (bounded; see the mapper's config).
    pub points_in_world: Vec<Point3<f64>>,
    /// Which estimation stage produced the current pose and size.
    #[serde(default)]
    pub stage: EstimateStage,
}

impl MapObject {
    /// The object's geometry (shape from its label).
    pub fn geometry(&self) -> ObjectGeometry {
        ObjectGeometry {
            shape: self.label.shape(),
            center: self.world_from_object.translation.vector,
            yaw_rad: yaw_of(&self.world_from_object),
            half_extents: self.half_extents,
        }
    }
}

/// The object map.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct ObjectMap {
    /// Objects, in creation order.
    pub objects: Vec<MapObject>,
    /// The next id to hand out.
    pub next_id: u32,
}

#[derive(Serialize)]
struct MapFile<'a> {
    format: &'a str,
    version: u32,
    content_hash: &'a str,
    #[serde(flatten)]
    map: &'a ObjectMap,
}

#[derive(Deserialize)]
struct MapHeader {
    format: String,
    version: u32,
    #[serde(default)]
    content_hash: Option<String>,
}

impl ObjectMap {
    /// An empty map.
    pub fn new() -> Self {
        Self::default()
    }

    /// Every object as an [`ObjectRecord`], in map order.
    pub fn object_records(&self) -> Vec<ObjectRecord> {
        let record = |o: &MapObject| ObjectRecord {
            id: o.id,
            label: o.label,
            geometry: o.geometry(),
            n_observations: o.observations.len(),
        };
        self.objects.iter().map(record).collect()
    }

    /// Add an object with a fresh id; returns the id.
    pub fn insert(&mut self, mut object: MapObject) -> u32 {
        object.id = self.next_id;
        self.next_id = self.next_id.saturating_add(1);
        let id = object.id;
        self.objects.push(object);
        id
    }

    /// Look an object up by id.
    pub fn get(&self, id: u32) -> Option<&MapObject> {
        self.objects.iter().find(|o| o.id == id)
    }

    /// Number of objects.
    pub fn len(&self) -> usize {
        self.objects.len()
    }

    /// Whether the map has no objects.
    pub fn is_empty(&self) -> bool {
        self.objects.is_empty()
    }

    /// Check the invariants of a map read from outside: unique ids below `next_id`; per object a
    /// finite position within ±[`validate::MAX_COORDINATE_M`], a unit quaternion (within
    /// [`validate::UNIT_QUATERNION_TOLERANCE`]), half-extents in [0,
    /// [`validate::MAX_HALF_EXTENT_M`]] (an estimate may be flat), finite observations with
    /// scores in [0, 1] and finite points. The error names the field (`objects[2].half_extents[0]`).
    pub fn validate(&self) -> Result<(), InvalidValue> {
        let mut ids = std::collections::BTreeSet::new();
        for (i, o) in self.objects.iter().enumerate() {
            let f = format!("objects[{i}]");
            if !ids.insert(o.id) {
                return Err(InvalidValue::new(format!("{f}.id"), format!("duplicate id {}", o.id)));
            }
            if o.id >= self.next_id {
                return Err(InvalidValue::new(
                    "next_id",
                    format!("{} is not above every object id (objects[{i}].id = {})", self.next_id, o.id),
                ));
            }
            check_position(
                o.world_from_object.translation.vector.as_slice(),
                &format!("{f}.world_from_object.translation"),
            )?;
            check_unit_quaternion(
                o.world_from_object.rotation.coords.as_slice(),
                &format!("{f}.world_from_object.rotation"),
            )?;
            check_estimated_half_extents(o.half_extents.as_slice(), &format!("{f}.half_extents"))?;
            for (k, ob) in o.observations.iter().enumerate() {
                let fo = format!("{f}.observations[{k}]");
                check_finite(&[ob.bbox.min[0], ob.bbox.min[1], ob.bbox.max[0], ob.bbox.max[1]], &format!("{fo}.bbox"))?;
                if !(0.0..=1.0).contains(&ob.score) {
                    return Err(InvalidValue::new(
                        format!("{fo}.score"),
                        format!("must be in [0, 1], got {}", ob.score),
                    ));
                }
                check_position(ob.centroid_in_world.as_slice(), &format!("{fo}.centroid_in_world"))?;
            }
            if let Some(k) = o.points_in_world.iter().position(|p| p.coords.iter().any(|v| !v.is_finite())) {
                return Err(InvalidValue::new(format!("{f}.points_in_world[{k}]"), "must be finite"));
            }
        }
        Ok(())
    }

    /// Serialise to the versioned JSON format, with the content hash of exactly this text.
    pub fn to_json(&self) -> String {
        let file = MapFile { format: MAP_FORMAT, version: MAP_VERSION, content_hash: HASH_PLACEHOLDER, map: self };
        let text = serde_json::to_string_pretty(&file).unwrap_or_default();
        text.replacen(HASH_PLACEHOLDER, &content_hash(&text), 1)
    }

    /// Parse and check the versioned JSON format ([`ObjectMap::validate`]); `path` only names the
    /// source in errors. A `"content_hash"` is not checked here (see [`ObjectMap::load`]).
    pub fn from_json(text: &str, path: &str) -> Result<Self, MapError> {
        Self::parse(text, path).map(|(map, _)| map)
    }

    fn parse(text: &str, path: &str) -> Result<(Self, MapHeader), MapError> {
        let malformed = |e: validate::JsonError| MapError::Malformed { path: path.into(), reason: e.to_string() };
        let header: MapHeader = parse_json(text).map_err(malformed)?;
        if header.format != MAP_FORMAT || header.version == 0 || header.version > MAP_VERSION {
            return Err(MapError::Version { path: path.into(), format: header.format, version: header.version });
        }
        let map: ObjectMap = parse_json(text).map_err(malformed)?;
        map.validate().map_err(|source| MapError::Invalid { path: path.into(), source })?;
        Ok((map, header))
    }

    /// Write to a file atomically: a temporary file beside it, flushed to disk, renamed over the
    /// target (a full disk leaves the old file, if any, untouched).
    pub fn save(&self, path: &Path) -> Result<(), MapError> {
        let p = path.display().to_string();
        let io = |source| MapError::Io { path: p.clone(), source };
        let tmp = path.with_extension("json.tmp");
        let written = (|| {
            let mut f = std::fs::File::create(&tmp)?;
            f.write_all(self.to_json().as_bytes())?;
            f.sync_all()
        })();
        if let Err(e) = written {
            let _ = std::fs::remove_file(&tmp);
            return Err(io(e));
        }
        std::fs::rename(&tmp, path).map_err(io)
    }

    /// Read a file and check it: format, version, [`ObjectMap::validate`] and the content hash
    /// (required: any byte changed since the file was written is refused).
    pub fn load(path: &Path) -> Result<Self, MapError> {
        let p = path.display().to_string();
        let bytes = std::fs::read(path).map_err(|source| MapError::Io { path: p.clone(), source })?;
        let text = String::from_utf8(bytes)
            .map_err(|e| MapError::Malformed { path: p.clone(), reason: format!("not UTF-8 text: {e}") })?;
        let (map, header) = Self::parse(&text, &p)?;
        let Some(found) = header.content_hash else {
            return Err(MapError::Checksum {
                path: p,
                reason: format!(
                    "missing (a version-{} file, written before maps carried one); after checking it, \
                     re-save it with objslam.save_map(open(path).read(), path)",
                    header.version
                ),
            });
        };
        let blanked = text.replacen(&format!("\"{found}\""), &format!("\"{HASH_PLACEHOLDER}\""), 1);
        let expected = content_hash(&blanked);
        if found != expected {
            return Err(MapError::Checksum {
                path: p,
                reason: format!("the file says {found}, its bytes hash to {expected}: it was damaged or edited"),
            });
        }
        Ok(map)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::se3_from_yaw;

    fn sample_map() -> ObjectMap {
        let mut m = ObjectMap::new();
        m.insert(MapObject {
            id: 0,
            label: Label::Book,
            world_from_object: se3_from_yaw(Vector3::new(0.4, -0.1, 0.02), 0.3),
            half_extents: Vector3::new(0.1, 0.07, 0.02),
            observations: vec![Observation {
                frame: 3,
                bbox: Box2::new(10.0, 20.0, 110.0, 90.0),
                score: 0.9,
                centroid_in_world: Vector3::new(0.4, -0.1, 0.02),
            }],
            points_in_world: vec![Point3::new(0.41, -0.1, 0.03)],
            stage: EstimateStage::Raw,
        });
        m
    }

    #[test]
    fn object_records_list_id_label_geometry_and_observations() {
        let m = sample_map();
        let records = m.object_records();
        assert_eq!(records.len(), 1);
        assert_eq!((records[0].id, records[0].label, records[0].n_observations), (0, Label::Book, 1));
        assert_eq!(records[0].geometry, m.objects[0].geometry());
        let json = serde_json::to_value(&records).unwrap();
        assert_eq!(json[0]["label"], "book");
        assert!(MapError::UnknownLabel("x".into()).is_input());
        assert!(!MapError::Checksum { path: "f".into(), reason: "r".into() }.is_input());
    }

    #[test]
    fn json_round_trip_is_exact() {
        let m = sample_map();
        let back = ObjectMap::from_json(&m.to_json(), "mem").unwrap();
        assert_eq!(m, back);
        assert!((back.objects[0].geometry().yaw_rad - 0.3).abs() < 1e-12);
    }

    #[test]
    fn newer_version_is_refused() {
        let text = sample_map().to_json().replace("\"version\": 2", "\"version\": 99");
        assert!(matches!(ObjectMap::from_json(&text, "f.json"), Err(MapError::Version { version: 99, .. })));
        assert!(matches!(ObjectMap::from_json("{\"format\": 3}", "f.json"), Err(MapError::Malformed { .. })));
    }

    #[test]
    fn a_malformed_object_is_named_in_the_error() {
        let text = r#"{"format": "objslam-map", "version": 1, "objects": [{"id": 0}], "next_id": 1}"#;
        match ObjectMap::from_json(text, "f.json") {
            Err(MapError::Malformed { reason, .. }) => {
                assert!(reason.contains("objects[0]") && reason.contains("missing field `label`"), "{reason}")
            }
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn labels_parse_and_map_to_shapes() {
        for l in Label::ALL {
            assert_eq!(Label::parse(l.as_str()).ok(), Some(l));
        }
        assert_eq!(Label::Cup.shape(), Shape::Cylinder);
        assert_eq!(Label::Book.shape(), Shape::Cuboid);
        assert!(Label::parse("chair").is_err());
    }

    fn write(dir: &Path, name: &str, text: &str) -> std::path::PathBuf {
        let p = dir.join(name);
        std::fs::write(&p, text).unwrap();
        p
    }

    fn temp_dir(tag: &str) -> std::path::PathBuf {
        let d = std::env::temp_dir().join(format!("objslam-map-{tag}-{}", std::process::id()));
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    #[test]
    fn saved_maps_load_back_and_carry_a_content_hash() {
        let d = temp_dir("roundtrip");
        let m = sample_map();
        m.save(&d.join("m.json")).unwrap();
        assert!(!d.join("m.json.tmp").exists());
        let text = std::fs::read_to_string(d.join("m.json")).unwrap();
        assert!(text.contains("\"content_hash\": \"fnv1a64:"), "{text}");
        assert_eq!(ObjectMap::load(&d.join("m.json")).unwrap(), m);
    }

    /// The hash covers the file's bytes: a file re-indented by hand is refused by `load`, while
    /// the same JSON passed in memory is read (value checks only).
    #[test]
    fn a_reformatted_file_is_refused_but_its_json_is_read() {
        let v: serde_json::Value = serde_json::from_str(&sample_map().to_json()).unwrap();
        let compact = serde_json::to_string(&v).unwrap();
        assert_eq!(ObjectMap::from_json(&compact, "m").unwrap(), sample_map());
        let p = write(&temp_dir("reformat"), "compact.json", &compact);
        assert!(matches!(ObjectMap::load(&p), Err(MapError::Checksum { .. })));
    }

    #[test]
    fn a_zero_quaternion_is_refused_by_load() {
        let d = temp_dir("quat");
        let mut m = sample_map();
        m.objects[0].world_from_object.rotation =
            nalgebra::Unit::new_unchecked(nalgebra::Quaternion::new(0.0, 0.0, 0.0, 0.0));
        // Written with a matching hash, so only the geometry check can refuse it.
        let p = write(&d, "zero_q.json", &m.to_json());
        match ObjectMap::load(&p) {
            Err(MapError::Invalid { source, .. }) => {
                assert_eq!(source.field, "objects[0].world_from_object.rotation", "{source}")
            }
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn a_negative_extent_is_refused_by_load() {
        let d = temp_dir("extent");
        let mut m = sample_map();
        m.objects[0].half_extents.y = -0.07;
        let p = write(&d, "neg.json", &m.to_json());
        match ObjectMap::load(&p) {
            Err(MapError::Invalid { source, .. }) => assert_eq!(source.field, "objects[0].half_extents[1]", "{source}"),
            other => panic!("{other:?}"),
        }
    }

    /// Every single-digit change of a saved map is refused (checksum, version or a parse error),
    /// never read as another valid map.
    #[test]
    fn a_flipped_digit_is_refused_by_load() {
        let d = temp_dir("flip");
        let text = sample_map().to_json();
        let digits: Vec<usize> = text.char_indices().filter(|(_, c)| c.is_ascii_digit()).map(|(i, _)| i).collect();
        assert!(digits.len() > 50);
        for &i in &digits {
            let mut bytes = text.clone().into_bytes();
            bytes[i] = if bytes[i] == b'9' { b'0' } else { bytes[i] + 1 };
            let p = write(&d, "flip.json", std::str::from_utf8(&bytes).unwrap());
            assert!(
                ObjectMap::load(&p).is_err(),
                "digit at byte {i} flipped was accepted: {}",
                &text[i.saturating_sub(40)..i + 5]
            );
        }
    }

    #[test]
    fn ids_and_next_id_are_checked() {
        let mut m = sample_map();
        m.next_id = 0;
        assert!(
            matches!(ObjectMap::from_json(&m.to_json(), "m"), Err(MapError::Invalid { source, .. }) if source.field == "next_id")
        );
        let mut m = sample_map();
        let dup = m.objects[0].clone();
        m.objects.push(dup);
        m.next_id = 5;
        assert!(
            matches!(ObjectMap::from_json(&m.to_json(), "m"), Err(MapError::Invalid { source, .. }) if source.field == "objects[1].id")
        );
    }

    #[test]
    fn a_file_without_a_hash_is_refused_with_the_way_out() {
        let m = sample_map();
        let v1 = serde_json::json!({"format": MAP_FORMAT, "version": 1, "objects": m.objects, "next_id": m.next_id});
        let text = v1.to_string();
        assert_eq!(ObjectMap::from_json(&text, "m").unwrap(), m);
        let d = temp_dir("v1");
        let p = write(&d, "v1.json", &text);
        assert!(matches!(ObjectMap::load(&p), Err(MapError::Checksum { reason, .. }) if reason.contains("save_map")));
    }
}
