//! `match_maps`: scene matching of two object maps (see `objslam_core::topo`), and
//! `relocalise_appearance` (`objslam_core::slam::relocalise`).
//!
//! `match_maps` takes the maps as versioned map JSON (as written to `map.json` / returned by
//! `map_json()`) and an optional partial `MatchConfig` as JSON. A failed match is a result
//! (`matched` False, `reason`, `reason_kind`), not an exception; malformed input raises
//! `MapFileError` (map JSON) or `InputError` (config JSON) naming the argument and the field.

use objslam_core::frame::{DepthImage, GreyImage};
use objslam_core::map::ObjectMap;
use objslam_core::slam::{relocalise_frames, AppearanceRequest};
use objslam_core::topo::report::{MatchReport, ReportDirection, ARRAY_FIELDS};
use objslam_core::topo::{match_object_maps, MatchConfig};
use pyo3::prelude::*;

use crate::{array, input_err, map_err, parse_json, parse_or_default, to_json, to_py_arrays};

/// Match two object maps: the similarity `query_from_prior` (q = s R p + t), or with
/// `relocalise` (a map built in a new session against a prior map) `prior_from_query`
/// (p = s R q + t) and the matched object ids.
///
/// Returns a dict (`objslam_core::topo::report::MatchReport`): `matched`; `rotation` (3×3),
/// `translation` (3,), `scale`, `matrix` (4×4) of the transform; `inliers` [[prior id, query id,
/// residual m]]; `matched_pairs` (the paper's best pair per prior object) [[prior id, query id,
/// score]]; `confidence`, `coverage`, `distinctiveness`, `fit`, `rms_residual`, `scale_umeyama`,
/// `scale_distance_ratio`; `stats`; with `relocalise`, `matched_ids` [[prior id, query id]] sorted
/// by prior id. No match: `matched` False, `reason` (text), `reason_kind`, transform keys None.
#[pyfunction]
#[pyo3(signature = (prior_map_json, query_map_json, config_json = None, *, relocalise = false))]
pub fn match_maps<'py>(
    py: Python<'py>,
    prior_map_json: &str,
    query_map_json: &str,
    config_json: Option<&str>,
    relocalise: bool,
) -> PyResult<Bound<'py, PyAny>> {
    let config: MatchConfig = parse_or_default("config_json", config_json)?;
    let prior = ObjectMap::from_json(prior_map_json, "prior_map_json").map_err(map_err)?;
    let query = ObjectMap::from_json(query_map_json, "query_map_json").map_err(map_err)?;
    let result = py.detach(|| match_object_maps(&prior, &query, &config));
    let direction = if relocalise { ReportDirection::PriorFromQuery } else { ReportDirection::QueryFromPrior };
    let report = MatchReport::new(&result, &prior, &query, direction);
    to_py_arrays(py, &report, "match", &ARRAY_FIELDS)
}

/// (grey, depth) frames from a uint8 and a float32 (N, H, W) stack of the same shape.
fn frames(grey: &Bound<'_, PyAny>, depth: &Bound<'_, PyAny>, field: &str) -> PyResult<Vec<(GreyImage, DepthImage)>> {
    let (grey, [n, h, w]) = array::<u8, 3>(grey, &format!("{field}_grey"), [None, None, None], "(N, H, W)")?;
    let shape = [Some(n), Some(h), Some(w)];
    let (depth, _) = array::<f32, 3>(depth, &format!("{field}_depth"), shape, "(N, H, W) of the grey images")?;
    let (size, (w, h)) = (h * w, (w as u32, h as u32));
    (0..n)
        .map(|i| {
            let g = GreyImage::new(w, h, grey[i * size..(i + 1) * size].to_vec());
            let d = DepthImage::new(w, h, depth[i * size..(i + 1) * size].to_vec());
            g.and_then(|g| Ok((g, d?))).map_err(|e| input_err(format!("{field}: {e}")))
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
    prior_grey: &Bound<'_, PyAny>,
    prior_depth: &Bound<'_, PyAny>,
    query_grey: &Bound<'_, PyAny>,
    query_depth: &Bound<'_, PyAny>,
) -> PyResult<String> {
    let request: AppearanceRequest = parse_json("request_json", request_json)?;
    let prior = frames(prior_grey, prior_depth, "prior")?;
    let query = frames(query_grey, query_depth, "query")?;
    let (keyframes, camera) =
        request.keyframes(prior, query.first()).map_err(|e| input_err(format!("request_json.{e}")))?;
    let results = py.detach(|| relocalise_frames(request.config, &keyframes, &query, &camera)).map_err(input_err)?;
    to_json(&results, "relocalisation")
}
