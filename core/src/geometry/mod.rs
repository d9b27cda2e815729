//! Geometry shared by every module: rigid transforms, the pinhole camera, 2D boxes, yaw-oriented
//! 3D boxes and vertical cylinders, and their overlap measures.
//!
//! Entry points:
//! - [`Se3`] (an `Isometry3<f64>`) and [`se3_from_matrix`], which validates a 4x4 matrix as rigid.
//! - [`PinholeCamera`]: OpenCV convention (x right, y down, z forward), `project` / `unproject`.
//! - [`Box2`]: an axis-aligned image box in pixels, with [`Box2::iou`].
//! - [`ObjectGeometry`]: a [`Shape`] (cuboid with yaw, or vertical cylinder) with centre and
//!   half-extents in the world; [`iou3d`] and [`iou_top`] (top-view 2D IoU) between two of them.
//!
//! Conventions (DESIGN.md "Frames and units"): transforms are named `a_from_b`, points say their
//! space (`p_in_world`), metres and radians inside. Yaw is a rotation about the world z axis
//! (table normal, up). A cylinder's axis is the world z axis; its radius is the mean of its two
//! horizontal half-extents.
//!
//! The 3D IoU of two yaw-oriented boxes is exact: the intersection of their top-view rectangles
//! (convex polygon clipping, Sutherland-Hodgman) times the overlap of their z intervals. The IoU of
//! two cylinders is exact too: the lens area of two circles times the z overlap. Between a box and
//! a cylinder the cylinder is replaced by its yaw-0 bounding box (stated approximation; evaluation
//! only compares objects of the same class, hence the same shape).

mod polygon;

use nalgebra::{Isometry3, Matrix3, Matrix4, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

pub use polygon::{convex_polygon_area, convex_polygon_intersection};

/// A rigid transform in 3D (rotation + translation), `a_from_b` maps points in `b` to `a`.
pub type Se3 = Isometry3<f64>;

/// Tolerance used when checking that a matrix is a rotation (orthonormal, determinant +1). Poses
/// from SAPIEN are single precision, so their rotation parts are orthonormal only to ~1e-4; larger
/// deviations (a scale or shear of 0.1 %) are rejected. Accepted matrices are re-orthonormalised
/// (via the nearest unit quaternion).
pub const RIGID_TOLERANCE: f64 = 1e-3;

/// Errors of the geometry module.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum GeometryError {
    /// A transform matrix has a non-finite entry.
    #[error("{field}: matrix has a non-finite entry")]
    NonFinite {
        /// Name of the offending argument.
        field: &'static str,
    },
    /// A 4x4 matrix is not a rigid transform (rotation part not orthonormal, or bad last row).
    #[error("{field}: not a rigid transform ({reason})")]
    NotRigid {
        /// Name of the offending argument.
        field: &'static str,
        /// What failed.
        reason: String,
    },
    /// Camera intrinsics are invalid.
    #[error("camera intrinsics: {reason}")]
    BadIntrinsics {
        /// What failed.
        reason: String,
    },
    /// A construction has no unique answer (e.g. a view whose eye and target coincide).
    #[error("{what}")]
    Degenerate {
        /// What is degenerate.
        what: &'static str,
    },
}

/// A matrix as rows of values (e.g. a pose's 4x4 homogeneous matrix for JSON).
pub fn rows<const R: usize, const C: usize>(m: &nalgebra::SMatrix<f64, R, C>) -> [[f64; C]; R] {
    std::array::from_fn(|r| std::array::from_fn(|c| m[(r, c)]))
}

/// Build an [`Se3`] from a row-major 4x4 homogeneous matrix, checking it is rigid.
///
/// `field` names the argument in the error (e.g. `"world_from_camera"`).
pub fn se3_from_matrix(m: &Matrix4<f64>, field: &'static str) -> Result<Se3, GeometryError> {
    if m.iter().any(|v| !v.is_finite()) {
        return Err(GeometryError::NonFinite { field });
    }
    let last = m.row(3);
    if (last[0].abs() + last[1].abs() + last[2].abs() + (last[3] - 1.0).abs()) > RIGID_TOLERANCE {
        return Err(GeometryError::NotRigid { field, reason: "last row is not [0, 0, 0, 1]".into() });
    }
    let r: Matrix3<f64> = m.fixed_view::<3, 3>(0, 0).into_owned();
    let orth = (r.transpose() * r - Matrix3::identity()).abs().max();
    if orth > RIGID_TOLERANCE {
        return Err(GeometryError::NotRigid {
            field,
            reason: format!("rotation part is not orthonormal (max |RᵀR − I| = {orth:.2e})"),
        });
    }
    let det = r.determinant();
    if (det - 1.0).abs() > RIGID_TOLERANCE {
        return Err(GeometryError::NotRigid { field, reason: format!("rotation determinant is {det:.4}, not +1") });
    }
    let rotation = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r));
    let translation = Translation3::new(m[(0, 3)], m[(1, 3)], m[(2, 3)]);
    Ok(Isometry3::from_parts(translation, rotation))
}

/// A rigid transform that rotates by `yaw_rad` about world z and translates by `center`.
pub fn se3_from_yaw(center: Vector3<f64>, yaw_rad: f64) -> Se3 {
    Isometry3::new(center, Vector3::new(0.0, 0.0, yaw_rad))
}

/// The yaw (rotation about z) of a transform's rotation, in (−π, π].
pub fn yaw_of(t: &Se3) -> f64 {
    let r = t.rotation.to_rotation_matrix();
    r[(1, 0)].atan2(r[(0, 0)])
}

/// Wrap an angle into (−π, π].
pub fn wrap_angle(a: f64) -> f64 {
    let two_pi = std::f64::consts::TAU;
    let mut x = a % two_pi;
    if x <= -std::f64::consts::PI {
        x += two_pi;
    } else if x > std::f64::consts::PI {
        x -= two_pi;
    }
    x
}

/// Pinhole camera intrinsics, camera axes as OpenCV (x right, y down, z forward), `u = fx · x / z +
/// cx`. Image coordinates are continuous with the origin at the image's top-left *corner*: pixel
/// `(i, j)` (column, row) spans `[i, i + 1) × [j, j + 1)` and its centre is `(i + 0.5, j + 0.5)`.
/// This is the convention of a rendered image (SAPIEN/OpenGL: a centred principal point is `(w/2,
/// h/2)`, [`PinholeCamera::from_fovy`]; `tests/test_sim.py` checks back-projected pixels against
/// SAPIEN's position buffer) and of the line segments
/// ([`crate::objects::lsd`]). Back-project a pixel of a depth image with
/// [`PinholeCamera::unproject_pixel`]; the pixel containing a projected point is `(⌊u⌋, ⌊v⌋)`.
/// OpenCV's calibration puts pixel centres at integers instead: add 0.5 to its `cx`, `cy`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PinholeCamera {
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Focal length along x, pixels.
    pub fx: f64,
    /// Focal length along y, pixels.
    pub fy: f64,
    /// Principal point x, pixels.
    pub cx: f64,
    /// Principal point y, pixels.
    pub cy: f64,
}

impl PinholeCamera {
    /// Build and validate intrinsics.
    pub fn new(width: u32, height: u32, fx: f64, fy: f64, cx: f64, cy: f64) -> Result<Self, GeometryError> {
        let cam = Self { width, height, fx, fy, cx, cy };
        cam.validate()?;
        Ok(cam)
    }

    /// Intrinsics for a given vertical field of view (radians), principal point at the centre.
    pub fn from_fovy(width: u32, height: u32, fovy_rad: f64) -> Result<Self, GeometryError> {
        if !(fovy_rad.is_finite() && fovy_rad > 0.0 && fovy_rad < std::f64::consts::PI) {
            return Err(GeometryError::BadIntrinsics { reason: format!("fovy {fovy_rad} rad outside (0, π)") });
        }
        let f = f64::from(height) / 2.0 / (fovy_rad / 2.0).tan();
        Self::new(width, height, f, f, f64::from(width) / 2.0, f64::from(height) / 2.0)
    }

    /// Build from a 3x3 intrinsic matrix `K`.
    pub fn from_matrix(width: u32, height: u32, k: &Matrix3<f64>) -> Result<Self, GeometryError> {
        Self::new(width, height, k[(0, 0)], k[(1, 1)], k[(0, 2)], k[(1, 2)])
    }

    /// Check the intrinsics are finite and positive.
    pub fn validate(&self) -> Result<(), GeometryError> {
        if self.width == 0 || self.height == 0 {
            return Err(GeometryError::BadIntrinsics { reason: format!("image size {}x{}", self.width, self.height) });
        }
        for (name, v) in [("fx", self.fx), ("fy", self.fy), ("cx", self.cx), ("cy", self.cy)] {
            if !v.is_finite() {
                return Err(GeometryError::BadIntrinsics { reason: format!("{name} is not finite") });
            }
        }
        if self.fx <= 0.0 || self.fy <= 0.0 {
            return Err(GeometryError::BadIntrinsics { reason: "focal lengths must be positive".into() });
        }
        Ok(())
    }

    /// The 3x3 intrinsic matrix.
    pub fn matrix(&self) -> Matrix3<f64> {
        Matrix3::new(self.fx, 0.0, self.cx, 0.0, self.fy, self.cy, 0.0, 0.0, 1.0)
    }

    /// Project a point in the camera frame to pixel coordinates; `None` behind the camera
    /// (z ≤ `MIN_DEPTH_M`). The result may fall outside the image.
    pub fn project(&self, p_in_camera: &Point3<f64>) -> Option<[f64; 2]> {
        if p_in_camera.z <= MIN_DEPTH_M {
            return None;
        }
        Some([self.fx * p_in_camera.x / p_in_camera.z + self.cx, self.fy * p_in_camera.y / p_in_camera.z + self.cy])
    }

    /// Back-project pixel `(u, v)` at depth `depth_m` (along z) into the camera frame.
    pub fn unproject(&self, u: f64, v: f64, depth_m: f64) -> Point3<f64> {
        Point3::new((u - self.cx) / self.fx * depth_m, (v - self.cy) / self.fy * depth_m, depth_m)
    }

    /// Back-project the centre of pixel `(col, row)` (image coordinates `(col + 0.5, row + 0.5)`) at
    /// depth `depth_m`: the point a depth image's value at that pixel stands for.
    pub fn unproject_pixel(&self, col: u32, row: u32, depth_m: f64) -> Point3<f64> {
        self.unproject(f64::from(col) + 0.5, f64::from(row) + 0.5, depth_m)
    }

    /// Whether pixel coordinates are inside the image.
    pub fn contains(&self, uv: [f64; 2]) -> bool {
        uv[0] >= 0.0 && uv[1] >= 0.0 && uv[0] < f64::from(self.width) && uv[1] < f64::from(self.height)
    }

    /// The whole image as a box.
    pub fn image_box(&self) -> Box2 {
        Box2 { min: [0.0, 0.0], max: [f64::from(self.width), f64::from(self.height)] }
    }
}

/// Points closer than this (metres, along the optical axis) do not project.
pub const MIN_DEPTH_M: f64 = 1e-6;

/// An axis-aligned box in image pixels: `min` = (left, top), `max` = (right, bottom).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Box2 {
    /// (u, v) of the top-left corner.
    pub min: [f64; 2],
    /// (u, v) of the bottom-right corner.
    pub max: [f64; 2],
}

impl Box2 {
    /// A box from its corners; corners are sorted so `min ≤ max`.
    pub fn new(u0: f64, v0: f64, u1: f64, v1: f64) -> Self {
        Self { min: [u0.min(u1), v0.min(v1)], max: [u0.max(u1), v0.max(v1)] }
    }

    /// The tightest box around a set of pixel coordinates (`None` if empty).
    pub fn from_points<'a>(points: impl IntoIterator<Item = &'a [f64; 2]>) -> Option<Self> {
        let mut it = points.into_iter();
        let first = it.next()?;
        let mut b = Self { min: *first, max: *first };
        for p in it {
            b.min = [b.min[0].min(p[0]), b.min[1].min(p[1])];
            b.max = [b.max[0].max(p[0]), b.max[1].max(p[1])];
        }
        Some(b)
    }

    /// Width in pixels.
    pub fn width(&self) -> f64 {
        (self.max[0] - self.min[0]).max(0.0)
    }

    /// Height in pixels.
    pub fn height(&self) -> f64 {
        (self.max[1] - self.min[1]).max(0.0)
    }

    /// Area in square pixels.
    pub fn area(&self) -> f64 {
        self.width() * self.height()
    }

    /// Centre (u, v).
    pub fn center(&self) -> [f64; 2] {
        [(self.min[0] + self.max[0]) / 2.0, (self.min[1] + self.max[1]) / 2.0]
    }

    /// Whether all coordinates are finite.
    pub fn is_finite(&self) -> bool {
        self.min.iter().chain(self.max.iter()).all(|v| v.is_finite())
    }

    /// Intersection with another box (`None` if they do not overlap).
    pub fn intersection(&self, other: &Self) -> Option<Self> {
        let b = Self {
            min: [self.min[0].max(other.min[0]), self.min[1].max(other.min[1])],
            max: [self.max[0].min(other.max[0]), self.max[1].min(other.max[1])],
        };
        (b.max[0] > b.min[0] && b.max[1] > b.min[1]).then_some(b)
    }

    /// Intersection over union; 0 when either box is empty.
    pub fn iou(&self, other: &Self) -> f64 {
        let inter = self.intersection(other).map_or(0.0, |b| b.area());
        let union = self.area() + other.area() - inter;
        if union <= 0.0 {
            0.0
        } else {
            inter / union
        }
    }

    /// Whether pixel `(u, v)` is inside (half-open on the max side).
    pub fn contains(&self, u: f64, v: f64) -> bool {
        u >= self.min[0] && v >= self.min[1] && u < self.max[0] && v < self.max[1]
    }
}

/// The primitive an object is modelled with (the paper's "class → model" rule).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Shape {
    /// A box with a yaw about world z (blocks, books, keyboards).
    Cuboid,
    /// A cylinder with its axis along world z; no yaw (cups, cans, bottles, balls).
    Cylinder,
}

/// An object's extent in the world: a [`Shape`] with centre, yaw and half-extents.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ObjectGeometry {
    /// Primitive.
    pub shape: Shape,
    /// Centre in the world frame, metres.
    pub center: Vector3<f64>,
    /// Rotation about world z, radians (ignored for cylinders).
    pub yaw_rad: f64,
    /// Half-extents along the object's x, y, z axes, metres.
    pub half_extents: Vector3<f64>,
}

impl ObjectGeometry {
    /// The same object seen in a world frame moved by the rigid `delta` (`new_world ← old_world`):
    /// centre moved, yaw turned by the heading change of the object's x axis, size unchanged
    /// (`delta` is meant to be close to a rotation about z, e.g. a SLAM gauge update).
    pub fn transformed(&self, delta: &Se3) -> ObjectGeometry {
        let center = (delta * Point3::from(self.center)).coords;
        let x = delta.rotation * Vector3::new(self.yaw_rad.cos(), self.yaw_rad.sin(), 0.0);
        let yaw_rad = if self.shape == Shape::Cylinder { self.yaw_rad } else { x.y.atan2(x.x) };
        ObjectGeometry { center, yaw_rad, ..*self }
    }

    /// Radius of a cylinder: mean of the two horizontal half-extents.
    pub fn radius(&self) -> f64 {
        (self.half_extents.x + self.half_extents.y) / 2.0
    }

    /// `world_from_object`.
    pub fn world_from_object(&self) -> Se3 {
        se3_from_yaw(self.center, if self.shape == Shape::Cylinder { 0.0 } else { self.yaw_rad })
    }

    /// Signed distance of a world point to the primitive's surface (negative inside), metres:
    /// the box's faces, or the cylinder's wall, top and bottom discs (its radius is
    /// [`Self::radius`]).
    pub fn surface_distance(&self, p: &Point3<f64>) -> f64 {
        let d = p.coords - self.center;
        let q = match self.shape {
            Shape::Cuboid => {
                let (s, c) = self.yaw_rad.sin_cos();
                let local = Vector3::new(c * d.x + s * d.y, -s * d.x + c * d.y, d.z);
                local.abs() - self.half_extents
            }
            Shape::Cylinder => {
                let radial = d.x.hypot(d.y) - self.radius();
                Vector3::new(radial, radial, d.z.abs() - self.half_extents.z)
            }
        };
        let outside = match self.shape {
            Shape::Cuboid => q.sup(&Vector3::zeros()).norm(),
            Shape::Cylinder => q.x.max(0.0).hypot(q.z.max(0.0)),
        };
        outside + q.max().min(0.0)
    }

    /// Volume in cubic metres.
    pub fn volume(&self) -> f64 {
        let h = 2.0 * self.half_extents.z;
        match self.shape {
            Shape::Cuboid => 8.0 * self.half_extents.x * self.half_extents.y * self.half_extents.z,
            Shape::Cylinder => std::f64::consts::PI * self.radius().powi(2) * h,
        }
    }

    /// Top-view footprint area in square metres.
    pub fn footprint_area(&self) -> f64 {
        match self.shape {
            Shape::Cuboid => 4.0 * self.half_extents.x * self.half_extents.y,
            Shape::Cylinder => std::f64::consts::PI * self.radius().powi(2),
        }
    }

    /// The four top-view corners of the cuboid footprint, counter-clockwise (cylinders give their
    /// yaw-0 bounding square).
    pub fn footprint_corners(&self) -> [[f64; 2]; 4] {
        let (hx, hy, yaw) = match self.shape {
            Shape::Cuboid => (self.half_extents.x, self.half_extents.y, self.yaw_rad),
            Shape::Cylinder => (self.radius(), self.radius(), 0.0),
        };
        let (s, c) = yaw.sin_cos();
        let local = [[hx, hy], [-hx, hy], [-hx, -hy], [hx, -hy]];
        let mut out = [[0.0; 2]; 4];
        for (o, l) in out.iter_mut().zip(local) {
            *o = [self.center.x + c * l[0] - s * l[1], self.center.y + s * l[0] + c * l[1]];
        }
        // (hx,hy) → (−hx,hy) → … is counter-clockwise for a right-handed frame.
        out
    }

    /// The eight corners of the cuboid in the world frame (a cylinder's bounding box).
    pub fn corners(&self) -> [Point3<f64>; 8] {
        let f = self.footprint_corners();
        let z0 = self.center.z - self.half_extents.z;
        let z1 = self.center.z + self.half_extents.z;
        let mut out = [Point3::origin(); 8];
        for (i, c) in f.iter().enumerate() {
            out[i] = Point3::new(c[0], c[1], z0);
            out[i + 4] = Point3::new(c[0], c[1], z1);
        }
        out
    }

    fn z_overlap(&self, other: &Self) -> f64 {
        let lo = (self.center.z - self.half_extents.z).max(other.center.z - other.half_extents.z);
        let hi = (self.center.z + self.half_extents.z).min(other.center.z + other.half_extents.z);
        (hi - lo).max(0.0)
    }
}

/// Area of the intersection of two top-view footprints, square metres.
pub fn footprint_intersection(a: &ObjectGeometry, b: &ObjectGeometry) -> f64 {
    if a.shape == Shape::Cylinder && b.shape == Shape::Cylinder {
        let d = ((a.center.x - b.center.x).powi(2) + (a.center.y - b.center.y).powi(2)).sqrt();
        return circle_intersection_area(a.radius(), b.radius(), d);
    }
    let pa = a.footprint_corners();
    let pb = b.footprint_corners();
    convex_polygon_area(&convex_polygon_intersection(&pa, &pb))
}

fn footprint_area_for_iou(g: &ObjectGeometry, other: &ObjectGeometry) -> f64 {
    if g.shape == Shape::Cylinder && other.shape == Shape::Cylinder {
        g.footprint_area()
    } else {
        // Mixed shapes: the cylinder is replaced by its bounding square.
        let c = g.footprint_corners();
        convex_polygon_area(&c)
    }
}

/// Area of the lens where two circles of radii `r0`, `r1` with centres `d` apart overlap.
pub fn circle_intersection_area(r0: f64, r1: f64, d: f64) -> f64 {
    if r0 <= 0.0 || r1 <= 0.0 || d >= r0 + r1 {
        return 0.0;
    }
    if d <= (r0 - r1).abs() {
        let r = r0.min(r1);
        return std::f64::consts::PI * r * r;
    }
    let a0 = ((d * d + r0 * r0 - r1 * r1) / (2.0 * d * r0)).clamp(-1.0, 1.0).acos();
    let a1 = ((d * d + r1 * r1 - r0 * r0) / (2.0 * d * r1)).clamp(-1.0, 1.0).acos();
    let k = (-d + r0 + r1) * (d + r0 - r1) * (d - r0 + r1) * (d + r0 + r1);
    r0 * r0 * a0 + r1 * r1 * a1 - 0.5 * k.max(0.0).sqrt()
}

/// Top-view (bird's-eye) 2D IoU of two objects' footprints.
pub fn iou_top(a: &ObjectGeometry, b: &ObjectGeometry) -> f64 {
    let inter = footprint_intersection(a, b);
    let union = footprint_area_for_iou(a, b) + footprint_area_for_iou(b, a) - inter;
    if union <= 0.0 {
        0.0
    } else {
        (inter / union).clamp(0.0, 1.0)
    }
}

/// Volume shared by two objects (exact for box–box with yaw and cylinder–cylinder; a cylinder
/// against a box counts as its bounding square prism).
pub fn intersection_volume(a: &ObjectGeometry, b: &ObjectGeometry) -> f64 {
    footprint_intersection(a, b) * a.z_overlap(b)
}

/// 3D IoU of two objects (exact for box–box with yaw and cylinder–cylinder).
pub fn iou3d(a: &ObjectGeometry, b: &ObjectGeometry) -> f64 {
    let inter = intersection_volume(a, b);
    let va = footprint_area_for_iou(a, b) * 2.0 * a.half_extents.z;
    let vb = footprint_area_for_iou(b, a) * 2.0 * b.half_extents.z;
    let union = va + vb - inter;
    if union <= 0.0 {
        0.0
    } else {
        (inter / union).clamp(0.0, 1.0)
    }
}

/// Yaw error in degrees between an estimate and the truth, modulo the shape's symmetry:
/// a cuboid is symmetric under 180°; one whose horizontal sides differ by less than
/// `square_tolerance` (relative) also under 90°. The yaws compared are those of each box's longer
/// horizontal side, so a box described as (a, b) at θ equals (b, a) at θ + 90°. Cylinders have no
/// yaw: `None`.
pub fn yaw_error_deg(estimate: &ObjectGeometry, truth: &ObjectGeometry, square_tolerance: f64) -> Option<f64> {
    if truth.shape == Shape::Cylinder {
        return None;
    }
    let (hx, hy) = (truth.half_extents.x, truth.half_extents.y);
    let square = (hx - hy).abs() <= square_tolerance * hx.max(hy);
    let period = if square { std::f64::consts::FRAC_PI_2 } else { std::f64::consts::PI };
    // A box with sides (a, b) at θ is the box (b, a) at θ + 90°: compare the yaws of the long sides.
    let long_side_yaw = |g: &ObjectGeometry| {
        if g.half_extents.x >= g.half_extents.y {
            g.yaw_rad
        } else {
            g.yaw_rad + std::f64::consts::FRAC_PI_2
        }
    };
    let d = (long_side_yaw(estimate) - long_side_yaw(truth)).rem_euclid(period);
    Some(d.min(period - d).to_degrees())
}

/// A point in the world, as nalgebra's type (re-exported for convenience).
pub type PointWorld = Point3<f64>;

/// Fixed-radius neighbour test on 3D points: a hash grid with cells of the radius, so "is any
/// stored point within `radius` of q" looks at the 27 cells around q. Non-finite points are not
/// stored and have no neighbours.
#[derive(Debug, Clone)]
pub struct RadiusGrid {
    radius: f64,
    cells: std::collections::HashMap<[i64; 3], Vec<Point3<f64>>, CellHashBuilder>,
}

/// The grid's cell hash: a multiply-rotate mix of the key's 8-byte words (the keys are integer
/// cell coordinates chosen by the program, not by an adversary, so the standard library's
/// DoS-resistant SipHash buys nothing here and costs a third of a lookup). The grid is only looked
/// up, never iterated, so the hash cannot change any result.
#[derive(Debug, Clone, Copy, Default)]
struct CellHashBuilder;

impl std::hash::BuildHasher for CellHashBuilder {
    type Hasher = CellHasher;
    fn build_hasher(&self) -> CellHasher {
        CellHasher(0)
    }
}

/// See [`CellHashBuilder`].
#[derive(Debug, Clone, Copy)]
struct CellHasher(u64);

impl CellHasher {
    const K: u64 = 0x517c_c1b7_2722_0a95;
    fn mix(&mut self, word: u64) {
        self.0 = (self.0.rotate_left(5) ^ word).wrapping_mul(Self::K);
    }
}

impl std::hash::Hasher for CellHasher {
    fn write(&mut self, bytes: &[u8]) {
        let mut chunks = bytes.chunks_exact(8);
        for c in &mut chunks {
            let mut w = [0u8; 8];
            w.copy_from_slice(c);
            self.mix(u64::from_le_bytes(w));
        }
        for b in chunks.remainder() {
            self.mix(u64::from(*b));
        }
    }
    fn write_u64(&mut self, v: u64) {
        self.mix(v);
    }
    fn write_usize(&mut self, v: usize) {
        self.mix(v as u64);
    }
    fn finish(&self) -> u64 {
        self.0
    }
}

impl RadiusGrid {
    /// An empty grid; `None` unless `radius` is finite and positive.
    pub fn new(radius: f64) -> Option<Self> {
        (radius.is_finite() && radius > 0.0)
            .then(|| Self { radius, cells: std::collections::HashMap::with_hasher(CellHashBuilder) })
    }

    fn cell(&self, p: &Point3<f64>) -> [i64; 3] {
        let r = self.radius;
        [(p.x / r).floor() as i64, (p.y / r).floor() as i64, (p.z / r).floor() as i64]
    }

    /// Store a point (ignored when non-finite).
    pub fn insert(&mut self, p: Point3<f64>) {
        if p.coords.iter().all(|v| v.is_finite()) {
            let c = self.cell(&p);
            self.cells.entry(c).or_default().push(p);
        }
    }

    /// Whether a stored point lies within the radius of `q` (inclusive).
    pub fn has_within(&self, q: &Point3<f64>) -> bool {
        if !q.coords.iter().all(|v| v.is_finite()) {
            return false;
        }
        let c = self.cell(q);
        let r2 = self.radius * self.radius;
        (-1..=1).any(|dx| {
            (-1..=1).any(|dy| {
                (-1..=1).any(|dz| {
                    self.cells
                        .get(&[c[0] + dx, c[1] + dy, c[2] + dz])
                        .is_some_and(|ps| ps.iter().any(|p| (p - q).norm_squared() <= r2))
                })
            })
        })
    }

    /// How many stored points lie within the radius of `q` (inclusive; 0 for a non-finite `q`).
    pub fn count_within(&self, q: &Point3<f64>) -> usize {
        if !q.coords.iter().all(|v| v.is_finite()) {
            return 0;
        }
        let c = self.cell(q);
        let r2 = self.radius * self.radius;
        let mut n = 0;
        for dx in -1..=1 {
            for dy in -1..=1 {
                for dz in -1..=1 {
                    if let Some(ps) = self.cells.get(&[c[0] + dx, c[1] + dy, c[2] + dz]) {
                        n += ps.iter().filter(|p| (*p - q).norm_squared() <= r2).count();
                    }
                }
            }
        }
        n
    }
}

/// The main body of a cloud: points are voxelised into cells of `voxel_m`; occupied cells within
/// `reach` cells of each other (per axis) are connected; the component with the most points is
/// kept, and so is every other component with at least `keep_share` of its points. Returns one
/// flag per point (non-finite points are never kept). A cloud with one component keeps everything;
/// an empty cloud, a non-positive voxel or a negative reach keeps everything too (nothing to decide).
pub fn main_components(points: &[Point3<f64>], voxel_m: f64, reach: i64, keep_share: f64) -> Vec<bool> {
    let finite = |p: &Point3<f64>| p.coords.iter().all(|v| v.is_finite());
    if points.is_empty() || !(voxel_m.is_finite() && voxel_m > 0.0) || reach < 0 {
        return points.iter().map(finite).collect();
    }
    let cell = |p: &Point3<f64>| {
        [(p.x / voxel_m).floor() as i64, (p.y / voxel_m).floor() as i64, (p.z / voxel_m).floor() as i64]
    };
    // Occupied cells with their point counts, in first-seen order (deterministic).
    let mut index: std::collections::HashMap<[i64; 3], usize> = std::collections::HashMap::new();
    let mut cells: Vec<([i64; 3], usize)> = Vec::new();
    let mut point_cell: Vec<Option<usize>> = Vec::with_capacity(points.len());
    for p in points {
        if !finite(p) {
            point_cell.push(None);
            continue;
        }
        let c = cell(p);
        let k = *index.entry(c).or_insert_with(|| {
            cells.push((c, 0));
            cells.len() - 1
        });
        cells[k].1 += 1;
        point_cell.push(Some(k));
    }
    // Breadth-first components over cells.
    let mut component = vec![usize::MAX; cells.len()];
    let mut sizes: Vec<usize> = Vec::new();
    for start in 0..cells.len() {
        if component[start] != usize::MAX {
            continue;
        }
        let id = sizes.len();
        let mut size = 0;
        component[start] = id;
        let mut queue = std::collections::VecDeque::from([start]);
        while let Some(k) = queue.pop_front() {
            size += cells[k].1;
            let c = cells[k].0;
            for dx in -reach..=reach {
                for dy in -reach..=reach {
                    for dz in -reach..=reach {
                        if let Some(&n) = index.get(&[c[0] + dx, c[1] + dy, c[2] + dz]) {
                            if component[n] == usize::MAX {
                                component[n] = id;
                                queue.push_back(n);
                            }
                        }
                    }
                }
            }
        }
        sizes.push(size);
    }
    let largest = sizes.iter().copied().max().unwrap_or(0) as f64;
    let keep: Vec<bool> = sizes.iter().map(|&s| s as f64 >= keep_share * largest).collect();
    point_cell.iter().map(|k| k.is_some_and(|k| keep[component[k]])).collect()
}

/// `world_from_camera` for a camera at `eye` looking at `target` (OpenCV axes: z towards the
/// target). Image "up" (−y) is world +z projected onto the image plane; when the view is within
/// ~8° of vertical it is instead the horizontal direction away from the robot base (world origin)
/// through the eye (world +x when the eye is above the origin).
pub fn look_at(eye: &Point3<f64>, target: &Point3<f64>) -> Result<Se3, GeometryError> {
    let d = target - eye;
    let radial = Vector3::new(eye.x, eye.y, 0.0);
    let up = if d.norm() > 0.0 && (d.z.abs() / d.norm()) > NEAR_VERTICAL_COS {
        if radial.norm() > 1e-6 {
            radial / radial.norm()
        } else {
            Vector3::x()
        }
    } else {
        Vector3::z()
    };
    look_at_with_up(eye, target, &up)
}

/// Viewing directions closer to vertical than this (|cos| of the angle to world z) use the
/// horizontal "away from the robot" direction as image up in [`look_at`].
const NEAR_VERTICAL_COS: f64 = 0.99;

/// `world_from_camera` looking from `eye` at `target` with image up (−y) along `up_hint`
/// projected onto the image plane. Errors when the eye and target coincide or `up_hint` is
/// (nearly) parallel to the viewing direction.
pub fn look_at_with_up(eye: &Point3<f64>, target: &Point3<f64>, up_hint: &Vector3<f64>) -> Result<Se3, GeometryError> {
    if eye.coords.iter().chain(target.coords.iter()).chain(up_hint.iter()).any(|v| !v.is_finite()) {
        return Err(GeometryError::NonFinite { field: "look_at eye/target/up" });
    }
    let d = target - eye;
    let n = d.norm();
    if n < 1e-9 {
        return Err(GeometryError::Degenerate { what: "look_at: eye and target coincide" });
    }
    let z = d / n;
    let up_perp = up_hint - z * up_hint.dot(&z);
    if up_perp.norm() < 1e-6 {
        return Err(GeometryError::Degenerate { what: "look_at: up direction parallel to the view" });
    }
    let y = -up_perp / up_perp.norm();
    let x = y.cross(&z);
    let r = Rotation3::from_matrix_unchecked(Matrix3::from_columns(&[x, y, z]));
    Ok(Se3::from_parts(Translation3::from(eye.coords), UnitQuaternion::from_rotation_matrix(&r)))
}

/// Per-axis quantile extent `[trim, 1 − trim]` of a point set (`None` if empty).
pub fn trimmed_extent(points: &[Point3<f64>], trim: f64) -> Option<(Vector3<f64>, Vector3<f64>)> {
    if points.is_empty() {
        return None;
    }
    let mut lo = Vector3::zeros();
    let mut hi = Vector3::zeros();
    let n = points.len();
    let k = ((trim.clamp(0.0, 0.49)) * n as f64).floor() as usize;
    let mut v: Vec<f64> = Vec::with_capacity(n);
    for axis in 0..3 {
        // Two order statistics by selection (linear time), the same values a full sort gives.
        v.clear();
        v.extend(points.iter().map(|p| p[axis]));
        let (_, low, above) = v.select_nth_unstable_by(k, f64::total_cmp);
        lo[axis] = *low;
        // The (n − 1 − k)-th smallest: the k-th largest, found among the values above the k-th.
        hi[axis] = if n - 1 - k == k {
            *low
        } else {
            let j = n - 1 - k - (k + 1);
            *above.select_nth_unstable_by(j, f64::total_cmp).1
        };
    }
    Some((lo, hi))
}

/// The image box of an object's corners seen from a camera, clipped to the image; `None` when any
/// corner is behind the camera or the box misses the image.
pub fn project_geometry(g: &ObjectGeometry, camera: &PinholeCamera, world_from_camera: &Se3) -> Option<Box2> {
    let camera_from_world = world_from_camera.inverse();
    let mut uvs = Vec::with_capacity(8);
    for c in g.corners() {
        uvs.push(camera.project(&(camera_from_world * c))?);
    }
    Box2::from_points(uvs.iter())?.intersection(&camera.image_box())
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::{FRAC_PI_2, FRAC_PI_4, PI};

    #[test]
    fn cylinder_surface_distance_is_signed() {
        let g = ObjectGeometry {
            shape: Shape::Cylinder,
            center: Vector3::new(1.0, 2.0, 0.05),
            yaw_rad: 0.7,
            half_extents: Vector3::new(0.03, 0.03, 0.05),
        };
        let at = |x: f64, y: f64, z: f64| g.surface_distance(&Point3::new(1.0 + x, 2.0 + y, 0.05 + z));
        // On the wall at any angle (the yaw does not matter), on the top disc.
        for a in [0.0, 0.9, 2.5, -1.7] {
            assert!(at(0.03 * f64::cos(a), 0.03 * f64::sin(a), 0.01).abs() < 1e-12);
        }
        assert!(at(0.01, -0.01, 0.05).abs() < 1e-12);
        // Outside the wall by 2 cm; inside, nearest the wall (1 cm) or the top (4 mm).
        assert!((at(0.0, 0.05, 0.0) - 0.02).abs() < 1e-12);
        assert!((at(0.02, 0.0, 0.0) + 0.01).abs() < 1e-12);
        assert!((at(0.0, 0.0, 0.046) + 0.004).abs() < 1e-12);
        // Beyond the rim: Euclidean distance to it (3 cm out, 4 cm up gives 5 cm).
        assert!((at(0.06, 0.0, 0.09) - 0.05).abs() < 1e-12);
        // A box point at its corner is off a cylinder of the box's half-width by (√2 − 1) of it.
        let corner = Point3::new(1.0 + 0.03, 2.0 + 0.03, 0.05);
        assert!((g.surface_distance(&corner) - 0.03 * (2f64.sqrt() - 1.0)).abs() < 1e-12);
    }

    #[test]
    fn radius_grid_counts_what_brute_force_counts() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        // Negative and positive cells, points on cell borders (a 5 mm lattice under a 1 cm radius).
        let mut pts: Vec<Point3<f64>> = (0..2000)
            .map(|_| {
                Point3::new(rng.random_range(-0.1..0.1), rng.random_range(-0.1..0.1), rng.random_range(-0.05..0.05))
            })
            .collect();
        pts.extend((-4..4).map(|i| Point3::new(f64::from(i) * 0.005, 0.0, 0.0)));
        let radius = 0.01;
        let mut grid = RadiusGrid::new(radius).unwrap();
        pts.iter().for_each(|p| grid.insert(*p));
        grid.insert(Point3::new(f64::NAN, 0.0, 0.0));
        for q in pts.iter().step_by(7).chain([Point3::new(0.0, 0.0, 0.0), Point3::new(0.5, 0.5, 0.5)].iter()) {
            let brute = pts.iter().filter(|p| (*p - q).norm_squared() <= radius * radius).count();
            assert_eq!(grid.count_within(q), brute, "{q:?}");
            assert_eq!(grid.has_within(q), brute > 0, "{q:?}");
        }
        assert_eq!(grid.count_within(&Point3::new(f64::INFINITY, 0.0, 0.0)), 0);
        assert!(RadiusGrid::new(0.0).is_none() && RadiusGrid::new(f64::NAN).is_none());
    }

    #[test]
    fn trimmed_extent_equals_the_sorted_quantiles() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        for n in 1..60 {
            // Repeated values too (ties): coordinates on a 1 cm lattice.
            let pts: Vec<Point3<f64>> = (0..n)
                .map(|_| {
                    Point3::new(
                        rng.random_range(-5..5) as f64 * 0.01,
                        rng.random_range(-1.0..1.0),
                        rng.random_range(0.0..0.2),
                    )
                })
                .collect();
            for trim in [0.0, 0.02, 0.1, 0.3, 0.49] {
                let (lo, hi) = trimmed_extent(&pts, trim).unwrap_or_default();
                let k = (trim * n as f64).floor() as usize;
                for axis in 0..3 {
                    let mut v: Vec<f64> = pts.iter().map(|p| p[axis]).collect();
                    v.sort_by(f64::total_cmp);
                    assert_eq!((lo[axis], hi[axis]), (v[k], v[n - 1 - k]), "n {n} trim {trim} axis {axis}");
                }
            }
        }
    }

    #[test]
    fn main_components_drop_a_separated_minority_cluster() {
        // A 10 x 10 x 5 grid of points 5 mm apart (the object) and a 4 x 4 x 4 cluster 20 cm away.
        let mut pts = Vec::new();
        for i in 0..10 {
            for j in 0..10 {
                for k in 0..5 {
                    pts.push(Point3::new(f64::from(i) * 0.005, f64::from(j) * 0.005, f64::from(k) * 0.005));
                }
            }
        }
        let n_main = pts.len();
        for i in 0..4 {
            for j in 0..4 {
                for k in 0..4 {
                    pts.push(Point3::new(0.2 + f64::from(i) * 0.005, f64::from(j) * 0.005, f64::from(k) * 0.005));
                }
            }
        }
        pts.push(Point3::new(f64::NAN, 0.0, 0.0));
        let keep = main_components(&pts, 0.01, 2, 0.5);
        assert_eq!(keep.len(), pts.len());
        assert!(keep[..n_main].iter().all(|k| *k));
        assert!(keep[n_main..].iter().all(|k| !*k));
        // A gap of 2 cm is bridged (reach 2 cells of 1 cm): one body, all kept.
        let bridged: Vec<Point3<f64>> =
            pts[..n_main].iter().copied().chain([Point3::new(0.065, 0.0, 0.0), Point3::new(0.07, 0.0, 0.0)]).collect();
        assert!(main_components(&bridged, 0.01, 2, 0.5).iter().all(|k| *k));
        // Two comparable halves are both kept at keep_share 0.5.
        let halves: Vec<Point3<f64>> = pts[..n_main]
            .iter()
            .chain(pts[..n_main].iter())
            .enumerate()
            .map(|(i, p)| if i < n_main { *p } else { p + Vector3::new(0.3, 0.0, 0.0) })
            .collect();
        assert!(main_components(&halves, 0.01, 2, 0.5).iter().all(|k| *k));
        assert!(main_components(&[], 0.01, 2, 0.5).is_empty());
    }

    fn cuboid(c: [f64; 3], yaw: f64, h: [f64; 3]) -> ObjectGeometry {
        ObjectGeometry { shape: Shape::Cuboid, center: Vector3::from(c), yaw_rad: yaw, half_extents: Vector3::from(h) }
    }

    fn cylinder(c: [f64; 3], r: f64, hz: f64) -> ObjectGeometry {
        ObjectGeometry {
            shape: Shape::Cylinder,
            center: Vector3::from(c),
            yaw_rad: 0.0,
            half_extents: Vector3::new(r, r, hz),
        }
    }

    #[test]
    fn iou_of_identical_boxes_is_one() {
        let a = cuboid([0.1, 0.2, 0.05], 0.3, [0.05, 0.02, 0.05]);
        assert!((iou3d(&a, &a) - 1.0).abs() < 1e-12);
        assert!((iou_top(&a, &a) - 1.0).abs() < 1e-12);
    }

    #[test]
    fn iou_of_half_shifted_unit_cubes_is_one_third() {
        // Two 1x1x1 cubes shifted by 0.5 along x: intersection 0.5, union 1.5.
        let a = cuboid([0.0, 0.0, 0.0], 0.0, [0.5, 0.5, 0.5]);
        let b = cuboid([0.5, 0.0, 0.0], 0.0, [0.5, 0.5, 0.5]);
        assert!((iou3d(&a, &b) - 1.0 / 3.0).abs() < 1e-12);
        // Also shifted by 0.5 in z: intersection 0.25, union 1.75.
        let c = cuboid([0.5, 0.0, 0.5], 0.0, [0.5, 0.5, 0.5]);
        assert!((iou3d(&a, &c) - 0.25 / 1.75).abs() < 1e-12);
        assert!((iou_top(&a, &c) - 1.0 / 3.0).abs() < 1e-12);
    }

    #[test]
    fn iou_of_square_rotated_45_degrees_matches_octagon_area() {
        // Unit square vs the same square rotated 45°: the intersection is a regular octagon of
        // area 2(√2 − 1) (side 1 square, inscribed octagon).
        let a = cuboid([0.0, 0.0, 0.0], 0.0, [0.5, 0.5, 0.5]);
        let b = cuboid([0.0, 0.0, 0.0], FRAC_PI_4, [0.5, 0.5, 0.5]);
        let inter = 2.0 * (2f64.sqrt() - 1.0);
        let expected = inter / (2.0 - inter);
        assert!((iou_top(&a, &b) - expected).abs() < 1e-12, "{}", iou_top(&a, &b));
        assert!((iou3d(&a, &b) - expected).abs() < 1e-12);
    }

    #[test]
    fn disjoint_boxes_have_zero_iou() {
        let a = cuboid([0.0, 0.0, 0.0], 0.2, [0.1, 0.1, 0.1]);
        let b = cuboid([1.0, 0.0, 0.0], 0.2, [0.1, 0.1, 0.1]);
        assert_eq!(iou3d(&a, &b), 0.0);
        let c = cuboid([0.0, 0.0, 1.0], 0.2, [0.1, 0.1, 0.1]);
        assert_eq!(iou3d(&a, &c), 0.0);
        assert!(iou_top(&a, &c) > 0.999);
    }

    #[test]
    fn cylinder_iou_matches_lens_formula() {
        // Equal circles r = 1, d = 1: lens area 2π/3 − √3/2.
        let lens = 2.0 * PI / 3.0 - 3f64.sqrt() / 2.0;
        assert!((circle_intersection_area(1.0, 1.0, 1.0) - lens).abs() < 1e-12);
        let a = cylinder([0.0, 0.0, 0.0], 1.0, 1.0);
        let b = cylinder([1.0, 0.0, 0.0], 1.0, 1.0);
        assert!((iou_top(&a, &b) - lens / (2.0 * PI - lens)).abs() < 1e-12);
        // Concentric, radii 1 and 0.5, same height: 0.25.
        let c = cylinder([0.0, 0.0, 0.0], 0.5, 1.0);
        assert!((iou3d(&a, &c) - 0.25).abs() < 1e-12);
    }

    #[test]
    fn yaw_error_respects_symmetry() {
        let t = cuboid([0.0; 3], 0.1, [0.1, 0.05, 0.05]);
        let e = cuboid([0.0; 3], 0.1 + PI, [0.1, 0.05, 0.05]);
        assert!(yaw_error_deg(&e, &t, 0.05).unwrap_or(f64::NAN) < 1e-9);
        let e90 = cuboid([0.0; 3], 0.1 + FRAC_PI_2, [0.1, 0.05, 0.05]);
        assert!((yaw_error_deg(&e90, &t, 0.05).unwrap_or(f64::NAN) - 90.0).abs() < 1e-9);
        let sq = cuboid([0.0; 3], 0.1, [0.05, 0.05, 0.05]);
        assert!(yaw_error_deg(&e90, &sq, 0.05).unwrap_or(f64::NAN) < 1e-9);
        let e10 = cuboid([0.0; 3], 0.1 - 10f64.to_radians(), [0.1, 0.05, 0.05]);
        assert!((yaw_error_deg(&e10, &t, 0.05).unwrap_or(f64::NAN) - 10.0).abs() < 1e-9);
        assert!(yaw_error_deg(&e10, &cylinder([0.0; 3], 0.1, 0.1), 0.05).is_none());
        // The same box described with swapped sides and yaw + 90° has no yaw error.
        let swapped = cuboid([0.0; 3], 0.1 + FRAC_PI_2, [0.05, 0.1, 0.05]);
        assert!(yaw_error_deg(&swapped, &t, 0.05).unwrap_or(f64::NAN) < 1e-9);
        assert!(yaw_error_deg(&t, &swapped, 0.05).unwrap_or(f64::NAN) < 1e-9);
    }

    #[test]
    fn projection_round_trips() {
        let cam = PinholeCamera::from_fovy(640, 480, 1.0).unwrap();
        let p = Point3::new(0.1, -0.05, 0.7);
        let uv = cam.project(&p).unwrap_or([f64::NAN; 2]);
        let q = cam.unproject(uv[0], uv[1], 0.7);
        assert!((p - q).norm() < 1e-12);
        assert!(cam.project(&Point3::new(0.0, 0.0, -1.0)).is_none());
        // fovy: a point at the top edge of the view projects to v = 0.
        let top = Point3::new(0.0, -(0.5f64).tan(), 1.0);
        assert!(cam.project(&top).map_or(f64::NAN, |uv| uv[1]).abs() < 1e-9);
    }

    #[test]
    fn rigid_check_rejects_scaled_and_accepts_rotation() {
        let t = se3_from_yaw(Vector3::new(1.0, 2.0, 3.0), 0.7);
        let m = t.to_homogeneous();
        let back = se3_from_matrix(&m, "world_from_camera").unwrap();
        assert!((back.to_homogeneous() - m).abs().max() < 1e-12);
        assert!((yaw_of(&back) - 0.7).abs() < 1e-12);
        let mut s = m;
        s[(0, 0)] *= 1.1;
        assert!(matches!(se3_from_matrix(&s, "p"), Err(GeometryError::NotRigid { field: "p", .. })));
        let mut n = m;
        n[(1, 3)] = f64::NAN;
        assert!(matches!(se3_from_matrix(&n, "p"), Err(GeometryError::NonFinite { .. })));
        let mirror = Matrix4::from_diagonal(&nalgebra::Vector4::new(1.0, 1.0, -1.0, 1.0));
        assert!(se3_from_matrix(&mirror, "p").is_err());
    }

    #[test]
    fn box2_iou() {
        let a = Box2::new(0.0, 0.0, 10.0, 10.0);
        let b = Box2::new(5.0, 0.0, 15.0, 10.0);
        assert!((a.iou(&b) - 50.0 / 150.0).abs() < 1e-12);
        assert_eq!(a.iou(&Box2::new(20.0, 20.0, 30.0, 30.0)), 0.0);
        assert_eq!(Box2::new(1.0, 1.0, 1.0, 1.0).iou(&Box2::new(1.0, 1.0, 1.0, 1.0)), 0.0);
    }

    #[test]
    fn wrap_angle_range() {
        for a in [-7.0, -PI, -1.0, 0.0, 1.0, PI, 7.0, 100.0] {
            let w = wrap_angle(a);
            assert!(w > -PI - 1e-12 && w <= PI + 1e-12);
            assert!(((a - w) / std::f64::consts::TAU - ((a - w) / std::f64::consts::TAU).round()).abs() < 1e-9);
        }
    }
}
