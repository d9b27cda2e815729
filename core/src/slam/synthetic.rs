//! Seeded synthetic test data: a procedural "random shapes" texture and a ray-cast RGB-D renderer.
//!
//! Used by the module's tests, the `slam` criterion benchmark and `experiments/bench/slam_refs.py`
//! (which re-implements [`shapes_texture`] bit for bit in NumPy, so the Rust benchmark and the
//! OpenCV reference time the very same frames without sharing a file). Nothing here is used by the
//! tracker itself.
//!
//! [`shapes_texture`] draws high-contrast axis-aligned rectangles and discs of random grey levels
//! on a random background, driven by SplitMix64 with integer arithmetic only (so the Python port is
//! exact). [`TabletopScene`] maps such a texture onto the table plane z = 0 and onto axis-aligned
//! boxes standing on it, and [`TabletopScene::render`] ray-casts a grey image (bilinear texture
//! lookup) and a depth image (metres along the optical axis) for any camera pose.

use nalgebra::{Point3, Vector3};

use crate::frame::{DepthImage, GreyImage};
use crate::geometry::{PinholeCamera, Se3};

/// SplitMix64 step (Steele, Lea, Flood 2014): the generator shared with the Python reference script.
pub fn splitmix64(state: &mut u64) -> u64 {
    *state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
    let mut z = *state;
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Pixels of image area per drawn shape in [`shapes_texture`].
pub const SHAPES_AREA_PER_SHAPE_PX: usize = 600;

/// A seeded texture of random rectangles and discs (integer-exact; see the module docs).
///
/// Draw order and random calls (each `r()` is one [`splitmix64`] draw, `%` is the u64 remainder):
/// background = 64 + r() % 128; then `width * height / 600` shapes, each: kind = r() % 2,
/// grey = r() % 256; a rectangle (kind 0) takes w = 4 + r() % 60, h = 4 + r() % 60,
/// x0 = r() % width, y0 = r() % height and fills `[x0, x0 + w) x [y0, y0 + h)` clipped; a disc
/// (kind 1) takes radius = 2 + r() % 30, cx = r() % width, cy = r() % height and fills the pixels
/// with `dx² + dy² ≤ radius²`, clipped.
pub fn shapes_texture(width: u32, height: u32, seed: u64) -> GreyImage {
    let (w, h) = (width as usize, height as usize);
    let mut state = seed;
    let mut r = move || splitmix64(&mut state);
    let background = (64 + r() % 128) as u8;
    let mut data = vec![background; w * h];
    if w == 0 || h == 0 {
        return GreyImage { width, height, data };
    }
    let n_shapes = w * h / SHAPES_AREA_PER_SHAPE_PX;
    for _ in 0..n_shapes {
        let kind = r() % 2;
        let grey = (r() % 256) as u8;
        if kind == 0 {
            let sw = 4 + (r() % 60) as usize;
            let sh = 4 + (r() % 60) as usize;
            let x0 = (r() % w as u64) as usize;
            let y0 = (r() % h as u64) as usize;
            for y in y0..(y0 + sh).min(h) {
                for px in &mut data[y * w + x0..y * w + (x0 + sw).min(w)] {
                    *px = grey;
                }
            }
        } else {
            let radius = 2 + (r() % 30) as i64;
            let cx = (r() % w as u64) as i64;
            let cy = (r() % h as u64) as i64;
            for y in (cy - radius).max(0)..=(cy + radius).min(h as i64 - 1) {
                for x in (cx - radius).max(0)..=(cx + radius).min(w as i64 - 1) {
                    let (dx, dy) = (x - cx, y - cy);
                    if dx * dx + dy * dy <= radius * radius {
                        data[y as usize * w + x as usize] = grey;
                    }
                }
            }
        }
    }
    GreyImage { width, height, data }
}

/// An axis-aligned textured box standing in a [`TabletopScene`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SceneBox {
    /// Centre in the world, metres.
    pub center: Vector3<f64>,
    /// Half-extents along world x, y, z, metres.
    pub half_extents: Vector3<f64>,
    /// Texture-space offset of this box's faces, texels (so boxes do not repeat the table).
    pub texture_offset: [f64; 2],
}

/// A textured table plane (z = 0) with axis-aligned textured boxes on it, for ray casting.
#[derive(Debug, Clone)]
pub struct TabletopScene {
    /// The texture, wrapped (tiled) over every surface.
    pub texture: GreyImage,
    /// Size of one texel on a surface, metres.
    pub texel_m: f64,
    /// Boxes on the table.
    pub boxes: Vec<SceneBox>,
}

impl TabletopScene {
    /// A table with four boxes of 4–12 cm around (0.5, 0), textured by [`shapes_texture`]
    /// (1024 x 1024 texels of 1 mm).
    pub fn tabletop(seed: u64) -> Self {
        let texture = shapes_texture(1024, 1024, seed);
        let mk = |x: f64, y: f64, hx: f64, hy: f64, hz: f64, o: f64| SceneBox {
            center: Vector3::new(x, y, hz),
            half_extents: Vector3::new(hx, hy, hz),
            texture_offset: [o, 2.0 * o],
        };
        let boxes = vec![
            mk(0.45, 0.08, 0.03, 0.04, 0.05, 131.0),
            mk(0.58, -0.10, 0.05, 0.03, 0.03, 257.0),
            mk(0.40, -0.12, 0.025, 0.025, 0.06, 389.0),
            mk(0.62, 0.12, 0.04, 0.06, 0.02, 521.0),
        ];
        Self { texture, texel_m: 0.001, boxes }
    }

    fn sample(&self, s: f64, t: f64) -> f32 {
        let (w, h) = (self.texture.width as i64, self.texture.height as i64);
        if w == 0 || h == 0 {
            return 0.0;
        }
        let (fs, ft) = (s.floor(), t.floor());
        let (a, b) = ((s - fs) as f32, (t - ft) as f32);
        let at = |x: i64, y: i64| -> f32 {
            let (x, y) = (x.rem_euclid(w), y.rem_euclid(h));
            f32::from(self.texture.data.get((y * w + x) as usize).copied().unwrap_or(0))
        };
        let (x0, y0) = (fs as i64, ft as i64);
        let top = at(x0, y0) * (1.0 - a) + at(x0 + 1, y0) * a;
        let bottom = at(x0, y0 + 1) * (1.0 - a) + at(x0 + 1, y0 + 1) * a;
        top * (1.0 - b) + bottom * b
    }

    /// Ray-cast a grey image and a depth image (metres along the optical axis; 0 where the ray
    /// escapes) seen from `world_from_camera` (OpenCV camera axes).
    pub fn render(&self, camera: &PinholeCamera, world_from_camera: &Se3) -> (GreyImage, DepthImage) {
        let (w, h) = (camera.width as usize, camera.height as usize);
        let mut grey = vec![0u8; w * h];
        let mut depth = vec![0f32; w * h];
        let origin = world_from_camera.translation.vector;
        let rot = world_from_camera.rotation.to_rotation_matrix();
        let inv_texel = 1.0 / self.texel_m;
        for v in 0..h {
            for u in 0..w {
                // Ray through the pixel centre with unit z in the camera frame: the ray parameter is
                // the depth.
                let d_in_camera = camera.unproject_pixel(u as u32, v as u32, 1.0).coords;
                let d = rot * d_in_camera;
                let mut best_t = f64::INFINITY;
                let mut best_st = [0.0, 0.0];
                if d.z < -1e-9 {
                    let t = -origin.z / d.z;
                    if t > 0.0 {
                        let p = origin + d * t;
                        best_t = t;
                        best_st = [p.x * inv_texel, p.y * inv_texel];
                    }
                }
                for b in &self.boxes {
                    if let Some((t, axis)) = ray_box(&origin, &d, b) {
                        if t < best_t {
                            let p = origin + d * t - b.center;
                            let (s, tt) = match axis {
                                0 => (p.y, p.z),
                                1 => (p.x, p.z),
                                _ => (p.x, p.y),
                            };
                            best_t = t;
                            best_st = [s * inv_texel + b.texture_offset[0], tt * inv_texel + b.texture_offset[1]];
                        }
                    }
                }
                if best_t.is_finite() {
                    grey[v * w + u] = self.sample(best_st[0], best_st[1]).round().clamp(0.0, 255.0) as u8;
                    depth[v * w + u] = best_t as f32;
                }
            }
        }
        (
            GreyImage { width: camera.width, height: camera.height, data: grey },
            DepthImage { width: camera.width, height: camera.height, data: depth },
        )
    }
}

/// Slab intersection: entry distance and the axis of the entry face.
fn ray_box(origin: &Vector3<f64>, d: &Vector3<f64>, b: &SceneBox) -> Option<(f64, usize)> {
    let mut t_near = f64::NEG_INFINITY;
    let mut t_far = f64::INFINITY;
    let mut axis = 0;
    for k in 0..3 {
        let lo = b.center[k] - b.half_extents[k];
        let hi = b.center[k] + b.half_extents[k];
        if d[k].abs() < 1e-12 {
            if origin[k] < lo || origin[k] > hi {
                return None;
            }
            continue;
        }
        let (mut t0, mut t1) = ((lo - origin[k]) / d[k], (hi - origin[k]) / d[k]);
        if t0 > t1 {
            std::mem::swap(&mut t0, &mut t1);
        }
        if t0 > t_near {
            t_near = t0;
            axis = k;
        }
        t_far = t_far.min(t1);
    }
    (t_near <= t_far && t_near > 0.0).then_some((t_near, axis))
}

/// A camera pose looking at `target` from `eye` (OpenCV axes: z towards the target, y down as
/// close to world −z as possible; world +x is image up for a vertical view).
pub fn look_at(eye: Point3<f64>, target: Point3<f64>) -> Se3 {
    let z = target - eye;
    let up = if z.cross(&Vector3::z()).norm() < 1e-6 * z.norm() { Vector3::x() } else { Vector3::z() };
    crate::geometry::look_at_with_up(&eye, &target, &up).unwrap_or(Se3::identity())
}

/// The `track_frame` benchmark's sequence: 640 x 480 frames (50° vertical field of view)
/// ray-cast from [`TabletopScene::tabletop`]`(3)` along a 20-pose arc, played back and forth so
/// the motion stays smooth, each with the prior of a robot whose error is
/// [`PriorNoiseConfig::default`] per view of two frames (seed 1).
pub struct TrackSequence {
    /// The camera.
    pub camera: PinholeCamera,
    /// The true poses of the arc.
    pub poses: Vec<Se3>,
    /// Each pose's grey image and depth.
    pub frames: Vec<(GreyImage, DepthImage)>,
    /// Playback order (forth and back) of the frames.
    pub order: Vec<usize>,
    robot: super::SyntheticPriorError,
}

impl TrackSequence {
    /// Render the sequence (about 0.4 s).
    pub fn new() -> Result<Self, crate::geometry::GeometryError> {
        let camera = PinholeCamera::from_fovy(640, 480, 50f64.to_radians())?;
        let scene = TabletopScene::tabletop(3);
        let poses: Vec<Se3> = (0..20)
            .map(|i| {
                let theta = -0.2 + 0.02 * f64::from(i);
                look_at(Point3::new(0.5 - 0.25 * theta.cos(), 0.25 * theta.sin(), 0.45), Point3::new(0.5, 0.0, 0.0))
            })
            .collect();
        let frames = poses.iter().map(|p| scene.render(&camera, p)).collect();
        let order = (0..poses.len()).chain((1..poses.len() - 1).rev()).collect();
        let robot = super::SyntheticPriorError::new(super::PriorNoiseConfig::default(), 1);
        Ok(Self { camera, poses, frames, order, robot })
    }

    /// The tracker's input at playback step `step` (the order repeats).
    pub fn input(&self, step: usize) -> super::TrackInput<'_> {
        let i = self.order[step % self.order.len()];
        let (grey, depth) = &self.frames[i];
        super::TrackInput {
            grey,
            depth,
            camera: &self.camera,
            world_from_camera_prior: self.robot.perturb(&self.poses[i], (step / 2) as u64, step as u64),
            view_index: (step / 2) as u64,
            world_from_camera_oracle: None,
        }
    }
}
