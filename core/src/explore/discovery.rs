//! Table discovery (beyond the paper): which parts of the table top the camera has seen.
//!
//! The paper's utility scores only the objects already in the map. An object that the Init views
//! did not detect (a narrow field of view, an occluded corner) has no grid, no candidate views
//! around it and no weight in f, and the stopping rule (s(x) = 0 for every *mapped* object) can end
//! exploration with it still missing. The table top is where such objects stand, so its unseen part
//! is what the map does not yet know:
//!
//! - [`TableCoverage`]: a 2D grid over the table rectangle, cells `cell_m` (2 cm by default). A cell
//!   is *seen* once depth returns of `min_frames` frames (3, the map's confirmation count) landed
//!   in its column, from pixels inside a border of `margin_frac` (10 %) of the image: the table
//!   surface or anything standing on it, up to `max_height_m` above the table. Cells inside a
//!   mapped object's footprint count as known (an object is there). Both rules keep a cell unknown
//!   while an object standing there may be unconfirmed in the map: truncated detections (at the
//!   border) do not seed objects, and an object needs `min_observations` detections (measured:
//!   scene02, seed 3, 35° camera, with one return enough a cup seen untruncated in only the last
//!   two frames of the episode was never confirmed, its cells counted seen, and the session
//!   stopped; a pilot, not kept as a report: the effect on the benchmark is the "objects never
//!   mapped" table of `studies/narrow_fov/README.md`).
//! - The discovery gain of a candidate view: D(x) = (cell_m / object cell)² · N(x) bits, where
//!   N(x) = the unseen, not-known cells whose centre projects into the candidate's image within
//!   range and whose ray from the camera is not blocked by the table or a mapped object. The unit is
//!   the object grids' (an unknown 1 cm surface cell holds 1 bit), so D is "bits per cm² of unseen
//!   table".
//! - `before_stop` (the stopping extension): when s(x) = 0 for every mapped object, the session
//!   does not stop while a reachable candidate aimed at unseen cells sees at least
//!   `min_new_cells` of them (by default 25 cells of 2 cm = 100 cm², the footprint of the smallest
//!   object class); it moves to the one with the highest f + D (f is 0 there but for
//!   expected-gain's motion cost). The paper's views are unchanged until then.
//! - `weight` w (the mixed term): w·D(x) is added to f of every candidate of object-driven and
//!   expected-gain, and candidates aimed at unseen cells join those around objects. Measured on the
//!   exploration benchmark (seed 0, default camera), w = 1 spends the first views on the empty
//!   table margins the Init views miss (lower 3D IoU than the paper's utility on a seed-0 pilot;
//!   not kept as a report), so the run default is 0 and
//!   `before_stop` on.
//! - `reserve` (the budget reserve): the paper's rule also stops at `max_views`, and a camera
//!   that sees little of the table per view (a narrow field of view) can spend the whole budget
//!   on the mapped objects with part of the table never seen. At each decision the session
//!   estimates how many discovery views are still worth taking: a greedy set cover over this
//!   step's candidates aimed at unseen cells, each pick revealing at least `min_new_cells` cells
//!   no earlier pick reveals, reachable ([`greedy_discovery_views`]). When the views left are no
//!   more than that, it takes a discovery view (the highest f + D among those seeing at least
//!   `min_new_cells`, so a view that also sees an object to explore wins) instead of the object
//!   NBV. Objects first, the table's share of the budget last: an episode that stops by the
//!   paper's rule before the budget is tight never meets it.
//! - `exclude_truncated_px` (off by default): pixels inside a detection box that reaches the image
//!   edge do not mark cells ([`truncated_boxes`]). The inner-image margin alone lets an object seen
//!   only truncated (its box at the border, part of it inside the margin) mark its own cells seen
//!   while the map never confirms it (measured: scene06, seed 6, 35° camera, exact poses: a block
//!   truncated in all but two frames, 98 % of the table known, "all explored" with the block
//!   missing; with the option at 2 px it is mapped).
//! - Object evidence (`evidence_height_m` > 0; off in core's default, 0.02 in the run config
//!   `explore.discovery_evidence_height_m`): returns more than this above the
//!   table top are evidence that something stands in the cell, not a sight of the table (counted
//!   from the whole image, border included: the border is where an object the map has not
//!   confirmed shows, truncated): they do not mark the cell seen, so the cell stays unknown until
//!   a mapped object's footprint covers it.
//!   A cell whose evidence came in `min_frames` frames and that lies farther than
//!   `evidence_explained_m` from every mapped object is *unexplained*, and unknown even if table
//!   returns reached part of it (an object's outline cells): the depth shows an object the map
//!   does not have (an object detected only truncated, or in fewer than
//!   `min_observations` frames). Each unexplained cell counts `evidence_weight` unseen cells in
//!   the discovery count, gain and budget reserve, and the discovery look-at targets are drawn
//!   from the unexplained cells first, so a handful of them (a 5 cm block overlaps 9-16 cells
//!   of 2 cm) justifies a view centred on them: the object's detection is then untruncated and the
//!   map confirms it. After `evidence_max_views` views taken for unexplained cells the session
//!   stops favouring them (they count as plain unseen cells): an object the map cannot confirm
//!   from a centred view (two objects merged into one estimate) does not take the budget. This
//!   targets the scene06 episode above without `exclude_truncated_px`'s cost: that option leaves
//!   the table inside every truncated box unseen, and on a 9-seed sweep the views spent on those
//!   patches made another episode run out of views (scene03, seed 7).
//! - All off (w = 0, `before_stop` and `reserve` false) is the paper.

use nalgebra::Point3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::visibility::{Occluders, Viewpoint};
use super::{check_range, ExploreError, GridConfig, TableRect};
use crate::frame::DepthImage;
use crate::geometry::{Box2, PinholeCamera, Se3};

/// Discovery settings (see the module docs).
#[derive(Debug, Clone, PartialEq)]
pub struct DiscoveryConfig {
    /// w: weight of the discovery gain added to every candidate's utility; 0 = no mixed term.
    pub weight: f64,
    /// Do not stop on "every object done" while a view would still see `min_new_cells` unseen
    /// cells (default true; false = the paper's stopping rule).
    pub before_stop: bool,
    /// Table cell side, metres, in [1 mm, 1 m]; the table must give at most [`MAX_TABLE_CELLS`] cells.
    pub cell_m: f64,
    /// Keep exploring after every object is done while a candidate sees at least this many unseen
    /// cells.
    pub min_new_cells: usize,
    /// Depth pixels sampled every `pixel_stride` pixels in u and v when marking cells seen.
    pub pixel_stride: usize,
    /// Returns higher than this above the table do not mark its cells (walls, the arm), metres.
    pub max_height_m: f64,
    /// Look-at targets (unseen cells, spread by farthest-point sampling) of the candidates aimed
    /// at the table.
    pub targets: usize,
    /// Budget reserve: take a discovery view now when the views left in the budget are no more
    /// than the discovery views still worth taking ([`greedy_discovery_views`]); default true;
    /// false = spend the budget on the objects until the stopping rule.
    pub reserve: bool,
    /// A cell counts as seen once depth returns landed in it in this many frames (the map
    /// confirms an object after `pipeline.min_observations` untruncated detections: a cell seen
    /// in fewer frames may hold an object the map has not confirmed yet).
    pub min_frames: u32,
    /// Returns within this fraction of the image width (height) of the left/right (top/bottom)
    /// border do not mark cells, and predicted views count only cells inside that inner image:
    /// an object at the border is truncated, and truncated detections do not seed map objects.
    pub margin_frac: f64,
    /// Pixels inside a detection box that comes within this many pixels of the image edge (a
    /// *truncated* detection, as the association defines it) do not mark cells: the object there
    /// may be one the map never confirms, since truncated detections do not seed objects. Pixels,
    /// default 0 = off (object evidence, `evidence_height_m`, covers the same case from the depth).
    pub exclude_truncated_px: f64,
    /// Returns more than this above the table top are object evidence, not a sight of the table
    /// (they do not mark the cell seen). Metres, default 0.02; 0 = off (every return up to
    /// `max_height_m` marks its cell).
    pub evidence_height_m: f64,
    /// An unexplained cell (evidence, not seen, farther than `evidence_explained_m` from every
    /// mapped object) counts as this many unseen cells in the discovery count, gain and reserve.
    pub evidence_weight: f64,
    /// Evidence within this distance of a mapped object's primitive is explained by it (the
    /// estimate's error and the per-view pose error), metres.
    pub evidence_explained_m: f64,
    /// Views taken for unexplained cells after which they count as plain unseen cells.
    pub evidence_max_views: usize,
}

impl Default for DiscoveryConfig {
    fn default() -> Self {
        Self {
            weight: 0.0,
            before_stop: true,
            cell_m: 0.02,
            min_new_cells: 25,
            pixel_stride: 4,
            max_height_m: 0.4,
            targets: 4,
            reserve: true,
            min_frames: 3,
            margin_frac: 0.1,
            exclude_truncated_px: 0.0,
            evidence_height_m: 0.02,
            evidence_weight: 10.0,
            evidence_explained_m: 0.025,
            evidence_max_views: 2,
        }
    }
}

impl DiscoveryConfig {
    /// Check every field's range.
    pub fn validate(&self) -> Result<(), ExploreError> {
        check_range("discovery.weight", self.weight, 0.0, 1e6)?;
        check_range("discovery.cell_m", self.cell_m, 1e-3, 1.0)?;
        check_range("discovery.max_height_m", self.max_height_m, 0.0, 10.0)?;
        check_range("discovery.margin_frac", self.margin_frac, 0.0, 0.45)?;
        check_range("discovery.exclude_truncated_px", self.exclude_truncated_px, 0.0, 1e4)?;
        check_range("discovery.evidence_height_m", self.evidence_height_m, 0.0, 1.0)?;
        check_range("discovery.evidence_weight", self.evidence_weight, 1.0, 1e6)?;
        check_range("discovery.evidence_explained_m", self.evidence_explained_m, 0.0, 1.0)?;
        if self.evidence_height_m > self.max_height_m {
            return Err(ExploreError::InvalidConfig {
                field: "discovery.evidence_height_m",
                reason: format!("{} exceeds max_height_m {}", self.evidence_height_m, self.max_height_m),
            });
        }
        if self.min_frames == 0 {
            return Err(ExploreError::InvalidConfig { field: "discovery.min_frames", reason: "must be ≥ 1".into() });
        }
        if self.pixel_stride == 0 {
            return Err(ExploreError::InvalidConfig {
                field: "discovery.pixel_stride", reason: "must be ≥ 1".into()
            });
        }
        Ok(())
    }

    /// Whether anything of discovery is on (the mixed term or the stopping extension).
    pub fn enabled(&self) -> bool {
        self.weight > 0.0 || self.before_stop || self.reserve
    }
}

/// Which cells of the table top have been seen (see the module docs).
#[derive(Debug, Clone, PartialEq)]
pub struct TableCoverage {
    table: TableRect,
    cell_m: f64,
    cols: usize,
    rows: usize,
    min_frames: u32,
    /// Object-evidence height above the table (0 = every return marks its cell).
    evidence_height_m: f64,
    /// Evidence this close to a mapped object is explained by it.
    evidence_explained_m: f64,
    /// Frames whose returns landed in each cell (saturating).
    frames: Vec<u32>,
    /// Frames whose object-evidence returns landed in each cell (saturating).
    evidence: Vec<u32>,
}

/// Most cells of the table-coverage grid (4 M cells, 32 MB): a table of
/// [`super::MAX_TABLE_SIDE_M`] needs `cell_m` ≥ 5 mm.
pub const MAX_TABLE_CELLS: usize = 1 << 22;

/// Below the table top by more than this, a return is not on the table (metres).
const BELOW_TABLE_TOLERANCE_M: f64 = 0.02;
/// Cell centres are tested this far above the table top (metres), clear of the plane itself.
const CELL_LIFT_M: f64 = 0.002;
/// A cell whose centre lies within this distance of a mapped object's primitive is known (metres).
const FOOTPRINT_MARGIN_M: f64 = 0.01;

impl TableCoverage {
    /// An all-unseen grid over `table` with cells of `config.cell_m`, a cell seen after
    /// `config.min_frames` frames.
    pub fn new(table: &TableRect, config: &DiscoveryConfig) -> Result<Self, ExploreError> {
        table.validate()?;
        config.validate()?;
        let cell_m = config.cell_m;
        let cols = ((table.size_m[0] / cell_m).ceil() as usize).max(1);
        let rows = ((table.size_m[1] / cell_m).ceil() as usize).max(1);
        if cols.saturating_mul(rows) > MAX_TABLE_CELLS {
            return Err(ExploreError::InvalidConfig {
                field: "discovery_cell_m",
                reason: format!(
                    "{cell_m} m over a {:?} m table gives {cols} x {rows} cells, more than {MAX_TABLE_CELLS}",
                    table.size_m
                ),
            });
        }
        Ok(Self {
            table: *table,
            cell_m,
            cols,
            rows,
            min_frames: config.min_frames,
            evidence_height_m: config.evidence_height_m,
            evidence_explained_m: config.evidence_explained_m,
            frames: vec![0; cols * rows],
            evidence: vec![0; cols * rows],
        })
    }

    fn is_seen(&self, i: usize) -> bool {
        self.frames[i] >= self.min_frames
    }

    /// Number of cells.
    pub fn len(&self) -> usize {
        self.frames.len()
    }

    /// Whether the grid has no cells (never: a valid table has at least one).
    pub fn is_empty(&self) -> bool {
        self.frames.is_empty()
    }

    /// Cells seen so far, in `min_frames` frames (depth returns only; see
    /// [`Self::known_fraction`]).
    pub fn seen_cells(&self) -> usize {
        (0..self.frames.len()).filter(|i| self.is_seen(*i)).count()
    }

    fn cell_of(&self, x: f64, y: f64) -> Option<usize> {
        let lx = x - (self.table.center_m[0] - self.table.size_m[0] / 2.0);
        let ly = y - (self.table.center_m[1] - self.table.size_m[1] / 2.0);
        if !(lx >= 0.0 && ly >= 0.0 && lx < self.table.size_m[0] && ly < self.table.size_m[1]) {
            return None;
        }
        let (c, r) = ((lx / self.cell_m) as usize, (ly / self.cell_m) as usize);
        (c < self.cols && r < self.rows).then_some(r * self.cols + c)
    }

    /// World position of a cell's centre, lifted `CELL_LIFT_M` above the table top.
    pub fn cell_center(&self, i: usize) -> Point3<f64> {
        let (c, r) = (i % self.cols, i / self.cols);
        let x0 = self.table.center_m[0] - self.table.size_m[0] / 2.0;
        let y0 = self.table.center_m[1] - self.table.size_m[1] / 2.0;
        Point3::new(
            (x0 + (c as f64 + 0.5) * self.cell_m).min(x0 + self.table.size_m[0]),
            (y0 + (r as f64 + 0.5) * self.cell_m).min(y0 + self.table.size_m[1]),
            self.table.height_m + CELL_LIFT_M,
        )
    }

    /// Count one frame for the cells under its depth returns (every `pixel_stride`-th pixel,
    /// pixel centres, outside the `margin_frac` border); returns how many cells became seen (reached
    /// `min_frames`). The depth must match the camera's size.
    pub fn integrate_depth(
        &mut self,
        camera: &PinholeCamera,
        world_from_camera: &Se3,
        depth: &DepthImage,
        config: &DiscoveryConfig,
    ) -> Result<usize, ExploreError> {
        self.integrate_depth_excluding(camera, world_from_camera, depth, &[], config)
    }

    /// [`Self::integrate_depth`] with the pixels inside `excluded` boxes (pixel centres) left out:
    /// the frame's truncated detections ([`truncated_boxes`]).
    pub fn integrate_depth_excluding(
        &mut self,
        camera: &PinholeCamera,
        world_from_camera: &Se3,
        depth: &DepthImage,
        excluded: &[Box2],
        config: &DiscoveryConfig,
    ) -> Result<usize, ExploreError> {
        config.validate()?;
        if depth.width != camera.width || depth.height != camera.height {
            return Err(ExploreError::Degenerate {
                what: format!("depth {}x{} vs camera {}x{}", depth.width, depth.height, camera.width, camera.height),
            });
        }
        let stride = config.pixel_stride;
        let (lo, hi) = (self.table.height_m - BELOW_TABLE_TOLERANCE_M, self.table.height_m + config.max_height_m);
        let (u_lo, u_hi) = inner_range(depth.width, config.margin_frac);
        let (v_lo, v_hi) = inner_range(depth.height, config.margin_frac);
        let evidence_above = (self.evidence_height_m > 0.0).then_some(self.table.height_m + self.evidence_height_m);
        let mut hit = vec![false; self.frames.len()];
        let mut evidence_hit = vec![false; self.frames.len()];
        // Evidence counts from the whole image (the border is where an object the map has not
        // confirmed shows, truncated); table sightings only from inside the border, outside the
        // excluded boxes.
        let whole = evidence_above.is_some();
        for v in (0..depth.height).step_by(stride).filter(|v| whole || (v_lo..v_hi).contains(v)) {
            for u in (0..depth.width).step_by(stride).filter(|u| whole || (u_lo..u_hi).contains(u)) {
                let (pu, pv) = (f64::from(u) + 0.5, f64::from(v) + 0.5);
                let sighting = (v_lo..v_hi).contains(&v)
                    && (u_lo..u_hi).contains(&u)
                    && !excluded.iter().any(|b| pu >= b.min[0] && pu <= b.max[0] && pv >= b.min[1] && pv <= b.max[1]);
                let Some(d) = depth.at(u, v) else { continue };
                let p = world_from_camera * camera.unproject(pu, pv, f64::from(d));
                if !(p.z >= lo && p.z <= hi) {
                    continue;
                }
                if let Some(i) = self.cell_of(p.x, p.y) {
                    match evidence_above {
                        Some(z) if p.z > z => evidence_hit[i] = true,
                        _ if sighting => hit[i] = true,
                        _ => {}
                    }
                }
            }
        }
        let mut newly = 0;
        for (i, h) in hit.iter().enumerate() {
            if *h {
                let was = self.is_seen(i);
                self.frames[i] = self.frames[i].saturating_add(1);
                newly += usize::from(!was && self.is_seen(i));
            }
        }
        for (i, h) in evidence_hit.iter().enumerate() {
            if *h {
                self.evidence[i] = self.evidence[i].saturating_add(1);
            }
        }
        Ok(newly)
    }

    /// [`Self::unknown_cells`] with, for each, whether it is *unexplained* (module docs): object
    /// evidence in `min_frames` frames and no mapped object within `evidence_explained_m` of its
    /// centre. An unexplained cell is unknown even where table returns also reached it (the
    /// cells along an object's outline).
    pub fn unknown_cells_with_evidence(&self, occluders: &Occluders) -> (Vec<Point3<f64>>, Vec<bool>) {
        (0..self.frames.len())
            .map(|i| (i, self.cell_center(i)))
            .filter(|(_, p)| !occluders.point_inside_object(p, FOOTPRINT_MARGIN_M))
            .filter_map(|(i, p)| {
                let unexplained = self.evidence_height_m > 0.0
                    && self.evidence[i] >= self.min_frames
                    && !occluders.point_inside_object(&p, self.evidence_explained_m);
                (unexplained || !self.is_seen(i)).then_some((p, unexplained))
            })
            .unzip()
    }

    /// Cells not known, as world points (centres lifted just above the table top): neither seen
    /// nor inside a mapped object's footprint (`occluders`: the map's primitives), or, with object
    /// evidence on, unexplained ([`Self::unknown_cells_with_evidence`]).
    pub fn unknown_cells(&self, occluders: &Occluders) -> Vec<Point3<f64>> {
        self.unknown_cells_with_evidence(occluders).0
    }

    /// Fraction of the table known: seen, or inside a mapped object's footprint.
    pub fn known_fraction(&self, occluders: &Occluders) -> f64 {
        1.0 - self.unknown_cells(occluders).len() as f64 / self.frames.len() as f64
    }

    /// Bits of one cell in the object grids' unit (1 bit per unknown cell of `object_cell_m`).
    pub fn bits_per_cell(&self, object_cell_m: f64) -> f64 {
        (self.cell_m / object_cell_m).powi(2)
    }
}

/// The detection boxes that come within `margin_px` of the image edge (`width` × `height`
/// pixels): truncated, so they never seed a map object; none when `margin_px` is 0.
pub fn truncated_boxes(boxes: impl IntoIterator<Item = Box2>, width: u32, height: u32, margin_px: f64) -> Vec<Box2> {
    if margin_px <= 0.0 {
        return Vec::new();
    }
    let (w, h) = (f64::from(width), f64::from(height));
    boxes
        .into_iter()
        .filter(|b| {
            b.min[0] < margin_px || b.min[1] < margin_px || b.max[0] > w - margin_px || b.max[1] > h - margin_px
        })
        .collect()
}

/// How many of `unknown` (from [`TableCoverage::unknown_cells`]) a camera at `world_from_camera`
/// would see: in its image inside the `config.margin_frac` border, within `grid`'s range, the ray
/// from the eye unblocked by the table and the mapped objects.
pub fn visible_unknown_cells(
    unknown: &[Point3<f64>],
    camera: &PinholeCamera,
    world_from_camera: &Se3,
    occluders: &Occluders,
    grid: &GridConfig,
    config: &DiscoveryConfig,
) -> usize {
    visible_unknown_indices(unknown, camera, world_from_camera, occluders, grid, config).len()
}

/// Pixel range `[lo, hi)` of an image side of `n` pixels inside a border of `margin_frac` · n.
fn inner_range(n: u32, margin_frac: f64) -> (u32, u32) {
    let m = ((f64::from(n) * margin_frac).round() as u32).min(n / 2);
    (m, n - m)
}

/// Indices into `unknown` of the cells a view would see (the test of [`visible_unknown_cells`]).
pub fn visible_unknown_indices(
    unknown: &[Point3<f64>],
    camera: &PinholeCamera,
    world_from_camera: &Se3,
    occluders: &Occluders,
    grid: &GridConfig,
    config: &DiscoveryConfig,
) -> Vec<usize> {
    let vp = Viewpoint::new(camera, world_from_camera);
    let (u_lo, u_hi) = inner_range(camera.width, config.margin_frac);
    let (v_lo, v_hi) = inner_range(camera.height, config.margin_frac);
    let inner = |uv: [f64; 2]| {
        uv[0] >= f64::from(u_lo) && uv[0] < f64::from(u_hi) && uv[1] >= f64::from(v_lo) && uv[1] < f64::from(v_hi)
    };
    (0..unknown.len())
        .filter(|i| {
            let p = &unknown[*i];
            let pc = vp.camera_from_world * *p;
            let dist = (*p - vp.eye_in_world).norm();
            pc.z >= grid.min_range_m
                && dist <= grid.max_range_m
                && camera.project(&pc).is_some_and(|uv| camera.contains(uv) && inner(uv))
                && !occluders.segment_blocked(&vp.eye_in_world, p, None)
        })
        .collect()
}

/// The discovery views still worth taking, by greedy set cover: repeatedly the view (index into
/// `seen_by_view`, each the cell indices that view sees) that reveals the most cells no earlier
/// pick reveals, as long as it reveals at least `min_new` of them and `accept` takes it (the
/// reachability check: a rejected view is dropped and the next best tried); at most `limit`
/// picks, in pick order. Its length is the session's estimate of the views that discovering the
/// rest of the table needs (the budget reserve, module docs).
pub fn greedy_discovery_views(
    seen_by_view: &[Vec<usize>],
    n_cells: usize,
    min_new: usize,
    limit: usize,
    accept: impl FnMut(usize) -> bool,
) -> Vec<usize> {
    greedy_discovery_views_weighted(seen_by_view, &vec![1.0; n_cells], min_new as f64, limit, accept)
}

/// [`greedy_discovery_views`] with a weight per cell (`weights[c]`, the count an unexplained cell
/// stands for: module docs): a view's gain is the summed weight of the cells it newly reveals, and
/// a pick must reveal at least `min_new` of it.
pub fn greedy_discovery_views_weighted(
    seen_by_view: &[Vec<usize>],
    weights: &[f64],
    min_new: f64,
    limit: usize,
    mut accept: impl FnMut(usize) -> bool,
) -> Vec<usize> {
    let mut covered = vec![false; weights.len()];
    let mut dropped = vec![false; seen_by_view.len()];
    let mut picks = Vec::new();
    while picks.len() < limit {
        let gain = |v: &Vec<usize>| -> f64 {
            v.iter().filter(|c| !covered.get(**c).copied().unwrap_or(true)).map(|c| weights[*c]).sum()
        };
        let best = (0..seen_by_view.len()).filter(|i| !dropped[*i]).map(|i| (i, gain(&seen_by_view[i]))).fold(
            None,
            |b: Option<(usize, f64)>, (i, g)| match b {
                Some((_, bg)) if bg >= g => b,
                _ => Some((i, g)),
            },
        );
        let Some((i, g)) = best else { break };
        if g < min_new.max(1.0) || g <= 0.0 {
            break;
        }
        dropped[i] = true;
        if !accept(i) {
            continue;
        }
        for c in &seen_by_view[i] {
            if let Some(slot) = covered.get_mut(*c) {
                *slot = true;
            }
        }
        picks.push(i);
    }
    picks
}

/// Up to `n` look-at targets among `unknown`, spread out: the first drawn at random (seeded), each
/// next the farthest from those chosen (farthest-point sampling, ties → lowest index).
pub fn discovery_targets(unknown: &[Point3<f64>], n: usize, seed: u64) -> Vec<Point3<f64>> {
    if unknown.is_empty() || n == 0 {
        return Vec::new();
    }
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0xD15C_0BE7);
    let first = rng.random_range(0..unknown.len());
    let mut chosen = vec![unknown[first]];
    let mut nearest: Vec<f64> = unknown.iter().map(|p| (p - unknown[first]).norm()).collect();
    while chosen.len() < n.min(unknown.len()) {
        let (i, d) = nearest.iter().enumerate().fold((0, -1.0), |b, (i, d)| if *d > b.1 { (i, *d) } else { b });
        if d <= 0.0 {
            break;
        }
        chosen.push(unknown[i]);
        for (k, p) in unknown.iter().enumerate() {
            nearest[k] = nearest[k].min((p - unknown[i]).norm());
        }
    }
    chosen
}
