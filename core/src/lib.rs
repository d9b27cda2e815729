//! objslam core: the brain of the object-SLAM active-mapping testbed.
//!
//! The simulator (Python, SAPIEN) senses and acts; this crate updates beliefs and decides. Data
//! flows one way per frame (see `ARCHITECTURE.md`): a [`frame::Frame`] (image, depth, intrinsics,
//! camera pose, detections) goes in; the [`map::ObjectMap`] comes out; [`eval`] scores it against
//! ground truth that never enters the estimator.
//!
//! Modules, one concept each:
//! - [`active`]: the exploration session: Init views, grid updates, next view per strategy.
//! - [`ar`]: augmented reality on the object map: registration, occlusion, collision, picking.
//! - [`association`]: ensemble object data association (M-IoU, Mann-Whitney, t-tests, P-IoU,
//!   duplicate merge) and association metrics.
//! - [`geometry`]: SE(3), pinhole camera, 2D boxes, yaw-oriented boxes and cylinders, IoUs.
//! - [`frame`]: sensor frames and detections, validated at the boundary.
//! - [`map`]: the object map, labels, versioned save/load.
//! - [`naive`]: the foundation's baseline estimator (the `naive` association ablation).
//! - [`explore`]: surface occupancy grids, ray-cast visibility, the next-best-view utility,
//!   candidate views and exploration baselines.
//! - [`objects`]: object parameterization: iForest centroid/scale, LSD segments, line-alignment yaw,
//!   joint yaw/scale refinement, class → model (paper Sec. "Object parameterization").
//! - [`eval`]: matching to ground truth, 3D/2D IoU, CDE, YAE, counts.
//! - [`pipeline`]: association (naive or ensemble modes) + parameterization → the object map.
//! - [`plan`]: Panda kinematics, collision checking, RRT-Connect, Ruckig trajectories, grasps.
//! - [`topo`]: semantic topological map, random-walk descriptors, scene matching, relocalisation.
//! - `record` (feature `rerun`): one Rerun recording per run.
//! - [`sensor`]: the RGB-D camera model (D435-class active-stereo depth, colour noise and blur,
//!   calibration errors) the simulator applies to rendered frames.
//! - [`slam`]: RGB-D visual tracking (ORB features, PnP + RANSAC, local BA), pose sources, ATE/RPE.
//! - [`system`]: the per-frame loop (tracking → gauge → pipeline → grids) and the session's
//!   decisions behind one type, [`system::System`].

pub mod active;
pub mod ar;
pub mod association;
pub mod eval;
pub mod explore;
pub mod frame;
pub mod geometry;
pub mod map;
pub mod naive;
pub mod objects;
pub mod pipeline;
pub mod plan;
#[cfg(feature = "rerun")]
pub mod record;
pub mod sensor;
pub mod slam;
pub mod system;
pub mod topo;

/// Threads one frame's work may use (the sensor model's row parts, line segments beside
/// tracking, the ORB pyramid levels and the projection searches inside tracking): two where the
/// machine has two cores or more, else one.
pub(crate) fn worker_threads() -> usize {
    static THREADS: std::sync::OnceLock<usize> = std::sync::OnceLock::new();
    *THREADS.get_or_init(|| std::thread::available_parallelism().map_or(1, |n| n.get()).min(2))
}
