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
//! Cost: steps 1 and 2 read the image a few times row by row (the shift's score of every
//! candidate from one pass over the silhouettes; the scale's median exactly from a histogram, no
//! sort); steps 3 and 4 are one top-down pass that writes the fused rows over the map's depth
//! image, so no other image-sized buffer is allocated. Its time at 640 × 480 is the criterion entry
//! `ar_stage/live_fusion_640x480` (`core/benches/ar.rs`).
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
/// all three the camera's size. See the module docs for the steps. The map's depth image is
/// refined in place and returned as the fused depth (no other image-sized buffer is allocated).
pub fn fuse_live_depth(
    camera: &PinholeCamera,
    map_depth: DepthImage,
    live: &DepthImage,
    grey: Option<&GreyImage>,
    config: &LiveDepthConfig,
) -> Result<LiveFusion, ArError> {
    config.validate()?;
    camera.validate()?;
    let (w, h) = (camera.width, camera.height);
    check_image("map_depth", &map_depth, w, h)?;
    check_image("real_depth", live, w, h)?;
    let (w, h) = (w as usize, h as usize);
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
            registration_shift(&live.data, g, w, h, config)
        }
        _ => [0, 0],
    };
    // The shifted live depth stays unscaled: scaling is monotone, so the nearest returns of the
    // scaled depth are the scaled nearest returns, and each value is scaled where it is used.
    let zs = ShiftedLive::new(&live.data, w, h, shift);
    let scale = if config.fit_scale { depth_scale(&zs, &map_depth.data) } else { 1.0 };
    let reach = config.hole_reach_px as usize;
    let row_fusion = RowFusion {
        camera,
        scale,
        band: config.band_m,
        fb: camera.fx * config.baseline_m,
        cos_grazing: config.grazing_deg.to_radians().cos(),
        shadow_slack_px: config.shadow_slack_px,
    };
    let mut map = map_depth.data;
    let (mut holes_px, mut dropped_px) = (0, 0);
    let mut holes = HoleBounds::new(w, reach);
    let (mut z, mut fused, mut map_above) = (vec![0.0f32; w], vec![0.0f32; w], vec![0.0f32; w]);
    // Top-down: each row is fused from the map rows around it (the one above kept as it was
    // before being overwritten) and written over its map row.
    for r in 0..h {
        zs.row(r, &mut z);
        let holes = holes.row(&zs, r, &z);
        holes_px += holes.len();
        let rows = MapRows {
            above: if r > 0 { &map_above } else { &[] },
            this: &map[r * w..(r + 1) * w],
            below: if r + 1 < h { &map[(r + 1) * w..(r + 2) * w] } else { &[] },
            r,
            h,
        };
        dropped_px += row_fusion.fuse(&rows, &z, holes, &mut fused);
        map_above.copy_from_slice(&map[r * w..(r + 1) * w]);
        map[r * w..(r + 1) * w].copy_from_slice(&fused);
    }
    Ok(LiveFusion {
        depth: DepthImage { width: w as u32, height: h as u32, data: map },
        summary: LiveSummary { shift_px: shift, scale, holes_px, dropped_px },
    })
}

/// A live depth as a return: metres, 0 = none (non-finite or not positive).
fn live_or_zero(d: f32) -> f32 {
    if d.is_finite() && d > 0.0 {
        d
    } else {
        0.0
    }
}

/// A map depth as a surface: metres, +∞ = none.
fn map_or_inf(d: f32) -> f64 {
    if d.is_finite() && d > 0.0 {
        f64::from(d)
    } else {
        f64::INFINITY
    }
}

/// The live depth moved by the registration shift, as returns ([`live_or_zero`]):
/// `zs(q) = live(q − shift)`, 0 where that falls outside.
struct ShiftedLive<'a> {
    live: &'a [f32],
    w: usize,
    h: usize,
    dx: isize,
    dy: isize,
    /// Destination columns `[c0, c1)` read source columns `[c0 − dx, c1 − dx)` ⊂ `[0, w)`.
    c0: usize,
    c1: usize,
}

impl<'a> ShiftedLive<'a> {
    fn new(live: &'a [f32], w: usize, h: usize, [dx, dy]: [i32; 2]) -> Self {
        let dx = dx as isize;
        let c0 = dx.clamp(0, w as isize) as usize;
        let c1 = (w as isize + dx).clamp(0, w as isize) as usize;
        Self { live, w, h, dx, dy: dy as isize, c0, c1 }
    }

    /// Row `r` into `out` (`w` long).
    fn row(&self, r: usize, out: &mut [f32]) {
        let sr = r as isize - self.dy;
        if sr < 0 || sr >= self.h as isize || self.c0 >= self.c1 {
            out.fill(0.0);
            return;
        }
        out[..self.c0].fill(0.0);
        out[self.c1..].fill(0.0);
        let src = &self.live[sr as usize * self.w + (self.c0 as isize - self.dx) as usize..][..self.c1 - self.c0];
        for (o, d) in out[self.c0..self.c1].iter_mut().zip(src) {
            *o = live_or_zero(*d);
        }
    }

    /// Pixel (c, r).
    fn at(&self, r: usize, c: usize) -> f32 {
        let sr = r as isize - self.dy;
        if sr < 0 || sr >= self.h as isize || c < self.c0 || c >= self.c1 {
            return 0.0;
        }
        live_or_zero(self.live[sr as usize * self.w + (c as isize - self.dx) as usize])
    }
}

/// A return seen along a row or column: its row or column and depth; depth 0 = none.
type Return = (u32, f32);

const NO_RETURN: Return = (0, 0.0);

/// A pixel without a return, and the nearest and farthest (unscaled) depth among its nearest
/// returns; (∞, −∞) while there is none.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Hole {
    col: u32,
    lo: f32,
    hi: f32,
}

impl Hole {
    /// Take a return in when it is within `reach` of position `k`.
    fn put(&mut self, (at, d): Return, k: usize, reach: usize) {
        if d > 0.0 && k.abs_diff(at as usize) <= reach {
            self.lo = self.lo.min(d);
            self.hi = self.hi.max(d);
        }
    }
}

/// The last return of every column above the current row (structure of arrays, so updating a
/// row vectorises).
struct ColumnReturns {
    row: Vec<u32>,
    depth: Vec<f32>,
}

impl ColumnReturns {
    fn new(w: usize) -> Self {
        Self { row: vec![0; w], depth: vec![0.0; w] }
    }

    fn at(&self, c: usize) -> Return {
        (self.row[c], self.depth[c])
    }

    /// Row `r`'s returns become their columns' last.
    fn update(&mut self, r: usize, z: &[f32]) {
        for ((at, depth), d) in self.row.iter_mut().zip(self.depth.iter_mut()).zip(z) {
            let hit = *d > 0.0;
            *at = if hit { r as u32 } else { *at };
            *depth = if hit { *d } else { *depth };
        }
    }
}

/// The first return below a row in every column, found by scanning down the column on demand;
/// rows already scanned are not scanned again, so a column costs at most its height.
struct ColumnNextReturn {
    next: Vec<Return>,
    /// Rows of column c before `scanned[c]` are scanned.
    scanned: Vec<u32>,
}

impl ColumnNextReturn {
    fn new(w: usize) -> Self {
        Self { next: vec![NO_RETURN; w], scanned: vec![0; w] }
    }

    /// The first return of column `c` in rows `r + 1..=r + reach`, or [`NO_RETURN`].
    fn after(&mut self, zs: &ShiftedLive, r: usize, c: usize, reach: usize) -> Return {
        let (at, d) = self.next[c];
        if d > 0.0 && at as usize > r {
            return (at, d);
        }
        let end = (r + reach).min(zs.h - 1);
        for row in (r + 1).max(self.scanned[c] as usize)..=end {
            let d = zs.at(row, c);
            if d > 0.0 {
                self.next[c] = (row as u32, d);
                self.scanned[c] = row as u32 + 1;
                return self.next[c];
            }
        }
        self.next[c] = NO_RETURN;
        self.scanned[c] = self.scanned[c].max(end as u32 + 1);
        NO_RETURN
    }
}

/// The holes of each row with the returns bounding them left, right, above and below within
/// `reach` pixels; rows are asked for top-down.
struct HoleBounds {
    reach: usize,
    above: ColumnReturns,
    below: ColumnNextReturn,
    holes: Vec<Hole>,
}

impl HoleBounds {
    fn new(w: usize, reach: usize) -> Self {
        Self { reach, above: ColumnReturns::new(w), below: ColumnNextReturn::new(w), holes: Vec::with_capacity(w) }
    }

    /// The holes of row `r` (`z`, the row of `zs`), left to right.
    fn row(&mut self, zs: &ShiftedLive, r: usize, z: &[f32]) -> &[Hole] {
        let (w, reach) = (z.len(), self.reach);
        self.holes.clear();
        // Each run of holes [a, b) is bounded by the returns at a − 1 and b.
        let mut c = 0;
        while let Some(a) = z[c..].iter().position(|d| *d <= 0.0).map(|k| c + k) {
            let b = z[a..].iter().position(|d| *d > 0.0).map_or(w, |k| a + k);
            let left = if a > 0 { ((a - 1) as u32, z[a - 1]) } else { NO_RETURN };
            let right = if b < w { (b as u32, z[b]) } else { NO_RETURN };
            for col in a..b {
                let mut hole = Hole { col: col as u32, lo: f32::INFINITY, hi: f32::NEG_INFINITY };
                hole.put(left, col, reach);
                hole.put(right, col, reach);
                hole.put(self.above.at(col), r, reach);
                hole.put(self.below.after(zs, r, col, reach), r, reach);
                self.holes.push(hole);
            }
            c = b;
        }
        self.above.update(r, z);
        &self.holes
    }
}

/// Rows `r − 1`, `r`, `r + 1` of the map's depth (empty outside the image).
struct MapRows<'a> {
    above: &'a [f32],
    this: &'a [f32],
    below: &'a [f32],
    r: usize,
    h: usize,
}

impl MapRows<'_> {
    /// The map depth at column `c` of row `r + dr` ([`map_or_inf`]).
    fn at(&self, c: usize, dr: i32) -> f64 {
        let row = match dr {
            -1 => self.above,
            0 => self.this,
            _ => self.below,
        };
        map_or_inf(row[c])
    }
}

/// Steps 3 and 4 of the fusion for one row.
struct RowFusion<'a> {
    camera: &'a PinholeCamera,
    scale: f64,
    band: f64,
    /// Focal length × baseline: the disparity of depth z is `fb / z` pixels.
    fb: f64,
    cos_grazing: f64,
    shadow_slack_px: f64,
}

impl RowFusion<'_> {
    /// Fuse one row (unscaled shifted live depth `z`, its holes with all four bounds, left to
    /// right) into `out`; returns how many map surfaces in its holes were dropped.
    fn fuse(&self, map: &MapRows, z: &[f32], holes: &[Hole], out: &mut [f32]) -> usize {
        let (w, scale, band) = (z.len(), self.scale, self.band);
        // Pixels with a return: the map clamped into live ± band (branch-free, vectorised; the
        // holes are overwritten below).
        for ((o, d), m) in out.iter_mut().zip(z).zip(map.this) {
            let zf = f64::from(*d) * scale;
            let fused = map_or_inf(*m).max(zf - band).min(zf + band);
            *o = if *d > 0.0 && fused.is_finite() { fused as f32 } else { 0.0 };
        }
        // Holes, right to left, carrying the smallest right-imager column of the returns to the
        // right (all pixels between two holes are returns).
        let mut right_min = f64::INFINITY;
        let mut end = w;
        let mut dropped_px = 0;
        for hole in holes.iter().rev() {
            let c = hole.col as usize;
            for (k, d) in z[c + 1..end].iter().enumerate() {
                right_min = right_min.min((c + 1 + k) as f64 + 0.5 - self.fb / (f64::from(*d) * scale));
            }
            end = c;
            let m = map.at(c, 0);
            let (lo, hi) = (f64::from(hole.lo) * scale, f64::from(hole.hi) * scale);
            let seen = m.is_finite()
                && right_min >= c as f64 + 0.5 - self.fb / m - self.shadow_slack_px
                && facing_cos(map, self.camera, w, c).is_some_and(|cos| cos > self.cos_grazing);
            let fused = if seen {
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
            out[c] = if fused.is_finite() { fused as f32 } else { 0.0 };
        }
        dropped_px
    }
}

/// Hide the visible pixels ([`COVER_VISIBLE`]) of `mask` (row-major, `width` wide) that belong to
/// 8-connected visible components of fewer than `min_px` pixels; returns how many were hidden.
pub fn remove_specks(mask: &mut [u8], width: usize, min_px: usize) -> usize {
    if min_px <= 1 || width == 0 {
        return 0;
    }
    // Pixels of a component being kept are marked in place (no visited image); only the rows
    // between the first and the last with a visible pixel are walked.
    const KEPT: u8 = COVER_VISIBLE | 0x80;
    let h = mask.len() / width;
    let has_visible = |r: &usize| mask[r * width..(r + 1) * width].contains(&COVER_VISIBLE);
    let Some(first) = (0..h).find(has_visible) else { return 0 };
    let last = (first..h).rev().find(has_visible).unwrap_or(first);
    let rows = first * width..(last + 1) * width;
    let mut hidden = 0;
    let mut component = Vec::new();
    for start in rows.clone() {
        if mask[start] != COVER_VISIBLE {
            continue;
        }
        mask[start] = KEPT;
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
                if mask[j] == COVER_VISIBLE {
                    mask[j] = KEPT;
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
    for m in &mut mask[rows] {
        if *m == KEPT {
            *m = COVER_VISIBLE;
        }
    }
    hidden
}

/// The shift `(dx, dy)` maximising the mean grey gradient at the live silhouettes moved by it;
/// ties go to the smaller shift. No silhouettes → no shift.
fn registration_shift(live: &[f32], grey: &GreyImage, w: usize, h: usize, config: &LiveDepthConfig) -> [i32; 2] {
    let s = config.max_shift_px as usize;
    if w <= 2 * s + 2 || h <= 2 * s + 2 {
        return [0, 0];
    }
    let edges = silhouettes(live, w, h, s, config.edge_jump_m);
    if edges.is_empty() {
        return [0, 0];
    }
    // Every shift's score at once: each silhouette pixel adds its (2s + 1)² window of grey
    // gradients. The terms are f32 and the sums f64, so every sum is exact (below 2^27 in total):
    // equal scores tie. The gradient rows live in a ring of 2s + 1 rows, computed as the
    // silhouettes (in row order) reach them.
    let n = 2 * s + 1;
    let mut score = vec![0.0f64; n * n];
    let mut ring = vec![0.0f32; n * w];
    let mut next_row = 0;
    for &(c, r) in &edges {
        for y in next_row.max(r - s)..=r + s {
            gradient_row(&grey.data, w, h, y, &mut ring[(y % n) * w..(y % n + 1) * w]);
        }
        next_row = next_row.max(r + s + 1);
        for (dy, acc) in score.chunks_exact_mut(n).enumerate() {
            let y = r + dy - s;
            let window = &ring[(y % n) * w + c - s..][..n];
            for (a, g) in acc.iter_mut().zip(window) {
                *a += f64::from(*g);
            }
        }
    }
    let si = s as i32;
    let mut shifts: Vec<[i32; 2]> = (-si..=si).flat_map(|dy| (-si..=si).map(move |dx| [dx, dy])).collect();
    shifts.sort_by_key(|[dx, dy]| (dx * dx + dy * dy, *dy, *dx));
    let mut best = (f64::NEG_INFINITY, [0, 0]);
    for [dx, dy] in shifts {
        let v = score[(dy + si) as usize * n + (dx + si) as usize];
        if v > best.0 {
            best = (v, [dx, dy]);
        }
    }
    best.1
}

/// The silhouette pixels `(column, row)` of a live depth image, in row-major order: both pixels
/// of every jump above `edge_jump_m` between returns ([`live_or_zero`]) from a pixel at least
/// `margin` from the border (rows and columns `margin..len − margin − 1`) to its right or lower
/// neighbour. Both pixels count, so the registration is not biased by half a pixel.
fn silhouettes(live: &[f32], w: usize, h: usize, margin: usize, edge_jump_m: f64) -> Vec<(usize, usize)> {
    let jump = |a: f32, b: f32| {
        let valid = |d: f32| (d > 0.0) & (d < f32::INFINITY);
        valid(a) & valid(b) & ((f64::from(a) - f64::from(b)).abs() > edge_jump_m)
    };
    let (c0, c1) = (margin, w - margin - 1);
    let mut edges = Vec::new();
    // right[c + 1]: jump between columns c and c + 1 of this row; down[c]: between this row and
    // the next; down_into[c]: between the previous row and this one.
    let mut right = vec![false; w + 1];
    let (mut down, mut down_into) = (vec![false; w], vec![false; w]);
    for r in margin..h - margin {
        if r < h - margin - 1 {
            let (row, below) = (&live[r * w..(r + 1) * w], &live[(r + 1) * w..(r + 2) * w]);
            for c in c0..c1 {
                right[c + 1] = jump(row[c], row[c + 1]);
                down[c] = jump(row[c], below[c]);
            }
        } else {
            right.fill(false);
            down.fill(false);
        }
        for c in 0..w {
            if down_into[c] | right[c] | right[c + 1] | down[c] {
                edges.push((c, r));
            }
        }
        std::mem::swap(&mut down, &mut down_into);
    }
    edges
}

/// Row `y` of the grey image's gradient magnitude (central differences), zero on the border.
fn gradient_row(grey: &[u8], w: usize, h: usize, y: usize, out: &mut [f32]) {
    out.fill(0.0);
    if y == 0 || y + 1 >= h {
        return;
    }
    let (up, row, down) = (&grey[(y - 1) * w..y * w], &grey[y * w..(y + 1) * w], &grey[(y + 1) * w..(y + 2) * w]);
    for c in 1..w - 1 {
        let gx = i32::from(row[c + 1]) - i32::from(row[c - 1]);
        let gy = i32::from(down[c]) - i32::from(up[c]);
        out[c] = ((gx * gx + gy * gy) as f32).sqrt();
    }
}

/// Median of map / live over the pixels where both have a surface within [`SCALE_AGREE`] of each
/// other (the ratio in f64); 1 with fewer than [`MIN_SCALE_PX`] such pixels.
///
/// Exact, without sorting the ratios: a histogram of their f32 approximations (bins of
/// `2 · SCALE_AGREE / SCALE_BINS`, over 100 times the approximation's error) finds the bin that
/// holds the median, and the median is selected among the exact ratios of that bin and its two
/// neighbours; the ratios of lower bins are smaller and those of higher bins larger.
fn depth_scale(zs: &ShiftedLive, zm: &[f32]) -> f64 {
    // Bin keys: key k ≥ 0 holds approximate ratios within δ/2 of (1 − SCALE_AGREE) + (k − 1)·δ,
    // so keys 1 and SCALE_BINS + 1 hold the bounds of the agreement interval; keys 0, 1,
    // SCALE_BINS + 1 and SCALE_BINS + 2 hold ratios near a bound (their membership is decided
    // exactly); -1 and SCALE_BINS + 3 stand for "not in".
    const KEYS: i32 = SCALE_BINS as i32 + 3;
    // Adding 1.5 · 2^23 rounds an f32 below 2^22 in magnitude to an integer in the low mantissa
    // bits: a float-to-integer conversion that vectorises.
    const ROUND: f32 = 12_582_912.0;
    let per_bin = (SCALE_BINS as f64 / (2.0 * SCALE_AGREE)) as f32;
    let origin = (1.0 - SCALE_AGREE - 2.0 * SCALE_AGREE / SCALE_BINS as f64) as f32;
    let exact = |s: f32, m: f32| {
        let q = f64::from(m) / f64::from(s);
        ((q - 1.0).abs() < SCALE_AGREE).then_some(q)
    };
    let w = zs.w;
    let (mut z, mut keys) = (vec![0.0f32; w], vec![0i32; w]);
    // Row r's live depth into `z` and its keys into `keys`, branch-free (vectorised).
    let row_keys = |r: usize, z: &mut [f32], keys: &mut [i32]| {
        zs.row(r, z);
        for ((s, m), k) in z.iter().zip(&zm[r * w..(r + 1) * w]).zip(keys.iter_mut()) {
            let both = (*s > 0.0) & (*m > 0.0) & (*m < f32::INFINITY);
            let key = ((m / s - origin) * per_bin).clamp(-1.0, KEYS as f32);
            let key = if both { key } else { -1.0 };
            *k = (key + ROUND).to_bits() as i32 - ROUND.to_bits() as i32;
        }
    };
    let near_bound = |k: i32| (0..=1).contains(&k) || (KEYS - 2..KEYS).contains(&k);
    let mut counts = vec![0usize; KEYS as usize + 2];
    for r in 0..zs.h {
        row_keys(r, &mut z, &mut keys);
        for ((k, s), m) in keys.iter().zip(&z).zip(&zm[r * w..(r + 1) * w]) {
            if near_bound(*k) && exact(*s, *m).is_none() {
                continue;
            }
            counts[(k + 1) as usize] += 1;
        }
    }
    // counts[0] and counts[KEYS + 1]: not in.
    let in_range = &counts[1..=KEYS as usize];
    let total: usize = in_range.iter().sum();
    if total < MIN_SCALE_PX {
        return 1.0;
    }
    let (mut rank, mut b) = (total / 2, 0);
    while in_range[b] <= rank {
        rank -= in_range[b];
        b += 1;
    }
    // The median is among the exact ratios of keys b − 1..=b + 1, after those of key b − 1.
    let first = b.saturating_sub(1);
    let rank = rank + in_range[first..b].iter().sum::<usize>();
    let (lo_key, span) = (first as i32, (b + 1 - first) as u32);
    let mut candidates: Vec<f64> = Vec::new();
    for r in 0..zs.h {
        row_keys(r, &mut z, &mut keys);
        for ((k, s), m) in keys.iter().zip(&z).zip(&zm[r * w..(r + 1) * w]) {
            if (k - lo_key) as u32 <= span {
                candidates.extend(exact(*s, *m));
            }
        }
    }
    *candidates.select_nth_unstable_by(rank, f64::total_cmp).1
}

/// Histogram bins of [`depth_scale`] over the agreement interval.
const SCALE_BINS: usize = 4096;

/// Relative agreement of map and live depth for the scale fit: 3 %.
const SCALE_AGREE: f64 = 0.03;

/// Fewest agreeing pixels for a depth-scale fit.
const MIN_SCALE_PX: usize = 100;

/// |cos| of the angle between pixel (c, r)'s ray and the surface normal of the map depth there
/// (central differences of back-projected points); `None` on the border, next to a missing
/// pixel, or across a depth jump (a silhouette).
fn facing_cos(map: &MapRows, cam: &PinholeCamera, w: usize, c: usize) -> Option<f64> {
    let r = map.r;
    if c == 0 || r == 0 || c + 1 >= w || r + 1 >= map.h {
        return None;
    }
    let z0 = map.at(c, 0);
    let point = |c: usize, dr: i32| {
        let d = map.at(c, dr);
        (d.is_finite() && (d - z0).abs() <= SILHOUETTE_JUMP_M + SILHOUETTE_JUMP_REL * z0).then(|| {
            let v = (r as f64 + f64::from(dr) + 0.5 - cam.cy) / cam.fy;
            nalgebra::Vector3::new((c as f64 + 0.5 - cam.cx) / cam.fx * d, v * d, d)
        })
    };
    let du = point(c + 1, 0)? - point(c - 1, 0)?;
    let dv = point(c, 1)? - point(c, -1)?;
    let n = du.cross(&dv);
    let p = point(c, 0)?;
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
        let f = fuse_live_depth(&cam(), map.clone(), &live, None, &no_shift_no_scale()).unwrap();
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
        let f = fuse_live_depth(&cam(), map.clone(), &live, None, &wide).unwrap();
        assert!((at(&f.depth, 32, 20) - 1.0).abs() < 1e-6);
        assert!((at(&f.depth, 36, 20) - 1.006).abs() < 1e-6, "{}", at(&f.depth, 36, 20));
        // Dropped: columns 35..40 (column 34 has no normal: its left neighbour is across a jump).
        assert_eq!(f.summary.dropped_px, 5 * inner_rows);
        assert_eq!(f.summary.holes_px, 10 * H as usize);
        // A 5 cm baseline: a 2.5 px shadow, so the wall in the hole would have been seen too; with
        // no return behind it, it is no surface.
        let f = fuse_live_depth(&cam(), map.clone(), &live, None, &no_shift_no_scale()).unwrap();
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
        let f = fuse_live_depth(&cam(), map.clone(), &live, Some(&grey), &config).unwrap();
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
        let mut live = vec![0.0; w * h];
        live[w] = 1.0;
        live[w + 4] = 3.0;
        live[3 * w + 2] = 2.0;
        let zs = ShiftedLive::new(&live, w, h, [0, 0]);
        let mut bounds = HoleBounds::new(w, 2);
        let mut z = vec![0.0; w];
        let rows: Vec<Vec<Hole>> = (0..h)
            .map(|r| {
                zs.row(r, &mut z);
                bounds.row(&zs, r, &z).to_vec()
            })
            .collect();
        assert_eq!(rows.iter().map(Vec::len).collect::<Vec<_>>(), [5, 3, 5, 4]);
        let at = |c: u32, r: usize| {
            let hole = rows[r].iter().find(|hole| hole.col == c).unwrap();
            (hole.lo, hole.hi)
        };
        assert_eq!(at(2, 1), (1.0, 3.0)); // left and right, 2 px each
        assert_eq!(at(1, 1), (1.0, 1.0)); // the right return is 3 px away
        assert_eq!(at(2, 0), (f32::INFINITY, f32::NEG_INFINITY)); // (2, 3) is 3 rows below
        assert_eq!(at(2, 2), (2.0, 2.0)); // below
        assert_eq!(at(0, 2), (1.0, 1.0)); // above
        assert_eq!(at(4, 3), (2.0, 3.0)); // left, and above at 2 rows
        assert!(rows[3].iter().all(|hole| hole.col != 2)); // a return is no hole
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
        assert!(matches!(fuse_live_depth(&cam(), ok.clone(), &small, None, &cfg), Err(ArError::ImageSize { .. })));
        let bad_band = LiveDepthConfig { band_m: f64::NAN, ..cfg };
        let e = fuse_live_depth(&cam(), ok.clone(), &ok, None, &bad_band).unwrap_err();
        assert!(e.to_string().contains("live.band_m"), "{e}");
    }
}
