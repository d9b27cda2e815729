//! Visibility by ray casting, and the per-frame grid update.
//!
//! A cell is *visible* from a camera when (1) its outward normal faces the camera within
//! [`GridConfig::max_incidence_deg`] (this handles self-occlusion of the convex primitive),
//! (2) its centre projects inside the image and lies within [`GridConfig::min_range_m`] …
//! [`GridConfig::max_range_m`], (3) the segment camera → cell centre (stopped
//! [`GridConfig::surface_offset_m`] short) crosses neither the table plane nor any *other* map
//! object's primitive (parry3d-f64 ray casts against cuboids and cylinders built from the
//! estimates; the table top is the plane z = [`GridConfig::table_height_m`], tested analytically),
//! and (4) when a depth image is given, the measured depth at the cell's pixel is not in front of
//! the cell by more than [`GridConfig::depth_tolerance_m`] (an unmodelled occluder) and is not
//! missing. Only visible cells are updated, so "free" always means seen-and-empty.

use nalgebra::{Matrix3, Point3, Vector3};
use parry3d_f64::math::Vector as PVec;
use parry3d_f64::query::{Ray, RayCast};
use parry3d_f64::shape::{Cuboid, Cylinder};

use super::grid::{CellRef, SurfaceGrid};
use super::{ExploreError, GridConfig};
use crate::frame::DepthImage;
use crate::geometry::{PinholeCamera, Se3, Shape};
use crate::map::{MapObject, ObjectMap};

#[derive(Debug, Clone)]
enum OccluderShape {
    Cuboid(Cuboid),
    /// parry's cylinder axis is its local y; object z maps to it (see `to_parry_local`).
    Cylinder(Cylinder),
}

#[derive(Debug, Clone)]
struct Occluder {
    object_id: u32,
    object_from_world: Se3,
    /// `object_from_world` as a rotation matrix and translation (segment tests transform many
    /// points per occluder; a matrix product is cheaper than a quaternion rotation).
    rot_from_world: Matrix3<f64>,
    trans_from_world: Vector3<f64>,
    center_in_world: Point3<f64>,
    bounding_radius_m: f64,
    shape: OccluderShape,
}

/// Whether the segment `o + t·d`, t ∈ [0, `max_t`], meets the solid box |x| ≤ h.x, |y| ≤ h.y,
/// |z| ≤ h.z (slab test).
#[inline]
pub(super) fn segment_hits_box(o: &Vector3<f64>, d: &Vector3<f64>, h: &Vector3<f64>, max_t: f64) -> bool {
    let (mut t0, mut t1) = (0.0f64, max_t);
    for a in 0..3 {
        if d[a].abs() < 1e-15 {
            if o[a].abs() > h[a] {
                return false;
            }
        } else {
            let inv = 1.0 / d[a];
            let (ta, tb) = ((-h[a] - o[a]) * inv, (h[a] - o[a]) * inv);
            t0 = t0.max(ta.min(tb));
            t1 = t1.min(ta.max(tb));
            if t0 > t1 {
                return false;
            }
        }
    }
    true
}

/// Whether the segment `o + t·d`, t ∈ [0, `max_t`], meets the solid cylinder x² + y² ≤ r²,
/// |z| ≤ `half_height` (closed form: the z slab intersected with the quadratic's interval).
#[inline]
pub(super) fn segment_hits_cylinder(o: &Vector3<f64>, d: &Vector3<f64>, r: f64, half_height: f64, max_t: f64) -> bool {
    let (mut t0, mut t1) = (0.0f64, max_t);
    if d.z.abs() < 1e-15 {
        if o.z.abs() > half_height {
            return false;
        }
    } else {
        let inv = 1.0 / d.z;
        let (ta, tb) = ((-half_height - o.z) * inv, (half_height - o.z) * inv);
        t0 = t0.max(ta.min(tb));
        t1 = t1.min(ta.max(tb));
        if t0 > t1 {
            return false;
        }
    }
    let a = d.x * d.x + d.y * d.y;
    let b = o.x * d.x + o.y * d.y;
    let c = o.x * o.x + o.y * o.y - r * r;
    if a < 1e-30 {
        return c <= 0.0;
    }
    let disc = b * b - a * c;
    if disc < 0.0 {
        return false;
    }
    let s = disc.sqrt();
    let (ra, rb) = ((-b - s) / a, (-b + s) / a);
    t0.max(ra) <= t1.min(rb)
}

/// The map's primitives as ray-cast occluders, plus the table plane.
#[derive(Debug, Clone)]
pub struct Occluders {
    items: Vec<Occluder>,
    table_height_m: f64,
}

fn pvec(v: &Vector3<f64>, cylinder: bool) -> PVec {
    if cylinder {
        // Object (x, y, z) → parry cylinder frame (x, z, −y): a proper rotation taking z to y.
        PVec::new(v.x, v.z, -v.y)
    } else {
        PVec::new(v.x, v.y, v.z)
    }
}

impl Occluders {
    /// Occluders for every object of the map (in map order), from their current estimates.
    /// Objects with non-finite poses or sizes are skipped.
    pub fn from_map(map: &ObjectMap, config: &GridConfig) -> Self {
        let items = map.objects.iter().filter_map(occluder_of).collect();
        Self { items, table_height_m: config.table_height_m }
    }

    /// Number of object occluders.
    pub fn len(&self) -> usize {
        self.items.len()
    }

    /// Whether there are no object occluders.
    pub fn is_empty(&self) -> bool {
        self.items.is_empty()
    }

    /// First hit of the ray `origin + t·dir` (`dir` need not be unit; `t` is returned in units of
    /// `dir`) with the table plane or any object, up to `max_t`: `(Some(object_id), t)` for an
    /// object, `(None, t)` for the table. Useful to render synthetic depth and segmentation from
    /// a map (tests, ground-truth oracles).
    pub fn cast_ray(&self, origin: &Point3<f64>, dir: &Vector3<f64>, max_t: f64) -> Option<(Option<u32>, f64)> {
        let mut best: Option<(Option<u32>, f64)> = None;
        if dir.z < 0.0 && origin.z >= self.table_height_m {
            let t = (self.table_height_m - origin.z) / dir.z;
            if t <= max_t {
                best = Some((None, t));
            }
        }
        for o in &self.items {
            let limit = best.map_or(max_t, |b| b.1);
            let p = o.object_from_world * origin;
            let d = o.object_from_world.rotation * dir;
            let toi = match &o.shape {
                OccluderShape::Cuboid(c) => {
                    c.cast_local_ray(&Ray::new(pvec(&p.coords, false), pvec(&d, false)), limit, true)
                }
                OccluderShape::Cylinder(c) => {
                    c.cast_local_ray(&Ray::new(pvec(&p.coords, true), pvec(&d, true)), limit, true)
                }
            };
            if let Some(t) = toi {
                if best.is_none_or(|b| t < b.1) {
                    best = Some((Some(o.object_id), t));
                }
            }
        }
        best
    }

    /// Whether the open segment `from → to` is blocked by the table plane or by any object other
    /// than `ignore_id`.
    pub fn segment_blocked(&self, from: &Point3<f64>, to: &Point3<f64>, ignore_id: Option<u32>) -> bool {
        self.segment_blocked_among(from, to, self.items.iter().filter(|o| Some(o.object_id) != ignore_id))
    }

    /// Indices of the occluders (other than `ignore_id`) that can block some segment from `from` to
    /// a point within `radius_m` of `center`: those whose bounding sphere comes within `radius_m`
    /// of the segment `from → center` (every such segment stays within `radius_m` of it). A
    /// superset of the occluders [`Self::segment_blocked`] tests exactly, so passing it to
    /// [`Self::segment_blocked_by`] gives the same answers for those segments.
    pub(crate) fn near_segments_to(
        &self,
        from: &Point3<f64>,
        center: &Point3<f64>,
        radius_m: f64,
        ignore_id: Option<u32>,
    ) -> Vec<usize> {
        let d = center - from;
        let len = d.norm();
        let dir = if len > 0.0 { d / len } else { Vector3::zeros() };
        (0..self.items.len())
            .filter(|&i| {
                let o = &self.items[i];
                if Some(o.object_id) == ignore_id {
                    return false;
                }
                let oc = o.center_in_world - from;
                let t = oc.dot(&dir).clamp(0.0, len);
                let reach = o.bounding_radius_m + radius_m + 1e-9;
                (oc - dir * t).norm_squared() <= reach * reach
            })
            .collect()
    }

    /// [`Self::segment_blocked`] testing only the occluders `among` (indices from
    /// [`Self::near_segments_to`]).
    pub(crate) fn segment_blocked_by(&self, from: &Point3<f64>, to: &Point3<f64>, among: &[usize]) -> bool {
        self.segment_blocked_among(from, to, among.iter().filter_map(|&i| self.items.get(i)))
    }

    fn segment_blocked_among<'a>(
        &'a self,
        from: &Point3<f64>,
        to: &Point3<f64>,
        items: impl Iterator<Item = &'a Occluder>,
    ) -> bool {
        let eps = 1e-6;
        if from.z < self.table_height_m - eps || to.z < self.table_height_m - eps {
            // Both ends above the plane never cross it; an end below it is behind the table.
            return true;
        }
        let d = to - from;
        let len = d.norm();
        if len <= eps {
            return false;
        }
        let dir = d / len;
        for o in items {
            // Bounding-sphere cull: distance from the sphere centre to the segment.
            let oc = o.center_in_world - from;
            let t = oc.dot(&dir).clamp(0.0, len);
            if (oc - dir * t).norm_squared() > o.bounding_radius_m * o.bounding_radius_m {
                continue;
            }
            let origin = o.rot_from_world * from.coords + o.trans_from_world;
            let dir_o = o.rot_from_world * dir;
            let hit = match &o.shape {
                OccluderShape::Cuboid(c) => {
                    let h = c.half_extents;
                    segment_hits_box(&origin, &dir_o, &Vector3::new(h.x, h.y, h.z), len)
                }
                // Object z is the cylinder's axis (parry's local y, see `pvec`).
                OccluderShape::Cylinder(c) => segment_hits_cylinder(&origin, &dir_o, c.radius, c.half_height, len),
            };
            if hit {
                return true;
            }
        }
        false
    }

    /// Whether a point is inside any object primitive inflated by `margin_m` (the test is on the
    /// primitive's own inflated extents) or lower than `margin_m` above the table top.
    pub fn point_inside_any(&self, p: &Point3<f64>, margin_m: f64) -> bool {
        self.point_inside_object(p, margin_m) || p.z < self.table_height_m + margin_m
    }

    /// Whether `p` lies inside any object primitive inflated by `margin_m` (the table not counted).
    pub fn point_inside_object(&self, p: &Point3<f64>, margin_m: f64) -> bool {
        self.items.iter().any(|o| {
            let q = o.object_from_world * p;
            match &o.shape {
                OccluderShape::Cuboid(c) => {
                    let h = c.half_extents;
                    q.x.abs() <= h.x + margin_m && q.y.abs() <= h.y + margin_m && q.z.abs() <= h.z + margin_m
                }
                OccluderShape::Cylinder(c) => {
                    (q.x * q.x + q.y * q.y).sqrt() <= c.radius + margin_m && q.z.abs() <= c.half_height + margin_m
                }
            }
        })
    }
}

fn occluder_of(o: &MapObject) -> Option<Occluder> {
    let h = o.half_extents;
    let t = o.world_from_object.translation.vector;
    if h.iter().chain(t.iter()).any(|v| !v.is_finite()) || h.iter().any(|v| *v <= 0.0) {
        return None;
    }
    let shape = match o.label.shape() {
        Shape::Cuboid => OccluderShape::Cuboid(Cuboid::new(PVec::new(h.x, h.y, h.z))),
        Shape::Cylinder => OccluderShape::Cylinder(Cylinder::new(h.z, (h.x + h.y) / 2.0)),
    };
    let object_from_world = o.world_from_object.inverse();
    Some(Occluder {
        object_id: o.id,
        object_from_world,
        rot_from_world: object_from_world.rotation.to_rotation_matrix().into_inner(),
        trans_from_world: object_from_world.translation.vector,
        center_in_world: Point3::from(t),
        bounding_radius_m: h.norm(),
        shape,
    })
}

/// Why a cell was or was not seen (for tests and diagnostics).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CellVisibility {
    /// Seen: its pixel (u, v) and its depth along the optical axis.
    Visible {
        /// Pixel column.
        u: u32,
        /// Pixel row.
        v: u32,
    },
    /// Faces away from the camera (or beyond the incidence limit).
    BackFacing,
    /// Outside the image or the range limits.
    OutOfView,
    /// The segment to the camera crosses the table or another object.
    Occluded,
}

/// A camera with its pose (both directions precomputed).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Viewpoint {
    /// Intrinsics.
    pub camera: PinholeCamera,
    /// Pose, OpenCV camera axes.
    pub world_from_camera: Se3,
    /// Inverse of `world_from_camera`.
    pub camera_from_world: Se3,
    /// Camera centre, world frame.
    pub eye_in_world: Point3<f64>,
}

impl Viewpoint {
    /// A viewpoint from intrinsics and pose.
    pub fn new(camera: &PinholeCamera, world_from_camera: &Se3) -> Self {
        Self {
            camera: *camera,
            world_from_camera: *world_from_camera,
            camera_from_world: world_from_camera.inverse(),
            eye_in_world: Point3::from(world_from_camera.translation.vector),
        }
    }
}

/// Geometric visibility of a surface point (world frame) with outward normal `n_in_world` from a
/// viewpoint; `object_id` is excluded from the occluders (its own convexity is handled by the
/// normal test). No depth test here.
pub fn point_visibility(
    p_in_world: &Point3<f64>,
    n_in_world: &Vector3<f64>,
    object_id: u32,
    view: &Viewpoint,
    occluders: &Occluders,
    config: &GridConfig,
) -> CellVisibility {
    let cos_max = config.max_incidence_deg.to_radians().cos();
    point_visibility_cos(p_in_world, n_in_world, object_id, view, occluders, config, cos_max, None)
}

/// [`point_visibility`] with `cos_max` = cos([`GridConfig::max_incidence_deg`]) given (hoisted out
/// of per-cell loops) and, optionally, the occluders that can block the point
/// ([`Occluders::near_segments_to`] from the eye, with `object_id` ignored).
#[allow(clippy::too_many_arguments)]
pub(crate) fn point_visibility_cos(
    p_in_world: &Point3<f64>,
    n_in_world: &Vector3<f64>,
    object_id: u32,
    view: &Viewpoint,
    occluders: &Occluders,
    config: &GridConfig,
    cos_max: f64,
    among: Option<&[usize]>,
) -> CellVisibility {
    let (camera, camera_from_world, eye) = (&view.camera, &view.camera_from_world, view.eye_in_world);
    let to_eye = eye - p_in_world;
    let dist = to_eye.norm();
    if dist.is_nan() || dist <= 0.0 || n_in_world.dot(&to_eye) < dist * cos_max {
        return CellVisibility::BackFacing;
    }
    let p_c = camera_from_world * p_in_world;
    if p_c.z < config.min_range_m || dist > config.max_range_m {
        return CellVisibility::OutOfView;
    }
    let Some(uv) = camera.project(&p_c) else {
        return CellVisibility::OutOfView;
    };
    if !camera.contains(uv) {
        return CellVisibility::OutOfView;
    }
    let start = p_in_world + n_in_world * config.surface_offset_m;
    let blocked = match among {
        Some(idx) => occluders.segment_blocked_by(&eye, &start, idx),
        None => occluders.segment_blocked(&eye, &start, Some(object_id)),
    };
    if blocked {
        return CellVisibility::Occluded;
    }
    CellVisibility::Visible { u: uv[0] as u32, v: uv[1] as u32 }
}

/// One object's points seen in one frame (world frame), as segmented by the pipeline.
#[derive(Debug, Clone, PartialEq)]
pub struct ObservedPoints {
    /// Map object id the points were associated with.
    pub object_id: u32,
    /// The points, world frame, metres.
    pub points_in_world: Vec<Point3<f64>>,
}

/// What one frame did to one object's grid.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct ObjectFrameUpdate {
    /// Object id.
    pub object_id: u32,
    /// Cells updated as hits (occupied evidence).
    pub hits: usize,
    /// Cells updated as misses (free evidence).
    pub misses: usize,
    /// Visible cells left untouched because the depth was missing or in front (occluded).
    pub depth_rejected: usize,
    /// Observed points dropped (farther than `max_point_distance_m` from the surface, on the
    /// bottom, or non-finite).
    pub points_dropped: usize,
}

/// Update one object's grid from one frame. Hits: cells containing at least one of this frame's
/// points of the object (one update per cell per frame, however many points fall in it), and —
/// with a depth image and [`GridConfig::depth_confirms_hit`] — visible cells whose measured depth
/// matches the cell's depth. Misses: visible cells without a hit whose measured depth lies behind
/// the cell (or any visible cell without a hit when no depth is given).
#[allow(clippy::too_many_arguments)]
pub fn integrate_object(
    grid: &mut SurfaceGrid,
    object: &MapObject,
    points_in_world: &[Point3<f64>],
    camera: &PinholeCamera,
    world_from_camera: &Se3,
    depth: Option<&DepthImage>,
    occluders: &Occluders,
    config: &GridConfig,
) -> ObjectFrameUpdate {
    let mut out = ObjectFrameUpdate { object_id: object.id, ..Default::default() };
    let object_from_world = object.world_from_object.inverse();
    let view = Viewpoint::new(camera, world_from_camera);
    let camera_from_world = view.camera_from_world;
    let mut hit_cells: Vec<CellRef> = Vec::new();
    for p in points_in_world {
        if !p.coords.iter().all(|v| v.is_finite()) {
            out.points_dropped += 1;
            continue;
        }
        match grid.cell_of_point(&(object_from_world * p), config.max_point_distance_m) {
            Some(c) => hit_cells.push(c),
            None => out.points_dropped += 1,
        }
    }
    hit_cells.sort_unstable();
    hit_cells.dedup();
    for c in &hit_cells {
        grid.update_cell(*c, true, config);
    }
    out.hits = hit_cells.len();
    let cells: Vec<CellRef> = grid.cells().collect();
    let cos_max = config.max_incidence_deg.to_radians().cos();
    for c in cells {
        if hit_cells.binary_search(&c).is_ok() {
            continue;
        }
        let Some(pose) = grid.cell_pose(c) else {
            continue;
        };
        let p_w = object.world_from_object * pose.p_in_object;
        let n_w = object.world_from_object.rotation * pose.normal_in_object;
        let vis = point_visibility_cos(&p_w, &n_w, object.id, &view, occluders, config, cos_max, None);
        let CellVisibility::Visible { u, v } = vis else {
            continue;
        };
        let hit = match depth {
            None => false,
            Some(d) => {
                let Some(measured) = d.at(u, v) else {
                    out.depth_rejected += 1;
                    continue;
                };
                let predicted = (camera_from_world * p_w).z;
                let diff = f64::from(measured) - predicted;
                if diff < -config.depth_tolerance_m {
                    out.depth_rejected += 1;
                    continue;
                }
                diff <= config.depth_tolerance_m && config.depth_confirms_hit
            }
        };
        grid.update_cell(c, hit, config);
        if hit {
            out.hits += 1;
        } else {
            out.misses += 1;
        }
    }
    out
}

/// Check a camera pose is finite.
pub(crate) fn check_pose(t: &Se3, field: &'static str) -> Result<(), ExploreError> {
    if t.translation.vector.iter().chain(t.rotation.coords.iter()).all(|v| v.is_finite()) {
        Ok(())
    } else {
        Err(ExploreError::NonFinite { field })
    }
}
