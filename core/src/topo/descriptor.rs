//! Random-walk object descriptors (paper Eq. "Descriptor", Alg. 3 `objectDescriptor`) and their
//! similarity score (Alg. 3 `match` / `maxScore`).

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use super::graph::TopoMap;
use crate::map::Label;

/// How two objects' labels are compared: in the matcher's candidate gate and in every walk step.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum LabelMatch {
    /// The paper: equal labels.
    Exact,
    /// Beyond the paper, default: equal primitive ([`Label::shape`], the paper's cuboid-like and
    /// cylinder-like classes). A detector confuses look-alikes of one shape (book and block, can and
    /// bottle, cup and bowl) from some viewing directions, and a map seen from a few views keeps the
    /// label those views gave; geometry (sizes, distances, angles, the pose solve) separates the rest.
    #[default]
    Shape,
}

impl LabelMatch {
    /// Whether labels `a` and `b` agree.
    pub fn agree(self, a: Label, b: Label) -> bool {
        match self {
            LabelMatch::Exact => a == b,
            LabelMatch::Shape => a.shape() == b.shape(),
        }
    }
}

/// Descriptor generation and comparison settings.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DescriptorConfig {
    /// Walk depth `i`: steps per walk after the start object. Paper: "a certain depth i" (value not
    /// given). Default 3 (tabletop maps have 4–14 objects).
    pub depth: usize,
    /// Walks per object `j` (rows of the descriptor). Paper: "time j" (value not given). Default 8.
    pub walks: usize,
    /// Seed of the walk RNG (ChaCha8). The same seed is used for both maps.
    pub seed: u64,
    /// Relative size tolerance when comparing two steps' sizes after undoing the pair's scale.
    /// Default 0.2 (5 % size noise per map, with margin).
    pub size_tolerance: f64,
    /// Absolute distance tolerance, in prior-map units (metres), of a step's edge length after
    /// undoing the pair's scale. Default 0.04 (1 cm position noise per axis per map).
    pub distance_tolerance: f64,
    /// Relative distance tolerance added to `distance_tolerance` (covers the size-derived pair scale
    /// error). Default 0.15.
    pub distance_tolerance_rel: f64,
    /// Tolerance on the angle between consecutive edges, radians. Default 0.35 (20°).
    pub angle_tolerance_rad: f64,
    /// How labels are compared (here and in the matcher's candidate gate). Default
    /// [`LabelMatch::Shape`]; the paper: [`LabelMatch::Exact`].
    pub label_match: LabelMatch,
}

impl Default for DescriptorConfig {
    fn default() -> Self {
        Self {
            depth: 3,
            walks: 8,
            seed: 0x70b0,
            size_tolerance: 0.2,
            distance_tolerance: 0.04,
            distance_tolerance_rel: 0.15,
            angle_tolerance_rad: 0.35,
            label_match: LabelMatch::default(),
        }
    }
}

/// One step of a random walk: the reached object's label and size, the edge length from the
/// previous object, and the angle between this edge and the previous one.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct WalkStep {
    /// Label of the reached object.
    pub label: Label,
    /// Size ‖s‖ of the reached object (map units).
    pub size: f64,
    /// Edge length `d` from the previous object (map units).
    pub distance: f64,
    /// Cosine of the unsigned angle `α` ∈ [0, π] between the previous edge (reversed, pointing back)
    /// and this edge; invariant to any similarity transform. Stored as cosine and sine so that
    /// comparing two angles needs no `acos`. 1 (α = 0, never compared) on the first step, which has
    /// no previous edge.
    pub angle_cos: f64,
    /// Sine of `α` (≥ 0).
    pub angle_sin: f64,
}

impl WalkStep {
    /// The angle `α`, radians in [0, π].
    pub fn angle_rad(&self) -> f64 {
        self.angle_sin.atan2(self.angle_cos)
    }
}

/// The descriptors of every object of a map, stored flat: object `o`, walk `w` occupies
/// `steps[(o * walks + w) * depth ..][.. lengths[o * walks + w]]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DescriptorSet {
    /// Walk depth `i`.
    pub depth: usize,
    /// Walks per object `j`.
    pub walks: usize,
    /// Steps, padded to `depth` per walk.
    pub steps: Vec<WalkStep>,
    /// Number of valid steps per walk (a walk stops early when every neighbour is already on it).
    pub lengths: Vec<usize>,
}

impl DescriptorSet {
    /// Generate the descriptors of every node (paper Alg. 3 `objectDescriptor`): `walks` random walks
    /// of up to `depth` steps from each object, never revisiting an object within a walk. Object `o`'s
    /// walks use their own ChaCha8 stream seeded by (`seed`, `o`), so they do not depend on which
    /// other objects are described.
    pub fn generate(map: &TopoMap, config: &DescriptorConfig) -> Self {
        Self::generate_for(map, config, &[])
    }

    /// As [`DescriptorSet::generate`], but only for the objects with `wanted[o] == true` (an empty
    /// slice means all); the others get empty walks. The matcher skips objects whose label does not
    /// occur in the other map.
    pub fn generate_for(map: &TopoMap, config: &DescriptorConfig, wanted: &[bool]) -> Self {
        let n = map.len();
        let (depth, walks) = (config.depth, config.walks);
        let filler = WalkStep { label: Label::Block, size: 0.0, distance: 0.0, angle_cos: 1.0, angle_sin: 0.0 };
        let mut steps = vec![filler; n * walks * depth];
        let mut lengths = vec![0usize; n * walks];
        let mut path: Vec<usize> = Vec::with_capacity(depth + 1);
        let mut options: Vec<usize> = Vec::with_capacity(16);
        for start in 0..n {
            if !wanted.is_empty() && !wanted.get(start).copied().unwrap_or(false) {
                continue;
            }
            let mut rng = ChaCha8Rng::seed_from_u64(config.seed ^ (start as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15));
            for w in 0..walks {
                let slot = start * walks + w;
                path.clear();
                path.push(start);
                let mut previous_direction: Option<nalgebra::Vector3<f64>> = None;
                let mut len = 0;
                while len < depth {
                    let Some(&current) = path.last() else { break };
                    let Some(edges) = map.adjacency.get(current) else { break };
                    options.clear();
                    options.extend((0..edges.len()).filter(|&k| !path.contains(&edges[k].to)));
                    if options.is_empty() {
                        break;
                    }
                    let pick = options[rng.random_range(0..options.len())];
                    let edge = &edges[pick];
                    let (angle_cos, angle_sin) = match previous_direction {
                        // Angle at `current` between the way back and the way on.
                        Some(prev) => {
                            let back = -prev;
                            (back.dot(&edge.direction).clamp(-1.0, 1.0), back.cross(&edge.direction).norm())
                        }
                        None => (1.0, 0.0),
                    };
                    let Some(node) = map.nodes.get(edge.to) else { break };
                    steps[slot * depth + len] = WalkStep {
                        label: node.label,
                        size: node.size(),
                        distance: edge.distance,
                        angle_cos,
                        angle_sin,
                    };
                    previous_direction = Some(edge.direction);
                    path.push(edge.to);
                    len += 1;
                }
                lengths[slot] = len;
            }
        }
        Self { depth, walks, steps, lengths }
    }

    /// Walk `w` of object `object` (empty when out of range).
    pub fn walk(&self, object: usize, w: usize) -> &[WalkStep] {
        let slot = object * self.walks + w;
        let len = self.lengths.get(slot).copied().unwrap_or(0);
        self.steps.get(slot * self.depth..slot * self.depth + len).unwrap_or(&[])
    }

    /// Number of objects described.
    pub fn objects(&self) -> usize {
        self.lengths.len().checked_div(self.walks).unwrap_or(0)
    }
}

/// Number of leading steps of `query` that agree with `prior` under the scale `scale`
/// (query units per prior unit): agreeing labels (`label_match`), size, distance and (from the second
/// step) angle.
fn matched_prefix(prior: &[WalkStep], query: &[WalkStep], scale: f64, config: &DescriptorConfig) -> usize {
    let angle_tolerance_cos = config.angle_tolerance_rad.min(std::f64::consts::PI).cos();
    let mut k = 0;
    for (p, q) in prior.iter().zip(query) {
        let size_ok = (q.size / (scale * p.size) - 1.0).abs() <= config.size_tolerance;
        let dist_ok = (q.distance / scale - p.distance).abs()
            <= config.distance_tolerance + config.distance_tolerance_rel * p.distance;
        // |α_q − α_p| ≤ tol  ⇔  cos(α_q − α_p) ≥ cos(tol), both angles in [0, π].
        let angle_ok = k == 0 || q.angle_cos * p.angle_cos + q.angle_sin * p.angle_sin >= angle_tolerance_cos;
        if !config.label_match.agree(p.label, q.label) || !size_ok || !dist_ok || !angle_ok {
            break;
        }
        k += 1;
    }
    k
}

/// Similarity of prior object `a` and query object `b` in [0, 1] under the scale hypothesis
/// `scale` (query units per prior unit): the mean over `a`'s walks of the best matched-prefix
/// fraction among `b`'s walks, averaged with the same score from `b`'s side.
pub fn similarity(
    prior: &DescriptorSet,
    a: usize,
    query: &DescriptorSet,
    b: usize,
    scale: f64,
    config: &DescriptorConfig,
) -> f64 {
    let depth = prior.depth.max(1) as f64;
    // M[wp][wq] = matched prefix of prior walk wp and query walk wq, computed once; the score from
    // the prior side takes row maxima, the score from the query side column maxima.
    const MAX_STACK_WALKS: usize = 32;
    let (np, nq) = (prior.walks, query.walks);
    if np == 0 || nq == 0 {
        return 0.0;
    }
    let mut col_best_stack = [0usize; MAX_STACK_WALKS];
    let mut col_best_heap = Vec::new();
    let col_best: &mut [usize] = if nq <= MAX_STACK_WALKS {
        &mut col_best_stack[..nq]
    } else {
        col_best_heap.resize(nq, 0);
        &mut col_best_heap[..]
    };
    let mut row_total = 0.0;
    for wp in 0..np {
        let walk_p = prior.walk(a, wp);
        let mut row_best = 0;
        for (wq, best_q) in col_best.iter_mut().enumerate() {
            let k = matched_prefix(walk_p, query.walk(b, wq), scale, config);
            row_best = row_best.max(k);
            *best_q = (*best_q).max(k);
        }
        row_total += row_best as f64 / depth;
    }
    let col_total: f64 = col_best.iter().map(|&k| k as f64 / depth).sum();
    0.5 * (row_total / np as f64 + col_total / nq as f64)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::topo::graph::{TopoConfig, TopoNode};
    use nalgebra::Vector3;

    fn nodes() -> Vec<TopoNode> {
        let labels = [Label::Cup, Label::Book, Label::Can, Label::Bowl, Label::Block];
        (0..5)
            .map(|i| TopoNode {
                label: labels[i],
                center: Vector3::new(0.3 + 0.1 * i as f64, 0.05 * (i * i) as f64 - 0.2, 0.03),
                yaw_rad: 0.0,
                half_extents: Vector3::new(0.03 + 0.01 * i as f64, 0.03, 0.03),
            })
            .collect()
    }

    #[test]
    fn walks_never_repeat_and_are_seeded() {
        let map = TopoMap::from_nodes(&nodes(), &TopoConfig::default());
        let config = DescriptorConfig { depth: 4, walks: 8, ..DescriptorConfig::default() };
        let d = DescriptorSet::generate(&map, &config);
        assert_eq!(d.objects(), 5);
        for o in 0..5 {
            for w in 0..8 {
                let walk = d.walk(o, w);
                assert_eq!(walk.len(), 4, "fully connected 5 nodes: every walk reaches depth 4");
                // Labels are unique per node here, so repeated labels mean a repeated node.
                let mut labels: Vec<Label> = walk.iter().map(|s| s.label).collect();
                labels.push(map.nodes[o].label);
                labels.sort();
                labels.dedup();
                assert_eq!(labels.len(), 5);
            }
        }
        assert_eq!(d, DescriptorSet::generate(&map, &config));
    }

    #[test]
    fn similarity_is_one_for_a_scaled_copy_and_low_for_strangers() {
        let config = DescriptorConfig::default();
        let a = TopoMap::from_nodes(&nodes(), &TopoConfig::default());
        let scaled: Vec<TopoNode> = nodes()
            .iter()
            .map(|n| TopoNode { center: n.center * 2.0, half_extents: n.half_extents * 2.0, ..*n })
            .collect();
        let b = TopoMap::from_nodes(&scaled, &TopoConfig::default());
        let (da, db) = (DescriptorSet::generate(&a, &config), DescriptorSet::generate(&b, &config));
        let same = similarity(&da, 2, &db, 2, 2.0, &config);
        assert!((same - 1.0).abs() < 1e-12, "{same}");
        let other = similarity(&da, 2, &db, 3, 2.0, &config);
        assert!(other < 0.5, "{other}");
        let wrong_scale = similarity(&da, 2, &db, 2, 1.0, &config);
        assert!(wrong_scale < 0.2, "{wrong_scale}");
    }
}
