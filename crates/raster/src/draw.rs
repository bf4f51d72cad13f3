//! Who draws: one interface ([`Draw`]) over the two producers, for callers that render
//! pictures and should not care which one runs.
//!
//! * [`Cpu`] — the CPU rasteriser ([`crate::cpu::render`]) on the calling thread. The right
//!   choice where the only Vulkan device is a CPU implementation: on lavapipe a 224² face
//!   takes 3.2 ms on the CPU rasteriser against 9.6 ms through wgpu (docs/BENCHMARKS.md).
//! * [`RenderThread`] — the wgpu [`Renderer`] owned by a thread of its own. Callers on any
//!   thread send their jobs and wait for the frames; the thread renders whatever requests
//!   are waiting when it is free as one batch (up to a job cap), so that concurrent callers
//!   share submissions. With [`Batching::Layers`] a face renders bit-identically whatever it
//!   is batched with (decision 0200), so batching across callers changes no pixel.
//!
//! [`open`] picks one from a [`Choice`]: `Auto` takes the wgpu thread only on a device that
//! is not a CPU implementation.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc;
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;

use crate::gpu::{Batching, Renderer};
use crate::job::RenderJob;
use crate::{Camera, Frame, RenderError};

/// Renders jobs into frames, in job order. One bad job fails the call, naming it.
pub trait Draw: Send + Sync {
    fn draw(&self, jobs: &[RenderJob]) -> Result<Vec<Frame>, RenderError>;
    /// What draws, for logs: "cpu rasteriser" or the adapter's name and backend.
    fn describe(&self) -> String;
}

/// The CPU rasteriser, on the calling thread.
#[derive(Clone, Copy, Debug, Default)]
pub struct Cpu;

impl Draw for Cpu {
    fn draw(&self, jobs: &[RenderJob]) -> Result<Vec<Frame>, RenderError> {
        jobs.iter()
            .enumerate()
            .map(|(i, j)| {
                crate::cpu::render(j).map_err(|e| match e {
                    RenderError::InvalidJob { message, .. } => RenderError::InvalidJob { job: i, message },
                    e => e,
                })
            })
            .collect()
    }

    fn describe(&self) -> String {
        "cpu rasteriser".into()
    }
}

/// A job with its own buffers, to cross to the render thread.
struct OwnedJob {
    positions: Vec<[f32; 3]>,
    triangles: Vec<[u32; 3]>,
    colors: Vec<[f32; 3]>,
    normals: Vec<[f32; 3]>,
    camera: Camera,
    width: u32,
    height: u32,
}

impl OwnedJob {
    fn of(j: &RenderJob) -> Self {
        OwnedJob {
            positions: j.positions.to_vec(),
            triangles: j.triangles.to_vec(),
            colors: j.colors.to_vec(),
            normals: j.normals.to_vec(),
            camera: j.camera,
            width: j.width,
            height: j.height,
        }
    }

    fn job(&self) -> RenderJob<'_> {
        RenderJob {
            positions: &self.positions,
            triangles: &self.triangles,
            colors: &self.colors,
            normals: &self.normals,
            camera: self.camera,
            width: self.width,
            height: self.height,
        }
    }
}

struct Request {
    jobs: Vec<OwnedJob>,
    reply: mpsc::SyncSender<Result<Vec<Frame>, RenderError>>,
}

/// The wgpu renderer on a thread of its own (see the module docs). Dropping the handle
/// lets the thread finish the requests already sent, then joins it.
pub struct RenderThread {
    tx: Mutex<Option<mpsc::Sender<Request>>>,
    thread: Option<JoinHandle<()>>,
    info: wgpu::AdapterInfo,
    stats: Arc<Stats>,
}

/// What the render thread has done so far.
#[derive(Debug, Default)]
struct Stats {
    submissions: AtomicU64,
    requests: AtomicU64,
    jobs: AtomicU64,
}

/// [`RenderThread::stats`]: counts since the thread started.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ThreadStats {
    /// Calls to the renderer (one per merged batch).
    pub submissions: u64,
    /// Requests answered (one per [`Draw::draw`] call).
    pub requests: u64,
    pub jobs: u64,
}

impl RenderThread {
    /// Opens the device on a new thread (see [`Renderer::new`] for which adapter). The thread
    /// merges waiting requests into one submission of at most `max_jobs` jobs (a single
    /// larger request is rendered alone).
    pub fn spawn(batching: Batching, max_jobs: usize) -> Result<RenderThread, RenderError> {
        let (tx, rx) = mpsc::channel::<Request>();
        let (ready_tx, ready_rx) = mpsc::sync_channel(1);
        let stats = Arc::new(Stats::default());
        let counts = stats.clone();
        let thread = std::thread::Builder::new()
            .name("facerecon-render".into())
            .spawn(move || {
                let mut renderer = match Renderer::with_batching(batching) {
                    Ok(r) => {
                        let _ = ready_tx.send(Ok(r.adapter_info().clone()));
                        r
                    }
                    Err(e) => {
                        let _ = ready_tx.send(Err(e));
                        return;
                    }
                };
                serve(&mut renderer, &rx, max_jobs.max(1), &counts);
            })
            .map_err(|e| RenderError::Device(format!("starting the render thread: {e}")))?;
        let info = ready_rx
            .recv()
            .map_err(|_| RenderError::Device("the render thread ended while opening the device".into()))??;
        Ok(RenderThread { tx: Mutex::new(Some(tx)), thread: Some(thread), info, stats })
    }

    /// Submissions, requests and jobs so far: requests ÷ submissions is how many callers a
    /// submission served on average.
    pub fn stats(&self) -> ThreadStats {
        ThreadStats {
            submissions: self.stats.submissions.load(Ordering::Relaxed),
            requests: self.stats.requests.load(Ordering::Relaxed),
            jobs: self.stats.jobs.load(Ordering::Relaxed),
        }
    }

    /// The adapter the thread renders on.
    pub fn adapter_info(&self) -> &wgpu::AdapterInfo {
        &self.info
    }
}

/// The thread's loop: wait for a request, take every other waiting one while the batch has
/// room, render them in one call, answer each with its frames.
fn serve(renderer: &mut Renderer, rx: &mpsc::Receiver<Request>, max_jobs: usize, stats: &Stats) {
    let mut pending: Option<Request> = None;
    loop {
        let first = match pending.take() {
            Some(r) => r,
            None => match rx.recv() {
                Ok(r) => r,
                Err(_) => return,
            },
        };
        let mut batch = vec![first];
        let mut n = batch[0].jobs.len();
        while n < max_jobs {
            match rx.try_recv() {
                Ok(r) if n + r.jobs.len() <= max_jobs => {
                    n += r.jobs.len();
                    batch.push(r);
                }
                Ok(r) => {
                    pending = Some(r);
                    break;
                }
                Err(_) => break,
            }
        }
        let jobs: Vec<RenderJob> = batch.iter().flat_map(|r| r.jobs.iter().map(OwnedJob::job)).collect();
        stats.submissions.fetch_add(1, Ordering::Relaxed);
        stats.requests.fetch_add(batch.len() as u64, Ordering::Relaxed);
        stats.jobs.fetch_add(jobs.len() as u64, Ordering::Relaxed);
        match renderer.render(&jobs) {
            Ok(frames) => {
                let mut frames = frames.into_iter();
                for r in batch {
                    let mine: Vec<Frame> = frames.by_ref().take(r.jobs.len()).collect();
                    let _ = r.reply.send(Ok(mine));
                }
            }
            // A merged batch failed: render each request alone, so that one request's
            // failure is its own (and job numbers are its own).
            Err(_) if batch.len() > 1 => {
                for r in batch {
                    let jobs: Vec<RenderJob> = r.jobs.iter().map(OwnedJob::job).collect();
                    let _ = r.reply.send(renderer.render(&jobs));
                }
            }
            Err(e) => {
                let _ = batch.pop().map(|r| r.reply.send(Err(e)));
            }
        }
    }
}

impl Draw for RenderThread {
    fn draw(&self, jobs: &[RenderJob]) -> Result<Vec<Frame>, RenderError> {
        if jobs.is_empty() {
            return Ok(Vec::new());
        }
        // Checked here so that a bad job is this caller's error and never reaches a batch.
        for (i, j) in jobs.iter().enumerate() {
            j.validate(i)?;
        }
        let (reply, answer) = mpsc::sync_channel(1);
        let request = Request { jobs: jobs.iter().map(OwnedJob::of).collect(), reply };
        {
            let tx = self.tx.lock().map_err(|_| RenderError::Device("render thread handle poisoned".into()))?;
            let tx = tx.as_ref().ok_or_else(|| RenderError::Device("the render thread has stopped".into()))?;
            tx.send(request).map_err(|_| RenderError::Device("the render thread has stopped".into()))?;
        }
        answer.recv().map_err(|_| RenderError::Device("the render thread stopped before answering".into()))?
    }

    fn describe(&self) -> String {
        format!("wgpu on {} ({:?}, {:?})", self.info.name, self.info.backend, self.info.device_type)
    }
}

impl Drop for RenderThread {
    fn drop(&mut self) {
        if let Ok(mut tx) = self.tx.lock() {
            tx.take();
        }
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// Which producer [`open`] returns.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Choice {
    /// The wgpu thread on a device that is not a CPU implementation; the CPU rasteriser
    /// otherwise (no adapter, or only lavapipe, where it is the faster of the two).
    #[default]
    Auto,
    Cpu,
    /// The wgpu thread on whatever adapter [`Renderer::new`] picks (lavapipe included);
    /// failing to open one is an error.
    Gpu,
}

/// Opens the producer `choice` names; the string says what was picked and, for `Auto`,
/// why.
pub fn open(choice: Choice, max_jobs: usize) -> Result<(Box<dyn Draw>, String), RenderError> {
    match choice {
        Choice::Cpu => Ok((Box::new(Cpu), "cpu rasteriser (configured)".into())),
        Choice::Gpu => {
            let t = RenderThread::spawn(Batching::Layers, max_jobs)?;
            let why = format!("{} (configured)", t.describe());
            Ok((Box::new(t), why))
        }
        Choice::Auto => match RenderThread::spawn(Batching::Layers, max_jobs) {
            Ok(t) if t.adapter_info().device_type != wgpu::DeviceType::Cpu => {
                let why = t.describe();
                Ok((Box::new(t), why))
            }
            Ok(t) => Ok((
                Box::new(Cpu),
                format!("cpu rasteriser (the only Vulkan device, {}, is a CPU implementation)", t.adapter_info().name),
            )),
            Err(e) => Ok((Box::new(Cpu), format!("cpu rasteriser (no GPU renderer: {e})"))),
        },
    }
}
