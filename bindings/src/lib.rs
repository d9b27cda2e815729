//! Thin pyo3 layer over `objslam-core`, built by maturin as the private module `objslam._native`.
//!
//! Rules: numpy arrays in, validated here by [`array`] (dtype, shape, finiteness, element count
//! against [`MAX_ARRAY_ELEMENTS`] before anything is copied, so a broadcast view of a huge shape is
//! refused instead of copied) with errors that name the argument; every core error maps to a
//! specific Python exception; no panic crosses into Python (core code has no unwrap, and these
//! wrappers only return `PyResult`). Complex structured values (maps, evaluations, configs) cross
//! as JSON strings, read with [`parse_json`] so errors name the field's path; core results come
//! back as Python values through their serde form ([`to_py`], [`to_py_arrays`]).

use nalgebra::{Point3, SMatrix};
use numpy::{PyArray2, PyReadonlyArrayDyn, PyUntypedArrayMethods, ToPyArray};
use objslam_core::eval::{config_from_json, estimates_from_map, evaluate, ground_truth_from_json, EvalConfig};
use objslam_core::frame::{DepthImage, Detection, Frame};
use objslam_core::geometry::{se3_from_matrix, Box2, PinholeCamera, Se3};
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
use pyo3::types::{PyDict, PyList};

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

/// A numpy argument of dtype `T` and `D` dimensions, copied out in row-major order with its shape.
/// `shape` fixes the lengths that must be (None = any), `text` names the shape in the error: the
/// wrong dtype or number of dimensions is a `TypeError`, a wrong length or more than
/// [`MAX_ARRAY_ELEMENTS`] elements an `InputError` (a broadcast view has a large shape and no
/// memory of its own: copying it would allocate the full shape).
pub(crate) fn array<T: numpy::Element + Copy, const D: usize>(
    obj: &Bound<'_, PyAny>,
    field: &str,
    shape: [Option<usize>; D],
    text: &str,
) -> PyResult<(Vec<T>, [usize; D])> {
    let arr: PyReadonlyArrayDyn<'_, T> =
        obj.extract().ok().filter(|a: &PyReadonlyArrayDyn<'_, T>| a.ndim() == D).ok_or_else(|| {
            let got = |attr: &str| obj.getattr(attr).map_or_else(|_| "?".to_string(), |v| v.to_string());
            let dtype = numpy::dtype::<T>(obj.py());
            PyTypeError::new_err(format!(
                "{field}: expected a {dtype} array of shape {text}, got dtype {} shape {}",
                got("dtype"),
                got("shape")
            ))
        })?;
    let a = arr.as_array();
    let dims: [usize; D] = std::array::from_fn(|i| a.shape()[i]);
    if dims.iter().zip(&shape).any(|(d, s)| s.is_some_and(|s| s != *d)) {
        return Err(input_err(format!("{field}: expected shape {text}, got {dims:?}")));
    }
    if dims.iter().try_fold(1usize, |n, d| n.checked_mul(*d)).is_none_or(|n| n > MAX_ARRAY_ELEMENTS) {
        return Err(input_err(format!("{field}: shape {dims:?} has more than {MAX_ARRAY_ELEMENTS} elements")));
    }
    Ok((a.as_slice().map_or_else(|| a.iter().copied().collect(), <[T]>::to_vec), dims))
}

/// [`array`] of float64 values, every one finite (the error names the first other one's index).
pub(crate) fn finite<const D: usize>(
    obj: &Bound<'_, PyAny>,
    field: &str,
    shape: [Option<usize>; D],
    text: &str,
) -> PyResult<(Vec<f64>, [usize; D])> {
    let (values, dims) = array::<f64, D>(obj, field, shape, text)?;
    let Some(mut rest) = values.iter().position(|v| !v.is_finite()) else { return Ok((values, dims)) };
    let mut index = [0usize; D];
    for k in (0..D).rev() {
        index[k] = rest % dims[k];
        rest /= dims[k];
    }
    Err(input_err(format!("{field}: non-finite value at {index:?}")))
}

/// A finite float64 matrix of a fixed shape.
fn matrix<const R: usize, const C: usize>(obj: &Bound<'_, PyAny>, field: &str) -> PyResult<SMatrix<f64, R, C>> {
    let (values, _) = finite::<2>(obj, field, [Some(R), Some(C)], &format!("({R}, {C})"))?;
    Ok(SMatrix::from_row_slice(&values))
}

pub(crate) fn pose(obj: &Bound<'_, PyAny>, field: &'static str) -> PyResult<Se3> {
    se3_from_matrix(&matrix::<4, 4>(obj, field)?, field).map_err(input_err)
}

pub(crate) fn camera(k: &Bound<'_, PyAny>, width: u32, height: u32) -> PyResult<PinholeCamera> {
    PinholeCamera::from_matrix(width, height, &matrix::<3, 3>(k, "intrinsics")?).map_err(input_err)
}

pub(crate) fn depth_image(obj: &Bound<'_, PyAny>) -> PyResult<DepthImage> {
    let (data, [h, w]) = array::<f32, 2>(obj, "depth", [None, None], "(H, W) in metres")?;
    DepthImage::new(w as u32, h as u32, data).map_err(input_err)
}

/// Points (N, 3) float64, finite.
fn points3(obj: &Bound<'_, PyAny>, field: &str) -> PyResult<Vec<Point3<f64>>> {
    let (values, _) = finite::<2>(obj, field, [None, Some(3)], "(N, 3)")?;
    Ok(values.chunks_exact(3).map(|p| Point3::new(p[0], p[1], p[2])).collect())
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

/// Parse JSON `text` given as argument `field`; errors name the field's path inside it.
pub(crate) fn parse_json<T: serde::de::DeserializeOwned>(field: &str, text: &str) -> PyResult<T> {
    objslam_core::map::validate::parse_json(text).map_err(|e| input_err(format!("{field}: {e}")))
}

/// [`parse_json`] of an optional argument, the type's default without it.
pub(crate) fn parse_or_default<T: serde::de::DeserializeOwned + Default>(
    field: &str,
    text: Option<&str>,
) -> PyResult<T> {
    text.map_or_else(|| Ok(T::default()), |t| parse_json(field, t))
}

/// A string argument naming one variant of a core enum (its serde name, e.g. `"refined"`).
pub(crate) fn choice<T: serde::de::DeserializeOwned>(field: &str, value: &str) -> PyResult<T> {
    serde_json::from_value(serde_json::Value::from(value)).map_err(|e| input_err(format!("{field}: {e}")))
}

/// A core value as JSON text.
pub(crate) fn to_json(value: &impl serde::Serialize, field: &str) -> PyResult<String> {
    serde_json::to_string(value).map_err(|e| input_err(format!("{field}: {e}")))
}

/// A core value as Python dicts / lists / numbers, through its JSON form.
pub(crate) fn to_py<'py>(py: Python<'py>, value: &impl serde::Serialize, field: &str) -> PyResult<Bound<'py, PyAny>> {
    py.import("json")?.call_method1("loads", (to_json(value, field)?,))
}

/// [`to_py`], with the values under `array_keys` (in the dict and the dicts and lists nested in
/// it, or in each dict of a list) as float64 numpy arrays.
pub(crate) fn to_py_arrays<'py>(
    py: Python<'py>,
    value: &impl serde::Serialize,
    field: &str,
    array_keys: &[&str],
) -> PyResult<Bound<'py, PyAny>> {
    fn convert(d: &Bound<'_, PyAny>, keys: &[&str], asarray: &Bound<'_, PyAny>) -> PyResult<()> {
        if let Ok(list) = d.cast::<PyList>() {
            return list.iter().try_for_each(|v| convert(&v, keys, asarray));
        }
        let Ok(d) = d.cast::<PyDict>() else { return Ok(()) };
        for v in d.values() {
            convert(&v, keys, asarray)?;
        }
        for key in keys {
            if let Some(v) = d.get_item(key)?.filter(|v| !v.is_none()) {
                d.set_item(key, asarray.call1((v, "float64"))?)?;
            }
        }
        Ok(())
    }
    let out = to_py(py, value, field)?;
    convert(&out, array_keys, &py.import("numpy")?.getattr("asarray")?)?;
    Ok(out)
}

/// A pose as a 4x4 float64 array.
pub(crate) fn matrix_py<'py>(py: Python<'py>, t: &Se3) -> Bound<'py, PyArray2<f64>> {
    rows_py(py, &objslam_core::geometry::rows(&t.to_homogeneous()))
}

/// Points as an (N, 3) float64 array.
pub(crate) fn points_py<'py>(py: Python<'py>, points: &[Point3<f64>]) -> Bound<'py, PyArray2<f64>> {
    rows_py(py, &points.iter().map(|p| [p.x, p.y, p.z]).collect::<Vec<_>>())
}

/// Rows of `C` values as an (N, C) float64 array.
pub(crate) fn rows_py<'py, const C: usize>(py: Python<'py>, rows: &[[f64; C]]) -> Bound<'py, PyArray2<f64>> {
    numpy::ndarray::Array2::from_shape_fn((rows.len(), C), |(r, c)| rows[r][c]).to_pyarray(py)
}

pub(crate) fn map_err(e: MapError) -> PyErr {
    if e.is_input() {
        input_err(e)
    } else {
        MapFileError::new_err(e.to_string())
    }
}

fn record_err(e: RecordError) -> PyErr {
    if e.is_input() {
        input_err(e)
    } else {
        RecordingError::new_err(e.to_string())
    }
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
        let config: NaiveConfig = parse_or_default("config", config_json)?;
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
        Ok(self.inner.update(&frame).map_err(input_err)?.assigned)
    }

    /// The map as versioned JSON.
    fn map_json(&self) -> String {
        self.inner.map().to_json()
    }

    /// The map's objects as JSON records `{"id", "label", "geometry", "n_observations"}`.
    fn objects_json(&self) -> PyResult<String> {
        to_json(&self.inner.map().object_records(), "objects")
    }

    /// Number of objects in the map.
    fn __len__(&self) -> usize {
        self.inner.map().len()
    }
}

/// The objects of a map given as versioned JSON (see `NaiveMapper.objects_json`).
#[pyfunction]
fn map_objects_json(map_json: &str) -> PyResult<String> {
    to_json(&ObjectMap::from_json(map_json, "map_json").map_err(map_err)?.object_records(), "objects")
}

/// Evaluate a map (versioned JSON) against ground truth (JSON list of GtObject); returns JSON.
#[pyfunction]
#[pyo3(signature = (gt_json, map_json, config_json = None))]
fn evaluate_map(gt_json: &str, map_json: &str, config_json: Option<&str>) -> PyResult<String> {
    let gt = ground_truth_from_json(gt_json).map_err(input_err)?;
    let map = ObjectMap::from_json(map_json, "map_json").map_err(map_err)?;
    let config: EvalConfig =
        config_json.map_or_else(|| Ok(EvalConfig::default()), config_from_json).map_err(input_err)?;
    to_json(&evaluate(&gt, &estimates_from_map(&map), &config), "evaluation")
}

/// The core's settings of a run (`{"slam", "map", "explore", "eval"}` tables as JSON, missing keys
/// taking the core's defaults) parsed, range-checked and returned complete as JSON; the error names
/// the field as `table.key` (`objslam_core::system::SystemConfig`).
#[pyfunction]
fn resolve_config(config_json: &str) -> PyResult<String> {
    to_json(&objslam_core::system::SystemConfig::from_json(config_json).map_err(input_err)?, "config")
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
        let options: RecordOptions = parse_or_default("options_json", options_json)?;
        let rec = Recorder::create(std::path::Path::new(path), application_id, options).map_err(record_err)?;
        Ok(Self { inner: Some(rec) })
    }

    /// The arm's links: `{link name: world_from_link (4x4)}`.
    fn log_robot_pose(&self, links: std::collections::HashMap<String, Bound<'_, PyAny>>) -> PyResult<()> {
        let poses: Vec<(String, Se3)> =
            links.into_iter().map(|(name, m)| Ok((name, pose(&m, "links")?))).collect::<PyResult<_>>()?;
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
        self.rec()?.log_camera(&p, &camera(intrinsics, width, height)?).map_err(record_err)
    }

    fn log_rgb(&self, py: Python<'_>, rgb: &Bound<'_, PyAny>) -> PyResult<()> {
        let (data, [h, w, _]) = array::<u8, 3>(rgb, "rgb", [None, None, Some(3)], "(H, W, 3)")?;
        let rec = self.rec()?;
        py.detach(|| rec.log_rgb(w as u32, h as u32, data)).map_err(record_err)
    }

    fn log_depth(&self, py: Python<'_>, depth: &Bound<'_, PyAny>) -> PyResult<()> {
        let d = depth_image(depth)?;
        let rec = self.rec()?;
        py.detach(|| rec.log_depth(d.width, d.height, d.data)).map_err(record_err)
    }

    fn log_detections(&self, detections: &Bound<'_, PyAny>) -> PyResult<()> {
        self.rec()?.log_detections(&self::detections(detections)?).map_err(record_err)
    }

    fn log_trajectory(&self, which: &str, positions: &Bound<'_, PyAny>) -> PyResult<()> {
        if which != "estimated" && which != "ground_truth" {
            return Err(input_err(format!("which: expected 'estimated' or 'ground_truth', got {which:?}")));
        }
        self.rec()?.log_trajectory(which, &points3(positions, "positions")?).map_err(record_err)
    }

    /// Objects from JSON: a list of {"id", "label", "geometry": ObjectGeometry}.
    fn log_objects(&self, root: &str, objects_json: &str) -> PyResult<()> {
        let objects: Vec<DrawnObject> = parse_json("objects_json", objects_json)?;
        self.rec()?.log_objects(root, &objects).map_err(record_err)
    }

    /// Points (N, 3) float64: with colours (N, 3) uint8 drawn at `radius_m`, else coloured by
    /// `group_keys` (one key per point).
    #[pyo3(signature = (entity, points, group_keys = None, *, colors = None, radius_m = 0.004))]
    fn log_points(
        &self,
        entity: &str,
        points: &Bound<'_, PyAny>,
        group_keys: Option<Vec<String>>,
        colors: Option<&Bound<'_, PyAny>>,
        radius_m: f32,
    ) -> PyResult<()> {
        let pts = points3(points, "points")?;
        match colors {
            Some(c) => self.rec()?.log_colored_points(entity, &pts, &colors_u8(c, pts.len())?, radius_m),
            None => self.rec()?.log_points(entity, &pts, &group_keys.unwrap_or_default()),
        }
        .map_err(record_err)
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

    /// Flush (the images still being encoded first) and close the file; later calls raise.
    fn close(&mut self, py: Python<'_>) -> PyResult<()> {
        match self.inner.take() {
            Some(rec) => py.detach(move || rec.flush()).map_err(record_err),
            None => Ok(()),
        }
    }
}

/// Colours (N, 3) uint8 for `n` points.
fn colors_u8(obj: &Bound<'_, PyAny>, n: usize) -> PyResult<Vec<[u8; 3]>> {
    let (values, _) = array::<u8, 2>(obj, "colors", [Some(n), Some(3)], "(N, 3)")?;
    Ok(values.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect())
}

#[pymodule]
fn _native(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    m.add("ObjslamError", py.get_type::<ObjslamError>())?;
    m.add("InputError", py.get_type::<InputError>())?;
    m.add("MapFileError", py.get_type::<MapFileError>())?;
    m.add("RecordingError", py.get_type::<RecordingError>())?;
    m.add("PlanningError", py.get_type::<plan::PlanningError>())?;
    m.add_class::<NaiveMapperPy>()?;
    m.add_class::<RecorderPy>()?;
    m.add_class::<active::ActiveMapperPy>()?;
    m.add_class::<plan::PlannerPy>()?;
    m.add_function(wrap_pyfunction!(ar::ar_run, m)?)?;
    m.add_function(wrap_pyfunction!(evaluate_map, m)?)?;
    m.add_function(wrap_pyfunction!(resolve_config, m)?)?;
    m.add_function(wrap_pyfunction!(load_map, m)?)?;
    m.add_function(wrap_pyfunction!(save_map, m)?)?;
    m.add_function(wrap_pyfunction!(map_objects_json, m)?)?;
    m.add_function(wrap_pyfunction!(topo::match_maps, m)?)?;
    m.add_function(wrap_pyfunction!(topo::relocalise_appearance, m)?)?;
    m.add_function(wrap_pyfunction!(sensor::sensor_model, m)?)?;
    m.add_function(wrap_pyfunction!(features::orb_extract, m)?)?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
