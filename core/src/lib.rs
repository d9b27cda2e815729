//! objslam core: the brain of the object-SLAM active-mapping testbed.
//!
//! The simulator (Python, SAPIEN) senses and acts; this crate updates beliefs and decides. Data
//! flows one way per frame (see `ARCHITECTURE.md`): a [`frame::Frame`] (image, depth, intrinsics,
//! camera pose, detections) goes in; the [`map::ObjectMap`] comes out; [`eval`] scores it against
//! ground truth that never enters the estimator.
//!
//! Modules, one concept each:
//! - [`active`]: the exploration session: Init views, grid updates, next view per strategy.
//! - [`ar`]: augmented reality on the object map: registration, occlusion, collision, picking.
//! - [`association`]: ensemble object data association (M-IoU, Mann-Whitney, t-tests, P-IoU,
//!   duplicate merge) and association metrics.
//! - [`geometry`]: SE(3), pinhole camera, 2D boxes, yaw-oriented boxes and cylinders, IoUs.
//! - [`frame`]: sensor frames and detections, validated at the boundary.
//! - [`map`]: the object map, labels, versioned save/load.
//! - [`naive`]: the foundation's baseline estimator (the `naive` association ablation).
//! - [`explore`]: surface occupancy grids, ray-cast visibility, the next-best-view utility,
//!   candidate views and exploration baselines.
//! - [`objects`]: object parameterization: iForest centroid/scale, LSD segments, line-alignment yaw,
//!   joint yaw/scale refinement, class → model (paper Sec. "Object parameterization").
//! - [`eval`]: matching to ground truth, 3D/2D IoU, CDE, YAE, counts.
//! - [`pipeline`]: association (naive or ensemble modes) + parameterization → the object map.
//! - [`plan`]: Panda kinematics, collision checking, RRT-Connect, Ruckig trajectories, grasps.
//! - [`topo`]: semantic topological map, random-walk descriptors, scene matching, relocalisation.
//! - `record` (feature `rerun`): one Rerun recording per run.
//! - [`sensor`]: the RGB-D camera model (D435-class active-stereo depth, colour noise and blur,
//!   calibration errors) the simulator applies to rendered frames.
//! - [`slam`]: RGB-D visual tracking (ORB features, PnP + RANSAC, local BA), pose sources, ATE/RPE.
//! - [`system`]: the per-frame loop (tracking → gauge → pipeline → grids) and the session's
//!   decisions behind one type, [`system::System`].

pub mod active;
pub mod ar;
pub mod association;
pub mod eval;
pub mod explore;
pub mod frame;
pub mod geometry;
pub mod map;
pub mod naive;
pub mod objects;
pub mod pipeline;
pub mod plan;
#[cfg(feature = "rerun")]
pub mod record;
pub mod sensor;
pub mod slam;
pub mod system;
pub mod topo;

/// Threads one frame's work may use (the sensor model's row parts, line segments beside
/// tracking, the ORB pyramid levels, the projection searches and the local bundle adjustment
/// inside tracking): two where the machine has two cores or more, else one.
pub(crate) fn worker_threads() -> usize {
    static THREADS: std::sync::OnceLock<usize> = std::sync::OnceLock::new();
    *THREADS.get_or_init(|| std::thread::available_parallelism().map_or(1, |n| n.get()).min(2))
}

/// The threads a frame's stages may use now, shared between them: a stage that runs beside
/// tracking (the line segments) holds the second core and hands it back when it ends; the
/// tracker's parallel stages (ORB levels, projection search, each bundle-adjustment pass) read
/// the budget when they start. Every such stage gives the same result on any thread count, so
/// when the budget changes changes only the time.
#[derive(Debug)]
pub struct ThreadBudget {
    now: std::sync::atomic::AtomicUsize,
}

impl ThreadBudget {
    /// A budget of `threads`, clamped to `1..=worker_threads()`.
    pub fn new(threads: usize) -> Self {
        Self { now: std::sync::atomic::AtomicUsize::new(threads.clamp(1, worker_threads())) }
    }

    /// The threads a stage starting now may use.
    pub fn get(&self) -> usize {
        self.now.load(std::sync::atomic::Ordering::Relaxed)
    }

    /// Set the budget (clamped to `1..=worker_threads()`).
    pub fn set(&self, threads: usize) {
        self.now.store(threads.clamp(1, worker_threads()), std::sync::atomic::Ordering::Relaxed);
    }
}

/// Size of the block [`keep_frame_buffers`] allocates and frees: above every per-frame buffer (the
/// largest, LSD's gradient field of a 640 x 480 frame, is 2.4 MB), at most glibc's cap on the
/// dynamic mmap threshold (32 MiB on 64-bit).
const FRAME_BUFFER_THRESHOLD_BYTES: usize = 16 << 20;

/// Keeps the per-frame buffers of a few megabytes (the line detector's gradient field and image
/// copies, the bundle adjustment's blocks) in the process between frames. glibc serves a block
/// above its mmap threshold (128 KiB at start) by `mmap` and unmaps it when freed, so each frame
/// would fault the pages of every such buffer in again (a sixth of a frame's CPU on scene01);
/// freeing one mmapped block of size S raises the threshold to S and the heap's trim threshold to
/// 2 S (mallopt(3), dynamic mmap threshold). This allocates and frees one block of
/// `FRAME_BUFFER_THRESHOLD_BYTES` (16 MiB), once per process ([`system::System::new`] calls it). Other
/// allocators merely see one allocation.
pub fn keep_frame_buffers() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        let block = vec![1u8; FRAME_BUFFER_THRESHOLD_BYTES];
        drop(std::hint::black_box(block));
    });
}

/// Cheap hasher for our own integer keys (map point ids, packed voxel keys): the SplitMix64
/// finaliser, not DoS-resistant. Tables keyed by it are only queried, never iterated, so hash
/// order cannot leak into results.
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct IntKeyHasher(u64);

impl std::hash::Hasher for IntKeyHasher {
    fn finish(&self) -> u64 {
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    fn write(&mut self, bytes: &[u8]) {
        for b in bytes {
            self.0 = self.0.rotate_left(8) ^ u64::from(*b);
        }
    }

    fn write_u64(&mut self, i: u64) {
        self.0 = self.0.rotate_left(21) ^ i;
    }
}

/// The build-hasher of [`IntKeyHasher`] for `HashMap` / `HashSet`.
pub(crate) type IntKeyBuild = std::hash::BuildHasherDefault<IntKeyHasher>;

/// `work(i)` for every `i` in `0..n` on up to `threads` threads, the results in index order: the
/// same as `(0..n).map(work).collect()` for any `threads`. With two or more, the calling thread
/// and one scoped helper take the next index from a shared counter until none is left, so a
/// helper that starts late takes fewer. A panic in either reaches the caller once both stopped.
pub(crate) fn map_indices<T: Send>(threads: usize, n: usize, work: impl Fn(usize) -> T + Sync) -> Vec<T> {
    if threads < 2 || n < 2 {
        return (0..n).map(work).collect();
    }
    let next = std::sync::atomic::AtomicUsize::new(0);
    let take = || {
        let mut done = Vec::new();
        loop {
            let i = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
            if i >= n {
                return done;
            }
            done.push((i, work(i)));
        }
    };
    let (mut done, helper_done) = std::thread::scope(|s| {
        let helper = s.spawn(take);
        let done = take();
        (done, helper.join().unwrap_or_else(|e| std::panic::resume_unwind(e)))
    });
    done.extend(helper_done);
    done.sort_unstable_by_key(|(i, _)| *i);
    done.into_iter().map(|(_, t)| t).collect()
}

#[cfg(test)]
mod tests {
    use super::map_indices;

    #[test]
    fn map_indices_keeps_the_order_on_any_thread_count() {
        let want: Vec<usize> = (0..100).map(|i| i * i).collect();
        for threads in [0, 1, 2, 3] {
            assert_eq!(map_indices(threads, 100, |i| i * i), want);
        }
        assert!(map_indices(2, 0, |i| i).is_empty());
    }

    #[test]
    fn a_panic_in_either_thread_reaches_the_caller() {
        // Index 0 is taken first, by either thread; every index panics in the second case.
        for bad in [0usize, usize::MAX] {
            let r = std::panic::catch_unwind(|| {
                map_indices(2, 64, |i| {
                    assert!(bad != usize::MAX && i != bad, "work {i} failed");
                    i
                })
            });
            assert!(r.is_err());
        }
        // The threads are gone: the next call works.
        assert_eq!(map_indices(2, 3, |i| i), vec![0, 1, 2]);
    }
}
