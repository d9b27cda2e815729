//! A frame-in, map-out wrapper around the [`Associator`] with the same shape as
//! [`crate::naive::NaiveMapper`], so an episode runner can switch between them by config.
//!
//! Per [`Frame`]: validate it; build one [`LocalObject`] per detection from the depth pixels inside
//! its box ([`local_objects_from_frame`]: every `pixel_stride`-th pixel, back-projected with the
//! frame's camera and `world_from_camera`, points at or below `min_height_m` above the table
//! dropped, cut to the depth surface connected to the box centre, and without the surface of an
//! occluding neighbour detection, see [`LocalCloudConfig`]); call
//! [`Associator::associate_frame`]. [`EnsembleMapper::map`] gives an [`ObjectMap`] of raw
//! estimates ([`GlobalObject::to_map_object_raw`]); parameterization refines them from
//! [`EnsembleMapper::associator`]'s clouds and histories.
//!
//! The paper's local clouds are ORB map points inside the box; depth pixels are the substitute
//! until the SLAM module provides map points (any source can call [`Associator`] directly).

use nalgebra::Point3;
use serde::{Deserialize, Serialize};

use super::{AssociationConfig, AssociationError, Associator, FrameAssociation, GlobalObject, LocalObject};
use crate::frame::Frame;
use crate::map::ObjectMap;

/// How local clouds are cut from a depth image.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LocalCloudConfig {
    /// Sample every n-th pixel in each direction inside a detection box (default 4; 0 acts as 1).
    pub pixel_stride: u32,
    /// Depth readings beyond this are ignored, metres (default 3.0).
    pub max_depth_m: f64,
    /// Points with world z at or below this are dropped as table surface, metres (default 0.005;
    /// the table top is z = 0 by the world-frame convention; `-inf` keeps everything).
    pub min_height_m: f64,
    /// Beyond the paper: keep only points whose depth is within this of the median depth of the
    /// box's central half (the detected object is what the box is centred on; surfaces of other
    /// objects or the floor behind it fall outside the gate), metres (default 0.15, the longest
    /// benchmark object's extent; `inf` disables the gate).
    pub depth_gate_m: f64,
    /// Beyond the paper: keep only the samples connected to the box's centre through a depth
    /// surface. Starting from the central-half samples within one step of the central median
    /// depth, a flood fill over the 4-neighbours of the sample grid accepts a neighbour when the
    /// depth changes by at most `max(connect_min_step_m, connect_slope × s)`, with `s` the lateral
    /// spacing of two samples at that depth (`pixel_stride × depth / fx`): surfaces up to
    /// `atan(connect_slope)` from fronto-parallel stay connected, while a neighbour or background
    /// object behind a depth jump is cut even inside the gate. Table points are dropped before, so
    /// the table cannot bridge two objects. `connect_slope` ≤ 0 disables the cut (default 3.0, 72°).
    pub connect_slope: f64,
    /// Smallest depth step accepted between neighbouring samples, metres (default 0.01: depth
    /// noise and quantisation at arm's length stay well below it).
    pub connect_min_step_m: f64,
    /// Beyond the paper: occluder exclusion. When most (`claim_share`) of a box's cut surface lies
    /// on the cut surface of another detection of the same frame, and that surface reaches well
    /// beyond the box (`claim_outside_share` of its samples outside it), the box's centre sits on
    /// an occluder crossing it (a bottle in front of a block): the neighbour's surface is masked
    /// and the box is cut again from the median of what is left (empty if nothing is). A
    /// neighbour's surface that stays inside the box (a false-positive box over the object) is
    /// not an occluder and changes nothing. Default true.
    pub claim_exclusion: bool,
    /// Share of the box's samples on the neighbour's surface that triggers the exclusion (default 0.5).
    pub claim_share: f64,
    /// Share of the neighbour's samples outside the box that makes it an occluder (default 0.25).
    pub claim_outside_share: f64,
    /// Beyond the paper: measure the table top in each frame instead of trusting z = 0. The
    /// frame's pose carries the SLAM gauge's error (millimetres, sometimes 1-2 cm and a fraction
    /// of a degree of tilt with few views); then the table around an object rises above
    /// `min_height_m` and joins its cloud (an object 15 cm wide instead of 5). With this set, the
    /// depth image is sampled every 8 pixels, samples within this band of z = 0 are fitted with a
    /// plane z = a·x + b·y + c (least squares, twice re-fitted on the samples within 5 mm), and
    /// `min_height_m` is measured from that plane; fewer than 200 samples or a tilt above 5°
    /// fall back to [`Self::table_prior`]. The band and the first fit are taken around that
    /// plane. Metres; 0 disables (default 0.03).
    pub table_fit_band_m: f64,
    /// The table plane `[a, b, c]` (z = a·x + b·y + c) the mapper is given by the cell's
    /// calibration (default `[0, 0, 0]`: the world frame's z = 0); where a frame's fit fails, and
    /// with the fit off, `min_height_m` is measured from it.
    pub table_prior: [f64; 3],
    /// Beyond the paper: look-alike split. The detector boxes each object on its own, so where the
    /// boxes of two same-label detections of about the same size (areas within
    /// `lookalike_area_ratio`) overlap, a sample goes only to the box whose centre is nearer
    /// (distance in units of each box's half-width and half-height). Side by side, look-alikes
    /// (a row of identical cans, two blocks millimetres apart) show one continuous depth surface
    /// that no depth cut separates; the boxes do. Default true.
    pub lookalike_split: bool,
    /// Largest area ratio of two same-label boxes for the look-alike split (default 2.0; a
    /// smaller box over a larger one is a different-sized object, occluded or not, and keeps its
    /// whole box).
    pub lookalike_area_ratio: f64,
}

impl Default for LocalCloudConfig {
    fn default() -> Self {
        Self {
            pixel_stride: 4,
            max_depth_m: 3.0,
            min_height_m: 0.005,
            depth_gate_m: 0.15,
            connect_slope: 3.0,
            connect_min_step_m: 0.01,
            claim_exclusion: true,
            claim_share: 0.5,
            claim_outside_share: 0.25,
            table_fit_band_m: 0.03,
            table_prior: [0.0; 3],
            lookalike_split: true,
            lookalike_area_ratio: 2.0,
        }
    }
}

/// Median of the valid depths in the central half of a box (`None` if it has none).
fn central_median_depth(frame: &Frame, u0: u32, v0: u32, u1: u32, v1: u32, stride: usize) -> Option<f64> {
    let (du, dv) = ((u1 - u0) / 4, (v1 - v0) / 4);
    let mut depths: Vec<f64> = Vec::new();
    for v in ((v0 + dv)..(v1 - dv)).step_by(stride) {
        for u in ((u0 + du)..(u1 - du)).step_by(stride) {
            if let Some(d) = frame.depth.at(u, v) {
                depths.push(f64::from(d));
            }
        }
    }
    median(depths)
}

/// The (upper) median of `values` (`None` when empty).
fn median(mut values: Vec<f64>) -> Option<f64> {
    if values.is_empty() {
        return None;
    }
    let mid = values.len() / 2;
    let (_, m, _) = values.select_nth_unstable_by(mid, f64::total_cmp);
    Some(*m)
}

/// Configuration of [`EnsembleMapper`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, Default)]
#[serde(default, deny_unknown_fields)]
pub struct EnsembleMapperConfig {
    /// Association thresholds and mode.
    pub association: AssociationConfig,
    /// Local cloud extraction.
    pub local: LocalCloudConfig,
}

/// One [`LocalObject`] per detection of a (validated) frame, in detection order: the depth pixels
/// inside the box (clipped to the image), back-projected into the world, gated and cut to the
/// surface connected to the box centre, then (with [`LocalCloudConfig::claim_exclusion`]) re-cut
/// without the surface of a neighbouring detection that occludes the box centre.
pub fn local_objects_from_frame(frame: &Frame, config: &LocalCloudConfig) -> Vec<LocalObject> {
    let table = table_plane(frame, config);
    let surfaces: Vec<Option<BoxSurface>> =
        frame.detections.iter().map(|det| BoxSurface::sample(frame, &det.bbox, config, &table)).collect();
    frame
        .detections
        .iter()
        .enumerate()
        .map(|(i, det)| {
            let points_in_world = match &surfaces[i] {
                None => Vec::new(),
                Some(own) => {
                    let claimed = if config.claim_exclusion {
                        claimed_by_neighbours(i, &surfaces, &frame.detections, config)
                    } else {
                        None
                    };
                    let lookalike = if config.lookalike_split {
                        nearer_lookalike(i, own, &frame.detections, config.lookalike_area_ratio)
                    } else {
                        None
                    };
                    match (claimed, lookalike) {
                        (Some(mut mask), Some(near)) => {
                            mask.iter_mut().zip(near).for_each(|(m, n)| *m |= n);
                            own.recut(&mask, frame, config)
                        }
                        (Some(mask), None) => own.recut(&mask, frame, config),
                        (None, Some(near)) => {
                            let keep: Vec<bool> = own.keep.iter().zip(near).map(|(k, n)| *k && !n).collect();
                            own.points_where(&keep)
                        }
                        (None, None) => own.points(),
                    }
                }
            };
            LocalObject { detection: *det, points_in_world }
        })
        .collect()
}

/// The table top seen by a frame, `z = a·x + b·y + c` in the world (see
/// [`LocalCloudConfig::table_fit_band_m`]); [`LocalCloudConfig::table_prior`] when not measured.
pub fn table_plane(frame: &Frame, config: &LocalCloudConfig) -> [f64; 3] {
    let band = config.table_fit_band_m;
    let prior = config.table_prior;
    let prior_z = |p: &Point3<f64>| prior[0] * p.x + prior[1] * p.y + prior[2];
    if !(band.is_finite() && band > 0.0) {
        return prior;
    }
    let mut pts: Vec<Point3<f64>> = Vec::new();
    for v in (0..frame.camera.height).step_by(8) {
        for u in (0..frame.camera.width).step_by(8) {
            let Some(d) = frame.depth.at(u, v) else { continue };
            let d = f64::from(d);
            if d > config.max_depth_m {
                continue;
            }
            let p: Point3<f64> = frame.world_from_camera * frame.camera.unproject_pixel(u, v, d);
            if (p.z - prior_z(&p)).abs() <= band {
                pts.push(p);
            }
        }
    }
    let mut plane = prior;
    let mut gate = band;
    for _ in 0..3 {
        let used: Vec<&Point3<f64>> =
            pts.iter().filter(|p| (p.z - (plane[0] * p.x + plane[1] * p.y + plane[2])).abs() <= gate).collect();
        if used.len() < 200 {
            return prior;
        }
        let mut ata = nalgebra::Matrix3::<f64>::zeros();
        let mut atb = nalgebra::Vector3::<f64>::zeros();
        for p in &used {
            let a = nalgebra::Vector3::new(p.x, p.y, 1.0);
            ata += a * a.transpose();
            atb += a * p.z;
        }
        let Some(x) = ata.lu().solve(&atb) else { return prior };
        plane = [x[0], x[1], x[2]];
        gate = 0.005;
    }
    let tilt = (plane[0] * plane[0] + plane[1] * plane[1]).sqrt().atan();
    if !plane.iter().all(|v| v.is_finite()) || tilt > 5f64.to_radians() {
        return prior;
    }
    plane
}

/// The sampled depth surface of one box: the stride grid of (depth, world point) samples that
/// pass the range, gate and table tests, and which of them the flood fill kept.
struct BoxSurface {
    u0: u32,
    v0: u32,
    stride: u32,
    cols: usize,
    rows: usize,
    grid: Vec<Option<(f64, Point3<f64>)>>,
    keep: Vec<bool>,
}

impl BoxSurface {
    /// `None` for a non-finite or empty box.
    fn sample(frame: &Frame, b: &crate::geometry::Box2, config: &LocalCloudConfig, table: &[f64; 3]) -> Option<Self> {
        let stride = config.pixel_stride.max(1);
        let w = f64::from(frame.camera.width);
        let h = f64::from(frame.camera.height);
        if !b.is_finite() {
            return None;
        }
        let u0 = b.min[0].clamp(0.0, w).floor() as u32;
        let v0 = b.min[1].clamp(0.0, h).floor() as u32;
        let u1 = b.max[0].clamp(0.0, w).ceil() as u32;
        let v1 = b.max[1].clamp(0.0, h).ceil() as u32;
        if u1 <= u0 || v1 <= v0 {
            return None;
        }
        let median = central_median_depth(frame, u0, v0, u1, v1, stride as usize);
        let cols = ((u1 - u0).div_ceil(stride)) as usize;
        let rows = ((v1 - v0).div_ceil(stride)) as usize;
        let mut grid: Vec<Option<(f64, Point3<f64>)>> = vec![None; cols * rows];
        for (r, v) in (v0..v1).step_by(stride as usize).enumerate() {
            for (c, u) in (u0..u1).step_by(stride as usize).enumerate() {
                let Some(d) = frame.depth.at(u, v) else { continue };
                let d = f64::from(d);
                if d > config.max_depth_m {
                    continue;
                }
                let p: Point3<f64> = frame.world_from_camera * frame.camera.unproject_pixel(u, v, d);
                if p.z - (table[0] * p.x + table[1] * p.y + table[2]) > config.min_height_m {
                    grid[r * cols + c] = Some((d, p));
                }
            }
        }
        let mut surface = Self { u0, v0, stride, cols, rows, grid, keep: Vec::new() };
        surface.keep = match median {
            Some(m) => surface.flood(m, None, frame, config),
            None => surface.grid.iter().map(Option::is_some).collect(),
        };
        Some(surface)
    }

    /// Pixel of grid cell `i`.
    fn pixel(&self, i: usize) -> (u32, u32) {
        (self.u0 + (i % self.cols) as u32 * self.stride, self.v0 + (i / self.cols) as u32 * self.stride)
    }

    /// The samples not `masked` within the depth gate around `median`; with a positive
    /// `connect_slope`, only those connected to the centre: seeds are the central-half samples
    /// within one step of `median`, then a 4-neighbour flood fill.
    fn flood(&self, median: f64, masked: Option<&[bool]>, frame: &Frame, config: &LocalCloudConfig) -> Vec<bool> {
        let (cols, rows) = (self.cols, self.rows);
        let usable = |i: usize| {
            masked.is_none_or(|m| !m[i])
                && self.grid[i]
                    .is_some_and(|(d, _)| !config.depth_gate_m.is_finite() || (d - median).abs() <= config.depth_gate_m)
        };
        if config.connect_slope <= 0.0 {
            return (0..cols * rows).map(usable).collect();
        }
        let spacing_per_m = f64::from(self.stride) / frame.camera.fx;
        let step = |d: f64| (config.connect_slope * spacing_per_m * d).max(config.connect_min_step_m);
        let mut keep = vec![false; cols * rows];
        let mut queue = std::collections::VecDeque::new();
        let (c_lo, c_hi, r_lo, r_hi) = (cols / 4, cols - cols / 4, rows / 4, rows - rows / 4);
        for r in r_lo..r_hi.max(r_lo + 1).min(rows) {
            for c in c_lo..c_hi.max(c_lo + 1).min(cols) {
                let i = r * cols + c;
                if usable(i) && self.grid[i].is_some_and(|(d, _)| (d - median).abs() <= step(median)) {
                    keep[i] = true;
                    queue.push_back(i);
                }
            }
        }
        while let Some(i) = queue.pop_front() {
            let Some((d, _)) = self.grid[i] else { continue };
            let (r, c) = (i / cols, i % cols);
            let neighbours = [
                (r > 0).then(|| i - cols),
                (r + 1 < rows).then(|| i + cols),
                (c > 0).then(|| i - 1),
                (c + 1 < cols).then(|| i + 1),
            ];
            for j in neighbours.into_iter().flatten() {
                if keep[j] || !usable(j) {
                    continue;
                }
                if let Some((dj, _)) = self.grid[j] {
                    if (dj - d).abs() <= step(d.min(dj)) {
                        keep[j] = true;
                        queue.push_back(j);
                    }
                }
            }
        }
        keep
    }

    fn points(&self) -> Vec<Point3<f64>> {
        self.points_where(&self.keep)
    }

    /// The world points of the samples flagged in `keep`.
    fn points_where(&self, keep: &[bool]) -> Vec<Point3<f64>> {
        self.grid.iter().zip(keep).filter_map(|(g, k)| if *k { g.map(|(_, p)| p) } else { None }).collect()
    }

    /// The cloud cut again from the central median of the samples left after `masked`.
    fn recut(&self, masked: &[bool], frame: &Frame, config: &LocalCloudConfig) -> Vec<Point3<f64>> {
        let (cols, rows) = (self.cols, self.rows);
        let (c_lo, c_hi, r_lo, r_hi) = (cols / 4, cols - cols / 4, rows / 4, rows - rows / 4);
        let mut depths: Vec<f64> = Vec::new();
        for r in r_lo..r_hi.max(r_lo + 1).min(rows) {
            for c in c_lo..c_hi.max(c_lo + 1).min(cols) {
                let i = r * cols + c;
                if let (false, Some((d, _))) = (masked[i], self.grid[i]) {
                    depths.push(d);
                }
            }
        }
        let Some(m) = median(depths) else { return Vec::new() };
        self.points_where(&self.flood(m, Some(masked), frame, config))
    }

    /// Whether pixel `(u, v)` at depth `d` lies on this box's kept surface: a kept sample within
    /// one stride in each direction and within `tol` in depth.
    fn on_surface(&self, u: u32, v: u32, d: f64, tol: f64) -> bool {
        let s = self.stride as i64;
        let (cu, cv) = ((i64::from(u) - i64::from(self.u0)) / s, (i64::from(v) - i64::from(self.v0)) / s);
        for dr in -1..=1 {
            for dc in -1..=1 {
                let (r, c) = (cv + dr, cu + dc);
                if r < 0 || c < 0 || r >= self.rows as i64 || c >= self.cols as i64 {
                    continue;
                }
                let i = r as usize * self.cols + c as usize;
                if self.keep[i] && self.grid[i].is_some_and(|(dj, _)| (dj - d).abs() <= tol) {
                    return true;
                }
            }
        }
        false
    }
}

/// The samples of detection `i`'s surface that lie in the box of a same-label detection of about
/// the same size (areas within `area_ratio`) whose centre is nearer, in units of each box's
/// half-sizes (see [`LocalCloudConfig::lookalike_split`]). `None` when no such box overlaps.
fn nearer_lookalike(
    i: usize,
    own: &BoxSurface,
    detections: &[crate::frame::Detection],
    area_ratio: f64,
) -> Option<Vec<bool>> {
    let di = detections.get(i)?;
    let bi = &di.bbox;
    let scaled = |b: &crate::geometry::Box2, u: f64, v: f64| {
        let c = b.center();
        let (hw, hh) = ((b.width() / 2.0).max(1.0), (b.height() / 2.0).max(1.0));
        ((u - c[0]) / hw).powi(2) + ((v - c[1]) / hh).powi(2)
    };
    let ratio_ok = |a: f64, b: f64| a > 0.0 && b > 0.0 && a.max(b) <= area_ratio * a.min(b);
    let rivals: Vec<&crate::geometry::Box2> = detections
        .iter()
        .enumerate()
        .filter(|(j, d)| *j != i && d.label == di.label && ratio_ok(bi.area(), d.bbox.area()))
        .map(|(_, d)| &d.bbox)
        .filter(|b| bi.intersection(b).is_some())
        .collect();
    if rivals.is_empty() {
        return None;
    }
    Some(
        (0..own.grid.len())
            .map(|k| {
                let (u, v) = own.pixel(k);
                let (u, v) = (f64::from(u), f64::from(v));
                let mine = scaled(bi, u, v);
                rivals.iter().any(|b| b.contains(u, v) && scaled(b, u, v) < mine)
            })
            .collect(),
    )
}

/// The samples of detection `i`'s surface that belong to a neighbouring detection `j` when `i`'s
/// box centre sits on `j`'s surface (see [`LocalCloudConfig::claim_exclusion`]): most of `i`'s
/// kept samples lie on `j`'s kept surface, and that surface reaches well beyond `i`'s box — an
/// occluder crossing the box, not a part of `i`. `None` when no neighbour claims the box.
fn claimed_by_neighbours(
    i: usize,
    surfaces: &[Option<BoxSurface>],
    detections: &[crate::frame::Detection],
    config: &LocalCloudConfig,
) -> Option<Vec<bool>> {
    let own = surfaces[i].as_ref()?;
    let n_kept = own.keep.iter().filter(|k| **k).count();
    if n_kept == 0 {
        return None;
    }
    let bi = &detections[i].bbox;
    let tol = config.connect_min_step_m;
    let mut mask: Option<Vec<bool>> = None;
    for (j, other) in surfaces.iter().enumerate() {
        let Some(other) = other.as_ref().filter(|_| j != i) else { continue };
        if bi.intersection(&detections[j].bbox).is_none() {
            continue;
        }
        // Every sample of the box on j's surface (kept by i's fill or not): the test's share and,
        // when it holds, the mask.
        let on_j: Vec<bool> = (0..own.grid.len())
            .map(|k| {
                let (u, v) = own.pixel(k);
                own.grid[k].is_some_and(|(d, _)| other.on_surface(u, v, d, tol))
            })
            .collect();
        let kept_on_j = on_j.iter().zip(&own.keep).filter(|(o, k)| **o && **k).count();
        if (kept_on_j as f64) < config.claim_share * n_kept as f64 {
            continue;
        }
        let j_kept = other.keep.iter().filter(|k| **k).count();
        let j_outside = (0..other.keep.len())
            .filter(|&k| other.keep[k])
            .filter(|&k| {
                let (u, v) = other.pixel(k);
                !bi.contains(f64::from(u), f64::from(v))
            })
            .count();
        if (j_outside as f64) < config.claim_outside_share * j_kept as f64 {
            continue;
        }
        let m = mask.get_or_insert_with(|| vec![false; own.keep.len()]);
        for (masked, on) in m.iter_mut().zip(on_j) {
            *masked |= on;
        }
    }
    mask
}

/// Depth frames in, object map out, with the ensemble association.
#[derive(Debug, Clone, PartialEq)]
pub struct EnsembleMapper {
    config: EnsembleMapperConfig,
    associator: Associator,
}

impl EnsembleMapper {
    /// A mapper with an empty map (config validated).
    pub fn new(config: EnsembleMapperConfig) -> Result<Self, AssociationError> {
        Ok(Self { config, associator: Associator::new(config.association)? })
    }

    /// The configuration.
    pub fn config(&self) -> &EnsembleMapperConfig {
        &self.config
    }

    /// The associator (global objects' clouds, histories, observations).
    pub fn associator(&self) -> &Associator {
        &self.associator
    }

    /// Fuse one frame. An invalid frame is an error and changes nothing.
    pub fn update(&mut self, frame: &Frame) -> Result<FrameAssociation, AssociationError> {
        frame.validate()?;
        let locals = local_objects_from_frame(frame, &self.config.local);
        self.associator.associate_frame(frame.index, &frame.camera, &frame.world_from_camera, &locals)
    }

    /// The current map with raw estimates (ids = global object ids; `next_id` past the largest).
    pub fn map(&self) -> ObjectMap {
        let objects: Vec<_> = self.associator.objects().map(GlobalObject::to_map_object_raw).collect();
        let next_id = objects.iter().map(|o| o.id + 1).max().unwrap_or(0);
        ObjectMap { objects, next_id }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::{DepthImage, Detection};
    use crate::geometry::{Box2, PinholeCamera, Se3};
    use crate::map::Label;
    use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};

    /// A top-down camera 0.5 m over the table; a block top at z = 0.10 fills image columns
    /// [40, 80), a lower object's top at z = 0.06 (4 cm deeper, inside the 15 cm gate) fills
    /// [80, 120), the table (z = 0) the rest; one detection box spans both objects, centred on the
    /// block.
    fn two_surfaces() -> Frame {
        let camera = PinholeCamera::from_fovy(160, 120, 0.8).unwrap();
        let rot = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI);
        let pose: Se3 = Isometry3::from_parts(Translation3::new(0.0, 0.0, 0.5), rot);
        let mut data = vec![0.0f32; 160 * 120];
        for v in 0..120usize {
            for u in 0..160usize {
                let z = if (40..80).contains(&u) && (30..90).contains(&v) {
                    0.10
                } else if (80..120).contains(&u) && (30..90).contains(&v) {
                    0.06
                } else {
                    0.0
                };
                data[v * 160 + u] = (0.5 - z) as f32;
            }
        }
        Frame {
            index: 0,
            camera,
            depth: DepthImage::new(160, 120, data).unwrap(),
            world_from_camera: pose,
            detections: vec![Detection { bbox: Box2::new(30.0, 25.0, 100.0, 95.0), label: Label::Block, score: 0.9 }],
        }
    }

    #[test]
    fn local_cloud_is_cut_at_depth_jumps() {
        let frame = two_surfaces();
        let cut = &local_objects_from_frame(&frame, &LocalCloudConfig::default())[0].points_in_world;
        assert!(!cut.is_empty());
        // Only the block's top (z = 0.10, exact depth) survives; the table went before.
        assert!(cut.iter().all(|p| (p.z - 0.10).abs() < 1e-6), "{:?}", cut.iter().map(|p| p.z).fold(0.0, f64::max));
        // Without the cut, the gate alone keeps the deeper neighbour's samples too.
        let gate_only = LocalCloudConfig { connect_slope: 0.0, ..LocalCloudConfig::default() };
        let all = &local_objects_from_frame(&frame, &gate_only)[0].points_in_world;
        let deeper = all.iter().filter(|p| (p.z - 0.06).abs() < 1e-6).count();
        assert!(deeper > 0 && all.len() == cut.len() + deeper, "{} {} {deeper}", all.len(), cut.len());
    }

    /// The frame of [`two_surfaces`] with the depth of surfaces at heights `top(u, v)` (table 0)
    /// and the given block-labelled boxes.
    fn frame_with(top: impl Fn(usize, usize) -> f64, boxes: &[Box2]) -> Frame {
        let mut frame = two_surfaces();
        let data: Vec<f32> = (0..120usize * 160).map(|i| (0.5 - top(i % 160, i / 160)) as f32).collect();
        frame.depth = DepthImage::new(160, 120, data).unwrap();
        frame.detections = boxes.iter().map(|b| Detection { bbox: *b, label: Label::Block, score: 0.9 }).collect();
        frame
    }

    #[test]
    fn an_occluder_crossing_the_box_centre_is_excluded() {
        // A low block (top z = 0.04) over columns [70, 130) x rows [40, 80); a tall narrow
        // object (top z = 0.15) over columns [90, 110) x rows [10, 110) crosses the block's box
        // through its centre and reaches far above and below it.
        let top = |u: usize, v: usize| {
            if (90..110).contains(&u) && (10..110).contains(&v) {
                0.15
            } else if (70..130).contains(&u) && (40..80).contains(&v) {
                0.04
            } else {
                0.0
            }
        };
        let boxes = [Box2::new(70.0, 40.0, 130.0, 80.0), Box2::new(90.0, 10.0, 110.0, 110.0)];
        let frame = frame_with(top, &boxes);
        let off = LocalCloudConfig { claim_exclusion: false, ..LocalCloudConfig::default() };
        let before = &local_objects_from_frame(&frame, &off)[0].points_in_world;
        assert!(
            !before.is_empty() && before.iter().all(|p| (p.z - 0.15).abs() < 1e-6),
            "the seed sits on the occluder"
        );
        let locals = local_objects_from_frame(&frame, &LocalCloudConfig::default());
        let block = &locals[0].points_in_world;
        assert!(block.len() > 20, "{}", block.len());
        assert!(block.iter().all(|p| (p.z - 0.04).abs() < 1e-6), "only the block's top is left");
        // The occluder's own cloud is untouched (the block's surface does not reach beyond its box
        // from its centre: the block is not on it).
        let tall = &locals[1].points_in_world;
        assert!(!tall.is_empty() && tall.iter().all(|p| (p.z - 0.15).abs() < 1e-6));
    }

    #[test]
    fn a_box_around_the_object_is_not_an_occluder() {
        // A second (false-positive) box encloses the block: its surface is the block's, all inside
        // the block's box, so the block keeps its cloud.
        let top = |u: usize, v: usize| if (70..130).contains(&u) && (40..80).contains(&v) { 0.04 } else { 0.0 };
        let boxes = [Box2::new(70.0, 40.0, 130.0, 80.0), Box2::new(20.0, 10.0, 150.0, 110.0)];
        let frame = frame_with(top, &boxes);
        let off = LocalCloudConfig { claim_exclusion: false, ..LocalCloudConfig::default() };
        let with = local_objects_from_frame(&frame, &LocalCloudConfig::default());
        let without = local_objects_from_frame(&frame, &off);
        assert!(with[0].points_in_world.len() > 100);
        assert_eq!(with[0].points_in_world, without[0].points_in_world);
    }

    #[test]
    fn the_table_is_measured_not_assumed() {
        // The frame's pose is 1.5 cm too low and tilted 0.5° about x: the table (z = 0 in truth)
        // appears at z ≈ +1.5 cm, tilted.
        let mut frame = frame_with(
            |u: usize, v: usize| if (70..90).contains(&u) && (50..70).contains(&v) { 0.06 } else { 0.0 },
            &[Box2::new(20.0, 20.0, 60.0, 100.0)],
        );
        let err = Isometry3::from_parts(
            Translation3::new(0.0, 0.0, 0.015),
            UnitQuaternion::from_axis_angle(&Vector3::x_axis(), 0.5f64.to_radians()),
        );
        frame.world_from_camera = err * frame.world_from_camera;
        let plane = table_plane(&frame, &LocalCloudConfig::default());
        // Closed form: the true table z = 0 mapped by `err`: z' = sin(θ)·y + 0.015 (to first order).
        assert!((plane[2] - 0.015).abs() < 1e-3, "{plane:?}");
        assert!((plane[1] - 0.5f64.to_radians().tan()).abs() < 1e-3, "{plane:?}");
        assert!(plane[0].abs() < 1e-3, "{plane:?}");
        // The box holds only table: nothing with the measured plane; the shifted table without it.
        let fitted = local_objects_from_frame(&frame, &LocalCloudConfig::default());
        assert!(fitted[0].points_in_world.is_empty(), "{}", fitted[0].points_in_world.len());
        let assumed = LocalCloudConfig { table_fit_band_m: 0.0, ..LocalCloudConfig::default() };
        assert!(local_objects_from_frame(&frame, &assumed)[0].points_in_world.len() > 50);
        // A frame that sees no table (all samples far from z = 0) falls back to z = 0.
        let mut high = frame.clone();
        high.world_from_camera = Isometry3::translation(0.0, 0.0, 0.2) * high.world_from_camera;
        assert_eq!(table_plane(&high, &LocalCloudConfig::default()), [0.0; 3]);
    }

    #[test]
    fn a_slanted_surface_stays_connected() {
        // A plane tilted 60° from fronto-parallel (depth grows by tan 60° per lateral step):
        // within the default slope of 3 (72°), so nothing is cut.
        let mut frame = two_surfaces();
        let (fx, cx) = (frame.camera.fx, frame.camera.cx);
        let mut data = vec![0.0f32; 160 * 120];
        for v in 0..120usize {
            for u in 0..160usize {
                // Depth d at column u satisfies d = 0.4 + tan60 · x with x = (u − cx) d / fx.
                let a = (u as f64 - cx) / fx;
                data[v * 160 + u] = (0.4 / (1.0 - 3f64.sqrt() * a)) as f32;
            }
        }
        frame.depth = DepthImage::new(160, 120, data).unwrap();
        let cut = local_objects_from_frame(&frame, &LocalCloudConfig::default())[0].points_in_world.len();
        let gate_only = LocalCloudConfig { connect_slope: 0.0, ..LocalCloudConfig::default() };
        let all = local_objects_from_frame(&frame, &gate_only)[0].points_in_world.len();
        assert!(all > 100 && cut == all, "{cut} of {all}");
    }
}
