//! The gates: a tracked pose that disagrees with the kinematic prior
//! ([`super::TrackerConfig::prior_gate_sigmas`]) or with the prior's motion since the last tracked
//! frames of the view ([`super::TrackerConfig::motion_gate_floor_m`]) counts as lost.

use super::{LostReason, Tracker};
use crate::geometry::Se3;

impl Tracker {
    /// `Some(reason)` if `map_from_camera` is implausibly far from the prior (both in the map
    /// frame) by [`TrackerConfig::prior_gate_sigmas`].
    pub(super) fn prior_disagreement(&self, map_from_camera: &Se3, prior_in_map: &Se3) -> Option<LostReason> {
        let k = self.config.prior_gate_sigmas;
        if k <= 0.0 {
            return None;
        }
        let n = &self.config.prior_noise;
        let gate_t = k * (n.bias_trans_m + 3.0 * n.jitter_trans_m).max(0.002);
        let gate_r = k * (n.bias_rot_deg + 3.0 * n.jitter_rot_deg).max(0.2);
        let dt = (map_from_camera.translation.vector - prior_in_map.translation.vector).norm();
        let dr = (map_from_camera.rotation.inverse() * prior_in_map.rotation).angle().to_degrees();
        (dt > gate_t || dr > gate_r).then(|| LostReason::PriorDisagreement {
            trans_mm: (dt * 1e3).round().min(f64::from(u32::MAX)) as u32,
            rot_cdeg: (dr * 100.0).round().min(f64::from(u32::MAX)) as u32,
        })
    }

    /// `Some(reason)` (against the newest reference) if `map_from_camera` disagrees with every
    /// prediction of the motion gate; `None` when it agrees with one or there are none.
    pub(super) fn motion_gate(&self, map_from_camera: &Se3, predicted: &[(Se3, Se3)]) -> Option<LostReason> {
        let mut reasons = predicted.iter().map(|(p, m)| self.motion_disagreement(map_from_camera, p, m));
        let first = reasons.next()??;
        reasons.all(|r| r.is_some()).then_some(first)
    }

    /// `Some(reason)` if `map_from_camera` is farther from `predicted` (the last tracked pose of
    /// this view moved by the prior's `motion` since then) than the motion gate
    /// ([`TrackerConfig::motion_gate_floor_m`]).
    pub(super) fn motion_disagreement(
        &self,
        map_from_camera: &Se3,
        predicted: &Se3,
        motion: &Se3,
    ) -> Option<LostReason> {
        let (floor_t, floor_r) = (self.config.motion_gate_floor_m, self.config.motion_gate_floor_deg);
        if floor_t <= 0.0 && floor_r <= 0.0 {
            return None;
        }
        let n = &self.config.prior_noise;
        let (theta, d) = (motion.rotation.angle(), motion.translation.vector.norm());
        let bias_rot = n.bias_rot_deg.to_radians();
        let gate_t = floor_t + theta * n.bias_trans_m + bias_rot * d;
        let gate_r = floor_r + (theta * bias_rot).to_degrees();
        let dt = (map_from_camera.translation.vector - predicted.translation.vector).norm();
        let dr = (map_from_camera.rotation.inverse() * predicted.rotation).angle().to_degrees();
        ((floor_t > 0.0 && dt > gate_t) || (floor_r > 0.0 && dr > gate_r)).then(|| LostReason::MotionDisagreement {
            trans_mm: (dt * 1e3).round().min(f64::from(u32::MAX)) as u32,
            rot_cdeg: (dr * 100.0).round().min(f64::from(u32::MAX)) as u32,
        })
    }
}
