//! Camera poses: candidate views around the objects, and the baseline view generators
//! (Init: four table corners; Coverage: Boustrophedon scan; Random: random reachable views).

use nalgebra::{Point3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::visibility::Occluders;
use super::{CandidateConfig, ExploreError, GridConfig, TableRect};
use crate::geometry::{look_at, look_at_with_up, PinholeCamera, Se3};
use crate::map::ObjectMap;

/// Whether the arm can place the camera at a pose (the lead implements it with IK). Any
/// `Fn(&Se3) -> bool` is one.
pub trait Reachability {
    /// `true` when `world_from_camera` is reachable.
    fn reachable(&self, world_from_camera: &Se3) -> bool;
}

impl<F: Fn(&Se3) -> bool> Reachability for F {
    fn reachable(&self, world_from_camera: &Se3) -> bool {
        self(world_from_camera)
    }
}

/// Everything is reachable (tests, synthetic maps).
#[derive(Debug, Clone, Copy, Default)]
pub struct AlwaysReachable;

impl Reachability for AlwaysReachable {
    fn reachable(&self, _: &Se3) -> bool {
        true
    }
}

/// Most views of a coverage sweep (a lawn-mower pattern over the table is tens of views).
pub const MAX_COVERAGE_VIEWS: usize = 10_000;

/// A candidate view with where it came from.
#[derive(Debug, Clone, PartialEq)]
pub struct CandidateView {
    /// The camera pose (OpenCV axes).
    pub world_from_camera: Se3,
    /// The object it was sampled around (`None` for generator baselines).
    pub target_object: Option<u32>,
}

/// Whether a camera position is admissible: above the table by `min_camera_height_m` and outside
/// every object primitive inflated by `collision_margin_m`.
pub fn camera_position_free(eye: &Point3<f64>, occluders: &Occluders, config: &CandidateConfig) -> bool {
    eye.z >= config.min_camera_height_m && !occluders.point_inside_any(eye, config.collision_margin_m)
}

/// Candidate views around the objects (paper: "sampled around the objects"): for each object in
/// map order, `views_per_object` eyes at distance `distance_m` (uniform in the range) from its
/// centre, azimuth stratified over the circle (one uniform draw per stratum), elevation uniform in
/// `elevation_deg`, looking at the centre; kept when collision-free and `reachable`. Deterministic
/// given `seed`.
pub fn sample_candidates(
    map: &ObjectMap,
    config: &CandidateConfig,
    grid: &GridConfig,
    reachable: &dyn Reachability,
    seed: u64,
) -> Result<Vec<CandidateView>, ExploreError> {
    sample_candidates_around(map, None, config, grid, reachable, seed)
}

/// [`sample_candidates`] restricted to the objects in `around` (e.g. those with s(x) = 1, from
/// [`super::ObjectFeatures::explore`]); `None` = every object. Collision checks still use the whole
/// map. The random stream is drawn per sampled object in map order, so the same `around` and
/// seed give the same views.
pub fn sample_candidates_around(
    map: &ObjectMap,
    around: Option<&[u32]>,
    config: &CandidateConfig,
    grid: &GridConfig,
    reachable: &dyn Reachability,
    seed: u64,
) -> Result<Vec<CandidateView>, ExploreError> {
    let targets: Vec<(Point3<f64>, Option<u32>)> = map
        .objects
        .iter()
        .filter(|o| around.is_none_or(|ids| ids.contains(&o.id)))
        .map(|o| (Point3::from(o.world_from_object.translation.vector), Some(o.id)))
        .filter(|(c, _)| c.coords.iter().all(|v| v.is_finite()))
        .collect();
    views_around(&targets, map, config, grid, reachable, seed)
}

/// For each target in order, `views_per_object` views looking at it (azimuth stratified over the
/// circle, one uniform draw per stratum; elevation uniform in `elevation_deg`; distance uniform in
/// `distance_m`), kept when collision-free among the map's objects and `reachable`. One random
/// stream seeded by `seed`, drawn per target in order.
fn views_around(
    targets: &[(Point3<f64>, Option<u32>)],
    map: &ObjectMap,
    config: &CandidateConfig,
    grid: &GridConfig,
    reachable: &dyn Reachability,
    seed: u64,
) -> Result<Vec<CandidateView>, ExploreError> {
    config.validate()?;
    let occluders = Occluders::from_map(map, grid);
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut out = Vec::new();
    let n = config.views_per_object;
    for (target, target_object) in targets {
        for k in 0..n {
            let az = std::f64::consts::TAU * (k as f64 + rng.random::<f64>()) / n as f64;
            let el = rng.random_range(config.elevation_deg[0]..=config.elevation_deg[1]).to_radians();
            let d = rng.random_range(config.distance_m[0]..=config.distance_m[1]);
            let eye = target + Vector3::new(el.cos() * az.cos(), el.cos() * az.sin(), el.sin()) * d;
            if !camera_position_free(&eye, &occluders, config) {
                continue;
            }
            let pose = look_at(&eye, target)?;
            if reachable.reachable(&pose) {
                out.push(CandidateView { world_from_camera: pose, target_object: *target_object });
            }
        }
    }
    Ok(out)
}

/// Candidate views aimed at points rather than objects (e.g. unseen table cells from
/// [`super::discovery_targets`]): `views_per_object` per target as [`sample_candidates_around`]
/// samples them around an object centre, `target_object` = `None`. Deterministic given `seed`.
pub fn sample_candidates_at(
    targets: &[Point3<f64>],
    map: &ObjectMap,
    config: &CandidateConfig,
    grid: &GridConfig,
    reachable: &dyn Reachability,
    seed: u64,
) -> Result<Vec<CandidateView>, ExploreError> {
    if targets.iter().any(|t| !t.coords.iter().all(|v| v.is_finite())) {
        return Err(ExploreError::NonFinite { field: "candidate target" });
    }
    let targets: Vec<(Point3<f64>, Option<u32>)> = targets.iter().map(|t| (*t, None)).collect();
    views_around(&targets, map, config, grid, reachable, seed)
}

/// Init (paper: "the camera is sequentially placed over the four desk corners from a top view"):
/// eyes `init_height_m` above the four corners of the table inset by `init_inset_m`, tilted
/// `init_tilt_deg` towards the table centre (0 = straight down), in the order near-left,
/// far-left, far-right, near-right (x = distance from the robot).
pub fn init_views(table: &TableRect, config: &CandidateConfig) -> Result<Vec<Se3>, ExploreError> {
    config.validate()?;
    table.validate()?;
    let (hx, hy) = (
        (table.size_m[0] / 2.0 - config.init_inset_m).max(0.0),
        (table.size_m[1] / 2.0 - config.init_inset_m).max(0.0),
    );
    let [cx, cy] = table.center_m;
    let h = config.init_height_m;
    let corners = [[cx - hx, cy + hy], [cx + hx, cy + hy], [cx + hx, cy - hy], [cx - hx, cy - hy]];
    corners
        .iter()
        .map(|p| {
            let eye = Point3::new(p[0], p[1], table.height_m + h);
            let inward = Vector3::new(cx - p[0], cy - p[1], 0.0);
            let shift = h * config.init_tilt_deg.to_radians().tan();
            let offset =
                if inward.norm() > 1e-9 { inward / inward.norm() * shift.min(inward.norm()) } else { Vector3::zeros() };
            let target = Point3::new(p[0], p[1], table.height_m) + offset;
            look_at(&eye, &target).map_err(ExploreError::from)
        })
        .collect()
}

/// Coverage (paper: a Boustrophedon coverage trajectory over the scene): top-down views at
/// `coverage_height_m` over the table inset by `coverage_inset_m`, on lanes of constant x spaced
/// by the image footprint's height × (1 − `coverage_overlap`), waypoints along each lane spaced by
/// the footprint's width × (1 − overlap), alternating direction lane by lane. Every view has the
/// same orientation: image up along world +x (away from the robot), so image u runs along −y.
pub fn coverage_views(
    table: &TableRect,
    camera: &PinholeCamera,
    config: &CandidateConfig,
) -> Result<Vec<Se3>, ExploreError> {
    config.validate()?;
    table.validate()?;
    camera.validate().map_err(ExploreError::Geometry)?;
    let h = config.coverage_height_m;
    let keep = 1.0 - config.coverage_overlap;
    // Top-down with up = away from the robot: image v runs along world x, u along world y.
    let step_x = (h * f64::from(camera.height) / camera.fy * keep).max(1e-3);
    let step_y = (h * f64::from(camera.width) / camera.fx * keep).max(1e-3);
    let (hx, hy) = (
        (table.size_m[0] / 2.0 - config.coverage_inset_m).max(0.0),
        (table.size_m[1] / 2.0 - config.coverage_inset_m).max(0.0),
    );
    let lanes = |half: f64, step: f64| -> Vec<f64> {
        let n = ((2.0 * half / step).ceil() as usize).max(1);
        (0..=n).map(|i| -half + 2.0 * half * i as f64 / n as f64).collect()
    };
    let n_lanes = |half: f64, step: f64| (2.0 * half / step).ceil().max(1.0) + 1.0;
    let n_views = n_lanes(hx, step_x) * n_lanes(hy, step_y);
    if n_views.is_nan() || n_views > MAX_COVERAGE_VIEWS as f64 {
        return Err(ExploreError::InvalidConfig {
            field: "coverage_height_m",
            reason: format!("the coverage sweep would take {n_views} views (at most {MAX_COVERAGE_VIEWS})"),
        });
    }
    let xs = lanes(hx, step_x);
    let ys = lanes(hy, step_y);
    let mut out = Vec::with_capacity(xs.len() * ys.len());
    for (i, x) in xs.iter().enumerate() {
        let row: Vec<f64> = if i % 2 == 0 { ys.clone() } else { ys.iter().rev().copied().collect() };
        for y in row {
            let eye = Point3::new(table.center_m[0] + x, table.center_m[1] + y, table.height_m + h);
            out.push(look_at_with_up(&eye, &Point3::new(eye.x, eye.y, table.height_m), &Vector3::x())?);
        }
    }
    Ok(out)
}

/// Random (paper: "the camera pose is randomly sampled from the reachable set"): eyes uniform
/// over the table rectangle (inset by `coverage_inset_m`) at heights uniform in
/// `random_height_m` above it, looking at a uniform point of the table; kept when collision-free
/// and reachable; at most `count` views from at most `count × max_attempts_per_view` draws.
pub fn random_views(
    table: &TableRect,
    map: &ObjectMap,
    config: &CandidateConfig,
    grid: &GridConfig,
    reachable: &dyn Reachability,
    count: usize,
    seed: u64,
) -> Result<Vec<Se3>, ExploreError> {
    config.validate()?;
    table.validate()?;
    let occluders = Occluders::from_map(map, grid);
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let (hx, hy) = (
        (table.size_m[0] / 2.0 - config.coverage_inset_m).max(0.0),
        (table.size_m[1] / 2.0 - config.coverage_inset_m).max(0.0),
    );
    let mut out = Vec::with_capacity(count);
    for _ in 0..count.saturating_mul(config.max_attempts_per_view) {
        if out.len() >= count {
            break;
        }
        let ex = table.center_m[0] + rng.random_range(-hx..=hx);
        let ey = table.center_m[1] + rng.random_range(-hy..=hy);
        let ez = table.height_m + rng.random_range(config.random_height_m[0]..=config.random_height_m[1]);
        let tx = table.center_m[0] + rng.random_range(-hx..=hx);
        let ty = table.center_m[1] + rng.random_range(-hy..=hy);
        let eye = Point3::new(ex, ey, ez);
        if !camera_position_free(&eye, &occluders, config) {
            continue;
        }
        let pose = look_at(&eye, &Point3::new(tx, ty, table.height_m))?;
        if reachable.reachable(&pose) {
            out.push(pose);
        }
    }
    Ok(out)
}
