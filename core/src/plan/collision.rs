//! Collision checking of the arm against the table, the map objects and itself (parry3d-f64).
//!
//! The arm is approximated by capsules fixed to its links ([`ArmCapsule`]; sizes in
//! [`panda_capsules`], fitted to the URDF's collision meshes so that they cover them up to
//! [`CAPSULE_COVERAGE_TOLERANCE_M`]). Obstacles are the table (everything under
//! `z = table_margin_m` is forbidden for all links but the base) and the map objects as cuboids or
//! upright cylinders grown by `object_margin_m` ([`CollisionScene`]). Self-collision is checked for
//! the link pairs of [`PlannerConfig::self_collision_pairs`](super::PlannerConfig).

use nalgebra::{Point3, Vector3};
use parry3d_f64::math::{Pose, Rotation, Vector};
use parry3d_f64::query::intersection_test;
use parry3d_f64::shape::{Capsule, Cuboid, Cylinder, Shape as ParryShape};

use super::kinematics::{ArmChain, JointVector};
use super::PlanError;
use crate::geometry::{ObjectGeometry, Se3, Shape};

/// A capsule (segment `a`–`b` swept by `radius_m`) fixed to a link, in that link's frame.
#[derive(Debug, Clone, PartialEq)]
pub struct ArmCapsule {
    /// Link name (`panda_link0` … `panda_link7`, `panda_hand`).
    pub link: String,
    /// First segment end in the link frame, metres.
    pub a_in_link: [f64; 3],
    /// Second segment end in the link frame, metres.
    pub b_in_link: [f64; 3],
    /// Radius, metres.
    pub radius_m: f64,
}

fn cap(link: &str, a: [f64; 3], b: [f64; 3], r: f64) -> ArmCapsule {
    ArmCapsule { link: link.to_string(), a_in_link: a, b_in_link: b, radius_m: r }
}

/// Finger capsule length below the hand, hand frame: fingers are modelled from z = 0.065 m to
/// z = 0.100 m (the TCP is at z = 0.1034 m), radius 0.012 m, at the gripper's full opening (0.08 m)
/// so the collision model never underestimates them during transit.
pub const FINGER_Z_RANGE_M: [f64; 2] = [0.065, 0.100];

/// How far the Panda's collision meshes may stick out of [`panda_capsules`], metres: the radii are
/// the distances that cover every surface sample of mani-skill's collision meshes
/// (`core/tests/fixtures/make_panda_collision_samples.py`), minus up to this much and rounded to
/// 5 mm; the default object margin (1 cm) absorbs the rest. Checked by `core/tests/plan.rs`.
pub const CAPSULE_COVERAGE_TOLERANCE_M: f64 = 0.005;

/// The Panda's collision capsules (link frames of `panda_v2.urdf`), fitted to the collision meshes
/// (`franka_description/meshes/collision/*.stl`, which are boxy: capsules covering their corners
/// are fat). Segment ends and radius, metres:
/// - link0 (base): (−0.09,0,0.06)–(0,0,0.06) r 0.11; (0,0,0.06)–(0,0,0.09) r 0.075 (the base is not
///   checked against the table it stands on);
/// - link1: (0,0,−0.19)–(0,0,−0.03) r 0.09; (0,−0.075,0)–(0,0,0) r 0.09;
/// - link2: (0,0,0)–(0,0,0.075) r 0.09; (0,0,0)–(0,−0.14,0) r 0.095;
/// - link3: (0,0,−0.07)–(0,0,0) r 0.085; (0.083,0,0)–(0.083,0.056,0) r 0.085; (0,0,0)–(0.083,0,0) r 0.075;
/// - link4: (0,0,0)–(0,0,0.056) r 0.09; (−0.083,0,0)–(−0.083,0.07,0) r 0.085; (0,0,0)–(−0.083,0,0) r 0.07;
/// - link5: (0,0,−0.21)–(0,0,−0.1) r 0.07; (0,0.075,−0.17)–(0,0.075,−0.06) r 0.065;
///   (0,0,0)–(0,0.075,0) r 0.055; (0,0,−0.1)–(0,0,0) r 0.06;
/// - link6: sphere at the origin r 0.055; (0.077,0,0)–(0.077,0.027,0) r 0.075; (0,0,0)–(0.077,0,0) r 0.065;
/// - link7: (0,0,0.075)–(0,0,0.08) r 0.05; sphere at (0.03,0.03,0.08) r 0.05;
/// - panda_hand: body (0,±0.07,0) r 0.035 and (0,±0.07,0.035) r 0.04; two fingers at y ±0.052
///   (full opening 0.08 + finger half-thickness), z over [`FINGER_Z_RANGE_M`], r 0.012 (the URDF's
///   finger boxes at full opening).
pub fn panda_capsules() -> Vec<ArmCapsule> {
    let [fz0, fz1] = FINGER_Z_RANGE_M;
    vec![
        cap("panda_link0", [-0.09, 0.0, 0.06], [0.0, 0.0, 0.06], 0.11),
        cap("panda_link0", [0.0, 0.0, 0.06], [0.0, 0.0, 0.09], 0.075),
        cap("panda_link1", [0.0, 0.0, -0.19], [0.0, 0.0, -0.03], 0.09),
        cap("panda_link1", [0.0, -0.075, 0.0], [0.0, 0.0, 0.0], 0.09),
        cap("panda_link2", [0.0, 0.0, 0.0], [0.0, 0.0, 0.075], 0.09),
        cap("panda_link2", [0.0, 0.0, 0.0], [0.0, -0.14, 0.0], 0.095),
        cap("panda_link3", [0.0, 0.0, -0.07], [0.0, 0.0, 0.0], 0.085),
        cap("panda_link3", [0.083, 0.0, 0.0], [0.083, 0.056, 0.0], 0.085),
        cap("panda_link3", [0.0, 0.0, 0.0], [0.083, 0.0, 0.0], 0.075),
        cap("panda_link4", [0.0, 0.0, 0.0], [0.0, 0.0, 0.056], 0.09),
        cap("panda_link4", [-0.083, 0.0, 0.0], [-0.083, 0.07, 0.0], 0.085),
        cap("panda_link4", [0.0, 0.0, 0.0], [-0.083, 0.0, 0.0], 0.07),
        cap("panda_link5", [0.0, 0.0, -0.21], [0.0, 0.0, -0.1], 0.07),
        cap("panda_link5", [0.0, 0.075, -0.17], [0.0, 0.075, -0.06], 0.065),
        cap("panda_link5", [0.0, 0.0, 0.0], [0.0, 0.075, 0.0], 0.055),
        cap("panda_link5", [0.0, 0.0, -0.1], [0.0, 0.0, 0.0], 0.06),
        cap("panda_link6", [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], 0.055),
        cap("panda_link6", [0.077, 0.0, 0.0], [0.077, 0.027, 0.0], 0.075),
        cap("panda_link6", [0.0, 0.0, 0.0], [0.077, 0.0, 0.0], 0.065),
        cap("panda_link7", [0.0, 0.0, 0.075], [0.0, 0.0, 0.08], 0.05),
        cap("panda_link7", [0.03, 0.03, 0.08], [0.03, 0.03, 0.08], 0.05),
        cap("panda_hand", [0.0, -0.07, 0.0], [0.0, 0.07, 0.0], 0.035),
        cap("panda_hand", [0.0, -0.07, 0.035], [0.0, 0.07, 0.035], 0.04),
        cap("panda_hand", [0.0, 0.052, fz0], [0.0, 0.052, fz1], 0.012),
        cap("panda_hand", [0.0, -0.052, fz0], [0.0, -0.052, fz1], 0.012),
    ]
}

/// Default self-collision link pairs: links that can meet but are not adjacent, i.e. the Panda
/// SRDF's pairs minus its "Adjacent" / "Never" / "Default" exclusions: {link0, link1, link2} ×
/// {link5, link6, link7, hand} without (link2, link6).
pub fn panda_self_collision_pairs() -> Vec<(String, String)> {
    let mut out = Vec::new();
    for a in ["panda_link0", "panda_link1", "panda_link2"] {
        for b in ["panda_link5", "panda_link6", "panda_link7", "panda_hand"] {
            if !(a == "panda_link2" && b == "panda_link6") {
                out.push((a.to_string(), b.to_string()));
            }
        }
    }
    out
}

/// An obstacle in the world: a map object's primitive, grown by the object margin.
#[derive(Debug, Clone)]
struct Obstacle {
    shape: ObstacleShape,
    world_pose: Pose,
    aabb_min: Vector3<f64>,
    aabb_max: Vector3<f64>,
}

#[derive(Debug, Clone)]
enum ObstacleShape {
    Cuboid(Cuboid),
    Cylinder(Cylinder),
}

impl ObstacleShape {
    fn as_shape(&self) -> &dyn ParryShape {
        match self {
            ObstacleShape::Cuboid(c) => c,
            ObstacleShape::Cylinder(c) => c,
        }
    }
}

fn pose_from_se3(t: &Se3) -> Pose {
    let q = t.rotation.coords; // (x, y, z, w)
    Pose::from_parts(
        Vector::new(t.translation.x, t.translation.y, t.translation.z),
        Rotation::from_xyzw(q.x, q.y, q.z, q.w),
    )
}

fn vec_of(p: &Point3<f64>) -> Vector {
    Vector::new(p.x, p.y, p.z)
}

/// The world the arm moves in: table plane and map objects (grown by a margin).
#[derive(Debug, Clone)]
pub struct CollisionScene {
    obstacles: Vec<Obstacle>,
    /// Links must stay above this height, metres (table top z = 0 plus margin).
    pub min_link_height_m: f64,
}

impl CollisionScene {
    /// Builds the scene from map object geometries, growing each by `object_margin_m` on every
    /// side; the table top is at z = 0 and links must stay above `table_margin_m`.
    ///
    /// Errors: [`PlanError::InvalidObject`] for non-finite or non-positive sizes.
    pub fn new(objects: &[ObjectGeometry], object_margin_m: f64, table_margin_m: f64) -> Result<Self, PlanError> {
        let mut obstacles = Vec::with_capacity(objects.len());
        for (index, o) in objects.iter().enumerate() {
            obstacles.push(Self::obstacle(o, object_margin_m).ok_or(PlanError::InvalidObject { index })?);
        }
        Ok(Self { obstacles, min_link_height_m: table_margin_m })
    }

    fn obstacle(o: &ObjectGeometry, margin: f64) -> Option<Obstacle> {
        let h = o.half_extents;
        let ok = o.center.iter().all(|v| v.is_finite())
            && o.yaw_rad.is_finite()
            && h.iter().all(|v| v.is_finite() && *v > 0.0)
            && margin.is_finite();
        if !ok {
            return None;
        }
        let (shape, world_from_shape, aabb_half) = match o.shape {
            Shape::Cuboid => {
                let he = h.add_scalar(margin);
                let c = Cuboid::new(Vector::new(he.x, he.y, he.z));
                let (s, co) = o.yaw_rad.sin_cos();
                let half = Vector3::new(co.abs() * he.x + s.abs() * he.y, s.abs() * he.x + co.abs() * he.y, he.z);
                (ObstacleShape::Cuboid(c), o.world_from_object(), half)
            }
            Shape::Cylinder => {
                let r = o.radius() + margin;
                let hz = h.z + margin;
                // parry's cylinder axis is y: rotate it onto world z.
                let world_from_shape = Se3::from_parts(
                    nalgebra::Translation3::from(o.center),
                    nalgebra::UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::FRAC_PI_2),
                );
                (ObstacleShape::Cylinder(Cylinder::new(hz, r)), world_from_shape, Vector3::new(r, r, hz))
            }
        };
        Some(Obstacle {
            shape,
            world_pose: pose_from_se3(&world_from_shape),
            aabb_min: o.center - aabb_half,
            aabb_max: o.center + aabb_half,
        })
    }

    /// Number of obstacles (map objects).
    pub fn len(&self) -> usize {
        self.obstacles.len()
    }

    /// Whether there are no map objects.
    pub fn is_empty(&self) -> bool {
        self.obstacles.is_empty()
    }
}

/// A capsule placed in the world.
#[derive(Debug, Clone, Copy)]
struct WorldCapsule {
    a: Point3<f64>,
    b: Point3<f64>,
    r: f64,
}

impl WorldCapsule {
    fn aabb_overlaps(&self, min: &Vector3<f64>, max: &Vector3<f64>) -> bool {
        (0..3).all(|i| self.a[i].min(self.b[i]) - self.r <= max[i] && self.a[i].max(self.b[i]) + self.r >= min[i])
    }
    fn parry(&self) -> Capsule {
        Capsule::new(vec_of(&self.a), vec_of(&self.b), self.r)
    }
}

/// What a configuration collides with (for diagnostics and typed errors).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Contact {
    /// A link is below the table margin.
    Table {
        /// Link name.
        link: String,
    },
    /// A link hits map object `object` (index into the scene's objects).
    Object {
        /// Link name.
        link: String,
        /// Object index.
        object: usize,
    },
    /// The held object ([`ArmCollisionModel::with_attached`]) hits map object `object`.
    HeldObject {
        /// Object index.
        object: usize,
    },
    /// Two links of the arm hit each other.
    SelfCollision {
        /// First link.
        link_a: String,
        /// Second link.
        link_b: String,
    },
}

/// The arm's collision model bound to its kinematic chain.
#[derive(Debug, Clone)]
pub struct ArmCollisionModel {
    /// Per capsule: index into `ArmChain::forward_all` (None = the root link) and the capsule.
    /// The first `n_arm` are the arm's own; the rest are attached (a held object,
    /// [`Self::with_attached`]).
    capsules: Vec<(Option<usize>, ArmCapsule)>,
    /// Number of the arm's own capsules (the attached ones follow).
    n_arm: usize,
    /// Capsule index pairs checked for self-collision.
    self_pairs: Vec<(usize, usize)>,
    /// Capsules exempt from the table test (the base).
    root_link: String,
}

impl ArmCollisionModel {
    /// Binds `capsules` to `chain`'s links and expands the link pairs into capsule pairs.
    ///
    /// Errors: [`PlanError::UnknownLink`] when a capsule or pair names a link not in the chain.
    pub fn new(
        chain: &ArmChain,
        capsules: Vec<ArmCapsule>,
        self_pairs: &[(String, String)],
    ) -> Result<Self, PlanError> {
        let mut bound = Vec::with_capacity(capsules.len());
        for c in capsules {
            let idx = if c.link == chain.root_link() {
                None
            } else {
                Some(chain.link_index(&c.link).ok_or_else(|| PlanError::UnknownLink { link: c.link.clone() })?)
            };
            bound.push((idx, c));
        }
        let known = |l: &str| bound.iter().any(|(_, c)| c.link == l);
        let mut pairs = Vec::new();
        for (la, lb) in self_pairs {
            for l in [la, lb] {
                if !known(l) {
                    return Err(PlanError::UnknownLink { link: l.clone() });
                }
            }
            for (i, (_, ca)) in bound.iter().enumerate() {
                for (j, (_, cb)) in bound.iter().enumerate() {
                    if ca.link == *la && cb.link == *lb {
                        pairs.push((i, j));
                    }
                }
            }
        }
        let n_arm = bound.len();
        Ok(Self { capsules: bound, n_arm, self_pairs: pairs, root_link: chain.root_link().to_string() })
    }

    /// This model with `capsule` attached to its link: a held object carried by the hand. Attached
    /// capsules are checked against the map objects only, not against the table (a held object is
    /// put down on it) nor against the arm (it sits between the fingers).
    ///
    /// Errors: [`PlanError::UnknownLink`] when the capsule's link is not in the chain.
    pub fn with_attached(&self, chain: &ArmChain, capsule: ArmCapsule) -> Result<Self, PlanError> {
        let idx = if capsule.link == chain.root_link() {
            None
        } else {
            Some(chain.link_index(&capsule.link).ok_or_else(|| PlanError::UnknownLink { link: capsule.link.clone() })?)
        };
        let mut out = self.clone();
        out.capsules.push((idx, capsule));
        Ok(out)
    }

    /// This model with the fingers of `hand_link` moved `by_m` towards each other: every capsule of
    /// that link lying wholly in [`FINGER_Z_RANGE_M`] at a constant nonzero `y` (a finger at full
    /// opening) has its `y` moved towards 0 by `by_m` (at most to 0). For a grasp whose fingers
    /// open less than fully.
    pub fn with_fingers_closed_by(&self, hand_link: &str, by_m: f64) -> Self {
        let mut out = self.clone();
        for (_, c) in out.capsules.iter_mut().take(self.n_arm) {
            let in_range = |p: &[f64; 3]| p[2] >= FINGER_Z_RANGE_M[0] - 1e-9 && p[2] <= FINGER_Z_RANGE_M[1] + 1e-9;
            let y = c.a_in_link[1];
            if c.link == hand_link
                && in_range(&c.a_in_link)
                && in_range(&c.b_in_link)
                && y != 0.0
                && c.b_in_link[1] == y
            {
                let moved = y.signum() * (y.abs() - by_m).max(0.0);
                c.a_in_link[1] = moved;
                c.b_in_link[1] = moved;
            }
        }
        out
    }

    /// The attached capsules (held objects), in their links' frames.
    pub fn attached(&self) -> impl Iterator<Item = &ArmCapsule> {
        self.capsules.iter().skip(self.n_arm).map(|(_, c)| c)
    }

    fn world_capsules(&self, links: &[Se3]) -> Vec<WorldCapsule> {
        self.capsules
            .iter()
            .map(|(idx, c)| {
                let t = idx.and_then(|i| links.get(i)).copied().unwrap_or_else(Se3::identity);
                WorldCapsule { a: t * Point3::from(c.a_in_link), b: t * Point3::from(c.b_in_link), r: c.radius_m }
            })
            .collect()
    }

    /// The first contact of configuration `q` in `scene`, or `None` when it is free.
    pub fn first_contact(&self, chain: &ArmChain, q: &JointVector, scene: &CollisionScene) -> Option<Contact> {
        let links = chain.forward_all(q);
        let caps = self.world_capsules(&links);
        // Table (cheapest) first; attached capsules are not tested against it.
        for (wc, (_, c)) in caps.iter().zip(self.capsules.iter()).take(self.n_arm) {
            if c.link != self.root_link && wc.a.z.min(wc.b.z) - wc.r < scene.min_link_height_m {
                return Some(Contact::Table { link: c.link.clone() });
            }
        }
        let identity = Pose::IDENTITY;
        for (i, (wc, (_, c))) in caps.iter().zip(self.capsules.iter()).enumerate() {
            for (k, o) in scene.obstacles.iter().enumerate() {
                if !wc.aabb_overlaps(&o.aabb_min, &o.aabb_max) {
                    continue;
                }
                let hit = intersection_test(&identity, &wc.parry(), &o.world_pose, o.shape.as_shape())
                    .map(|r| r.intersecting)
                    .unwrap_or(true);
                if hit {
                    if i >= self.n_arm {
                        return Some(Contact::HeldObject { object: k });
                    }
                    return Some(Contact::Object { link: c.link.clone(), object: k });
                }
            }
        }
        for &(i, j) in &self.self_pairs {
            let (Some(a), Some(b)) = (caps.get(i), caps.get(j)) else {
                continue;
            };
            let min = a.a.coords.inf(&a.b.coords).add_scalar(-a.r);
            let max = a.a.coords.sup(&a.b.coords).add_scalar(a.r);
            if !b.aabb_overlaps(&min, &max) {
                continue;
            }
            let hit =
                intersection_test(&identity, &a.parry(), &identity, &b.parry()).map(|r| r.intersecting).unwrap_or(true);
            if hit {
                let name = |k: usize| self.capsules.get(k).map(|(_, c)| c.link.clone()).unwrap_or_default();
                return Some(Contact::SelfCollision { link_a: name(i), link_b: name(j) });
            }
        }
        None
    }

    /// Whether `q` is collision-free in `scene`.
    pub fn is_free(&self, chain: &ArmChain, q: &JointVector, scene: &CollisionScene) -> bool {
        self.first_contact(chain, q, scene).is_none()
    }

    /// Smallest distance from the hand capsules (hand body and open fingers) placed at
    /// `world_from_hand` to the objects of `scene`, metres (negative-free: 0 when touching);
    /// `f64::INFINITY` for an empty scene.
    pub fn hand_clearance(&self, world_from_hand: &Se3, hand_link: &str, scene: &CollisionScene) -> f64 {
        let identity = Pose::IDENTITY;
        let mut best = f64::INFINITY;
        for (_, c) in self.capsules.iter().take(self.n_arm).filter(|(_, c)| c.link == hand_link) {
            let cap = Capsule::new(
                vec_of(&(world_from_hand * Point3::from(c.a_in_link))),
                vec_of(&(world_from_hand * Point3::from(c.b_in_link))),
                c.radius_m,
            );
            for o in &scene.obstacles {
                if let Ok(d) = parry3d_f64::query::distance(&identity, &cap, &o.world_pose, o.shape.as_shape()) {
                    best = best.min(d.distance);
                }
            }
        }
        best
    }
}
