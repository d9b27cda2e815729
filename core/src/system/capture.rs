//! Recorded system inputs of one episode (`experiments/capture.py`), replayed through [`System`]
//! by the integration test and `cargo run --example slam_replay`.
//!
//! A capture is a folder:
//! - `system.json`: `{"mapper_config", "active_config", "tracker_config" (or null), "table":
//!   [centre x, centre y, size x, size y], "ground_truth": [GtObject, ...]}`; the configs are the
//!   episode's own, as the core's serde structs read them.
//! - `events.jsonl`: one event per line, in the episode's order: `{"event": "frame", "index",
//!   "view_index", "width", "height", "intrinsics" (3x3 row-major), "world_from_camera_prior" and
//!   "world_from_camera_gt" (4x4 row-major), "detections": [[u0, v0, u1, v1, label, score], ...]}`
//!   or `{"event": "view_done", "counts_as_view": bool}`.
//! - `grey_<index>.u8.gz` (H·W bytes) and `depth_<index>.f32.gz` (H·W little-endian float32
//!   metres), gzip-compressed.

use std::io::Read;
use std::path::{Path, PathBuf};

use nalgebra::{Matrix3, Matrix4};
use serde::Deserialize;
use thiserror::Error;

use super::{FrameInput, System, SystemError};
use crate::active::ActiveConfig;
use crate::eval::GtObject;
use crate::explore::TableRect;
use crate::frame::{DepthImage, Detection, Frame, GreyImage};
use crate::geometry::{se3_from_matrix, Box2, PinholeCamera, Se3};
use crate::map::Label;
use crate::pipeline::PipelineConfig;
use crate::slam::TrackerConfig;

/// Errors reading or replaying a capture.
#[derive(Debug, Error)]
pub enum CaptureError {
    /// A file could not be read.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// A file is not the JSON the format says.
    #[error("{path}: {source}")]
    Json {
        /// The file (with the line for `events.jsonl`).
        path: String,
        /// The cause.
        source: serde_json::Error,
    },
    /// A value is out of range or inconsistent.
    #[error("{field}: {reason}")]
    Invalid {
        /// Where.
        field: String,
        /// What is wrong.
        reason: String,
    },
    /// The system refused an input.
    #[error(transparent)]
    System(#[from] SystemError),
}

/// `system.json`.
#[derive(Debug, Clone, Deserialize)]
pub struct CaptureHeader {
    /// The object pipeline's config.
    pub mapper_config: PipelineConfig,
    /// The exploration session's config.
    pub active_config: ActiveConfig,
    /// The tracker's config (None: frames mapped at their prior pose).
    pub tracker_config: Option<TrackerConfig>,
    /// Table top: centre x, centre y, size x, size y (metres, top at z = 0).
    pub table: [f64; 4],
    /// The scene's objects, for judging the replayed map only.
    pub ground_truth: Vec<GtObject>,
}

/// One event of `events.jsonl`.
#[derive(Debug, Clone, Deserialize)]
#[serde(tag = "event", rename_all = "snake_case")]
pub enum CaptureEvent {
    /// A frame.
    Frame(Box<CapturedFrame>),
    /// A view was reached and its frames fused.
    ViewDone {
        /// False for Init views.
        counts_as_view: bool,
    },
}

/// A frame's metadata; its images are in the folder.
#[derive(Debug, Clone, Deserialize)]
pub struct CapturedFrame {
    /// Frame index (names the image files).
    pub index: u32,
    /// View (arm configuration) index.
    pub view_index: u64,
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// 3x3 intrinsics, row-major.
    pub intrinsics: [f64; 9],
    /// The kinematic prior of the camera pose, 4x4 row-major.
    pub world_from_camera_prior: [f64; 16],
    /// The true camera pose, 4x4 row-major (pose metrics only).
    pub world_from_camera_gt: [f64; 16],
    /// Detections: u0, v0, u1, v1, label, score.
    pub detections: Vec<(f64, f64, f64, f64, String, f64)>,
}

/// A capture folder.
#[derive(Debug, Clone)]
pub struct Capture {
    /// The folder.
    pub dir: PathBuf,
    /// `system.json`.
    pub header: CaptureHeader,
    /// `events.jsonl`.
    pub events: Vec<CaptureEvent>,
}

fn read_gz(path: &Path) -> Result<Vec<u8>, CaptureError> {
    let file = std::fs::File::open(path).map_err(|source| CaptureError::Io { path: path.to_path_buf(), source })?;
    let mut out = Vec::new();
    flate2::read::GzDecoder::new(file)
        .read_to_end(&mut out)
        .map_err(|source| CaptureError::Io { path: path.to_path_buf(), source })?;
    Ok(out)
}

impl CapturedFrame {
    /// The camera's true pose (`world_from_camera_gt`): for judging, and for the ground-truth
    /// pose-source ablation only.
    pub fn true_pose(&self) -> Result<Se3, CaptureError> {
        se3_from_matrix(&Matrix4::from_row_slice(&self.world_from_camera_gt), "gt").map_err(|e| CaptureError::Invalid {
            field: format!("frame {}: world_from_camera_gt", self.index),
            reason: e.to_string(),
        })
    }
}

impl Capture {
    /// Read `system.json` and `events.jsonl` of `dir` (images are read per frame).
    pub fn open(dir: &Path) -> Result<Self, CaptureError> {
        let read = |name: &str| {
            let path = dir.join(name);
            std::fs::read_to_string(&path).map_err(|source| CaptureError::Io { path, source })
        };
        let header: CaptureHeader = serde_json::from_str(&read("system.json")?)
            .map_err(|source| CaptureError::Json { path: "system.json".into(), source })?;
        let events = read("events.jsonl")?
            .lines()
            .enumerate()
            .filter(|(_, l)| !l.trim().is_empty())
            .map(|(i, l)| {
                serde_json::from_str(l)
                    .map_err(|source| CaptureError::Json { path: format!("events.jsonl line {}", i + 1), source })
            })
            .collect::<Result<Vec<_>, _>>()?;
        Ok(Self { dir: dir.to_path_buf(), header, events })
    }

    /// A fresh system with the capture's configs.
    pub fn system(&self) -> Result<System, CaptureError> {
        self.system_with(self.header.mapper_config.clone())
    }

    /// A fresh system with the capture's exploration and tracker configs and `mapper_config`.
    pub fn system_with(&self, mapper_config: PipelineConfig) -> Result<System, CaptureError> {
        let [cx, cy, sx, sy] = self.header.table;
        let table = TableRect { center_m: [cx, cy], size_m: [sx, sy], height_m: 0.0 };
        Ok(System::new(mapper_config, self.header.active_config.clone(), self.header.tracker_config, table)?)
    }

    /// A frame's grey image, depth and core frame (its true pose: [`CapturedFrame::true_pose`]).
    pub fn load_frame(&self, f: &CapturedFrame) -> Result<(Frame, GreyImage), CaptureError> {
        let invalid = |field: &str, reason: String| CaptureError::Invalid {
            field: format!("frame {}: {field}", f.index),
            reason,
        };
        let grey = GreyImage::new(f.width, f.height, read_gz(&self.dir.join(format!("grey_{}.u8.gz", f.index)))?)
            .map_err(|e| invalid("grey", e.to_string()))?;
        let raw = read_gz(&self.dir.join(format!("depth_{}.f32.gz", f.index)))?;
        let depth = DepthImage::new(
            f.width,
            f.height,
            raw.chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect(),
        )
        .map_err(|e| invalid("depth", e.to_string()))?;
        let camera = PinholeCamera::from_matrix(f.width, f.height, &Matrix3::from_row_slice(&f.intrinsics))
            .map_err(|e| invalid("intrinsics", e.to_string()))?;
        let world_from_camera = se3_from_matrix(&Matrix4::from_row_slice(&f.world_from_camera_prior), "prior")
            .map_err(|e| invalid("world_from_camera_prior", e.to_string()))?;
        let detections = f
            .detections
            .iter()
            .enumerate()
            .map(|(i, (u0, v0, u1, v1, label, score))| {
                let label =
                    Label::parse(label).map_err(|e| invalid(&format!("detections[{i}].label"), e.to_string()))?;
                Ok(Detection { bbox: Box2::new(*u0, *v0, *u1, *v1), label, score: *score })
            })
            .collect::<Result<Vec<_>, CaptureError>>()?;
        Ok((Frame { index: f.index, camera, world_from_camera, depth, detections }, grey))
    }

    /// Replay every event through `system`; returns the number of frames processed.
    pub fn replay(&self, system: &mut System) -> Result<usize, CaptureError> {
        let mut frames = 0;
        for event in &self.events {
            match event {
                CaptureEvent::Frame(f) => {
                    let (frame, grey) = self.load_frame(f)?;
                    let gt = f.true_pose()?;
                    system.process_frame(FrameInput {
                        frame,
                        grey: Some(&grey),
                        view_index: f.view_index,
                        world_from_camera_gt: Some(gt),
                    })?;
                    frames += 1;
                }
                CaptureEvent::ViewDone { counts_as_view } => system.view_done(*counts_as_view),
            }
        }
        Ok(frames)
    }
}
