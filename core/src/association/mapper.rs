//! A frame-in, map-out wrapper around the [`Associator`] with the same shape as
//! [`crate::naive::NaiveMapper`], so an episode runner can switch between them by config.
//!
//! Per [`Frame`]: validate it; build one [`LocalObject`] per detection from the depth pixels inside
//! its box ([`local_objects_from_frame`]: every `pixel_stride`-th pixel, back-projected with the
//! frame's camera and `world_from_camera`, points at or below `min_height_m` above the table
//! dropped); call [`Associator::associate_frame`]. [`EnsembleMapper::map`] gives an [`ObjectMap`]
//! of raw estimates ([`GlobalObject::to_map_object_raw`]); parameterization refines them from
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
    if depths.is_empty() {
        return None;
    }
    let mid = depths.len() / 2;
    let (_, m, _) = depths.select_nth_unstable_by(mid, f64::total_cmp);
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
/// surface connected to the box centre (see [`LocalCloudConfig`]).
pub fn local_objects_from_frame(frame: &Frame, config: &LocalCloudConfig) -> Vec<LocalObject> {
    frame
        .detections
        .iter()
        .map(|det| LocalObject { detection: *det, points_in_world: box_cloud(frame, &det.bbox, config) })
        .collect()
}

/// The local cloud of one box (empty for a non-finite or empty box).
fn box_cloud(frame: &Frame, b: &crate::geometry::Box2, config: &LocalCloudConfig) -> Vec<Point3<f64>> {
    let stride = config.pixel_stride.max(1);
    let w = f64::from(frame.camera.width);
    let h = f64::from(frame.camera.height);
    if !b.is_finite() {
        return Vec::new();
    }
    let u0 = b.min[0].clamp(0.0, w).floor() as u32;
    let v0 = b.min[1].clamp(0.0, h).floor() as u32;
    let u1 = b.max[0].clamp(0.0, w).ceil() as u32;
    let v1 = b.max[1].clamp(0.0, h).ceil() as u32;
    if u1 <= u0 || v1 <= v0 {
        return Vec::new();
    }
    let median = central_median_depth(frame, u0, v0, u1, v1, stride as usize);
    let gate = if config.depth_gate_m.is_finite() { median } else { None };
    // The sample grid: (depth, world point) of the samples that pass the range, gate and table tests.
    let cols = ((u1 - u0).div_ceil(stride)) as usize;
    let rows = ((v1 - v0).div_ceil(stride)) as usize;
    let mut grid: Vec<Option<(f64, Point3<f64>)>> = vec![None; cols * rows];
    for (r, v) in (v0..v1).step_by(stride as usize).enumerate() {
        for (c, u) in (u0..u1).step_by(stride as usize).enumerate() {
            let Some(d) = frame.depth.at(u, v) else { continue };
            let d = f64::from(d);
            if d > config.max_depth_m || gate.is_some_and(|m| (d - m).abs() > config.depth_gate_m) {
                continue;
            }
            let p: Point3<f64> = frame.world_from_camera * frame.camera.unproject(f64::from(u), f64::from(v), d);
            if p.z > config.min_height_m {
                grid[r * cols + c] = Some((d, p));
            }
        }
    }
    let (Some(m), true) = (median, config.connect_slope > 0.0) else {
        return grid.into_iter().flatten().map(|(_, p)| p).collect();
    };
    let spacing_per_m = f64::from(stride) / frame.camera.fx;
    let step = |d: f64| (config.connect_slope * spacing_per_m * d).max(config.connect_min_step_m);
    // Seeds: central-half samples on the median surface; then a 4-neighbour flood fill.
    let mut keep = vec![false; cols * rows];
    let mut queue = std::collections::VecDeque::new();
    let (c_lo, c_hi, r_lo, r_hi) = (cols / 4, cols - cols / 4, rows / 4, rows - rows / 4);
    for r in r_lo..r_hi.max(r_lo + 1).min(rows) {
        for c in c_lo..c_hi.max(c_lo + 1).min(cols) {
            let i = r * cols + c;
            if grid[i].is_some_and(|(d, _)| (d - m).abs() <= step(m)) {
                keep[i] = true;
                queue.push_back(i);
            }
        }
    }
    while let Some(i) = queue.pop_front() {
        let Some((d, _)) = grid[i] else { continue };
        let (r, c) = (i / cols, i % cols);
        let neighbours = [
            (r > 0).then(|| i - cols),
            (r + 1 < rows).then(|| i + cols),
            (c > 0).then(|| i - 1),
            (c + 1 < cols).then(|| i + 1),
        ];
        for j in neighbours.into_iter().flatten() {
            if keep[j] {
                continue;
            }
            if let Some((dj, _)) = grid[j] {
                if (dj - d).abs() <= step(d.min(dj)) {
                    keep[j] = true;
                    queue.push_back(j);
                }
            }
        }
    }
    grid.into_iter().zip(keep).filter_map(|(g, k)| if k { g.map(|(_, p)| p) } else { None }).collect()
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
        let camera = PinholeCamera::from_fovy(160, 120, 0.8).unwrap_or_else(|e| panic!("{e}"));
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
            depth: DepthImage::new(160, 120, data).unwrap_or_else(|e| panic!("{e}")),
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
        frame.depth = DepthImage::new(160, 120, data).unwrap_or_else(|e| panic!("{e}"));
        let cut = local_objects_from_frame(&frame, &LocalCloudConfig::default())[0].points_in_world.len();
        let gate_only = LocalCloudConfig { connect_slope: 0.0, ..LocalCloudConfig::default() };
        let all = local_objects_from_frame(&frame, &gate_only)[0].points_in_world.len();
        assert!(all > 100 && cut == all, "{cut} of {all}");
    }
}
