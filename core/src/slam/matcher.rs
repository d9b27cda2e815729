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
/// (second and third bins only if they hold more than 10 % of the first, as in ORB-SLAM2).
pub fn orientation_consistent(
    matches: &[FeatureMatch],
    query: &[Keypoint],
    train: &[Keypoint],
    bins: usize,
) -> Vec<bool> {
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
    let kept: Vec<usize> = order.iter().take(3).copied().filter(|&b| hist[b] > 0 && hist[b] * 10 > top).collect();
    bin_of.iter().map(|b| b.is_some_and(|b| kept.contains(&b))).collect()
}

/// A uniform grid over level-0 pixels holding keypoint indices, for radius searches. The cells
/// are stored row-major in one array (each cell's keypoints in index order, with their
/// positions), so that the cells of one grid row in a search window are one contiguous slice.
#[derive(Debug, Clone)]
pub struct KeypointGrid {
    cell_px: f32,
    cols: usize,
    rows: usize,
    /// `entries[starts[c]..starts[c + 1]]` are cell `c`'s keypoints.
    starts: Vec<u32>,
    entries: Vec<GridEntry>,
}

/// A keypoint in a [`KeypointGrid`]: its position and index.
#[derive(Debug, Clone, Copy)]
struct GridEntry {
    x: f32,
    y: f32,
    index: u32,
}

impl KeypointGrid {
    /// Index `keypoints` of an image of `width` x `height` pixels on cells of `cell_px`.
    pub fn new(keypoints: &[Keypoint], width: u32, height: u32, cell_px: f32) -> Self {
        let cell_px = cell_px.max(1.0);
        let cols = ((width as f32 / cell_px).ceil() as usize).max(1);
        let rows = ((height as f32 / cell_px).ceil() as usize).max(1);
        let cell_of = |k: &Keypoint| {
            let (cx, cy) = ((k.x / cell_px) as usize, (k.y / cell_px) as usize);
            (k.x >= 0.0 && k.y >= 0.0 && cx < cols && cy < rows).then_some(cy * cols + cx)
        };
        // Counting sort by cell (stable: index order within a cell).
        let mut starts = vec![0u32; cols * rows + 1];
        for c in keypoints.iter().filter_map(cell_of) {
            starts[c + 1] += 1;
        }
        for c in 0..cols * rows {
            starts[c + 1] += starts[c];
        }
        let mut fill: Vec<u32> = starts[..cols * rows].to_vec();
        let mut entries = vec![GridEntry { x: 0.0, y: 0.0, index: 0 }; starts[cols * rows] as usize];
        for (i, k) in keypoints.iter().enumerate() {
            if let Some(c) = cell_of(k) {
                entries[fill[c] as usize] = GridEntry { x: k.x, y: k.y, index: i as u32 };
                fill[c] += 1;
            }
        }
        Self { cell_px, cols, rows, starts, entries }
    }

    /// Indices of keypoints within `radius_px` of `(u, v)` (appended to `out`, which is cleared).
    /// `keypoints` are the ones the grid was built from.
    pub fn within(&self, keypoints: &[Keypoint], u: f32, v: f32, radius_px: f32, out: &mut Vec<u32>) {
        out.clear();
        if !(u.is_finite() && v.is_finite()) || keypoints.is_empty() {
            return;
        }
        let c0 = ((u - radius_px) / self.cell_px).floor().max(0.0) as usize;
        let c1 = (((u + radius_px) / self.cell_px).floor().max(0.0) as usize).min(self.cols - 1);
        let r0 = ((v - radius_px) / self.cell_px).floor().max(0.0) as usize;
        let r1 = (((v + radius_px) / self.cell_px).floor().max(0.0) as usize).min(self.rows - 1);
        if c0 > c1 {
            return;
        }
        let r2 = radius_px * radius_px;
        for r in r0..=r1 {
            let (from, to) = (self.starts[r * self.cols + c0] as usize, self.starts[r * self.cols + c1 + 1] as usize);
            for e in self.entries.get(from..to).unwrap_or(&[]) {
                if (e.x - u).powi(2) + (e.y - v).powi(2) <= r2 {
                    out.push(e.index);
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn kp(x: f32, y: f32, angle_rad: f32) -> Keypoint {
        Keypoint { x, y, level: 0, scale: 1.0, angle_rad, score: 10 }
    }

    #[test]
    fn grid_radius_search_equals_brute_force() {
        let kps: Vec<Keypoint> =
            (0..400).map(|i| kp((i * 37 % 640) as f32 + 0.5, (i * 53 % 480) as f32 + 0.25, 0.0)).collect();
        let grid = KeypointGrid::new(&kps, 640, 480, 16.0);
        let mut out = Vec::new();
        for (u, v, r) in
            [(100.0, 100.0, 30.0), (0.0, 0.0, 50.0), (639.0, 479.0, 12.0), (-40.0, 10.0, 45.0), (320.0, 240.0, 1000.0)]
        {
            grid.within(&kps, u, v, r, &mut out);
            let mut got: Vec<u32> = out.clone();
            got.sort_unstable();
            let want: Vec<u32> =
                (0..kps.len() as u32).filter(|&i| (kps[i as usize].x - u).hypot(kps[i as usize].y - v) <= r).collect();
            assert_eq!(got, want, "query ({u}, {v}, {r})");
        }
        grid.within(&kps, f32::NAN, 3.0, 10.0, &mut out);
        assert!(out.is_empty());
    }

    #[test]
    fn orientation_check_drops_the_odd_rotation() {
        // Ten matches rotate by ~30°, one by 180°: the latter is dropped.
        let q: Vec<Keypoint> = (0..11).map(|i| kp(i as f32, 0.0, 0.1)).collect();
        let mut t: Vec<Keypoint> = (0..11).map(|i| kp(i as f32, 0.0, 0.1 + 30f32.to_radians())).collect();
        t[10].angle_rad = 0.1 + std::f32::consts::PI;
        let m: Vec<FeatureMatch> =
            (0..11).map(|i| FeatureMatch { query_index: i, train_index: i, distance: 0 }).collect();
        let keep = orientation_consistent(&m, &q, &t, 30);
        assert_eq!(keep.iter().filter(|&&k| k).count(), 10);
        assert!(!keep[10]);
    }

    #[test]
    fn brute_force_applies_ratio_and_uniqueness() {
        let d = |b: u64| [b, 0, 0, 0];
        let query = vec![d(0b1111), d(0xFFFF_0000), d(0b1111)];
        let train = vec![d(0b1111), d(0xFFFF_0001)];
        let kq = vec![kp(0.0, 0.0, 0.0); 3];
        let kt = vec![kp(0.0, 0.0, 0.0); 2];
        let cfg = MatchConfig { check_orientation: false, ..MatchConfig::default() };
        let m = match_brute_force(&query, &kq, &train, &kt, &cfg);
        // Query 0 and 2 both want train 0 at distance 0: only the first is kept; query 1 → train 1.
        assert_eq!(m.len(), 2);
        assert_eq!((m[0].query_index, m[0].train_index, m[0].distance), (0, 0, 0));
        assert_eq!((m[1].query_index, m[1].train_index, m[1].distance), (1, 1, 1));
    }
}
