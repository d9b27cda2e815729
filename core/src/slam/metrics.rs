//! Trajectory metrics: absolute trajectory error (ATE) and relative pose error (RPE).
//!
//! No alignment is applied: estimated and ground-truth poses live in the same world frame (the
//! robot base), so any global offset of the estimate is an error the downstream object map would
//! inherit, and must count. ATE RMSE = sqrt(mean ‖t_est,i − t_gt,i‖²) over camera positions
//! (Sturm et al. 2012, without the Horn alignment). RPE between consecutive frames: with
//! `E_i = (gt_i⁻¹ gt_{i+1})⁻¹ (est_i⁻¹ est_{i+1})`, translation RMSE of ‖trans(E_i)‖ (metres) and
//! rotation RMSE of angle(E_i) (degrees).

use super::SlamError;
use crate::geometry::Se3;

/// Relative pose error between consecutive frames.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rpe {
    /// RMSE of the relative translation error, metres.
    pub trans_m: f64,
    /// RMSE of the relative rotation error, degrees.
    pub rot_deg: f64,
}

fn check(estimated: &[Se3], ground_truth: &[Se3], min_len: usize) -> Result<(), SlamError> {
    if estimated.len() != ground_truth.len() {
        return Err(SlamError::TrajectoryLength { estimated: estimated.len(), ground_truth: ground_truth.len() });
    }
    if estimated.len() < min_len {
        return Err(SlamError::TooFewPoses { required: min_len, actual: estimated.len() });
    }
    Ok(())
}

/// ATE RMSE in metres (no alignment; see the module docs).
pub fn ate_rmse_m(estimated: &[Se3], ground_truth: &[Se3]) -> Result<f64, SlamError> {
    check(estimated, ground_truth, 1)?;
    let sum: f64 = estimated
        .iter()
        .zip(ground_truth)
        .map(|(e, g)| (e.translation.vector - g.translation.vector).norm_squared())
        .sum();
    Ok((sum / estimated.len() as f64).sqrt())
}

/// RPE between consecutive frames (needs ≥ 2 poses).
pub fn rpe(estimated: &[Se3], ground_truth: &[Se3]) -> Result<Rpe, SlamError> {
    check(estimated, ground_truth, 2)?;
    let (mut st, mut sr) = (0.0, 0.0);
    let n = estimated.len() - 1;
    for i in 0..n {
        let de = estimated[i].inverse() * estimated[i + 1];
        let dg = ground_truth[i].inverse() * ground_truth[i + 1];
        let e = dg.inverse() * de;
        st += e.translation.vector.norm_squared();
        sr += e.rotation.angle().to_degrees().powi(2);
    }
    Ok(Rpe { trans_m: (st / n as f64).sqrt(), rot_deg: (sr / n as f64).sqrt() })
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion, Vector3};

    fn pose(x: f64, yaw_deg: f64) -> Se3 {
        Se3::from_parts(
            Translation3::new(x, 0.0, 0.0),
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw_deg.to_radians()),
        )
    }

    #[test]
    fn ate_of_a_constant_offset_is_the_offset() {
        let gt: Vec<Se3> = (0..5).map(|i| pose(0.1 * i as f64, 0.0)).collect();
        let est: Vec<Se3> = gt.iter().map(|g| Se3::translation(0.0, 0.003, 0.004) * g).collect();
        assert!((ate_rmse_m(&est, &gt).unwrap_or(f64::NAN) - 0.005).abs() < 1e-12);
        // A constant offset has no relative error.
        let r = rpe(&est, &gt).unwrap_or(Rpe { trans_m: f64::NAN, rot_deg: f64::NAN });
        assert!(r.trans_m < 1e-12 && r.rot_deg < 1e-9);
    }

    #[test]
    fn ate_rmse_mixes_errors_quadratically_and_rpe_sees_steps() {
        let gt = vec![pose(0.0, 0.0), pose(0.0, 0.0)];
        let est = vec![pose(0.0, 0.0), pose(0.02, 2.0)];
        // sqrt((0 + 0.02²) / 2)
        assert!((ate_rmse_m(&est, &gt).unwrap_or(f64::NAN) - 0.02 / 2f64.sqrt()).abs() < 1e-12);
        let r = rpe(&est, &gt).unwrap_or(Rpe { trans_m: f64::NAN, rot_deg: f64::NAN });
        assert!((r.trans_m - 0.02).abs() < 1e-12);
        assert!((r.rot_deg - 2.0).abs() < 1e-9);
    }

    #[test]
    fn mismatched_or_short_trajectories_are_errors() {
        assert!(matches!(ate_rmse_m(&[pose(0.0, 0.0)], &[]), Err(SlamError::TrajectoryLength { .. })));
        assert!(matches!(ate_rmse_m(&[], &[]), Err(SlamError::TooFewPoses { .. })));
        assert!(matches!(
            rpe(&[pose(0.0, 0.0)], &[pose(0.0, 0.0)]),
            Err(SlamError::TooFewPoses { required: 2, actual: 1 })
        ));
    }
}
