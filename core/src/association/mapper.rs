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
}

impl Default for LocalCloudConfig {
    fn default() -> Self {
        Self { pixel_stride: 4, max_depth_m: 3.0, min_height_m: 0.005, depth_gate_m: 0.15 }
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
/// inside the box (clipped to the image), back-projected into the world.
pub fn local_objects_from_frame(frame: &Frame, config: &LocalCloudConfig) -> Vec<LocalObject> {
    let stride = config.pixel_stride.max(1) as usize;
    let w = f64::from(frame.camera.width);
    let h = f64::from(frame.camera.height);
    frame
        .detections
        .iter()
        .map(|det| {
            let b = &det.bbox;
            let mut points = Vec::new();
            if b.is_finite() {
                let u0 = b.min[0].clamp(0.0, w).floor() as u32;
                let v0 = b.min[1].clamp(0.0, h).floor() as u32;
                let u1 = b.max[0].clamp(0.0, w).ceil() as u32;
                let v1 = b.max[1].clamp(0.0, h).ceil() as u32;
                let gate = if config.depth_gate_m.is_finite() && u1 > u0 && v1 > v0 {
                    central_median_depth(frame, u0, v0, u1, v1, stride)
                } else {
                    None
                };
                for v in (v0..v1).step_by(stride) {
                    for u in (u0..u1).step_by(stride) {
                        let Some(d) = frame.depth.at(u, v) else { continue };
                        let d = f64::from(d);
                        if d > config.max_depth_m {
                            continue;
                        }
                        if let Some(m) = gate {
                            if (d - m).abs() > config.depth_gate_m {
                                continue;
                            }
                        }
                        let p_in_world: Point3<f64> =
                            frame.world_from_camera * frame.camera.unproject(f64::from(u), f64::from(v), d);
                        if p_in_world.z > config.min_height_m {
                            points.push(p_in_world);
                        }
                    }
                }
            }
            LocalObject { detection: *det, points_in_world: points }
        })
        .collect()
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
