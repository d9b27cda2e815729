//! Per-frame pose: projection search of the map around seeds (the last tracked frame moved by the
//! prior's motion, the prior through the gauge), PnP RANSAC and robust refinement.

use super::local_map::MapPoint;
use super::{LostReason, Tracker};
use crate::frame::DepthImage;
use crate::geometry::{PinholeCamera, Se3};
use crate::slam::features::{hamming, Features};
use crate::slam::matcher::KeypointGrid;
use crate::slam::pnp::{refine_pose, solve_pnp_ransac, Correspondence};

/// Per-frame working data.
pub(super) struct FrameData {
    pub(super) features: Features,
    pub(super) depth_m: Vec<Option<f64>>,
    pub(super) grid: KeypointGrid,
}

/// A match from the projection search.
#[derive(Debug, Clone, Copy)]
pub(super) struct PointMatch {
    pub(super) point_id: u64,
    pub(super) keypoint: usize,
}

impl Tracker {
    /// Known pose: just associate to the map (no pose estimation). Returns map ← camera.
    pub(super) fn step_known_pose(
        &self,
        frame: &FrameData,
        camera: &PinholeCamera,
        world_from_camera: Se3,
    ) -> (Se3, Vec<PointMatch>, usize) {
        let map_from_camera = world_from_camera; // map frame = world for non-slam sources
        let matches = self.search_by_projection(
            frame,
            camera,
            &map_from_camera.inverse(),
            2.0 * self.config.fine_radius_px,
            true,
        );
        let n = matches.len();
        (map_from_camera, matches, n)
    }

    pub(super) fn step_slam(
        &self,
        frame: &FrameData,
        depth: &DepthImage,
        camera: &PinholeCamera,
        prior: &Se3,
        view_index: u64,
    ) -> Result<(Se3, Vec<PointMatch>, usize), LostReason> {
        let anchored = self.world_from_map().inverse() * prior;
        if self.points.is_empty() {
            let valid = frame.depth_m.iter().flatten().count();
            if valid < self.config.min_init_points {
                return Err(LostReason::NoDepth { valid, required: self.config.min_init_points });
            }
            // After a reset: dead-reckoned from the last tracked frame within its view.
            let start = match self.last {
                Some((last_map_from_camera, last_prior, last_view)) if last_view == view_index => {
                    last_map_from_camera * (last_prior.inverse() * prior)
                }
                _ => anchored,
            };
            return Ok((start, Vec::new(), 0));
        }
        let mut seeds = Vec::with_capacity(2);
        // The prior's motion since the last tracked frames of this view (same bias): the gate's
        // predictions (newest first); since the last one, the first seed.
        let mut predicted = Vec::new();
        if let Some((last_map_from_camera, last_prior, last_view)) = self.last {
            seeds.push(last_map_from_camera * (last_prior.inverse() * prior));
            if last_view == view_index {
                predicted = self
                    .view_tracked
                    .iter()
                    .rev()
                    .map(|(m, p)| {
                        let motion = p.inverse() * prior;
                        (m * motion, motion)
                    })
                    .collect();
            }
        }
        seeds.push(anchored);
        let (mut best_inliers, mut in_view) = (0, 0);
        let mut disagreement = None;
        for seed in seeds {
            match self.estimate_from_seed(frame, camera, &seed) {
                Ok(r) => {
                    match self.prior_disagreement(&r.0, &anchored).or_else(|| self.motion_gate(&r.0, &predicted)) {
                        None => return Ok(r),
                        Some(d) => disagreement = Some(d),
                    }
                }
                Err(n) => {
                    best_inliers = best_inliers.max(n);
                    in_view = in_view.max(self.points_in_view(camera, &seed.inverse(), depth));
                }
            }
        }
        if let Some(d) = disagreement {
            return Err(d);
        }
        Err(LostReason::TooFewInliers { inliers: best_inliers, required: self.config.min_tracked_inliers, in_view })
    }

    /// Map points `camera_from_map` predicts visible: in front of the camera, inside the image,
    /// and where the image has depth, within 5 cm or 5 % of it (a point behind what the camera
    /// sees, or where it sees nothing, does not count).
    pub(super) fn points_in_view(&self, camera: &PinholeCamera, camera_from_map: &Se3, depth: &DepthImage) -> usize {
        self.points
            .values()
            .filter(|p| {
                let x = camera_from_map * p.p_in_map;
                if x.z < self.config.min_depth_m {
                    return false;
                }
                let Some(uv) = camera.project(&x).filter(|uv| camera.contains(*uv)) else {
                    return false;
                };
                let (col, row) = (uv[0].floor() as usize, uv[1].floor() as usize);
                let d = depth.data.get(row * depth.width as usize + col).copied().unwrap_or(0.0);
                let d = f64::from(d);
                d.is_finite() && d > 0.0 && (d - x.z).abs() <= 0.05f64.max(0.05 * x.z)
            })
            .count()
    }

    /// Coarse projection search + RANSAC, then fine search + robust refinement. `Err(inliers)`.
    pub(super) fn estimate_from_seed(
        &self,
        frame: &FrameData,
        camera: &PinholeCamera,
        seed: &Se3,
    ) -> Result<(Se3, Vec<PointMatch>, usize), usize> {
        let coarse = self.search_by_projection(frame, camera, &seed.inverse(), self.config.coarse_radius_px, false);
        let corr = self.correspondences(frame, &coarse);
        let mut ransac = self.config.ransac;
        ransac.seed ^= self.frame_index.wrapping_mul(0x9E37_79B9_7F4A_7C15);
        let est = solve_pnp_ransac(&corr, camera, seed, &ransac, &self.config.refine).map_err(|_| 0usize)?;
        let fine = self.search_by_projection(
            frame,
            camera,
            &est.world_from_camera.inverse(),
            self.config.fine_radius_px,
            true,
        );
        let corr = self.correspondences(frame, &fine);
        let refined =
            refine_pose(&corr, camera, &est.world_from_camera, &self.config.refine).map_err(|_| est.n_inliers)?;
        if refined.n_inliers < self.config.min_tracked_inliers {
            return Err(refined.n_inliers);
        }
        let inlier_matches: Vec<PointMatch> =
            fine.iter().zip(&refined.inliers).filter_map(|(m, &k)| k.then_some(*m)).collect();
        Ok((refined.world_from_camera, inlier_matches, refined.n_inliers))
    }

    pub(super) fn correspondences(&self, frame: &FrameData, matches: &[PointMatch]) -> Vec<Correspondence> {
        matches
            .iter()
            .filter_map(|m| {
                let p = self.points.get(&m.point_id)?;
                let k = frame.features.keypoints.get(m.keypoint)?;
                Some(Correspondence {
                    p_in_world: p.p_in_map,
                    pixel: k.image_point(),
                    depth_m: frame.depth_m.get(m.keypoint).copied().flatten(),
                    sigma_px: f64::from(k.scale),
                })
            })
            .collect()
    }

    /// Project every map point with `camera_from_map` and match it to the best keypoint within
    /// `radius_px × scale` (ratio test; each keypoint keeps its closest point, the first in point
    /// order among equals). With two threads ([`Tracker::set_threads`]) and enough points, each searches half of
    /// the points (in point order) and the halves' winners are merged: the same matches.
    pub(super) fn search_by_projection(
        &self,
        frame: &FrameData,
        camera: &PinholeCamera,
        camera_from_map: &Se3,
        radius_px: f64,
        scale_radius: bool,
    ) -> Vec<PointMatch> {
        let search = Search { frame, camera, camera_from_map, radius_px, scale_radius };
        let n = self.points.len();
        let middle = (self.threads.get() > 1 && n >= PARALLEL_SEARCH_MIN_POINTS)
            .then(|| self.points.keys().nth(n / 2).copied())
            .flatten();
        let best_for_kp = match middle {
            Some(middle) => {
                let (mut first, second) = std::thread::scope(|s| {
                    let second = s.spawn(|| self.best_for_keypoints(&search, self.points.range(middle..)));
                    let first = self.best_for_keypoints(&search, self.points.range(..middle));
                    (first, second.join().unwrap_or_else(|e| std::panic::resume_unwind(e)))
                });
                // The second half's points come later: they win only when strictly closer.
                for (a, b) in first.iter_mut().zip(second) {
                    if let Some((d, _)) = b {
                        if a.is_none_or(|(da, _)| d < da) {
                            *a = b;
                        }
                    }
                }
                first
            }
            None => self.best_for_keypoints(&search, self.points.iter()),
        };
        best_for_kp
            .iter()
            .enumerate()
            .filter_map(|(i, s)| s.map(|(_, id)| PointMatch { point_id: id, keypoint: i }))
            .collect()
    }

    /// Per keypoint, the (distance, point id) of the closest of `points` that matched it in a
    /// projection search (the first among equals).
    fn best_for_keypoints<'a>(
        &self,
        search: &Search<'_>,
        points: impl Iterator<Item = (&'a u64, &'a MapPoint)>,
    ) -> Vec<Option<(u32, u64)>> {
        let frame = search.frame;
        let camera = search.camera;
        let kps = &frame.features.keypoints;
        let mut best_for_kp: Vec<Option<(u32, u64)>> = vec![None; kps.len()];
        let mut cand = Vec::new();
        let scale_factor = self.config.orb.scale_factor;
        for (&id, p) in points {
            let x = search.camera_from_map * p.p_in_map;
            if x.z < self.config.min_depth_m {
                continue;
            }
            let Some(uv) = camera.project(&x) else {
                continue;
            };
            if !camera.contains(uv) {
                continue;
            }
            let r = if search.scale_radius {
                search.radius_px * scale_factor.powi(i32::from(p.level))
            } else {
                search.radius_px
            };
            // The grid holds keypoint indices (pixel centre at the index): image point − 0.5.
            frame.grid.within(kps, (uv[0] - 0.5) as f32, (uv[1] - 0.5) as f32, r as f32, &mut cand);
            let (mut best, mut second, mut best_i) = (u32::MAX, u32::MAX, usize::MAX);
            for &i in &cand {
                let i = i as usize;
                let (Some(k), Some(d)) = (kps.get(i), frame.features.descriptors.get(i)) else {
                    continue;
                };
                if k.level.abs_diff(p.level) > self.config.max_level_difference {
                    continue;
                }
                let dist = hamming(&p.descriptor, d);
                if dist < best {
                    second = best;
                    best = dist;
                    best_i = i;
                } else if dist < second {
                    second = dist;
                }
            }
            if best > self.config.match_max_distance
                || (second != u32::MAX && best as f32 >= self.config.match_ratio * second as f32)
            {
                continue;
            }
            if let Some(slot) = best_for_kp.get_mut(best_i) {
                if slot.is_none_or(|(d, _)| best < d) {
                    *slot = Some((best, id));
                }
            }
        }
        best_for_kp
    }
}

/// Map points below which a projection search stays on one thread (a second thread costs a
/// spawn, some tens of microseconds).
const PARALLEL_SEARCH_MIN_POINTS: usize = 400;

/// One projection search: the frame, the camera at `camera_from_map`, the search radius
/// (`radius_px`, times the point's level scale if `scale_radius`).
struct Search<'a> {
    frame: &'a FrameData,
    camera: &'a PinholeCamera,
    camera_from_map: &'a Se3,
    radius_px: f64,
    scale_radius: bool,
}
