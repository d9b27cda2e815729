//! Time per AR frame at 640x480 (paper Table "Time analysis of augmented reality"): registration
//! of three virtual models on a seven-object map + the map's depth image (objects and table) +
//! its fusion with a live RGB-D frame (registration shift search over ±8 px, scale, holes) + the
//! three occlusion masks and their speck filter + one physics frame (1/30 s in 4 sub-steps) of a
//! rapier world whose bodies are landing (2 mm above their supports, so contacts are computed in
//! the timed step). This is what `run_request` does per frame with a live depth image.
//!
//! The live frame is made from the map's depth as a sensor would see it: shifted 3 px right and
//! 1 px down (registration error), 1 % too far (scale error), ±1 mm seeded noise, and no return
//! in a 6 px band left of every silhouette (stereo shadow); its grey image shades the true depth.
//!
//! The scene is `scenes/scene03.toml`'s layout written out (books, cans, bottle, cup, block on a
//! 0.8 × 1.2 m table); the camera is the simulator's hand camera (58° vertical field of view)
//! 0.45 m above the table looking down at 35° from vertical.
//! `ar_stage/*` time the stages alone (the fusion stages on a fresh copy of the map's depth, which
//! the fusion refines in place).
//! Run: `cargo bench -p objslam-core --bench ar -- --warm-up-time 1 --measurement-time 3`.

// `criterion_group!` generates an undocumented public function.
#![allow(missing_docs)]

use std::hint::black_box;

use criterion::{criterion_group, criterion_main, BatchSize, Criterion};
use nalgebra::{Matrix3, Point3, Translation3, UnitQuaternion, Vector3};
use objslam_core::ar::{
    fuse_live_depth, occlusion_masks, register, remove_specks, render_scene_depth, ArConfig, ArPhysics, ArScene,
    Placement, RealObject, TableTop, VirtualModel, VirtualShape,
};
use objslam_core::frame::{DepthImage, GreyImage};
use objslam_core::geometry::{ObjectGeometry, PinholeCamera, Se3, Shape};
use objslam_core::map::Label;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn object(id: u32, label: Label, xy: [f64; 2], yaw: f64, half: [f64; 3]) -> RealObject {
    RealObject {
        id,
        label,
        geometry: ObjectGeometry {
            shape: label.shape(),
            center: Vector3::new(xy[0], xy[1], half[2]),
            yaw_rad: if label.shape() == Shape::Cuboid { yaw } else { 0.0 },
            half_extents: Vector3::from(half),
        },
    }
}

fn scene() -> ArScene {
    let objects = vec![
        object(0, Label::Book, [0.60, 0.20], -0.6, [0.074, 0.031, 0.017]),
        object(1, Label::Bottle, [0.42, 0.18], 0.0, [0.028, 0.028, 0.109]),
        object(2, Label::Book, [0.48, -0.09], 0.23, [0.077, 0.025, 0.019]),
        object(3, Label::Can, [0.57, -0.28], 0.0, [0.033, 0.033, 0.052]),
        object(4, Label::Cup, [0.35, -0.05], 0.0, [0.04, 0.04, 0.05]),
        object(5, Label::Block, [0.70, -0.05], 0.4, [0.025, 0.025, 0.025]),
        object(6, Label::Can, [0.30, 0.30], 0.0, [0.03, 0.03, 0.06]),
    ];
    let table = TableTop { center_xy_m: [0.5, 0.0], size_xy_m: [0.8, 1.2], height_m: 0.0, thickness_m: 0.05 };
    ArScene { objects, table: Some(table) }
}

fn on_top(name: &str, label: Label, shape: VirtualShape, lift_m: f64) -> VirtualModel {
    VirtualModel {
        name: name.into(),
        shape,
        placement: Placement::Object {
            label,
            object_id: None,
            on_top: true,
            offset_m: [0.0, 0.0, lift_m],
            yaw_rad: 0.3,
        },
    }
}

fn camera() -> (PinholeCamera, Se3) {
    let cam = PinholeCamera::from_fovy(640, 480, 58f64.to_radians()).unwrap_or_else(|_| unreachable!());
    // Look at the table centre from 0.45 m above it, tilted 35° towards the robot side.
    let target = Point3::new(0.5, 0.0, 0.0);
    let tilt = 35f64.to_radians();
    let eye = Point3::new(0.5 - 0.45 * tilt.tan(), 0.0, 0.45);
    let z = (target - eye).normalize();
    let x = Vector3::new(0.0, -1.0, 0.0);
    let y = z.cross(&x);
    let rot = UnitQuaternion::from_matrix(&Matrix3::from_columns(&[x, y, z]));
    (cam, Se3::from_parts(Translation3::from(eye.coords), rot))
}

/// A live frame of `depth` as a sensor would deliver it (see the module docs), and its grey image.
fn live_frame(depth: &DepthImage) -> (DepthImage, GreyImage) {
    let (w, h) = (depth.width as usize, depth.height as usize);
    let mut rng = ChaCha8Rng::seed_from_u64(39);
    let mut live = vec![0.0f32; w * h];
    for r in 1..h {
        for c in 3..w {
            let d = depth.data[(r - 1) * w + c - 3];
            if d > 0.0 {
                live[r * w + c] = d * 1.01 + rng.random_range(-0.001..0.001);
            }
        }
    }
    for r in 0..h {
        for c in 0..w.saturating_sub(6) {
            let (a, b) = (live[r * w + c], live[r * w + c + 6]);
            if a > 0.0 && b > 0.0 && b < a - 0.02 {
                live[r * w + c] = 0.0;
            }
        }
    }
    let grey = depth.data.iter().map(|d| (255.0 * (1.0 - d.clamp(0.0, 1.0))) as u8).collect();
    (
        DepthImage { width: depth.width, height: depth.height, data: live },
        GreyImage { width: depth.width, height: depth.height, data: grey },
    )
}

fn bench_ar(c: &mut Criterion) {
    let scene = scene();
    let models = vec![
        on_top("robot_toy", Label::Book, VirtualShape::Cuboid { half_extents_m: [0.03, 0.02, 0.04] }, 0.002),
        on_top("lamp", Label::Can, VirtualShape::Cylinder { radius_m: 0.02, half_height_m: 0.06 }, 0.002),
        on_top("marble", Label::Block, VirtualShape::Ball { radius_m: 0.015 }, 0.002),
    ];
    let config = ArConfig::default();
    let (cam, world_from_camera) = camera();
    let (live, grey) = live_frame(
        &render_scene_depth(&scene, &cam, &world_from_camera, &config.render).unwrap_or_else(|e| panic!("{e}")),
    );
    c.bench_function("ar_frame_640x480", |b| {
        b.iter_batched(
            || {
                let mut physics = ArPhysics::new(&scene, &config.physics).unwrap_or_else(|e| panic!("{e}"));
                for m in register(&scene, &models).unwrap_or_else(|e| panic!("{e}")) {
                    physics.add(&m, [0.0; 3]).unwrap_or_else(|e| panic!("{e}"));
                }
                physics
            },
            |mut physics| {
                let registered = register(&scene, &models).unwrap_or_else(|e| panic!("{e}"));
                let map_depth = render_scene_depth(&scene, &cam, &world_from_camera, &config.render)
                    .unwrap_or_else(|e| panic!("{e}"));
                let fused = fuse_live_depth(&cam, map_depth, &live, Some(&grey), &config.live)
                    .unwrap_or_else(|e| panic!("{e}"));
                let mut masks = occlusion_masks(&registered, &cam, &world_from_camera, &fused.depth, &config.render)
                    .unwrap_or_else(|e| panic!("{e}"));
                for m in &mut masks {
                    remove_specks(&mut m.coverage, cam.width as usize, config.live.min_visible_px);
                }
                physics.step_frame();
                black_box((masks, physics.states()))
            },
            BatchSize::SmallInput,
        )
    });
    // The frame's stages alone (the paper's table splits its AR time by stage too).
    let registered = register(&scene, &models).unwrap_or_else(|e| panic!("{e}"));
    let depth = render_scene_depth(&scene, &cam, &world_from_camera, &config.render).unwrap_or_else(|e| panic!("{e}"));
    c.bench_function("ar_stage/registration", |b| b.iter(|| black_box(register(&scene, &models))));
    c.bench_function("ar_stage/map_depth_640x480", |b| {
        b.iter(|| black_box(render_scene_depth(&scene, &cam, &world_from_camera, &config.render)))
    });
    c.bench_function("ar_stage/live_fusion_640x480", |b| {
        b.iter_batched(
            || depth.clone(),
            |map_depth| black_box(fuse_live_depth(&cam, map_depth, &live, Some(&grey), &config.live)),
            BatchSize::LargeInput,
        )
    });
    // The same fusion without the registration shift search (a unit whose shift is known).
    let known_shift = objslam_core::ar::LiveDepthConfig { max_shift_px: 0, ..config.live };
    c.bench_function("ar_stage/live_fusion_no_shift_640x480", |b| {
        b.iter_batched(
            || depth.clone(),
            |map_depth| black_box(fuse_live_depth(&cam, map_depth, &live, Some(&grey), &known_shift)),
            BatchSize::LargeInput,
        )
    });
    c.bench_function("ar_stage/masks_640x480", |b| {
        b.iter(|| black_box(occlusion_masks(&registered, &cam, &world_from_camera, &depth, &config.render)))
    });
    c.bench_function("ar_stage/physics_frame", |b| {
        b.iter_batched(
            || {
                let mut physics = ArPhysics::new(&scene, &config.physics).unwrap_or_else(|e| panic!("{e}"));
                for m in &registered {
                    physics.add(m, [0.0; 3]).unwrap_or_else(|e| panic!("{e}"));
                }
                physics
            },
            |mut physics| {
                physics.step_frame();
                black_box(physics.states())
            },
            BatchSize::SmallInput,
        )
    });
}

criterion_group!(benches, bench_ar);
criterion_main!(benches);
