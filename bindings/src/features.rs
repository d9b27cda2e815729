//! `orb_extract(grey, config_json=None) -> (keypoints, descriptors)`: the core's ORB extractor
//! (`objslam_core::slam::OrbExtractor`, kept between calls) on one uint8 (H, W) image. `keypoints` is float32 (N, 5):
//! x, y (level-0 pixel indices), level, angle (radians), FAST score; `descriptors` uint8 (N, 32).

use numpy::{IntoPyArray, PyArray2, PyReadonlyArray2};
use objslam_core::frame::GreyImage;
use objslam_core::slam::{OrbConfig, OrbExtractor};
use pyo3::prelude::*;

use crate::{check_elements, input_err, parse_json};

static CACHE: std::sync::Mutex<Option<OrbExtractor>> = std::sync::Mutex::new(None);

type OrbAnswer<'py> = (Bound<'py, PyArray2<f32>>, Bound<'py, PyArray2<u8>>);

/// Detect and describe ORB features (`config_json`: an `OrbConfig`, defaults if omitted).
#[pyfunction]
#[pyo3(signature = (grey, config_json = None))]
pub fn orb_extract<'py>(
    py: Python<'py>,
    grey: PyReadonlyArray2<'py, u8>,
    config_json: Option<&str>,
) -> PyResult<OrbAnswer<'py>> {
    let config: OrbConfig = config_json.map_or(Ok(OrbConfig::default()), |t| parse_json("config_json", t))?;
    let a = grey.as_array();
    check_elements("grey", a.shape())?;
    let image =
        GreyImage { width: a.shape()[1] as u32, height: a.shape()[0] as u32, data: a.iter().copied().collect() };
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
    let n = features.keypoints.len();
    let kp: Vec<f32> = features
        .keypoints
        .iter()
        .flat_map(|k| [k.x, k.y, f32::from(k.level), k.angle_rad, f32::from(k.score)])
        .collect();
    let desc: Vec<u8> = features.descriptors.iter().flat_map(|d| d.iter().flat_map(|w| w.to_le_bytes())).collect();
    let kp = numpy::ndarray::Array2::from_shape_vec((n, 5), kp).map_err(input_err)?;
    let desc = numpy::ndarray::Array2::from_shape_vec((n, 32), desc).map_err(input_err)?;
    Ok((kp.into_pyarray(py), desc.into_pyarray(py)))
}
