//! The camera images of a recording: encoding (JPEG colour, 16-bit PNG depth) and logging, on the
//! calling thread or on the recorder's encoder thread ([`Encoder`]), which also logs the arm's
//! link poses.
//!
//! The encoder thread takes each job with the time it was logged at (`frame`, `sim_time`), sets
//! that time on its own timelines (Rerun's time is per thread) and runs it, in the order the jobs
//! were handed over. The hand-over queue is bounded ([`QUEUE`] jobs): a caller that gets ahead of
//! the encoder waits. [`Encoder::finish`] waits until every image handed over is logged;
//! dropping the encoder does the same before the thread ends.

use std::sync::mpsc::{sync_channel, Receiver, SyncSender};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;

use rerun::RecordingStream;

use super::{RecordError, RecordOptions};

/// Jobs the encoder thread holds at most beside the one it works on.
pub(crate) const QUEUE: usize = 4;

/// Entity paths of the camera images.
const RGB_ENTITY: &str = "world/camera/image/rgb";
const DEPTH_ENTITY: &str = "world/camera/image/depth";

/// A camera image to log, its size checked.
pub(crate) enum Image {
    /// RGB, row-major, 3 bytes a pixel.
    Rgb { width: u32, height: u32, data: Vec<u8> },
    /// Depth in metres, row-major.
    Depth { width: u32, height: u32, data: Vec<f32> },
}

/// The time of a log call: frame index and simulated seconds (None: no time set).
pub(crate) type Time = Option<(u32, f64)>;

/// Logging work handed to the encoder thread.
pub(crate) type Work = Box<dyn FnOnce(&RecordingStream, &RecordOptions) -> Result<(), RecordError> + Send>;

enum Job {
    Log(Time, Work),
    /// Reply once every job before it is done.
    Finish(SyncSender<()>),
}

/// The recorder's encoder thread.
pub(crate) struct Encoder {
    jobs: Option<SyncSender<Job>>,
    worker: Option<JoinHandle<()>>,
    /// The first error of a job, reported by the next [`Self::take_error`].
    failed: Arc<Mutex<Option<RecordError>>>,
}

fn stopped() -> RecordError {
    RecordError::Log { entity: "<encoder>".into(), reason: "the encoder thread stopped".into() }
}

impl Encoder {
    /// Starts the thread, logging into `stream` with `options`' encoding.
    pub(crate) fn start(stream: RecordingStream, options: RecordOptions) -> Result<Self, RecordError> {
        let (jobs, rx) = sync_channel::<Job>(QUEUE);
        let failed = Arc::new(Mutex::new(None));
        let sink = Arc::clone(&failed);
        let worker = std::thread::Builder::new()
            .name("objslam-record-encoder".into())
            .spawn(move || run(&stream, &options, &rx, &sink))
            .map_err(|e| RecordError::Log { entity: "<encoder>".into(), reason: e.to_string() })?;
        Ok(Self { jobs: Some(jobs), worker: Some(worker), failed })
    }

    /// Hands `work` over, to be run at `time`; waits while the queue is full.
    pub(crate) fn log(&self, time: Time, work: Work) -> Result<(), RecordError> {
        self.take_error()?;
        let jobs = self.jobs.as_ref().ok_or_else(stopped)?;
        jobs.send(Job::Log(time, work)).map_err(|_| stopped())
    }

    /// Waits until every job handed over is done; the first error of any of them.
    pub(crate) fn finish(&self) -> Result<(), RecordError> {
        let jobs = self.jobs.as_ref().ok_or_else(stopped)?;
        let (done, wait) = sync_channel(1);
        jobs.send(Job::Finish(done)).map_err(|_| stopped())?;
        wait.recv().map_err(|_| stopped())?;
        self.take_error()
    }

    /// The first error of a job since the last call, if any.
    pub(crate) fn take_error(&self) -> Result<(), RecordError> {
        match self.failed.lock().unwrap_or_else(|e| e.into_inner()).take() {
            Some(e) => Err(e),
            None => Ok(()),
        }
    }
}

impl Drop for Encoder {
    /// Runs every job handed over, then ends the thread.
    fn drop(&mut self) {
        drop(self.jobs.take());
        if let Some(worker) = self.worker.take() {
            let _ = worker.join();
        }
    }
}

fn run(stream: &RecordingStream, options: &RecordOptions, rx: &Receiver<Job>, failed: &Mutex<Option<RecordError>>) {
    for job in rx {
        match job {
            Job::Log(time, work) => {
                match time {
                    Some((frame, sim_time_s)) => {
                        stream.set_time_sequence("frame", i64::from(frame));
                        stream.set_duration_secs("sim_time", sim_time_s);
                    }
                    None => stream.reset_time(),
                }
                if let Err(e) = work(stream, options) {
                    failed.lock().unwrap_or_else(|e| e.into_inner()).get_or_insert(e);
                }
            }
            Job::Finish(done) => {
                let _ = done.send(());
            }
        }
    }
}

/// Encodes `image` as `options` say and logs it at the calling thread's time.
pub(crate) fn log_image(stream: &RecordingStream, options: &RecordOptions, image: Image) -> Result<(), RecordError> {
    let log = |entity: &str, value: &dyn rerun::AsComponents| {
        stream.log(entity, value).map_err(|e| RecordError::Log { entity: entity.into(), reason: e.to_string() })
    };
    match image {
        Image::Rgb { width, height, data } if options.jpeg_quality == 0 => {
            log(RGB_ENTITY, &rerun::Image::from_rgb24(data, [width, height]))
        }
        Image::Rgb { width, height, data } => {
            let jpeg = rgb_jpeg(width, height, &data, options.jpeg_quality)?;
            log(RGB_ENTITY, &rerun::EncodedImage::from_file_contents(jpeg).with_media_type(rerun::MediaType::jpeg()))
        }
        Image::Depth { width, height, data } if options.depth_png => {
            let png = depth_png_mm(width, height, &data)?;
            log(
                DEPTH_ENTITY,
                &rerun::EncodedDepthImage::from_file_contents(png).with_media_type(rerun::MediaType::png()),
            )
        }
        Image::Depth { width, height, data } => {
            let bytes: Vec<u8> = data.iter().flat_map(|d| d.to_le_bytes()).collect();
            log(
                DEPTH_ENTITY,
                &rerun::DepthImage::from_data_type_and_bytes(bytes, [width, height], rerun::ChannelDatatype::F32)
                    .with_meter(1.0),
            )
        }
    }
}

/// An RGB image (3 bytes a pixel) as a baseline JPEG at `quality` (1-100).
pub(crate) fn rgb_jpeg(width: u32, height: u32, rgb: &[u8], quality: u8) -> Result<Vec<u8>, RecordError> {
    let too_large = || RecordError::Encode { field: "rgb", reason: format!("{width} x {height} exceeds JPEG's 65535") };
    let (w, h) = (u16::try_from(width).map_err(|_| too_large())?, u16::try_from(height).map_err(|_| too_large())?);
    let mut jpeg = Vec::with_capacity(rgb.len() / 10);
    jpeg_encoder::Encoder::new(&mut jpeg, quality)
        .encode(rgb, w, h, jpeg_encoder::ColorType::Rgb)
        .map_err(|e| RecordError::Encode { field: "rgb", reason: e.to_string() })?;
    Ok(jpeg)
}

/// Depth in metres → a 16-bit greyscale PNG in millimetres (0 = no return).
pub(crate) fn depth_png_mm(width: u32, height: u32, depth_m: &[f32]) -> Result<Vec<u8>, RecordError> {
    let mm: Vec<u8> = depth_m
        .iter()
        .map(|&d| {
            let v = f64::from(d) * 1000.0;
            if v.is_finite() && v > 0.0 && v <= f64::from(u16::MAX) {
                v.round() as u16
            } else {
                0
            }
        })
        .flat_map(u16::to_ne_bytes)
        .collect();
    let mut png = Vec::with_capacity(mm.len() / 3);
    image::ImageEncoder::write_image(
        image::codecs::png::PngEncoder::new_with_quality(
            &mut png,
            // The fast deflate with the left-neighbour filter: depth rows are smooth, and the
            // default level with adaptive filtering cost about as much as a rendered frame.
            image::codecs::png::CompressionType::Fast,
            image::codecs::png::FilterType::Sub,
        ),
        &mm,
        width,
        height,
        image::ExtendedColorType::L16,
    )
    .map_err(|e| RecordError::Encode { field: "depth", reason: e.to_string() })?;
    Ok(png)
}
