//! Joint-space path planning: the straight line when it is free, else seeded RRT-Connect
//! (Kuffner & LaValle 2000) followed by random shortcutting.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::collision::{ArmCollisionModel, CollisionScene};
use super::kinematics::{ArmChain, JointVector};
use super::{PlanError, PlannerConfig};

/// Euclidean distance in joint space, radians.
pub fn joint_distance(a: &JointVector, b: &JointVector) -> f64 {
    a.iter().zip(b.iter()).map(|(x, y)| (x - y) * (x - y)).sum::<f64>().sqrt()
}

/// Largest absolute joint difference, radians.
pub fn joint_max_abs_diff(a: &JointVector, b: &JointVector) -> f64 {
    a.iter().zip(b.iter()).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max)
}

fn lerp(a: &JointVector, b: &JointVector, t: f64) -> JointVector {
    let mut q = *a;
    for ((v, x), y) in q.iter_mut().zip(a.iter()).zip(b.iter()) {
        *v = x + t * (y - x);
    }
    q
}

/// Checker bundling chain, collision model, scene and resolution.
pub(crate) struct Checker<'a> {
    pub chain: &'a ArmChain,
    pub model: &'a ArmCollisionModel,
    pub scene: &'a CollisionScene,
    pub resolution_rad: f64,
}

impl Checker<'_> {
    pub fn config_free(&self, q: &JointVector) -> bool {
        self.chain.within_limits(q) && self.model.is_free(self.chain, q, self.scene)
    }

    /// Whether the straight segment a → b is free, checked every `resolution_rad` of the largest
    /// joint motion (endpoints included), in bisection order so collisions are found early.
    pub fn segment_free(&self, a: &JointVector, b: &JointVector) -> bool {
        let steps = (joint_max_abs_diff(a, b) / self.resolution_rad).ceil().max(1.0) as usize;
        if !self.config_free(b) {
            return false;
        }
        // Van der Corput-like order: coarse samples first.
        let mut stride = steps.next_power_of_two();
        let mut checked = vec![false; steps + 1];
        // `a` is assumed free (checked by the caller or a tree node); `b` was checked above.
        for i in [0, steps] {
            if let Some(c) = checked.get_mut(i) {
                *c = true;
            }
        }
        while stride >= 1 {
            let mut i = stride;
            while i < steps {
                if let Some(c) = checked.get_mut(i) {
                    if !*c {
                        *c = true;
                        if !self.config_free(&lerp(a, b, i as f64 / steps as f64)) {
                            return false;
                        }
                    }
                }
                i += stride;
            }
            stride /= 2;
        }
        true
    }
}

struct Tree {
    nodes: Vec<JointVector>,
    parents: Vec<usize>,
}

impl Tree {
    fn new(root: JointVector) -> Self {
        Self { nodes: vec![root], parents: vec![0] }
    }
    fn nearest(&self, q: &JointVector) -> usize {
        let mut best = (0, f64::INFINITY);
        for (i, n) in self.nodes.iter().enumerate() {
            let d = joint_distance(n, q);
            if d < best.1 {
                best = (i, d);
            }
        }
        best.0
    }
    fn add(&mut self, q: JointVector, parent: usize) -> usize {
        self.nodes.push(q);
        self.parents.push(parent);
        self.nodes.len() - 1
    }
    fn path_to_root(&self, mut i: usize) -> Vec<JointVector> {
        let mut out = Vec::new();
        while let Some(n) = self.nodes.get(i) {
            out.push(*n);
            if i == 0 {
                break;
            }
            i = self.parents.get(i).copied().unwrap_or(0);
        }
        out
    }
}

enum Extend {
    Reached(usize),
    Advanced(usize),
    Trapped,
}

fn extend(tree: &mut Tree, target: &JointVector, step: f64, checker: &Checker) -> Extend {
    let near_i = tree.nearest(target);
    let Some(near) = tree.nodes.get(near_i).copied() else {
        return Extend::Trapped;
    };
    let d = joint_distance(&near, target);
    let (new, reached) = if d <= step { (*target, true) } else { (lerp(&near, target, step / d), false) };
    if !checker.segment_free(&near, &new) {
        return Extend::Trapped;
    }
    let i = tree.add(new, near_i);
    if reached {
        Extend::Reached(i)
    } else {
        Extend::Advanced(i)
    }
}

fn connect(tree: &mut Tree, target: &JointVector, step: f64, checker: &Checker) -> Extend {
    loop {
        match extend(tree, target, step, checker) {
            Extend::Advanced(_) => continue,
            other => return other,
        }
    }
}

/// Plans a collision-free joint path `start → goal` (both must be free). Returns waypoints, start
/// first and goal last; consecutive waypoints are joined by straight, checked segments.
pub(crate) fn plan_path(
    start: &JointVector,
    goal: &JointVector,
    checker: &Checker,
    config: &PlannerConfig,
) -> Result<Vec<JointVector>, PlanError> {
    if checker.segment_free(start, goal) {
        return Ok(vec![*start, *goal]);
    }
    let began = std::time::Instant::now();
    let mut rng = ChaCha8Rng::seed_from_u64(config.rng_seed);
    let mut tree_a = Tree::new(*start);
    let mut tree_b = Tree::new(*goal);
    let mut a_is_start = true;
    let step = config.rrt_step_rad;
    for iteration in 0..config.rrt_max_iterations {
        if let Some(limit) = config.timeout_s {
            if began.elapsed().as_secs_f64() > limit {
                return Err(PlanError::Timeout { seconds: limit, iterations: iteration });
            }
        }
        let sample = if rng.random::<f64>() < config.rrt_goal_bias {
            tree_b.nodes.first().copied().unwrap_or(*goal)
        } else {
            checker.chain.random_configuration(&mut rng)
        };
        if let Extend::Advanced(i) | Extend::Reached(i) = extend(&mut tree_a, &sample, step, checker) {
            let Some(q_new) = tree_a.nodes.get(i).copied() else {
                continue;
            };
            if let Extend::Reached(j) = connect(&mut tree_b, &q_new, step, checker) {
                let mut half_a = tree_a.path_to_root(i);
                half_a.reverse();
                let half_b = tree_b.path_to_root(j);
                // half_a ends at q_new and half_b starts at q_new: drop the duplicate.
                half_a.extend(half_b.into_iter().skip(1));
                if !a_is_start {
                    half_a.reverse();
                }
                let path = shortcut(half_a, checker, config, &mut rng);
                return Ok(path);
            }
        }
        std::mem::swap(&mut tree_a, &mut tree_b);
        a_is_start = !a_is_start;
    }
    Err(PlanError::PlannerExhausted { iterations: config.rrt_max_iterations })
}

/// Random shortcutting: repeatedly joins two random waypoints by a straight segment when it is free,
/// then drops waypoints whose neighbours see each other.
fn shortcut(
    mut path: Vec<JointVector>,
    checker: &Checker,
    config: &PlannerConfig,
    rng: &mut ChaCha8Rng,
) -> Vec<JointVector> {
    for _ in 0..config.shortcut_iterations {
        if path.len() < 3 {
            break;
        }
        let i = rng.random_range(0..path.len() - 2);
        let j = rng.random_range(i + 2..path.len());
        let (Some(a), Some(b)) = (path.get(i).copied(), path.get(j).copied()) else {
            continue;
        };
        if checker.segment_free(&a, &b) {
            path.drain(i + 1..j);
        }
    }
    // Greedy pass.
    let mut out = Vec::with_capacity(path.len());
    let mut i = 0;
    while i < path.len() {
        let Some(a) = path.get(i).copied() else { break };
        out.push(a);
        let mut j = path.len() - 1;
        while j > i + 1 {
            if path.get(j).is_some_and(|b| checker.segment_free(&a, b)) {
                break;
            }
            j -= 1;
        }
        i = if j > i { j } else { i + 1 };
    }
    out
}
