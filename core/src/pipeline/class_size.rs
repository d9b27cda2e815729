//! Class size priors: the sizes an object of each label can have, and the test that holds back an
//! estimate no object of its label could have when other objects already explain its points
//! ([`super::PipelineConfig::class_size_tolerance`]).
//!
//! The detector's persistent label confusions make a second object of one real object under a
//! look-alike's label (a carton called a can from most directions), and the estimator fits that
//! label's primitive to a box that reaches over the neighbours: a can 15 cm wide and 18 cm tall.
//! Slivers beside a real object (a bottle 2.5 cm wide) and a cup 2.7 cm tall on a mug's rim are
//! the same kind of duplicate. A robot knows how large a can is; these priors are that knowledge.

use std::collections::BTreeMap;

use nalgebra::Point3;
use serde::{Deserialize, Serialize};

use crate::geometry::ObjectGeometry;
use crate::map::Label;

/// The sizes of one class, metres: `[min, max]` of its footprint's extent (a cuboid's longer
/// side, a cylinder's diameter) and of its height.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ClassSize {
    /// Footprint extent range, metres.
    pub extent_m: [f64; 2],
    /// Height range, metres.
    pub height_m: [f64; 2],
}

impl ClassSize {
    /// Whether `g` fits the class with every bound widened by the factor `tolerance` (≥ 1): each
    /// dimension in `[min / tolerance, max · tolerance]`.
    pub fn admits(&self, g: &ObjectGeometry, tolerance: f64) -> bool {
        let extent = 2.0 * g.half_extents.x.max(g.half_extents.y);
        let height = 2.0 * g.half_extents.z;
        let within = |v: f64, [lo, hi]: [f64; 2]| v >= lo / tolerance && v <= hi * tolerance;
        within(extent, self.extent_m) && within(height, self.height_m)
    }

    /// The range's problem, if any: a name for the first bad field.
    pub(super) fn invalid(&self) -> Option<&'static str> {
        let ok = |[lo, hi]: [f64; 2]| lo.is_finite() && hi.is_finite() && lo > 0.0 && lo <= hi;
        if !ok(self.extent_m) {
            Some("extent_m")
        } else if !ok(self.height_m) {
            Some("height_m")
        } else {
            None
        }
    }
}

/// The default priors: every object the scene generators place (`objslam.scene.CLASS_SIZES` for
/// primitives, `objslam.meshes.ASSETS` over their scale ranges; `tests/test_class_sizes.py` checks
/// that each scene's ground truth lies inside), rounded outward.
pub fn default_class_sizes() -> BTreeMap<Label, ClassSize> {
    let size = |extent_m, height_m| ClassSize { extent_m, height_m };
    BTreeMap::from([
        // Cubes of 4-6 cm, butter cartons 10.3 x 5.3 x 2.4 cm, juice and milk cartons 16.4 cm tall.
        (Label::Block, size([0.04, 0.11], [0.02, 0.18])),
        // Flat boxes 13-18 cm long, a popcorn box lying flat, a paperback standing 13 cm tall.
        (Label::Book, size([0.09, 0.18], [0.025, 0.135])),
        (Label::Keyboard, size([0.30, 0.36], [0.02, 0.03])),
        // Cups 6-9 cm across, a mug with its handle 9.1 cm.
        (Label::Cup, size([0.06, 0.095], [0.08, 0.11])),
        // Cans 5.6-6.8 cm across; soup cans 7.3 cm tall.
        (Label::Can, size([0.056, 0.07], [0.07, 0.12])),
        // Bottles 5-6.8 cm across, 14-22 cm tall.
        (Label::Bottle, size([0.05, 0.07], [0.14, 0.22])),
        (Label::Bowl, size([0.12, 0.16], [0.05, 0.07])),
        (Label::Ball, size([0.06, 0.08], [0.06, 0.08])),
    ])
}

/// Share of `own`'s points that the other clouds claim: a point is claimed when some other cloud
/// has more points than `own` within `radius` of it (the ownership rule of
/// [`super::PipelineConfig::ownership_radius_m`]). `others_bounds` holds each other cloud's
/// [`super::cloud_bounds`], in order (computed once by a caller testing several clouds against the
/// same others). 0 for an empty cloud.
pub(super) fn claimed_share(
    own: &[Point3<f64>],
    others: &[&[Point3<f64>]],
    others_bounds: &[Option<(Point3<f64>, Point3<f64>)>],
    radius: f64,
) -> f64 {
    if own.is_empty() {
        return 0.0;
    }
    let clouds: Vec<&[Point3<f64>]> = std::iter::once(own).chain(others.iter().copied()).collect();
    let bounds: Vec<_> = std::iter::once(super::cloud_bounds(own)).chain(others_bounds.iter().copied()).collect();
    let kept = super::owned_points(&clouds, &bounds, 0, radius).len();
    1.0 - kept as f64 / own.len() as f64
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Shape;
    use nalgebra::Vector3;

    fn cylinder(radius: f64, height: f64) -> ObjectGeometry {
        ObjectGeometry {
            shape: Shape::Cylinder,
            center: Vector3::new(0.5, 0.0, height / 2.0),
            yaw_rad: 0.0,
            half_extents: Vector3::new(radius, radius, height / 2.0),
        }
    }

    #[test]
    fn a_can_fits_the_can_range_and_a_merged_blob_does_not() {
        let can = default_class_sizes()[&Label::Can];
        // A 6.6 cm soup can 7.5 cm tall; the same at the tolerance's edge; a 15 cm "can".
        assert!(can.admits(&cylinder(0.033, 0.075), 1.0));
        assert!(can.admits(&cylinder(0.0525, 0.075), 1.5));
        assert!(!can.admits(&cylinder(0.0535, 0.075), 1.5));
        assert!(!can.admits(&cylinder(0.075, 0.18), 1.5));
        // Too small counts as well: a sliver 2.5 cm wide, a rim 2.7 cm tall.
        assert!(!can.admits(&cylinder(0.0125, 0.1), 1.5));
        assert!(!default_class_sizes()[&Label::Cup].admits(&cylinder(0.037, 0.027), 1.5));
        assert_eq!(can.invalid(), None);
        assert_eq!(ClassSize { extent_m: [0.1, 0.05], height_m: [0.1, 0.2] }.invalid(), Some("extent_m"));
        assert_eq!(ClassSize { extent_m: [0.05, 0.1], height_m: [f64::NAN, 0.2] }.invalid(), Some("height_m"));
    }

    #[test]
    fn a_denser_cloud_on_the_same_surface_claims_the_points() {
        // A 10 cm patch on a 5 mm lattice, and another cloud over its left half sampled twice as
        // densely: every point of the left half (and the column next to it) is claimed.
        let patch: Vec<Point3<f64>> = (0..20)
            .flat_map(|i| (0..20).map(move |j| Point3::new(f64::from(i) * 0.005, f64::from(j) * 0.005, 0.1)))
            .collect();
        let dense: Vec<Point3<f64>> = (0..20)
            .flat_map(|i| (0..40).map(move |j| Point3::new(f64::from(i) * 0.0025, f64::from(j) * 0.0025, 0.1)))
            .collect();
        let share = claimed_share(&patch, &[&dense], &[super::super::cloud_bounds(&dense)], 0.005);
        assert!((0.5..=0.6).contains(&share), "{share}");
        // Nothing near: nothing claimed; an empty cloud claims and is claimed nothing.
        let far: Vec<Point3<f64>> = dense.iter().map(|p| p + Vector3::new(0.0, 0.0, 0.1)).collect();
        assert_eq!(claimed_share(&patch, &[&far], &[super::super::cloud_bounds(&far)], 0.005), 0.0);
        assert_eq!(claimed_share(&[], &[&dense], &[super::super::cloud_bounds(&dense)], 0.005), 0.0);
        assert_eq!(claimed_share(&patch, &[], &[], 0.005), 0.0);
    }
}
