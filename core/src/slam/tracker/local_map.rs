//! Local mapping: keyframes and map points (insertion with new points from depth, local bundle
//! adjustment over a window of keyframes, culling), map reset and extension.

use std::collections::{BTreeMap, HashMap};

use nalgebra::Point3;

use super::tracking::{FrameData, PointMatch};
use super::{PoseSource, Tracker};
use crate::geometry::{PinholeCamera, Se3};
use crate::slam::ba::{BundleConfig, BundleObservation, BundleProblem};
use crate::slam::features::Descriptor;

/// A point id's index in a bundle problem (only queried, never iterated).
type PointIndex = HashMap<u64, usize, crate::IntKeyBuild>;

#[derive(Debug, Clone)]
pub(super) struct MapPoint {
    pub(super) p_in_map: Point3<f64>,
    pub(super) descriptor: Descriptor,
    pub(super) level: u8,
    pub(super) keyframes: Vec<usize>,
    pub(super) created_kf: usize,
    pub(super) n_visible: u32,
    pub(super) n_found: u32,
}

/// A local bundle problem and where its parts come from.
#[derive(Debug)]
pub(super) struct LocalBundle {
    problem: BundleProblem,
    /// The keyframe of each pose.
    kf_list: Vec<usize>,
    /// The map point id of each point.
    local_ids: Vec<u64>,
    /// The (keyframe, observation index) of each observation.
    obs_src: Vec<(usize, usize)>,
}

impl LocalBundle {
    /// Optimise on the threads `budget` grants; returns each observation's inlier flag.
    fn solve(&mut self, camera: &PinholeCamera, config: &BundleConfig, budget: &crate::ThreadBudget) -> Vec<bool> {
        self.problem.optimize_with_budget(camera, config, budget);
        self.problem.inlier_flags(camera, config)
    }
}

/// A keyframe's local bundle adjustment not applied yet ([`TrackerConfig::defer_local_bundle`]).
#[derive(Debug)]
pub(super) enum PendingBundle {
    /// Built, not started ([`Tracker::start_bundle`] starts it).
    Ready(LocalBundle, PinholeCamera),
    /// On its worker thread: the solved bundle and its inlier flags.
    Running(std::thread::JoinHandle<(LocalBundle, Vec<bool>)>),
}

#[derive(Debug, Clone, Copy)]
pub(super) struct KfObservation {
    pub(super) point_id: u64,
    pub(super) pixel: [f64; 2],
    pub(super) depth_m: Option<f64>,
    pub(super) sigma_px: f64,
}

#[derive(Debug, Clone)]
pub(super) struct KeyFrame {
    pub(super) map_from_camera: Se3,
    pub(super) observations: Vec<KfObservation>,
    /// Inserted at an estimated pose without tracking ([`TrackerConfig::extend_after_unmapped`]):
    /// held fixed in bundle adjustment.
    pub(super) fixed: bool,
}

impl Tracker {
    /// Insert a fixed keyframe at `world_from_camera` (the frame's output pose) so tracking goes
    /// on where the map has no points ([`TrackerConfig::extend_after_unmapped`]).
    pub(super) fn extend_map(
        &mut self,
        frame: &FrameData,
        camera: &PinholeCamera,
        world_from_camera: &Se3,
        prior: &Se3,
        view_index: u64,
    ) {
        let map_from_camera = self.world_from_map().inverse() * world_from_camera;
        let (map_from_camera, _) = self.insert_keyframe_with(frame, camera, map_from_camera, &[], true, false);
        self.n_extensions += 1;
        self.unmapped_streak = 0;
        // The next frame is seeded from here by the prior's motion, as from a tracked frame; the
        // motion gate predicts from it too (within the view the estimate's error is the last
        // tracked frame's plus the jitter).
        if self.last.is_some_and(|(_, _, v)| v != view_index) {
            self.view_tracked.clear();
        }
        self.view_tracked.push_back((map_from_camera, *prior));
        while self.view_tracked.len() > self.config.motion_gate_references.max(1) {
            self.view_tracked.pop_front();
        }
        self.last = Some((map_from_camera, *prior, view_index));
    }

    /// Drop the map's points and keyframes. The map frame, the world ← map gauge (with every view
    /// it was fitted to) and the last tracked frame stay: the next frame with depth starts the new
    /// map at its pose estimate in the same frame (dead-reckoned from the last tracked frame
    /// within its view, else the prior through the gauge), so the object map, placed with the
    /// gauge, stays where it is.
    pub(super) fn reset_map(&mut self) {
        self.points.clear();
        self.keyframes.clear();
        self.view_tracked.clear();
        self.n_resets += 1;
        self.lost_streak = 0;
        self.unmapped_streak = 0;
    }

    /// Bookkeeping after a successful pose: visibility counts, keyframe insertion (new points,
    /// local BA, culling). Returns the (possibly BA-refined) pose, the observed points and whether
    /// a keyframe was inserted.
    pub(super) fn after_tracking(
        &mut self,
        frame: &FrameData,
        camera: &PinholeCamera,
        map_from_camera: Se3,
        matches: &[PointMatch],
    ) -> (Se3, Vec<PointMatch>, bool) {
        let camera_from_map = map_from_camera.inverse();
        for p in self.points.values_mut() {
            let x = camera_from_map * p.p_in_map;
            if camera.project(&x).is_some_and(|uv| camera.contains(uv)) {
                p.n_visible += 1;
            }
        }
        for m in matches {
            if let Some(p) = self.points.get_mut(&m.point_id) {
                p.n_found += 1;
            }
        }
        self.frames_since_keyframe += 1;
        let need_kf = self.keyframes.is_empty()
            || self.frames_since_keyframe >= self.config.keyframe_max_interval
            || (matches.len() as f64) < self.config.keyframe_inlier_ratio * self.last_keyframe_tracked as f64;
        if !need_kf {
            return (map_from_camera, matches.to_vec(), false);
        }
        let (pose, observed) =
            self.insert_keyframe_with(frame, camera, map_from_camera, matches, false, self.config.defer_local_bundle);
        (pose, observed, true)
    }

    /// Start the keyframe's deferred local bundle adjustment, if one waits, on a worker thread of
    /// its own (one thread).
    pub(super) fn start_pending_bundle(&mut self) {
        if let Some(PendingBundle::Ready(mut bundle, camera)) = self.pending_bundle.take() {
            let config = self.config.bundle;
            self.pending_bundle = Some(PendingBundle::Running(std::thread::spawn(move || {
                let flags = bundle.solve(&camera, &config, &crate::ThreadBudget::new(1));
                (bundle, flags)
            })));
        }
    }

    /// Apply the keyframe's deferred local bundle adjustment, if any (waiting for its thread, or
    /// solving it here when it was not started), then cull; the last tracked frame (the keyframe's) takes the adjusted pose as the
    /// next frame's seed, the motion gate's reference and its trajectory entry. The tracker's
    /// state is then what it would have been had the adjustment run within the keyframe's frame.
    pub(super) fn settle_bundle(&mut self) {
        let (bundle, flags) = match self.pending_bundle.take() {
            None => return,
            Some(PendingBundle::Ready(mut bundle, camera)) => {
                let flags = bundle.solve(&camera, &self.config.bundle, &self.threads);
                (bundle, flags)
            }
            Some(PendingBundle::Running(handle)) => handle.join().unwrap_or_else(|e| std::panic::resume_unwind(e)),
        };
        self.apply_bundle(bundle, &flags);
        self.cull();
        let Some(pose) = self.keyframes.last().map(|k| k.map_from_camera) else {
            return;
        };
        if let Some(last) = self.last.as_mut() {
            last.0 = pose;
        }
        if let Some(newest) = self.view_tracked.back_mut() {
            newest.0 = pose;
        }
        if let Some(record) = self.records.last_mut() {
            record.map_from_camera = Some(pose);
        }
    }

    /// Insert a keyframe (`fixed`: held fixed in bundle adjustment) with new points from the
    /// unmatched keypoints with depth, then bundle-adjust and cull. With `defer` the adjustment
    /// is built and left pending; [`Self::settle_bundle`] applies it with the culling: the
    /// keyframe keeps `map_from_camera` and its points their positions until then.
    pub(super) fn insert_keyframe_with(
        &mut self,
        frame: &FrameData,
        camera: &PinholeCamera,
        map_from_camera: Se3,
        matches: &[PointMatch],
        fixed: bool,
        defer: bool,
    ) -> (Se3, Vec<PointMatch>) {
        let kf_index = self.keyframes.len();
        let kps = &frame.features.keypoints;
        let mut observations = Vec::with_capacity(matches.len() + self.config.max_new_points);
        let mut observed = matches.to_vec();
        let mut used = vec![false; kps.len()];
        for m in matches {
            let Some(k) = kps.get(m.keypoint) else {
                continue;
            };
            if let Some(u) = used.get_mut(m.keypoint) {
                *u = true;
            }
            if let Some(p) = self.points.get_mut(&m.point_id) {
                p.keyframes.push(kf_index);
            }
            observations.push(KfObservation {
                point_id: m.point_id,
                pixel: k.image_point(),
                depth_m: frame.depth_m.get(m.keypoint).copied().flatten(),
                sigma_px: f64::from(k.scale),
            });
        }
        // New points from unmatched keypoints with depth, closest first.
        let mut fresh: Vec<(usize, f64)> = (0..kps.len())
            .filter(|&i| !used.get(i).copied().unwrap_or(true))
            .filter_map(|i| Some((i, frame.depth_m.get(i).copied().flatten()?)))
            .collect();
        fresh.sort_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)));
        for &(i, d) in fresh.iter().take(self.config.max_new_points) {
            let (Some(k), Some(desc)) = (kps.get(i), frame.features.descriptors.get(i)) else {
                continue;
            };
            let [ku, kv] = k.image_point();
            let p_in_camera = camera.unproject(ku, kv, d);
            let id = self.next_point_id;
            self.next_point_id += 1;
            self.points.insert(
                id,
                MapPoint {
                    p_in_map: map_from_camera * p_in_camera,
                    descriptor: *desc,
                    level: k.level,
                    keyframes: vec![kf_index],
                    created_kf: kf_index,
                    n_visible: 1,
                    n_found: 1,
                },
            );
            observations.push(KfObservation {
                point_id: id,
                pixel: k.image_point(),
                depth_m: Some(d),
                sigma_px: f64::from(k.scale),
            });
            observed.push(PointMatch { point_id: id, keypoint: i });
        }
        self.keyframes.push(KeyFrame { map_from_camera, observations, fixed });
        self.frames_since_keyframe = 0;
        self.last_keyframe_tracked = matches.len().max(
            self.keyframes.last().map_or(0, |k| k.observations.len()).min(matches.len() + self.config.max_new_points),
        );
        if self.config.pose_source == PoseSource::Slam && self.keyframes.len() > 1 {
            if let Some(mut bundle) = self.local_bundle() {
                if defer {
                    self.pending_bundle = Some(PendingBundle::Ready(bundle, *camera));
                    return (map_from_camera, observed);
                }
                let flags = bundle.solve(camera, &self.config.bundle, &self.threads);
                self.apply_bundle(bundle, &flags);
            }
        }
        self.cull();
        observed.retain(|m| self.points.contains_key(&m.point_id));
        let pose = self.keyframes.last().map_or(map_from_camera, |k| k.map_from_camera);
        (pose, observed)
    }

    /// The local bundle problem of the newest keyframe: the last
    /// [`TrackerConfig::local_keyframes`] keyframes, their points and the keyframes outside the
    /// window that see them (fixed). None when a keyframe is missing.
    fn local_bundle(&self) -> Option<LocalBundle> {
        let n_kf = self.keyframes.len();
        let first_local = n_kf.saturating_sub(self.config.local_keyframes);
        // Points seen by the local window, numbered in order of first sight.
        let mut point_index: PointIndex = PointIndex::default();
        let mut local_ids: Vec<u64> = Vec::new();
        for kf in &self.keyframes[first_local..] {
            for o in &kf.observations {
                if self.points.contains_key(&o.point_id) {
                    point_index.entry(o.point_id).or_insert_with(|| {
                        local_ids.push(o.point_id);
                        local_ids.len() - 1
                    });
                }
            }
        }
        // Keyframes involved: the window plus fixed ones observing its points (points in id
        // order). The points' positions come along.
        let mut by_id: Vec<(u64, usize)> = local_ids.iter().enumerate().map(|(i, id)| (*id, i)).collect();
        by_id.sort_unstable();
        let mut points = vec![Point3::origin(); local_ids.len()];
        let mut kf_set: BTreeMap<usize, usize> = BTreeMap::new();
        for &(id, i) in &by_id {
            if let Some(p) = self.points.get(&id) {
                points[i] = p.p_in_map;
                for &k in &p.keyframes {
                    let n = kf_set.len();
                    kf_set.entry(k).or_insert(n);
                }
            }
        }
        for k in first_local..n_kf {
            let n = kf_set.len();
            kf_set.entry(k).or_insert(n);
        }
        let kf_list: Vec<usize> = {
            let mut v: Vec<(usize, usize)> = kf_set.iter().map(|(k, i)| (*i, *k)).collect();
            v.sort_unstable();
            v.into_iter().map(|(_, k)| k).collect()
        };
        let mut fixed: Vec<bool> = kf_list
            .iter()
            .map(|&k| k < first_local || k == 0 || self.keyframes.get(k).is_some_and(|kf| kf.fixed))
            .collect();
        if !fixed.iter().any(|&f| f) {
            if let Some(f) = kf_list.iter().position(|&k| k == first_local) {
                fixed[f] = true;
            }
        }
        let mut observations = Vec::new();
        let mut obs_src = Vec::new();
        for (pi, &k) in kf_list.iter().enumerate() {
            let Some(kf) = self.keyframes.get(k) else {
                continue;
            };
            for (oi, o) in kf.observations.iter().enumerate() {
                if let Some(&pt) = point_index.get(&o.point_id) {
                    observations.push(BundleObservation {
                        pose: pi,
                        point: pt,
                        pixel: o.pixel,
                        depth_m: o.depth_m,
                        sigma_px: o.sigma_px,
                    });
                    obs_src.push((k, oi));
                }
            }
        }
        let problem = BundleProblem {
            camera_from_world: kf_list
                .iter()
                .filter_map(|&k| self.keyframes.get(k).map(|kf| kf.map_from_camera.inverse()))
                .collect(),
            fixed,
            points,
            observations,
        };
        (problem.camera_from_world.len() == kf_list.len()).then_some(LocalBundle {
            problem,
            kf_list,
            local_ids,
            obs_src,
        })
    }

    /// Write a solved local bundle back: the variable keyframes' poses, the points, and drop the
    /// observations `flags` marks as outliers.
    fn apply_bundle(&mut self, bundle: LocalBundle, flags: &[bool]) {
        let LocalBundle { problem, kf_list, local_ids, obs_src } = bundle;
        for (pi, &k) in kf_list.iter().enumerate() {
            if !problem.fixed[pi] {
                if let (Some(kf), Some(p)) = (self.keyframes.get_mut(k), problem.camera_from_world.get(pi)) {
                    kf.map_from_camera = p.inverse();
                }
            }
        }
        for (id, q) in local_ids.iter().zip(&problem.points) {
            if let Some(p) = self.points.get_mut(id) {
                p.p_in_map = *q;
            }
        }
        // Drop outlier observations.
        let mut drop: BTreeMap<usize, Vec<usize>> = BTreeMap::new();
        for (flag, &(k, oi)) in flags.iter().zip(&obs_src) {
            if !flag {
                drop.entry(k).or_default().push(oi);
            }
        }
        for (k, list) in drop {
            let Some(kf) = self.keyframes.get_mut(k) else {
                continue;
            };
            // `list` is ascending: one pass keeps the others in order.
            let mut dropped = list.iter().peekable();
            let mut oi = 0;
            kf.observations.retain(|o| {
                let gone = dropped.next_if_eq(&&oi).is_some();
                oi += 1;
                if gone {
                    if let Some(p) = self.points.get_mut(&o.point_id) {
                        p.keyframes.retain(|&x| x != k);
                    }
                }
                !gone
            });
        }
    }

    pub(super) fn cull(&mut self) {
        let n_kf = self.keyframes.len();
        let c = &self.config;
        self.points.retain(|_, p| {
            if p.keyframes.is_empty() {
                return false;
            }
            if p.n_visible >= c.cull_min_visible && f64::from(p.n_found) < c.cull_found_ratio * f64::from(p.n_visible) {
                return false;
            }
            !(c.cull_after_keyframes > 0 && n_kf >= p.created_kf + 1 + c.cull_after_keyframes && p.keyframes.len() < 2)
        });
    }
}
