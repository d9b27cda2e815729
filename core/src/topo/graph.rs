//! The semantic topological map: nodes ⟨l, t, θ, s⟩ and undirected edges ⟨d, α⟩ (paper Eq. "Node").

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

use crate::geometry::yaw_of;
use crate::map::{Label, MapObject, ObjectMap};

/// Minimum edge length, in map units; pairs of nodes closer than this (duplicate positions) get no
/// edge, since a zero-length edge has no direction and breaks distance ratios.
pub const MIN_EDGE_LENGTH: f64 = 1e-6;

/// A node of the topological map: one object ⟨label, centre, yaw, size⟩.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct TopoNode {
    /// Class label `l`.
    pub label: Label,
    /// Object centre `t`, in the map's frame (map units: metres for a metric map).
    pub center: Vector3<f64>,
    /// Yaw `θ` about the map's z axis, radians. Carried for completeness; the matcher does not use
    /// it (yaw of symmetric objects is ambiguous, and it is meaningless in a tilted map).
    pub yaw_rad: f64,
    /// Half-extents `s` along the object axes, map units.
    pub half_extents: Vector3<f64>,
}

impl TopoNode {
    /// The node of a map object.
    pub fn from_map_object(object: &MapObject) -> Self {
        Self {
            label: object.label,
            center: object.world_from_object.translation.vector,
            yaw_rad: yaw_of(&object.world_from_object),
            half_extents: object.half_extents,
        }
    }

    /// The scalar size carried by random-walk steps: the half-diagonal ‖s‖ (map units).
    pub fn size(&self) -> f64 {
        self.half_extents.norm()
    }

    /// Half-extents sorted in decreasing order (invariant to swapped object axes), absolute values.
    pub fn sorted_extents(&self) -> [f64; 3] {
        let mut e = [self.half_extents.x.abs(), self.half_extents.y.abs(), self.half_extents.z.abs()];
        e.sort_by(|a, b| b.total_cmp(a));
        e
    }

    /// Whether every number in the node is finite and the size is positive.
    pub fn is_valid(&self) -> bool {
        self.center.iter().all(|v| v.is_finite())
            && self.yaw_rad.is_finite()
            && self.half_extents.iter().all(|v| v.is_finite())
            && self.size() > 0.0
    }
}

/// The nodes of an object map, in the map's object order.
pub fn nodes_from_map(map: &ObjectMap) -> Vec<TopoNode> {
    map.objects.iter().map(TopoNode::from_map_object).collect()
}

/// An undirected edge ⟨d, α⟩ between two nodes (stored once per direction in the adjacency).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct TopoEdge {
    /// The neighbour's node index.
    pub to: usize,
    /// Distance `d` between the two centres, map units.
    pub distance: f64,
    /// Unit direction from this node to `to`, map frame.
    pub direction: Vector3<f64>,
}

impl TopoEdge {
    /// Angle `α`: heading of the edge in the map's xy plane, `atan2(Δy, Δx)`, radians. Expressed in
    /// the map frame, so not invariant; descriptors use the angle *between* consecutive edges.
    pub fn angle_rad(&self) -> f64 {
        self.direction.y.atan2(self.direction.x)
    }
}

/// Edge construction limits.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TopoConfig {
    /// Maximum edge length, map units. The paper's "distance constraint". Default infinity: two
    /// maps to be matched may have different scales, and a metric limit would cut them differently;
    /// set it only for maps in a common metric scale (e.g. 0.6 m on a tabletop).
    pub max_edge_distance: f64,
    /// Maximum number of neighbours per node (nearest first); the paper's "number constraint".
    /// Scale-invariant. An edge is kept when either end selects the other (union), so degrees can
    /// exceed this. Default 6 (tabletop scenes have 4–14 objects).
    pub max_neighbours: usize,
}

impl Default for TopoConfig {
    fn default() -> Self {
        Self { max_edge_distance: f64::INFINITY, max_neighbours: 6 }
    }
}

/// The semantic topological map: nodes and, per node, its edges sorted by neighbour index.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TopoMap {
    /// Nodes (objects).
    pub nodes: Vec<TopoNode>,
    /// `adjacency[i]`: edges of node `i`, sorted by `to`.
    pub adjacency: Vec<Vec<TopoEdge>>,
}

impl TopoMap {
    /// Build the map from nodes. Nodes with non-finite values get no edges; pairs closer than
    /// [`MIN_EDGE_LENGTH`] get no edge.
    pub fn from_nodes(nodes: &[TopoNode], config: &TopoConfig) -> Self {
        let n = nodes.len();
        let mut selected = vec![false; n * n];
        let mut order: Vec<(f64, usize)> = Vec::with_capacity(n);
        for i in 0..n {
            if !nodes[i].is_valid() {
                continue;
            }
            order.clear();
            for (j, other) in nodes.iter().enumerate() {
                if j == i || !other.is_valid() {
                    continue;
                }
                let d = (other.center - nodes[i].center).norm();
                if d >= MIN_EDGE_LENGTH && d <= config.max_edge_distance {
                    order.push((d, j));
                }
            }
            order.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
            for &(_, j) in order.iter().take(config.max_neighbours) {
                selected[i * n + j] = true;
                selected[j * n + i] = true;
            }
        }
        let adjacency = (0..n)
            .map(|i| {
                (0..n)
                    .filter(|&j| selected[i * n + j])
                    .map(|j| {
                        let delta = nodes[j].center - nodes[i].center;
                        let distance = delta.norm();
                        TopoEdge { to: j, distance, direction: delta / distance }
                    })
                    .collect()
            })
            .collect();
        Self { nodes: nodes.to_vec(), adjacency }
    }

    /// Build the map from an object map.
    pub fn from_object_map(map: &ObjectMap, config: &TopoConfig) -> Self {
        Self::from_nodes(&nodes_from_map(map), config)
    }

    /// Number of nodes.
    pub fn len(&self) -> usize {
        self.nodes.len()
    }

    /// Whether the map has no nodes.
    pub fn is_empty(&self) -> bool {
        self.nodes.is_empty()
    }

    /// Number of undirected edges.
    pub fn edge_count(&self) -> usize {
        self.adjacency.iter().map(Vec::len).sum::<usize>() / 2
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn node(x: f64, y: f64) -> TopoNode {
        TopoNode {
            label: Label::Cup,
            center: Vector3::new(x, y, 0.05),
            yaw_rad: 0.0,
            half_extents: Vector3::new(0.04, 0.04, 0.05),
        }
    }

    #[test]
    fn edges_respect_limits_and_are_symmetric() {
        // Gaps 0.10, 0.12, 0.14, 0.16, 0.18: every node's nearest neighbour is its left one.
        let xs = [0.0, 0.1, 0.22, 0.36, 0.52, 0.70];
        let nodes: Vec<TopoNode> = xs.iter().map(|&x| node(x, 0.0)).collect();
        let map = TopoMap::from_nodes(&nodes, &TopoConfig { max_edge_distance: 0.25, max_neighbours: 1 });
        assert_eq!(map.edge_count(), 5);
        for (i, edges) in map.adjacency.iter().enumerate() {
            for e in edges {
                assert!(map.adjacency[e.to].iter().any(|b| b.to == i));
                assert!(e.to.abs_diff(i) == 1);
                assert!((e.distance - (xs[i] - xs[e.to]).abs()).abs() < 1e-12);
            }
        }
        let all = TopoMap::from_nodes(&nodes, &TopoConfig { max_edge_distance: 0.25, max_neighbours: 10 });
        // Within 0.25: the 5 consecutive pairs and (0, 2) at 0.22.
        assert_eq!(all.edge_count(), 6);
        assert!((all.adjacency[0][0].angle_rad() - 0.0).abs() < 1e-12);
        assert!((all.adjacency[1][0].angle_rad() - std::f64::consts::PI).abs() < 1e-12);
    }

    #[test]
    fn duplicate_positions_and_nan_get_no_edges() {
        let mut nodes = vec![node(0.0, 0.0), node(0.0, 0.0), node(0.2, 0.0)];
        nodes.push(TopoNode { center: Vector3::new(f64::NAN, 0.0, 0.0), ..node(0.0, 0.0) });
        let map = TopoMap::from_nodes(&nodes, &TopoConfig::default());
        assert!(map.adjacency[0].iter().all(|e| e.to != 1));
        assert!(map.adjacency[3].is_empty());
        assert!(map.adjacency.iter().flatten().all(|e| e.distance.is_finite() && e.to != 3));
    }
}
