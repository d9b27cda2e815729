//! The RGB-D sensor model (`objslam_core::sensor`): one entry point, numpy in, numpy out.

use crate::input_err;
use nalgebra::{Matrix3, Matrix4};
use numpy::ndarray::{Array2, Array3};
use numpy::{IntoPyArray, PyArray2, PyArray3, PyReadonlyArray3, PyUntypedArrayMethods};
use objslam_core::sensor::{simulate_frame, Intrinsics, RenderedFrame, SensorConfig, SensorUnit};
use pyo3::prelude::*;
use serde::Deserialize;

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct Request {
    #[serde(default)]
    config: SensorConfig,
    seed: u64,
    #[serde(default)]
    frame_index: u64,
    /// Nominal (assumed) colour intrinsics, 3 × 3.
    intrinsics: [[f64; 3]; 3],
    #[serde(default)]
    camera_end_from_start: Option<[[f64; 4]; 4]>,
}

type SensorOutput<'py> = (Option<Bound<'py, PyArray2<f32>>>, Option<Bound<'py, PyArray3<u8>>>, String);

fn slice<'a, T: numpy::Element>(a: &'a PyReadonlyArray3<'_, T>, field: &str, h: usize, w: usize) -> PyResult<&'a [T]> {
    let shape = a.shape();
    if shape != [h, w, 3] {
        return Err(input_err(format!("{field}: expected shape ({h}, {w}, 3), got {shape:?}")));
    }
    a.as_slice().map_err(|_| input_err(format!("{field}: must be C-contiguous")))
}

/// The sensor model on one rendered frame. ``request_json``: ``{"config": {stereo, colour,
/// calibration}, "seed", "frame_index", "intrinsics" (nominal colour 3x3), "camera_end_from_start"
/// (4x4 or null)}``; ``points`` / ``normals``: (H, W, 3) float32 in the colour camera's OpenCV
/// frame (z ≤ 0 = no surface); ``rgb``: (H, W, 3) uint8 or None. Returns ``(depth (H, W) float32 or
/// None, rgb or None, info_json)``, info = ``{"unit": the episode's calibration state, "stats"}``.
/// Without ``points`` only the unit is drawn (the simulator renders with its true intrinsics).
#[pyfunction]
#[pyo3(signature = (request_json, points = None, normals = None, rgb = None))]
pub fn sensor_model<'py>(
    py: Python<'py>,
    request_json: &str,
    points: Option<PyReadonlyArray3<'py, f32>>,
    normals: Option<PyReadonlyArray3<'py, f32>>,
    rgb: Option<PyReadonlyArray3<'py, u8>>,
) -> PyResult<SensorOutput<'py>> {
    let req: Request = serde_json::from_str(request_json).map_err(|e| input_err(format!("request_json: {e}")))?;
    let k = Intrinsics::from_matrix(&Matrix3::from_fn(|r, c| req.intrinsics[r][c]));
    let unit = SensorUnit::draw(&req.config, k, req.seed).map_err(input_err)?;
    let (Some(points), Some(normals)) = (points, normals) else {
        let info = serde_json::json!({ "unit": unit, "stats": null });
        return Ok((None, None, info.to_string()));
    };
    let &[h, w, _] = points.shape() else { return Err(input_err("points: expected shape (H, W, 3)")) };
    let p = slice(&points, "points", h, w)?;
    let n = slice(&normals, "normals", h, w)?;
    let c = match &rgb {
        Some(a) => slice(a, "rgb", h, w)?,
        None => &[],
    };
    let motion = req.camera_end_from_start.map(|m| Matrix4::from_fn(|r, c| m[r][c]));
    let frame = RenderedFrame { width: w, height: h, points_in_camera: p, normals_in_camera: n, rgb: c };
    let out =
        simulate_frame(&req.config, &unit, &frame, motion.as_ref(), req.seed, req.frame_index).map_err(input_err)?;
    let depth = Array2::from_shape_vec((h, w), out.depth_m).map_err(input_err)?.into_pyarray(py);
    let colour = if out.rgb.is_empty() {
        None
    } else {
        Some(Array3::from_shape_vec((h, w, 3), out.rgb).map_err(input_err)?.into_pyarray(py))
    };
    let info = serde_json::json!({ "unit": unit, "stats": out.stats });
    Ok((Some(depth), colour, info.to_string()))
}
