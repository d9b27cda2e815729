//! Sensor frames and detections, as they cross from the simulator into the core.
//!
//! Entry points: [`DepthImage`] (metres, row-major), [`GreyImage`] (u8), [`Detection`] (2D box,
//! label, score), and [`Frame`], which bundles them with the intrinsics and the camera pose prior
//! and is validated once by [`Frame::validate`]. Everything downstream may assume a validated frame.
//!
//! Depth convention: metres along the optical axis; 0 (or any non-finite value) means "no return"
//! and is skipped by consumers, never an error. Negative depth is an error.

use crate::geometry::{Box2, PinholeCamera, Se3};
use crate::map::Label;

/// Errors raised when a frame does not make sense.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum FrameError {
    /// An image's size disagrees with the camera's.
    #[error("{field}: image is {actual_width}x{actual_height}, camera is {width}x{height}")]
    SizeMismatch {
        /// Which image.
        field: &'static str,
        /// Camera width.
        width: u32,
        /// Camera height.
        height: u32,
        /// Image width.
        actual_width: u32,
        /// Image height.
        actual_height: u32,
    },
    /// A buffer's length is not width × height.
    #[error("{field}: buffer has {actual} values, expected {expected}")]
    BufferLength {
        /// Which buffer.
        field: &'static str,
        /// Expected length.
        expected: usize,
        /// Actual length.
        actual: usize,
    },
    /// Depth holds a negative value.
    #[error("depth: negative value {value} at pixel ({u}, {v})")]
    NegativeDepth {
        /// Column.
        u: u32,
        /// Row.
        v: u32,
        /// The value, metres.
        value: f32,
    },
    /// A detection is malformed.
    #[error("detections[{index}]: {reason}")]
    BadDetection {
        /// Index in the frame's detection list.
        index: usize,
        /// What failed.
        reason: String,
    },
    /// Camera intrinsics invalid.
    #[error(transparent)]
    Geometry(#[from] crate::geometry::GeometryError),
}

/// A depth image in metres, row-major (`data[v * width + u]`).
#[derive(Debug, Clone, PartialEq)]
pub struct DepthImage {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Depth values, metres; 0 or non-finite = no return.
    pub data: Vec<f32>,
}

impl DepthImage {
    /// Wrap a buffer, checking its length.
    pub fn new(width: u32, height: u32, data: Vec<f32>) -> Result<Self, FrameError> {
        let expected = width as usize * height as usize;
        if data.len() != expected {
            return Err(FrameError::BufferLength { field: "depth", expected, actual: data.len() });
        }
        Ok(Self { width, height, data })
    }

    /// Depth at a pixel (`None` when outside, zero or non-finite).
    pub fn at(&self, u: u32, v: u32) -> Option<f32> {
        if u >= self.width || v >= self.height {
            return None;
        }
        let d = self.data[v as usize * self.width as usize + u as usize];
        (d.is_finite() && d > 0.0).then_some(d)
    }
}

/// A grey image, row-major u8.
#[derive(Debug, Clone, PartialEq)]
pub struct GreyImage {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Intensities.
    pub data: Vec<u8>,
}

impl GreyImage {
    /// Wrap a buffer, checking its length.
    pub fn new(width: u32, height: u32, data: Vec<u8>) -> Result<Self, FrameError> {
        let expected = width as usize * height as usize;
        if data.len() != expected {
            return Err(FrameError::BufferLength { field: "grey", expected, actual: data.len() });
        }
        Ok(Self { width, height, data })
    }

    /// The ITU-R BT.601 luma of an RGB image (three bytes a pixel, row-major):
    /// `0.299 R + 0.587 G + 0.114 B` in `f32`, rounded to nearest (`+ ½`, clamped, truncated).
    pub fn from_rgb(width: u32, height: u32, rgb: &[u8]) -> Result<Self, FrameError> {
        let expected = 3 * width as usize * height as usize;
        if rgb.len() != expected {
            return Err(FrameError::BufferLength { field: "rgb", expected, actual: rgb.len() });
        }
        // Each channel's product, looked up: the same `f32` products, summed in the same order.
        let (mut r, mut g, mut b) = ([0f32; 256], [0f32; 256], [0f32; 256]);
        for (v, ((rv, gv), bv)) in (0u8..=255).zip(r.iter_mut().zip(g.iter_mut()).zip(b.iter_mut())) {
            (*rv, *gv, *bv) = (f32::from(v) * LUMA_R, f32::from(v) * LUMA_G, f32::from(v) * LUMA_B);
        }
        let luma = |p: &[u8]| {
            let y = r[usize::from(p[0])] + g[usize::from(p[1])] + b[usize::from(p[2])];
            (y + 0.5).clamp(0.0, 255.0) as u8
        };
        Ok(Self { width, height, data: rgb.chunks_exact(3).map(luma).collect() })
    }
}

/// ITU-R BT.601 luma weights of red, green and blue ([`GreyImage::from_rgb`]).
const LUMA_R: f32 = 0.299;
/// See [`LUMA_R`].
const LUMA_G: f32 = 0.587;
/// See [`LUMA_R`].
const LUMA_B: f32 = 0.114;

/// A 2D detection: box, class label and confidence.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Detection {
    /// Box in pixels.
    pub bbox: Box2,
    /// Class label.
    pub label: Label,
    /// Confidence in [0, 1].
    pub score: f64,
}

/// One sensor frame.
#[derive(Debug, Clone)]
pub struct Frame {
    /// Frame index within the run (monotonic).
    pub index: u32,
    /// Intrinsics.
    pub camera: PinholeCamera,
    /// Depth in metres.
    pub depth: DepthImage,
    /// Camera pose prior (forward kinematics), OpenCV camera axes.
    pub world_from_camera: Se3,
    /// Detections in this frame.
    pub detections: Vec<Detection>,
}

impl Frame {
    /// Check sizes, depth values and detections against the camera.
    pub fn validate(&self) -> Result<(), FrameError> {
        self.camera.validate()?;
        if self.depth.width != self.camera.width || self.depth.height != self.camera.height {
            return Err(FrameError::SizeMismatch {
                field: "depth",
                width: self.camera.width,
                height: self.camera.height,
                actual_width: self.depth.width,
                actual_height: self.depth.height,
            });
        }
        if let Some(i) = self.depth.data.iter().position(|d| *d < 0.0) {
            let w = self.depth.width as usize;
            return Err(FrameError::NegativeDepth { u: (i % w) as u32, v: (i / w) as u32, value: self.depth.data[i] });
        }
        for (index, d) in self.detections.iter().enumerate() {
            if !d.bbox.is_finite() {
                return Err(FrameError::BadDetection { index, reason: "box has a non-finite coordinate".into() });
            }
            if !(d.score.is_finite() && (0.0..=1.0).contains(&d.score)) {
                return Err(FrameError::BadDetection { index, reason: format!("score {} outside [0, 1]", d.score) });
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::PinholeCamera;

    #[test]
    fn luma_of_rgb_is_bt601_rounded() {
        let rgb = [255, 255, 255, 0, 0, 0, 255, 0, 0, 0, 255, 0, 0, 0, 255, 100, 150, 200];
        let grey = GreyImage::from_rgb(3, 2, &rgb).unwrap();
        // 0.299 · 255 = 76.2, 0.587 · 255 = 149.7, 0.114 · 255 = 29.1, 29.9 + 88.05 + 22.8 = 140.75.
        assert_eq!(grey.data, vec![255, 0, 76, 150, 29, 141]);
        assert!(GreyImage::from_rgb(3, 3, &rgb).unwrap_err().to_string().contains("rgb"));
    }

    #[test]
    fn luma_is_the_rounded_f32_formula_for_every_colour() {
        // All 2^24 colours, one row of 256 blues per (red, green), against the formula itself.
        let mut row = vec![0u8; 3 * 256];
        for (red, green) in (0..=255u8).flat_map(|r| (0..=255u8).map(move |g| (r, g))) {
            for (blue, p) in (0..=255u8).zip(row.chunks_exact_mut(3)) {
                p.copy_from_slice(&[red, green, blue]);
            }
            let grey = GreyImage::from_rgb(256, 1, &row).unwrap();
            for (blue, y) in (0..=255u8).zip(&grey.data) {
                let v = f32::from(red) * 0.299 + f32::from(green) * 0.587 + f32::from(blue) * 0.114;
                assert_eq!(*y, (v + 0.5).clamp(0.0, 255.0) as u8, "rgb ({red}, {green}, {blue})");
            }
        }
    }

    fn frame() -> Frame {
        let camera = PinholeCamera::from_fovy(4, 3, 1.0).unwrap();
        Frame {
            index: 0,
            camera,
            depth: DepthImage::new(4, 3, vec![0.5; 12]).unwrap(),
            world_from_camera: Se3::identity(),
            detections: vec![Detection { bbox: Box2::new(0.0, 0.0, 2.0, 2.0), label: Label::Cup, score: 0.8 }],
        }
    }

    #[test]
    fn validation_names_the_problem() {
        assert!(frame().validate().is_ok());
        assert!(matches!(DepthImage::new(4, 3, vec![0.0; 11]), Err(FrameError::BufferLength { field: "depth", .. })));
        let mut f = frame();
        f.depth.data[5] = -1.0;
        assert_eq!(f.validate(), Err(FrameError::NegativeDepth { u: 1, v: 1, value: -1.0 }));
        let mut f = frame();
        f.detections[0].score = f64::NAN;
        assert!(matches!(f.validate(), Err(FrameError::BadDetection { index: 0, .. })));
        let mut f = frame();
        f.depth = DepthImage::new(3, 4, vec![0.5; 12]).unwrap();
        assert!(matches!(f.validate(), Err(FrameError::SizeMismatch { field: "depth", .. })));
    }

    #[test]
    fn zero_and_nan_depth_are_no_return() {
        let mut f = frame();
        f.depth.data[0] = 0.0;
        f.depth.data[1] = f32::NAN;
        assert!(f.validate().is_ok());
        assert_eq!(f.depth.at(0, 0), None);
        assert_eq!(f.depth.at(1, 0), None);
        assert_eq!(f.depth.at(2, 0), Some(0.5));
        assert_eq!(f.depth.at(9, 0), None);
    }
}
