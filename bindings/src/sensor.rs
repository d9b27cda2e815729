//! The RGB-D sensor model (`objslam_core::sensor`): one entry point, numpy in, numpy out.

use numpy::ndarray::{Array2, Array3};
use numpy::{IntoPyArray, PyArray2, PyArray3, PyReadonlyArray2, PyReadonlyArray3, PyUntypedArrayMethods};
use objslam_core::sensor::{RenderedFrame, RendererBuffers, SensorRequest};
use pyo3::prelude::*;

use crate::{input_err, parse_json, to_json};

type SensorOutput<'py> = (Option<Bound<'py, PyArray2<f32>>>, Option<Bound<'py, PyArray3<u8>>>, String);

fn slice<'a, T: numpy::Element>(a: &'a PyReadonlyArray3<'_, T>, field: &str, shape: [usize; 3]) -> PyResult<&'a [T]> {
    if a.shape() != shape {
        return Err(input_err(format!("{field}: expected shape {shape:?}, got {:?}", a.shape())));
    }
    a.as_slice().map_err(|_| input_err(format!("{field}: must be C-contiguous")))
}

/// The sensor model on one rendered frame. ``request_json``: `objslam_core::sensor::SensorRequest`.
/// Buffers: ``points`` / ``normals`` (H, W, 3) float32, OpenCV camera axes, z ≤ 0 = no surface,
/// ``rgb`` (H, W, 3) uint8; or the renderer's (`objslam_core::sensor::RendererBuffers`): (H, W, 4)
/// float32, OpenGL axes, position w ≥ 1 = no surface, ``rgb`` RGBA in [0, 1], and optionally
/// ``segmentation`` (H, W) uint32 whose ``dropped_ids`` count as no surface. Returns ``(depth
/// (H, W) float32, rgb (H, W, 3) uint8 or None, info_json {"unit", "stats"})``; without
/// ``points``, ``(None, None, info)`` with the episode's unit only. The model runs without the GIL,
/// reading the arrays in place.
#[pyfunction]
#[pyo3(signature = (request_json, points = None, normals = None, rgb = None, segmentation = None, dropped_ids = vec![]))]
pub fn sensor_model<'py>(
    py: Python<'py>,
    request_json: &str,
    points: Option<PyReadonlyArray3<'py, f32>>,
    normals: Option<PyReadonlyArray3<'py, f32>>,
    rgb: Option<Bound<'py, PyAny>>,
    segmentation: Option<PyReadonlyArray2<'py, u32>>,
    dropped_ids: Vec<u32>,
) -> PyResult<SensorOutput<'py>> {
    let request: SensorRequest = parse_json("request_json", request_json)?;
    let (Some(points), Some(normals)) = (points, normals) else {
        let (info, _) = request.run(None).map_err(input_err)?;
        return Ok((None, None, to_json(&info, "info")?));
    };
    let &[h, w, c] = points.shape() else { return Err(input_err("points: expected shape (H, W, 3 or 4)")) };
    let rgb_err = |_| input_err("rgb: uint8 (H, W, 3) with (H, W, 3) points, float32 (H, W, 4) with (H, W, 4)");
    let (info, out) = if c == 4 {
        let rgb = rgb.map(|a| a.extract::<PyReadonlyArray3<f32>>().map_err(rgb_err)).transpose()?;
        let colour = rgb.as_ref().map_or(Ok(&[][..]), |a| slice(a, "rgb", [h, w, 4]))?;
        let (position, normal) = (slice(&points, "points", [h, w, 4])?, slice(&normals, "normals", [h, w, 4])?);
        let segmentation = match &segmentation {
            Some(a) if a.shape() != [h, w] => return Err(input_err("segmentation: expected shape (H, W)")),
            Some(a) => a.as_slice().map_err(|_| input_err("segmentation: must be C-contiguous"))?,
            None => &[],
        };
        let dropped_ids = &dropped_ids;
        let buffers = RendererBuffers { width: w, height: h, position, normal, colour, segmentation, dropped_ids };
        py.detach(|| request.run_renderer(&buffers)).map_err(input_err)?
    } else {
        let rgb = rgb.map(|a| a.extract::<PyReadonlyArray3<u8>>().map_err(rgb_err)).transpose()?;
        let rgb = rgb.as_ref().map_or(Ok(&[][..]), |a| slice(a, "rgb", [h, w, 3]))?;
        let (points_in_camera, normals_in_camera) =
            (slice(&points, "points", [h, w, 3])?, slice(&normals, "normals", [h, w, 3])?);
        let frame = RenderedFrame { width: w, height: h, points_in_camera, normals_in_camera, rgb };
        let (info, out) = py.detach(|| request.run(Some(&frame))).map_err(input_err)?;
        (info, out.ok_or_else(|| input_err("sensor model: no frame simulated"))?)
    };
    let depth = Array2::from_shape_vec((h, w), out.depth_m).map_err(input_err)?.into_pyarray(py);
    let colour = match out.rgb.is_empty() {
        true => None,
        false => Some(Array3::from_shape_vec((h, w, 3), out.rgb).map_err(input_err)?.into_pyarray(py)),
    };
    Ok((Some(depth), colour, to_json(&info, "info")?))
}
