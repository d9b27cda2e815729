//! `ar_run`: augmented reality on an object map (see `objslam_core::ar::request` for the request).
//!
//! `ar_run(request_json, real_depth=None, grey=None) -> (answer_json, coverage, depth)`: `real_depth`
//! float32 (H, W) is a live frame (fused with the map; `grey` uint8 (H, W) its image) or, with
//! `config.live.source = "exact"`, the real depth itself. `coverage` is uint8
//! (models, H, W) with 0 / 1 hidden / 2 visible (shape (0, 0, 0) without a camera), `depth` the float32
//! (H, W) depth the masks used (None without a camera). Bad input raises `InputError` naming the field.

use numpy::{IntoPyArray, PyArray2, PyArray3, PyReadonlyArray2};
use objslam_core::ar::{run_request, ArRequest};
use objslam_core::frame::{DepthImage, GreyImage};
use pyo3::prelude::*;

use crate::input_err;

type ArAnswer<'py> = (String, Bound<'py, PyArray3<u8>>, Option<Bound<'py, PyArray2<f32>>>);

/// Run an AR request (registration, masks, picks, drop) given as JSON.
#[pyfunction]
#[pyo3(signature = (request_json, real_depth=None, grey=None))]
pub fn ar_run<'py>(
    py: Python<'py>,
    request_json: &str,
    real_depth: Option<PyReadonlyArray2<'py, f32>>,
    grey: Option<PyReadonlyArray2<'py, u8>>,
) -> PyResult<ArAnswer<'py>> {
    let req = ArRequest::from_json(request_json).map_err(input_err)?;
    let depth = real_depth.map(|a| {
        let a = a.as_array();
        DepthImage { width: a.shape()[1] as u32, height: a.shape()[0] as u32, data: a.iter().copied().collect() }
    });
    let grey = grey.map(|a| {
        let a = a.as_array();
        GreyImage { width: a.shape()[1] as u32, height: a.shape()[0] as u32, data: a.iter().copied().collect() }
    });
    let out = py.detach(|| run_request(&req, depth, grey)).map_err(input_err)?;
    let json = serde_json::to_string(&out).map_err(input_err)?;
    let (h, w) = out.real_depth.as_ref().map_or((0, 0), |d| (d.height as usize, d.width as usize));
    let n = out.coverage.len().checked_div(h * w).unwrap_or(0);
    let coverage = numpy::ndarray::Array3::from_shape_vec((n, h, w), out.coverage).map_err(input_err)?;
    let depth = match out.real_depth {
        Some(d) => Some(numpy::ndarray::Array2::from_shape_vec((h, w), d.data).map_err(input_err)?.into_pyarray(py)),
        None => None,
    };
    Ok((json, coverage.into_pyarray(py), depth))
}
