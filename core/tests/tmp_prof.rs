use objslam_core::frame::GreyImage;
#[test]
fn prof() {
    let bytes = std::fs::read(concat!(env!("CARGO_MANIFEST_DIR"), "/tests/fixtures/lsd/frame0.pgm")).unwrap();
    let n = 640 * 480;
    let img = GreyImage::new(640, 480, bytes[bytes.len() - n..].to_vec()).unwrap();
    let cfg = objslam_core::objects::lsd::LsdConfig::default();
    for _ in 0..3 {
        let t = std::time::Instant::now();
        let s = objslam_core::objects::lsd::detect_segments(&img, &cfg).unwrap();
        let a = t.elapsed();
        let t = std::time::Instant::now();
        let small: Vec<f64> = (0..512 * 384).map(|i| img.data[(i / 512) * 640 * 5 / 4 * 0 + i % 512 + (i / 512) * 640] as f64).collect();
        let b0 = t.elapsed();
        let t = std::time::Instant::now();
        let s2 = lsdetect::detect(&small, 512, 384, 1.0).unwrap();
        let b = t.elapsed();
        let t = std::time::Instant::now();
        let s3 = lsdetect::detect(&img.data, 640, 480, 0.8).unwrap();
        let c = t.elapsed();
        eprintln!("ours {a:?} ({}), conv {b0:?} lsdetect@1 {b:?} ({}) lsdetect@0.8 {c:?} ({})", s.len(), s2.len(), s3.len());
    }
}
