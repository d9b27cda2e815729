//! The RGB-D sensor model (`objslam_core::sensor`): one entry point, numpy in, numpy out.

use numpy::ndarray::{Array2, Array3};
use numpy::{IntoPyArray, PyArray2, PyArray3, PyReadonlyArray3, PyUntypedArrayMethods};
use objslam_core::sensor::{RenderedFrame, SensorRequest};
use pyo3::prelude::*;

use crate::{input_err, parse_json, to_json};

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
/// (4x4 or null)}`` (`objslam_core::sensor::SensorRequest`); ``points`` / ``normals``: (H, W, 3)
/// float32 in the colour camera's OpenCV frame (z ≤ 0 = no surface); ``rgb``: (H, W, 3) uint8 or
/// None. Returns ``(depth (H, W) float32 or None, rgb or None, info_json)``, info = ``{"unit": the
/// episode's calibration state, "stats"}``. Without ``points`` only the unit is drawn (the
/// simulator renders with its true intrinsics).
#[pyfunction]
#[pyo3(signature = (request_json, points = None, normals = None, rgb = None))]
pub fn sensor_model<'py>(
    py: Python<'py>,
    request_json: &str,
    points: Option<PyReadonlyArray3<'py, f32>>,
    normals: Option<PyReadonlyArray3<'py, f32>>,
    rgb: Option<PyReadonlyArray3<'py, u8>>,
) -> PyResult<SensorOutput<'py>> {
    let request: SensorRequest = parse_json("request_json", request_json)?;
    let (Some(points), Some(normals)) = (points, normals) else {
        let (info, _) = request.run(None).map_err(input_err)?;
        return Ok((None, None, to_json(&info, "info")?));
    };
    let &[h, w, _] = points.shape() else { return Err(input_err("points: expected shape (H, W, 3)")) };
    let rgb = match &rgb {
        Some(a) => slice(a, "rgb", h, w)?,
        None => &[],
    };
    let (points_in_camera, normals_in_camera) = (slice(&points, "points", h, w)?, slice(&normals, "normals", h, w)?);
    let frame = RenderedFrame { width: w, height: h, points_in_camera, normals_in_camera, rgb };
    let (info, out) = request.run(Some(&frame)).map_err(input_err)?;
    let Some(out) = out else { return Err(input_err("sensor model: no frame simulated")) };
    let depth = Array2::from_shape_vec((h, w), out.depth_m).map_err(input_err)?.into_pyarray(py);
    let colour = match out.rgb.is_empty() {
        true => None,
        false => Some(Array3::from_shape_vec((h, w, 3), out.rgb).map_err(input_err)?.into_pyarray(py)),
    };
    Ok((Some(depth), colour, to_json(&info, "info")?))
}
