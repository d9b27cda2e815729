//! Interaction: the map object under a pixel, and the event its class fires (paper: "clicking
//! different real-world objects produces different virtual interactive effects").

use std::collections::BTreeMap;

use nalgebra::{Point3, Vector3};
use serde::{Deserialize, Serialize};

use super::solid::Solid;
use super::{bad, ArError, ArScene, RenderConfig};
use crate::geometry::{PinholeCamera, Se3};
use crate::map::Label;

/// Event names per class.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(default)]
pub struct InteractionConfig {
    /// Event fired when an object of a class is picked; a class not listed fires
    /// `"<class>_selected"` (e.g. `"cup_selected"`). Default: empty.
    pub events: BTreeMap<Label, String>,
}

impl InteractionConfig {
    /// The event a class fires.
    pub fn event_of(&self, label: Label) -> String {
        self.events.get(&label).cloned().unwrap_or_else(|| format!("{label}_selected"))
    }
}

/// A pick that landed on a map object.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PickEvent {
    /// The pixel (column, row).
    pub pixel: [f64; 2],
    /// The object hit first along the pixel's ray.
    pub object_id: u32,
    /// Its class.
    pub label: Label,
    /// The event its class fires.
    pub event: String,
    /// Depth of the hit along the optical axis, metres.
    pub depth_m: f64,
    /// The hit point, world frame.
    pub point_in_world: [f64; 3],
}

/// Cast the ray through `pixel` (image coordinates, (0.5, 0.5) = centre of the top-left pixel) and
/// return the first map object it meets within the render range; `None` when the first surface is
/// the table or nothing (an empty map included). A pixel outside the image or non-finite is an error.
pub fn pick(
    scene: &ArScene,
    camera: &PinholeCamera,
    world_from_camera: &Se3,
    pixel: [f64; 2],
    render: &RenderConfig,
    config: &InteractionConfig,
) -> Result<Option<PickEvent>, ArError> {
    scene.validate()?;
    camera.validate()?;
    super::check_finite("world_from_camera", world_from_camera.to_homogeneous().as_slice())?;
    if !(pixel.iter().all(|v| v.is_finite()) && camera.contains(pixel)) {
        return Err(bad("picks", format!("pixel {pixel:?} outside the {}x{} image", camera.width, camera.height)));
    }
    let dir_in_camera = Vector3::new((pixel[0] - camera.cx) / camera.fx, (pixel[1] - camera.cy) / camera.fy, 1.0);
    let origin = Point3::from(world_from_camera.translation.vector);
    let dir = world_from_camera.rotation * dir_in_camera;
    let mut best: Option<(Option<usize>, f64)> = None;
    let solids = scene.objects.iter().enumerate().map(|(i, o)| (Some(i), Solid::of_real(o)));
    for (who, s) in solids.chain(scene.table.iter().map(|t| (None, Solid::of_table(t)))) {
        if let Some(t) = s.hit_world(&origin, &dir, render.near_m) {
            if t <= render.far_m && best.is_none_or(|b| t < b.1) {
                best = Some((who, t));
            }
        }
    }
    Ok(best.and_then(|(who, t)| {
        let o = &scene.objects[who?];
        let p = origin + dir * t;
        Some(PickEvent {
            pixel,
            object_id: o.id,
            label: o.label,
            event: config.event_of(o.label),
            depth_m: t,
            point_in_world: [p.x, p.y, p.z],
        })
    }))
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // tests may unwrap (STYLE.md, 18)
mod tests {
    use nalgebra::{Translation3, UnitQuaternion};

    use super::*;
    use crate::ar::{RealObject, TableTop};
    use crate::geometry::{ObjectGeometry, Shape};

    #[test]
    fn a_pixel_picks_the_object_under_it() {
        let cam = PinholeCamera::new(640, 480, 500.0, 500.0, 320.0, 240.0).unwrap();
        let down = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI);
        let pose = Se3::from_parts(Translation3::new(0.0, 0.0, 1.0), down);
        let cup = RealObject {
            id: 5,
            label: Label::Cup,
            geometry: ObjectGeometry {
                shape: Shape::Cylinder,
                center: Vector3::new(0.0, 0.0, 0.05),
                yaw_rad: 0.0,
                half_extents: Vector3::new(0.04, 0.04, 0.05),
            },
        };
        let table = TableTop { center_xy_m: [0.0, 0.0], size_xy_m: [1.0, 1.0], height_m: 0.0, thickness_m: 0.05 };
        let scene = ArScene { objects: vec![cup], table: Some(table) };
        let mut config = InteractionConfig::default();
        config.events.insert(Label::Cup, "pour_tea".into());
        let r = RenderConfig::default();
        let hit = pick(&scene, &cam, &pose, [320.0, 240.0], &r, &config).unwrap().unwrap();
        assert_eq!((hit.object_id, hit.event.as_str()), (5, "pour_tea"));
        assert!((hit.depth_m - 0.9).abs() < 1e-12);
        // 0.05 m off-centre at depth 0.9 is beyond the radius: the table.
        assert!(pick(&scene, &cam, &pose, [320.0 + 0.05 * 500.0 / 0.9, 240.0], &r, &config).unwrap().is_none());
        assert!(pick(&ArScene::default(), &cam, &pose, [1.0, 1.0], &r, &config).unwrap().is_none());
        assert!(pick(&scene, &cam, &pose, [700.0, 1.0], &r, &config).is_err());
        assert_eq!(InteractionConfig::default().event_of(Label::Book), "book_selected");
    }
}
