//! Unit tests of the explore module on synthetic maps (closed forms and geometric facts).

use nalgebra::{Point3, Vector3};

use super::*;
use crate::geometry::{look_at, se3_from_yaw, Box2, ObjectGeometry, Shape};
use crate::map::{EstimateStage, Label, MapObject};

fn object(label: Label, center: [f64; 3], yaw: f64, half: [f64; 3]) -> MapObject {
    MapObject {
        id: 0,
        label,
        world_from_object: se3_from_yaw(Vector3::from(center), yaw),
        half_extents: Vector3::from(half),
        observations: Vec::new(),
        points_in_world: Vec::new(),
        stage: EstimateStage::Raw,
    }
}

fn map_of(objects: Vec<MapObject>) -> ObjectMap {
    let mut m = ObjectMap::new();
    for o in objects {
        m.insert(o);
    }
    m
}

fn camera() -> PinholeCamera {
    PinholeCamera::from_fovy(640, 480, 1.0).unwrap()
}

/// Eye at `dist` from `center`, azimuth `az_deg` about z, elevation `el_deg`.
fn eye_around(center: [f64; 3], az_deg: f64, el_deg: f64, dist: f64) -> Point3<f64> {
    let (az, el) = (az_deg.to_radians(), el_deg.to_radians());
    Point3::from(Vector3::from(center) + Vector3::new(el.cos() * az.cos(), el.cos() * az.sin(), el.sin()) * dist)
}

fn view(eye: Point3<f64>, target: [f64; 3]) -> Se3 {
    look_at(&eye, &Point3::from(Vector3::from(target))).unwrap()
}

fn face_index(f: Face) -> usize {
    Face::ALL.iter().position(|x| *x == f).unwrap_or(usize::MAX)
}

#[test]
fn all_unknown_grid_has_maximal_entropy() {
    let o = object(Label::Block, [0.5, 0.0, 0.02], 0.3, [0.05, 0.03, 0.02]);
    let g = SurfaceGrid::new(&o, &GridConfig::default()).unwrap();
    let s = g.stats();
    // ±x: 6×4, ±y: 10×4, top: 10×6 cells of 1 cm.
    assert_eq!(s.cells(), 2 * 24 + 2 * 40 + 60);
    assert_eq!(s.unknown, s.cells());
    assert!((s.entropy_bits - s.cells() as f64).abs() < 1e-9, "H_obj = {}", s.entropy_bits);
    assert!((s.normalized_entropy() - 1.0).abs() < 1e-12);
    assert_eq!(s.occupied_ratio(), 0.0);
    // H(p) ≤ H(0.5) = 1 bit for every p.
    for p in [0.01, 0.2, 0.49, 0.51, 0.9] {
        assert!(binary_entropy_bits(p) < 1.0);
    }
    assert!((binary_entropy_bits(0.5) - 1.0).abs() < 1e-15);
    // A cylinder: four quarter arcs plus the masked top disc, all unknown, H̄ = 1.
    let c = object(Label::Can, [0.4, 0.1, 0.06], 0.0, [0.03, 0.03, 0.06]);
    let gc = SurfaceGrid::new(&c, &GridConfig::default()).unwrap();
    let sc = gc.stats();
    let top = gc.face_stats(face_index(Face::Top)).cells();
    // Disc of radius 3 cm on 1 cm cells: between π(r − √2/2 cm)² and π(r + √2/2 cm)² cells.
    assert!(top > 15 && top < 45, "top cells {top}");
    // Each quarter arc: ceil(π·3/2 cm) = 5 cells around, 12 up.
    assert_eq!(sc.cells() - top, 4 * 5 * 12);
    assert!((sc.normalized_entropy() - 1.0).abs() < 1e-12);
}

#[test]
fn every_cell_centre_maps_back_to_its_cell() {
    let cfg = GridConfig::default();
    for o in [
        object(Label::Book, [0.5, 0.0, 0.02], 0.7, [0.1, 0.07, 0.02]),
        object(Label::Bottle, [0.3, -0.2, 0.1], 0.0, [0.035, 0.035, 0.1]),
    ] {
        let g = SurfaceGrid::new(&o, &cfg).unwrap();
        for c in g.cells() {
            let pose = g.cell_pose(c).unwrap_or_else(|| panic!("no pose for {c:?}"));
            assert!((pose.normal_in_object.norm() - 1.0).abs() < 1e-12);
            // Slightly outside the surface along the normal still lands on the same cell.
            let p = pose.p_in_object + pose.normal_in_object * 0.001;
            assert_eq!(g.cell_of_point(&p, 0.03), Some(c), "{:?} cell {c:?}", o.label);
        }
        // A point below the object (nearest face: bottom) and a far point are not projected.
        let h = o.half_extents;
        assert_eq!(g.cell_of_point(&Point3::new(0.0, 0.0, -h.z - 0.001), 0.03), None);
        assert_eq!(g.cell_of_point(&Point3::new(0.0, 0.0, h.z + 0.2), 0.03), None);
    }
}

fn top_points(o: &MapObject, spacing_m: f64) -> Vec<Point3<f64>> {
    let h = o.half_extents;
    let mut pts = Vec::new();
    let (nx, ny) = ((2.0 * h.x / spacing_m) as usize, (2.0 * h.y / spacing_m) as usize);
    for i in 0..nx {
        for j in 0..ny {
            let p = Point3::new(-h.x + (i as f64 + 0.5) * spacing_m, -h.y + (j as f64 + 0.5) * spacing_m, h.z);
            pts.push(o.world_from_object * p);
        }
    }
    pts
}

#[test]
fn observing_a_face_lowers_normalized_entropy() {
    let cfg = GridConfig::default();
    let map = map_of(vec![object(Label::Block, [0.5, 0.0, 0.05], 0.4, [0.05, 0.05, 0.05])]);
    let o = &map.objects[0];
    let mut grids = ExplorationGrids::new();
    grids.sync(&map, &cfg).unwrap();
    let before = grids.get(o.id).map(|g| g.stats()).unwrap_or_default();
    // Straight down from 0.4 m above the top: only the top faces the camera within 80°.
    let pose = view(Point3::new(0.5, 0.0, 0.5), [0.5, 0.0, 0.05]);
    let obs = [ObservedPoints { object_id: o.id, points_in_world: top_points(o, 0.005) }];
    let up = grids.integrate_frame(&map, &camera(), &pose, &obs, None, &cfg).unwrap();
    let g = grids.get(o.id).expect("no grid");
    let after = g.stats();
    assert!(
        after.normalized_entropy() < before.normalized_entropy() - 0.03,
        "{} → {}",
        before.normalized_entropy(),
        after.normalized_entropy()
    );
    let top = g.face_stats(face_index(Face::Top));
    assert_eq!(top.occupied, 100);
    assert_eq!(up.objects[0].hits, 100);
    assert_eq!(up.objects[0].points_dropped, 0);
    for f in [Face::PosX, Face::NegX, Face::PosY, Face::NegY] {
        assert_eq!(g.face_stats(face_index(f)).unknown, 100, "{f:?}");
    }
    // Expected value: 100 cells at p_hit, 400 unknown.
    let expected = (100.0 * binary_entropy_bits(cfg.p_hit) + 400.0) / 500.0;
    assert!((after.normalized_entropy() - expected).abs() < 1e-6);

    // A side view with no points and no depth: the facing side and the top become free, the far
    // side stays unknown.
    let mut grids2 = ExplorationGrids::new();
    let side = view(eye_around([0.5, 0.0, 0.05], 0.0, 30.0, 0.5), [0.5, 0.0, 0.05]);
    let map0 = map_of(vec![object(Label::Block, [0.5, 0.0, 0.05], 0.0, [0.05, 0.05, 0.05])]);
    grids2.integrate_frame(&map0, &camera(), &side, &[], None, &cfg).unwrap();
    let g2 = grids2.get(0).expect("no grid");
    assert_eq!(g2.face_stats(face_index(Face::PosX)).free, 100);
    assert_eq!(g2.face_stats(face_index(Face::Top)).free, 100);
    assert_eq!(g2.face_stats(face_index(Face::NegX)).unknown, 100);
    assert!(g2.stats().normalized_entropy() < 1.0);
    let m = grids2.mean_normalized_entropy().unwrap_or(f64::NAN);
    assert!((m - g2.stats().normalized_entropy()).abs() < 1e-12);
    assert_eq!(ExplorationGrids::new().mean_normalized_entropy(), None);
}

#[test]
fn occluded_cells_stay_unknown() {
    let cfg = GridConfig::default();
    let wall = object(Label::Book, [0.4, 0.0, 0.1], 0.0, [0.03, 0.1, 0.1]);
    let target = object(Label::Block, [0.55, 0.0, 0.04], 0.0, [0.04, 0.04, 0.04]);
    let eye = Point3::new(0.05, 0.0, 0.08);
    let pose = view(eye, [0.55, 0.0, 0.04]);
    let map = map_of(vec![wall.clone(), target.clone()]);
    let mut grids = ExplorationGrids::new();
    grids.integrate_frame(&map, &camera(), &pose, &[], None, &cfg).unwrap();
    let g_target = grids.get(1).expect("no grid");
    let s = g_target.stats();
    assert_eq!(s.unknown, s.cells(), "target behind the wall must stay unknown: {s:?}");
    let g_wall = grids.get(0).expect("no grid");
    assert_eq!(g_wall.face_stats(face_index(Face::NegX)).free, g_wall.face_stats(face_index(Face::NegX)).cells());
    // The same cell is reported occluded by the visibility query.
    let occ = Occluders::from_map(&map, &cfg);
    let c = g_target.cell_pose(CellRef { face: face_index(Face::NegX), cell: 0 }).expect("cell");
    let p_w = target.world_from_object * c.p_in_object;
    let vis = point_visibility(&p_w, &c.normal_in_object, 1, &Viewpoint::new(&camera(), &pose), &occ, &cfg);
    assert_eq!(vis, CellVisibility::Occluded);
    // Control: without the wall the facing side is seen (free).
    let map_alone = map_of(vec![target]);
    let mut grids2 = ExplorationGrids::new();
    grids2.integrate_frame(&map_alone, &camera(), &pose, &[], None, &cfg).unwrap();
    let g2 = grids2.get(0).expect("no grid");
    assert_eq!(g2.face_stats(face_index(Face::NegX)).free, 64);
    // The table plane blocks a camera below it.
    assert!(occ.segment_blocked(&Point3::new(0.5, 0.5, -0.1), &Point3::new(0.5, 0.0, 0.1), None));
}

#[test]
fn depth_in_front_of_a_cell_leaves_it_unknown_and_matching_depth_makes_it_occupied() {
    let cfg = GridConfig::default();
    let map = map_of(vec![object(Label::Block, [0.5, 0.0, 0.05], 0.0, [0.05, 0.05, 0.05])]);
    let cam = PinholeCamera::from_fovy(64, 48, 1.0).unwrap();
    let pose = view(Point3::new(0.5, 0.0, 0.5), [0.5, 0.0, 0.05]);
    // Everything at 0.2 m: an unmodelled occluder in front of the top (at 0.4 m).
    let near = DepthImage::new(64, 48, vec![0.2; 64 * 48]).unwrap();
    let mut grids = ExplorationGrids::new();
    let up = grids.integrate_frame(&map, &cam, &pose, &[], Some(&near), &cfg).unwrap();
    assert_eq!(grids.get(0).map(|g| g.stats().unknown), Some(500));
    assert_eq!(up.objects[0].depth_rejected, 100);
    // Depth exactly at the top (0.45 m − 0.05 m − 0.05 m... the top is at z = 0.1, camera at 0.5).
    let at_top = DepthImage::new(64, 48, vec![0.4; 64 * 48]).unwrap();
    grids.integrate_frame(&map, &cam, &pose, &[], Some(&at_top), &cfg).unwrap();
    assert_eq!(grids.get(0).map(|g| g.face_stats(face_index(Face::Top)).occupied), Some(100));
    // Depth behind the top (the estimate is too tall): free.
    let far = DepthImage::new(64, 48, vec![0.6; 64 * 48]).unwrap();
    let mut grids2 = ExplorationGrids::new();
    grids2.integrate_frame(&map, &cam, &pose, &[], Some(&far), &cfg).unwrap();
    assert_eq!(grids2.get(0).map(|g| g.face_stats(face_index(Face::Top)).free), Some(100));
}

fn observe_all_but(grids: &mut ExplorationGrids, id: u32, skip: Face, cfg: &GridConfig) {
    let g = grids.grids.get_mut(&id).expect("no grid");
    let cells: Vec<CellRef> = g.cells().filter(|c| Face::ALL[c.face] != skip).collect();
    for c in cells {
        for _ in 0..6 {
            g.update_cell(c, c.cell % 3 == 0, cfg);
        }
    }
}

#[test]
fn utility_prefers_the_view_facing_the_unobserved_face() {
    let cfg = ExploreConfig::default();
    let center = [0.5, 0.0, 0.05];
    let map = map_of(vec![object(Label::Block, center, 0.0, [0.05, 0.05, 0.05])]);
    let mut grids = ExplorationGrids::new();
    grids.sync(&map, &cfg.grid).unwrap();
    observe_all_but(&mut grids, 0, Face::NegX, &cfg.grid);
    let ctx = UtilityContext::new(&map, &grids, &HistoryBook::default(), &camera(), &cfg).unwrap();
    let facing_seen = view(eye_around(center, 0.0, 30.0, 0.45), center);
    let facing_unseen = view(eye_around(center, 180.0, 30.0, 0.45), center);
    let side = view(eye_around(center, 90.0, 30.0, 0.45), center);
    for strategy in [Strategy::ObjectDrivenDiscovery, Strategy::ExpectedGain] {
        let s = ctx.score_all(&[facing_seen, side, facing_unseen], strategy, None).unwrap();
        assert!(
            s[2].utility > s[0].utility && s[2].utility > s[1].utility,
            "{strategy:?}: {:?}",
            s.iter().map(|x| x.utility).collect::<Vec<_>>()
        );
        assert_eq!(next_best_view(&s), Some(2));
        assert_eq!(s[2].objects.len(), 1);
        assert!(s[2].objects[0].visible_cells >= 50);
    }
    // Motion cost: a far view loses exactly μ·(distance + ρ·angle).
    let cur = facing_seen;
    let a = ctx.score(&facing_unseen, Strategy::ExpectedGain, None).unwrap();
    let b = ctx.score(&facing_unseen, Strategy::ExpectedGain, Some(&cur)).unwrap();
    let d = (cur.translation.vector - facing_unseen.translation.vector).norm();
    let ang = cur.rotation.angle_to(&facing_unseen.rotation);
    let expected = cfg.motion_cost_bits_per_m * (d + cfg.motion_cost_m_per_rad * ang);
    assert!((a.utility - b.utility - expected).abs() < 1e-9);
}

#[test]
fn occlusion_term_follows_the_paper_formula() {
    let cfg = ExploreConfig::default();
    let a = object(Label::Block, [0.5, 0.0, 0.05], 0.0, [0.05, 0.05, 0.05]);
    let b = object(Label::Block, [0.62, 0.0, 0.05], 0.0, [0.05, 0.05, 0.05]);
    let map = map_of(vec![a, b]);
    let mut grids = ExplorationGrids::new();
    grids.sync(&map, &cfg.grid).unwrap();
    let ctx = UtilityContext::new(&map, &grids, &HistoryBook::default(), &camera(), &cfg).unwrap();
    // Looking along +x, the two blocks overlap in the image.
    let s = ctx
        .score(
            &view(eye_around([0.56, 0.0, 0.05], 180.0, 20.0, 0.5), [0.56, 0.0, 0.05]),
            Strategy::ObjectDrivenDiscovery,
            None,
        )
        .unwrap();
    assert_eq!(s.objects.len(), 2);
    for t in &s.objects {
        assert!(t.r_iou > 0.1, "{t:?}");
        assert!((t.h_iou - plogp_bits(t.r_iou / 2.0)).abs() < 1e-12);
        // No history: p(V̄) = 0 → H_V = 0; s = 1.
        assert_eq!(t.h_v, 0.0);
        assert_eq!(t.s, 1.0);
        assert!((t.total - (t.entropy_term + 0.2 * t.h_iou)).abs() < 1e-9);
    }
    // Looking along y they do not overlap.
    let s2 = ctx
        .score(
            &view(eye_around([0.56, 0.0, 0.05], 90.0, 20.0, 0.5), [0.56, 0.0, 0.05]),
            Strategy::ObjectDrivenDiscovery,
            None,
        )
        .unwrap();
    assert!(s2.objects.iter().all(|t| t.r_iou == 0.0));
}

#[test]
fn volume_convergence_and_s_rule() {
    let g = |s: f64| ObjectGeometry {
        shape: Shape::Cuboid,
        center: Vector3::new(0.5, 0.0, 0.05),
        yaw_rad: 0.0,
        half_extents: Vector3::new(0.05 * s, 0.05, 0.05),
    };
    let steady = ObjectHistory { estimates: vec![g(1.0), g(1.0), g(1.0)] };
    assert!((steady.volume_convergence(2, 0.05) - 1.0).abs() < 1e-12);
    assert_eq!(steady.consecutive_iou(), Some(1.0));
    let jump = ObjectHistory { estimates: vec![g(1.0), g(1.0), g(1.0), g(2.0)] };
    // Normalised volumes 0.8, 0.8, 0.8, 1.6: σ = √0.12, z = 0.6/√0.12 → p = exp(−1.5).
    assert!((jump.volume_convergence(2, 0.05) - (-1.5f64).exp()).abs() < 1e-9);
    assert_eq!(ObjectHistory { estimates: vec![g(1.0)] }.volume_convergence(2, 0.05), 0.0);
    let cfg = ExploreConfig::default();
    assert!(!needs_exploring(0.4, 0.1, 0.9, &cfg));
    assert!(!needs_exploring(0.9, 0.6, 0.9, &cfg));
    assert!(needs_exploring(0.4, 0.1, 0.7, &cfg));
    assert!(needs_exploring(0.6, 0.4, 0.95, &cfg));

    // Stopping: a fully observed, steady object is done; the budget stops anyway.
    let map = map_of(vec![object(Label::Block, [0.5, 0.0, 0.05], 0.0, [0.05, 0.05, 0.05])]);
    let mut grids = ExplorationGrids::new();
    grids.sync(&map, &cfg.grid).unwrap();
    let mut hist = HistoryBook::default();
    let f0 = object_features(&map, &grids, &hist, &cfg);
    assert_eq!(stop_reason(&f0, 3, &cfg), None);
    assert_eq!(stop_reason(&f0, 10, &cfg), Some(StopReason::MaxViews));
    observe_all_but(&mut grids, 0, Face::Top, &cfg.grid);
    {
        let g = grids.grids.get_mut(&0).expect("no grid");
        let cells: Vec<CellRef> = g.cells().filter(|c| Face::ALL[c.face] == Face::Top).collect();
        for c in cells {
            for _ in 0..6 {
                g.update_cell(c, false, &cfg.grid);
            }
        }
    }
    hist.record(&map);
    hist.record(&map);
    let f1 = object_features(&map, &grids, &hist, &cfg);
    assert!(f1[0].normalized_entropy < 0.5 && f1[0].volume_probability > 0.99, "{:?}", f1[0]);
    assert_eq!(stop_reason(&f1, 3, &cfg), Some(StopReason::AllExplored));
    assert_eq!(stop_reason(&[], 3, &cfg), None);
    // Done objects count for nothing (s = 0) unless every object is counted again (the
    // equal-budget mode of the active session): then the view facing the block scores its terms.
    let mut ctx = UtilityContext::new(&map, &grids, &hist, &camera(), &cfg).unwrap();
    let facing = view(eye_around([0.5, 0.0, 0.05], 180.0, 40.0, 0.45), [0.5, 0.0, 0.05]);
    let done = ctx.score(&facing, Strategy::ObjectDrivenDiscovery, None).unwrap();
    assert!(done.objects.iter().all(|t| t.s == 0.0) && done.utility == 0.0, "{done:?}");
    ctx.explore_every_object();
    assert!(ctx.features().iter().all(|f| f.explore));
    let again = ctx.score(&facing, Strategy::ObjectDrivenDiscovery, None).unwrap();
    assert_eq!(again.objects.len(), 1);
    assert!(again.objects[0].s == 1.0 && again.utility > 0.0, "{again:?}");
}

#[test]
fn grids_follow_the_object_when_its_estimate_changes() {
    let cfg = GridConfig::default();
    let mut map = map_of(vec![object(Label::Block, [0.5, 0.0, 0.05], 0.0, [0.05, 0.05, 0.05])]);
    let mut grids = ExplorationGrids::new();
    grids.sync(&map, &cfg).unwrap();
    observe_all_but(&mut grids, 0, Face::NegX, &cfg);
    let before = grids.get(0).map(|g| g.face_stats(face_index(Face::PosX))).unwrap_or_default();
    // Move and rotate: nothing to resample, states unchanged.
    map.objects[0].world_from_object = se3_from_yaw(Vector3::new(0.45, 0.1, 0.05), 1.0);
    assert!(grids.sync(&map, &cfg).unwrap().is_empty());
    assert_eq!(grids.get(0).map(|g| g.face_stats(face_index(Face::PosX))), Some(before));
    // Grow by 1.5 along y: +x face (y × z) gets 15 × 10 cells, all still observed; −x unknown.
    map.objects[0].half_extents = Vector3::new(0.05, 0.075, 0.05);
    assert_eq!(grids.sync(&map, &cfg).unwrap(), vec![0]);
    let g = grids.get(0).expect("no grid");
    let px = g.face_stats(face_index(Face::PosX));
    assert_eq!(px.cells(), 150);
    assert_eq!(px.unknown, 0);
    assert_eq!(g.face_stats(face_index(Face::NegX)).unknown, 150);
    // Removed (merged) objects lose their grid.
    map.objects.clear();
    grids.sync(&map, &cfg).unwrap();
    assert!(grids.grids.is_empty());
}

fn three_object_map() -> ObjectMap {
    map_of(vec![
        object(Label::Block, [0.45, 0.1, 0.04], 0.3, [0.04, 0.03, 0.04]),
        object(Label::Cup, [0.6, -0.15, 0.05], 0.0, [0.04, 0.04, 0.05]),
        object(Label::Book, [0.5, -0.3, 0.02], -0.5, [0.1, 0.07, 0.02]),
    ])
}

#[test]
fn same_seed_gives_same_candidates_and_utilities() {
    let map = three_object_map();
    let cc = CandidateConfig::default();
    let cfg = ExploreConfig::default();
    let a = sample_candidates(&map, &cc, &cfg.grid, &AlwaysReachable, 7).unwrap();
    let b = sample_candidates(&map, &cc, &cfg.grid, &AlwaysReachable, 7).unwrap();
    let c = sample_candidates(&map, &cc, &cfg.grid, &AlwaysReachable, 8).unwrap();
    assert_eq!(a, b);
    assert_ne!(a, c);
    assert!(a.len() >= 30, "{} candidates", a.len());
    let occ = Occluders::from_map(&map, &cfg.grid);
    for v in &a {
        let eye = Point3::from(v.world_from_camera.translation.vector);
        assert!(camera_position_free(&eye, &occ, &cc));
        let target = map.get(v.target_object.unwrap_or(u32::MAX)).expect("target");
        let d = (target.world_from_object.translation.vector - eye.coords).norm();
        assert!((0.35 - 1e-9..=0.6 + 1e-9).contains(&d));
        // The optical axis points at the target.
        let z = v.world_from_camera.rotation * Vector3::z();
        assert!((z.dot(&(target.world_from_object.translation.vector - eye.coords)) / d - 1.0).abs() < 1e-9);
    }
    let grids = {
        let mut g = ExplorationGrids::new();
        g.integrate_frame(&map, &camera(), &a[0].world_from_camera, &[], None, &cfg.grid).unwrap();
        g
    };
    let views: Vec<Se3> = a.iter().map(|v| v.world_from_camera).collect();
    let ctx = UtilityContext::new(&map, &grids, &HistoryBook::default(), &camera(), &cfg).unwrap();
    for strategy in [Strategy::ObjectDrivenDiscovery, Strategy::ExpectedGain] {
        let s1 = ctx.score_all(&views, strategy, Some(&views[0])).unwrap();
        let s2 = ctx.score_all(&views, strategy, Some(&views[0])).unwrap();
        assert_eq!(s1, s2);
        assert!(next_best_view(&s1).is_some());
    }
    // Restricting to one object samples only around it.
    let one = sample_candidates_around(&map, Some(&[1]), &cc, &cfg.grid, &AlwaysReachable, 7).unwrap();
    assert!(!one.is_empty() && one.iter().all(|v| v.target_object == Some(1)));
    // A reachability callback filters.
    let only_positive_y = |p: &Se3| p.translation.vector.y > 0.0;
    let f = sample_candidates(&map, &cc, &cfg.grid, &only_positive_y, 7).unwrap();
    assert!(!f.is_empty() && f.len() < a.len());
    assert!(f.iter().all(|v| v.world_from_camera.translation.vector.y > 0.0));
}

#[test]
fn look_at_points_z_at_target_with_image_up_along_world_z() {
    let eye = Point3::new(0.2, 0.1, 0.4);
    let target = Point3::new(0.5, 0.0, 0.0);
    let t = look_at(&eye, &target).unwrap();
    let r = t.rotation;
    let z = r * Vector3::z();
    assert!((z - (target - eye).normalize()).norm() < 1e-12);
    let up = r * -Vector3::y();
    assert!(up.z > 0.0);
    // The target projects to the principal point.
    let cam = camera();
    let uv = cam.project(&(t.inverse() * target)).unwrap_or([f64::NAN; 2]);
    assert!((uv[0] - cam.cx).abs() < 1e-9 && (uv[1] - cam.cy).abs() < 1e-9);
    // Straight down: image up points away from the robot base (radially).
    let down = look_at(&Point3::new(0.5, 0.0, 0.45), &Point3::new(0.5, 0.0, 0.0)).unwrap();
    let up_down = down.rotation * -Vector3::y();
    assert!((up_down - Vector3::x()).norm() < 1e-9, "{up_down:?}");
    assert!(look_at(&eye, &eye).is_err());
    assert!(look_at(&Point3::new(f64::NAN, 0.0, 0.0), &target).is_err());
}

#[test]
fn baseline_generators() {
    let table = TableRect { center_m: [0.5, 0.0], size_m: [0.8, 1.2], height_m: 0.0 };
    // The paper's Init: straight down, 0.45 m high, corners inset 0.15 m.
    let cc = CandidateConfig {
        init_height_m: 0.45,
        init_inset_m: 0.15,
        init_tilt_deg: 0.0,
        coverage_inset_m: 0.1,
        ..CandidateConfig::default()
    };
    let init = init_views(&table, &cc).unwrap();
    assert_eq!(init.len(), 4);
    for v in &init {
        let z = v.rotation * Vector3::z();
        assert!((z + Vector3::z()).norm() < 1e-9, "top view");
        let t = v.translation.vector;
        assert!((t.z - 0.45).abs() < 1e-12);
        assert!(((t.x - 0.5).abs() - 0.25).abs() < 1e-12 && (t.y.abs() - 0.45).abs() < 1e-12);
    }
    let cam = camera();
    let cov = coverage_views(&table, &cam, &cc).unwrap();
    assert!(cov.len() >= 4);
    // Boustrophedon: consecutive waypoints move along y within a lane, then one step in x.
    let first = cov[0].rotation;
    for v in &cov {
        assert!(v.rotation.angle_to(&first) < 1e-9, "coverage views share one orientation");
        assert!((v.rotation * -Vector3::y() - Vector3::x()).norm() < 1e-9);
    }
    for w in cov.windows(2) {
        let (a, b) = (w[0].translation.vector, w[1].translation.vector);
        assert!((a.x - b.x).abs() < 1e-12 || (a.y - b.y).abs() < 1e-12);
    }
    let map = three_object_map();
    let r1 = random_views(&table, &map, &cc, &GridConfig::default(), &AlwaysReachable, 10, 3).unwrap();
    let r2 = random_views(&table, &map, &cc, &GridConfig::default(), &AlwaysReachable, 10, 3).unwrap();
    assert_eq!(r1.len(), 10);
    assert_eq!(r1, r2);
    let never = |_: &Se3| false;
    assert!(random_views(&table, &map, &cc, &GridConfig::default(), &never, 10, 3).unwrap_or_default().is_empty());
    assert!(init_views(&TableRect { size_m: [0.0, 1.0], ..table }, &cc).is_err());
}

#[test]
fn bad_inputs_give_typed_errors() {
    let cfg = GridConfig::default();
    let map = three_object_map();
    let mut grids = ExplorationGrids::new();
    let pose = view(Point3::new(0.5, 0.0, 0.5), [0.5, 0.0, 0.0]);
    let ghost = [ObservedPoints { object_id: 99, points_in_world: vec![Point3::origin()] }];
    assert_eq!(
        grids.integrate_frame(&map, &camera(), &pose, &ghost, None, &cfg),
        Err(ExploreError::UnknownObject { object_id: 99 })
    );
    let mut bad_pose = pose;
    bad_pose.translation.vector.x = f64::NAN;
    assert!(matches!(
        grids.integrate_frame(&map, &camera(), &bad_pose, &[], None, &cfg),
        Err(ExploreError::NonFinite { .. })
    ));
    let small = DepthImage::new(4, 4, vec![0.5; 16]).unwrap();
    assert!(matches!(
        grids.integrate_frame(&map, &camera(), &pose, &[], Some(&small), &cfg),
        Err(ExploreError::Degenerate { .. })
    ));
    let bad_cfg = GridConfig { p_miss: 0.7, ..GridConfig::default() };
    assert!(matches!(
        grids.integrate_frame(&map, &camera(), &pose, &[], None, &bad_cfg),
        Err(ExploreError::InvalidConfig { field: "p_miss", .. })
    ));
    // NaN points are dropped, not panics.
    let nan_pts = [ObservedPoints { object_id: 0, points_in_world: vec![Point3::new(f64::NAN, 0.0, 0.0)] }];
    let up = grids.integrate_frame(&map, &camera(), &pose, &nan_pts, None, &cfg).unwrap();
    assert_eq!(up.objects[0].points_dropped, 1);
    // A non-finite size is an error; a zero size is raised to the minimum and still has cells.
    let mut nan_map = map.clone();
    nan_map.objects[0].half_extents.x = f64::NAN;
    assert!(ExplorationGrids::new().sync(&nan_map, &cfg).is_err());
    let flat = object(Label::Book, [0.5, 0.0, 0.0], 0.0, [0.1, 0.1, 0.0]);
    assert!(SurfaceGrid::new(&flat, &cfg).map(|g| g.stats().cells()).unwrap_or(0) > 0);
    // Empty map: no candidates, no NBV, utility 0.
    let empty = ObjectMap::new();
    let ec = ExploreConfig::default();
    assert!(sample_candidates(&empty, &CandidateConfig::default(), &cfg, &AlwaysReachable, 1)
        .unwrap_or_default()
        .is_empty());
    assert_eq!(next_best_view(&[]), None);
    let ctx = UtilityContext::new(&empty, &ExplorationGrids::new(), &HistoryBook::default(), &camera(), &ec).unwrap();
    assert_eq!(ctx.score(&pose, Strategy::ObjectDriven, None).map(|s| s.utility), Ok(0.0));
    assert!(ctx.score(&bad_pose, Strategy::ObjectDriven, None).is_err());
    assert_eq!(Strategy::parse("expected-gain"), Ok(Strategy::ExpectedGain));
    assert!(Strategy::parse("greedy").is_err());
}

#[test]
fn expected_entropy_reduction_is_largest_for_unknown_cells() {
    let cfg = ExploreConfig::default();
    let g0 = expected_entropy_reduction(0.0, &cfg);
    assert!(g0 > 0.1 && g0 < 1.0, "{g0}");
    let lmax = log_odds(cfg.grid.p_max);
    let gsat = expected_entropy_reduction(lmax, &cfg);
    assert!(gsat < g0 * 0.5, "{gsat} vs {g0}");
    assert!(gsat >= 0.0);
}

#[test]
fn utility_matches_closed_form_for_one_unknown_cube() {
    // A 10 cm cube, all 500 cells unknown (1 bit each), no history (H_V = 0), alone (R_IoU = 0).
    let cfg = ExploreConfig::default();
    let center = [0.5, 0.0, 0.05];
    let map = map_of(vec![object(Label::Block, center, 0.0, [0.05, 0.05, 0.05])]);
    let mut grids = ExplorationGrids::new();
    grids.sync(&map, &cfg.grid).unwrap();
    let ctx = UtilityContext::new(&map, &grids, &HistoryBook::default(), &camera(), &cfg).unwrap();
    // Level with the centre, facing +x: only the +x face (100 cells) faces the camera within 80°.
    let level =
        ctx.score(&view(eye_around(center, 0.0, 0.0, 0.5), center), Strategy::ObjectDrivenDiscovery, None).unwrap();
    assert!((level.utility - 100.0).abs() < 1e-9, "{level:?}");
    assert_eq!(level.objects[0].visible_cells, 100);
    // 45° above +x: the +x face and the top (incidence 45°) are seen: 200 bits.
    let high =
        ctx.score(&view(eye_around(center, 0.0, 45.0, 0.5), center), Strategy::ObjectDrivenDiscovery, None).unwrap();
    assert!((high.utility - 200.0).abs() < 1e-9, "{high:?}");
    // Whole-object scope: H_obj = 500 bits from any view that sees the object.
    let whole = ExploreConfig { entropy_scope: EntropyScope::Object, ..ExploreConfig::default() };
    let ctx2 = UtilityContext::new(&map, &grids, &HistoryBook::default(), &camera(), &whole).unwrap();
    let s2 =
        ctx2.score(&view(eye_around(center, 0.0, 0.0, 0.5), center), Strategy::ObjectDrivenDiscovery, None).unwrap();
    assert!((s2.utility - 500.0).abs() < 1e-9);
    // The paper's object-driven uses the whole-object scope whatever the configured one.
    let paper = ctx.score(&view(eye_around(center, 0.0, 0.0, 0.5), center), Strategy::ObjectDriven, None).unwrap();
    assert!((paper.utility - 500.0).abs() < 1e-9, "{paper:?}");
    // Looking away: the object is not in the view, f = 0.
    let away = look_at(&eye_around(center, 0.0, 0.0, 0.5), &Point3::new(2.0, 0.0, 0.05)).unwrap();
    let s3 = ctx.score(&away, Strategy::ObjectDrivenDiscovery, None).unwrap();
    assert_eq!(s3.utility, 0.0);
    assert!(s3.objects.is_empty());
}

fn table() -> TableRect {
    TableRect { center_m: [0.5, 0.0], size_m: [0.8, 1.2], height_m: 0.0 }
}

fn on(disc: DiscoveryConfig) -> DiscoveryConfig {
    DiscoveryConfig { weight: 1.0, ..disc }
}

#[test]
fn a_top_down_view_sees_its_footprint_of_the_table() {
    // Camera 0.5 m straight above the table centre; flat table: z-depth 0.5 everywhere.
    let cam = camera();
    let h = 0.5;
    let pose = view(Point3::new(0.5, 0.0, h), [0.5, 0.0, 0.0]);
    let depth = DepthImage::new(640, 480, vec![h as f32; 640 * 480]).unwrap();
    // One frame marks a cell and the whole image counts (the closed form below); the default
    // rules (3 frames, 10 % border) are checked at the end.
    let cfg = on(DiscoveryConfig { min_frames: 1, margin_frac: 0.0, ..paper_discovery() });
    let mut cov = TableCoverage::new(&table(), &cfg).unwrap();
    assert_eq!(cov.len(), 40 * 60);
    let newly = cov.integrate_depth(&cam, &pose, &depth, &cfg).unwrap();
    // Footprint (closed form): an axis-aligned 2·h·(W/2)/f × 2·h·(H/2)/f rectangle, i.e. a × b
    // cells; it covers at least (a − 1)(b − 1) whole cells and touches at most (a + 2)(b + 2)
    // (samples every 4 px ≈ 4.6 mm reach nearly every touched cell).
    let a = 2.0 * h * cam.cx / cam.fx / cfg.cell_m;
    let b = 2.0 * h * cam.cy / cam.fy / cfg.cell_m;
    let seen = cov.seen_cells() as f64;
    assert_eq!(newly, cov.seen_cells());
    assert!(seen >= (a - 1.0) * (b - 1.0) && seen <= (a + 2.0) * (b + 2.0), "seen {seen}, a × b = {a} × {b}");
    let empty = Occluders::from_map(&ObjectMap::new(), &GridConfig::default());
    assert!((cov.known_fraction(&empty) - seen / 2400.0).abs() < 1e-12);
    // The same frame again changes nothing; returns below the table top mark nothing.
    assert_eq!(cov.integrate_depth(&cam, &pose, &depth, &cfg).unwrap(), 0);
    let below = DepthImage::new(640, 480, vec![0.6; 640 * 480]).unwrap();
    let mut cov2 = TableCoverage::new(&table(), &cfg).unwrap();
    assert_eq!(cov2.integrate_depth(&cam, &pose, &below, &cfg).unwrap(), 0);
    // Wrong depth size: a typed error.
    let small = DepthImage::new(64, 48, vec![0.5; 64 * 48]).unwrap();
    assert!(matches!(cov2.integrate_depth(&cam, &pose, &small, &cfg), Err(ExploreError::Degenerate { .. })));
    // Defaults: nothing is seen after two frames, the inner 80 % × 80 % footprint after three.
    let strict = on(paper_discovery());
    let mut cov3 = TableCoverage::new(&table(), &strict).unwrap();
    for k in 0..3 {
        let n = cov3.integrate_depth(&cam, &pose, &depth, &strict).unwrap();
        assert_eq!(n == 0, k < 2, "frame {k}: {n} newly seen");
    }
    let (a3, b3) = (a * (1.0 - 2.0 * strict.margin_frac), b * (1.0 - 2.0 * strict.margin_frac));
    let seen3 = cov3.seen_cells() as f64;
    assert!(seen3 >= (a3 - 1.0) * (b3 - 1.0) && seen3 <= (a3 + 2.0) * (b3 + 2.0), "seen {seen3}, {a3} × {b3}");
    // A bad rule is a typed error naming the field.
    let bad = DiscoveryConfig { min_frames: 0, ..paper_discovery() };
    assert!(matches!(
        TableCoverage::new(&table(), &bad),
        Err(ExploreError::InvalidConfig { field: "discovery.min_frames", .. })
    ));
}

#[test]
fn unseen_cells_are_counted_where_the_camera_looks_and_not_behind_objects() {
    let cam = camera();
    let cfg = on(DiscoveryConfig { min_frames: 1, margin_frac: 0.0, ..paper_discovery() });
    let grid = GridConfig::default();
    let mut cov = TableCoverage::new(&table(), &cfg).unwrap();
    // See the y < 0 half from above (depth 0.5 over the view's footprint).
    let seen_pose = view(Point3::new(0.5, -0.3, 0.5), [0.5, -0.3, 0.0]);
    let depth = DepthImage::new(640, 480, vec![0.5; 640 * 480]).unwrap();
    cov.integrate_depth(&cam, &seen_pose, &depth, &cfg).unwrap();
    let empty_map = ObjectMap::new();
    let empty = Occluders::from_map(&empty_map, &grid);
    let unknown = cov.unknown_cells(&empty);
    let towards_seen = visible_unknown_cells(&unknown, &cam, &seen_pose, &empty, &grid, &cfg);
    let unseen_pose = view(Point3::new(0.5, 0.3, 0.5), [0.5, 0.3, 0.0]);
    let towards_unseen = visible_unknown_cells(&unknown, &cam, &unseen_pose, &empty, &grid, &cfg);
    assert_eq!(towards_seen, 0);
    assert!(towards_unseen > 500, "{towards_unseen}");
    // A tall block in the unseen half: its footprint counts as known, and from a low oblique
    // camera the cells behind it are hidden.
    let map = map_of(vec![object(Label::Block, [0.5, 0.3, 0.15], 0.0, [0.06, 0.06, 0.15])]);
    let occ = Occluders::from_map(&map, &grid);
    let unknown_obj = cov.unknown_cells(&occ);
    let footprint = unknown.len() - unknown_obj.len();
    assert!((36..=64).contains(&footprint), "{footprint}"); // (12 + 2·1 cm margin)² / 4 cm² = 49
    let low = view(Point3::new(0.5, -0.1, 0.25), [0.5, 0.45, 0.0]);
    let without = visible_unknown_cells(&unknown_obj, &cam, &low, &empty, &grid, &cfg);
    let with = visible_unknown_cells(&unknown_obj, &cam, &low, &occ, &grid, &cfg);
    assert!(with + 20 < without, "with {with}, without {without}");
    assert!((cov.known_fraction(&occ) - (1.0 - unknown_obj.len() as f64 / 2400.0)).abs() < 1e-12);
}

#[test]
fn discovery_targets_spread_over_the_unseen_cells() {
    let mut pts: Vec<Point3<f64>> = (0..10).map(|i| Point3::new(0.2 + 0.01 * f64::from(i), -0.4, 0.0)).collect();
    pts.extend((0..10).map(|i| Point3::new(0.2 + 0.01 * f64::from(i), 0.4, 0.0)));
    let t = discovery_targets(&pts, 2, 7);
    assert_eq!(t.len(), 2);
    assert!(t[0].y * t[1].y < 0.0, "one target per cluster: {t:?}");
    assert_eq!(t, discovery_targets(&pts, 2, 7));
    assert!(discovery_targets(&[], 3, 0).is_empty());
    assert_eq!(discovery_targets(&pts[..1], 3, 0).len(), 1);
}

#[test]
fn discovery_keeps_an_empty_map_looking_at_the_table() {
    // Nothing mapped and nothing seen (Init saw no object): the paper's utility has no candidate,
    // the discovery term aims at the unseen table.
    use crate::active::{ActiveConfig, ActiveSession, NextView, SessionStop};
    let cam = camera();
    let here = view(Point3::new(0.3, 0.0, 0.5), [0.5, 0.0, 0.0]);
    let map = ObjectMap::new();
    let paper = paper_active();
    let mut s = ActiveSession::new(paper.clone(), table()).unwrap();
    let d = s.next_view(&map, &cam, &here, &AlwaysReachable).unwrap();
    assert_eq!(d, NextView::Stop { reason: SessionStop::NoReachableView });
    let before_stop_only = ActiveConfig { discovery_before_stop: true, ..paper.clone() };
    let mut s = ActiveSession::new(before_stop_only, table()).unwrap();
    let d = s.next_view(&map, &cam, &here, &AlwaysReachable).unwrap();
    assert_eq!(d, NextView::Stop { reason: SessionStop::NoReachableView }, "an empty map is not 'all explored'");
    let disc = ActiveConfig { discovery_weight: 1.0, ..paper };
    let mut s = ActiveSession::new(disc, table()).unwrap();
    let d = s.next_view(&map, &cam, &here, &AlwaysReachable).unwrap();
    let NextView::Move { world_from_camera, utility, .. } = d else { panic!("expected a move, got {d:?}") };
    assert!(utility >= 4.0 * 25.0, "at least min_new_cells × 4 bits: {utility}");
    // It looks down at the table top.
    let axis = world_from_camera.rotation * Vector3::z();
    assert!(axis.z < -0.5, "{axis:?}");
}

/// Depth (z) and the points on object `id` seen by `cam` at `pose`, ray cast against `map`.
fn render(map: &ObjectMap, cam: &PinholeCamera, pose: &Se3, id: u32) -> (DepthImage, Vec<Point3<f64>>) {
    let occ = Occluders::from_map(map, &GridConfig::default());
    let eye = Point3::from(pose.translation.vector);
    let mut depth = vec![0.0f32; (cam.width * cam.height) as usize];
    let mut points = Vec::new();
    for v in 0..cam.height {
        for u in 0..cam.width {
            let dir = pose.rotation * cam.unproject_pixel(u, v, 1.0).coords;
            if let Some((hit, t)) = occ.cast_ray(&eye, &dir, 5.0) {
                depth[(v * cam.width + u) as usize] = t as f32;
                if hit == Some(id) {
                    points.push(eye + dir * t);
                }
            }
        }
    }
    (DepthImage::new(cam.width, cam.height, depth).unwrap(), points)
}

#[test]
fn before_stop_looks_at_the_unseen_table_when_every_object_is_done() {
    use crate::active::{ActiveConfig, ActiveSession, NextView, SessionStop};
    use crate::frame::Frame;
    let map = map_of(vec![object(Label::Block, [0.5, 0.0, 0.05], 0.0, [0.05, 0.05, 0.05])]);
    let cam = PinholeCamera::from_fovy(96, 72, 0.8).unwrap();
    let c = [0.5, 0.0, 0.05];
    let mut poses = vec![view(Point3::new(0.5, 0.0, 0.45), c)];
    poses.extend([0.0, 90.0, 180.0, 270.0].map(|az| view(eye_around(c, az, 35.0, 0.4), c)));
    let run = |config: ActiveConfig| {
        let mut s = ActiveSession::new(config, table()).unwrap();
        for (i, pose) in poses.iter().enumerate() {
            let (depth, points) = render(&map, &cam, pose, 0);
            let frame = Frame { index: i as u32, camera: cam, depth, world_from_camera: *pose, detections: Vec::new() };
            let observed = [ObservedPoints { object_id: 0, points_in_world: points }];
            s.integrate_frame(&map, &frame, &observed).unwrap();
            s.view_done(&map, false);
        }
        let known = *s.table_known_curve().last().unwrap_or(&1.0);
        let d = s.next_view(&map, &cam, &poses[0], &AlwaysReachable).unwrap();
        (d, known, s.table_known_curve().len())
    };
    let (paper, known, n) = run(paper_active());
    assert_eq!(paper, NextView::Stop { reason: SessionStop::AllExplored }, "the block is done");
    assert_eq!(n, poses.len());
    assert!(known > 0.05 && known < 0.6, "the small camera saw part of the table: {known}");
    let (disc, _, _) = run(ActiveConfig { discovery_before_stop: true, ..paper_active() });
    let NextView::Move { world_from_camera, utility, candidates } = disc else { panic!("expected a move: {disc:?}") };
    assert!(utility >= 4.0 * 25.0, "{utility}");
    assert!(candidates.iter().all(|c| c.utility.is_finite()));
    // It looks at the table away from the block's neighbourhood it has seen.
    let axis = world_from_camera.rotation * Vector3::z();
    assert!(axis.z < -0.3, "{axis:?}");
}

#[test]
fn greedy_discovery_views_cover_the_most_new_cells_first() {
    let set = |r: std::ops::Range<usize>| r.collect::<Vec<usize>>();
    let views = vec![set(0..30), set(0..30), set(30..40), set(40..80), set(75..82)];
    // 40 new, then 30, then 10; the copy of the second adds 0 and the last 2 (< 5).
    assert_eq!(greedy_discovery_views(&views, 82, 5, 10, |_| true), vec![3, 0, 2]);
    assert_eq!(greedy_discovery_views(&views, 82, 5, 2, |_| true), vec![3, 0], "limit");
    assert_eq!(greedy_discovery_views(&views, 82, 20, 10, |_| true), vec![3, 0], "min_new");
    // An unreachable view is dropped and the next best taken; ties go to the lower index.
    assert_eq!(greedy_discovery_views(&views, 82, 5, 10, |i| i != 3), vec![0, 2, 4]);
    assert_eq!(greedy_discovery_views(&views, 82, 5, 10, |i| i != 0), vec![3, 1, 2]);
    assert!(greedy_discovery_views(&[], 82, 5, 10, |_| true).is_empty());
    // Indices outside the cell count are ignored rather than panicking.
    assert_eq!(greedy_discovery_views(&[vec![500, 501]], 82, 1, 10, |_| true), Vec::<usize>::new());
}

#[test]
fn the_budget_reserve_takes_the_last_view_for_the_unseen_table() {
    use crate::active::{ActiveConfig, ActiveSession, NextView};
    use crate::frame::Frame;
    // One block seen from above only (its sides unknown: not done), most of the table unseen.
    let map = map_of(vec![object(Label::Block, [0.5, 0.0, 0.05], 0.0, [0.05, 0.05, 0.05])]);
    let cam = PinholeCamera::from_fovy(96, 72, 0.8).unwrap();
    let top = view(Point3::new(0.5, 0.0, 0.45), [0.5, 0.0, 0.05]);
    let grid = GridConfig::default();
    let decide = |config: ActiveConfig, views_taken: usize| {
        let mut s = ActiveSession::new(config, table()).unwrap();
        let (depth, points) = render(&map, &cam, &top, 0);
        let frame = Frame { index: 0, camera: cam, depth, world_from_camera: top, detections: Vec::new() };
        let observed = [ObservedPoints { object_id: 0, points_in_world: points }];
        s.integrate_frame(&map, &frame, &observed).unwrap();
        s.view_done(&map, false);
        for _ in 0..views_taken {
            s.view_done(&map, true);
        }
        let unknown = s.table_unknown_cells(&map);
        let d = s.next_view(&map, &cam, &top, &AlwaysReachable).unwrap();
        let NextView::Move { world_from_camera, .. } = d else { panic!("expected a move: {d:?}") };
        let occ = Occluders::from_map(&map, &grid);
        (world_from_camera, visible_unknown_cells(&unknown, &cam, &world_from_camera, &occ, &grid, &paper_discovery()))
    };
    let reserve = ActiveConfig { discovery_reserve: true, ..paper_active() };
    // Plenty of budget left: the object NBV, exactly the paper's choice.
    let (paper_pose, _) = decide(paper_active(), 0);
    let (early_pose, _) = decide(reserve.clone(), 0);
    assert_eq!(paper_pose, early_pose, "objects first");
    // One view left, and the unseen table needs at least one: a discovery view.
    let (paper_last, _) = decide(paper_active(), 9);
    let (reserve_last, new_cells) = decide(reserve, 9);
    assert_ne!(paper_last, reserve_last);
    assert!(new_cells >= 25, "the reserve view sees {new_cells} unseen cells");
    let axis = reserve_last.rotation * Vector3::z();
    assert!(axis.z < -0.3, "it looks down at the table: {axis:?}");
}

#[test]
fn truncated_detections_do_not_mark_table_cells() {
    // Camera 0.5 m straight above the table: a 160 × 160 px box at the left edge covers
    // 160 · h / f metres square of table (closed form), which stays unseen; an interior box
    // and the same box with the option off change nothing.
    let cam = camera();
    let h = 0.5;
    let pose = view(Point3::new(0.5, 0.0, h), [0.5, 0.0, 0.0]);
    let depth = DepthImage::new(640, 480, vec![h as f32; 640 * 480]).unwrap();
    let edge = Box2::new(0.0, 160.0, 160.0, 320.0);
    let inner = Box2::new(240.0, 160.0, 400.0, 320.0);
    assert_eq!(truncated_boxes([edge, inner], 640, 480, 2.0), vec![edge]);
    assert!(truncated_boxes([edge, inner], 640, 480, 0.0).is_empty());
    let cfg = on(DiscoveryConfig { min_frames: 1, margin_frac: 0.0, ..paper_discovery() });
    let seen_with = |excluded: &[Box2]| {
        let mut cov = TableCoverage::new(&table(), &cfg).unwrap();
        cov.integrate_depth_excluding(&cam, &pose, &depth, excluded, &cfg).unwrap();
        cov.seen_cells() as f64
    };
    let all = seen_with(&[]);
    let side = 160.0 * h / cam.fx / cfg.cell_m; // the box's footprint, cells per side
    let lost = all - seen_with(&truncated_boxes([edge], 640, 480, 2.0));
    // Cells wholly inside the footprint are lost; cells it only touches may keep other returns.
    assert!(lost >= (side - 2.0).powi(2) && lost <= (side + 1.0).powi(2), "lost {lost}, side {side}");
    assert_eq!(seen_with(&truncated_boxes([inner], 640, 480, 2.0)), all);
    // A bad margin is a typed error naming the field.
    let bad = DiscoveryConfig { exclude_truncated_px: -1.0, ..paper_discovery() };
    assert!(matches!(
        TableCoverage::new(&table(), &bad),
        Err(ExploreError::InvalidConfig { field: "discovery.exclude_truncated_px", .. })
    ));
}

/// A 640 × 480 depth image of a flat table at `h` with an object top at depth `top` in image
/// columns `cols`, rows 200..280.
fn flat_with_top(h: f64, cols: std::ops::Range<usize>, top: f32) -> DepthImage {
    let mut z = vec![h as f32; 640 * 480];
    for v in 200..280 {
        for u in cols.clone() {
            z[v * 640 + u] = top;
        }
    }
    DepthImage::new(640, 480, z).unwrap()
}

#[test]
fn object_evidence_keeps_its_cells_unknown_until_a_mapped_object_explains_them() {
    // Camera 0.5 m above a flat table; an 80 × 80 px patch of the image sees a 5 cm high top
    // (depth 0.45): its footprint is 80 · 0.45 / f metres square (closed form).
    let cam = camera();
    let h = 0.5;
    let pose = view(Point3::new(0.5, 0.0, h), [0.5, 0.0, 0.0]);
    let depth = flat_with_top(h, 280..360, 0.45);
    let base = on(DiscoveryConfig { min_frames: 1, margin_frac: 0.0, ..paper_discovery() });
    let evidence = DiscoveryConfig { evidence_height_m: 0.02, ..base.clone() };
    let empty = Occluders::from_map(&ObjectMap::new(), &GridConfig::default());
    let cells_with = |cfg: &DiscoveryConfig, occ: &Occluders| {
        let mut cov = TableCoverage::new(&table(), cfg).unwrap();
        cov.integrate_depth(&cam, &pose, &depth, cfg).unwrap();
        let all_unknown = cov.unknown_cells(&empty).len();
        let (unknown, unexplained) = cov.unknown_cells_with_evidence(occ);
        (all_unknown, unknown.len(), unexplained.iter().filter(|u| **u).count())
    };
    let (off_unknown, _, off_unexplained) = cells_with(&base, &empty);
    let (on_unknown, _, on_unexplained) = cells_with(&evidence, &empty);
    let side = 80.0 * 0.45 / cam.fx / base.cell_m; // the top's footprint, cells per side
    let lost = (on_unknown - off_unknown) as f64;
    // Every cell the top touches is unexplained (its outline cells get table returns too).
    assert!(lost >= side.ceil().powi(2) && lost <= (side.ceil() + 1.0).powi(2), "lost {lost}, side {side}");
    assert_eq!(off_unexplained, 0, "off: no evidence is kept");
    assert_eq!(on_unexplained as f64, lost, "with nothing mapped, every such cell is unexplained");
    // A mapped object on the patch explains it (and its footprint makes the cells known) ...
    let c = pose * cam.unproject(320.0, 240.0, 0.45);
    let there = map_of(vec![object(Label::Block, [c.x, c.y, 0.025], 0.0, [0.04, 0.04, 0.025])]);
    let occ_there = Occluders::from_map(&there, &GridConfig::default());
    let (_, known_there, unexplained_there) = cells_with(&evidence, &occ_there);
    assert_eq!(unexplained_there, 0);
    assert!(known_there < off_unknown + 1, "the object's footprint is known: {known_there}");
    // ... one 15 cm away does not.
    let away = map_of(vec![object(Label::Block, [c.x + 0.15, c.y, 0.025], 0.0, [0.02, 0.02, 0.025])]);
    let occ_away = Occluders::from_map(&away, &GridConfig::default());
    assert_eq!(cells_with(&evidence, &occ_away).2, on_unexplained);
    // Evidence counts from the image border too (where table sightings do not): a top seen in
    // the left 48 px of a 10 % (64 px) border.
    let border = flat_with_top(h, 0..48, 0.45);
    let strict = DiscoveryConfig { margin_frac: 0.1, ..evidence.clone() };
    let mut cov = TableCoverage::new(&table(), &strict).unwrap();
    cov.integrate_depth(&cam, &pose, &border, &strict).unwrap();
    let n = cov.unknown_cells_with_evidence(&empty).1.iter().filter(|u| **u).count() as f64;
    let (a, b) = (48.0 * 0.45 / cam.fx / base.cell_m, 80.0 * 0.45 / cam.fy / base.cell_m);
    assert!(n >= a.floor() * b.floor() && n <= (a.ceil() + 1.0) * (b.ceil() + 1.0), "{n} cells, {a} × {b}");
    // A height above max_height_m is a typed error naming the field.
    let bad = DiscoveryConfig { evidence_height_m: 0.5, ..paper_discovery() };
    assert!(matches!(
        TableCoverage::new(&table(), &bad),
        Err(ExploreError::InvalidConfig { field: "discovery.evidence_height_m", .. })
    ));
}

#[test]
fn unexplained_evidence_draws_a_view_centred_on_the_unmapped_object() {
    use crate::active::{ActiveConfig, ActiveSession, NextView, SessionStop};
    use crate::frame::Frame;
    // The world holds blocks A and B; the map only A, explored from around. The whole table is
    // seen from above, B's top included, so the paper's rule (and discovery without evidence)
    // stops "all explored" with B missing; with object evidence B's cells are unexplained.
    let a = [0.6, -0.25, 0.025];
    let b = [0.3, 0.35, 0.025];
    let world = map_of(vec![
        object(Label::Block, a, 0.0, [0.025, 0.025, 0.025]),
        object(Label::Block, b, 0.3, [0.025, 0.025, 0.025]),
    ]);
    let map = map_of(vec![object(Label::Block, a, 0.0, [0.025, 0.025, 0.025])]);
    let cam = PinholeCamera::from_fovy(320, 240, 1.0).unwrap();
    let mut poses: Vec<Se3> = [0.25, 0.5, 0.75]
        .iter()
        .flat_map(|x| [-0.45, -0.15, 0.15, 0.45].map(|y| view(Point3::new(*x, y, 0.5), [*x, y, 0.0])))
        .collect();
    poses.extend([0.0, 90.0, 180.0, 270.0].map(|az| view(eye_around(a, az, 35.0, 0.35), a)));
    let frames: Vec<(Frame, Vec<Point3<f64>>)> = poses
        .iter()
        .enumerate()
        .map(|(i, pose)| {
            let (depth, points) = render(&world, &cam, pose, 0);
            (Frame { index: i as u32, camera: cam, depth, world_from_camera: *pose, detections: Vec::new() }, points)
        })
        .collect();
    let occ = Occluders::from_map(&map, &GridConfig::default());
    let run = |config: ActiveConfig| {
        let mut s = ActiveSession::new(config, table()).unwrap();
        for (frame, points) in &frames {
            let observed = [ObservedPoints { object_id: 0, points_in_world: points.clone() }];
            for _ in 0..3 {
                s.integrate_frame(&map, frame, &observed).unwrap();
            }
            s.view_done(&map, false);
        }
        let (_, unexplained) = s.table_coverage().unknown_cells_with_evidence(&occ);
        let n = unexplained.iter().filter(|u| **u).count();
        // The session's per-view curve holds the same count after the last view.
        assert_eq!(s.table_unexplained_curve().len(), frames.len());
        assert_eq!(s.table_unexplained_curve().last(), Some(&n));
        let before = s.clone();
        (s.next_view(&map, &cam, &poses[0], &AlwaysReachable).unwrap(), n, before)
    };
    let before_stop = ActiveConfig { discovery_before_stop: true, discovery_reserve: true, ..paper_active() };
    let all_explored = NextView::Stop { reason: SessionStop::AllExplored };
    let (d, n, _) = run(before_stop.clone());
    assert_eq!((d, n), (all_explored.clone(), 0), "without evidence B's cells count as seen");
    let evidence = ActiveConfig { discovery_evidence_height_m: 0.02, ..before_stop };
    let (d, n, step) = run(evidence.clone());
    // B (5 cm square, turned 0.3 rad) overlaps 9-16 cells of 2 cm.
    assert!((9..=16).contains(&n), "{n} unexplained cells");
    let NextView::Move { world_from_camera, .. } = d else { panic!("expected a move: {d:?}") };
    // B is in the inner image of the chosen view, A's cells explained by the map.
    let uv = cam.project(&(world_from_camera.inverse() * Point3::from(Vector3::from(b)))).expect("B behind the camera");
    assert!(uv[0] > 32.0 && uv[0] < 288.0 && uv[1] > 24.0 && uv[1] < 216.0, "B at {uv:?}");
    // The same step as a strategy outside the core sees it: the paper's rule says "all
    // explored", the weighted unseen table is worth a view, and the argmax of the discovery gain
    // over the table candidates revealing min_new_cells is the built-in choice, gain and pose.
    let NextView::Move { utility, .. } = d else { unreachable!() };
    let min_new = evidence.discovery_min_new_cells as f64;
    assert_eq!(step.paper_stop(&map, &cam).unwrap(), Some(SessionStop::AllExplored));
    let weight = step.table_unknown_weight(&map);
    assert!(weight >= min_new && weight >= evidence.discovery_evidence_weight * n as f64, "{weight}");
    let views: Vec<Se3> = step.table_candidate_views(&map).unwrap().iter().map(|c| c.world_from_camera).collect();
    let gains = step.table_gain(&map, &cam, &views);
    let best = (0..views.len())
        .filter(|i| gains[*i].cells >= min_new)
        .max_by(|a, b| gains[*a].bits.total_cmp(&gains[*b].bits).then(b.cmp(a)))
        .unwrap_or_else(|| panic!("no table view reveals {min_new} cells"));
    assert_eq!(views[best], world_from_camera);
    assert_eq!(gains[best].bits, utility);
    assert!(gains[best].unexplained);
    assert!(step.table_views_needed(&map, &cam, &AlwaysReachable, 10).unwrap() >= 1);
    // Views chosen outside the core count towards evidence_max_views like the built-in ones:
    // once spent, the unexplained cells weigh 1.
    let mut outside = step.clone();
    for _ in 0..evidence.discovery_evidence_max_views {
        assert!(outside.table_unknown_weight(&map) > weight - 1e-9);
        outside.note_chosen_view(&map, &cam, &world_from_camera);
    }
    let plain = outside.table_unknown_weight(&map);
    assert!((weight - plain - (evidence.discovery_evidence_weight - 1.0) * n as f64).abs() < 1e-9, "{weight} {plain}");
    // With no views left for evidence it counts as plain unseen cells: fewer than
    // min_new_cells, so the session stops.
    assert_eq!(run(ActiveConfig { discovery_evidence_max_views: 0, ..evidence }).0, all_explored);
    assert!(plain < min_new, "{plain}");
}

#[test]
fn the_decision_step_view_reproduces_the_built_in_utility_strategies() {
    // A strategy outside the core (Python) sees the step through `object_features`,
    // `candidate_views` and `score_views`; the argmax of the paper's utility over the candidates
    // around the objects still to explore is the built-in object-driven decision (discovery off),
    // and likewise for expected-gain, here with the reachability filter dropping the best view.
    use crate::active::{ActiveConfig, ActiveSession, NextView, SessionStop};
    use crate::frame::Frame;
    let map = map_of(vec![
        object(Label::Block, [0.45, 0.1, 0.04], 0.3, [0.04, 0.03, 0.04]),
        object(Label::Can, [0.6, -0.1, 0.06], 0.0, [0.033, 0.033, 0.06]),
    ]);
    let cam = PinholeCamera::from_fovy(96, 72, 0.8).unwrap();
    let top = view(Point3::new(0.5, 0.0, 0.5), [0.5, 0.0, 0.04]);
    for strategy in [Strategy::ObjectDriven, Strategy::ExpectedGain] {
        let config = ActiveConfig { strategy, seed: 7, ..paper_active() };
        let mut s = ActiveSession::new(config, table()).unwrap();
        for id in 0..2 {
            let (depth, points) = render(&map, &cam, &top, id);
            let frame = Frame { index: id, camera: cam, depth, world_from_camera: top, detections: Vec::new() };
            let observed = [ObservedPoints { object_id: id, points_in_world: points }];
            s.integrate_frame(&map, &frame, &observed).unwrap();
        }
        s.view_done(&map, false);
        let features = s.object_features(&map, &cam).unwrap();
        assert_eq!(features.len(), 2);
        assert!(features.iter().all(|f| f.explore), "sides unseen: both still to explore");
        assert_eq!(s.paper_stop(&map, &cam).unwrap(), None);
        let around: Vec<u32> = features.iter().filter(|f| f.explore).map(|f| f.object_id).collect();
        let views: Vec<Se3> =
            s.candidate_views(&map, Some(&around)).unwrap().iter().map(|c| c.world_from_camera).collect();
        assert!(views.len() >= 8, "{}", views.len());
        let scores = s.score_views(&map, &cam, &views, strategy, &top, false).unwrap();
        let mut order: Vec<usize> = (0..views.len()).filter(|i| scores[*i].utility.is_finite()).collect();
        order.sort_by(|a, b| scores[*b].utility.total_cmp(&scores[*a].utility).then(a.cmp(b)));
        // The best view is unreachable: the second is taken, by both.
        let banned = views[order[0]];
        let reachable = |p: &Se3| (p.translation.vector - banned.translation.vector).norm() > 1e-9;
        let d = s.next_view(&map, &cam, &top, &reachable).unwrap();
        let NextView::Move { world_from_camera, utility, .. } = d else { panic!("expected a move: {d:?}") };
        assert_eq!(world_from_camera, views[order[1]], "{strategy:?}");
        assert_eq!(utility, scores[order[1]].utility, "{strategy:?}");
        assert!(scores[order[0]].utility > 0.0);
        // The budget: after max_views views the paper's rule stops.
        for _ in 0..s.max_views() {
            s.view_done(&map, true);
        }
        assert_eq!(s.paper_stop(&map, &cam).unwrap(), Some(SessionStop::MaxViews));
    }
}

/// The paper's session: no table discovery (before stop, budget reserve, object evidence).
/// object-driven-discovery (whose discovery settings apply) with before-stop, the reserve and object
/// evidence off: the paper's stopping rule.
fn paper_active() -> crate::active::ActiveConfig {
    crate::active::ActiveConfig {
        strategy: Strategy::ObjectDrivenDiscovery,
        discovery_before_stop: false,
        discovery_reserve: false,
        discovery_evidence_height_m: 0.0,
        ..crate::active::ActiveConfig::default()
    }
}

/// Table discovery settings with before-stop, the reserve and object evidence off.
fn paper_discovery() -> DiscoveryConfig {
    DiscoveryConfig { before_stop: false, reserve: false, evidence_height_m: 0.0, ..DiscoveryConfig::default() }
}

#[test]
fn closed_form_segment_tests_agree_with_parry() {
    use parry3d_f64::math::Vector as PVec;
    use parry3d_f64::query::{Ray, RayCast};
    use parry3d_f64::shape::{Cuboid, Cylinder};
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
    let (half, r, hh) = (Vector3::new(0.05, 0.03, 0.08), 0.04, 0.06);
    let cuboid = Cuboid::new(PVec::new(half.x, half.y, half.z));
    let cylinder = Cylinder::new(hh, r);
    let (mut disagree, mut hits) = (0usize, 0usize);
    let n = 20_000;
    for _ in 0..n {
        let mut p =
            || Vector3::new(rng.random_range(-0.2..0.2), rng.random_range(-0.2..0.2), rng.random_range(-0.2..0.2));
        let (o, e) = (p(), p());
        let len = (e - o).norm();
        let d = (e - o) / len;
        let box_ours = super::visibility::segment_hits_box(&o, &d, &half, len);
        let box_parry = cuboid.intersects_local_ray(&Ray::new(PVec::new(o.x, o.y, o.z), PVec::new(d.x, d.y, d.z)), len);
        // parry's cylinder axis is its local y: object (x, y, z) → (x, z, −y).
        let cyl_ours = super::visibility::segment_hits_cylinder(&o, &d, r, hh, len);
        let cyl_parry =
            cylinder.intersects_local_ray(&Ray::new(PVec::new(o.x, o.z, -o.y), PVec::new(d.x, d.z, -d.y)), len);
        disagree += usize::from(box_ours != box_parry) + usize::from(cyl_ours != cyl_parry);
        hits += usize::from(box_ours) + usize::from(cyl_ours);
    }
    // Both shapes are hit by a good share of the segments; the answers agree except for at most a
    // few grazing segments where parry's GJK tolerance decides.
    assert!(hits > n / 4, "hits {hits}");
    assert!(disagree <= 4, "disagree on {disagree} of {}", 2 * n);
}

/// The explore bench's scene (core/benches/explore.rs: twelve objects, init-view grids, 100
/// candidates), with the utilities and discovery counts the parry-based visibility gave: the
/// closed-form segment tests and the occluder prefilter leave every score unchanged.
#[test]
fn bench_scene_scores_match_the_parry_reference() {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(12);
    let mut map = ObjectMap::new();
    for i in 0..12 {
        let label = Label::ALL[i % Label::ALL.len()];
        let (gx, gy) = ((i % 3) as f64, (i / 3) as f64);
        let half = match label {
            Label::Keyboard => Vector3::new(0.12, 0.05, 0.015),
            Label::Book => Vector3::new(0.08, 0.06, 0.02),
            Label::Bowl => Vector3::new(0.06, 0.06, 0.03),
            Label::Bottle => Vector3::new(0.035, 0.035, 0.1),
            _ => Vector3::new(0.03 + 0.02 * rng.random::<f64>(), 0.03 + 0.02 * rng.random::<f64>(), 0.04),
        };
        let c = Vector3::new(
            0.3 + 0.2 * gx + rng.random_range(-0.02..0.02),
            -0.35 + 0.233 * gy + rng.random_range(-0.02..0.02),
            half.z,
        );
        map.insert(MapObject {
            id: 0,
            label,
            world_from_object: se3_from_yaw(c, rng.random_range(-1.5..1.5)),
            half_extents: half,
            observations: Vec::new(),
            points_in_world: Vec::new(),
            stage: EstimateStage::Raw,
        });
    }
    let camera = camera();
    // The defaults the reference values were computed with (the paper's Init and candidates,
    // discovery without before-stop, reserve and object evidence).
    let cfg = ExploreConfig { discovery: paper_discovery(), ..ExploreConfig::default() };
    let cc = CandidateConfig {
        elevation_deg: [25.0, 75.0],
        init_height_m: 0.45,
        init_inset_m: 0.15,
        init_tilt_deg: 0.0,
        coverage_inset_m: 0.1,
        ..CandidateConfig::default()
    };
    let table = TableRect { center_m: [0.5, 0.0], size_m: [0.8, 1.2], height_m: 0.0 };
    let mut grids = ExplorationGrids::new();
    for v in init_views(&table, &cc).unwrap() {
        grids.integrate_frame(&map, &camera, &v, &[], None, &cfg.grid).unwrap();
    }
    let cands = sample_candidates(&map, &cc, &cfg.grid, &AlwaysReachable, 1).unwrap();
    let views: Vec<Se3> = cands.iter().take(100).map(|c| c.world_from_camera).collect();
    assert_eq!(views.len(), 100);
    let ctx = UtilityContext::new(&map, &grids, &HistoryBook::default(), &camera, &cfg).unwrap();
    let eg = ctx.score_all(&views, Strategy::ExpectedGain, Some(&views[0])).unwrap();
    let sum: f64 = eg.iter().map(|s| s.utility).sum();
    let cells: usize = eg.iter().flat_map(|s| s.objects.iter().map(|o| o.visible_cells)).sum();
    assert!((sum - 83_679.819_818_211_44).abs() < 1e-6 * sum, "expected-gain sum {sum}");
    assert_eq!(cells, 128_377);
    assert_eq!(next_best_view(&eg), Some(8));
    let od = ctx.score_all(&views, Strategy::ObjectDrivenDiscovery, None).unwrap();
    let od_sum: f64 = od.iter().map(|s| s.utility).sum();
    assert!((od_sum - 125_760.433_794_101_85).abs() < 1e-6 * od_sum, "object-driven sum {od_sum}");
    let occ = Occluders::from_map(&map, &cfg.grid);
    let unknown = TableCoverage::new(&table, &cfg.discovery).unwrap().unknown_cells(&occ);
    let disc: Vec<usize> =
        views.iter().map(|v| visible_unknown_cells(&unknown, &camera, v, &occ, &cfg.grid, &cfg.discovery)).collect();
    assert_eq!(disc.iter().sum::<usize>(), 54_777);
    assert_eq!(&disc[..10], &[372, 388, 433, 499, 490, 609, 942, 532, 1108, 734]);
}
