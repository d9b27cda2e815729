//! The foundation's baseline estimator, kept as the `naive` association ablation.
//!
//! Per frame, for each detection: back-project the depth pixels inside its box (every
//! [`NaiveConfig::pixel_stride`]-th pixel) into the world with the frame's camera pose; associate
//! the detection with the map object of the same label whose current box, projected into this
//! frame, overlaps it best (IoU ≥ [`NaiveConfig::iou_threshold`], each object and detection used at
//! most once, greedy by IoU); otherwise start a new object. An object's estimate is the axis-aligned
//! extent of its accumulated points (per-axis [`NaiveConfig::trim_fraction`] quantiles), yaw 0.
//!
//! No outlier rejection, no yaw, no statistics: this is the "IoU only" strawman the paper's
//! association and parameterization improve on. Points are stored on a voxel grid
//! ([`NaiveConfig::voxel_m`]) so memory stays bounded, in a `BTreeMap` so results are
//! deterministic.

use std::collections::BTreeMap;

use nalgebra::{Point3, Vector3};
use serde::{Deserialize, Serialize};

use crate::frame::{Frame, FrameError};
use crate::geometry::{project_geometry, se3_from_yaw, trimmed_extent, Box2};
use crate::map::{EstimateStage, Label, MapObject, ObjectMap, Observation};

/// Configuration of the naive estimator.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct NaiveConfig {
    /// Sample every n-th pixel in each direction inside a detection box (default 4; ≥ 1).
    pub pixel_stride: u32,
    /// Minimum projected-box IoU to associate a detection with an object (default 0.3; in [0, 1]).
    pub iou_threshold: f64,
    /// Voxel size for the stored point cloud, metres (default 0.005; in [1e-4, 1]).
    pub voxel_m: f64,
    /// Fraction trimmed at each end of every axis before taking the extent (default 0.02; in
    /// [0, 0.5)).
    pub trim_fraction: f64,
    /// Detections yielding fewer valid depth points than this are skipped (default 20).
    pub min_points: usize,
    /// Depth readings beyond this are ignored, metres (default 3.0; > 0).
    pub max_depth_m: f64,
}

impl NaiveConfig {
    /// Check the ranges stated on each field; the error is `(field, reason)`.
    pub fn validate(&self) -> Result<(), (&'static str, String)> {
        let bad = |field: &'static str, v: f64, range: &str| Err((field, format!("{v} outside {range}")));
        if self.pixel_stride == 0 {
            return bad("pixel_stride", 0.0, "[1, ∞)");
        }
        if !(0.0..=1.0).contains(&self.iou_threshold) {
            return bad("iou_threshold", self.iou_threshold, "[0, 1]");
        }
        if !(1e-4..=1.0).contains(&self.voxel_m) {
            return bad("voxel_m", self.voxel_m, "[1e-4, 1] m");
        }
        if !(0.0..0.5).contains(&self.trim_fraction) {
            return bad("trim_fraction", self.trim_fraction, "[0, 0.5)");
        }
        if !(self.max_depth_m.is_finite() && self.max_depth_m > 0.0) {
            return bad("max_depth_m", self.max_depth_m, "(0, ∞) m");
        }
        Ok(())
    }
}

impl Default for NaiveConfig {
    fn default() -> Self {
        Self {
            pixel_stride: 4,
            iou_threshold: 0.3,
            voxel_m: 0.005,
            trim_fraction: 0.02,
            min_points: 20,
            max_depth_m: 3.0,
        }
    }
}

/// Per-object state beyond what the map stores.
#[derive(Debug, Clone, Default)]
struct Track {
    voxels: BTreeMap<(i64, i64, i64), Point3<f64>>,
    label_votes: [u32; Label::ALL.len()],
}

/// What one update did (for logging and tests).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct UpdateSummary {
    /// For each detection: the object id it updated or created (`None` if skipped).
    pub assigned: Vec<Option<u32>>,
    /// Number of objects created by this update.
    pub created: usize,
    /// This frame's points (world frame) per updated or created object id.
    pub observed: BTreeMap<u32, Vec<Point3<f64>>>,
}

/// The naive mapper: owns an [`ObjectMap`] and updates it frame by frame.
#[derive(Debug, Clone, Default)]
pub struct NaiveMapper {
    config: NaiveConfig,
    map: ObjectMap,
    tracks: BTreeMap<u32, Track>,
}

impl NaiveMapper {
    /// A mapper with an empty map.
    pub fn new(config: NaiveConfig) -> Self {
        Self { config, map: ObjectMap::new(), tracks: BTreeMap::new() }
    }

    /// The current map.
    pub fn map(&self) -> &ObjectMap {
        &self.map
    }

    /// Fuse one frame. The frame is validated first; an invalid frame changes nothing.
    pub fn update(&mut self, frame: &Frame) -> Result<UpdateSummary, FrameError> {
        frame.validate()?;
        let clouds: Vec<Vec<Point3<f64>>> =
            frame.detections.iter().map(|d| self.points_in_box(frame, &d.bbox)).collect();

        // Candidate pairs (IoU of the object's projected box with the detection), greedy by IoU.
        let projected: Vec<Option<Box2>> = self
            .map
            .objects
            .iter()
            .map(|o| project_geometry(&o.geometry(), &frame.camera, &frame.world_from_camera))
            .collect();
        let mut pairs: Vec<(f64, usize, usize)> = Vec::new();
        for (di, det) in frame.detections.iter().enumerate() {
            for (oi, obj) in self.map.objects.iter().enumerate() {
                if obj.label != det.label {
                    continue;
                }
                if let Some(pb) = projected[oi] {
                    let iou = pb.iou(&det.bbox);
                    if iou >= self.config.iou_threshold {
                        pairs.push((iou, di, oi));
                    }
                }
            }
        }
        pairs.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)).then(a.2.cmp(&b.2)));
        let mut det_to_obj: Vec<Option<usize>> = vec![None; frame.detections.len()];
        let mut obj_used = vec![false; self.map.objects.len()];
        for (_, di, oi) in pairs {
            if det_to_obj[di].is_none() && !obj_used[oi] {
                det_to_obj[di] = Some(oi);
                obj_used[oi] = true;
            }
        }

        let mut summary =
            UpdateSummary { assigned: vec![None; frame.detections.len()], created: 0, observed: BTreeMap::new() };
        for (di, det) in frame.detections.iter().enumerate() {
            let cloud = &clouds[di];
            if cloud.len() < self.config.min_points {
                continue;
            }
            let centroid = cloud.iter().fold(Vector3::zeros(), |acc, p| acc + p.coords) / cloud.len() as f64;
            let observation =
                Observation { frame: frame.index, bbox: det.bbox, score: det.score, centroid_in_world: centroid };
            let id = match det_to_obj[di] {
                Some(oi) => {
                    self.map.objects[oi].observations.push(observation);
                    self.map.objects[oi].id
                }
                None => {
                    summary.created += 1;
                    self.map.insert(MapObject {
                        id: 0,
                        label: det.label,
                        world_from_object: se3_from_yaw(centroid, 0.0),
                        half_extents: Vector3::zeros(),
                        observations: vec![observation],
                        points_in_world: Vec::new(),
                        stage: EstimateStage::Raw,
                    })
                }
            };
            let track = self.tracks.entry(id).or_default();
            track.label_votes[det.label.index()] += 1;
            for p in cloud {
                let key = voxel_key(p, self.config.voxel_m);
                track.voxels.entry(key).or_insert(*p);
            }
            self.refresh(id);
            summary.assigned[di] = Some(id);
            summary.observed.entry(id).or_default().extend_from_slice(cloud);
        }
        Ok(summary)
    }

    fn refresh(&mut self, id: u32) {
        let Some(track) = self.tracks.get(&id) else { return };
        let Some(obj) = self.map.objects.iter_mut().find(|o| o.id == id) else { return };
        let points: Vec<Point3<f64>> = track.voxels.values().copied().collect();
        if let Some((lo, hi)) = trimmed_extent(&points, self.config.trim_fraction) {
            let center = (lo + hi) / 2.0;
            obj.world_from_object = se3_from_yaw(center, 0.0);
            obj.half_extents = (hi - lo) / 2.0;
        }
        // Majority label; ties go to the lower label index (deterministic).
        let mut best = 0;
        for (i, v) in track.label_votes.iter().enumerate() {
            if *v > track.label_votes[best] {
                best = i;
            }
        }
        obj.label = Label::ALL[best];
        obj.points_in_world = points;
    }

    fn points_in_box(&self, frame: &Frame, bbox: &Box2) -> Vec<Point3<f64>> {
        let stride = self.config.pixel_stride.max(1) as usize;
        let w = frame.camera.width as f64;
        let h = frame.camera.height as f64;
        let u0 = bbox.min[0].clamp(0.0, w) as u32;
        let v0 = bbox.min[1].clamp(0.0, h) as u32;
        let u1 = bbox.max[0].clamp(0.0, w) as u32;
        let v1 = bbox.max[1].clamp(0.0, h) as u32;
        let mut out = Vec::new();
        for v in (v0..v1).step_by(stride) {
            for u in (u0..u1).step_by(stride) {
                if let Some(d) = frame.depth.at(u, v) {
                    let d = f64::from(d);
                    if d <= self.config.max_depth_m {
                        let p_in_camera = frame.camera.unproject_pixel(u, v, d);
                        out.push(frame.world_from_camera * p_in_camera);
                    }
                }
            }
        }
        out
    }
}

fn voxel_key(p: &Point3<f64>, voxel_m: f64) -> (i64, i64, i64) {
    let s = voxel_m.max(1e-6);
    ((p.x / s).floor() as i64, (p.y / s).floor() as i64, (p.z / s).floor() as i64)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::{DepthImage, Detection};
    use crate::geometry::{PinholeCamera, Se3};
    use nalgebra::{Isometry3, UnitQuaternion};

    /// Camera 0.5 m above the origin looking straight down (OpenCV axes: z forward = world −z).
    fn top_down_pose(x: f64) -> Se3 {
        let rot = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI);
        Isometry3::from_parts(nalgebra::Translation3::new(x, 0.0, 0.5), rot)
    }

    /// Render the depth of a flat-topped block (top at z = 0.1) over a table at z = 0.
    fn render(camera: &PinholeCamera, pose: &Se3, half: f64) -> (DepthImage, Box2) {
        let mut data = vec![0.0f32; (camera.width * camera.height) as usize];
        let mut pts = Vec::new();
        for v in 0..camera.height {
            for u in 0..camera.width {
                // Ray through the pixel in world coordinates.
                let dir_c = camera.unproject_pixel(u, v, 1.0).coords;
                let dir_w = pose.rotation * dir_c;
                let origin = pose.translation.vector;
                let t_top = (0.1 - origin.z) / dir_w.z;
                let hit = origin + dir_w * t_top;
                let on_block = hit.x.abs() <= half && hit.y.abs() <= half;
                let t = if on_block { t_top } else { (0.0 - origin.z) / dir_w.z };
                data[(v * camera.width + u) as usize] = (t * 1.0) as f32; // dir_c.z = 1: t is depth
                if on_block {
                    pts.push([f64::from(u), f64::from(v)]);
                }
            }
        }
        let b = Box2::from_points(pts.iter()).unwrap_or(Box2::new(0.0, 0.0, 0.0, 0.0));
        (DepthImage::new(camera.width, camera.height, data).unwrap(), b)
    }

    #[test]
    fn block_top_is_recovered_and_tracked_across_frames() {
        let camera = PinholeCamera::from_fovy(160, 120, 0.8).unwrap();
        let mut mapper =
            NaiveMapper::new(NaiveConfig { pixel_stride: 1, trim_fraction: 0.0, ..NaiveConfig::default() });
        for (i, x) in [0.0, 0.02, 0.04].iter().enumerate() {
            let pose = top_down_pose(*x);
            let (depth, bbox) = render(&camera, &pose, 0.05);
            // Shrink the box by one pixel so no table pixel falls inside.
            let bbox = Box2::new(bbox.min[0] + 1.0, bbox.min[1] + 1.0, bbox.max[0] - 1.0, bbox.max[1] - 1.0);
            let frame = Frame {
                index: i as u32,
                camera,
                depth,
                world_from_camera: pose,
                detections: vec![Detection { bbox, label: Label::Block, score: 0.9 }],
            };
            let s = mapper.update(&frame).unwrap();
            assert_eq!(s.assigned, vec![Some(0)], "frame {i} must update object 0");
        }
        let map = mapper.map();
        assert_eq!(map.len(), 1);
        let g = map.objects[0].geometry();
        // Only the top face is seen: z = 0.1, x and y within ±5 cm (pixel quantisation ≤ 1 cm).
        assert!((g.center.z - 0.1).abs() < 1e-3, "{:?}", g.center);
        assert!(g.center.x.abs() < 0.01 && g.center.y.abs() < 0.01, "{:?}", g.center);
        assert!((g.half_extents.x - 0.05).abs() < 0.01 && (g.half_extents.y - 0.05).abs() < 0.01);
        assert_eq!(map.objects[0].observations.len(), 3);
    }

    #[test]
    fn different_label_creates_new_object_and_tiny_boxes_are_skipped() {
        let camera = PinholeCamera::from_fovy(160, 120, 0.8).unwrap();
        let pose = top_down_pose(0.0);
        let (depth, bbox) = render(&camera, &pose, 0.05);
        let frame = Frame {
            index: 0,
            camera,
            depth,
            world_from_camera: pose,
            detections: vec![
                Detection { bbox, label: Label::Block, score: 0.9 },
                Detection { bbox, label: Label::Cup, score: 0.5 },
                Detection { bbox: Box2::new(0.0, 0.0, 2.0, 2.0), label: Label::Book, score: 0.5 },
            ],
        };
        let s = mapper_update(&frame);
        assert_eq!(s.created, 2);
        assert_eq!(s.assigned[2], None);
    }

    fn mapper_update(frame: &Frame) -> UpdateSummary {
        NaiveMapper::new(NaiveConfig::default()).update(frame).unwrap()
    }

    #[test]
    fn trimmed_extent_drops_outliers() {
        let mut pts: Vec<Point3<f64>> = (0..100).map(|i| Point3::new(f64::from(i) / 100.0, 0.0, 0.0)).collect();
        pts.push(Point3::new(10.0, 0.0, 0.0));
        let (lo, hi) = trimmed_extent(&pts, 0.02).unwrap_or_default();
        assert!(hi.x < 1.0 && lo.x > 0.0);
        assert!(trimmed_extent(&[], 0.02).is_none());
    }
}
