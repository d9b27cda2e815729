//! Depth-aware compositing: the map's depth refined by the live depth image of an RGB-D camera
//! (what AR devices composite against), so a virtual model is hidden by what the sensor sees now
//! and by what the map knows where the sensor sees nothing.
//!
//! [`fuse_live_depth`] turns the map's rendered depth and one live frame (depth, and optionally
//! the grey image the virtual models are drawn into) into the real depth the masks use:
//! 1. **Registration** (with a grey image): depth-to-colour registration of a real RGB-D unit is
//!    off by a few pixels; the integer shift (within [`LiveDepthConfig::max_shift_px`]) that puts
//!    the live depth's silhouettes (jumps above [`LiveDepthConfig::edge_jump_m`]) on the largest
//!    grey-image gradients is estimated per frame and applied.
//! 2. **Scale**: the live depth is scaled by the median ratio map / live over pixels where both
//!    agree within 3 % (the table dominates), absorbing the unit's depth-scale error
//!    ([`LiveDepthConfig::fit_scale`]).
//! 3. **Pixels with a return**: the map's depth clamped into `live ± band_m`. Outside the band the
//!    sensor decides (a phantom or an oversized map object does not hide what the sensor sees
//!    behind it; a missed object hides); inside it, where the sensor cannot tell a virtual surface
//!    from the real one, the map decides.
//! 4. **Pixels without a return** (stereo shadow, grazing incidence, out of range): bounded by the
//!    nearest returns left, right, above and below within [`LiveDepthConfig::hole_reach_px`]: the
//!    map's depth clamped into their interval. A map surface that the sensor would have seen
//!    (facing the camera below [`LiveDepthConfig::grazing_deg`], not in the second imager's
//!    shadow of a nearer live surface to its right, [`LiveDepthConfig::baseline_m`]) but did not
//!    is not there: the pixel takes the farthest neighbouring return when that is behind the map
//!    surface, or no surface at all.
//!
//! The fused depth is one image, so the masks ([`super::occlusion_masks`]) are unchanged: a model
//! pixel is visible when it is nearer than the fused depth. Then [`remove_specks`] hides visible
//! specks smaller than [`LiveDepthConfig::min_visible_px`] (single wrong returns and hole edges on
//! a real surface in front of the model).

use serde::{Deserialize, Serialize};

use super::{bad, check_image, ArError, COVER_HIDDEN, COVER_VISIBLE};
use crate::frame::{DepthImage, GreyImage};
use crate::geometry::PinholeCamera;

/// Live depth fusion settings (request `config.live`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LiveDepthConfig {
    /// What a depth image passed with a request is: `live` (a sensor frame, fused with the map's
    /// depth; the default) or `exact` (the real scene's exact depth, used alone: a simulator's
    /// truth).
    pub source: DepthSource,
    /// Half-width of the band around a live depth inside which the map decides, metres. Default
    /// 0.006 (several times the D435's depth noise at 0.5 m, 1 mm, plus the 1 mm depth unit).
    pub band_m: f64,
    /// Largest depth-to-colour registration shift searched, pixels; 0 = none. Default 8 (a D435's
    /// factory registration error is a few pixels).
    pub max_shift_px: u32,
    /// A live depth jump between neighbours above this is a silhouette, metres. Default 0.01.
    pub edge_jump_m: f64,
    /// How far a pixel without a return looks for returns along its row and column, pixels.
    /// Default 40.
    pub hole_reach_px: u32,
    /// Incidence angle from which a surface may give no return, degrees. Default 70 (where the
    /// sensor model's grazing dropouts start).
    pub grazing_deg: f64,
    /// Stereo baseline, the second imager to the right of the first, metres. Default 0.05 (D435).
    pub baseline_m: f64,
    /// Tolerance of the shadow test, pixels. Default 2.
    pub shadow_slack_px: f64,
    /// Scale the live depth to the map's (median ratio). Default true.
    pub fit_scale: bool,
    /// Visible parts of a model (8-connected) with fewer pixels than this are hidden; 0 = keep
    /// all. Default 8 (about a 3 × 3 block).
    pub min_visible_px: usize,
}

/// What a depth image passed with a request is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DepthSource {
    /// A depth sensor's frame: fused with the map's depth ([`fuse_live_depth`]).
    Live,
    /// The real scene's exact depth: used as it is.
    Exact,
}

impl Default for LiveDepthConfig {
    fn default() -> Self {
        Self {
            source: DepthSource::Live,
            band_m: 0.006,
            max_shift_px: 8,
            edge_jump_m: 0.01,
            hole_reach_px: 40,
            grazing_deg: 70.0,
            baseline_m: 0.05,
            shadow_slack_px: 2.0,
            fit_scale: true,
            min_visible_px: 8,
        }
    }
}

impl LiveDepthConfig {
    fn validate(&self) -> Result<(), ArError> {
        for (field, v) in [
            ("live.band_m", self.band_m),
            ("live.edge_jump_m", self.edge_jump_m),
            ("live.baseline_m", self.baseline_m),
            ("live.shadow_slack_px", self.shadow_slack_px),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(bad(field, format!("must be finite and >= 0, got {v}")));
            }
        }
        if !(self.grazing_deg.is_finite() && 0.0 < self.grazing_deg && self.grazing_deg <= 90.0) {
            return Err(bad("live.grazing_deg", format!("must be in (0, 90], got {}", self.grazing_deg)));
        }
        if self.max_shift_px > 64 || self.hole_reach_px > 4096 {
            return Err(bad("live.max_shift_px/hole_reach_px", "at most 64 and 4096 pixels"));
        }
        Ok(())
    }
}

/// The fused depth and what the fusion found.
#[derive(Debug, Clone, PartialEq)]
pub struct LiveFusion {
    /// The real depth for the masks, metres, 0 = no surface.
    pub depth: DepthImage,
    /// Summary.
    pub summary: LiveSummary,
}

/// What [`fuse_live_depth`] found in one frame.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct LiveSummary {
    /// Registration shift applied to the live depth, pixels (column, row): the live pixel at
    /// `q − shift` lands on `q`.
    pub shift_px: [i32; 2],
    /// Scale applied to the live depth.
    pub scale: f64,
    /// Pixels with no live return.
    pub holes_px: usize,
    /// Pixels without a return where a map surface was dropped (it would have been seen).
    pub dropped_px: usize,
}

/// Fuse the map's depth with a live depth frame (and its grey image, for the registration shift);
/// all three the camera's size. See the module docs for the steps.
pub fn fuse_live_depth(
    camera: &PinholeCamera,
    map_depth: &DepthImage,
    live: &DepthImage,
    grey: Option<&GreyImage>,
    config: &LiveDepthConfig,
) -> Result<LiveFusion, ArError> {
    config.validate()?;
    camera.validate()?;
    let (w, h) = (camera.width, camera.height);
    check_image("map_depth", map_depth, w, h)?;
    check_image("real_depth", live, w, h)?;
    let (w, h) = (w as usize, h as usize);
    let raw: Vec<f64> = live.data.iter().map(|d| if d.is_finite() && *d > 0.0 { f64::from(*d) } else { 0.0 }).collect();
    let shift = match grey {
        Some(g) if config.max_shift_px > 0 => {
            if g.width as usize != w || g.height as usize != h {
                return Err(ArError::ImageSize {
                    field: "grey",
                    expected_w: w as u32,
                    expected_h: h as u32,
                    actual_w: g.width,
                    actual_h: g.height,
                });
            }
            registration_shift(&raw, g, w, h, config)
        }
        _ => [0, 0],
    };
    let mut zs = shifted(&raw, w, h, shift);
    let zm: Vec<f64> =
        map_depth.data.iter().map(|d| if d.is_finite() && *d > 0.0 { f64::from(*d) } else { f64::INFINITY }).collect();
    let scale = if config.fit_scale { depth_scale(&zs, &zm) } else { 1.0 };
    for z in &mut zs {
        *z *= scale;
    }
    let band = config.band_m;
    let reach = config.hole_reach_px as usize;
    let near = nearest_returns(&zs, w, h, reach);
    let cos_grazing = config.grazing_deg.to_radians().cos();
    let fb = camera.fx * config.baseline_m;
    let mut out = vec![f64::INFINITY; w * h];
    let (mut holes_px, mut dropped_px) = (0, 0);
    for r in 0..h {
        // Right-imager column of each live return, and its minimum over the pixels to the right.
        let mut right_min = vec![f64::INFINITY; w + 1];
        for c in (0..w).rev() {
            let z = zs[r * w + c];
            let x = if z > 0.0 { c as f64 + 0.5 - fb / z } else { f64::INFINITY };
            right_min[c] = right_min[c + 1].min(x);
        }
        for c in 0..w {
            let i = r * w + c;
            let (z, m) = (zs[i], zm[i]);
            if z > 0.0 {
                out[i] = m.clamp(z - band, z + band);
                continue;
            }
            holes_px += 1;
            let (lo, hi) = near[i];
            let seen = m.is_finite()
                && facing_cos(&zm, camera, w, h, c, r).is_some_and(|cos| cos > cos_grazing)
                && right_min[c + 1] >= c as f64 + 0.5 - fb / m - config.shadow_slack_px;
            out[i] = if seen {
                dropped_px += 1;
                if hi.is_finite() && hi > m + band {
                    hi + band
                } else {
                    f64::INFINITY
                }
            } else if lo.is_finite() {
                m.clamp(lo - band, hi + band)
            } else {
                m
            };
        }
    }
    let data = out.iter().map(|d| if d.is_finite() { *d as f32 } else { 0.0 }).collect();
    Ok(LiveFusion {
        depth: DepthImage { width: w as u32, height: h as u32, data },
        summary: LiveSummary { shift_px: shift, scale, holes_px, dropped_px },
    })
}

/// Hide the visible pixels ([`COVER_VISIBLE`]) of `mask` (row-major, `width` wide) that belong to
/// 8-connected visible components of fewer than `min_px` pixels; returns how many were hidden.
pub fn remove_specks(mask: &mut [u8], width: usize, min_px: usize) -> usize {
    if min_px <= 1 || width == 0 {
        return 0;
    }
    let h = mask.len() / width;
    let mut seen = vec![false; mask.len()];
    let mut hidden = 0;
    let mut component = Vec::new();
    for start in 0..mask.len() {
        if seen[start] || mask[start] != COVER_VISIBLE {
            continue;
        }
        seen[start] = true;
        component.clear();
        component.push(start);
        let mut k = 0;
        while k < component.len() {
            let i = component[k];
            k += 1;
            let (c, r) = ((i % width) as i64, (i / width) as i64);
            for (dc, dr) in [(-1, -1), (0, -1), (1, -1), (-1, 0), (1, 0), (-1, 1), (0, 1), (1, 1)] {
                let (nc, nr) = (c + dc, r + dr);
                if nc < 0 || nr < 0 || nc >= width as i64 || nr >= h as i64 {
                    continue;
                }
                let j = nr as usize * width + nc as usize;
                if !seen[j] && mask[j] == COVER_VISIBLE {
                    seen[j] = true;
                    component.push(j);
                }
            }
        }
        if component.len() < min_px {
            for &i in &component {
                mask[i] = COVER_HIDDEN;
            }
            hidden += component.len();
        }
    }
    hidden
}

/// The shift `(dx, dy)` maximising the mean grey gradient at the live silhouettes moved by it;
/// ties go to the smaller shift. No silhouettes → no shift.
fn registration_shift(z: &[f64], grey: &GreyImage, w: usize, h: usize, config: &LiveDepthConfig) -> [i32; 2] {
    let s = config.max_shift_px as usize;
    if w <= 2 * s + 2 || h <= 2 * s + 2 {
        return [0, 0];
    }
    let g = |c: usize, r: usize| f64::from(grey.data[r * w + c]);
    let jump = |a: f64, b: f64| a > 0.0 && b > 0.0 && (a - b).abs() > config.edge_jump_m;
    // Both pixels of a jump are silhouette pixels, so the estimate is not biased by half a pixel.
    let mut edge = vec![false; w * h];
    for r in s..h - s - 1 {
        for c in s..w - s - 1 {
            let i = r * w + c;
            if jump(z[i], z[i + 1]) {
                edge[i] = true;
                edge[i + 1] = true;
            }
            if jump(z[i], z[i + w]) {
                edge[i] = true;
                edge[i + w] = true;
            }
        }
    }
    let edges: Vec<(usize, usize)> = (0..w * h).filter(|i| edge[*i]).map(|i| (i % w, i / w)).collect();
    if edges.is_empty() {
        return [0, 0];
    }
    // Gradient magnitude of the grey image (central differences), zero on the border.
    let mut grad = vec![0.0; w * h];
    for r in 1..h - 1 {
        for c in 1..w - 1 {
            grad[r * w + c] = (g(c + 1, r) - g(c - 1, r)).hypot(g(c, r + 1) - g(c, r - 1));
        }
    }
    let si = s as i32;
    let mut shifts: Vec<[i32; 2]> = (-si..=si).flat_map(|dy| (-si..=si).map(move |dx| [dx, dy])).collect();
    shifts.sort_by_key(|[dx, dy]| (dx * dx + dy * dy, *dy, *dx));
    let mut best = (f64::NEG_INFINITY, [0, 0]);
    for [dx, dy] in shifts {
        let score: f64 =
            edges.iter().map(|&(c, r)| grad[(r as i32 + dy) as usize * w + (c as i32 + dx) as usize]).sum();
        if score > best.0 {
            best = (score, [dx, dy]);
        }
    }
    best.1
}

/// `out(q) = z(q − shift)`, 0 where that falls outside.
fn shifted(z: &[f64], w: usize, h: usize, [dx, dy]: [i32; 2]) -> Vec<f64> {
    let mut out = vec![0.0; w * h];
    for r in 0..h {
        let sr = r as i64 - i64::from(dy);
        if sr < 0 || sr >= h as i64 {
            continue;
        }
        for c in 0..w {
            let sc = c as i64 - i64::from(dx);
            if sc >= 0 && sc < w as i64 {
                out[r * w + c] = z[sr as usize * w + sc as usize];
            }
        }
    }
    out
}

/// Median of map / live over the pixels where both have a surface within 3 % of each other; 1
/// with fewer than [`MIN_SCALE_PX`] such pixels.
fn depth_scale(zs: &[f64], zm: &[f64]) -> f64 {
    let mut ratios: Vec<f64> = zs
        .iter()
        .zip(zm)
        .filter(|(s, m)| **s > 0.0 && m.is_finite())
        .map(|(s, m)| m / s)
        .filter(|q| (q - 1.0).abs() < 0.03)
        .collect();
    if ratios.len() < MIN_SCALE_PX {
        return 1.0;
    }
    let k = ratios.len() / 2;
    *ratios.select_nth_unstable_by(k, f64::total_cmp).1
}

/// Fewest agreeing pixels for a depth-scale fit.
const MIN_SCALE_PX: usize = 100;

/// Per pixel, the (nearest, farthest) depth among the nearest returns left, right, above and below
/// within `reach` pixels; (∞, −∞) when there is none. Every pass walks the image row by row.
fn nearest_returns(z: &[f64], w: usize, h: usize, reach: usize) -> Vec<(f64, f64)> {
    fn put(o: &mut (f64, f64), last: Option<(usize, f64)>, k: usize, reach: usize) {
        if let Some((at, d)) = last {
            if k.abs_diff(at) <= reach {
                *o = (o.0.min(d), o.1.max(d));
            }
        }
    }
    let mut out = vec![(f64::INFINITY, f64::NEG_INFINITY); w * h];
    for (row, out_row) in z.chunks_exact(w).zip(out.chunks_exact_mut(w)) {
        let mut last = None;
        for (c, (d, o)) in row.iter().zip(out_row.iter_mut()).enumerate() {
            put(o, last, c, reach);
            if *d > 0.0 {
                last = Some((c, *d));
            }
        }
        last = None;
        for (c, (d, o)) in row.iter().zip(out_row.iter_mut()).enumerate().rev() {
            put(o, last, c, reach);
            if *d > 0.0 {
                last = Some((c, *d));
            }
        }
    }
    // Columns: the last return above (then below) each column, carried from row to row.
    let mut last: Vec<Option<(usize, f64)>> = vec![None; w];
    for (r, (row, out_row)) in z.chunks_exact(w).zip(out.chunks_exact_mut(w)).enumerate() {
        for ((d, o), l) in row.iter().zip(out_row.iter_mut()).zip(last.iter_mut()) {
            put(o, *l, r, reach);
            if *d > 0.0 {
                *l = Some((r, *d));
            }
        }
    }
    last.fill(None);
    for (r, (row, out_row)) in z.chunks_exact(w).zip(out.chunks_exact_mut(w)).enumerate().rev() {
        for ((d, o), l) in row.iter().zip(out_row.iter_mut()).zip(last.iter_mut()) {
            put(o, *l, r, reach);
            if *d > 0.0 {
                *l = Some((r, *d));
            }
        }
    }
    out
}

/// |cos| of the angle between pixel (c, r)'s ray and the surface normal of the depth image
/// `z` there (central differences of back-projected points); `None` on the border, next to a
/// missing pixel, or across a depth jump (a silhouette).
fn facing_cos(z: &[f64], cam: &PinholeCamera, w: usize, h: usize, c: usize, r: usize) -> Option<f64> {
    if c == 0 || r == 0 || c + 1 >= w || r + 1 >= h {
        return None;
    }
    let z0 = z[r * w + c];
    let point = |c: usize, r: usize| {
        let d = z[r * w + c];
        (d.is_finite() && (d - z0).abs() <= SILHOUETTE_JUMP_M + SILHOUETTE_JUMP_REL * z0).then(|| {
            nalgebra::Vector3::new((c as f64 + 0.5 - cam.cx) / cam.fx * d, (r as f64 + 0.5 - cam.cy) / cam.fy * d, d)
        })
    };
    let du = point(c + 1, r)? - point(c - 1, r)?;
    let dv = point(c, r + 1)? - point(c, r - 1)?;
    let n = du.cross(&dv);
    let p = point(c, r)?;
    let norm = n.norm() * p.norm();
    (norm > 0.0).then(|| n.dot(&p).abs() / norm)
}

/// A map depth jump between neighbours above `SILHOUETTE_JUMP_M + SILHOUETTE_JUMP_REL · z` is a
/// silhouette (no normal there); the sensor model's silhouette threshold.
const SILHOUETTE_JUMP_M: f64 = 0.01;
const SILHOUETTE_JUMP_REL: f64 = 0.02;

#[cfg(test)]
#[allow(clippy::unwrap_used)] // tests may unwrap (STYLE.md, 18)
mod tests {
    use super::*;

    const W: u32 = 64;
    const H: u32 = 48;

    fn cam() -> PinholeCamera {
        PinholeCamera::new(W, H, 50.0, 50.0, 32.0, 24.0).unwrap()
    }

    fn image(f: impl Fn(usize, usize) -> f32) -> DepthImage {
        let data = (0..H as usize).flat_map(|r| (0..W as usize).map(move |c| (c, r))).map(|(c, r)| f(c, r)).collect();
        DepthImage { width: W, height: H, data }
    }

    fn at(d: &DepthImage, c: usize, r: usize) -> f32 {
        d.data[r * W as usize + c]
    }

    fn no_shift_no_scale() -> LiveDepthConfig {
        LiveDepthConfig { fit_scale: false, max_shift_px: 0, ..LiveDepthConfig::default() }
    }

    #[test]
    fn the_sensor_decides_outside_the_band_and_the_map_inside() {
        // A wall at 1 m. The map has a phantom box at 0.8 m on columns 10..20 and misses a real
        // object at 0.7 m on columns 40..50; on columns 25..30 the map says 0.998 m.
        let live = image(|c, _| if (40..50).contains(&c) { 0.7 } else { 1.0 });
        let map = image(|c, _| {
            if (10..20).contains(&c) {
                0.8
            } else if (25..30).contains(&c) {
                0.998
            } else {
                1.0
            }
        });
        let f = fuse_live_depth(&cam(), &map, &live, None, &no_shift_no_scale()).unwrap();
        assert!((at(&f.depth, 15, 10) - 0.994).abs() < 1e-6, "phantom: live − band");
        assert!((at(&f.depth, 45, 10) - 0.706).abs() < 1e-6, "missed object: live + band");
        assert!((at(&f.depth, 27, 10) - 0.998).abs() < 1e-6, "inside the band the map decides");
        assert_eq!(f.summary.holes_px, 0);
    }

    #[test]
    fn a_hole_keeps_a_surface_the_sensor_could_not_see_and_drops_one_it_should_have() {
        // Live: a wall at 1 m, a near block at 0.5 m on columns 40..64, no return on columns
        // 30..40. The map: the wall, and the block from column 34 (too wide by 6 pixels).
        let live = image(|c, _| match c {
            30..40 => 0.0,
            40.. => 0.5,
            _ => 1.0,
        });
        let map = image(|c, _| if c >= 34 { 0.5 } else { 1.0 });
        let inner_rows = H as usize - 2; // normals need both neighbours
                                         // A 0.25 m baseline: the block's shadow on the wall is f·B·(1/0.5 − 1/1) = 12.5 px wide, so
                                         // the wall in the hole is in the shadow and stays; the map's block there faces the camera
                                         // and is not shadowed (same depth as the live block), so the sensor would have seen it:
                                         // dropped for the farthest neighbouring return behind it, the wall (+ band).
        let wide = LiveDepthConfig { baseline_m: 0.25, ..no_shift_no_scale() };
        let f = fuse_live_depth(&cam(), &map, &live, None, &wide).unwrap();
        assert!((at(&f.depth, 32, 20) - 1.0).abs() < 1e-6);
        assert!((at(&f.depth, 36, 20) - 1.006).abs() < 1e-6, "{}", at(&f.depth, 36, 20));
        // Dropped: columns 35..40 (column 34 has no normal: its left neighbour is across a jump).
        assert_eq!(f.summary.dropped_px, 5 * inner_rows);
        assert_eq!(f.summary.holes_px, 10 * H as usize);
        // A 5 cm baseline: a 2.5 px shadow, so the wall in the hole would have been seen too; with
        // no return behind it, it is no surface.
        let f = fuse_live_depth(&cam(), &map, &live, None, &no_shift_no_scale()).unwrap();
        assert_eq!(at(&f.depth, 32, 20), 0.0);
        assert_eq!(f.summary.dropped_px, 8 * inner_rows);
    }

    #[test]
    fn registration_shift_and_scale_are_recovered() {
        // A bright square (columns 20..36, rows 12..28) on a dark ground, and the live depth of
        // the square-shaped block drawn 3 columns left and 2 rows down of it; 2 % too far.
        let grey = GreyImage {
            width: W,
            height: H,
            data: (0..H as usize)
                .flat_map(|r| {
                    (0..W as usize).map(move |c| if (20..36).contains(&c) && (12..28).contains(&r) { 200 } else { 20 })
                })
                .collect(),
        };
        let live = image(|c, r| if (17..33).contains(&c) && (14..30).contains(&r) { 0.51 } else { 1.02 });
        let map = image(|_, _| 1.0);
        let config = LiveDepthConfig { max_shift_px: 5, ..LiveDepthConfig::default() };
        let f = fuse_live_depth(&cam(), &map, &live, Some(&grey), &config).unwrap();
        assert_eq!(f.summary.shift_px, [3, -2]);
        assert!((f.summary.scale - 1.0 / 1.02).abs() < 1e-6, "{}", f.summary.scale);
        // The block now sits on the square, at 0.5 m (map 1.0 clamped to live + band).
        assert!((at(&f.depth, 21, 13) - 0.506).abs() < 1e-5, "{}", at(&f.depth, 21, 13));
        assert!((at(&f.depth, 18, 13) - 1.0).abs() < 1e-5);
    }

    #[test]
    fn nearest_returns_look_along_rows_and_columns_within_reach() {
        // 5 × 4, returns at (0, 1) = 1.0, (4, 1) = 3.0 and (2, 3) = 2.0 (column, row).
        let (w, h) = (5, 4);
        let mut z = vec![0.0; w * h];
        z[w] = 1.0;
        z[w + 4] = 3.0;
        z[3 * w + 2] = 2.0;
        let near = nearest_returns(&z, w, h, 2);
        assert_eq!(near[w + 2], (1.0, 3.0)); // left and right, 2 px each
        assert_eq!(near[w + 1], (1.0, 1.0)); // the right return is 3 px away
        assert_eq!(near[2], (f64::INFINITY, f64::NEG_INFINITY)); // (2, 3) is 3 rows below
        assert_eq!(near[w * 2 + 2], (2.0, 2.0)); // below
        assert_eq!(near[3 * w + 2], (f64::INFINITY, f64::NEG_INFINITY)); // itself only
    }

    #[test]
    fn specks_smaller_than_the_minimum_are_hidden() {
        // A 3 × 3 visible block, a diagonal pair (8-connected: one component of 2) and a single pixel.
        let w = 10;
        let mut mask = vec![COVER_HIDDEN; w * 8];
        for r in 1..4 {
            for c in 1..4 {
                mask[r * w + c] = COVER_VISIBLE;
            }
        }
        mask[6 * w + 6] = COVER_VISIBLE;
        mask[7 * w + 7] = COVER_VISIBLE;
        mask[w + 8] = COVER_VISIBLE;
        assert_eq!(remove_specks(&mut mask.clone(), w, 0), 0);
        assert_eq!(remove_specks(&mut mask, w, 3), 3);
        assert_eq!(mask.iter().filter(|m| **m == COVER_VISIBLE).count(), 9);
        assert_eq!(remove_specks(&mut mask, w, 10), 9);
    }

    #[test]
    fn bad_sizes_and_settings_are_typed_errors() {
        let small = DepthImage { width: 4, height: 4, data: vec![1.0; 16] };
        let ok = image(|_, _| 1.0);
        let cfg = LiveDepthConfig::default();
        assert!(matches!(fuse_live_depth(&cam(), &ok, &small, None, &cfg), Err(ArError::ImageSize { .. })));
        let bad_band = LiveDepthConfig { band_m: f64::NAN, ..cfg };
        let e = fuse_live_depth(&cam(), &ok, &ok, None, &bad_band).unwrap_err();
        assert!(e.to_string().contains("live.band_m"), "{e}");
    }
}
