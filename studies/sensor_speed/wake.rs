//! Spawn-to-run latency of a second thread after the process slept: on this 2-vCPU VM an idle
//! vCPU takes milliseconds to wake. `rustc -O wake.rs && ./wake`.

/// Main-thread work while the spawned thread is woken, milliseconds.
const WORK_MS: u64 = 10;

use std::time::{Duration, Instant};
fn main() {
    for sleep_ms in [0u64, 1, 5, 20, 50] {
        let mut lat = vec![];
        for _ in 0..20 {
            std::thread::sleep(Duration::from_millis(sleep_ms));
            let t0 = Instant::now();
            let started = std::thread::scope(|s| {
                let h = s.spawn(|| Instant::now());
                // main does 1 ms of work meanwhile
                let mut x = 0u64; while t0.elapsed() < Duration::from_millis(WORK_MS) { x = x.wrapping_add(1); }
                std::hint::black_box(x);
                h.join().unwrap()
            });
            lat.push((started - t0).as_secs_f64() * 1e3);
        }
        lat.sort_by(f64::total_cmp);
        println!("sleep {sleep_ms} ms: spawn->run median {:.3} ms, max {:.3}", lat[10], lat[19]);
    }
}
