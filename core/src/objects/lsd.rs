//! Line segments on the grey frame (LSD, Grompone von Gioi et al., IPOL 2012) and their
//! assignment to object boxes (paper, "Estimation of orientation", input 1 of Alg. 2).
//!
//! The detector is the `lsdetect` crate (pure Rust, an independent implementation of the LSD
//! article). It is checked against OpenCV's `cv2.createLineSegmentDetector()` on seeded synthetic
//! tabletop frames by `core/tests/objects_lsd.rs` (fixture from `core/tests/fixtures/make_lsd.py`):
//! at least 90 % of OpenCV's segments of 30 px or more are found with both endpoints within 2 px.

use crate::frame::GreyImage;
use crate::geometry::Box2;

use super::ObjectsError;

/// A line segment in pixel coordinates (OpenCV's convention: pixel centres at integer + 0.5 as in
/// `cv2.createLineSegmentDetector`).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct LineSegment {
    /// First endpoint `(u, v)`, pixels.
    pub a: [f64; 2],
    /// Second endpoint `(u, v)`, pixels.
    pub b: [f64; 2],
}

impl LineSegment {
    /// A segment from its endpoints.
    pub fn new(a: [f64; 2], b: [f64; 2]) -> Self {
        Self { a, b }
    }

    /// Length in pixels.
    pub fn length_px(&self) -> f64 {
        (self.b[0] - self.a[0]).hypot(self.b[1] - self.a[1])
    }

    /// Undirected image angle in `[0, π)` (the paper's α(·)), radians; 0 = along +u.
    pub fn angle_rad(&self) -> f64 {
        let a = (self.b[1] - self.a[1]).atan2(self.b[0] - self.a[0]);
        a.rem_euclid(std::f64::consts::PI)
    }

    /// Midpoint `(u, v)`.
    pub fn midpoint(&self) -> [f64; 2] {
        [(self.a[0] + self.b[0]) / 2.0, (self.a[1] + self.b[1]) / 2.0]
    }

    /// Whether both endpoints are finite.
    pub fn is_finite(&self) -> bool {
        self.a.iter().chain(self.b.iter()).all(|v| v.is_finite())
    }
}

/// Configuration of the line-segment detector.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LsdConfig {
    /// Working scale: the image is Gaussian-blurred and subsampled by this factor first (LSD
    /// article and OpenCV default 0.8; 1.0 = full resolution, slower, more short segments).
    pub scale: f64,
    /// Segments shorter than this are dropped, pixels (default 10; the yaw score of Alg. 2 weighs
    /// every segment equally, so tiny texture segments only add noise).
    pub min_length_px: f64,
}

impl Default for LsdConfig {
    fn default() -> Self {
        Self { scale: 0.8, min_length_px: 10.0 }
    }
}

/// Detect line segments in a grey image, longest first.
///
/// Errors: [`ObjectsError::BadImage`] when the buffer does not match the size or the scale is not
/// in (0, 1].
pub fn detect_segments(image: &GreyImage, config: &LsdConfig) -> Result<Vec<LineSegment>, ObjectsError> {
    if !(config.scale.is_finite() && config.scale > 0.0 && config.scale <= 1.0) {
        return Err(ObjectsError::BadConfig { field: "lsd.scale", reason: format!("{} not in (0, 1]", config.scale) });
    }
    let (w, h) = (image.width as usize, image.height as usize);
    if image.data.len() != w * h {
        return Err(ObjectsError::BadImage { expected: w * h, actual: image.data.len() });
    }
    let segments = if config.scale < 1.0 {
        let (scaled, sw, sh) = gaussian_downscale(&image.data, w, h, config.scale);
        let back = 1.0 / config.scale;
        lsdetect::detect(&scaled, sw, sh, 1.0)
            .map_err(|e| ObjectsError::BadImage { expected: e.expected, actual: e.got })?
            .into_iter()
            .map(|mut s| {
                s.x1 *= back;
                s.y1 *= back;
                s.x2 *= back;
                s.y2 *= back;
                s
            })
            .collect::<Vec<_>>()
    } else {
        lsdetect::detect(&image.data, w, h, 1.0)
            .map_err(|e| ObjectsError::BadImage { expected: e.expected, actual: e.got })?
    };
    Ok(segments
        .iter()
        .map(|s| LineSegment::new([s.x1, s.y1], [s.x2, s.y2]))
        .filter(|s| s.is_finite() && s.length_px() >= config.min_length_px)
        .collect())
}

/// The segments assigned to an object whose detection box is `bbox`: those whose midpoint lies in
/// the box grown by `margin_px` and whose both endpoints lie in the box grown by
/// `2 * margin_px` (a segment crossing the box edge belongs to the background). Order is kept.
pub fn segments_in_box(segments: &[LineSegment], bbox: &Box2, margin_px: f64) -> Vec<LineSegment> {
    let grow = |m: f64| Box2::new(bbox.min[0] - m, bbox.min[1] - m, bbox.max[0] + m, bbox.max[1] + m);
    let inner = grow(margin_px);
    let outer = grow(2.0 * margin_px);
    segments
        .iter()
        .filter(|s| {
            let m = s.midpoint();
            inner.contains(m[0], m[1]) && outer.contains(s.a[0], s.a[1]) && outer.contains(s.b[0], s.b[1])
        })
        .copied()
        .collect()
}

/// The pre-scaling's Gaussian kernel (normalised, `f32`) and its half-size: σ = 0.6 / scale,
/// half-size ⌈σ·√(2·3·ln 10)⌉ (OpenCV's LSD).
fn blur_kernel(scale: f64) -> (Vec<f32>, usize) {
    const SIGMA_SCALE: f64 = 0.6;
    const SPREC: f64 = 3.0;
    let sigma = SIGMA_SCALE / scale;
    let half = (sigma * (2.0 * SPREC * std::f64::consts::LN_10).sqrt()).ceil() as usize;
    let kernel: Vec<f64> = (0..=2 * half).map(|i| (-0.5 * ((i as f64 - half as f64) / sigma).powi(2)).exp()).collect();
    let total: f64 = kernel.iter().sum();
    (kernel.iter().map(|k| (k / total) as f32).collect(), half)
}

/// Reflect-101 index (OpenCV's BORDER_DEFAULT) of `i` in `0..n`, for the few border taps.
fn reflect101(i: isize, n: usize) -> usize {
    let n = n as isize;
    if n == 1 {
        return 0;
    }
    let mut i = i;
    while i < 0 || i >= n {
        i = if i < 0 { -i } else { 2 * n - 2 - i };
    }
    i as usize
}

/// The vertical pass of the Gaussian blur over the horizontally blurred rows (reflect-101 border),
/// rounded to 8 bits.
fn blur_columns(horiz: &[f32], width: usize, height: usize, kernel: &[f32], half: usize) -> Vec<u8> {
    let mut blurred = vec![0u8; width * height];
    let mut acc = vec![0.0f32; width];
    for (y, out) in blurred.chunks_exact_mut(width).enumerate() {
        acc.iter_mut().for_each(|a| *a = 0.0);
        for (k, &kv) in kernel.iter().enumerate() {
            let sy = reflect101(y as isize + k as isize - half as isize, height);
            for (a, v) in acc.iter_mut().zip(&horiz[sy * width..(sy + 1) * width]) {
                *a += kv * v;
            }
        }
        for (o, a) in out.iter_mut().zip(&acc) {
            *o = (a + 0.5) as u8;
        }
    }
    blurred
}

/// `round(scale · n)`, at least 1.
fn scaled_size(n: usize, scale: f64) -> usize {
    ((n as f64 * scale).round() as usize).max(1)
}

/// Bilinear resampling with pixel-centre alignment: the two source indices of output index `dst`
/// (of a side `n` long in the source) and the second one's weight.
fn bilinear_taps(dst: usize, n: usize, scale: f64) -> (usize, usize, f32) {
    let s = ((dst as f64 + 0.5) * (1.0 / scale) - 0.5).max(0.0);
    let i0 = (s.floor() as usize).min(n - 1);
    let i1 = (i0 + 1).min(n - 1);
    (i0, i1, (s - i0 as f64) as f32)
}

/// OpenCV's LSD pre-scaling: Gaussian blur with σ = 0.6 / scale (kernel half-size
/// ⌈σ·√(2·3·ln 10)⌉, reflect-101 border), then bilinear resampling to `round(scale · size)` with
/// pixel-centre alignment (`cv2.resize(.., INTER_LINEAR)`), both rounded to 8 bits as OpenCV does.
/// `lsdetect`'s own scaling picks the nearest source pixel instead, which jitters oblique edges and
/// splits long segments; this keeps the output close to OpenCV's.
fn gaussian_downscale(image: &[u8], width: usize, height: usize, scale: f64) -> (Vec<u8>, usize, usize) {
    let (kernel, half) = blur_kernel(scale);
    let reflect = reflect101;
    let mut horiz = vec![0.0f32; width * height];
    let mut padded = vec![0.0f32; width + 2 * half];
    for (row, out) in image.chunks_exact(width).zip(horiz.chunks_exact_mut(width)) {
        // The row itself in the middle, its reflections in the `half` taps either side.
        for (p, &v) in padded[half..half + width].iter_mut().zip(row) {
            *p = f32::from(v);
        }
        for i in (0..half).chain(half + width..width + 2 * half) {
            padded[i] = f32::from(row[reflect(i as isize - half as isize, width)]);
        }
        // Tap-major accumulation: each pass over the row is a plain multiply-add the compiler
        // vectorises.
        for (k, &kv) in kernel.iter().enumerate() {
            for (o, &v) in out.iter_mut().zip(&padded[k..k + width]) {
                *o += kv * v;
            }
        }
    }
    let blurred = blur_columns(&horiz, width, height, &kernel, half);
    let (new_w, new_h) = (scaled_size(width, scale), scaled_size(height, scale));
    let taps = |dst: usize, n: usize| bilinear_taps(dst, n, scale);
    let cols: Vec<(usize, usize, f32)> = (0..new_w).map(|x| taps(x, width)).collect();
    // Each source row resampled along x once (an output row reads two, and neighbouring output
    // rows share them), then the rows blended: the same products and sums per pixel.
    let resample_row = |y: usize, into: &mut Vec<f32>| {
        let r = &blurred[y * width..(y + 1) * width];
        into.clear();
        into.extend(cols.iter().map(|&(x0, x1, fx)| f32::from(r[x0]) * (1.0 - fx) + f32::from(r[x1]) * fx));
    };
    let mut out = vec![0u8; new_w * new_h];
    let (mut top, mut bottom) = (Vec::with_capacity(new_w), Vec::with_capacity(new_w));
    let (mut top_row, mut bottom_row) = (usize::MAX, usize::MAX);
    for (y, dst) in out.chunks_exact_mut(new_w).enumerate() {
        let (y0, y1, fy) = taps(y, height);
        if top_row != y0 {
            if bottom_row == y0 {
                std::mem::swap(&mut top, &mut bottom);
                bottom_row = usize::MAX;
            } else {
                resample_row(y0, &mut top);
            }
            top_row = y0;
        }
        if bottom_row != y1 {
            resample_row(y1, &mut bottom);
            bottom_row = y1;
        }
        for ((o, &t), &b) in dst.iter_mut().zip(&top).zip(&bottom) {
            *o = (t * (1.0 - fy) + b * fy + 0.5) as u8;
        }
    }
    (out, new_w, new_h)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn step_image(w: u32, h: u32, split: u32) -> GreyImage {
        let data = (0..w * h).map(|i| if i % w < split { 40 } else { 210 }).collect();
        GreyImage::new(w, h, data).unwrap()
    }

    #[test]
    fn vertical_step_gives_one_long_vertical_segment() {
        let img = step_image(160, 120, 80);
        let segs = detect_segments(&img, &LsdConfig::default()).unwrap();
        let longest = segs.first().expect("no segment");
        assert!(longest.length_px() > 100.0, "{longest:?}");
        let u = (longest.a[0] + longest.b[0]) / 2.0;
        assert!((u - 80.0).abs() < 1.5, "edge at u = {u}");
        assert!((longest.angle_rad() - std::f64::consts::FRAC_PI_2).abs() < 0.02);
    }

    #[test]
    fn flat_image_and_bad_input() {
        let flat = GreyImage { width: 64, height: 48, data: vec![128; 64 * 48] };
        assert!(detect_segments(&flat, &LsdConfig::default()).unwrap().is_empty());
        let short = GreyImage { width: 64, height: 48, data: vec![0; 10] };
        assert_eq!(
            detect_segments(&short, &LsdConfig::default()),
            Err(ObjectsError::BadImage { expected: 64 * 48, actual: 10 })
        );
        let bad = LsdConfig { scale: 0.0, ..Default::default() };
        assert!(matches!(detect_segments(&flat, &bad), Err(ObjectsError::BadConfig { .. })));
        let tiny = GreyImage { width: 2, height: 2, data: vec![0, 255, 0, 255] };
        assert!(detect_segments(&tiny, &LsdConfig::default()).unwrap().is_empty());
    }

    #[test]
    fn segments_are_assigned_to_boxes() {
        let bbox = Box2::new(100.0, 100.0, 200.0, 180.0);
        let inside = LineSegment::new([110.0, 120.0], [190.0, 125.0]);
        let outside = LineSegment::new([300.0, 120.0], [390.0, 125.0]);
        let crossing = LineSegment::new([150.0, 150.0], [260.0, 150.0]); // leaves the box by 60 px
        let on_edge = LineSegment::new([99.0, 101.0], [99.0, 179.0]); // the box's own left edge
        let got = segments_in_box(&[inside, outside, crossing, on_edge], &bbox, 4.0);
        assert_eq!(got, vec![inside, on_edge]);
    }

    #[test]
    fn segment_angles_are_undirected() {
        let a = LineSegment::new([0.0, 0.0], [10.0, 10.0]);
        let b = LineSegment::new([10.0, 10.0], [0.0, 0.0]);
        assert!((a.angle_rad() - b.angle_rad()).abs() < 1e-12);
        assert!((a.angle_rad() - std::f64::consts::FRAC_PI_4).abs() < 1e-12);
        assert!((a.length_px() - 200f64.sqrt()).abs() < 1e-12);
    }

    /// The downscale as first written (one source-pixel gather per tap and output pixel), the
    /// reference of the faster one.
    fn gaussian_downscale_reference(image: &[u8], width: usize, height: usize, scale: f64) -> (Vec<u8>, usize, usize) {
        let (kernel, half) = blur_kernel(scale);
        let reflect = reflect101;
        let mut horiz = vec![0.0f32; width * height];
        let mut padded = vec![0.0f32; width + 2 * half];
        for (row, out) in image.chunks_exact(width).zip(horiz.chunks_exact_mut(width)) {
            for (i, p) in padded.iter_mut().enumerate() {
                *p = f32::from(row[reflect(i as isize - half as isize, width)]);
            }
            // Tap-major accumulation: each pass over the row is a plain multiply-add the compiler
            // vectorises.
            for (k, &kv) in kernel.iter().enumerate() {
                for (o, &v) in out.iter_mut().zip(&padded[k..k + width]) {
                    *o += kv * v;
                }
            }
        }
        let blurred = blur_columns(&horiz, width, height, &kernel, half);
        let (new_w, new_h) = (scaled_size(width, scale), scaled_size(height, scale));
        let taps = |dst: usize, n: usize| bilinear_taps(dst, n, scale);
        let cols: Vec<(usize, usize, f32)> = (0..new_w).map(|x| taps(x, width)).collect();
        let mut out = vec![0u8; new_w * new_h];
        for (y, dst) in out.chunks_exact_mut(new_w).enumerate() {
            let (y0, y1, fy) = taps(y, height);
            let r0 = &blurred[y0 * width..(y0 + 1) * width];
            let r1 = &blurred[y1 * width..(y1 + 1) * width];
            for (o, &(x0, x1, fx)) in dst.iter_mut().zip(&cols) {
                let top = f32::from(r0[x0]) * (1.0 - fx) + f32::from(r0[x1]) * fx;
                let bottom = f32::from(r1[x0]) * (1.0 - fx) + f32::from(r1[x1]) * fx;
                *o = (top * (1.0 - fy) + bottom * fy + 0.5) as u8;
            }
        }
        (out, new_w, new_h)
    }

    #[test]
    fn the_downscale_matches_its_reference_bit_for_bit() {
        // Seeded noise with edges, odd and even sizes, and a real frame's size.
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        for (w, h) in [(640usize, 480usize), (161, 97), (7, 5), (1, 9)] {
            let image: Vec<u8> = (0..w * h)
                .map(|i| {
                    state ^= state << 13;
                    state ^= state >> 7;
                    state ^= state << 17;
                    let edge = if (i % w) * 3 > w + (i / w) { 120 } else { 0 };
                    ((state >> 56) as u8 / 4).wrapping_add(edge)
                })
                .collect();
            for scale in [0.8, 0.5, 0.37, 1.0] {
                assert_eq!(
                    gaussian_downscale(&image, w, h, scale),
                    gaussian_downscale_reference(&image, w, h, scale),
                    "{w} x {h} at {scale}"
                );
            }
        }
    }
}
