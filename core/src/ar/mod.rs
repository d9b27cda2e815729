//! Augmented reality on the object map: registration, occlusion, collision and interaction
//! (paper, section "Augmented Reality Experiment": object-triggered 3D registration, occlusion and
//! collision between the real scene and virtual models, semantic interaction).
//!
//! The real scene is what the object map says: each map object's primitive (cuboid or upright
//! cylinder, from its label, pose and size) plus the table top ([`ArScene`]). Virtual models are
//! primitives or triangle meshes ([`VirtualShape`]) placed by a [`Placement`].
//!
//! # Entry points
//! - Registration: [`register`]`(scene, models)` → [`RegisteredModel`]s. A model is anchored on the
//!   map object of its class ([`Placement::Object`]: replacing it, or resting on its top, with an
//!   optional offset) or placed in the world ([`Placement::World`]). [`VirtualShape::Fit`] takes
//!   the anchor's own primitive and size (the paper's "virtual models in place of the real
//!   objects").
//! - Occlusion ([`occlusion`]): [`render_scene_depth`] rasterises the map objects and the table to
//!   a depth image for a camera pose and intrinsics; [`occlusion_masks`] gives each registered
//!   model's silhouette and the part of it that no real surface (and no nearer virtual model)
//!   hides. The real depth can be any [`DepthImage`]: the map's, an exact one, or the map's
//!   refined by a live sensor frame ([`live`]: [`fuse_live_depth`], depth-aware compositing).
//! - Collision ([`physics`]): [`ArPhysics`] is a rapier3d world whose static colliders are the map
//!   objects and the table and whose dynamic bodies are the virtual models;
//!   [`ArPhysics::step_frame`] advances it by one frame (1 / `frame_rate_hz`);
//!   [`drop_to_rest`] runs drops until every body rests and reports rest poses and contacts.
//! - Interaction ([`interact`]): [`pick`] casts the ray of a pixel into the scene and returns the
//!   map object under it with the event named for its class ([`InteractionConfig`]).
//! - One request in, one answer out ([`request`]): [`run_request`] does all of the above from a
//!   JSON-friendly [`ArRequest`] (used by the Python bindings).
//!
//! # Conventions
//! World frame z up, table top at `z = table.height_m`; cameras in OpenCV axes (x right, y down,
//! z forward), `world_from_camera`; depth is the camera z of the first surface along a pixel's
//! centre ray (what SAPIEN's `Position` picture and the depth images of [`crate::frame`] hold).
//! Cylinders of the map have radius = mean of the two horizontal half-extents
//! ([`ObjectGeometry::radius`]).

pub mod interact;
pub mod live;
pub mod occlusion;
pub mod physics;
pub mod request;
mod solid;

use nalgebra::{Translation3, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

pub use interact::{pick, InteractionConfig, PickEvent};
pub use live::{fuse_live_depth, remove_specks, DepthSource, LiveDepthConfig, LiveFusion, LiveSummary};
pub use occlusion::{occlusion_masks, render_scene_depth, ModelMask, RenderConfig, COVER_HIDDEN, COVER_VISIBLE};
pub use physics::{drop_to_rest, ArPhysics, BodyState, ContactTarget, DropOutcome, PhysicsConfig};
pub use request::{run_request, ArRequest, ArResponse};

use crate::frame::DepthImage;
use crate::geometry::{ObjectGeometry, Se3, Shape};
use crate::map::{Label, ObjectMap};

/// Errors of the AR module. Each names the offending field or model.
#[derive(Debug, thiserror::Error)]
pub enum ArError {
    /// A model anchored on a class has no map object of that class.
    #[error("virtual model {model:?}: no map object of class {label}")]
    NoObjectOfClass {
        /// Model name.
        model: String,
        /// Class asked for.
        label: Label,
    },
    /// A model anchored on an object id that the map does not hold (with that class).
    #[error("virtual model {model:?}: no map object with id {object_id} and class {label}")]
    UnknownObject {
        /// Model name.
        model: String,
        /// Class asked for.
        label: Label,
        /// Object id asked for.
        object_id: u32,
    },
    /// A non-finite or out-of-range number.
    #[error("{field}: {reason}")]
    BadValue {
        /// Field path, e.g. `models[2].shape.radius_m`.
        field: String,
        /// What is wrong.
        reason: String,
    },
    /// A depth image whose size differs from the camera's.
    #[error("{field}: image is {actual_w}x{actual_h}, the camera is {expected_w}x{expected_h}")]
    ImageSize {
        /// Which image.
        field: &'static str,
        /// Camera width.
        expected_w: u32,
        /// Camera height.
        expected_h: u32,
        /// Image width.
        actual_w: u32,
        /// Image height.
        actual_h: u32,
    },
    /// Bad camera intrinsics or pose.
    #[error("camera: {0}")]
    Camera(#[from] crate::geometry::GeometryError),
    /// A request that is not valid JSON for [`ArRequest`].
    #[error("malformed AR request: {0}")]
    Malformed(String),
}

fn bad(field: impl Into<String>, reason: impl Into<String>) -> ArError {
    ArError::BadValue { field: field.into(), reason: reason.into() }
}

fn check_finite(field: &str, values: &[f64]) -> Result<(), ArError> {
    if values.iter().all(|v| v.is_finite()) {
        Ok(())
    } else {
        Err(bad(field, format!("non-finite value in {values:?}")))
    }
}

fn check_positive(field: &str, values: &[f64]) -> Result<(), ArError> {
    check_finite(field, values)?;
    if values.iter().all(|v| *v > 0.0) {
        Ok(())
    } else {
        Err(bad(field, format!("must be > 0, got {values:?}")))
    }
}

/// The table top: a horizontal rectangle (axis-aligned in the world) whose top face is at
/// `height_m`; a slab of `thickness_m` below it for the physics.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct TableTop {
    /// Centre of the top face in world x, y, metres.
    pub center_xy_m: [f64; 2],
    /// Extent along world x and y, metres.
    pub size_xy_m: [f64; 2],
    /// Height of the top face (world z), metres. The simulator's table: 0.
    #[serde(default)]
    pub height_m: f64,
    /// Thickness of the slab collider under the top face, metres. Default 0.05 (the simulator's).
    #[serde(default = "default_table_thickness")]
    pub thickness_m: f64,
}

fn default_table_thickness() -> f64 {
    0.05
}

impl TableTop {
    fn validate(&self) -> Result<(), ArError> {
        check_finite("table.center_xy_m", &self.center_xy_m)?;
        check_positive("table.size_xy_m", &self.size_xy_m)?;
        check_finite("table.height_m", &[self.height_m])?;
        check_positive("table.thickness_m", &[self.thickness_m])
    }
}

/// A real object as the AR module sees it: id, class and primitive (the layout of the
/// evaluation's ground-truth objects, so a map and the simulator's truth load alike).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RealObject {
    /// Map (or simulator) id.
    pub id: u32,
    /// Class label.
    pub label: Label,
    /// Primitive, pose and size.
    pub geometry: ObjectGeometry,
}

/// The real scene: objects and (optionally) the table.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct ArScene {
    /// Real objects (map order).
    pub objects: Vec<RealObject>,
    /// The table top; `None` = no table (nothing under the objects).
    pub table: Option<TableTop>,
}

impl ArScene {
    /// The scene of an object map (every object's current estimate) on a table.
    pub fn from_map(map: &ObjectMap, table: Option<TableTop>) -> Self {
        let objects =
            map.objects.iter().map(|o| RealObject { id: o.id, label: o.label, geometry: o.geometry() }).collect();
        Self { objects, table }
    }

    /// Check every number: finite poses, positive sizes.
    pub fn validate(&self) -> Result<(), ArError> {
        if let Some(t) = &self.table {
            t.validate()?;
        }
        for (i, o) in self.objects.iter().enumerate() {
            let g = &o.geometry;
            check_finite(&format!("objects[{i}].geometry.center"), g.center.as_slice())?;
            check_finite(&format!("objects[{i}].geometry.yaw_rad"), &[g.yaw_rad])?;
            check_positive(&format!("objects[{i}].geometry.half_extents"), g.half_extents.as_slice())?;
        }
        Ok(())
    }
}

/// A virtual model's geometry, in the model frame (z up, origin at its centre for primitives).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum VirtualShape {
    /// A box with half-extents along the model x, y, z, metres.
    Cuboid {
        /// Half-extents, metres.
        half_extents_m: [f64; 3],
    },
    /// A cylinder about the model z axis.
    Cylinder {
        /// Radius, metres.
        radius_m: f64,
        /// Half of the height, metres.
        half_height_m: f64,
    },
    /// A sphere.
    Ball {
        /// Radius, metres.
        radius_m: f64,
    },
    /// A triangle mesh (model-frame vertices, metres; triangles index them, counter-clockwise seen
    /// from outside). Its collider is the convex hull of the vertices.
    Mesh {
        /// Vertices, metres.
        vertices_m: Vec<[f64; 3]>,
        /// Vertex indices, three per triangle.
        triangles: Vec<[u32; 3]>,
    },
    /// The anchor object's own primitive and size (only with [`Placement::Object`]).
    Fit,
}

impl VirtualShape {
    /// Lowest model-frame z of the shape (the distance from its origin down to its base, negated).
    pub fn bottom_z_m(&self) -> f64 {
        match self {
            VirtualShape::Cuboid { half_extents_m } => -half_extents_m[2],
            VirtualShape::Cylinder { half_height_m, .. } => -half_height_m,
            VirtualShape::Ball { radius_m } => -radius_m,
            VirtualShape::Mesh { vertices_m, .. } => vertices_m.iter().map(|v| v[2]).fold(f64::INFINITY, f64::min),
            VirtualShape::Fit => 0.0,
        }
    }

    fn validate(&self, field: &str) -> Result<(), ArError> {
        match self {
            VirtualShape::Cuboid { half_extents_m } => {
                check_positive(&format!("{field}.half_extents_m"), half_extents_m)
            }
            VirtualShape::Cylinder { radius_m, half_height_m } => {
                check_positive(&format!("{field}.radius_m"), &[*radius_m])?;
                check_positive(&format!("{field}.half_height_m"), &[*half_height_m])
            }
            VirtualShape::Ball { radius_m } => check_positive(&format!("{field}.radius_m"), &[*radius_m]),
            VirtualShape::Mesh { vertices_m, triangles } => {
                if vertices_m.len() < 4 || triangles.is_empty() {
                    return Err(bad(
                        field,
                        format!(
                            "a mesh needs >= 4 vertices and >= 1 triangle, got {} and {}",
                            vertices_m.len(),
                            triangles.len()
                        ),
                    ));
                }
                for (i, v) in vertices_m.iter().enumerate() {
                    check_finite(&format!("{field}.vertices_m[{i}]"), v)?;
                }
                let n = vertices_m.len() as u32;
                if let Some(i) = triangles.iter().position(|t| t.iter().any(|k| *k >= n)) {
                    return Err(bad(format!("{field}.triangles[{i}]"), format!("vertex index out of range (< {n})")));
                }
                Ok(())
            }
            VirtualShape::Fit => Ok(()),
        }
    }

    /// The shape of a real object's primitive (what [`VirtualShape::Fit`] resolves to).
    pub fn of_geometry(g: &ObjectGeometry) -> Self {
        match g.shape {
            Shape::Cuboid => {
                VirtualShape::Cuboid { half_extents_m: [g.half_extents.x, g.half_extents.y, g.half_extents.z] }
            }
            Shape::Cylinder => VirtualShape::Cylinder { radius_m: g.radius(), half_height_m: g.half_extents.z },
        }
    }
}

/// Where a virtual model goes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "mode", rename_all = "snake_case")]
pub enum Placement {
    /// A fixed world pose: centre and yaw about world z.
    World {
        /// Model origin in the world, metres.
        position_m: [f64; 3],
        /// Yaw about world z, radians.
        #[serde(default)]
        yaw_rad: f64,
    },
    /// On a map object of a class: at its centre (`on_top = false`, replacing it) or resting on
    /// its top face (`on_top = true`), moved by `offset_m` (world axes) and turned by `yaw_rad`
    /// relative to the object's yaw.
    Object {
        /// Class of the anchor object.
        label: Label,
        /// A specific object id; `None` = the lowest id of that class.
        #[serde(default)]
        object_id: Option<u32>,
        /// Rest the model's base on the object's top face instead of sharing its centre.
        #[serde(default)]
        on_top: bool,
        /// Offset added to the anchored position, world axes, metres.
        #[serde(default)]
        offset_m: [f64; 3],
        /// Yaw added to the object's yaw, radians.
        #[serde(default)]
        yaw_rad: f64,
    },
}

/// A virtual model to register: a name (unique within a request), a shape and a placement.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct VirtualModel {
    /// Name, used in answers and events.
    pub name: String,
    /// Geometry.
    pub shape: VirtualShape,
    /// Where it goes.
    pub placement: Placement,
}

/// A registered virtual model: a resolved shape (never [`VirtualShape::Fit`]) at a world pose.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RegisteredModel {
    /// Model name.
    pub name: String,
    /// Geometry in the model frame.
    pub shape: VirtualShape,
    /// Model pose.
    pub world_from_model: Se3,
    /// The map object it is anchored on, if any.
    pub anchor_object_id: Option<u32>,
}

/// Register virtual models on the scene (paper: "object-triggered 3D registration": models are
/// placed by the semantics, pose and size encoded in the object map).
///
/// Errors: [`ArError::NoObjectOfClass`] / [`ArError::UnknownObject`] for an anchor the map lacks
/// (an empty map included), [`ArError::BadValue`] for non-finite poses or bad sizes.
pub fn register(scene: &ArScene, models: &[VirtualModel]) -> Result<Vec<RegisteredModel>, ArError> {
    scene.validate()?;
    models.iter().enumerate().map(|(i, m)| register_one(scene, m, i)).collect()
}

fn register_one(scene: &ArScene, m: &VirtualModel, i: usize) -> Result<RegisteredModel, ArError> {
    let field = format!("models[{i}]");
    m.shape.validate(&format!("{field}.shape"))?;
    match &m.placement {
        Placement::World { position_m, yaw_rad } => {
            check_finite(&format!("{field}.placement.position_m"), position_m)?;
            check_finite(&format!("{field}.placement.yaw_rad"), &[*yaw_rad])?;
            if m.shape == VirtualShape::Fit {
                return Err(bad(format!("{field}.shape"), "\"fit\" needs an object placement"));
            }
            Ok(RegisteredModel {
                name: m.name.clone(),
                shape: m.shape.clone(),
                world_from_model: pose_of(Vector3::from(*position_m), *yaw_rad),
                anchor_object_id: None,
            })
        }
        Placement::Object { label, object_id, on_top, offset_m, yaw_rad } => {
            check_finite(&format!("{field}.placement.offset_m"), offset_m)?;
            check_finite(&format!("{field}.placement.yaw_rad"), &[*yaw_rad])?;
            let anchor =
                match object_id {
                    Some(id) => scene.objects.iter().find(|o| o.id == *id && o.label == *label).ok_or_else(|| {
                        ArError::UnknownObject { model: m.name.clone(), label: *label, object_id: *id }
                    })?,
                    None => scene
                        .objects
                        .iter()
                        .filter(|o| o.label == *label)
                        .min_by_key(|o| o.id)
                        .ok_or_else(|| ArError::NoObjectOfClass { model: m.name.clone(), label: *label })?,
                };
            let g = &anchor.geometry;
            let shape = if m.shape == VirtualShape::Fit { VirtualShape::of_geometry(g) } else { m.shape.clone() };
            let mut center = g.center;
            if *on_top {
                center.z = g.center.z + g.half_extents.z - shape.bottom_z_m();
            }
            let object_yaw = if g.shape == Shape::Cylinder { 0.0 } else { g.yaw_rad };
            Ok(RegisteredModel {
                name: m.name.clone(),
                shape,
                world_from_model: pose_of(center + Vector3::from(*offset_m), object_yaw + yaw_rad),
                anchor_object_id: Some(anchor.id),
            })
        }
    }
}

fn pose_of(p: Vector3<f64>, yaw_rad: f64) -> Se3 {
    Se3::from_parts(Translation3::from(p), UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw_rad))
}

/// All AR settings, grouped.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(default)]
pub struct ArConfig {
    /// Depth rendering and masks.
    pub render: RenderConfig,
    /// Rigid-body simulation of the virtual models.
    pub physics: PhysicsConfig,
    /// Pixel picking and events.
    pub interaction: InteractionConfig,
    /// How a depth image passed with a request is used (live sensor frame or exact depth).
    pub live: LiveDepthConfig,
}

/// The real depth as `f32` metres with "no surface" as +∞ (depth images hold 0 or NaN there).
fn depth_or_inf(d: f32) -> f32 {
    if d.is_finite() && d > 0.0 {
        d
    } else {
        f32::INFINITY
    }
}

fn check_image(field: &'static str, img: &DepthImage, w: u32, h: u32) -> Result<(), ArError> {
    if img.width != w || img.height != h {
        return Err(ArError::ImageSize {
            field,
            expected_w: w,
            expected_h: h,
            actual_w: img.width,
            actual_h: img.height,
        });
    }
    Ok(())
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // tests may unwrap (STYLE.md, 18)
mod tests {
    use super::*;
    use crate::geometry::ObjectGeometry;

    fn block(id: u32, label: Label, x: f64) -> RealObject {
        RealObject {
            id,
            label,
            geometry: ObjectGeometry {
                shape: label.shape(),
                center: Vector3::new(x, 0.0, 0.05),
                yaw_rad: 0.3,
                half_extents: Vector3::new(0.04, 0.03, 0.05),
            },
        }
    }

    #[test]
    fn registration_on_top_rests_on_the_object() {
        let scene = ArScene { objects: vec![block(3, Label::Book, 0.5), block(1, Label::Book, 0.7)], table: None };
        let m = VirtualModel {
            name: "cat".into(),
            shape: VirtualShape::Ball { radius_m: 0.02 },
            placement: Placement::Object {
                label: Label::Book,
                object_id: None,
                on_top: true,
                offset_m: [0.0; 3],
                yaw_rad: 0.0,
            },
        };
        let r = register(&scene, &[m]).unwrap();
        assert_eq!(r[0].anchor_object_id, Some(1));
        let p = r[0].world_from_model.translation.vector;
        assert!((p - Vector3::new(0.7, 0.0, 0.12)).norm() < 1e-12, "{p}");
    }

    #[test]
    fn fit_replaces_the_object_with_its_primitive() {
        let scene = ArScene { objects: vec![block(2, Label::Can, 0.5)], table: None };
        let m = VirtualModel {
            name: "soda".into(),
            shape: VirtualShape::Fit,
            placement: Placement::Object {
                label: Label::Can,
                object_id: Some(2),
                on_top: false,
                offset_m: [0.0; 3],
                yaw_rad: 0.0,
            },
        };
        let r = register(&scene, &[m]).unwrap();
        assert_eq!(r[0].shape, VirtualShape::Cylinder { radius_m: 0.035, half_height_m: 0.05 });
    }

    #[test]
    fn bad_input_is_a_typed_error() {
        let anchored = |label| VirtualModel {
            name: "m".into(),
            shape: VirtualShape::Fit,
            placement: Placement::Object { label, object_id: None, on_top: false, offset_m: [0.0; 3], yaw_rad: 0.0 },
        };
        let empty = ArScene::default();
        assert!(matches!(register(&empty, &[anchored(Label::Cup)]), Err(ArError::NoObjectOfClass { .. })));
        assert!(register(&empty, &[]).unwrap().is_empty());
        let scene = ArScene { objects: vec![block(0, Label::Book, 0.5)], table: None };
        assert!(matches!(register(&scene, &[anchored(Label::Cup)]), Err(ArError::NoObjectOfClass { .. })));
        let nan = VirtualModel {
            name: "n".into(),
            shape: VirtualShape::Ball { radius_m: 0.01 },
            placement: Placement::World { position_m: [f64::NAN, 0.0, 0.0], yaw_rad: 0.0 },
        };
        let e = register(&scene, &[nan]).unwrap_err();
        assert!(e.to_string().contains("models[0].placement.position_m"), "{e}");
        let mut bad_scene = scene.clone();
        bad_scene.objects[0].geometry.center.x = f64::NAN;
        assert!(matches!(register(&bad_scene, &[]), Err(ArError::BadValue { .. })));
    }
}
