//! LSD against OpenCV: `objects::lsd::detect_segments` must find at least 90 % of the segments of
//! 30 px or more that `cv2.createLineSegmentDetector()` finds on the same frames, with both
//! endpoints within 2 px (in either order). Fixture: `core/tests/fixtures/make_lsd.py`.

// Test code may unwrap (clippy.toml allows it in #[test] functions; this covers their helpers).
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::PathBuf;

use objslam_core::frame::GreyImage;
use objslam_core::objects::lsd::{detect_segments, LineSegment, LsdConfig};

const LONG_PX: f64 = 30.0;
const ENDPOINT_TOL_PX: f64 = 2.0;
const MIN_RECALL: f64 = 0.9;

fn fixture_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/lsd")
}

/// Read a binary PGM (P5, maxval 255) as written by `make_lsd.py`.
pub fn read_pgm(path: &std::path::Path) -> GreyImage {
    let bytes = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut fields = Vec::new();
    let mut pos = 0;
    while fields.len() < 4 {
        while bytes[pos].is_ascii_whitespace() {
            pos += 1;
        }
        let start = pos;
        while !bytes[pos].is_ascii_whitespace() {
            pos += 1;
        }
        fields.push(String::from_utf8_lossy(&bytes[start..pos]).to_string());
    }
    assert_eq!(fields[0], "P5");
    let w: u32 = fields[1].parse().unwrap();
    let h: u32 = fields[2].parse().unwrap();
    let data = bytes[pos + 1..].to_vec();
    GreyImage::new(w, h, data).unwrap()
}

fn close(p: [f64; 2], q: [f64; 2]) -> bool {
    (p[0] - q[0]).hypot(p[1] - q[1]) <= ENDPOINT_TOL_PX
}

fn matches(r: &LineSegment, s: &LineSegment) -> bool {
    (close(r.a, s.a) && close(r.b, s.b)) || (close(r.a, s.b) && close(r.b, s.a))
}

#[test]
fn lsd_finds_cv2_long_segments() {
    let text = std::fs::read_to_string(fixture_dir().join("lsd_cv2.json")).unwrap();
    let json: serde_json::Value = serde_json::from_str(&text).unwrap();
    let frames = json["frames"].as_array().expect("frames");
    let (mut total, mut found) = (0usize, 0usize);
    for f in frames {
        let file = f["file"].as_str().expect("file");
        let image = read_pgm(&fixture_dir().join(file));
        let ours = detect_segments(&image, &LsdConfig::default()).unwrap();
        let reference: Vec<LineSegment> = f["segments_x1y1x2y2"]
            .as_array()
            .expect("segments")
            .iter()
            .map(|s| {
                let v: Vec<f64> = s.as_array().expect("seg").iter().filter_map(|x| x.as_f64()).collect();
                LineSegment::new([v[0], v[1]], [v[2], v[3]])
            })
            .filter(|s| s.length_px() >= LONG_PX)
            .collect();
        let hit = reference.iter().filter(|r| ours.iter().any(|s| matches(r, s))).count();
        for r in reference.iter().filter(|r| !ours.iter().any(|s| matches(r, s))) {
            let best = ours
                .iter()
                .map(|s| {
                    let d1 = (r.a[0] - s.a[0]).hypot(r.a[1] - s.a[1]).max((r.b[0] - s.b[0]).hypot(r.b[1] - s.b[1]));
                    let d2 = (r.a[0] - s.b[0]).hypot(r.a[1] - s.b[1]).max((r.b[0] - s.a[0]).hypot(r.b[1] - s.a[1]));
                    (d1.min(d2), *s)
                })
                .min_by(|x, y| x.0.total_cmp(&y.0));
            eprintln!("{file}: missed cv2 {r:?} (len {:.1}); nearest ours {best:?}", r.length_px());
        }
        eprintln!("{file}: {hit}/{} long cv2 segments found; ours {} total", reference.len(), ours.len());
        total += reference.len();
        found += hit;
    }
    assert!(total >= 30, "fixture too small: {total} long segments");
    let recall = found as f64 / total as f64;
    assert!(recall >= MIN_RECALL, "recall {recall:.3} < {MIN_RECALL} ({found}/{total})");
}
