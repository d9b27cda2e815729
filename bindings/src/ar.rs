//! `ar_run`: augmented reality on an object map (see `objslam_core::ar::request` for the request).
//!
//! `ar_run(request_json, real_depth=None, grey=None) -> (answer_json, coverage, depth)`: `real_depth`
//! float32 (H, W) is a live frame (fused with the map; `grey` uint8 (H, W) its image) or, with
//! `config.live.source = "exact"`, the real depth itself. `coverage` is uint8
//! (models, H, W) with 0 / 1 hidden / 2 visible (shape (0, 0, 0) without a camera), `depth` the float32
//! (H, W) depth the masks used (None without a camera). Bad input raises `InputError` naming the field.

use numpy::{IntoPyArray, PyArray2, PyArray3};
use objslam_core::ar::{run_request, ArRequest};
use objslam_core::frame::{DepthImage, GreyImage};
use pyo3::prelude::*;

use crate::{array, input_err, to_json};

type ArAnswer<'py> = (String, Bound<'py, PyArray3<u8>>, Option<Bound<'py, PyArray2<f32>>>);

/// Run an AR request (registration, masks, picks, drop) given as JSON.
#[pyfunction]
#[pyo3(signature = (request_json, real_depth=None, grey=None))]
pub fn ar_run<'py>(
    py: Python<'py>,
    request_json: &str,
    real_depth: Option<&Bound<'py, PyAny>>,
    grey: Option<&Bound<'py, PyAny>>,
) -> PyResult<ArAnswer<'py>> {
    let req = ArRequest::from_json(request_json).map_err(input_err)?;
    let depth = real_depth.map(|a| array::<f32, 2>(a, "real_depth", [None, None], "(H, W) in metres")).transpose()?;
    let depth = depth.map(|(data, [h, w])| DepthImage { width: w as u32, height: h as u32, data });
    let grey = grey.map(|a| array::<u8, 2>(a, "grey", [None, None], "(H, W) grey levels")).transpose()?;
    let grey = grey.map(|(data, [h, w])| GreyImage { width: w as u32, height: h as u32, data });
    let out = py.detach(|| run_request(&req, depth, grey)).map_err(input_err)?;
    let json = to_json(&out, "answer")?;
    let (h, w) = out.real_depth.as_ref().map_or((0, 0), |d| (d.height as usize, d.width as usize));
    let n = out.coverage.len().checked_div(h * w).unwrap_or(0);
    let coverage = numpy::ndarray::Array3::from_shape_vec((n, h, w), out.coverage).map_err(input_err)?;
    let depth = match out.real_depth {
        Some(d) => Some(numpy::ndarray::Array2::from_shape_vec((h, w), d.data).map_err(input_err)?.into_pyarray(py)),
        None => None,
    };
    Ok((json, coverage.into_pyarray(py), depth))
}
