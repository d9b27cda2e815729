//! The arm drawn from its URDF: each link's collision mesh, logged once (static) at
//! `world/robot/<link>/mesh` with the mesh's pose in the link frame; the links' world poses are
//! logged per frame by [`super::Recorder::log_robot_pose`].
//!
//! Collision meshes, not the visual ones: for the Panda of the mani-skill package they are 0.15 MB
//! in all (STL) against 10 MB of textured glTF, and they show the arm's pose and volume, which is
//! what a recording needs.

use std::path::Path;

use nalgebra::{Translation3, UnitQuaternion};

use super::{transform, RecordError, Recorder};
use crate::geometry::Se3;

/// Colour of the drawn arm.
const ROBOT_COLOR: [u8; 3] = [225, 225, 230];

/// Log every link's collision mesh under `world/robot/<link>/mesh`; returns the names of the
/// links that have one.
pub(super) fn log_model(rec: &Recorder, urdf_path: &Path) -> Result<Vec<String>, RecordError> {
    let robot_err = |path: &Path, reason: String| RecordError::Robot { path: path.display().to_string(), reason };
    let robot = urdf_rs::read_file(urdf_path).map_err(|e| robot_err(urdf_path, e.to_string()))?;
    let dir = urdf_path.parent().unwrap_or_else(|| Path::new("."));
    let mut drawn = Vec::new();
    for link in &robot.links {
        let Some((collision, filename)) = link.collision.iter().find_map(|c| match &c.geometry {
            urdf_rs::Geometry::Mesh { filename, .. } => Some((c, filename)),
            _ => None,
        }) else {
            continue;
        };
        let mesh_path = dir.join(filename.trim_start_matches("package://"));
        let asset = rerun::Asset3D::from_file_path(&mesh_path)
            .map_err(|e| robot_err(&mesh_path, e.to_string()))?
            .with_albedo_factor(rerun::Rgba32::from_rgb(ROBOT_COLOR[0], ROBOT_COLOR[1], ROBOT_COLOR[2]));
        let o = &collision.origin;
        let link_from_mesh = Se3::from_parts(
            Translation3::new(o.xyz[0], o.xyz[1], o.xyz[2]),
            UnitQuaternion::from_euler_angles(o.rpy[0], o.rpy[1], o.rpy[2]),
        );
        let entity = format!("world/robot/{}/mesh", link.name);
        rec.log_static(&entity, &transform(&link_from_mesh))?;
        rec.log_static(&entity, &asset)?;
        drawn.push(link.name.clone());
    }
    if drawn.is_empty() {
        return Err(robot_err(urdf_path, "no link has a collision mesh".into()));
    }
    Ok(drawn)
}
