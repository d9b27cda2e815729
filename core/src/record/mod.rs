//! Rerun recording of a run (feature `rerun`): one `.rrd` file per run, readable by the pinned
//! viewer (`rerun-sdk==0.36.*`, `make view`).
//!
//! Entry point: [`Recorder`]. Every log call is stamped with the current time set by
//! [`Recorder::set_frame`] on two timelines: `frame` (sequence) and `sim_time` (seconds of
//! simulated time).
//!
//! Entity paths (stable: scripts and blueprints rely on them):
//! - `world/camera` — estimated `world_from_camera` (Transform3D) + pinhole (OpenCV RDF axes);
//!   `world/camera/image/rgb`, `world/camera/image/depth`, `world/camera/image/detections`.
//! - `world/trajectory/estimated`, `world/trajectory/ground_truth` — camera paths.
//! - `world/map/objects` — estimated objects (boxes; cylinders under `world/map/cylinders`),
//!   `world/map/points` — object point clouds.
//! - `world/ground_truth/objects` (+ `/cylinders`) — simulator truth, never mixed with estimates.
//! - `timings/<stage>_ms` — per-frame timings as scalars; `log/events` — text events.

use std::path::Path;

use nalgebra::{Point3, UnitQuaternion};
use rerun::{RecordingStream, RecordingStreamBuilder};

use crate::frame::Detection;
use crate::geometry::{ObjectGeometry, PinholeCamera, Se3, Shape};

/// Errors of the recorder.
#[derive(Debug, thiserror::Error)]
pub enum RecordError {
    /// Creating the file sink failed.
    #[error("cannot create recording {path}: {reason}")]
    Create {
        /// File path.
        path: String,
        /// Underlying message.
        reason: String,
    },
    /// Logging failed.
    #[error("recording {entity}: {reason}")]
    Log {
        /// Entity path.
        entity: String,
        /// Underlying message.
        reason: String,
    },
    /// An image buffer has the wrong size.
    #[error("{field}: buffer has {actual} values, expected {expected}")]
    BufferLength {
        /// Which buffer.
        field: &'static str,
        /// Expected length.
        expected: usize,
        /// Actual length.
        actual: usize,
    },
}

/// A labelled object to draw (estimate or ground truth).
#[derive(Debug, Clone)]
pub struct DrawnObject {
    /// Id shown in the label.
    pub id: u32,
    /// Class name shown in the label.
    pub label: String,
    /// Geometry.
    pub geometry: ObjectGeometry,
}

/// Writes one `.rrd` file.
pub struct Recorder {
    stream: RecordingStream,
}

fn quat(q: &UnitQuaternion<f64>) -> rerun::Quaternion {
    rerun::Quaternion::from_xyzw([q.i as f32, q.j as f32, q.k as f32, q.w as f32])
}

fn v3(p: &Point3<f64>) -> [f32; 3] {
    [p.x as f32, p.y as f32, p.z as f32]
}

/// A stable colour per class id (tab10-like palette).
fn class_color(key: &str) -> rerun::Color {
    const PALETTE: [[u8; 3]; 10] = [
        [31, 119, 180],
        [255, 127, 14],
        [44, 160, 44],
        [214, 39, 40],
        [148, 103, 189],
        [140, 86, 75],
        [227, 119, 194],
        [127, 127, 127],
        [188, 189, 34],
        [23, 190, 207],
    ];
    let h = key.bytes().fold(7u32, |h, b| h.wrapping_mul(31).wrapping_add(u32::from(b)));
    let c = PALETTE[(h % PALETTE.len() as u32) as usize];
    rerun::Color::from_rgb(c[0], c[1], c[2])
}

impl Recorder {
    /// Create a recording that streams to `path` (created or truncated).
    pub fn create(path: &Path, application_id: &str) -> Result<Self, RecordError> {
        let app = rerun::ApplicationId::try_from(application_id.to_string()).map_err(|e| RecordError::Create {
            path: path.display().to_string(),
            reason: format!("application id: {e}"),
        })?;
        let stream = RecordingStreamBuilder::new(app)
            .save(path)
            .map_err(|e| RecordError::Create { path: path.display().to_string(), reason: e.to_string() })?;
        let rec = Self { stream };
        rec.log_static("world", &rerun::ViewCoordinates::RIGHT_HAND_Z_UP())?;
        Ok(rec)
    }

    fn log<AS: ?Sized + rerun::AsComponents>(&self, entity: &str, value: &AS) -> Result<(), RecordError> {
        self.stream.log(entity, value).map_err(|e| RecordError::Log { entity: entity.into(), reason: e.to_string() })
    }

    fn log_static<AS: ?Sized + rerun::AsComponents>(&self, entity: &str, value: &AS) -> Result<(), RecordError> {
        self.stream
            .log_static(entity, value)
            .map_err(|e| RecordError::Log { entity: entity.into(), reason: e.to_string() })
    }

    /// Set the time of subsequent logs: frame index and simulated seconds.
    pub fn set_frame(&self, frame: u32, sim_time_s: f64) {
        self.stream.set_time_sequence("frame", i64::from(frame));
        self.stream.set_duration_secs("sim_time", sim_time_s);
    }

    /// The camera: pose and intrinsics at `world/camera`.
    pub fn log_camera(&self, world_from_camera: &Se3, camera: &PinholeCamera) -> Result<(), RecordError> {
        let t = world_from_camera.translation.vector;
        self.log(
            "world/camera",
            &rerun::Transform3D::from_translation_rotation(
                [t.x as f32, t.y as f32, t.z as f32],
                quat(&world_from_camera.rotation),
            ),
        )?;
        self.log(
            "world/camera/image",
            &rerun::Pinhole::from_focal_length_and_resolution(
                [camera.fx as f32, camera.fy as f32],
                [camera.width as f32, camera.height as f32],
            )
            .with_principal_point([camera.cx as f32, camera.cy as f32])
            .with_camera_xyz(rerun::components::ViewCoordinates::RDF)
            .with_image_plane_distance(0.1),
        )
    }

    /// An RGB image (row-major, 3 bytes per pixel).
    pub fn log_rgb(&self, width: u32, height: u32, rgb: &[u8]) -> Result<(), RecordError> {
        let expected = width as usize * height as usize * 3;
        if rgb.len() != expected {
            return Err(RecordError::BufferLength { field: "rgb", expected, actual: rgb.len() });
        }
        self.log("world/camera/image/rgb", &rerun::Image::from_rgb24(rgb.to_vec(), [width, height]))
    }

    /// A depth image in metres (row-major f32).
    pub fn log_depth(&self, width: u32, height: u32, depth_m: &[f32]) -> Result<(), RecordError> {
        let expected = width as usize * height as usize;
        if depth_m.len() != expected {
            return Err(RecordError::BufferLength { field: "depth", expected, actual: depth_m.len() });
        }
        let bytes: Vec<u8> = depth_m.iter().flat_map(|d| d.to_le_bytes()).collect();
        self.log(
            "world/camera/image/depth",
            &rerun::DepthImage::from_data_type_and_bytes(bytes, [width, height], rerun::ChannelDatatype::F32)
                .with_meter(1.0),
        )
    }

    /// Detections as labelled 2D boxes over the image.
    pub fn log_detections(&self, detections: &[Detection]) -> Result<(), RecordError> {
        let mins: Vec<[f32; 2]> = detections.iter().map(|d| [d.bbox.min[0] as f32, d.bbox.min[1] as f32]).collect();
        let sizes: Vec<[f32; 2]> = detections.iter().map(|d| [d.bbox.width() as f32, d.bbox.height() as f32]).collect();
        let labels: Vec<String> = detections.iter().map(|d| format!("{} {:.2}", d.label, d.score)).collect();
        let colors: Vec<rerun::Color> = detections.iter().map(|d| class_color(d.label.as_str())).collect();
        self.log(
            "world/camera/image/detections",
            &rerun::Boxes2D::from_mins_and_sizes(mins, sizes).with_labels(labels).with_colors(colors),
        )
    }

    /// A camera path as a line strip (`which` = "estimated" or "ground_truth").
    pub fn log_trajectory(&self, which: &str, positions: &[Point3<f64>]) -> Result<(), RecordError> {
        let strip: Vec<[f32; 3]> = positions.iter().map(v3).collect();
        let color = if which == "ground_truth" {
            rerun::Color::from_rgb(40, 200, 40)
        } else {
            rerun::Color::from_rgb(230, 80, 30)
        };
        self.log(&format!("world/trajectory/{which}"), &rerun::LineStrips3D::new([strip]).with_colors([color]))
    }

    /// Objects as boxes and cylinders under `root` (`world/map` or `world/ground_truth`).
    pub fn log_objects(&self, root: &str, objects: &[DrawnObject]) -> Result<(), RecordError> {
        let (cubes, cyls): (Vec<&DrawnObject>, Vec<&DrawnObject>) =
            objects.iter().partition(|o| o.geometry.shape == Shape::Cuboid);
        let centers =
            |v: &[&DrawnObject]| -> Vec<[f32; 3]> { v.iter().map(|o| v3(&Point3::from(o.geometry.center))).collect() };
        let labels =
            |v: &[&DrawnObject]| -> Vec<String> { v.iter().map(|o| format!("{} #{}", o.label, o.id)).collect() };
        let colors = |v: &[&DrawnObject]| -> Vec<rerun::Color> { v.iter().map(|o| class_color(&o.label)).collect() };
        let half: Vec<[f32; 3]> = cubes
            .iter()
            .map(|o| {
                let h = o.geometry.half_extents;
                [h.x as f32, h.y as f32, h.z as f32]
            })
            .collect();
        let rotations: Vec<rerun::Quaternion> =
            cubes.iter().map(|o| quat(&UnitQuaternion::from_euler_angles(0.0, 0.0, o.geometry.yaw_rad))).collect();
        self.log(
            &format!("{root}/objects"),
            &rerun::Boxes3D::from_centers_and_half_sizes(centers(&cubes), half)
                .with_quaternions(rotations)
                .with_labels(labels(&cubes))
                .with_colors(colors(&cubes)),
        )?;
        let lengths: Vec<f32> = cyls.iter().map(|o| (2.0 * o.geometry.half_extents.z) as f32).collect();
        let radii: Vec<f32> = cyls.iter().map(|o| o.geometry.radius() as f32).collect();
        self.log(
            &format!("{root}/cylinders"),
            &rerun::Cylinders3D::from_lengths_and_radii(lengths, radii)
                .with_centers(centers(&cyls))
                .with_labels(labels(&cyls))
                .with_colors(colors(&cyls)),
        )
    }

    /// A point cloud under `entity`, one colour per point group key.
    pub fn log_points(&self, entity: &str, points: &[Point3<f64>], group_keys: &[String]) -> Result<(), RecordError> {
        let positions: Vec<[f32; 3]> = points.iter().map(v3).collect();
        let mut arch = rerun::Points3D::new(positions).with_radii([0.002f32]);
        if group_keys.len() == points.len() {
            arch = arch.with_colors(group_keys.iter().map(|k| class_color(k)).collect::<Vec<_>>());
        }
        self.log(entity, &arch)
    }

    /// Points with explicit RGB colours (e.g. grid cells coloured by state).
    pub fn log_colored_points(
        &self,
        entity: &str,
        points: &[Point3<f64>],
        colors: &[[u8; 3]],
        radius_m: f32,
    ) -> Result<(), RecordError> {
        if colors.len() != points.len() {
            return Err(RecordError::BufferLength { field: "colors", expected: points.len(), actual: colors.len() });
        }
        let positions: Vec<[f32; 3]> = points.iter().map(v3).collect();
        let colors: Vec<rerun::Color> = colors.iter().map(|c| rerun::Color::from_rgb(c[0], c[1], c[2])).collect();
        self.log(entity, &rerun::Points3D::new(positions).with_colors(colors).with_radii([radius_m]))
    }

    /// Arrows (e.g. candidate views: origin = camera centre, vector = viewing direction).
    pub fn log_arrows(
        &self,
        entity: &str,
        origins: &[Point3<f64>],
        vectors: &[nalgebra::Vector3<f64>],
        colors: &[[u8; 3]],
    ) -> Result<(), RecordError> {
        if vectors.len() != origins.len() || colors.len() != origins.len() {
            return Err(RecordError::BufferLength {
                field: "vectors/colors",
                expected: origins.len(),
                actual: vectors.len().min(colors.len()),
            });
        }
        let o: Vec<[f32; 3]> = origins.iter().map(v3).collect();
        let v: Vec<[f32; 3]> = vectors.iter().map(|d| [d.x as f32, d.y as f32, d.z as f32]).collect();
        let c: Vec<rerun::Color> = colors.iter().map(|c| rerun::Color::from_rgb(c[0], c[1], c[2])).collect();
        self.log(entity, &rerun::Arrows3D::from_vectors(v).with_origins(o).with_colors(c))
    }

    /// A scalar time series value (e.g. `timings/render_ms`).
    pub fn log_scalar(&self, entity: &str, value: f64) -> Result<(), RecordError> {
        self.log(entity, &rerun::Scalars::single(value))
    }

    /// A text event in `log/events`.
    pub fn log_event(&self, text: &str) -> Result<(), RecordError> {
        self.log("log/events", &rerun::TextLog::new(text))
    }

    /// Flush everything to disk (also done on drop).
    pub fn flush(&self) -> Result<(), RecordError> {
        self.stream.flush_blocking().map_err(|e| RecordError::Log { entity: "<flush>".into(), reason: e.to_string() })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{Box2, Shape};
    use crate::map::Label;
    use nalgebra::Vector3;

    #[test]
    fn writes_a_nonempty_rrd() {
        let dir = std::env::temp_dir().join(format!("objslam-record-test-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap_or_else(|e| panic!("{e}"));
        let path = dir.join("t.rrd");
        {
            let rec = Recorder::create(&path, "objslam-test").unwrap_or_else(|e| panic!("{e}"));
            let cam = PinholeCamera::from_fovy(8, 6, 1.0).unwrap_or_else(|e| panic!("{e}"));
            rec.set_frame(0, 0.0);
            rec.log_camera(&Se3::identity(), &cam).unwrap_or_else(|e| panic!("{e}"));
            rec.log_rgb(8, 6, &[128u8; 8 * 6 * 3]).unwrap_or_else(|e| panic!("{e}"));
            rec.log_depth(8, 6, &[0.5f32; 48]).unwrap_or_else(|e| panic!("{e}"));
            assert!(matches!(rec.log_depth(8, 6, &[0.5f32; 47]), Err(RecordError::BufferLength { .. })));
            rec.log_detections(&[Detection { bbox: Box2::new(1.0, 1.0, 4.0, 4.0), label: Label::Cup, score: 0.9 }])
                .unwrap_or_else(|e| panic!("{e}"));
            let g = ObjectGeometry {
                shape: Shape::Cylinder,
                center: Vector3::new(0.5, 0.0, 0.05),
                yaw_rad: 0.0,
                half_extents: Vector3::new(0.03, 0.03, 0.05),
            };
            let b = ObjectGeometry { shape: Shape::Cuboid, yaw_rad: 0.4, ..g };
            rec.log_objects(
                "world/map",
                &[
                    DrawnObject { id: 0, label: "cup".into(), geometry: g },
                    DrawnObject { id: 1, label: "block".into(), geometry: b },
                ],
            )
            .unwrap_or_else(|e| panic!("{e}"));
            rec.log_trajectory("estimated", &[Point3::origin(), Point3::new(0.1, 0.0, 0.5)])
                .unwrap_or_else(|e| panic!("{e}"));
            rec.log_scalar("timings/render_ms", 70.0).unwrap_or_else(|e| panic!("{e}"));
            rec.log_event("done").unwrap_or_else(|e| panic!("{e}"));
            rec.flush().unwrap_or_else(|e| panic!("{e}"));
        }
        let len = std::fs::metadata(&path).map(|m| m.len()).unwrap_or(0);
        assert!(len > 1000, "rrd has {len} bytes");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
