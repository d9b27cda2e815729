//! The object map: what the robot believes is on the table.
//!
//! Entry points:
//! - [`Label`]: object classes and their model ([`Label::shape`], the paper's "class → model").
//! - [`MapObject`]: label, `world_from_object`, half-extents, observation history and a bounded
//!   point cloud.
//! - [`ObjectMap`]: the collection, with versioned JSON [`ObjectMap::save`] / [`ObjectMap::load`].
//!
//! The file format is JSON with a top-level `"format"` = [`MAP_FORMAT`] and `"version"` =
//! [`MAP_VERSION`]; loading a file of another format or a newer version is an error, never a guess.

use std::path::Path;

use nalgebra::{Point3, Vector3};
use serde::{Deserialize, Serialize};

use crate::geometry::{yaw_of, Box2, ObjectGeometry, Se3, Shape};

/// The `"format"` field of a saved map.
pub const MAP_FORMAT: &str = "objslam-map";
/// The current map file version. Bump on any incompatible change and keep a loader for the old one.
pub const MAP_VERSION: u32 = 1;

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
    /// An unknown class label.
    #[error("unknown label {0:?} (known: block, book, keyboard, cup, can, bottle, bowl, ball)")]
    UnknownLabel(String),
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

#[derive(Serialize, Deserialize)]
struct MapFile {
    format: String,
    version: u32,
    #[serde(flatten)]
    map: Option<ObjectMap>,
}

#[derive(Deserialize)]
struct MapHeader {
    format: String,
    version: u32,
}

impl ObjectMap {
    /// An empty map.
    pub fn new() -> Self {
        Self::default()
    }

    /// Add an object with a fresh id; returns the id.
    pub fn insert(&mut self, mut object: MapObject) -> u32 {
        object.id = self.next_id;
        self.next_id += 1;
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

    /// Serialise to the versioned JSON format.
    pub fn to_json(&self) -> String {
        let file = MapFile { format: MAP_FORMAT.into(), version: MAP_VERSION, map: Some(self.clone()) };
        serde_json::to_string_pretty(&file).unwrap_or_default()
    }

    /// Parse the versioned JSON format; `path` only names the source in errors.
    pub fn from_json(text: &str, path: &str) -> Result<Self, MapError> {
        let header: MapHeader =
            serde_json::from_str(text).map_err(|e| MapError::Malformed { path: path.into(), reason: e.to_string() })?;
        if header.format != MAP_FORMAT || header.version == 0 || header.version > MAP_VERSION {
            return Err(MapError::Version { path: path.into(), format: header.format, version: header.version });
        }
        let file: MapFile =
            serde_json::from_str(text).map_err(|e| MapError::Malformed { path: path.into(), reason: e.to_string() })?;
        match file.map {
            Some(map) => Ok(map),
            // The flattened optional map hides why it failed: parse the content alone for the
            // message that names the missing or malformed field.
            None => Err(MapError::Malformed {
                path: path.into(),
                reason: serde_json::from_str::<ObjectMap>(text)
                    .err()
                    .map_or_else(|| "no map content".into(), |e| e.to_string()),
            }),
        }
    }

    /// Write to a file (atomically: a temporary file renamed over the target).
    pub fn save(&self, path: &Path) -> Result<(), MapError> {
        let p = path.display().to_string();
        let tmp = path.with_extension("json.tmp");
        std::fs::write(&tmp, self.to_json()).map_err(|source| MapError::Io { path: p.clone(), source })?;
        std::fs::rename(&tmp, path).map_err(|source| MapError::Io { path: p, source })
    }

    /// Read from a file.
    pub fn load(path: &Path) -> Result<Self, MapError> {
        let p = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|source| MapError::Io { path: p.clone(), source })?;
        Self::from_json(&text, &p)
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
    fn json_round_trip_is_exact() {
        let m = sample_map();
        let back = ObjectMap::from_json(&m.to_json(), "mem").unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(m, back);
        assert!((back.objects[0].geometry().yaw_rad - 0.3).abs() < 1e-12);
    }

    #[test]
    fn newer_version_is_refused() {
        let text = sample_map().to_json().replace("\"version\": 1", "\"version\": 99");
        assert!(matches!(ObjectMap::from_json(&text, "f.json"), Err(MapError::Version { version: 99, .. })));
        assert!(matches!(ObjectMap::from_json("{\"format\": 3}", "f.json"), Err(MapError::Malformed { .. })));
    }

    #[test]
    fn a_malformed_object_is_named_in_the_error() {
        let text = r#"{"format": "objslam-map", "version": 1, "objects": [{"id": 0}], "next_id": 1}"#;
        match ObjectMap::from_json(text, "f.json") {
            Err(MapError::Malformed { reason, .. }) => assert!(reason.contains("missing field `label`"), "{reason}"),
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
}
