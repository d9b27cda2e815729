//! The sensor model's benchmark frame: rendered buffers of a synthetic tabletop, for the `sensor`
//! criterion benchmark and fixed-work timing (`core/examples/fixed_work.rs sensor`). Nothing here
//! is used by the model itself.

use nalgebra::{Matrix4, Rotation3, Vector3};

use super::{Intrinsics, RenderedFrame};

/// Rendered buffers of one 640 × 480 frame: a table plane 0.5 m away tilted 30° about the
/// camera's x axis, a box face 0.42 m away and a cylinder-like bump 0.40 m away standing in
/// front of it; colour a checkerboard with ramps.
pub struct TiltedTable {
    /// Intrinsics of the rendering camera (fx = fy = 433 px, centred).
    pub intrinsics: Intrinsics,
    /// Points in the camera frame, row-major, three per pixel.
    pub points: Vec<f32>,
    /// Unit normals in the camera frame, three per pixel.
    pub normals: Vec<f32>,
    /// RGB, three bytes per pixel.
    pub rgb: Vec<u8>,
}

impl TiltedTable {
    /// Width and height, pixels.
    pub const SIZE: (usize, usize) = (640, 480);

    /// The frame's buffers.
    pub fn new() -> Self {
        let (w, h) = Self::SIZE;
        let k = Intrinsics { fx: 433.0, fy: 433.0, cx: 320.0, cy: 240.0 };
        let (mut p, mut n, mut rgb) = (vec![0.0f32; 3 * w * h], vec![0.0f32; 3 * w * h], vec![0u8; 3 * w * h]);
        let tilt = 30f64.to_radians();
        // Plane through (0, 0, 0.5) with normal (0, -sin, -cos) (facing the camera, tilted about x).
        let normal = Vector3::new(0.0, -tilt.sin(), -tilt.cos());
        for y in 0..h {
            for x in 0..w {
                let r = Vector3::new((x as f64 + 0.5 - k.cx) / k.fx, (y as f64 + 0.5 - k.cy) / k.fy, 1.0);
                let t_plane = 0.5 * normal.z / r.dot(&normal);
                let in_box = (250..390).contains(&x) && (180..300).contains(&y);
                let in_bump = ((x as f64 - 480.0).powi(2) + (y as f64 - 160.0).powi(2)).sqrt() < 50.0;
                let (t, nv) = if in_box {
                    (0.42, Vector3::new(0.0, 0.0, -1.0))
                } else if in_bump {
                    (0.40, Vector3::new((x as f64 - 480.0) / 50.0, 0.0, -1.0).normalize())
                } else {
                    (t_plane, normal)
                };
                let i = y * w + x;
                for a in 0..3 {
                    p[3 * i + a] = (r[a] * t) as f32;
                    n[3 * i + a] = nv[a] as f32;
                }
                let checker = ((x / 7 + y / 5) % 2) as u8;
                rgb[3 * i] = 60 + 120 * checker;
                rgb[3 * i + 1] = 90 + (x % 50) as u8;
                rgb[3 * i + 2] = 140 - (y % 60) as u8;
            }
        }
        Self { intrinsics: k, points: p, normals: n, rgb }
    }

    /// The buffers as the sensor model's input.
    pub fn frame(&self) -> RenderedFrame<'_> {
        let (width, height) = Self::SIZE;
        RenderedFrame {
            width,
            height,
            points_in_camera: &self.points,
            normals_in_camera: &self.normals,
            rgb: &self.rgb,
        }
    }

    /// The camera's motion over an exposure of `exposure_s` seconds when it moves at 0.3 m/s
    /// along x and turns at 0.5 rad/s about y.
    pub fn motion(exposure_s: f64) -> Matrix4<f64> {
        let mut m = Matrix4::identity();
        let r = Rotation3::new(Vector3::new(0.0, 0.5 * exposure_s, 0.0));
        m.fixed_view_mut::<3, 3>(0, 0).copy_from(r.matrix());
        m[(0, 3)] = 0.3 * exposure_s;
        m
    }

    /// The camera's motion over an exposure of `exposure_s` seconds when it rolls at 1.2 rad/s
    /// about its optical axis (a wrist turning: about 7 px at the image corners over 15 ms, under
    /// a pixel at the centre, opposite directions on opposite sides), turns at 0.1 rad/s about x
    /// and −0.05 rad/s about y and moves at 0.05 m/s.
    pub fn rolling_motion(exposure_s: f64) -> Matrix4<f64> {
        let mut m = Matrix4::identity();
        let r = Rotation3::new(Vector3::new(0.1, -0.05, 1.2) * exposure_s);
        m.fixed_view_mut::<3, 3>(0, 0).copy_from(r.matrix());
        m.fixed_view_mut::<3, 1>(0, 3).copy_from(&(Vector3::new(0.02, 0.01, 0.045) * exposure_s));
        m
    }
}

impl Default for TiltedTable {
    fn default() -> Self {
        Self::new()
    }
}
