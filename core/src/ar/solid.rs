//! Solids for ray casting: a shape in its own frame, its pose, and exact ray intersections
//! (slabs for boxes, quadratic for cylinders and spheres, Möller–Trumbore for meshes).

use nalgebra::{Point3, Vector3};

use super::{RealObject, RegisteredModel, TableTop, VirtualShape};
use crate::geometry::{Se3, Shape};

/// The local geometry of a solid.
#[derive(Debug, Clone)]
pub(crate) enum Local {
    Cuboid(Vector3<f64>),
    /// Radius, half-height (axis z).
    Cylinder(f64, f64),
    Ball(f64),
    Mesh {
        vertices: Vec<Point3<f64>>,
        triangles: Vec<[u32; 3]>,
    },
}

/// A solid in the world.
#[derive(Debug, Clone)]
pub(crate) struct Solid {
    pub local: Local,
    pub world_from_local: Se3,
    pub local_from_world: Se3,
}

impl Solid {
    pub fn new(local: Local, world_from_local: Se3) -> Self {
        Self { local, local_from_world: world_from_local.inverse(), world_from_local }
    }

    pub fn of_real(o: &RealObject) -> Self {
        let g = &o.geometry;
        let local = match g.shape {
            Shape::Cuboid => Local::Cuboid(g.half_extents),
            Shape::Cylinder => Local::Cylinder(g.radius(), g.half_extents.z),
        };
        Self::new(local, g.world_from_object())
    }

    pub fn of_model(m: &RegisteredModel) -> Self {
        let local = match &m.shape {
            VirtualShape::Cuboid { half_extents_m } => Local::Cuboid(Vector3::from(*half_extents_m)),
            VirtualShape::Cylinder { radius_m, half_height_m } => Local::Cylinder(*radius_m, *half_height_m),
            VirtualShape::Ball { radius_m } => Local::Ball(*radius_m),
            VirtualShape::Mesh { vertices_m, triangles } => Local::Mesh {
                vertices: vertices_m.iter().map(|v| Point3::new(v[0], v[1], v[2])).collect(),
                triangles: triangles.clone(),
            },
            // Registration resolves `Fit`; an unresolved one has no extent.
            VirtualShape::Fit => Local::Ball(0.0),
        };
        Self::new(local, m.world_from_model)
    }

    /// The table's top face as a thin box (its top face at `height_m`).
    pub fn of_table(t: &TableTop) -> Self {
        let half = Vector3::new(t.size_xy_m[0] / 2.0, t.size_xy_m[1] / 2.0, t.thickness_m / 2.0);
        let c = Vector3::new(t.center_xy_m[0], t.center_xy_m[1], t.height_m - half.z);
        Self::new(Local::Cuboid(half), Se3::translation(c.x, c.y, c.z))
    }

    /// Corners of the local bounding box.
    pub fn local_aabb(&self) -> (Vector3<f64>, Vector3<f64>) {
        match &self.local {
            Local::Cuboid(h) => (-h, *h),
            Local::Cylinder(r, hz) => (Vector3::new(-r, -r, -hz), Vector3::new(*r, *r, *hz)),
            Local::Ball(r) => (Vector3::repeat(-r), Vector3::repeat(*r)),
            Local::Mesh { vertices, .. } => {
                let mut lo = Vector3::repeat(f64::INFINITY);
                let mut hi = Vector3::repeat(f64::NEG_INFINITY);
                for v in vertices {
                    lo = lo.inf(&v.coords);
                    hi = hi.sup(&v.coords);
                }
                (lo, hi)
            }
        }
    }

    /// Smallest `t > t_min` with `origin + t·dir` on the solid's surface (`dir` need not be unit).
    /// A ray starting inside the solid hits its exit.
    pub fn hit_local(&self, o: &Vector3<f64>, d: &Vector3<f64>, t_min: f64) -> Option<f64> {
        match &self.local {
            Local::Cuboid(h) => hit_box(o, d, h, t_min),
            Local::Cylinder(r, hz) => hit_cylinder(o, d, *r, *hz, t_min),
            Local::Ball(r) => hit_ball(o, d, *r, t_min),
            Local::Mesh { vertices, triangles } => {
                let mut best: Option<f64> = None;
                for tri in triangles {
                    let [a, b, c] = tri.map(|k| vertices[k as usize].coords);
                    if let Some(t) = hit_triangle(o, d, &a, &b, &c, t_min) {
                        if best.is_none_or(|x| t < x) {
                            best = Some(t);
                        }
                    }
                }
                best
            }
        }
    }

    /// World-frame ray; `t` in units of `dir`.
    pub fn hit_world(&self, origin: &Point3<f64>, dir: &Vector3<f64>, t_min: f64) -> Option<f64> {
        let o = (self.local_from_world * origin).coords;
        let d = self.local_from_world.rotation * dir;
        self.hit_local(&o, &d, t_min)
    }
}

fn hit_box(o: &Vector3<f64>, d: &Vector3<f64>, h: &Vector3<f64>, t_min: f64) -> Option<f64> {
    let mut t0 = f64::NEG_INFINITY;
    let mut t1 = f64::INFINITY;
    for k in 0..3 {
        if d[k].abs() < 1e-300 {
            if o[k].abs() > h[k] {
                return None;
            }
            continue;
        }
        let inv = 1.0 / d[k];
        let (a, b) = ((-h[k] - o[k]) * inv, (h[k] - o[k]) * inv);
        let (a, b) = if a < b { (a, b) } else { (b, a) };
        t0 = t0.max(a);
        t1 = t1.min(b);
        if t0 > t1 {
            return None;
        }
    }
    if t0 > t_min {
        Some(t0)
    } else if t1 > t_min {
        Some(t1)
    } else {
        None
    }
}

fn hit_cylinder(o: &Vector3<f64>, d: &Vector3<f64>, r: f64, hz: f64, t_min: f64) -> Option<f64> {
    // Interval of t inside the infinite cylinder, then clip to the slab |z| <= hz.
    let a = d.x * d.x + d.y * d.y;
    let b = o.x * d.x + o.y * d.y;
    let c = o.x * o.x + o.y * o.y - r * r;
    let (mut t0, mut t1) = if a < 1e-300 {
        if c > 0.0 {
            return None;
        }
        (f64::NEG_INFINITY, f64::INFINITY)
    } else {
        let disc = b * b - a * c;
        if disc < 0.0 {
            return None;
        }
        let s = disc.sqrt();
        ((-b - s) / a, (-b + s) / a)
    };
    if d.z.abs() < 1e-300 {
        if o.z.abs() > hz {
            return None;
        }
    } else {
        let (za, zb) = ((-hz - o.z) / d.z, (hz - o.z) / d.z);
        let (za, zb) = if za < zb { (za, zb) } else { (zb, za) };
        t0 = t0.max(za);
        t1 = t1.min(zb);
    }
    if t0 > t1 {
        None
    } else if t0 > t_min {
        Some(t0)
    } else if t1 > t_min {
        Some(t1)
    } else {
        None
    }
}

fn hit_ball(o: &Vector3<f64>, d: &Vector3<f64>, r: f64, t_min: f64) -> Option<f64> {
    let a = d.norm_squared();
    let b = o.dot(d);
    let c = o.norm_squared() - r * r;
    let disc = b * b - a * c;
    if a < 1e-300 || disc < 0.0 {
        return None;
    }
    let s = disc.sqrt();
    let (t0, t1) = ((-b - s) / a, (-b + s) / a);
    if t0 > t_min {
        Some(t0)
    } else if t1 > t_min {
        Some(t1)
    } else {
        None
    }
}

fn hit_triangle(
    o: &Vector3<f64>,
    d: &Vector3<f64>,
    a: &Vector3<f64>,
    b: &Vector3<f64>,
    c: &Vector3<f64>,
    t_min: f64,
) -> Option<f64> {
    let e1 = b - a;
    let e2 = c - a;
    let p = d.cross(&e2);
    let det = e1.dot(&p);
    if det.abs() < 1e-300 {
        return None;
    }
    let inv = 1.0 / det;
    let s = o - a;
    let u = s.dot(&p) * inv;
    if !(0.0..=1.0).contains(&u) {
        return None;
    }
    let q = s.cross(&e1);
    let v = d.dot(&q) * inv;
    if v < 0.0 || u + v > 1.0 {
        return None;
    }
    let t = e2.dot(&q) * inv;
    (t > t_min).then_some(t)
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // tests may unwrap (STYLE.md, 18)
mod tests {
    use super::*;

    #[test]
    fn ray_hits_match_closed_forms() {
        let o = Vector3::new(0.0, 0.0, 1.0);
        let d = Vector3::new(0.0, 0.0, -2.0);
        assert!((hit_box(&o, &d, &Vector3::new(0.1, 0.2, 0.3), 0.0).unwrap() - 0.35).abs() < 1e-12);
        assert!((hit_cylinder(&o, &d, 0.1, 0.3, 0.0).unwrap() - 0.35).abs() < 1e-12);
        assert!((hit_ball(&o, &d, 0.5, 0.0).unwrap() - 0.25).abs() < 1e-12);
        // Side of a cylinder: from x = 1 towards the axis.
        let side = hit_cylinder(&Vector3::new(1.0, 0.0, 0.0), &Vector3::new(-1.0, 0.0, 0.0), 0.1, 0.3, 0.0);
        assert!((side.unwrap() - 0.9).abs() < 1e-12);
        // Miss above the cap, exit from inside.
        assert!(hit_cylinder(&Vector3::new(1.0, 0.0, 0.5), &Vector3::new(-1.0, 0.0, 0.0), 0.1, 0.3, 0.0).is_none());
        assert!((hit_box(&Vector3::zeros(), &Vector3::x(), &Vector3::repeat(0.2), 0.0).unwrap() - 0.2).abs() < 1e-12);
        let (a, b, c) = (Vector3::new(-1.0, -1.0, 0.0), Vector3::new(1.0, -1.0, 0.0), Vector3::new(0.0, 1.0, 0.0));
        assert!((hit_triangle(&o, &d, &a, &b, &c, 0.0).unwrap() - 0.5).abs() < 1e-12);
    }
}
