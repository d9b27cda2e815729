//! Rerun recording of a run (feature `rerun`): one `.rrd` file per run, readable by the pinned
//! viewer (`rerun-sdk==0.36.*`, `make view`), optionally streamed live to a viewer as it goes.
//!
//! Entry point: [`Recorder`], created with [`RecordOptions`]. Every log call is stamped with the
//! current time set by [`Recorder::set_frame`] on two timelines: `frame` (sequence) and `sim_time`
//! (seconds of simulated time). Every recording carries its viewer layout ([`blueprint`]).
//!
//! Entity paths (stable: scripts and the blueprint rely on them):
//! - `world/camera` — estimated `world_from_camera` (Transform3D) + pinhole (OpenCV RDF axes);
//!   `world/camera/image/rgb` (JPEG, [`RecordOptions::jpeg_quality`]), `world/camera/image/depth`
//!   (16-bit PNG in millimetres, [`RecordOptions::depth_png`]), `world/camera/image/detections`.
//! - `world/trajectory/estimated`, `world/trajectory/ground_truth` — camera paths.
//! - `world/map/objects` — estimated objects (solid boxes coloured by class, labelled `class #id`;
//!   cylinders under `world/map/cylinders`), `world/map/points` — object point clouds.
//! - `world/ground_truth/objects` (+ `/cylinders`) — simulator truth as grey wireframes without
//!   labels, never mixed with estimates.
//! - `world/table` — the table top; `world/robot/<link>` — the arm's links ([`Recorder::log_robot_pose`]),
//!   each drawn by its URDF collision mesh at `world/robot/<link>/mesh` (logged once).
//! - `timings/<stage>_ms` — per-frame timings as scalars; `log/events` — text events.

pub mod blueprint;
mod encode;
mod robot;

use std::path::{Path, PathBuf};
use std::sync::Mutex;

use nalgebra::{Point3, UnitQuaternion};
use rerun::{RecordingStream, RecordingStreamBuilder};

pub use blueprint::TableTop;
use encode::{Encoder, Image};

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
    /// Encoding an image (JPEG colour, PNG depth) failed.
    #[error("encoding {field}: {reason}")]
    Encode {
        /// Which image.
        field: &'static str,
        /// Underlying message.
        reason: String,
    },
    /// The robot model (URDF or one of its meshes) cannot be read.
    #[error("robot model {path}: {reason}")]
    Robot {
        /// File path.
        path: String,
        /// Underlying message.
        reason: String,
    },
    /// An option is out of range.
    #[error("{field}: {reason}")]
    Option {
        /// Option name.
        field: &'static str,
        /// What is wrong.
        reason: String,
    },
}

impl RecordError {
    /// Whether the caller gave a bad value (a buffer of the wrong size, an option out of range)
    /// rather than the recording failing.
    pub fn is_input(&self) -> bool {
        matches!(self, RecordError::BufferLength { .. } | RecordError::Option { .. })
    }
}

/// JPEG quality of colour frames when not set: visually lossless on the simulator's renders at
/// about a twentieth of the raw size.
pub const DEFAULT_JPEG_QUALITY: u8 = 85;

/// What a recording stores and where it goes.
#[derive(Debug, Clone, PartialEq, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RecordOptions {
    /// JPEG quality (1-100) of colour frames, stored as encoded images; 0 stores them raw (RGB24,
    /// 0.9 MB per 640×480 frame). Default [`DEFAULT_JPEG_QUALITY`].
    pub jpeg_quality: u8,
    /// Store depth frames as lossless 16-bit PNG in millimetres (depth beyond 65.5 m or invalid
    /// becomes 0 = no return); false stores float32 metres. Default true.
    pub depth_png: bool,
    /// Also stream to a viewer's gRPC proxy at this URL while recording (e.g.
    /// `rerun+http://127.0.0.1:9876/proxy`, what `rerun --serve-web` or a native `rerun` listen
    /// on). Default none.
    pub live_url: Option<String>,
    /// The table top to draw (`world/table`) and to frame the 3D view on. Default none.
    pub table: Option<TableTop>,
    /// URDF of the arm to draw (`world/robot`): its collision meshes are logged once. Default none.
    pub robot_urdf: Option<PathBuf>,
    /// Encode and log the camera images (and log the arm's link poses) on the recorder's own
    /// thread, so that [`Recorder::log_rgb`], [`Recorder::log_depth`] and
    /// [`Recorder::log_robot_pose`] return once the data is handed over (the same bytes at the
    /// same times; [`Recorder::flush`] and drop wait for them). False: on the calling thread.
    /// Default true.
    pub encoder_thread: bool,
}

impl Default for RecordOptions {
    fn default() -> Self {
        Self {
            jpeg_quality: DEFAULT_JPEG_QUALITY,
            depth_png: true,
            live_url: None,
            table: None,
            robot_urdf: None,
            encoder_thread: true,
        }
    }
}

/// Thickness of the drawn table top, metres (the top surface is z = 0).
const TABLE_THICKNESS_M: f32 = 0.02;
/// Colour of the drawn table.
const TABLE_COLOR: [u8; 3] = [205, 190, 170];
/// Colour and line radius of ground-truth wireframes.
const GROUND_TRUTH_COLOR: [u8; 3] = [150, 150, 150];
const GROUND_TRUTH_LINE_RADIUS_M: f32 = 0.0015;
/// Root of the simulator's truth: drawn as wireframes without labels.
pub const GROUND_TRUTH_ROOT: &str = "world/ground_truth";

/// A labelled object to draw (estimate or ground truth); its JSON is an object record
/// `{"id", "label", "geometry"}` (other keys are ignored).
#[derive(Debug, Clone, serde::Deserialize)]
pub struct DrawnObject {
    /// Id shown in the label.
    pub id: u32,
    /// Class name shown in the label.
    pub label: String,
    /// Geometry.
    pub geometry: ObjectGeometry,
}

/// Writes one `.rrd` file (and optionally streams to a live viewer).
pub struct Recorder {
    stream: RecordingStream,
    options: RecordOptions,
    robot_links: Vec<String>,
    /// The time [`Recorder::set_frame`] set last, for the encoder thread.
    time: Mutex<encode::Time>,
    /// The encoder thread ([`RecordOptions::encoder_thread`]).
    encoder: Option<Encoder>,
}

fn quat(q: &UnitQuaternion<f64>) -> rerun::Quaternion {
    rerun::Quaternion::from_xyzw([q.i as f32, q.j as f32, q.k as f32, q.w as f32])
}

fn transform(t: &Se3) -> rerun::Transform3D {
    let v = t.translation.vector;
    rerun::Transform3D::from_translation_rotation([v.x as f32, v.y as f32, v.z as f32], quat(&t.rotation))
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
    /// Create a recording that streams to `path` (created or truncated) and, with
    /// [`RecordOptions::live_url`], to a viewer; sends the layout, the table and the robot model.
    pub fn create(path: &Path, application_id: &str, options: RecordOptions) -> Result<Self, RecordError> {
        let create_err = |reason: String| RecordError::Create { path: path.display().to_string(), reason };
        if options.jpeg_quality > 100 {
            return Err(RecordError::Option {
                field: "jpeg_quality",
                reason: format!("expected 0 (raw) or 1-100, got {}", options.jpeg_quality),
            });
        }
        let app = rerun::ApplicationId::try_from(application_id.to_string())
            .map_err(|e| create_err(format!("application id: {e}")))?;
        let builder = RecordingStreamBuilder::new(app);
        let stream = match &options.live_url {
            None => builder.save(path).map_err(|e| create_err(e.to_string()))?,
            Some(url) => {
                let uri: rerun::external::re_uri::ProxyUri =
                    url.parse().map_err(|e| RecordError::Option { field: "live_url", reason: format!("{e}") })?;
                let file = rerun::sink::FileSink::new(path).map_err(|e| create_err(e.to_string()))?;
                builder.set_sinks((file, rerun::sink::GrpcSink::new(uri))).map_err(|e| create_err(e.to_string()))?
            }
        };
        blueprint::send(&stream, application_id, options.table.as_ref())?;
        let encoder = match options.encoder_thread {
            true => Some(Encoder::start(stream.clone(), options.clone())?),
            false => None,
        };
        let mut rec = Self { stream, options, robot_links: Vec::new(), time: Mutex::new(None), encoder };
        rec.log_static("world", &rerun::ViewCoordinates::RIGHT_HAND_Z_UP())?;
        if let Some(t) = rec.options.table {
            let half = [0.5 * t.size[0] as f32, 0.5 * t.size[1] as f32, 0.5 * TABLE_THICKNESS_M];
            rec.log_static(
                "world/table",
                &rerun::Boxes3D::from_centers_and_half_sizes(
                    [[t.center[0] as f32, t.center[1] as f32, -0.5 * TABLE_THICKNESS_M]],
                    [half],
                )
                .with_fill_mode(rerun::FillMode::Solid)
                .with_colors([rerun::Color::from_rgb(TABLE_COLOR[0], TABLE_COLOR[1], TABLE_COLOR[2])]),
            )?;
        }
        if let Some(urdf) = rec.options.robot_urdf.clone() {
            rec.robot_links = robot::log_model(&rec, &urdf)?;
        }
        Ok(rec)
    }

    /// The options this recording was created with.
    pub fn options(&self) -> &RecordOptions {
        &self.options
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
        *self.time.lock().unwrap_or_else(|e| e.into_inner()) = Some((frame, sim_time_s));
        self.stream.set_time_sequence("frame", i64::from(frame));
        self.stream.set_duration_secs("sim_time", sim_time_s);
    }

    /// The camera: pose and intrinsics at `world/camera`.
    pub fn log_camera(&self, world_from_camera: &Se3, camera: &PinholeCamera) -> Result<(), RecordError> {
        self.log("world/camera", &transform(world_from_camera))?;
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

    /// An RGB image (row-major, 3 bytes per pixel): JPEG-encoded at
    /// [`RecordOptions::jpeg_quality`], raw when it is 0; on the encoder thread with
    /// [`RecordOptions::encoder_thread`] (an encoding error is then returned by a later call).
    pub fn log_rgb(&self, width: u32, height: u32, rgb: impl Into<Vec<u8>>) -> Result<(), RecordError> {
        let data = rgb.into();
        let expected = width as usize * height as usize * 3;
        if data.len() != expected {
            return Err(RecordError::BufferLength { field: "rgb", expected, actual: data.len() });
        }
        if self.options.jpeg_quality > 0 && (width > u32::from(u16::MAX) || height > u32::from(u16::MAX)) {
            return Err(RecordError::Encode {
                field: "rgb",
                reason: format!("{width} x {height} exceeds JPEG's 65535"),
            });
        }
        self.log_image(Image::Rgb { width, height, data })
    }

    /// A depth image in metres (row-major f32): a 16-bit millimetre PNG with
    /// [`RecordOptions::depth_png`] (non-finite, non-positive or beyond 65.535 m → 0, no return),
    /// else raw float32; on the encoder thread as [`Self::log_rgb`].
    pub fn log_depth(&self, width: u32, height: u32, depth_m: impl Into<Vec<f32>>) -> Result<(), RecordError> {
        let data = depth_m.into();
        let expected = width as usize * height as usize;
        if data.len() != expected {
            return Err(RecordError::BufferLength { field: "depth", expected, actual: data.len() });
        }
        self.log_image(Image::Depth { width, height, data })
    }

    fn log_image(&self, image: Image) -> Result<(), RecordError> {
        self.on_encoder(Box::new(move |stream, options| encode::log_image(stream, options, image)))
    }

    /// `work` on the encoder thread at the current time, or now on this thread without one.
    fn on_encoder(&self, work: encode::Work) -> Result<(), RecordError> {
        match &self.encoder {
            Some(encoder) => encoder.log(*self.time.lock().unwrap_or_else(|e| e.into_inner()), work),
            None => work(&self.stream, &self.options),
        }
    }

    /// The arm's links: `world_from_link` of each link by name, at `world/robot/<link>` (on the
    /// encoder thread with [`RecordOptions::encoder_thread`]). Links without a mesh in the model
    /// are skipped; with no model (no [`RecordOptions::robot_urdf`]) nothing is logged.
    pub fn log_robot_pose(&self, links: &[(String, Se3)]) -> Result<(), RecordError> {
        let poses: Vec<(String, rerun::Transform3D)> = links
            .iter()
            .filter(|(name, _)| self.robot_links.iter().any(|l| l == name))
            .map(|(name, world_from_link)| (format!("world/robot/{name}"), transform(world_from_link)))
            .collect();
        if poses.is_empty() {
            return Ok(());
        }
        self.on_encoder(Box::new(move |stream, _| {
            for (entity, pose) in &poses {
                stream
                    .log(entity.as_str(), pose)
                    .map_err(|e| RecordError::Log { entity: entity.clone(), reason: e.to_string() })?;
            }
            Ok(())
        }))
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

    /// Objects as boxes and cylinders under `root` (`world/map` or [`GROUND_TRUTH_ROOT`]).
    /// Estimates are solid, coloured by class and labelled `class #id`; the ground truth is a grey
    /// wireframe without labels, so the two never look alike and only one label marks an object.
    pub fn log_objects(&self, root: &str, objects: &[DrawnObject]) -> Result<(), RecordError> {
        let truth = root == GROUND_TRUTH_ROOT;
        let (cubes, cyls): (Vec<&DrawnObject>, Vec<&DrawnObject>) =
            objects.iter().partition(|o| o.geometry.shape == Shape::Cuboid);
        let centers =
            |v: &[&DrawnObject]| -> Vec<[f32; 3]> { v.iter().map(|o| v3(&Point3::from(o.geometry.center))).collect() };
        let labels =
            |v: &[&DrawnObject]| -> Vec<String> { v.iter().map(|o| format!("{} #{}", o.label, o.id)).collect() };
        let colors = |v: &[&DrawnObject]| -> Vec<rerun::Color> {
            v.iter()
                .map(|o| {
                    if truth {
                        let [r, g, b] = GROUND_TRUTH_COLOR;
                        rerun::Color::from_rgb(r, g, b)
                    } else {
                        class_color(&o.label)
                    }
                })
                .collect()
        };
        let (fill, radius) = if truth {
            (rerun::FillMode::MajorWireframe, GROUND_TRUTH_LINE_RADIUS_M)
        } else {
            (rerun::FillMode::Solid, 0.0)
        };
        let half: Vec<[f32; 3]> = cubes
            .iter()
            .map(|o| {
                let h = o.geometry.half_extents;
                [h.x as f32, h.y as f32, h.z as f32]
            })
            .collect();
        let rotations: Vec<rerun::Quaternion> =
            cubes.iter().map(|o| quat(&UnitQuaternion::from_euler_angles(0.0, 0.0, o.geometry.yaw_rad))).collect();
        let mut boxes = rerun::Boxes3D::from_centers_and_half_sizes(centers(&cubes), half)
            .with_quaternions(rotations)
            .with_colors(colors(&cubes))
            .with_fill_mode(fill)
            .with_labels(labels(&cubes))
            .with_show_labels(!truth);
        if truth {
            boxes = boxes.with_radii([radius]);
        }
        self.log(&format!("{root}/objects"), &boxes)?;
        let lengths: Vec<f32> = cyls.iter().map(|o| (2.0 * o.geometry.half_extents.z) as f32).collect();
        let radii: Vec<f32> = cyls.iter().map(|o| o.geometry.radius() as f32).collect();
        let mut cylinders = rerun::Cylinders3D::from_lengths_and_radii(lengths, radii)
            .with_centers(centers(&cyls))
            .with_colors(colors(&cyls))
            .with_fill_mode(fill)
            .with_labels(labels(&cyls))
            .with_show_labels(!truth);
        if truth {
            cylinders = cylinders.with_line_radii([radius]);
        }
        self.log(&format!("{root}/cylinders"), &cylinders)
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

    /// Flush everything to disk, the images handed to the encoder thread first (also done on
    /// drop); the first error of the encoder thread, if any.
    pub fn flush(&self) -> Result<(), RecordError> {
        let encoded = self.encoder.as_ref().map_or(Ok(()), Encoder::finish);
        self.stream
            .flush_blocking()
            .map_err(|e| RecordError::Log { entity: "<flush>".into(), reason: e.to_string() })?;
        encoded
    }
}

#[cfg(test)]
mod report_tests {
    use super::*;

    #[test]
    fn drawn_objects_read_object_records_and_input_errors_are_told_apart() {
        let json = r#"[{"id": 4, "label": "cup", "n_observations": 2,
            "geometry": {"shape": "cylinder", "center": [0.1, 0.2, 0.05], "yaw_rad": 0.0, "half_extents": [0.04, 0.04, 0.05]}}]"#;
        let objects: Vec<DrawnObject> = serde_json::from_str(json).unwrap();
        assert_eq!((objects[0].id, objects[0].label.as_str()), (4, "cup"));
        assert!(RecordError::Option { field: "jpeg_quality", reason: "r".into() }.is_input());
        assert!(!RecordError::Log { entity: "e".into(), reason: "r".into() }.is_input());
    }
}

#[cfg(test)]
mod tests {
    use super::encode::depth_png_mm;
    use super::*;
    use crate::geometry::{Box2, Shape};
    use crate::map::Label;
    use nalgebra::Vector3;

    fn temp_dir(tag: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("objslam-record-{tag}-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    fn record_frames(path: &Path, options: RecordOptions) -> u64 {
        {
            let rec = Recorder::create(path, "objslam-test", options).unwrap();
            let cam = PinholeCamera::from_fovy(64, 48, 1.0).unwrap();
            // A textured image and a tilted plane with noise, changing from frame to frame: what a
            // camera sees of a table (the file's own compression finds little to share).
            let noise = |i: u32, f: u32| (i.wrapping_mul(2_654_435_761) ^ f.wrapping_mul(40_503)) >> 29;
            for f in 0..20u32 {
                let rgb: Vec<u8> = (0..64 * 48u32)
                    .flat_map(|i| {
                        [(i % 64 * 3 + noise(i, f)) as u8, (i / 64 * 4 + f) as u8, 90 + noise(i, f + 7) as u8]
                    })
                    .collect();
                let depth: Vec<f32> =
                    (0..64 * 48u32).map(|i| 0.6 + 0.002 * (i / 64) as f32 + 0.0004 * noise(i, f) as f32).collect();
                rec.set_frame(f, 0.25 * f64::from(f));
                rec.log_camera(&Se3::identity(), &cam).unwrap();
                rec.log_rgb(64, 48, rgb).unwrap();
                rec.log_depth(64, 48, depth).unwrap();
            }
            rec.flush().unwrap();
        }
        std::fs::metadata(path).map(|m| m.len()).unwrap_or(0)
    }

    #[test]
    fn writes_a_nonempty_rrd() {
        let dir = temp_dir("basic");
        let path = dir.join("t.rrd");
        {
            let table = TableTop { center: [0.5, 0.0], size: [0.8, 1.0] };
            let rec =
                Recorder::create(&path, "objslam-test", RecordOptions { table: Some(table), ..Default::default() })
                    .unwrap();
            let cam = PinholeCamera::from_fovy(8, 6, 1.0).unwrap();
            rec.set_frame(0, 0.0);
            rec.log_camera(&Se3::identity(), &cam).unwrap();
            rec.log_rgb(8, 6, [128u8; 8 * 6 * 3].as_slice()).unwrap();
            rec.log_depth(8, 6, [0.5f32; 48].as_slice()).unwrap();
            assert!(matches!(rec.log_depth(8, 6, [0.5f32; 47].as_slice()), Err(RecordError::BufferLength { .. })));
            rec.log_detections(&[Detection { bbox: Box2::new(1.0, 1.0, 4.0, 4.0), label: Label::Cup, score: 0.9 }])
                .unwrap();
            let g = ObjectGeometry {
                shape: Shape::Cylinder,
                center: Vector3::new(0.5, 0.0, 0.05),
                yaw_rad: 0.0,
                half_extents: Vector3::new(0.03, 0.03, 0.05),
            };
            let b = ObjectGeometry { shape: Shape::Cuboid, yaw_rad: 0.4, ..g };
            let objects = [
                DrawnObject { id: 0, label: "cup".into(), geometry: g },
                DrawnObject { id: 1, label: "block".into(), geometry: b },
            ];
            rec.log_objects("world/map", &objects).unwrap();
            rec.log_objects(GROUND_TRUTH_ROOT, &objects).unwrap();
            rec.log_trajectory("estimated", &[Point3::origin(), Point3::new(0.1, 0.0, 0.5)]).unwrap();
            rec.log_scalar("timings/render_ms", 70.0).unwrap();
            rec.log_event("done").unwrap();
            rec.flush().unwrap();
        }
        let len = std::fs::metadata(&path).map(|m| m.len()).unwrap_or(0);
        assert!(len > 1000, "rrd has {len} bytes");
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn encoded_frames_are_smaller_than_raw_ones() {
        let dir = temp_dir("size");
        let raw = record_frames(
            &dir.join("raw.rrd"),
            RecordOptions { jpeg_quality: 0, depth_png: false, ..Default::default() },
        );
        let encoded = record_frames(&dir.join("enc.rrd"), RecordOptions::default());
        // 20 frames of 64×48: 184 kB of raw colour and 246 kB of raw depth (the file's compression
        // finds little in the noisy frames); each frame's camera and metadata weigh the same in both.
        assert!(raw > 20 * 64 * 48 * 3, "raw recording has {raw} bytes");
        assert!(encoded * 2 < raw, "encoded {encoded} bytes vs raw {raw}");
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn depth_png_round_trips_in_millimetres() {
        let depth = [0.0f32, 0.4567, 1.0, f32::NAN, -1.0, 70.0, 2.5, 0.0011];
        let png = depth_png_mm(4, 2, &depth).unwrap();
        let img = image::load_from_memory(&png).unwrap().into_luma16();
        let got: Vec<u16> = img.pixels().map(|p| p.0[0]).collect();
        assert_eq!(got, vec![0, 457, 1000, 0, 0, 0, 2500, 1]);
    }

    #[test]
    fn bad_jpeg_quality_is_a_named_error() {
        let dir = temp_dir("quality");
        let r = Recorder::create(
            &dir.join("q.rrd"),
            "objslam-test",
            RecordOptions { jpeg_quality: 101, ..Default::default() },
        );
        assert!(matches!(r, Err(RecordError::Option { field: "jpeg_quality", .. })));
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn robot_model_logs_the_links_with_meshes() {
        let dir = temp_dir("robot");
        // A one-triangle ASCII STL and a URDF with one meshed link and one empty link.
        std::fs::write(
            dir.join("tri.stl"),
            "solid t\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nvertex 0 1 0\nendloop\nendfacet\nendsolid t\n",
        )
        .unwrap();
        let urdf = dir.join("r.urdf");
        std::fs::write(
            &urdf,
            r#"<robot name="r"><link name="base"><collision><origin xyz="0 0 0.1" rpy="0 0 0"/>
<geometry><mesh filename="tri.stl"/></geometry></collision></link><link name="tip"/>
<joint name="j" type="fixed"><parent link="base"/><child link="tip"/></joint></robot>"#,
        )
        .unwrap();
        let rec = Recorder::create(
            &dir.join("r.rrd"),
            "objslam-test",
            RecordOptions { robot_urdf: Some(urdf), ..Default::default() },
        )
        .unwrap();
        assert_eq!(rec.robot_links, vec!["base".to_string()]);
        rec.log_robot_pose(&[("base".into(), Se3::identity()), ("tip".into(), Se3::identity())]).unwrap();
        let missing = Recorder::create(
            &dir.join("m.rrd"),
            "objslam-test",
            RecordOptions { robot_urdf: Some(dir.join("none.urdf")), ..Default::default() },
        );
        assert!(matches!(missing, Err(RecordError::Robot { .. })));
        let _ = std::fs::remove_dir_all(&dir);
    }
}
