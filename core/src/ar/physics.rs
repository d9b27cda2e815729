//! Collision: virtual models as dynamic rigid bodies among the map's static objects (rapier3d-f64).
//!
//! Static colliders: each real object's primitive (cuboid, or a cylinder about world z) and the
//! table slab. Dynamic bodies: the registered models (cuboid, cylinder, ball, or the convex hull of a
//! mesh), density [`PhysicsConfig::density_kg_m3`]. [`ArPhysics::step_frame`] advances the world
//! by one frame, 1 / [`PhysicsConfig::frame_rate_hz`]; [`drop_to_rest`] steps until every body
//! rests and reports each body's final pose and the colliders it touches ([`ContactTarget`]).

use nalgebra::{Quaternion, Translation3, UnitQuaternion, Vector3};
use rapier3d_f64::math::{Pose, Rotation, Vector};
use rapier3d_f64::prelude::{
    ColliderBuilder, ColliderHandle, PhysicsWorld, RigidBodyBuilder, RigidBodyHandle, SharedShape,
};
use serde::{Deserialize, Serialize};

use super::solid::{Local, Solid};
use super::{bad, check_finite, ArError, ArScene, RegisteredModel};
use crate::geometry::Se3;

/// Rigid-body settings.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct PhysicsConfig {
    /// Frames per second; one [`ArPhysics::step_frame`] advances 1 / this, seconds. Default 30
    /// (a video frame rate).
    pub frame_rate_hz: f64,
    /// Physics sub-steps per frame (smaller steps settle contacts more accurately). Default 4.
    pub substeps: usize,
    /// Solver iterations per sub-step. Default 8.
    pub solver_iterations: usize,
    /// Gravity, m/s², along world −z. Default 9.81.
    pub gravity_m_s2: f64,
    /// Coulomb friction of every collider (combined by the average). Default 0.8.
    pub friction: f64,
    /// Restitution of every collider. Default 0 (no bounce, like the simulator's objects).
    pub restitution: f64,
    /// Density of the virtual bodies, kg/m³. Default 300 (the simulator's objects).
    pub density_kg_m3: f64,
    /// rapier's length unit, metres: its tolerances (allowed penetration 0.1 %, prediction
    /// distance) scale with it. Default 0.1 (tabletop objects of a few centimetres).
    pub length_unit_m: f64,
    /// A body rests when its speed stays below this, m/s ... Default 0.005.
    pub rest_speed_m_s: f64,
    /// ... and its angular speed below this, rad/s ... Default 0.05.
    pub rest_angular_speed_rad_s: f64,
    /// ... for this many consecutive frames. Default 10.
    pub rest_frames: usize,
    /// [`drop_to_rest`] gives up after this much simulated time, seconds. Default 5.
    pub max_time_s: f64,
}

impl Default for PhysicsConfig {
    fn default() -> Self {
        Self {
            frame_rate_hz: 30.0,
            substeps: 4,
            solver_iterations: 8,
            gravity_m_s2: 9.81,
            friction: 0.8,
            restitution: 0.0,
            density_kg_m3: 300.0,
            length_unit_m: 0.1,
            rest_speed_m_s: 0.005,
            rest_angular_speed_rad_s: 0.05,
            rest_frames: 10,
            max_time_s: 5.0,
        }
    }
}

impl PhysicsConfig {
    fn validate(&self) -> Result<(), ArError> {
        let positive = [
            ("physics.frame_rate_hz", self.frame_rate_hz),
            ("physics.density_kg_m3", self.density_kg_m3),
            ("physics.length_unit_m", self.length_unit_m),
            ("physics.max_time_s", self.max_time_s),
        ];
        for (name, v) in positive {
            if !(v.is_finite() && v > 0.0) {
                return Err(bad(name, format!("must be finite and > 0, got {v}")));
            }
        }
        let non_negative = [
            ("physics.gravity_m_s2", self.gravity_m_s2),
            ("physics.friction", self.friction),
            ("physics.restitution", self.restitution),
            ("physics.rest_speed_m_s", self.rest_speed_m_s),
            ("physics.rest_angular_speed_rad_s", self.rest_angular_speed_rad_s),
        ];
        for (name, v) in non_negative {
            if !(v.is_finite() && v >= 0.0) {
                return Err(bad(name, format!("must be finite and >= 0, got {v}")));
            }
        }
        if self.substeps == 0 || self.solver_iterations == 0 {
            return Err(bad("physics.substeps/solver_iterations", "must be >= 1"));
        }
        Ok(())
    }
}

/// What a body touches.
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum ContactTarget {
    /// The table.
    Table,
    /// A real object, by its id.
    Object {
        /// Map (or simulator) id.
        id: u32,
    },
    /// Another virtual model, by name.
    Virtual {
        /// Model name.
        name: String,
    },
}

/// A virtual body's state.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BodyState {
    /// Model name.
    pub name: String,
    /// Pose of the model frame.
    pub world_from_model: Se3,
    /// Linear speed, m/s.
    pub speed_m_s: f64,
    /// Colliders in contact, sorted.
    pub contacts: Vec<ContactTarget>,
    /// Whether the body has rested for [`PhysicsConfig::rest_frames`] frames.
    pub at_rest: bool,
}

/// Result of [`drop_to_rest`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DropOutcome {
    /// Final state per model (request order).
    pub bodies: Vec<BodyState>,
    /// Frames simulated.
    pub frames: usize,
    /// Whether every body came to rest within [`PhysicsConfig::max_time_s`].
    pub settled: bool,
}

struct Body {
    name: String,
    handle: RigidBodyHandle,
    collider: ColliderHandle,
    rest_count: usize,
}

/// The rapier world of one AR scene.
pub struct ArPhysics {
    world: PhysicsWorld,
    config: PhysicsConfig,
    targets: Vec<(ColliderHandle, ContactTarget)>,
    bodies: Vec<Body>,
}

fn pose_of(t: &Se3) -> Pose {
    let q = t.rotation.coords; // (x, y, z, w)
    Pose::from_parts(
        Vector::new(t.translation.x, t.translation.y, t.translation.z),
        Rotation::from_xyzw(q.x, q.y, q.z, q.w),
    )
}

fn se3_of(p: &Pose) -> Se3 {
    let (r, t) = (p.rotation, p.translation);
    Se3::from_parts(
        Translation3::new(t.x, t.y, t.z),
        UnitQuaternion::from_quaternion(Quaternion::new(r.w, r.x, r.y, r.z)),
    )
}

/// parry's cylinders run along their local y; ours along z.
fn y_to_z() -> Pose {
    Pose::from_parts(Vector::ZERO, Rotation::from_rotation_x(std::f64::consts::FRAC_PI_2))
}

fn shape_of(solid: &Solid, field: &str) -> Result<(SharedShape, Pose), ArError> {
    Ok(match &solid.local {
        Local::Cuboid(h) => (SharedShape::cuboid(h.x, h.y, h.z), Pose::IDENTITY),
        Local::Cylinder(r, hz) => (SharedShape::cylinder(*hz, *r), y_to_z()),
        Local::Ball(r) => (SharedShape::ball(*r), Pose::IDENTITY),
        Local::Mesh { vertices, .. } => {
            let pts: Vec<Vector> = vertices.iter().map(|v| Vector::new(v.x, v.y, v.z)).collect();
            let hull = SharedShape::convex_hull(&pts).ok_or_else(|| bad(field, "mesh has no convex hull (flat?)"))?;
            (hull, Pose::IDENTITY)
        }
    })
}

impl ArPhysics {
    /// A world with the scene's objects and table as static colliders and no bodies yet.
    pub fn new(scene: &ArScene, config: &PhysicsConfig) -> Result<Self, ArError> {
        scene.validate()?;
        config.validate()?;
        let mut world = PhysicsWorld::new();
        world.gravity = Vector::new(0.0, 0.0, -config.gravity_m_s2);
        let p = &mut world.integration_parameters;
        p.dt = 1.0 / (config.frame_rate_hz * config.substeps as f64);
        p.num_solver_iterations = config.solver_iterations;
        p.length_unit = config.length_unit_m;
        let mut me = Self { world, config: *config, targets: Vec::new(), bodies: Vec::new() };
        let statics = scene
            .objects
            .iter()
            .map(|o| (Solid::of_real(o), ContactTarget::Object { id: o.id }))
            .chain(scene.table.iter().map(|t| (Solid::of_table(t), ContactTarget::Table)));
        let ground = me.world.insert_body(RigidBodyBuilder::fixed());
        for (solid, target) in statics {
            let (shape, local) = shape_of(&solid, "objects")?;
            let c = ColliderBuilder::new(shape)
                .position(pose_of(&solid.world_from_local) * local)
                .friction(config.friction)
                .restitution(config.restitution);
            let h = me.world.insert_collider(c, Some(ground));
            me.targets.push((h, target));
        }
        Ok(me)
    }

    /// Add a registered model as a dynamic body with an initial velocity (world frame, m/s).
    /// Returns its index.
    pub fn add(&mut self, model: &RegisteredModel, linvel_m_s: [f64; 3]) -> Result<usize, ArError> {
        let i = self.bodies.len();
        check_finite(&format!("drops[{i}].linvel_m_s"), &linvel_m_s)?;
        check_finite(&format!("models[{i}].world_from_model"), model.world_from_model.to_homogeneous().as_slice())?;
        let solid = Solid::of_model(model);
        let (shape, local) = shape_of(&solid, &format!("models[{i}].shape"))?;
        let body = RigidBodyBuilder::dynamic()
            .pose(pose_of(&model.world_from_model))
            .linvel(Vector::new(linvel_m_s[0], linvel_m_s[1], linvel_m_s[2]))
            .ccd_enabled(true);
        let collider = ColliderBuilder::new(shape)
            .position(local)
            .density(self.config.density_kg_m3)
            .friction(self.config.friction)
            .restitution(self.config.restitution);
        let (handle, collider) = self.world.insert(body, collider);
        self.targets.push((collider, ContactTarget::Virtual { name: model.name.clone() }));
        self.bodies.push(Body { name: model.name.clone(), handle, collider, rest_count: 0 });
        Ok(i)
    }

    /// Advance by one frame (1 / `frame_rate_hz` seconds, in `substeps` steps).
    pub fn step_frame(&mut self) {
        for _ in 0..self.config.substeps {
            self.world.step();
        }
        let c = &self.config;
        for b in &mut self.bodies {
            let Some(rb) = self.world.bodies.get(b.handle) else { continue };
            let still = rb.is_sleeping()
                || (rb.linvel().length() < c.rest_speed_m_s && rb.angvel().length() < c.rest_angular_speed_rad_s);
            b.rest_count = if still { b.rest_count + 1 } else { 0 };
        }
    }

    /// Current state of every body (insertion order).
    pub fn states(&self) -> Vec<BodyState> {
        self.bodies
            .iter()
            .filter_map(|b| {
                let rb = self.world.bodies.get(b.handle)?;
                let mut contacts: Vec<ContactTarget> = self
                    .world
                    .narrow_phase
                    .contact_pairs_with(b.collider)
                    .filter(|p| p.has_any_active_contact())
                    .filter_map(|p| {
                        let other = if p.collider1 == b.collider { p.collider2 } else { p.collider1 };
                        self.targets.iter().find(|(h, _)| *h == other).map(|(_, t)| t.clone())
                    })
                    .collect();
                contacts.sort();
                contacts.dedup();
                Some(BodyState {
                    name: b.name.clone(),
                    world_from_model: se3_of(rb.position()),
                    speed_m_s: rb.linvel().length(),
                    contacts,
                    at_rest: b.rest_count >= self.config.rest_frames,
                })
            })
            .collect()
    }

    /// Whether every body has rested for `rest_frames` frames.
    pub fn all_at_rest(&self) -> bool {
        self.bodies.iter().all(|b| b.rest_count >= self.config.rest_frames)
    }
}

/// Drop `models` (each with an initial velocity, world m/s) into the scene and step until all rest
/// or `max_time_s` passes. No models → an empty, settled outcome.
pub fn drop_to_rest(
    scene: &ArScene,
    models: &[RegisteredModel],
    linvel_m_s: &[[f64; 3]],
    config: &PhysicsConfig,
) -> Result<DropOutcome, ArError> {
    if linvel_m_s.len() != models.len() {
        return Err(bad("drops.linvel_m_s", format!("{} velocities for {} models", linvel_m_s.len(), models.len())));
    }
    let mut world = ArPhysics::new(scene, config)?;
    for (m, v) in models.iter().zip(linvel_m_s) {
        world.add(m, *v)?;
    }
    let max_frames = (config.max_time_s * config.frame_rate_hz).ceil() as usize;
    let mut frames = 0;
    while frames < max_frames && !world.all_at_rest() {
        world.step_frame();
        frames += 1;
    }
    Ok(DropOutcome { bodies: world.states(), frames, settled: world.all_at_rest() })
}

/// The centre of a body state, for reports.
pub fn position_of(state: &BodyState) -> Vector3<f64> {
    state.world_from_model.translation.vector
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // tests may unwrap (STYLE.md, 18)
mod tests {
    use super::*;
    use crate::ar::{RealObject, TableTop, VirtualShape};
    use crate::geometry::{ObjectGeometry, Shape};
    use crate::map::Label;

    fn scene() -> ArScene {
        let table = TableTop { center_xy_m: [0.5, 0.0], size_xy_m: [0.8, 1.2], height_m: 0.0, thickness_m: 0.05 };
        let block = RealObject {
            id: 4,
            label: Label::Block,
            geometry: ObjectGeometry {
                shape: Shape::Cuboid,
                center: Vector3::new(0.5, 0.0, 0.04),
                yaw_rad: 0.4,
                half_extents: Vector3::new(0.06, 0.05, 0.04),
            },
        };
        let can = RealObject {
            id: 9,
            label: Label::Can,
            geometry: ObjectGeometry {
                shape: Shape::Cylinder,
                center: Vector3::new(0.5, 0.3, 0.06),
                yaw_rad: 0.0,
                half_extents: Vector3::new(0.03, 0.03, 0.06),
            },
        };
        ArScene { objects: vec![block, can], table: Some(table) }
    }

    fn ball(name: &str, at: [f64; 3], r: f64) -> RegisteredModel {
        RegisteredModel {
            name: name.into(),
            shape: VirtualShape::Ball { radius_m: r },
            world_from_model: Se3::translation(at[0], at[1], at[2]),
            anchor_object_id: None,
        }
    }

    #[test]
    fn drops_rest_at_the_analytic_heights() {
        let cube = RegisteredModel {
            name: "cube".into(),
            shape: VirtualShape::Cuboid { half_extents_m: [0.02, 0.02, 0.02] },
            world_from_model: Se3::translation(0.5, 0.0, 0.2),
            anchor_object_id: None,
        };
        let models = [cube, ball("on_can", [0.5, 0.3, 0.25], 0.01), ball("on_table", [0.3, -0.3, 0.1], 0.015)];
        let out = drop_to_rest(&scene(), &models, &[[0.0; 3]; 3], &PhysicsConfig::default()).unwrap();
        assert!(out.settled, "{out:?}");
        let z = |i: usize| position_of(&out.bodies[i]).z;
        // Cube on the block's top (z = 0.08): centre at 0.10; ball on the can's top (0.12): 0.13;
        // ball on the table: its radius.
        assert!((z(0) - 0.10).abs() < 1e-3, "cube at {}", z(0));
        assert!((z(1) - 0.13).abs() < 1e-3, "ball at {}", z(1));
        assert!((z(2) - 0.015).abs() < 1e-3, "ball at {}", z(2));
        assert_eq!(out.bodies[0].contacts, vec![ContactTarget::Object { id: 4 }]);
        assert_eq!(out.bodies[1].contacts, vec![ContactTarget::Object { id: 9 }]);
        assert_eq!(out.bodies[2].contacts, vec![ContactTarget::Table]);
        // The cube lands flat: its x axis stays horizontal.
        let x_axis = out.bodies[0].world_from_model.rotation * Vector3::x();
        assert!(x_axis.z.abs() < 1e-2);
    }

    #[test]
    fn a_cube_slid_against_the_can_stops_at_its_side() {
        // A flat cube sliding along +y on the table towards the can (centre y = 0.3, radius 0.03).
        let cube = RegisteredModel {
            name: "slider".into(),
            shape: VirtualShape::Cuboid { half_extents_m: [0.02, 0.02, 0.01] },
            world_from_model: Se3::translation(0.5, 0.15, 0.0101),
            anchor_object_id: None,
        };
        let out = drop_to_rest(&scene(), &[cube], &[[0.0, 1.6, 0.0]], &PhysicsConfig::default()).unwrap();
        assert!(out.settled);
        let p = position_of(&out.bodies[0]);
        assert!((p.y - (0.3 - 0.03 - 0.02)).abs() < 2e-3, "stopped at {p}");
        assert!(out.bodies[0].contacts.contains(&ContactTarget::Object { id: 9 }), "{:?}", out.bodies[0].contacts);
    }

    #[test]
    fn empty_inputs_and_bad_values() {
        let out = drop_to_rest(&ArScene::default(), &[], &[], &PhysicsConfig::default()).unwrap();
        assert!(out.bodies.is_empty() && out.settled);
        let cfg = PhysicsConfig { frame_rate_hz: f64::NAN, ..PhysicsConfig::default() };
        assert!(matches!(ArPhysics::new(&scene(), &cfg), Err(ArError::BadValue { .. })));
        let mut w = ArPhysics::new(&scene(), &PhysicsConfig::default()).unwrap();
        assert!(w.add(&ball("b", [0.5, 0.0, 0.3], 0.01), [f64::NAN, 0.0, 0.0]).is_err());
    }
}
