//! Five-face surface occupancy grids (paper, "Observation Completeness Measurement").
//!
//! One [`SurfaceGrid`] per map object. Cells live in *object-normalised face coordinates*: each
//! face is a `cols × rows` raster over `(u, v) ∈ [0, 1]²` of that face, and the face itself is
//! defined in the object frame by the object's half-extents. A change of the object's pose moves
//! the grid with it for free (nothing is stored in the world frame); a change of its size
//! resamples every face by nearest neighbour in `(u, v)` ([`SurfaceGrid::sync`]).

use nalgebra::{Point3, Vector3};

use super::{ExploreError, GridConfig};
use crate::geometry::Shape;
use crate::map::MapObject;

/// The five faces that carry a grid (the bottom face, on the table, has none).
///
/// For a cuboid these are the faces whose outward normals are the object's +x, −x, +y, −y and
/// +z axes. For a cylinder the lateral surface is cut into four quarter arcs centred on the same
/// directions (e.g. [`Face::PosX`] covers azimuths −45°…45° about the object's z axis), each
/// unrolled to a raster over (arc length, height); [`Face::Top`] is the cap, rasterised over its
/// bounding square with cells outside the disc masked out (not counted anywhere).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Face {
    /// Outward normal +x (object frame).
    PosX,
    /// Outward normal −x.
    NegX,
    /// Outward normal +y.
    PosY,
    /// Outward normal −y.
    NegY,
    /// Outward normal +z (the top).
    Top,
}

impl Face {
    /// The five faces, in grid storage order.
    pub const ALL: [Face; 5] = [Face::PosX, Face::NegX, Face::PosY, Face::NegY, Face::Top];

    /// Azimuth (rad, about object z) of a lateral face's centre; `None` for the top.
    fn azimuth_rad(self) -> Option<f64> {
        use std::f64::consts::{FRAC_PI_2, PI};
        match self {
            Face::PosX => Some(0.0),
            Face::PosY => Some(FRAC_PI_2),
            Face::NegX => Some(PI),
            Face::NegY => Some(-FRAC_PI_2),
            Face::Top => None,
        }
    }
}

/// The state of one cell (paper: unknown / occupied / free).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CellState {
    /// Never observed.
    Unknown,
    /// Observed, occupancy probability > 0.5.
    Occupied,
    /// Observed, occupancy probability ≤ 0.5.
    Free,
}

/// Binary entropy in bits, `H(p) = −p log₂ p − (1 − p) log₂ (1 − p)` (paper Eq. `eq:grid`);
/// 0 at p ∈ {0, 1}, 1 at p = 0.5.
pub fn binary_entropy_bits(p: f64) -> f64 {
    plogp_bits(p) + plogp_bits(1.0 - p)
}

/// `−p log₂ p` (paper Eq. `eq:plogp`); 0 for p ≤ 0 and for non-finite p.
pub fn plogp_bits(p: f64) -> f64 {
    if !(p.is_finite() && p > 0.0) {
        return 0.0;
    }
    -p * p.log2()
}

/// Logistic function: occupancy probability from log-odds.
pub fn probability_from_log_odds(l: f64) -> f64 {
    1.0 / (1.0 + (-l).exp())
}

/// Log-odds from a probability.
pub fn log_odds(p: f64) -> f64 {
    (p / (1.0 - p)).ln()
}

/// One face's raster. Row-major: `index = row * cols + col`; `col` runs along `u`, `row` along `v`.
#[derive(Debug, Clone, PartialEq)]
pub struct FaceGrid {
    /// Which face.
    pub face: Face,
    /// Cells along `u`.
    pub cols: usize,
    /// Cells along `v`.
    pub rows: usize,
    /// Log-odds of occupancy per cell (0 = p₀ = 0.5).
    pub log_odds: Vec<f32>,
    /// Number of updates each cell received (0 = unknown).
    pub updates: Vec<u32>,
    /// Whether the cell is part of the surface (false only outside a cylinder's top disc).
    pub valid: Vec<bool>,
}

impl FaceGrid {
    /// State of cell `i` (`None` when masked out or out of range).
    pub fn state(&self, i: usize) -> Option<CellState> {
        if !*self.valid.get(i)? {
            return None;
        }
        let n = *self.updates.get(i)?;
        let l = *self.log_odds.get(i)?;
        Some(if n == 0 {
            CellState::Unknown
        } else if l > 0.0 {
            CellState::Occupied
        } else {
            CellState::Free
        })
    }

    /// Occupancy probability of cell `i`.
    pub fn probability(&self, i: usize) -> f64 {
        self.log_odds.get(i).map_or(0.5, |l| probability_from_log_odds(f64::from(*l)))
    }

    /// Number of cells (including masked ones).
    pub fn len(&self) -> usize {
        self.cols * self.rows
    }

    /// Whether the raster is empty (never, for a valid grid).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// Counts and entropies of one object's grid (the paper's |O|, |F|, |U|, H_obj, H̄_obj, R_o).
#[derive(Debug, Clone, Copy, PartialEq, Default, serde::Serialize)]
pub struct GridStats {
    /// Occupied cells |O|.
    pub occupied: usize,
    /// Free cells |F|.
    pub free: usize,
    /// Unknown cells |U|.
    pub unknown: usize,
    /// H_obj = Σ H(p) over all cells, bits (Eq. `eq:obj`).
    pub entropy_bits: f64,
}

impl GridStats {
    /// Number of cells |O| + |F| + |U|.
    pub fn cells(&self) -> usize {
        self.occupied + self.free + self.unknown
    }

    /// Normalised entropy H̄_obj = H_obj / (|O| + |F| + |U|) in [0, 1] bits (Eq. `eq:ba_grid`);
    /// 1 (maximal) for a grid without cells.
    pub fn normalized_entropy(&self) -> f64 {
        let n = self.cells();
        if n == 0 {
            1.0
        } else {
            self.entropy_bits / n as f64
        }
    }

    /// R_o = |O| / (|O| + |F| + |U|): the ratio of occupied cells (0 without cells).
    pub fn occupied_ratio(&self) -> f64 {
        let n = self.cells();
        if n == 0 {
            0.0
        } else {
            self.occupied as f64 / n as f64
        }
    }

    /// Ratio of observed (occupied or free) cells.
    pub fn observed_ratio(&self) -> f64 {
        let n = self.cells();
        if n == 0 {
            0.0
        } else {
            (self.occupied + self.free) as f64 / n as f64
        }
    }
}

/// A cell's location: face index (into [`Face::ALL`]) and cell index within that face.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct CellRef {
    /// Index into [`SurfaceGrid::faces`].
    pub face: usize,
    /// Row-major cell index within the face.
    pub cell: usize,
}

/// A cell's centre and outward unit normal, object frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CellPose {
    /// Centre of the cell on the surface, object frame, metres.
    pub p_in_object: Point3<f64>,
    /// Outward unit normal, object frame.
    pub normal_in_object: Vector3<f64>,
}

/// One cell in the world frame (see [`SurfaceGrid::cells_in_world`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WorldCell {
    /// Which cell.
    pub cell: CellRef,
    /// Cell centre, world frame, metres.
    pub p_in_world: Point3<f64>,
    /// Outward unit normal, world frame.
    pub normal_in_world: Vector3<f64>,
    /// Unknown / occupied / free.
    pub state: CellState,
    /// Occupancy probability.
    pub probability: f64,
}

/// The surface occupancy grid of one map object.
#[derive(Debug, Clone, PartialEq)]
pub struct SurfaceGrid {
    /// Map object id.
    pub object_id: u32,
    /// Primitive the faces are laid on.
    pub shape: Shape,
    /// Half-extents (object frame, metres) the faces were built for.
    pub half_extents: Vector3<f64>,
    /// Cell size the rasters were built for, metres.
    pub cell_size_m: f64,
    /// The five faces, in [`Face::ALL`] order.
    pub faces: Vec<FaceGrid>,
}

/// Half-extents below this (metres) are raised to it so a degenerate estimate still has cells.
const MIN_HALF_EXTENT_M: f64 = 1e-3;
/// Upper bound on cells per face side, protecting against absurd estimates (3 m at 1 cm; larger
/// faces get coarser cells).
const MAX_CELLS_PER_SIDE: usize = 300;

fn sanitize_half_extents(h: &Vector3<f64>) -> Result<Vector3<f64>, ExploreError> {
    if h.iter().any(|v| !v.is_finite()) {
        return Err(ExploreError::NonFinite { field: "half_extents" });
    }
    Ok(h.map(|v| v.max(MIN_HALF_EXTENT_M)))
}

fn cylinder_radius(h: &Vector3<f64>) -> f64 {
    (h.x + h.y) / 2.0
}

/// Side lengths (u, v) of a face in metres.
fn face_size_m(shape: Shape, h: &Vector3<f64>, face: Face) -> (f64, f64) {
    match shape {
        Shape::Cuboid => match face {
            Face::PosX | Face::NegX => (2.0 * h.y, 2.0 * h.z),
            Face::PosY | Face::NegY => (2.0 * h.x, 2.0 * h.z),
            Face::Top => (2.0 * h.x, 2.0 * h.y),
        },
        Shape::Cylinder => {
            let r = cylinder_radius(h);
            match face {
                Face::Top => (2.0 * r, 2.0 * r),
                _ => (r * std::f64::consts::FRAC_PI_2, 2.0 * h.z),
            }
        }
    }
}

fn cells_along(len_m: f64, cell_m: f64) -> usize {
    // The small tolerance keeps 0.1 m / 0.01 m = 10.000000000000002 at 10 cells.
    ((len_m / cell_m - 1e-9).ceil() as usize).clamp(1, MAX_CELLS_PER_SIDE)
}

/// Centre and normal at normalised face coordinates `(u, v) ∈ [0, 1]²`, object frame.
fn surface_point(shape: Shape, h: &Vector3<f64>, face: Face, u: f64, v: f64) -> CellPose {
    let z = -h.z + v * 2.0 * h.z;
    match shape {
        Shape::Cuboid => {
            let (p, n) = match face {
                // u runs along +y on ±x faces, along +x on ±y faces and the top; v along +z
                // (on the top, v runs along +y).
                Face::PosX => (Point3::new(h.x, -h.y + u * 2.0 * h.y, z), Vector3::x()),
                Face::NegX => (Point3::new(-h.x, -h.y + u * 2.0 * h.y, z), -Vector3::x()),
                Face::PosY => (Point3::new(-h.x + u * 2.0 * h.x, h.y, z), Vector3::y()),
                Face::NegY => (Point3::new(-h.x + u * 2.0 * h.x, -h.y, z), -Vector3::y()),
                Face::Top => (Point3::new(-h.x + u * 2.0 * h.x, -h.y + v * 2.0 * h.y, h.z), Vector3::z()),
            };
            CellPose { p_in_object: p, normal_in_object: n }
        }
        Shape::Cylinder => {
            let r = cylinder_radius(h);
            match face.azimuth_rad() {
                Some(az0) => {
                    // u ∈ [0, 1] spans azimuths az0 − 45° … az0 + 45° counter-clockwise.
                    let az = az0 - std::f64::consts::FRAC_PI_4 + u * std::f64::consts::FRAC_PI_2;
                    let (s, c) = az.sin_cos();
                    CellPose { p_in_object: Point3::new(r * c, r * s, z), normal_in_object: Vector3::new(c, s, 0.0) }
                }
                None => CellPose {
                    p_in_object: Point3::new(-r + u * 2.0 * r, -r + v * 2.0 * r, h.z),
                    normal_in_object: Vector3::z(),
                },
            }
        }
    }
}

/// Where a point (object frame) lands on the surface: face, normalised (u, v) and its distance to
/// the surface (metres). `None` when the nearest surface is the bottom.
fn locate(shape: Shape, h: &Vector3<f64>, p: &Point3<f64>) -> Option<(Face, f64, f64, f64)> {
    let v = ((p.z + h.z) / (2.0 * h.z)).clamp(0.0, 1.0);
    match shape {
        Shape::Cuboid => {
            let candidates = [
                ((p.x - h.x).abs(), Some(Face::PosX)),
                ((p.x + h.x).abs(), Some(Face::NegX)),
                ((p.y - h.y).abs(), Some(Face::PosY)),
                ((p.y + h.y).abs(), Some(Face::NegY)),
                ((p.z - h.z).abs(), Some(Face::Top)),
                ((p.z + h.z).abs(), None),
            ];
            let (d, face) =
                candidates.iter().copied().fold((f64::INFINITY, None), |best, c| if c.0 < best.0 { c } else { best });
            let face = face?;
            let ux = ((p.x + h.x) / (2.0 * h.x)).clamp(0.0, 1.0);
            let uy = ((p.y + h.y) / (2.0 * h.y)).clamp(0.0, 1.0);
            Some(match face {
                Face::PosX | Face::NegX => (face, uy, v, d),
                Face::PosY | Face::NegY => (face, ux, v, d),
                Face::Top => (face, ux, uy, d),
            })
        }
        Shape::Cylinder => {
            let r = cylinder_radius(h);
            let rho = (p.x * p.x + p.y * p.y).sqrt();
            let d_lat = (rho - r).abs();
            let d_top = (p.z - h.z).abs();
            let d_bottom = (p.z + h.z).abs();
            if d_bottom < d_lat && d_bottom < d_top {
                return None;
            }
            if d_top <= d_lat {
                let u = ((p.x + r) / (2.0 * r)).clamp(0.0, 1.0);
                let w = ((p.y + r) / (2.0 * r)).clamp(0.0, 1.0);
                return Some((Face::Top, u, w, d_top));
            }
            let az = p.y.atan2(p.x);
            // Quarter arcs centred on 0, 90°, 180°, −90°.
            let q = (az / std::f64::consts::FRAC_PI_2).round();
            let face = match q as i64 {
                0 => Face::PosX,
                1 => Face::PosY,
                -1 => Face::NegY,
                _ => Face::NegX,
            };
            let az0 = face.azimuth_rad().unwrap_or(0.0);
            let rel = crate::geometry::wrap_angle(az - az0);
            let u = ((rel + std::f64::consts::FRAC_PI_4) / std::f64::consts::FRAC_PI_2).clamp(0.0, 1.0);
            Some((face, u, v, d_lat))
        }
    }
}

fn cell_index(cols: usize, rows: usize, u: f64, v: f64) -> usize {
    let col = ((u * cols as f64) as usize).min(cols.saturating_sub(1));
    let row = ((v * rows as f64) as usize).min(rows.saturating_sub(1));
    row * cols + col
}

fn build_face(shape: Shape, h: &Vector3<f64>, face: Face, cell_m: f64) -> FaceGrid {
    let (lu, lv) = face_size_m(shape, h, face);
    let (cols, rows) = (cells_along(lu, cell_m), cells_along(lv, cell_m));
    let n = cols * rows;
    let mut valid = vec![true; n];
    if shape == Shape::Cylinder && face == Face::Top {
        let r = cylinder_radius(h);
        for (i, ok) in valid.iter_mut().enumerate() {
            let (col, row) = (i % cols, i / cols);
            let x = -r + (col as f64 + 0.5) / cols as f64 * 2.0 * r;
            let y = -r + (row as f64 + 0.5) / rows as f64 * 2.0 * r;
            *ok = x * x + y * y <= r * r;
        }
        // A disc smaller than one cell keeps its centre cell.
        if !valid.iter().any(|v| *v) {
            if let Some(c) = valid.get_mut(cell_index(cols, rows, 0.5, 0.5)) {
                *c = true;
            }
        }
    }
    FaceGrid { face, cols, rows, log_odds: vec![0.0; n], updates: vec![0; n], valid }
}

impl SurfaceGrid {
    /// An all-unknown grid (every cell at p₀ = 0.5) for an object.
    pub fn new(object: &MapObject, config: &GridConfig) -> Result<Self, ExploreError> {
        config.validate()?;
        let shape = object.label.shape();
        let h = sanitize_half_extents(&object.half_extents)?;
        let faces = Face::ALL.iter().map(|f| build_face(shape, &h, *f, config.cell_size_m)).collect();
        Ok(Self { object_id: object.id, shape, half_extents: h, cell_size_m: config.cell_size_m, faces })
    }

    /// Follow the object's current estimate. The pose needs nothing (cells are in the object
    /// frame); when the size, shape or cell size changed, every face is rebuilt for the new size
    /// and each new cell takes the state of the old cell at the same normalised `(u, v)` (nearest
    /// neighbour), so observations are kept across re-estimation. Returns whether it resampled.
    pub fn sync(&mut self, object: &MapObject, config: &GridConfig) -> Result<bool, ExploreError> {
        let shape = object.label.shape();
        let h = sanitize_half_extents(&object.half_extents)?;
        let same_size = (h - self.half_extents).abs().max() < config.resample_tolerance_m;
        if shape == self.shape && same_size && config.cell_size_m == self.cell_size_m {
            return Ok(false);
        }
        let mut faces: Vec<FaceGrid> =
            Face::ALL.iter().map(|f| build_face(shape, &h, *f, config.cell_size_m)).collect();
        for (new, old) in faces.iter_mut().zip(self.faces.iter()) {
            for i in 0..new.len() {
                let u = ((i % new.cols) as f64 + 0.5) / new.cols as f64;
                let v = ((i / new.cols) as f64 + 0.5) / new.rows as f64;
                let j = cell_index(old.cols, old.rows, u, v);
                if let (Some(l), Some(n)) = (old.log_odds.get(j), old.updates.get(j)) {
                    new.log_odds[i] = *l;
                    new.updates[i] = *n;
                }
            }
        }
        self.shape = shape;
        self.half_extents = h;
        self.cell_size_m = config.cell_size_m;
        self.faces = faces;
        Ok(true)
    }

    /// Centre and outward normal of a cell, object frame (`None` for an invalid reference).
    pub fn cell_pose(&self, r: CellRef) -> Option<CellPose> {
        let f = self.faces.get(r.face)?;
        if r.cell >= f.len() {
            return None;
        }
        let u = ((r.cell % f.cols) as f64 + 0.5) / f.cols as f64;
        let v = ((r.cell / f.cols) as f64 + 0.5) / f.rows as f64;
        Some(surface_point(self.shape, &self.half_extents, f.face, u, v))
    }

    /// The cell a point (object frame) projects onto, if its distance to the surface is at most
    /// `max_distance_m` and its nearest surface is not the bottom or a masked cell.
    pub fn cell_of_point(&self, p_in_object: &Point3<f64>, max_distance_m: f64) -> Option<CellRef> {
        let (face, u, v, d) = locate(self.shape, &self.half_extents, p_in_object)?;
        if d.is_nan() || d > max_distance_m {
            return None;
        }
        let fi = Face::ALL.iter().position(|f| *f == face)?;
        let f = self.faces.get(fi)?;
        let cell = cell_index(f.cols, f.rows, u, v);
        f.valid.get(cell).copied().unwrap_or(false).then_some(CellRef { face: fi, cell })
    }

    /// Every valid cell, in storage order (face, then row-major).
    pub fn cells(&self) -> impl Iterator<Item = CellRef> + '_ {
        self.faces.iter().enumerate().flat_map(|(fi, f)| {
            f.valid.iter().enumerate().filter(|(_, ok)| **ok).map(move |(ci, _)| CellRef { face: fi, cell: ci })
        })
    }

    /// Log-odds of a cell (0 for an invalid reference).
    pub fn log_odds(&self, r: CellRef) -> f64 {
        self.faces.get(r.face).and_then(|f| f.log_odds.get(r.cell)).map_or(0.0, |l| f64::from(*l))
    }

    /// State of a cell (`None` for an invalid or masked reference).
    pub fn state(&self, r: CellRef) -> Option<CellState> {
        self.faces.get(r.face)?.state(r.cell)
    }

    /// Apply one measurement to a cell: `hit` adds the hit log-odds, a miss the miss log-odds,
    /// clamped to the configured probability bounds. Invalid references are ignored.
    pub fn update_cell(&mut self, r: CellRef, hit: bool, config: &GridConfig) {
        let Some(f) = self.faces.get_mut(r.face) else {
            return;
        };
        let (Some(l), Some(n)) = (f.log_odds.get_mut(r.cell), f.updates.get_mut(r.cell)) else {
            return;
        };
        let delta = if hit { log_odds(config.p_hit) } else { log_odds(config.p_miss) };
        let (lo, hi) = (log_odds(config.p_min), log_odds(config.p_max));
        *l = (f64::from(*l) + delta).clamp(lo, hi) as f32;
        *n = n.saturating_add(1);
    }

    /// Counts and entropies (|O|, |F|, |U|, H_obj) over all valid cells.
    pub fn stats(&self) -> GridStats {
        let mut s = GridStats::default();
        for f in &self.faces {
            for i in 0..f.len() {
                match f.state(i) {
                    Some(CellState::Occupied) => s.occupied += 1,
                    Some(CellState::Free) => s.free += 1,
                    Some(CellState::Unknown) => s.unknown += 1,
                    None => continue,
                }
                s.entropy_bits += binary_entropy_bits(f.probability(i));
            }
        }
        s
    }

    /// Every valid cell in the world frame for recording / plotting: centre, outward normal,
    /// state and occupancy probability, given the object's current `world_from_object`.
    pub fn cells_in_world(&self, world_from_object: &crate::geometry::Se3) -> Vec<WorldCell> {
        self.cells()
            .filter_map(|c| {
                let pose = self.cell_pose(c)?;
                Some(WorldCell {
                    cell: c,
                    p_in_world: world_from_object * pose.p_in_object,
                    normal_in_world: world_from_object.rotation * pose.normal_in_object,
                    state: self.state(c)?,
                    probability: probability_from_log_odds(self.log_odds(c)),
                })
            })
            .collect()
    }

    /// Stats of one face (index into [`Face::ALL`]).
    pub fn face_stats(&self, face: usize) -> GridStats {
        let mut s = GridStats::default();
        if let Some(f) = self.faces.get(face) {
            for i in 0..f.len() {
                match f.state(i) {
                    Some(CellState::Occupied) => s.occupied += 1,
                    Some(CellState::Free) => s.free += 1,
                    Some(CellState::Unknown) => s.unknown += 1,
                    None => continue,
                }
                s.entropy_bits += binary_entropy_bits(f.probability(i));
            }
        }
        s
    }
}
