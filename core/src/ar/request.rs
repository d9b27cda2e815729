//! One AR request in, one answer out: registration, occlusion masks, picks and drops from a
//! JSON-friendly [`ArRequest`] (the Python bindings' single entry point).
//!
//! Request fields (all optional but `models` when masks or drops are asked for):
//! - `map`: a saved object map (versioned JSON, as `map.json`), or `objects`: real objects in the
//!   evaluation's ground-truth layout (`{id, label, geometry: {shape, center, yaw_rad,
//!   half_extents}}`); `table`: a [`TableTop`].
//! - `models`: [`VirtualModel`]s to register.
//! - `camera`: `{intrinsics: {width, height, fx, fy, cx, cy}, world_from_camera: 4x4 row-major}`;
//!   with it, the masks of the registered models are computed against the map's depth; when the
//!   caller passes a depth image to [`run_request`], against the map's depth fused with it (a live
//!   sensor frame, with its grey image for the registration shift: [`fuse_live_depth`]) or against
//!   it alone (`config.live.source = "exact"`).
//! - `picks`: pixels `[u, v]` to pick (needs `camera`).
//! - `drop`: initial velocities `[vx, vy, vz]` (m/s), one per model: run [`drop_to_rest`].
//! - `config`: an [`ArConfig`].

use nalgebra::Matrix4;
use serde::{Deserialize, Serialize};

use super::{
    bad, drop_to_rest, fuse_live_depth, occlusion_masks, pick, register, remove_specks, render_scene_depth, ArConfig,
    ArError, ArScene, DepthSource, DropOutcome, LiveSummary, PickEvent, RealObject, RegisteredModel, TableTop,
    VirtualModel,
};
use crate::frame::{DepthImage, GreyImage};
use crate::geometry::{se3_from_matrix, PinholeCamera};
use crate::map::ObjectMap;

/// A camera for masks and picks.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CameraRequest {
    /// Intrinsics and image size.
    pub intrinsics: PinholeCamera,
    /// Camera pose (OpenCV axes), 4x4 row-major.
    pub world_from_camera: [[f64; 4]; 4],
}

/// Everything one AR call may ask for.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ArRequest {
    /// A saved object map (versioned JSON value).
    #[serde(default)]
    pub map: Option<serde_json::Value>,
    /// Real objects given directly (instead of `map`).
    #[serde(default)]
    pub objects: Option<Vec<RealObject>>,
    /// The table top.
    #[serde(default)]
    pub table: Option<TableTop>,
    /// Virtual models to register.
    #[serde(default)]
    pub models: Vec<VirtualModel>,
    /// Camera for masks and picks.
    #[serde(default)]
    pub camera: Option<CameraRequest>,
    /// Pixels to pick.
    #[serde(default)]
    pub picks: Vec<[f64; 2]>,
    /// Initial velocities of a drop, one per model.
    #[serde(default)]
    pub drop: Option<Vec<[f64; 3]>>,
    /// Settings.
    #[serde(default)]
    pub config: ArConfig,
}

/// Mask sizes per model (the masks themselves are in [`ArResponse::coverage`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MaskSummary {
    /// Model name.
    pub name: String,
    /// Pixels covered by the model.
    pub silhouette_px: usize,
    /// Pixels where it is visible.
    pub visible_px: usize,
}

/// The answer.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct ArResponse {
    /// Registered models (request order).
    pub registered: Vec<RegisteredModel>,
    /// Per-model mask sizes (empty without a camera).
    pub masks: Vec<MaskSummary>,
    /// One entry per requested pixel: the picked object and its event, or `None`.
    pub picks: Vec<Option<PickEvent>>,
    /// The drop's outcome, when a drop was requested.
    pub drop: Option<DropOutcome>,
    /// What the live depth fusion found, when a live frame was passed.
    pub live: Option<LiveSummary>,
    /// Model coverage images, `models × height × width` row-major, values 0 / 1 (hidden) / 2
    /// (visible); empty without a camera.
    #[serde(skip)]
    pub coverage: Vec<u8>,
    /// The depth the masks were computed against (the map's, or the one passed in); `None`
    /// without a camera.
    #[serde(skip)]
    pub real_depth: Option<DepthImage>,
}

impl ArRequest {
    /// Parse a JSON request.
    pub fn from_json(text: &str) -> Result<Self, ArError> {
        serde_json::from_str(text).map_err(|e| ArError::Malformed(e.to_string()))
    }

    /// The real scene of the request (`map` or `objects`, plus `table`).
    pub fn scene(&self) -> Result<ArScene, ArError> {
        match (&self.map, &self.objects) {
            (Some(_), Some(_)) => Err(bad("map/objects", "give one of them, not both")),
            (Some(v), None) => {
                let map = ObjectMap::from_json(&v.to_string(), "map").map_err(|e| bad("map", e.to_string()))?;
                Ok(ArScene::from_map(&map, self.table))
            }
            (None, objects) => Ok(ArScene { objects: objects.clone().unwrap_or_default(), table: self.table }),
        }
    }
}

/// Run a request. `real_depth` (same size as the camera; 0 = no return) is a live sensor frame
/// fused with the map's rendered depth (`grey`: its grey image, for the registration shift), or
/// with `config.live.source = "exact"` the real depth used alone, as the occluder of the masks.
pub fn run_request(
    req: &ArRequest,
    real_depth: Option<DepthImage>,
    grey: Option<GreyImage>,
) -> Result<ArResponse, ArError> {
    let scene = req.scene()?;
    let registered = register(&scene, &req.models)?;
    let mut out = ArResponse { registered, ..ArResponse::default() };
    let cfg = &req.config;
    if let Some(cam) = &req.camera {
        let world_from_camera =
            se3_from_matrix(&Matrix4::from_fn(|r, c| cam.world_from_camera[r][c]), "camera.world_from_camera")?;
        let depth = match (real_depth, cfg.live.source) {
            (Some(d), DepthSource::Exact) => d,
            (live, _) => {
                let map_depth = render_scene_depth(&scene, &cam.intrinsics, &world_from_camera, &cfg.render)?;
                match live {
                    Some(live) => {
                        let f = fuse_live_depth(&cam.intrinsics, map_depth, &live, grey.as_ref(), &cfg.live)?;
                        out.live = Some(f.summary);
                        f.depth
                    }
                    None => map_depth,
                }
            }
        };
        let mut masks = occlusion_masks(&out.registered, &cam.intrinsics, &world_from_camera, &depth, &cfg.render)?;
        if out.live.is_some() {
            for m in &mut masks {
                m.visible_px -= remove_specks(&mut m.coverage, cam.intrinsics.width as usize, cfg.live.min_visible_px);
            }
        }
        for m in masks {
            out.coverage.extend_from_slice(&m.coverage);
            out.masks.push(MaskSummary { name: m.name, silhouette_px: m.silhouette_px, visible_px: m.visible_px });
        }
        out.real_depth = Some(depth);
        for p in &req.picks {
            out.picks.push(pick(&scene, &cam.intrinsics, &world_from_camera, *p, &cfg.render, &cfg.interaction)?);
        }
    } else if !req.picks.is_empty() {
        return Err(bad("picks", "picking needs a camera"));
    } else if real_depth.is_some() {
        return Err(bad("real_depth", "a depth image needs a camera"));
    }
    if let Some(v) = &req.drop {
        out.drop = Some(drop_to_rest(&scene, &out.registered, v, &cfg.physics)?);
    }
    Ok(out)
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // tests may unwrap (STYLE.md, 18)
mod tests {
    use super::*;

    #[test]
    fn a_json_request_round_trip() {
        let req = r#"{
            "objects": [{"id": 3, "label": "book",
                         "geometry": {"shape": "cuboid", "center": [0.0, 0.0, 0.02], "yaw_rad": 0.0,
                                      "half_extents": [0.1, 0.07, 0.02]}}],
            "table": {"center_xy_m": [0.0, 0.0], "size_xy_m": [1.0, 1.0]},
            "models": [{"name": "lamp", "shape": {"kind": "cylinder", "radius_m": 0.02, "half_height_m": 0.05},
                        "placement": {"mode": "object", "label": "book", "on_top": true}}],
            "camera": {"intrinsics": {"width": 64, "height": 48, "fx": 50.0, "fy": 50.0, "cx": 32.0, "cy": 24.0},
                       "world_from_camera": [[1,0,0,0],[0,-1,0,0],[0,0,-1,1],[0,0,0,1]]},
            "picks": [[32.0, 24.0]],
            "drop": [[0.0, 0.0, 0.0]]
        }"#;
        let r = run_request(&ArRequest::from_json(req).unwrap(), None, None).unwrap();
        assert_eq!(r.coverage.len(), 64 * 48);
        assert!(r.masks[0].visible_px > 0 && r.masks[0].visible_px == r.masks[0].silhouette_px);
        assert_eq!(r.picks[0].as_ref().map(|p| p.event.as_str()), Some("book_selected"));
        let z = r.drop.unwrap().bodies[0].world_from_model.translation.z;
        assert!((z - 0.09).abs() < 1e-3, "lamp rests at {z}");
        assert!(matches!(ArRequest::from_json(r#"{"modles": []}"#), Err(ArError::Malformed(_))));
    }
}
