//! The work behind the RPC handlers, in the shape of text-embeddings-inference's router:
//!
//! * **admission**: a semaphore of `queue_capacity` photos. A unary call that finds it full
//!   is refused at once (RESOURCE_EXHAUSTED); a stream waits for room (back-pressure).
//! * **per photo, on the CPU pool**: decode (with limits) and find the faces (detection and
//!   landmarks, or the caller's boxes or landmarks).
//! * **one batcher task** owns the face queue. It takes the first waiting face, then
//!   either everything else already queued ("greedy", `max_queue_delay_ms = 0`) or what
//!   arrives within the delay, up to `max_batch_size`; drops faces whose caller went away
//!   or whose deadline passed; and hands the batch, each face with its resolution bucket,
//!   to the backend: the faces that start from the encoder go through it in one pass (their
//!   crops and buckets as one `CropBatch`, across photos), then every face's fit runs in
//!   parallel over the batch on the backend's own threads, so that it never waits behind
//!   queued decode jobs. Only one batch is in the backend at a time, so batches form while
//!   it works.
//! * **per photo, on the CPU pool**: the outputs (meshes, pictures). Pictures are drawn by
//!   the configured [`Draw`]: the CPU rasteriser on the pool thread, or the wgpu renderer
//!   on its own thread, which merges the pictures of concurrent photos into one submission.
//!
//! Work whose caller went away is dropped before it starts: every stage's result goes to a
//! oneshot channel, and a stage whose receiver is gone does not run. Panics in a stage
//! become INTERNAL for that request only.

use std::panic::AssertUnwindSafe;
use std::sync::Arc;
use std::time::{Duration, Instant};

use facerecon_raster::Draw;
use facerecon_recon::{FaceError, FaceRecon, Options, Pipeline, Reconstruction, Refine, Start};
use facerecon_vision::pipeline::Face;
use image::RgbImage;
use rayon::prelude::*;
use tokio::sync::{Semaphore, mpsc, oneshot};
use tonic::Status;

use crate::convert::{self, Wanted};
use crate::metrics as m;
use facerecon_proto::v1 as pb;

/// The pool the CPU stages run on (decode, detect, fit, outputs).
pub type CpuPool = rayon::ThreadPool;

/// A CPU pool of `threads` threads (0: one per core).
pub fn cpu_pool(threads: usize) -> Result<CpuPool, rayon::ThreadPoolBuildError> {
    let threads = match threads {
        0 => std::thread::available_parallelism().map_or(2, |n| n.get()),
        n => n,
    };
    rayon::ThreadPoolBuilder::new().num_threads(threads).thread_name(|i| format!("facerecon-cpu-{i}")).build()
}

/// Batching and capacity settings (from the server configuration).
#[derive(Clone, Copy, Debug)]
pub struct EngineSettings {
    pub max_batch_size: usize,
    /// `None`: greedy.
    pub max_queue_delay: Option<Duration>,
    pub queue_capacity: usize,
}

/// One photo to reconstruct.
pub struct Job {
    pub id: String,
    pub image: Vec<u8>,
    pub options: Options,
    pub wanted: Wanted,
    pub deadline: Option<Instant>,
}

/// One face waiting for the backend.
struct FaceJob {
    image: Arc<RgbImage>,
    face: Face,
    start: Start,
    refine: Refine,
    deadline: Option<Instant>,
    enqueued: Instant,
    reply: oneshot::Sender<FaceRecon>,
}

/// The loaded pipeline, the CPU pool, the admission semaphore and the batcher's queue.
pub struct Engine {
    pipeline: Arc<Pipeline>,
    pool: Arc<rayon::ThreadPool>,
    admission: Arc<Semaphore>,
    /// One per CPU-pool thread (see [`Engine::cpu`]).
    cpu_slots: Semaphore,
    faces: mpsc::UnboundedSender<FaceJob>,
    settings: EngineSettings,
    draw: Arc<dyn Draw>,
}

/// A photo's place in the queue; dropping it frees the place.
pub struct Admitted {
    _permit: tokio::sync::OwnedSemaphorePermit,
}

impl Drop for Admitted {
    fn drop(&mut self) {
        metrics::gauge!(m::QUEUE_DEPTH).decrement(1.0);
    }
}

impl Engine {
    /// Starts the batcher task (on the current tokio runtime) and the backend's threads;
    /// pictures are drawn by `draw`.
    pub fn start(
        pipeline: Arc<Pipeline>,
        pool: Arc<rayon::ThreadPool>,
        settings: EngineSettings,
        draw: Arc<dyn Draw>,
    ) -> Result<Arc<Engine>, rayon::ThreadPoolBuildError> {
        let (tx, rx) = mpsc::unbounded_channel();
        // The face queue is bounded by admission: at most queue_capacity photos of at most
        // max_faces faces each are in the system.
        // The backend has threads of its own, so that a batch never waits behind decode jobs
        // (on the shared pool, a batch's `par_iter` can steal them, tens of ms each).
        let threads = pool.current_num_threads();
        let backend = Arc::new(
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .thread_name(|i| format!("facerecon-fit-{i}"))
                .build()?,
        );
        tokio::spawn(batcher(rx, pipeline.clone(), backend, settings));
        Ok(Arc::new(Engine {
            pipeline,
            pool,
            admission: Arc::new(Semaphore::new(settings.queue_capacity)),
            cpu_slots: Semaphore::new(threads),
            faces: tx,
            settings,
            draw,
        }))
    }

    pub fn pipeline(&self) -> &Arc<Pipeline> {
        &self.pipeline
    }

    /// A place in the queue now, or RESOURCE_EXHAUSTED.
    pub fn try_admit(&self) -> Result<Admitted, Status> {
        match self.admission.clone().try_acquire_owned() {
            Ok(p) => Ok(self.admitted(p)),
            Err(_) => {
                metrics::counter!(m::REJECTED).increment(1);
                Err(Status::resource_exhausted(format!(
                    "server busy: {} photos queued or in work; retry with backoff",
                    self.settings.queue_capacity
                )))
            }
        }
    }

    /// A place in the queue, waiting for one.
    pub async fn admit(&self) -> Admitted {
        let p = self.admission.clone().acquire_owned().await.expect("the admission semaphore is never closed");
        self.admitted(p)
    }

    fn admitted(&self, p: tokio::sync::OwnedSemaphorePermit) -> Admitted {
        metrics::gauge!(m::QUEUE_DEPTH).increment(1.0);
        Admitted { _permit: p }
    }

    /// Whether the loaded pipeline has an encoder (requests may start from it).
    pub fn has_encoder(&self) -> bool {
        self.pipeline.encoder().is_some()
    }

    /// Reconstructs one admitted photo. Deadlines are the caller's to enforce around this
    /// future (dropping it cancels the remaining work); stages also check it.
    pub async fn run(&self, job: Job, _admitted: &Admitted) -> Result<pb::ReconstructResponse, Status> {
        let Job { id, image, options, wanted, deadline } = job;
        let pipeline = self.pipeline.clone();
        let opts = options.clone();
        let (found, waited, decode_detect_s) = self
            .cpu(move || {
                let image = pipeline.decode(&image)?;
                let faces = pipeline.find_faces(&image, &opts)?;
                Ok::<_, facerecon_recon::ReconError>((image, faces))
            })
            .await?;
        let (image, faces) = found.map_err(|e| convert::recon_status(&e))?;
        let mut queue_s = waited;
        metrics::histogram!(m::STAGE_SECONDS, "stage" => "decode_detect").record(decode_detect_s);
        metrics::histogram!(m::FACES_PER_IMAGE).record(faces.len() as f64);
        check_deadline(deadline)?;

        let t = Instant::now();
        let image = Arc::new(image);
        let mut replies = Vec::with_capacity(faces.len());
        for face in faces {
            let (tx, rx) = oneshot::channel();
            let job = FaceJob {
                image: image.clone(),
                face,
                start: options.start,
                refine: options.refine,
                deadline,
                enqueued: Instant::now(),
                reply: tx,
            };
            self.faces.send(job).map_err(|_| Status::unavailable("the server is shutting down"))?;
            replies.push(rx);
        }
        let mut recons = Vec::with_capacity(replies.len());
        for rx in replies {
            // The batcher drops a face whose deadline passed, and a failed (panicked) batch
            // drops its senders: either closes the channel.
            recons.push(rx.await.map_err(|_| match deadline.is_some_and(|d| Instant::now() >= d) {
                true => deadline_exceeded(),
                false => Status::internal("the fit of a face failed (a bug; it is logged)"),
            })?);
        }
        let fit_s = t.elapsed().as_secs_f64();

        let recon = Reconstruction { image: Arc::unwrap_or_clone(image), faces: recons };
        let (pipeline, draw) = (self.pipeline.clone(), self.draw.clone());
        let (response, waited, outputs_s) =
            self.cpu(move || convert::response(pipeline.model(), &recon, &wanted, &*draw)).await?;
        let mut response = response?;
        queue_s += waited;
        metrics::histogram!(m::STAGE_SECONDS, "stage" => "outputs").record(outputs_s);
        response.id = id;
        response.timing = Some(pb::Timing { queue_s, decode_detect_s, fit_s, outputs_s });
        Ok(response)
    }
}

impl Engine {
    /// Runs `f` on the CPU pool once one of its threads is free. Waiting here, in tokio's
    /// fair (FIFO) semaphore, instead of in rayon's queue keeps photos in arrival order:
    /// rayon runs queued jobs in no fixed order (a thread waiting inside a `par_iter` steals
    /// whatever is queued), which let some photos wait seconds at concurrency 32.
    /// Returns `f`'s value, the seconds waited for a thread and the seconds `f` ran.
    async fn cpu<T: Send + 'static>(&self, f: impl FnOnce() -> T + Send + 'static) -> Result<(T, f64, f64), Status> {
        let t = Instant::now();
        let _slot = self.cpu_slots.acquire().await.map_err(|_| Status::unavailable("the server is shutting down"))?;
        let waited = t.elapsed().as_secs_f64();
        let t = Instant::now();
        let v = on_pool(&self.pool, f).await?;
        Ok((v, waited, t.elapsed().as_secs_f64()))
    }
}

fn check_deadline(deadline: Option<Instant>) -> Result<(), Status> {
    match deadline {
        Some(d) if Instant::now() >= d => Err(deadline_exceeded()),
        _ => Ok(()),
    }
}

pub fn deadline_exceeded() -> Status {
    Status::deadline_exceeded("deadline exceeded before the reconstruction finished")
}

/// Runs `f` on the CPU pool unless the caller has gone away first. A panic in `f` is the
/// server's fault and answers INTERNAL.
pub async fn on_pool<T: Send + 'static>(
    pool: &rayon::ThreadPool,
    f: impl FnOnce() -> T + Send + 'static,
) -> Result<T, Status> {
    let (tx, rx) = oneshot::channel();
    pool.spawn(move || {
        if tx.is_closed() {
            metrics::counter!(m::DROPPED, "stage" => "cpu").increment(1);
            return;
        }
        let r = std::panic::catch_unwind(AssertUnwindSafe(f));
        let _ = tx.send(r);
    });
    match rx.await {
        Ok(Ok(v)) => Ok(v),
        Ok(Err(panic)) => {
            let what = panic
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| panic.downcast_ref::<String>().cloned())
                .unwrap_or_default();
            tracing::error!(panic = %what, "a pipeline stage panicked");
            Err(Status::internal("the server failed on this request (a bug; it is logged)"))
        }
        Err(_) => Err(Status::internal("the CPU pool dropped a task")),
    }
}

async fn batcher(
    mut rx: mpsc::UnboundedReceiver<FaceJob>,
    pipeline: Arc<Pipeline>,
    pool: Arc<rayon::ThreadPool>,
    settings: EngineSettings,
) {
    while let Some(first) = rx.recv().await {
        let mut batch = vec![first];
        match settings.max_queue_delay {
            None => {
                while batch.len() < settings.max_batch_size {
                    match rx.try_recv() {
                        Ok(j) => batch.push(j),
                        Err(_) => break,
                    }
                }
            }
            Some(delay) => {
                let until = tokio::time::Instant::now() + delay;
                while batch.len() < settings.max_batch_size {
                    match tokio::time::timeout_at(until, rx.recv()).await {
                        Ok(Some(j)) => batch.push(j),
                        _ => break,
                    }
                }
            }
        }
        let now = Instant::now();
        batch.retain(|j| {
            if j.reply.is_closed() {
                metrics::counter!(m::DROPPED, "stage" => "batch").increment(1);
                false
            } else if j.deadline.is_some_and(|d| now >= d) {
                // Dropping the sender tells the photo's task (which answers DEADLINE_EXCEEDED).
                metrics::counter!(m::DROPPED, "stage" => "deadline").increment(1);
                false
            } else {
                metrics::histogram!(m::QUEUE_SECONDS).record(now.duration_since(j.enqueued).as_secs_f64());
                true
            }
        });
        if batch.is_empty() {
            continue;
        }
        metrics::histogram!(m::BATCH_SIZE).record(batch.len() as f64);
        for j in &batch {
            metrics::counter!(m::FACES, "bucket" => bucket_label(&j.face)).increment(1);
        }
        let t = Instant::now();
        let p = pipeline.clone();
        // On a pool thread, `par_iter` spreads the batch over the same pool.
        let done = on_pool(&pool, move || {
            // The faces that start from the encoder go through it in one pass.
            let wants: Vec<(&RgbImage, &Face)> =
                batch.iter().filter(|j| j.start == Start::Encoder).map(|j| (&*j.image, &j.face)).collect();
            let mut encoded = match wants.is_empty() {
                true => Ok(Vec::new()),
                false => {
                    let t = Instant::now();
                    let e = p.encode_faces(&wants);
                    metrics::histogram!(m::STAGE_SECONDS, "stage" => "encode").record(t.elapsed().as_secs_f64());
                    e
                }
            }
            .map(Vec::into_iter);
            let starts: Vec<Result<Option<_>, String>> = batch
                .iter()
                .map(|j| match (j.start, &mut encoded) {
                    (Start::Landmarks, _) => Ok(None),
                    (Start::Encoder, Ok(it)) => Ok(it.next().flatten()),
                    (Start::Encoder, Err(e)) => Err(e.to_string()),
                })
                .collect();
            batch
                .into_par_iter()
                .zip(starts)
                .map(|(j, start)| {
                    let FaceJob { image, face, refine, reply, .. } = j;
                    let r = match start {
                        Ok(start) => p.fit_face_from(&image, face, refine, start),
                        Err(e) => p.failed_face(face, FaceError::Fit(e)),
                    };
                    // Before the reply, so that the photo's task can take the image back.
                    drop(image);
                    (reply, r)
                })
                .collect::<Vec<_>>()
        })
        .await;
        metrics::histogram!(m::STAGE_SECONDS, "stage" => "fit_batch").record(t.elapsed().as_secs_f64());
        match done {
            Ok(results) => {
                for (reply, r) in results {
                    let _ = reply.send(r);
                }
            }
            // A panic in a fit: the batch's senders are dropped, its callers get an error.
            Err(e) => tracing::error!(status = %e, "a batch failed"),
        }
    }
}

fn bucket_label(face: &Face) -> &'static str {
    match face.bucket.index() {
        Some(0) => "0",
        Some(1) => "1",
        Some(2) => "2",
        Some(3) => "3",
        _ => "too_small",
    }
}
