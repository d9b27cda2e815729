//! `match_maps` / `relocalise`: scene matching of two object maps (see `objslam_core::topo`).
//!
//! Both take the maps as versioned map JSON (as written to `map.json` / returned by `map_json()`)
//! and an optional partial `MatchConfig` as JSON, and return a dict. A failed match is a result
//! (`matched` False, `reason`, `reason_kind`), not an exception; malformed input raises
//! `MapFileError` (map JSON) or `InputError` (config JSON) naming the argument and the field.

use nalgebra::{Matrix3, Matrix4, Similarity3};
use numpy::{PyArray1, PyArray2, ToPyArray};
use objslam_core::geometry::se3_from_matrix;
use objslam_core::map::ObjectMap;
use objslam_core::topo::{match_object_maps, MatchConfig, MatchResult, MatchStats, TopoError};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::{json_err, map_err};

fn config(config_json: Option<&str>) -> PyResult<MatchConfig> {
    match config_json {
        Some(s) => serde_json::from_str(s).map_err(|e| json_err("config_json", e)),
        None => Ok(MatchConfig::default()),
    }
}

fn maps(prior_map_json: &str, query_map_json: &str) -> PyResult<(ObjectMap, ObjectMap)> {
    let prior = ObjectMap::from_json(prior_map_json, "prior_map_json").map_err(map_err)?;
    let query = ObjectMap::from_json(query_map_json, "query_map_json").map_err(map_err)?;
    Ok((prior, query))
}

/// A short, stable name of a no-match reason.
fn reason_kind(e: &TopoError) -> &'static str {
    match e {
        TopoError::EmptyMap { .. } => "empty_map",
        TopoError::TooFewObjects { .. } => "too_few_objects",
        TopoError::NonFinite { .. } => "non_finite",
        TopoError::NoCandidates => "no_candidates",
        TopoError::NoConsistentSample { .. } => "no_consistent_sample",
        TopoError::TooFewInliers { .. } => "too_few_inliers",
    }
}

fn stats_dict<'py>(py: Python<'py>, s: &MatchStats) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("candidates", s.candidates)?;
    d.set_item("consistent_samples", s.consistent_samples)?;
    d.set_item("iterations", s.iterations)?;
    d.set_item("runner_up_inliers", s.runner_up_inliers)?;
    Ok(d)
}

/// Writes `rotation` (3×3), `translation` (3,), `scale` and `matrix` (4×4, s R | t) of `t`.
fn transform_items(d: &Bound<'_, PyDict>, t: &Similarity3<f64>) -> PyResult<()> {
    let py = d.py();
    let r = t.isometry.rotation.to_rotation_matrix().into_inner();
    let rotation = numpy::ndarray::Array2::from_shape_fn((3, 3), |(i, j)| r[(i, j)]);
    let v = t.isometry.translation.vector;
    let m: Matrix4<f64> = t.to_homogeneous();
    let matrix = numpy::ndarray::Array2::from_shape_fn((4, 4), |(i, j)| m[(i, j)]);
    let rotation: Bound<'_, PyArray2<f64>> = rotation.to_pyarray(py);
    let translation: Bound<'_, PyArray1<f64>> = numpy::ndarray::arr1(&[v.x, v.y, v.z]).to_pyarray(py);
    d.set_item("rotation", rotation)?;
    d.set_item("translation", translation)?;
    d.set_item("scale", t.scaling())?;
    d.set_item("matrix", matrix.to_pyarray(py))?;
    Ok(())
}

/// The transform keys set to None (no match).
fn no_transform_items(d: &Bound<'_, PyDict>) -> PyResult<()> {
    for key in ["rotation", "translation", "scale", "matrix"] {
        d.set_item(key, d.py().None())?;
    }
    Ok(())
}

fn id_of(map: &ObjectMap, index: usize) -> u32 {
    map.objects.get(index).map_or(u32::MAX, |o| o.id)
}

/// The common part of both results.
fn result_dict<'py>(
    py: Python<'py>,
    result: &MatchResult,
    prior: &ObjectMap,
    query: &ObjectMap,
    inverse: bool,
) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("stats", stats_dict(py, &result.stats())?)?;
    match result {
        MatchResult::Match(m) => {
            d.set_item("matched", true)?;
            d.set_item("reason", py.None())?;
            d.set_item("reason_kind", py.None())?;
            transform_items(&d, &if inverse { m.prior_from_query() } else { m.query_from_prior })?;
            let inliers: Vec<(u32, u32, f64)> =
                m.inliers.iter().map(|p| (id_of(prior, p.prior), id_of(query, p.query), p.residual)).collect();
            let best: Vec<(u32, u32, f64)> =
                m.best_pairs.iter().map(|p| (id_of(prior, p.prior), id_of(query, p.query), p.score)).collect();
            d.set_item("inliers", inliers)?;
            d.set_item("matched_pairs", best)?;
            d.set_item("confidence", m.confidence)?;
            d.set_item("coverage", m.coverage)?;
            d.set_item("distinctiveness", m.distinctiveness)?;
            d.set_item("fit", m.fit)?;
            d.set_item("rms_residual", m.rms_residual)?;
            d.set_item("scale_umeyama", m.scale_umeyama)?;
            d.set_item("scale_distance_ratio", m.scale_distance_ratio)?;
        }
        MatchResult::NoMatch { reason, .. } => {
            d.set_item("matched", false)?;
            d.set_item("reason", reason.to_string())?;
            d.set_item("reason_kind", reason_kind(reason))?;
            no_transform_items(&d)?;
            d.set_item("inliers", Vec::<(u32, u32, f64)>::new())?;
            d.set_item("matched_pairs", Vec::<(u32, u32, f64)>::new())?;
            d.set_item("confidence", 0.0)?;
            for key in ["coverage", "distinctiveness", "fit", "rms_residual", "scale_umeyama", "scale_distance_ratio"] {
                d.set_item(key, py.None())?;
            }
        }
    }
    Ok(d)
}

/// Parse both maps and the config (typed errors naming the argument), then match without the GIL.
fn parse_and_match(
    py: Python<'_>,
    prior_map_json: &str,
    query_map_json: &str,
    config_json: Option<&str>,
) -> PyResult<(ObjectMap, ObjectMap, MatchResult)> {
    let config = config(config_json)?;
    let (prior, query) = maps(prior_map_json, query_map_json)?;
    let result = py.detach(|| match_object_maps(&prior, &query, &config));
    Ok((prior, query, result))
}

/// Match two object maps: the similarity `query_from_prior` (q = s R p + t).
///
/// Returns a dict: `matched`; `rotation` (3×3), `translation` (3,), `scale`, `matrix` (4×4) of
/// `query_from_prior`; `inliers` [(prior id, query id, residual m)]; `matched_pairs` (the paper's
/// best pair per prior object) [(prior id, query id, score)]; `confidence`, `coverage`,
/// `distinctiveness`, `fit`, `rms_residual`, `scale_umeyama`, `scale_distance_ratio`; `stats`.
/// No match: `matched` False, `reason` (text), `reason_kind`, transform keys None.
#[pyfunction]
#[pyo3(signature = (prior_map_json, query_map_json, config_json = None))]
pub fn match_maps<'py>(
    py: Python<'py>,
    prior_map_json: &str,
    query_map_json: &str,
    config_json: Option<&str>,
) -> PyResult<Bound<'py, PyDict>> {
    let (prior, query, result) = parse_and_match(py, prior_map_json, query_map_json, config_json)?;
    result_dict(py, &result, &prior, &query, false)
}

/// Relocalise a map built in a new session against a prior map: the similarity `prior_from_query`
/// (p = s R q + t) and the matched object ids.
///
/// The same dict as `match_maps`, with the transform keys holding `prior_from_query` and
/// `matched_ids` [(prior id, query id)] sorted by prior id.
#[pyfunction]
#[pyo3(signature = (prior_map_json, query_map_json, config_json = None))]
pub fn relocalise<'py>(
    py: Python<'py>,
    prior_map_json: &str,
    query_map_json: &str,
    config_json: Option<&str>,
) -> PyResult<Bound<'py, PyDict>> {
    let (prior, query, result) = parse_and_match(py, prior_map_json, query_map_json, config_json)?;
    let d = result_dict(py, &result, &prior, &query, true)?;
    let mut ids: Vec<(u32, u32)> = match &result {
        MatchResult::Match(m) => m.inliers.iter().map(|p| (id_of(&prior, p.prior), id_of(&query, p.query))).collect(),
        MatchResult::NoMatch { .. } => Vec::new(),
    };
    ids.sort_unstable();
    d.set_item("matched_ids", ids)?;
    Ok(d)
}

#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct AppearanceRequest {
    #[serde(default)]
    config: objslam_core::slam::AppearanceConfig,
    intrinsics: [[f64; 3]; 3],
    prior_world_from_camera: Vec<[[f64; 4]; 4]>,
}

fn frames<'a>(
    grey: &'a numpy::PyReadonlyArray3<'_, u8>,
    depth: &'a numpy::PyReadonlyArray3<'_, f32>,
    field: &str,
) -> PyResult<Vec<(objslam_core::frame::GreyImage, objslam_core::frame::DepthImage)>> {
    let (g, d) = (grey.as_array(), depth.as_array());
    if g.shape() != d.shape() {
        return Err(crate::input_err(format!("{field}: grey {:?} and depth {:?} shapes differ", g.shape(), d.shape())));
    }
    crate::check_elements(field, g.shape())?;
    let (h, w) = (g.shape()[1] as u32, g.shape()[2] as u32);
    (0..g.shape()[0])
        .map(|i| {
            let gi = objslam_core::frame::GreyImage::new(
                w,
                h,
                g.index_axis(numpy::ndarray::Axis(0), i).iter().copied().collect(),
            );
            let di = objslam_core::frame::DepthImage::new(
                w,
                h,
                d.index_axis(numpy::ndarray::Axis(0), i).iter().copied().collect(),
            );
            match (gi, di) {
                (Ok(gi), Ok(di)) => Ok((gi, di)),
                (Err(e), _) | (_, Err(e)) => Err(crate::input_err(format!("{field}: {e}"))),
            }
        })
        .collect()
}

/// Appearance-based relocalisation (`objslam_core::slam::relocalise`) of query RGB-D frames against
/// prior keyframes. `request_json`: `{"config": partial AppearanceConfig, "intrinsics": 3x3,
/// "prior_world_from_camera": [4x4 per keyframe]}`; `prior_grey` / `query_grey` uint8 (N, H, W),
/// `prior_depth` / `query_depth` float32 (N, H, W) metres. Returns JSON, one record per query
/// frame: `{"ok", "world_from_camera" (4x4 or null), "keyframe", "matches", "inliers", "reason"}`.
#[pyfunction]
pub fn relocalise_appearance(
    py: Python<'_>,
    request_json: &str,
    prior_grey: numpy::PyReadonlyArray3<'_, u8>,
    prior_depth: numpy::PyReadonlyArray3<'_, f32>,
    query_grey: numpy::PyReadonlyArray3<'_, u8>,
    query_depth: numpy::PyReadonlyArray3<'_, f32>,
) -> PyResult<String> {
    use objslam_core::slam::{relocalise_frames, RgbdKeyframe};
    let req: AppearanceRequest = crate::parse_json("request_json", request_json)?;
    let prior = frames(&prior_grey, &prior_depth, "prior")?;
    let query = frames(&query_grey, &query_depth, "query")?;
    if prior.len() != req.prior_world_from_camera.len() {
        return Err(crate::input_err(format!(
            "request_json.prior_world_from_camera: {} poses for {} keyframes",
            req.prior_world_from_camera.len(),
            prior.len()
        )));
    }
    let (w, h) = prior.first().or(query.first()).map_or((1, 1), |(g, _)| (g.width, g.height));
    let k = Matrix3::from_fn(|r, c| req.intrinsics[r][c]);
    let camera = objslam_core::geometry::PinholeCamera::from_matrix(w, h, &k)
        .map_err(|e| crate::input_err(format!("request_json.intrinsics: {e}")))?;
    let mut keyframes = Vec::with_capacity(prior.len());
    for (i, ((grey, depth), m)) in prior.into_iter().zip(&req.prior_world_from_camera).enumerate() {
        let pose = se3_from_matrix(&Matrix4::from_fn(|r, c| m[r][c]), "prior_world_from_camera")
            .map_err(|e| crate::input_err(format!("request_json.prior_world_from_camera[{i}]: {e}")))?;
        keyframes.push(RgbdKeyframe { grey, depth, camera, world_from_camera: pose });
    }
    let results = py.detach(|| relocalise_frames(req.config, &keyframes, &query, &camera)).map_err(crate::input_err)?;
    serde_json::to_string(&results).map_err(crate::input_err)
}
