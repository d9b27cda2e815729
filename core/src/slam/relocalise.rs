//! Appearance-based relocalisation of an RGB-D frame against a keyframe database, as ORB-SLAM
//! relocalises: the baseline the object-level relocalisation (`crate::topo`) is compared with.
//!
//! # Entry points
//! - [`AppearanceDatabase::build`]: ORB features ([`OrbExtractor`]) of every prior keyframe, each
//!   keypoint with depth lifted to a map point in the prior's frame through the keyframe's pose.
//! - [`AppearanceDatabase::relocalise`]: the pose of a query RGB-D frame in the prior's frame.
//!
//! # Algorithm
//! 1. The query's ORB features are matched exhaustively against every keyframe
//!    ([`match_brute_force`]: Hamming threshold, ratio test, orientation consistency); keyframes
//!    with fewer than [`AppearanceConfig::min_matches`] matches are dropped and the best
//!    [`AppearanceConfig::candidates`] by match count are tried (ORB-SLAM2's bag-of-words
//!    candidates, here found exhaustively, which can only find more).
//! 2. Per candidate, RANSAC over 3-point minimal sets of 3D–3D pairs (query keypoint lifted by its
//!    own depth ↔ the keyframe's map point; Umeyama's rigid fit, [`crate::topo::umeyama`]): no pose
//!    prior is needed, as a relocalising camera has none. A pair is an inlier when the moved query
//!    point lies within `inlier_m + inlier_rel × depth` of its map point.
//! 3. The best hypothesis is refined by robust motion-only optimisation ([`refine_pose`]: pixel and
//!    depth residuals, χ² re-classification) over all matches of the candidate; it is accepted with
//!    at least [`AppearanceConfig::min_inliers`] inliers (ORB-SLAM2: 50). The candidate with the
//!    most inliers wins.

use nalgebra::{Matrix3, Matrix4, Point3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use super::features::{Features, OrbConfig, OrbExtractor};
use super::matcher::{match_brute_force, MatchConfig};
use super::pnp::{refine_pose, Correspondence, PoseRefineConfig};
use super::SlamError;
use crate::frame::{DepthImage, GreyImage};
use crate::geometry::{se3_from_matrix, PinholeCamera, Se3};
use crate::map::validate::InvalidValue;
use crate::topo::umeyama;

/// Configuration of appearance-based relocalisation.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct AppearanceConfig {
    /// ORB extractor of both the keyframes and the query (ORB-SLAM2's 1000 features, 8 levels).
    pub orb: OrbConfig,
    /// Descriptor matching (ORB-SLAM2 relocalisation: ratio 0.75, orientation check).
    pub matcher: MatchConfig,
    /// Keyframes with fewer matches than this are not tried (ORB-SLAM2: 15).
    pub min_matches: usize,
    /// Keyframes tried per query, best by match count first.
    pub candidates: usize,
    /// RANSAC hypotheses per candidate keyframe.
    pub ransac_iterations: usize,
    /// Inlier distance of a 3D–3D pair, metres, at zero depth.
    pub inlier_m: f64,
    /// Inlier distance growth per metre of query depth (depth noise grows with range).
    pub inlier_rel: f64,
    /// Inliers needed after refinement to accept a pose (ORB-SLAM2 relocalisation: 50).
    pub min_inliers: usize,
    /// Robust pose refinement of the best hypothesis.
    pub refine: PoseRefineConfig,
    /// Seed of the RANSAC sampler.
    pub seed: u64,
}

impl Default for AppearanceConfig {
    fn default() -> Self {
        Self {
            orb: OrbConfig::default(),
            matcher: MatchConfig { max_distance: 64, ratio: 0.75, check_orientation: true, orientation_bins: 30 },
            min_matches: 15,
            candidates: 5,
            ransac_iterations: 300,
            inlier_m: 0.01,
            inlier_rel: 0.02,
            min_inliers: 50,
            refine: PoseRefineConfig::default(),
            seed: 7,
        }
    }
}

/// A prior keyframe: grey image, depth, camera and its pose in the prior map's frame.
#[derive(Debug, Clone)]
pub struct RgbdKeyframe {
    /// Grey image.
    pub grey: GreyImage,
    /// Depth, metres (0 = no return).
    pub depth: DepthImage,
    /// Intrinsics.
    pub camera: PinholeCamera,
    /// The keyframe's pose in the prior map's frame (OpenCV camera axes).
    pub world_from_camera: Se3,
}

/// A successful relocalisation.
#[derive(Debug, Clone, PartialEq)]
pub struct Relocalisation {
    /// The query camera's pose in the prior map's frame.
    pub world_from_camera: Se3,
    /// Index of the keyframe it was found against.
    pub keyframe: usize,
    /// Descriptor matches with that keyframe.
    pub matches: usize,
    /// Inliers after refinement.
    pub inliers: usize,
}

/// One query frame's outcome, as the bindings report it (JSON).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RelocalisationRecord {
    /// Whether the frame relocalised.
    pub ok: bool,
    /// Its pose in the prior's frame (4x4, rows), when it did.
    pub world_from_camera: Option<[[f64; 4]; 4]>,
    /// The keyframe it was found against, when it did.
    pub keyframe: Option<usize>,
    /// Descriptor matches with that keyframe, when it did.
    pub matches: Option<usize>,
    /// Inliers (the best count reached when it did not).
    pub inliers: usize,
    /// Why not (`too_few_inliers`), when it did not.
    pub reason: Option<&'static str>,
}

/// Relocalise every `(grey, depth)` query frame against `keyframes` (one [`AppearanceDatabase`]).
/// Errors: a bad config or image size; a frame that does not relocalise is a record, not an error.
pub fn relocalise_frames(
    config: AppearanceConfig,
    keyframes: &[RgbdKeyframe],
    queries: &[(GreyImage, DepthImage)],
    camera: &PinholeCamera,
) -> Result<Vec<RelocalisationRecord>, SlamError> {
    let mut db = AppearanceDatabase::build(config, keyframes)?;
    queries
        .iter()
        .map(|(grey, depth)| match db.relocalise(grey, depth, camera) {
            Ok(r) => {
                let m = r.world_from_camera.to_homogeneous();
                Ok(RelocalisationRecord {
                    ok: true,
                    world_from_camera: Some(std::array::from_fn(|i| std::array::from_fn(|j| m[(i, j)]))),
                    keyframe: Some(r.keyframe),
                    matches: Some(r.matches),
                    inliers: r.inliers,
                    reason: None,
                })
            }
            Err(SlamError::TooFewInliers { actual, .. }) => Ok(RelocalisationRecord {
                ok: false,
                world_from_camera: None,
                keyframe: None,
                matches: None,
                inliers: actual,
                reason: Some("too_few_inliers"),
            }),
            Err(e) => Err(e),
        })
        .collect()
}

#[derive(Debug, Clone)]
struct Entry {
    features: Features,
    /// Map point of each keypoint, prior frame; `None` without depth.
    points_in_world: Vec<Option<Point3<f64>>>,
}

/// The prior's keyframes as features and map points ([module docs](self)).
#[derive(Debug, Clone)]
pub struct AppearanceDatabase {
    config: AppearanceConfig,
    extractor: OrbExtractor,
    entries: Vec<Entry>,
}

/// Depth at a keypoint's (rounded) pixel, as the tracker reads it.
fn depth_at(depth: &DepthImage, x: f32, y: f32) -> Option<f64> {
    let (u, v) = (x.round(), y.round());
    if u < 0.0 || v < 0.0 {
        return None;
    }
    depth.at(u as u32, v as u32).map(f64::from)
}

fn check_size(field: &'static str, camera: &PinholeCamera, w: u32, h: u32) -> Result<(), SlamError> {
    if camera.width != w || camera.height != h {
        return Err(SlamError::ImageSize {
            field,
            width: camera.width,
            height: camera.height,
            actual_width: w,
            actual_height: h,
        });
    }
    Ok(())
}

impl AppearanceDatabase {
    /// Extract features of every keyframe and lift those with depth into the prior's frame.
    /// Errors: a bad config, or an image or depth whose size disagrees with its camera.
    pub fn build(config: AppearanceConfig, keyframes: &[RgbdKeyframe]) -> Result<Self, SlamError> {
        if config.candidates == 0 {
            return Err(SlamError::Config { field: "candidates", reason: "must be ≥ 1".into() });
        }
        if !(config.inlier_m.is_finite() && config.inlier_m > 0.0 && config.inlier_rel.is_finite()) {
            return Err(SlamError::Config { field: "inlier_m", reason: "must be finite and > 0".into() });
        }
        let mut extractor = OrbExtractor::new(config.orb)?;
        let mut entries = Vec::with_capacity(keyframes.len());
        for kf in keyframes {
            check_size("keyframe grey", &kf.camera, kf.grey.width, kf.grey.height)?;
            check_size("keyframe depth", &kf.camera, kf.depth.width, kf.depth.height)?;
            let features = extractor.extract(&kf.grey)?;
            let points_in_world = features
                .keypoints
                .iter()
                .map(|k| {
                    depth_at(&kf.depth, k.x, k.y).map(|z| {
                        let [u, v] = k.image_point();
                        kf.world_from_camera * kf.camera.unproject(u, v, z)
                    })
                })
                .collect();
            entries.push(Entry { features, points_in_world });
        }
        Ok(Self { config, extractor, entries })
    }

    /// Number of keyframes.
    pub fn len(&self) -> usize {
        self.entries.len()
    }

    /// Whether the database has no keyframe.
    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }

    /// The pose of a query RGB-D frame in the prior's frame ([module docs](self)). Errors:
    /// [`SlamError::TooFewInliers`] when no candidate reaches `min_inliers` (its `actual` is the
    /// best count reached), or an image whose size disagrees with the camera.
    pub fn relocalise(
        &mut self,
        grey: &GreyImage,
        depth: &DepthImage,
        camera: &PinholeCamera,
    ) -> Result<Relocalisation, SlamError> {
        check_size("query grey", camera, grey.width, grey.height)?;
        check_size("query depth", camera, depth.width, depth.height)?;
        let query = self.extractor.extract(grey)?;
        let cfg = self.config;
        let mut ranked: Vec<(usize, Vec<super::FeatureMatch>)> = self
            .entries
            .iter()
            .enumerate()
            .map(|(i, e)| {
                let m = match_brute_force(
                    &query.descriptors,
                    &query.keypoints,
                    &e.features.descriptors,
                    &e.features.keypoints,
                    &cfg.matcher,
                );
                (i, m)
            })
            .filter(|(_, m)| m.len() >= cfg.min_matches)
            .collect();
        ranked.sort_by_key(|(i, m)| (std::cmp::Reverse(m.len()), *i));
        let mut best: Option<Relocalisation> = None;
        let mut best_count = 0;
        for (kf, matches) in ranked.into_iter().take(cfg.candidates) {
            let entry = &self.entries[kf];
            let mut corr = Vec::new();
            let mut pairs: Vec<(Vector3<f64>, Vector3<f64>, f64)> = Vec::new();
            for m in &matches {
                let (Some(kp), Some(Some(p_in_world))) =
                    (query.keypoints.get(m.query_index), entry.points_in_world.get(m.train_index))
                else {
                    continue;
                };
                let z = depth_at(depth, kp.x, kp.y);
                let pixel = kp.image_point();
                corr.push(Correspondence { p_in_world: *p_in_world, pixel, depth_m: z, sigma_px: f64::from(kp.scale) });
                if let Some(z) = z {
                    pairs.push((camera.unproject(pixel[0], pixel[1], z).coords, p_in_world.coords, z));
                }
            }
            let Some(hypothesis) = ransac_rigid(&pairs, &cfg, kf as u64) else { continue };
            let Ok(refined) = refine_pose(&corr, camera, &hypothesis, &cfg.refine) else { continue };
            if refined.n_inliers > best_count {
                best_count = refined.n_inliers;
                best = Some(Relocalisation {
                    world_from_camera: refined.world_from_camera,
                    keyframe: kf,
                    matches: matches.len(),
                    inliers: refined.n_inliers,
                });
            }
        }
        match best {
            Some(r) if r.inliers >= cfg.min_inliers => Ok(r),
            _ => Err(SlamError::TooFewInliers { required: cfg.min_inliers, actual: best_count }),
        }
    }
}

/// RANSAC of a rigid `world_from_camera` over 3D–3D pairs `(p_in_camera, p_in_world, depth)`:
/// 3-point Umeyama fits (scale discarded), scored by the depth-scaled inlier distance, the best
/// refitted on its inliers. `None` with fewer than 3 pairs or no non-degenerate sample.
fn ransac_rigid(pairs: &[(Vector3<f64>, Vector3<f64>, f64)], cfg: &AppearanceConfig, stream: u64) -> Option<Se3> {
    let n = pairs.len();
    if n < 3 {
        return None;
    }
    let inliers_of = |pose: &Se3| -> Vec<usize> {
        pairs
            .iter()
            .enumerate()
            .filter(|(_, (c, w, z))| {
                (pose * Point3::from(*c) - Point3::from(*w)).norm() <= cfg.inlier_m + cfg.inlier_rel * z
            })
            .map(|(i, _)| i)
            .collect()
    };
    let fit = |idx: &[usize]| -> Option<Se3> {
        let cam: Vec<Vector3<f64>> = idx.iter().map(|&i| pairs[i].0).collect();
        let world: Vec<Vector3<f64>> = idx.iter().map(|&i| pairs[i].1).collect();
        umeyama(&cam, &world).map(|s| s.isometry)
    };
    let mut rng = ChaCha8Rng::seed_from_u64(cfg.seed ^ stream.wrapping_mul(0x9E37_79B9_7F4A_7C15));
    let mut best: Option<(Se3, usize)> = None;
    for _ in 0..cfg.ransac_iterations {
        let a = rng.random_range(0..n);
        let b = rng.random_range(0..n);
        let c = rng.random_range(0..n);
        if a == b || b == c || a == c {
            continue;
        }
        let Some(pose) = fit(&[a, b, c]) else { continue };
        let k = inliers_of(&pose).len();
        if best.as_ref().is_none_or(|(_, bk)| k > *bk) {
            best = Some((pose, k));
        }
    }
    let (pose, _) = best?;
    let inliers = inliers_of(&pose);
    if inliers.len() >= 3 {
        fit(&inliers).or(Some(pose))
    } else {
        Some(pose)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::slam::synthetic::{look_at, TabletopScene};

    fn keyframe(scene: &TabletopScene, camera: &PinholeCamera, eye: [f64; 3]) -> RgbdKeyframe {
        let pose = look_at(Point3::new(eye[0], eye[1], eye[2]), Point3::new(0.5, 0.0, 0.0));
        let (grey, depth) = scene.render(camera, &pose);
        RgbdKeyframe { grey, depth, camera: *camera, world_from_camera: pose }
    }

    #[test]
    fn a_request_builds_keyframes_and_names_the_bad_field() {
        let scene = TabletopScene::tabletop(3);
        let camera = PinholeCamera::from_fovy(64, 48, 58f64.to_radians()).unwrap();
        let kf = keyframe(&scene, &camera, [0.1, 0.0, 0.5]);
        let rows = |m: nalgebra::Matrix4<f64>| std::array::from_fn(|r| std::array::from_fn(|c| m[(r, c)]));
        let k = camera.matrix();
        let request = AppearanceRequest {
            config: AppearanceConfig::default(),
            intrinsics: std::array::from_fn(|r| std::array::from_fn(|c| k[(r, c)])),
            prior_world_from_camera: vec![rows(kf.world_from_camera.to_homogeneous())],
        };
        let (keyframes, cam) = request.keyframes(vec![(kf.grey.clone(), kf.depth.clone())], None).unwrap();
        assert_eq!(cam, camera);
        assert!(
            (keyframes[0].world_from_camera.to_homogeneous() - kf.world_from_camera.to_homogeneous()).abs().max()
                < 1e-12
        );
        let err = request.keyframes(Vec::new(), None).unwrap_err();
        assert_eq!(err.field, "prior_world_from_camera");
        let mut bad = request.clone();
        bad.prior_world_from_camera[0][3][3] = 2.0;
        let err = bad.keyframes(vec![(kf.grey, kf.depth)], None).unwrap_err();
        assert_eq!(err.field, "prior_world_from_camera[0]");
    }

    #[test]
    fn relocalises_a_nearby_view_without_a_prior() {
        let scene = TabletopScene::tabletop(3);
        let camera = PinholeCamera::from_fovy(640, 480, 58f64.to_radians()).unwrap();
        let kfs = vec![keyframe(&scene, &camera, [0.1, 0.0, 0.5]), keyframe(&scene, &camera, [0.5, 0.45, 0.5])];
        let mut db = AppearanceDatabase::build(AppearanceConfig::default(), &kfs).unwrap();
        let query = keyframe(&scene, &camera, [0.15, 0.08, 0.45]);
        let r = db.relocalise(&query.grey, &query.depth, &camera).unwrap();
        assert_eq!(r.keyframe, 0);
        let err = r.world_from_camera.inverse() * query.world_from_camera;
        assert!(err.translation.vector.norm() < 0.01, "translation error {}", err.translation.vector.norm());
        assert!(err.rotation.angle() < 1f64.to_radians(), "rotation error {}", err.rotation.angle());
    }

    #[test]
    fn an_unrelated_view_is_refused() {
        let scene = TabletopScene::tabletop(3);
        let other = TabletopScene::tabletop(11);
        let camera = PinholeCamera::from_fovy(640, 480, 58f64.to_radians()).unwrap();
        let mut db =
            AppearanceDatabase::build(AppearanceConfig::default(), &[keyframe(&scene, &camera, [0.1, 0.0, 0.5])])
                .unwrap();
        let query = keyframe(&other, &camera, [0.1, 0.0, 0.5]);
        assert!(matches!(
            db.relocalise(&query.grey, &query.depth, &camera),
            Err(SlamError::TooFewInliers { required: 50, .. })
        ));
    }
}

/// An appearance relocalisation request as the Python API gives it: the settings, the nominal
/// intrinsics and the prior keyframes' poses (the images come separately).
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AppearanceRequest {
    /// Settings (missing keys take the defaults).
    #[serde(default)]
    pub config: AppearanceConfig,
    /// Intrinsics 3x3 (rows) of every frame.
    pub intrinsics: [[f64; 3]; 3],
    /// Each prior keyframe's `world_from_camera` (4x4, rows).
    pub prior_world_from_camera: Vec<[[f64; 4]; 4]>,
}

impl AppearanceRequest {
    /// The prior keyframes from their `(grey, depth)` frames and this request's poses, and the
    /// camera (of the first prior frame's size, else `first_query`'s). Errors name the field.
    pub fn keyframes(
        &self,
        prior: Vec<(GreyImage, DepthImage)>,
        first_query: Option<&(GreyImage, DepthImage)>,
    ) -> Result<(Vec<RgbdKeyframe>, PinholeCamera), InvalidValue> {
        if prior.len() != self.prior_world_from_camera.len() {
            let reason = format!("{} poses for {} keyframes", self.prior_world_from_camera.len(), prior.len());
            return Err(InvalidValue::new("prior_world_from_camera", reason));
        }
        let (w, h) = prior.first().or(first_query).map_or((1, 1), |(g, _)| (g.width, g.height));
        let k = Matrix3::from_fn(|r, c| self.intrinsics[r][c]);
        let camera =
            PinholeCamera::from_matrix(w, h, &k).map_err(|e| InvalidValue::new("intrinsics", e.to_string()))?;
        let keyframes = prior
            .into_iter()
            .zip(&self.prior_world_from_camera)
            .enumerate()
            .map(|(i, ((grey, depth), m))| {
                let world_from_camera =
                    se3_from_matrix(&Matrix4::from_fn(|r, c| m[r][c]), "prior_world_from_camera")
                        .map_err(|e| InvalidValue::new(format!("prior_world_from_camera[{i}]"), e.to_string()))?;
                Ok(RgbdKeyframe { grey, depth, camera, world_from_camera })
            })
            .collect::<Result<_, InvalidValue>>()?;
        Ok((keyframes, camera))
    }
}
