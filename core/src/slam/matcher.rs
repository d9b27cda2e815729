//! Descriptor matching: brute force with ratio test and orientation-consistency histogram, and a
//! keypoint grid for projection-guided search.

use serde::{Deserialize, Serialize};

use super::features::{hamming, Descriptor, Keypoint};

/// Configuration of descriptor matching.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MatchConfig {
    /// Largest accepted Hamming distance (ORB-SLAM2 `TH_HIGH` = 100, `TH_LOW` = 50; of 256 bits).
    pub max_distance: u32,
    /// Lowe ratio: the best distance must be below `ratio` × the second best (ORB-SLAM2: 0.6–0.9;
    /// 0.8 here).
    pub ratio: f32,
    /// Keep only matches whose orientation change falls in the three most populated bins of a
    /// histogram (ORB-SLAM2 `mbCheckOrientation`).
    pub check_orientation: bool,
    /// Bins of that histogram over 360° (ORB-SLAM2 `HISTO_LENGTH` = 30).
    pub orientation_bins: usize,
}

impl Default for MatchConfig {
    fn default() -> Self {
        Self { max_distance: 64, ratio: 0.8, check_orientation: true, orientation_bins: 30 }
    }
}

/// A match between `query[query_index]` and `train[train_index]`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FeatureMatch {
    /// Index into the query set.
    pub query_index: usize,
    /// Index into the train set.
    pub train_index: usize,
    /// Hamming distance.
    pub distance: u32,
}

/// Brute-force matching of every query descriptor against every train descriptor: ratio test,
/// distance threshold, one query per train (the closest wins), then (optionally) the orientation
/// consistency check. Output sorted by query index.
pub fn match_brute_force(
    query: &[Descriptor],
    query_keypoints: &[Keypoint],
    train: &[Descriptor],
    train_keypoints: &[Keypoint],
    config: &MatchConfig,
) -> Vec<FeatureMatch> {
    let mut best_for_train: Vec<Option<FeatureMatch>> = vec![None; train.len()];
    for (qi, q) in query.iter().enumerate() {
        let (mut best, mut second, mut best_i) = (u32::MAX, u32::MAX, usize::MAX);
        for (ti, t) in train.iter().enumerate() {
            let d = hamming(q, t);
            if d < best {
                second = best;
                best = d;
                best_i = ti;
            } else if d < second {
                second = d;
            }
        }
        if best > config.max_distance || (best as f32) >= config.ratio * second as f32 {
            continue;
        }
        if let Some(slot) = best_for_train.get_mut(best_i) {
            if slot.is_none_or(|m| best < m.distance) {
                *slot = Some(FeatureMatch { query_index: qi, train_index: best_i, distance: best });
            }
        }
    }
    let mut matches: Vec<FeatureMatch> = best_for_train.into_iter().flatten().collect();
    matches.sort_unstable_by_key(|m| m.query_index);
    if config.check_orientation {
        let keep = orientation_consistent(&matches, query_keypoints, train_keypoints, config.orientation_bins);
        matches = matches.into_iter().zip(keep).filter_map(|(m, k)| k.then_some(m)).collect();
    }
    matches
}

/// Which matches fall in the three most populated bins of the orientation-change histogram
/// (second and third bins only if they hold ≥ 10 % of the first, as in ORB-SLAM2).
pub fn orientation_consistent(matches: &[FeatureMatch], query: &[Keypoint], train: &[Keypoint], bins: usize) -> Vec<bool> {
    let bins = bins.max(1);
    let bin_of: Vec<Option<usize>> = matches
        .iter()
        .map(|m| {
            let (q, t) = (query.get(m.query_index)?, train.get(m.train_index)?);
            let d = (t.angle_rad - q.angle_rad).rem_euclid(std::f32::consts::TAU);
            Some(((d / std::f32::consts::TAU * bins as f32) as usize).min(bins - 1))
        })
        .collect();
    let mut hist = vec![0usize; bins];
    for b in bin_of.iter().flatten() {
        hist[*b] += 1;
    }
    let mut order: Vec<usize> = (0..bins).collect();
    order.sort_by_key(|&b| (std::cmp::Reverse(hist[b]), b));
    let top = hist[order[0]];
    let kept: Vec<usize> = order.iter().take(3).copied().filter(|&b| hist[b] > 0 && hist[b] * 10 >= top).collect();
    bin_of.iter().map(|b| b.is_some_and(|b| kept.contains(&b))).collect()
}

/// A uniform grid over level-0 pixels holding keypoint indices, for radius searches.
#[derive(Debug, Clone)]
pub struct KeypointGrid {
    cell_px: f32,
    cols: usize,
    rows: usize,
    cells: Vec<Vec<u32>>,
}

impl KeypointGrid {
    /// Index `keypoints` of an image of `width` x `height` pixels on cells of `cell_px`.
    pub fn new(keypoints: &[Keypoint], width: u32, height: u32, cell_px: f32) -> Self {
        let cell_px = cell_px.max(1.0);
        let cols = ((width as f32 / cell_px).ceil() as usize).max(1);
        let rows = ((height as f32 / cell_px).ceil() as usize).max(1);
        let mut cells = vec![Vec::new(); cols * rows];
        for (i, k) in keypoints.iter().enumerate() {
            let (cx, cy) = ((k.x / cell_px) as usize, (k.y / cell_px) as usize);
            if k.x >= 0.0 && k.y >= 0.0 && cx < cols && cy < rows {
                cells[cy * cols + cx].push(i as u32);
            }
        }
        Self { cell_px, cols, rows, cells }
    }

    /// Indices of keypoints within `radius_px` of `(u, v)` (appended to `out`, which is cleared).
    pub fn within(&self, keypoints: &[Keypoint], u: f32, v: f32, radius_px: f32, out: &mut Vec<u32>) {
        out.clear();
        if !(u.is_finite() && v.is_finite()) {
            return;
        }
        let c0 = ((u - radius_px) / self.cell_px).floor().max(0.0) as usize;
        let c1 = (((u + radius_px) / self.cell_px).floor().max(0.0) as usize).min(self.cols - 1);
        let r0 = ((v - radius_px) / self.cell_px).floor().max(0.0) as usize;
        let r1 = (((v + radius_px) / self.cell_px).floor().max(0.0) as usize).min(self.rows - 1);
        let r2 = radius_px * radius_px;
        for r in r0..=r1 {
            for c in c0..=c1 {
                for &i in &self.cells[r * self.cols + c] {
                    if let Some(k) = keypoints.get(i as usize) {
                        if (k.x - u).powi(2) + (k.y - v).powi(2) <= r2 {
                            out.push(i);
                        }
                    }
                }
            }
        }
    }
}
