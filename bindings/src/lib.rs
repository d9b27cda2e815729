//! Thin pyo3 layer over `objslam-core`, built by maturin as the private module `objslam._native`.
//!
//! Rules: numpy arrays in, validated here (dtype, shape, finiteness, element count against
//! [`MAX_ARRAY_ELEMENTS`] before anything is copied, so a broadcast view of a huge shape is refused
//! instead of copied) with errors that name the argument; every core error maps to a specific
//! Python exception; no panic crosses into Python (core code has no unwrap, and these wrappers
//! only return `PyResult`). Complex structured values (maps, evaluations, configs) cross as JSON
//! strings, read with [`parse_json`] so errors name the field's path.

use nalgebra::{Matrix3, Matrix4, Point3};
use numpy::{PyReadonlyArray2, PyReadonlyArray3};
use objslam_core::eval::{config_from_json, estimates_from_map, evaluate, ground_truth_from_json, EvalConfig};
use objslam_core::frame::{DepthImage, Detection, Frame, FrameError};
use objslam_core::geometry::{se3_from_matrix, Box2, GeometryError, ObjectGeometry, PinholeCamera, Se3};
use objslam_core::map::{Label, MapError, ObjectMap};
use objslam_core::naive::{NaiveConfig, NaiveMapper};
use objslam_core::record::{DrawnObject, RecordError, RecordOptions, Recorder};
mod active;
mod ar;
mod features;
mod plan;
mod sensor;
mod topo;

use pyo3::create_exception;
use pyo3::exceptions::{PyTypeError, PyValueError};
use pyo3::prelude::*;

create_exception!(_native, ObjslamError, PyValueError, "Base class of every objslam error.");
create_exception!(_native, InputError, ObjslamError, "An argument has the wrong shape, dtype or value.");
create_exception!(_native, MapFileError, ObjslamError, "A map file cannot be read or written.");
create_exception!(_native, RecordingError, ObjslamError, "The Rerun recording failed.");

pub(crate) fn input_err(msg: impl std::fmt::Display) -> PyErr {
    InputError::new_err(msg.to_string())
}

/// Most elements of one numpy argument (2^26, e.g. an 8192 x 8192 depth image or 22 M points),
/// checked before the array is copied.
pub(crate) const MAX_ARRAY_ELEMENTS: usize = 1 << 26;

/// Refuse an array of more than [`MAX_ARRAY_ELEMENTS`] elements (a broadcast view has a large
/// shape and no memory of its own: copying it would allocate the full shape).
pub(crate) fn check_elements(field: &str, shape: &[usize]) -> PyResult<()> {
    let n = shape.iter().try_fold(1usize, |acc, d| acc.checked_mul(*d));
    match n {
        Some(n) if n <= MAX_ARRAY_ELEMENTS => Ok(()),
        _ => Err(input_err(format!("{field}: shape {shape:?} has more than {MAX_ARRAY_ELEMENTS} elements"))),
    }
}

/// Parse JSON `text` given as argument `field`; errors name the field's path inside it.
pub(crate) fn parse_json<T: serde::de::DeserializeOwned>(field: &str, text: &str) -> PyResult<T> {
    objslam_core::map::validate::parse_json(text).map_err(|e| input_err(format!("{field}: {e}")))
}

fn frame_err(e: FrameError) -> PyErr {
    input_err(e)
}

fn geometry_err(e: GeometryError) -> PyErr {
    input_err(e)
}

pub(crate) fn map_err(e: MapError) -> PyErr {
    match e {
        MapError::UnknownLabel(_) => input_err(e),
        _ => MapFileError::new_err(e.to_string()),
    }
}

fn record_err(e: RecordError) -> PyErr {
    match e {
        RecordError::BufferLength { .. } | RecordError::Option { .. } => input_err(e),
        _ => RecordingError::new_err(e.to_string()),
    }
}

fn dtype_name(obj: &Bound<'_, PyAny>) -> String {
    obj.getattr("dtype").map(|d| d.to_string()).unwrap_or_else(|_| obj.get_type().to_string())
}

fn shape_of(obj: &Bound<'_, PyAny>) -> String {
    obj.getattr("shape").map(|d| d.to_string()).unwrap_or_else(|_| "?".into())
}

/// Extract a float64 matrix of a fixed shape, finite.
fn matrix<const R: usize, const C: usize>(obj: &Bound<'_, PyAny>, field: &str) -> PyResult<[[f64; C]; R]> {
    let arr: PyReadonlyArray2<'_, f64> = obj.extract().map_err(|_| {
        PyTypeError::new_err(format!(
            "{field}: expected a float64 array of shape ({R}, {C}), got dtype {} shape {}",
            dtype_name(obj),
            shape_of(obj)
        ))
    })?;
    let a = arr.as_array();
    if a.shape() != [R, C] {
        return Err(input_err(format!("{field}: expected shape ({R}, {C}), got {:?}", a.shape())));
    }
    let mut out = [[0.0; C]; R];
    for r in 0..R {
        for c in 0..C {
            let v = a[[r, c]];
            if !v.is_finite() {
                return Err(input_err(format!("{field}: non-finite value at [{r}, {c}]")));
            }
            out[r][c] = v;
        }
    }
    Ok(out)
}

pub(crate) fn pose(obj: &Bound<'_, PyAny>, field: &'static str) -> PyResult<Se3> {
    let m = matrix::<4, 4>(obj, field)?;
    let mat = Matrix4::from_fn(|r, c| m[r][c]);
    se3_from_matrix(&mat, field).map_err(geometry_err)
}

pub(crate) fn camera(k: &Bound<'_, PyAny>, width: u32, height: u32) -> PyResult<PinholeCamera> {
    let m = matrix::<3, 3>(k, "intrinsics")?;
    PinholeCamera::from_matrix(width, height, &Matrix3::from_fn(|r, c| m[r][c])).map_err(geometry_err)
}

pub(crate) fn depth_image(obj: &Bound<'_, PyAny>) -> PyResult<DepthImage> {
    let arr: PyReadonlyArray2<'_, f32> = obj.extract().map_err(|_| {
        PyTypeError::new_err(format!(
            "depth: expected a float32 array of shape (H, W) in metres, got dtype {} shape {}",
            dtype_name(obj),
            shape_of(obj)
        ))
    })?;
    let a = arr.as_array();
    check_elements("depth", a.shape())?;
    let (h, w) = (a.shape()[0], a.shape()[1]);
    let data: Vec<f32> = a.iter().copied().collect();
    DepthImage::new(w as u32, h as u32, data).map_err(frame_err)
}

/// Detections from a list of `(u0, v0, u1, v1, label, score)` tuples.
pub(crate) fn detections(list: &Bound<'_, PyAny>) -> PyResult<Vec<Detection>> {
    let items: Vec<(f64, f64, f64, f64, String, f64)> = list.extract().map_err(|_| {
        PyTypeError::new_err("detections: expected a list of (u0, v0, u1, v1, label: str, score) tuples")
    })?;
    items
        .into_iter()
        .enumerate()
        .map(|(i, (u0, v0, u1, v1, label, score))| {
            if ![u0, v0, u1, v1].iter().all(|v| v.is_finite()) {
                return Err(input_err(format!("detections[{i}]: box has a non-finite coordinate")));
            }
            let label = Label::parse(&label).map_err(|e| input_err(format!("detections[{i}].label: {e}")))?;
            Ok(Detection { bbox: Box2::new(u0, v0, u1, v1), label, score })
        })
        .collect()
}

/// A core [`Frame`] from the Python arguments every per-frame call takes (validated later by the
/// consumer's `Frame::validate`).
pub(crate) fn frame_from_py(
    index: u32,
    intrinsics: &Bound<'_, PyAny>,
    depth: &Bound<'_, PyAny>,
    world_from_camera: &Bound<'_, PyAny>,
    detections: &Bound<'_, PyAny>,
) -> PyResult<Frame> {
    let depth = depth_image(depth)?;
    Ok(Frame {
        index,
        camera: camera(intrinsics, depth.width, depth.height)?,
        world_from_camera: pose(world_from_camera, "world_from_camera")?,
        depth,
        detections: self::detections(detections)?,
    })
}

pub(crate) fn json_err(field: &str, e: serde_json::Error) -> PyErr {
    input_err(format!("{field}: {e}"))
}

/// A core value as Python dicts / lists / numbers, through its JSON form.
pub(crate) fn to_py<'py>(py: Python<'py>, value: &impl serde::Serialize, field: &str) -> PyResult<Bound<'py, PyAny>> {
    let s = serde_json::to_string(value).map_err(|e| json_err(field, e))?;
    py.import("json")?.call_method1("loads", (s,))
}

/// The foundation's naive mapper (depth points in the box, box-IoU association, AABB extent).
#[pyclass(module = "objslam._native", name = "NaiveMapper")]
struct NaiveMapperPy {
    inner: NaiveMapper,
}

#[pymethods]
impl NaiveMapperPy {
    #[new]
    #[pyo3(signature = (config_json = None))]
    fn new(config_json: Option<&str>) -> PyResult<Self> {
        let config: NaiveConfig = match config_json {
            Some(s) => parse_json("config", s)?,
            None => NaiveConfig::default(),
        };
        config.validate().map_err(|(field, reason)| input_err(format!("config.{field}: {reason}")))?;
        Ok(Self { inner: NaiveMapper::new(config) })
    }

    /// Fuse one frame; returns, per detection, the object id it updated or created (or None).
    #[pyo3(signature = (*, index, intrinsics, depth, world_from_camera, detections))]
    fn update(
        &mut self,
        index: u32,
        intrinsics: &Bound<'_, PyAny>,
        depth: &Bound<'_, PyAny>,
        world_from_camera: &Bound<'_, PyAny>,
        detections: &Bound<'_, PyAny>,
    ) -> PyResult<Vec<Option<u32>>> {
        let frame = frame_from_py(index, intrinsics, depth, world_from_camera, detections)?;
        let summary = self.inner.update(&frame).map_err(frame_err)?;
        Ok(summary.assigned)
    }

    /// The map as versioned JSON.
    fn map_json(&self) -> String {
        self.inner.map().to_json()
    }

    /// The map's objects as JSON records `{"id", "label", "geometry", "n_observations"}`.
    fn objects_json(&self) -> PyResult<String> {
        objects_json(self.inner.map())
    }

    /// Number of objects in the map.
    fn __len__(&self) -> usize {
        self.inner.map().len()
    }
}

pub(crate) fn objects_json(map: &ObjectMap) -> PyResult<String> {
    let records: Vec<serde_json::Value> = map
        .objects
        .iter()
        .map(|o| {
            serde_json::json!({
                "id": o.id,
                "label": o.label,
                "geometry": o.geometry(),
                "n_observations": o.observations.len(),
            })
        })
        .collect();
    serde_json::to_string(&records).map_err(|e| json_err("objects", e))
}

/// The objects of a map given as versioned JSON (see `NaiveMapper.objects_json`).
#[pyfunction]
fn map_objects_json(map_json: &str) -> PyResult<String> {
    objects_json(&ObjectMap::from_json(map_json, "map_json").map_err(map_err)?)
}

/// Evaluate a map (versioned JSON) against ground truth (JSON list of GtObject); returns JSON.
#[pyfunction]
#[pyo3(signature = (gt_json, map_json, config_json = None))]
fn evaluate_map(gt_json: &str, map_json: &str, config_json: Option<&str>) -> PyResult<String> {
    let gt = ground_truth_from_json(gt_json).map_err(input_err)?;
    let map = ObjectMap::from_json(map_json, "map_json").map_err(map_err)?;
    let config: EvalConfig = match config_json {
        Some(s) => config_from_json(s).map_err(input_err)?,
        None => EvalConfig::default(),
    };
    let ev = evaluate(&gt, &estimates_from_map(&map), &config);
    serde_json::to_string(&ev).map_err(|e| json_err("evaluation", e))
}

/// The core's settings of a run (`{"slam", "map", "explore", "eval"}` tables as JSON, missing keys
/// taking the core's defaults) parsed, range-checked and returned complete as JSON; the error names
/// the field as `table.key` (`objslam_core::system::SystemConfig`).
#[pyfunction]
fn resolve_config(config_json: &str) -> PyResult<String> {
    let c = objslam_core::system::SystemConfig::from_json(config_json).map_err(input_err)?;
    serde_json::to_string(&c).map_err(|e| json_err("config", e))
}

/// Load a map file and return its JSON (checks format, version, content hash and values).
#[pyfunction]
fn load_map(path: &str) -> PyResult<String> {
    ObjectMap::load(std::path::Path::new(path)).map(|m| m.to_json()).map_err(map_err)
}

/// Validate map JSON and write it atomically to `path`.
#[pyfunction]
fn save_map(map_json: &str, path: &str) -> PyResult<()> {
    let map = ObjectMap::from_json(map_json, "map_json").map_err(map_err)?;
    map.save(std::path::Path::new(path)).map_err(map_err)
}

fn points3(obj: &Bound<'_, PyAny>, field: &str) -> PyResult<Vec<Point3<f64>>> {
    let arr: PyReadonlyArray2<'_, f64> = obj.extract().map_err(|_| {
        PyTypeError::new_err(format!(
            "{field}: expected a float64 array of shape (N, 3), got dtype {} shape {}",
            dtype_name(obj),
            shape_of(obj)
        ))
    })?;
    let a = arr.as_array();
    if a.shape()[1] != 3 {
        return Err(input_err(format!("{field}: expected shape (N, 3), got {:?}", a.shape())));
    }
    check_elements(field, a.shape())?;
    let mut out = Vec::with_capacity(a.shape()[0]);
    for (i, row) in a.rows().into_iter().enumerate() {
        if !row.iter().all(|v| v.is_finite()) {
            return Err(input_err(format!("{field}: non-finite value in row {i}")));
        }
        out.push(Point3::new(row[0], row[1], row[2]));
    }
    Ok(out)
}

fn colors_u8(obj: &Bound<'_, PyAny>, n: usize) -> PyResult<Vec<[u8; 3]>> {
    let arr: PyReadonlyArray2<'_, u8> = obj.extract().map_err(|_| {
        PyTypeError::new_err(format!(
            "colors: expected a uint8 array of shape (N, 3), got dtype {} shape {}",
            dtype_name(obj),
            shape_of(obj)
        ))
    })?;
    let a = arr.as_array();
    if a.shape() != [n, 3] {
        return Err(input_err(format!("colors: expected shape ({n}, 3), got {:?}", a.shape())));
    }
    Ok(a.rows().into_iter().map(|r| [r[0], r[1], r[2]]).collect())
}

/// One Rerun recording (`.rrd` file); see `objslam_core::record` for entity paths.
#[pyclass(module = "objslam._native", name = "Recorder")]
struct RecorderPy {
    inner: Option<Recorder>,
}

impl RecorderPy {
    fn rec(&self) -> PyResult<&Recorder> {
        self.inner.as_ref().ok_or_else(|| RecordingError::new_err("recorder is closed"))
    }
}

#[pymethods]
impl RecorderPy {
    /// `options_json`: `objslam_core::record::RecordOptions` as JSON (default: its defaults).
    #[new]
    #[pyo3(signature = (path, application_id = "objslam", options_json = None))]
    fn new(path: &str, application_id: &str, options_json: Option<&str>) -> PyResult<Self> {
        let options: RecordOptions = match options_json {
            Some(j) => serde_json::from_str(j).map_err(|e| json_err("options_json", e))?,
            None => RecordOptions::default(),
        };
        let rec = Recorder::create(std::path::Path::new(path), application_id, options).map_err(record_err)?;
        Ok(Self { inner: Some(rec) })
    }

    /// The arm's links: `{link name: world_from_link (4x4)}`.
    fn log_robot_pose(&self, links: std::collections::HashMap<String, Bound<'_, PyAny>>) -> PyResult<()> {
        let mut poses = Vec::with_capacity(links.len());
        for (name, m) in links {
            poses.push((name, pose(&m, "links")?));
        }
        self.rec()?.log_robot_pose(&poses).map_err(record_err)
    }

    fn set_frame(&self, frame: u32, sim_time_s: f64) -> PyResult<()> {
        self.rec()?.set_frame(frame, sim_time_s);
        Ok(())
    }

    #[pyo3(signature = (*, world_from_camera, intrinsics, width, height))]
    fn log_camera(
        &self,
        world_from_camera: &Bound<'_, PyAny>,
        intrinsics: &Bound<'_, PyAny>,
        width: u32,
        height: u32,
    ) -> PyResult<()> {
        let p = pose(world_from_camera, "world_from_camera")?;
        let cam = camera(intrinsics, width, height)?;
        self.rec()?.log_camera(&p, &cam).map_err(record_err)
    }

    fn log_rgb(&self, rgb: &Bound<'_, PyAny>) -> PyResult<()> {
        let arr: PyReadonlyArray3<'_, u8> = rgb.extract().map_err(|_| {
            PyTypeError::new_err(format!(
                "rgb: expected a uint8 array of shape (H, W, 3), got dtype {} shape {}",
                dtype_name(rgb),
                shape_of(rgb)
            ))
        })?;
        let a = arr.as_array();
        if a.shape()[2] != 3 {
            return Err(input_err(format!("rgb: expected shape (H, W, 3), got {:?}", a.shape())));
        }
        check_elements("rgb", a.shape())?;
        let data: Vec<u8> = a.iter().copied().collect();
        self.rec()?.log_rgb(a.shape()[1] as u32, a.shape()[0] as u32, &data).map_err(record_err)
    }

    fn log_depth(&self, depth: &Bound<'_, PyAny>) -> PyResult<()> {
        let d = depth_image(depth)?;
        self.rec()?.log_depth(d.width, d.height, &d.data).map_err(record_err)
    }

    fn log_detections(&self, detections: &Bound<'_, PyAny>) -> PyResult<()> {
        let dets = self::detections(detections)?;
        self.rec()?.log_detections(&dets).map_err(record_err)
    }

    fn log_trajectory(&self, which: &str, positions: &Bound<'_, PyAny>) -> PyResult<()> {
        if which != "estimated" && which != "ground_truth" {
            return Err(input_err(format!("which: expected 'estimated' or 'ground_truth', got {which:?}")));
        }
        let pts = points3(positions, "positions")?;
        self.rec()?.log_trajectory(which, &pts).map_err(record_err)
    }

    /// Objects from JSON: a list of {"id", "label", "geometry": ObjectGeometry}.
    fn log_objects(&self, root: &str, objects_json: &str) -> PyResult<()> {
        #[derive(serde::Deserialize)]
        struct In {
            id: u32,
            label: String,
            geometry: ObjectGeometry,
        }
        let v: Vec<In> = parse_json("objects_json", objects_json)?;
        let objs: Vec<DrawnObject> =
            v.into_iter().map(|o| DrawnObject { id: o.id, label: o.label, geometry: o.geometry }).collect();
        self.rec()?.log_objects(root, &objs).map_err(record_err)
    }

    #[pyo3(signature = (entity, points, group_keys = None))]
    fn log_points(&self, entity: &str, points: &Bound<'_, PyAny>, group_keys: Option<Vec<String>>) -> PyResult<()> {
        let pts = points3(points, "points")?;
        self.rec()?.log_points(entity, &pts, &group_keys.unwrap_or_default()).map_err(record_err)
    }

    /// Points (N, 3) float64 with colours (N, 3) uint8.
    #[pyo3(signature = (entity, points, colors, radius_m = 0.004))]
    fn log_colored_points(
        &self,
        entity: &str,
        points: &Bound<'_, PyAny>,
        colors: &Bound<'_, PyAny>,
        radius_m: f32,
    ) -> PyResult<()> {
        let pts = points3(points, "points")?;
        let cols = colors_u8(colors, pts.len())?;
        self.rec()?.log_colored_points(entity, &pts, &cols, radius_m).map_err(record_err)
    }

    /// Arrows: origins (N, 3), vectors (N, 3) float64, colours (N, 3) uint8.
    fn log_arrows(
        &self,
        entity: &str,
        origins: &Bound<'_, PyAny>,
        vectors: &Bound<'_, PyAny>,
        colors: &Bound<'_, PyAny>,
    ) -> PyResult<()> {
        let o = points3(origins, "origins")?;
        let v: Vec<nalgebra::Vector3<f64>> = points3(vectors, "vectors")?.iter().map(|p| p.coords).collect();
        if v.len() != o.len() {
            return Err(input_err(format!("vectors: {} rows, origins has {}", v.len(), o.len())));
        }
        let cols = colors_u8(colors, o.len())?;
        self.rec()?.log_arrows(entity, &o, &v, &cols).map_err(record_err)
    }

    fn log_scalar(&self, entity: &str, value: f64) -> PyResult<()> {
        self.rec()?.log_scalar(entity, value).map_err(record_err)
    }

    fn log_event(&self, text: &str) -> PyResult<()> {
        self.rec()?.log_event(text).map_err(record_err)
    }

    /// Flush and close the file; later calls raise.
    fn close(&mut self) -> PyResult<()> {
        if let Some(rec) = self.inner.take() {
            rec.flush().map_err(record_err)?;
        }
        Ok(())
    }
}

#[pymodule]
fn _native(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    m.add("ObjslamError", py.get_type::<ObjslamError>())?;
    m.add("InputError", py.get_type::<InputError>())?;
    m.add("MapFileError", py.get_type::<MapFileError>())?;
    m.add("RecordingError", py.get_type::<RecordingError>())?;
    m.add_class::<NaiveMapperPy>()?;
    m.add_class::<RecorderPy>()?;
    m.add_class::<active::ActiveMapperPy>()?;
    m.add("PlanningError", py.get_type::<plan::PlanningError>())?;
    m.add_class::<plan::PlannerPy>()?;
    m.add_function(wrap_pyfunction!(ar::ar_run, m)?)?;
    m.add_function(wrap_pyfunction!(evaluate_map, m)?)?;
    m.add_function(wrap_pyfunction!(resolve_config, m)?)?;
    m.add_function(wrap_pyfunction!(load_map, m)?)?;
    m.add_function(wrap_pyfunction!(save_map, m)?)?;
    m.add_function(wrap_pyfunction!(map_objects_json, m)?)?;
    m.add_function(wrap_pyfunction!(topo::match_maps, m)?)?;
    m.add_function(wrap_pyfunction!(topo::relocalise, m)?)?;
    m.add_function(wrap_pyfunction!(topo::relocalise_appearance, m)?)?;
    m.add_function(wrap_pyfunction!(sensor::sensor_model, m)?)?;
    m.add_function(wrap_pyfunction!(features::orb_extract, m)?)?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
