//! Occlusion: depth of the real scene from the map, and each virtual model's visible pixels.
//!
//! Every pixel's centre ray is intersected exactly with each solid whose projected bounding box
//! covers the pixel (boxes by slabs, cylinders and spheres by their quadratics, meshes triangle by
//! triangle), so the depth image is the primitives' true depth at pixel centres, not a tessellation.
//! The table is drawn as its top face (a rectangle at `height_m`; its sides are not drawn).
//! A virtual pixel is visible when its depth is smaller than the real depth there and it is the
//! nearest virtual surface; "real depth" is any [`DepthImage`] with 0 / non-finite = nothing: the
//! map's ([`render_scene_depth`]) or a sensor's.

use nalgebra::{Point3, Vector3};
use serde::{Deserialize, Serialize};

use super::solid::Solid;
use super::{check_image, depth_or_inf, ArError, ArScene, RegisteredModel, TableTop};
use crate::frame::DepthImage;
use crate::geometry::{PinholeCamera, Se3};

/// Coverage value of a model pixel hidden by a real surface or a nearer virtual model.
pub const COVER_HIDDEN: u8 = 1;
/// Coverage value of a visible model pixel.
pub const COVER_VISIBLE: u8 = 2;

/// Depth rendering settings.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct RenderConfig {
    /// Near clipping distance along the optical axis, metres; surfaces closer are not drawn.
    /// Default 0.02 (the simulator camera's).
    pub near_m: f64,
    /// Far clipping distance, metres; farther surfaces are not drawn. Default 3.0 (the
    /// simulator camera's).
    pub far_m: f64,
}

impl Default for RenderConfig {
    fn default() -> Self {
        Self { near_m: 0.02, far_m: 3.0 }
    }
}

impl RenderConfig {
    fn validate(&self) -> Result<(), ArError> {
        if !(self.near_m.is_finite() && self.far_m.is_finite() && 0.0 < self.near_m && self.near_m < self.far_m) {
            return Err(super::bad(
                "render.near_m/far_m",
                format!("need 0 < near < far, got {} and {}", self.near_m, self.far_m),
            ));
        }
        Ok(())
    }
}

/// A virtual model's pixels in one image.
#[derive(Debug, Clone, PartialEq)]
pub struct ModelMask {
    /// Model name.
    pub name: String,
    /// Pixels the model covers (what an overlay without occlusion draws).
    pub silhouette_px: usize,
    /// Pixels where the model is visible.
    pub visible_px: usize,
    /// Row-major, one byte per pixel: 0 = not covered, [`COVER_HIDDEN`], [`COVER_VISIBLE`].
    pub coverage: Vec<u8>,
}

/// Pixel rectangle `[c0, c1) × [r0, r1)`.
#[derive(Debug, Clone, Copy)]
struct Rect {
    c0: usize,
    c1: usize,
    r0: usize,
    r1: usize,
}

/// A solid's depth over its pixel rectangle (+∞ where its surface is not hit).
struct Patch {
    rect: Rect,
    depth: Vec<f32>,
}

impl Patch {
    fn at(&self, c: usize, r: usize) -> f32 {
        let Rect { c0, c1, r0, r1 } = self.rect;
        if c < c0 || c >= c1 || r < r0 || r >= r1 {
            f32::INFINITY
        } else {
            self.depth[(r - r0) * (c1 - c0) + (c - c0)]
        }
    }
}

/// Ray generator of one camera pose.
struct View<'a> {
    camera: &'a PinholeCamera,
    camera_from_world: Se3,
    near: f64,
    far: f64,
}

impl View<'_> {
    fn width(&self) -> usize {
        self.camera.width as usize
    }

    /// The pixels that the projection of `corners` (camera frame) can cover: their projected
    /// bounding box, or the whole image when a corner reaches the near plane.
    fn rect_of(&self, corners: impl Iterator<Item = Point3<f64>>) -> Option<Rect> {
        let cam = self.camera;
        let (w, h) = (cam.width as usize, cam.height as usize);
        let (mut u0, mut u1, mut v0, mut v1) = (f64::INFINITY, f64::NEG_INFINITY, f64::INFINITY, f64::NEG_INFINITY);
        for p in corners {
            if p.z <= self.near {
                return Some(Rect { c0: 0, c1: w, r0: 0, r1: h });
            }
            let (u, v) = (cam.fx * p.x / p.z + cam.cx, cam.fy * p.y / p.z + cam.cy);
            u0 = u0.min(u);
            u1 = u1.max(u);
            v0 = v0.min(v);
            v1 = v1.max(v);
        }
        let clamp = |x: f64, n: usize| x.clamp(0.0, n as f64) as usize;
        let r = Rect {
            c0: clamp((u0 - 0.5).floor(), w),
            c1: clamp((u1 + 0.5).ceil(), w),
            r0: clamp((v0 - 0.5).floor(), h),
            r1: clamp((v1 + 0.5).ceil(), h),
        };
        (r.c0 < r.c1 && r.r0 < r.r1).then_some(r)
    }

    /// The depth of `solid` over the pixels its bounding box projects to.
    fn patch(&self, solid: &Solid) -> Option<Patch> {
        let cam = self.camera;
        let camera_from_local = self.camera_from_world * solid.world_from_local;
        let (lo, hi) = solid.local_aabb();
        let corners = (0..8).map(|k| {
            camera_from_local
                * Point3::new(
                    if k & 1 == 0 { lo.x } else { hi.x },
                    if k & 2 == 0 { lo.y } else { hi.y },
                    if k & 4 == 0 { lo.z } else { hi.z },
                )
        });
        let rect = self.rect_of(corners)?;
        // Local ray direction of pixel (c, r): d0 + c·du + r·dv (camera ray has z = 1, so t = depth).
        let local_from_camera = camera_from_local.inverse();
        let rot = local_from_camera.rotation;
        let origin = local_from_camera.translation.vector;
        let d0 = rot * Vector3::new((0.5 - cam.cx) / cam.fx, (0.5 - cam.cy) / cam.fy, 1.0);
        let du = rot * Vector3::new(1.0 / cam.fx, 0.0, 0.0);
        let dv = rot * Vector3::new(0.0, 1.0 / cam.fy, 0.0);
        let mut depth = Vec::with_capacity((rect.c1 - rect.c0) * (rect.r1 - rect.r0));
        for r in rect.r0..rect.r1 {
            let row = d0 + dv * r as f64;
            for c in rect.c0..rect.c1 {
                let t = solid.hit_local(&origin, &(row + du * c as f64), self.near).filter(|t| *t <= self.far);
                depth.push(t.map_or(f32::INFINITY, |t| t as f32));
            }
        }
        Some(Patch { rect, depth })
    }

    /// Write the table's top face into `depth` (min with what is there). The top face is a
    /// horizontal rectangle: one ray–plane division per pixel.
    fn table_into(&self, t: &TableTop, depth: &mut [f32]) {
        let cam = self.camera;
        let world_from_camera = self.camera_from_world.inverse();
        let [cx, cy] = t.center_xy_m;
        let [hx, hy] = [t.size_xy_m[0] / 2.0, t.size_xy_m[1] / 2.0];
        let corners = [(-1.0, -1.0), (1.0, -1.0), (-1.0, 1.0), (1.0, 1.0)]
            .map(|(sx, sy)| self.camera_from_world * Point3::new(cx + sx * hx, cy + sy * hy, t.height_m));
        let Some(rect) = self.rect_of(corners.into_iter()) else { return };
        let rot = world_from_camera.rotation;
        let o = world_from_camera.translation.vector;
        let d0 = rot * Vector3::new((0.5 - cam.cx) / cam.fx, (0.5 - cam.cy) / cam.fy, 1.0);
        let du = rot * Vector3::new(1.0 / cam.fx, 0.0, 0.0);
        let dv = rot * Vector3::new(0.0, 1.0 / cam.fy, 0.0);
        let w = self.width();
        let (near, far) = (self.near, self.far);
        for r in rect.r0..rect.r1 {
            let row = d0 + dv * r as f64;
            // Branch-free, so the row vectorises.
            for (c, out) in (rect.c0..rect.c1).zip(&mut depth[r * w + rect.c0..r * w + rect.c1]) {
                let c = c as f64;
                let (dx, dy, dz) = (row.x + du.x * c, row.y + du.y * c, row.z + du.z * c);
                let tt = (t.height_m - o.z) / dz;
                let (x, y) = (o.x + tt * dx - cx, o.y + tt * dy - cy);
                let hit = (tt > near) & (tt <= far) & (x.abs() <= hx) & (y.abs() <= hy);
                *out = out.min(if hit { tt as f32 } else { f32::INFINITY });
            }
        }
    }
}

fn view<'a>(camera: &'a PinholeCamera, world_from_camera: &Se3, config: &RenderConfig) -> Result<View<'a>, ArError> {
    camera.validate()?;
    config.validate()?;
    super::check_finite("world_from_camera", world_from_camera.to_homogeneous().as_slice())?;
    Ok(View { camera, camera_from_world: world_from_camera.inverse(), near: config.near_m, far: config.far_m })
}

/// The depth image of the real scene (map objects and the table's top face) seen from
/// `world_from_camera`: metres along the optical axis, 0 where no surface is within range.
pub fn render_scene_depth(
    scene: &ArScene,
    camera: &PinholeCamera,
    world_from_camera: &Se3,
    config: &RenderConfig,
) -> Result<DepthImage, ArError> {
    scene.validate()?;
    let v = view(camera, world_from_camera, config)?;
    let w = v.width();
    let mut depth = vec![f32::INFINITY; w * camera.height as usize];
    if let Some(t) = &scene.table {
        v.table_into(t, &mut depth);
    }
    for o in &scene.objects {
        if let Some(p) = v.patch(&Solid::of_real(o)) {
            let Rect { c0, c1, r0, r1 } = p.rect;
            for r in r0..r1 {
                let src = &p.depth[(r - r0) * (c1 - c0)..(r - r0 + 1) * (c1 - c0)];
                for (d, s) in depth[r * w + c0..r * w + c1].iter_mut().zip(src) {
                    *d = d.min(*s);
                }
            }
        }
    }
    for d in &mut depth {
        if !d.is_finite() {
            *d = 0.0;
        }
    }
    Ok(DepthImage { width: camera.width, height: camera.height, data: depth })
}

/// Each model's silhouette and visible pixels against `real_depth` (same size as the camera).
/// Models hide each other too: a pixel is visible for the nearest model only (the first in
/// request order on a tie). No models → empty.
pub fn occlusion_masks(
    models: &[RegisteredModel],
    camera: &PinholeCamera,
    world_from_camera: &Se3,
    real_depth: &DepthImage,
    config: &RenderConfig,
) -> Result<Vec<ModelMask>, ArError> {
    let v = view(camera, world_from_camera, config)?;
    check_image("real_depth", real_depth, camera.width, camera.height)?;
    let w = v.width();
    let n = w * camera.height as usize;
    let patches: Vec<Option<Patch>> = models.iter().map(|m| v.patch(&Solid::of_model(m))).collect();
    let mut out = Vec::with_capacity(models.len());
    for (i, m) in models.iter().enumerate() {
        let mut coverage = vec![0u8; n];
        let (mut silhouette_px, mut visible_px) = (0, 0);
        if let Some(p) = &patches[i] {
            let Rect { c0, c1, r0, r1 } = p.rect;
            for r in r0..r1 {
                for c in c0..c1 {
                    let d = p.depth[(r - r0) * (c1 - c0) + (c - c0)];
                    if !d.is_finite() {
                        continue;
                    }
                    silhouette_px += 1;
                    let nearest = patches.iter().enumerate().all(|(j, q)| match q {
                        Some(q) if j < i => d < q.at(c, r),
                        Some(q) if j > i => d <= q.at(c, r),
                        _ => true,
                    });
                    let k = r * w + c;
                    if nearest && d < depth_or_inf(real_depth.data[k]) {
                        coverage[k] = COVER_VISIBLE;
                        visible_px += 1;
                    } else {
                        coverage[k] = COVER_HIDDEN;
                    }
                }
            }
        }
        out.push(ModelMask { name: m.name.clone(), silhouette_px, visible_px, coverage });
    }
    Ok(out)
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // tests may unwrap (STYLE.md, 18)
mod tests {
    use nalgebra::{Translation3, UnitQuaternion, Vector3};

    use super::*;
    use crate::ar::{RealObject, TableTop, VirtualShape};
    use crate::geometry::{ObjectGeometry, Shape};
    use crate::map::Label;

    /// A camera at (0, 0, 1) looking straight down (image x = world x, image y = world −y).
    fn top_camera() -> (PinholeCamera, Se3) {
        let cam = PinholeCamera::new(640, 480, 500.0, 500.0, 320.0, 240.0).unwrap();
        let rot = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI);
        (cam, Se3::from_parts(Translation3::new(0.0, 0.0, 1.0), rot))
    }

    fn real_box(center: [f64; 3], half: [f64; 3]) -> RealObject {
        RealObject {
            id: 7,
            label: Label::Block,
            geometry: ObjectGeometry {
                shape: Shape::Cuboid,
                center: Vector3::from(center),
                yaw_rad: 0.0,
                half_extents: Vector3::from(half),
            },
        }
    }

    fn model(center: [f64; 3], half: [f64; 3]) -> RegisteredModel {
        RegisteredModel {
            name: "v".into(),
            shape: VirtualShape::Cuboid { half_extents_m: half },
            world_from_model: Se3::translation(center[0], center[1], center[2]),
            anchor_object_id: None,
        }
    }

    /// Pixels whose centres fall in [a, b) along one axis: the count of k with a ≤ k + 0.5 < b.
    fn px(a: f64, b: f64) -> usize {
        ((b - 0.5).ceil() - (a - 0.5).ceil()) as usize
    }

    #[test]
    fn map_depth_is_the_primitives_depth() {
        let (cam, pose) = top_camera();
        let table = TableTop { center_xy_m: [0.0, 0.0], size_xy_m: [2.0, 2.0], height_m: 0.0, thickness_m: 0.05 };
        let scene = ArScene { objects: vec![real_box([0.0, 0.0, 0.1], [0.05, 0.05, 0.1])], table: Some(table) };
        let d = render_scene_depth(&scene, &cam, &pose, &RenderConfig::default()).unwrap();
        assert!((d.data[240 * 640 + 320] - 0.8).abs() < 1e-6);
        assert!((d.data[10 * 640 + 10] - 1.0).abs() < 1e-6);
    }

    #[test]
    fn box_behind_a_box_loses_the_projected_overlap() {
        let (cam, pose) = top_camera();
        // Real box top at z = 0.2 (depth 0.8), footprint x ∈ [−0.05, 0.05]; the virtual box below it
        // (top at z = 0.1, depth 0.9) spans x ∈ [0, 0.1], y ∈ [−0.05, 0.05].
        let scene = ArScene { objects: vec![real_box([0.0, 0.0, 0.1], [0.05, 0.05, 0.1])], table: None };
        let real = render_scene_depth(&scene, &cam, &pose, &RenderConfig::default()).unwrap();
        let m = model([0.05, 0.0, 0.05], [0.05, 0.05, 0.05]);
        let masks = occlusion_masks(std::slice::from_ref(&m), &cam, &pose, &real, &RenderConfig::default()).unwrap();
        // Virtual top face at depth 0.9: x ∈ [0, 0.1] → u ∈ [320, 375.6]; y ∈ ±0.05 → v ∈ 240 ± 27.8.
        let (fu, fv) = (500.0 / 0.9, 500.0 / 0.9);
        let rows = px(240.0 - 0.05 * fv, 240.0 + 0.05 * fv);
        let silhouette = px(320.0, 320.0 + 0.1 * fu) * rows;
        assert_eq!(masks[0].silhouette_px, silhouette);
        // The real box's top at depth 0.8 covers u < 320 + 0.05·500/0.8 = 351.25 over the same rows
        // (its v-range, 240 ± 31.25, contains the model's).
        let hidden = px(320.0, 320.0 + 0.05 * 500.0 / 0.8) * rows;
        assert_eq!(masks[0].visible_px, silhouette - hidden);
        // In front of the real box: nothing hidden.
        let front = model([0.05, 0.0, 0.25], [0.05, 0.05, 0.05]);
        let masks = occlusion_masks(&[front], &cam, &pose, &real, &RenderConfig::default()).unwrap();
        assert_eq!(masks[0].visible_px, masks[0].silhouette_px);
        let hidden_px = masks[0].coverage.iter().filter(|c| **c == COVER_HIDDEN).count();
        assert_eq!(hidden_px, 0);
    }

    #[test]
    fn wrong_sizes_and_poses_are_typed_errors() {
        let (cam, pose) = top_camera();
        let small = DepthImage { width: 10, height: 10, data: vec![0.0; 100] };
        assert!(matches!(
            occlusion_masks(&[], &cam, &pose, &small, &RenderConfig::default()),
            Err(ArError::ImageSize { .. })
        ));
        let mut nan_pose = pose;
        nan_pose.translation.x = f64::NAN;
        assert!(render_scene_depth(&ArScene::default(), &cam, &nan_pose, &RenderConfig::default()).is_err());
        let empty = render_scene_depth(&ArScene::default(), &cam, &pose, &RenderConfig::default()).unwrap();
        assert!(empty.data.iter().all(|d| *d == 0.0));
    }
}
