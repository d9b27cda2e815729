//! Fixed-work timing of the tracker and the ORB extractor, for whole-process CPU comparisons of
//! two builds (criterion runs for a time budget, not a fixed amount of work).
//!
//! `cargo build --release -p objslam-core --example fixed_work`, then time
//! `target/release/examples/fixed_work track 400` (400 `Tracker::track` calls on the
//! `track_frame` bench's sequence, `slam::synthetic::TrackSequence`, after ray-casting its 20
//! frames, about 0.4 s), `... orb 600` (600 extractions of the `orb_extract_640x480` bench
//! frames) or `... sensor 150` (150 frames of the `sensor_model_640x480` bench,
//! `sensor::synthetic::TiltedTable`; `sensor-roll`: the same frames with the `_rolling` bench's
//! motion). Prints a checksum (inliers, keypoints, or a hash of every depth and colour value) so
//! two builds' work can be compared too.

use anyhow::{anyhow, bail, Result};
use objslam_core::sensor::synthetic::TiltedTable;
use objslam_core::sensor::{simulate_frame, SensorConfig, SensorUnit};
use objslam_core::slam::synthetic::{shapes_texture, TrackSequence};
use objslam_core::slam::{OrbConfig, OrbExtractor, Tracker, TrackerConfig};

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let usage = || anyhow!("usage: fixed_work (track | orb | sensor | sensor-roll) <count>");
    let n: usize = args.get(2).ok_or_else(usage)?.parse().map_err(|_| usage())?;
    match args.get(1).map(String::as_str) {
        Some("orb") => {
            let frames: Vec<_> = (0..8).map(|s| shapes_texture(640, 480, s)).collect();
            let mut orb = OrbExtractor::new(OrbConfig::default())?;
            let mut acc = 0;
            for i in 0..n {
                acc += orb.extract(&frames[i % frames.len()])?.keypoints.len();
            }
            println!("{acc}");
        }
        Some("track") => {
            let seq = TrackSequence::new()?;
            let mut tracker = Tracker::new(TrackerConfig::default())?;
            let t0 = std::time::Instant::now();
            let mut acc = 0;
            for step in 0..n {
                acc += tracker.track(&seq.input(step))?.n_inliers;
            }
            println!("{acc} {:.3} ms/frame", t0.elapsed().as_secs_f64() * 1e3 / n.max(1) as f64);
        }
        Some(which @ ("sensor" | "sensor-roll")) => {
            let cfg = SensorConfig::default();
            let scene = TiltedTable::new();
            let unit = SensorUnit::draw(&cfg, scene.intrinsics, 3)?;
            let motion = match which {
                "sensor" => TiltedTable::motion(cfg.colour.exposure_s),
                _ => TiltedTable::rolling_motion(cfg.colour.exposure_s),
            };
            let mut hash = 0u64;
            for i in 0..n as u64 {
                let out = simulate_frame(&cfg, &unit, &scene.frame(), Some(&motion), 7, i)?;
                let values =
                    out.depth_m.iter().map(|v| u64::from(v.to_bits())).chain(out.rgb.iter().map(|&v| u64::from(v)));
                hash = values.fold(hash, |h, v| h.wrapping_mul(31).wrapping_add(v));
            }
            println!("{hash:x}");
        }
        _ => bail!(usage()),
    }
    Ok(())
}
