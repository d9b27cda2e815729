//! `orb_extract(grey, config_json=None) -> (keypoints, descriptors)`: the core's ORB extractor
//! (`objslam_core::slam::OrbExtractor`, kept between calls) on one uint8 (H, W) image. `keypoints` is float32 (N, 5):
//! x, y (level-0 pixel indices), level, angle (radians), FAST score; `descriptors` uint8 (N, 32).

use numpy::{IntoPyArray, PyArray2};
use objslam_core::frame::GreyImage;
use objslam_core::slam::{OrbConfig, OrbExtractor};
use pyo3::prelude::*;

use crate::{array, input_err, parse_or_default};

static CACHE: std::sync::Mutex<Option<OrbExtractor>> = std::sync::Mutex::new(None);

type OrbAnswer<'py> = (Bound<'py, PyArray2<f32>>, Bound<'py, PyArray2<u8>>);

/// Detect and describe ORB features (`config_json`: an `OrbConfig`, defaults if omitted).
#[pyfunction]
#[pyo3(signature = (grey, config_json = None))]
pub fn orb_extract<'py>(
    py: Python<'py>,
    grey: &Bound<'py, PyAny>,
    config_json: Option<&str>,
) -> PyResult<OrbAnswer<'py>> {
    let config: OrbConfig = parse_or_default("config_json", config_json)?;
    let (data, [h, w]) = array::<u8, 2>(grey, "grey", [None, None], "(H, W)")?;
    let image = GreyImage { width: w as u32, height: h as u32, data };
    let features = py
        .detach(|| {
            // One extractor kept between calls (its pattern tables and pyramid buffers), rebuilt
            // when the configuration changes.
            let mut cached = CACHE.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
            if cached.as_ref().is_none_or(|o| *o.config() != config) {
                *cached = Some(OrbExtractor::new(config)?);
            }
            match cached.as_mut() {
                Some(orb) => orb.extract(&image),
                None => Ok(Default::default()),
            }
        })
        .map_err(input_err)?;
    let keypoints = numpy::ndarray::arr2(&features.keypoint_rows()).into_pyarray(py);
    Ok((keypoints, numpy::ndarray::arr2(&features.descriptor_bytes()).into_pyarray(py)))
}
