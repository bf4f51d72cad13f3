//! `facerecon-server`: the gRPC service over the [`facerecon_recon`] pipeline (DESIGN §10).
//! This crate holds only protocol, configuration, queue, batcher and telemetry; the
//! reconstruction is the pipeline's, the same one `facerecon fit` runs in-process.
//!
//! * [`config`]: defaults, file, environment, flags;
//! * [`convert`]: request validation and the response messages;
//! * [`engine`]: admission, CPU pool, batcher;
//! * [`service`]: the RPC handlers (deadlines, streams, per-call metrics);
//! * [`metrics`]: metric names and the Prometheus exporter;
//! * [`telemetry`]: log lines and the optional OTLP trace export;
//! * [`serve`]: health, reflection, auth, TLS, message limits, graceful shutdown.

pub mod config;
pub mod convert;
pub mod engine;
pub mod metrics;
pub mod service;
pub mod telemetry;

use std::future::Future;
use std::sync::{Arc, OnceLock};
use std::time::{Duration, Instant};

use anyhow::Context;
use facerecon_proto::v1 as pb;
use facerecon_recon::Pipeline;
use tonic::Status;
use tonic::transport::{Identity, Server, ServerTlsConfig};
use tonic_health::ServingStatus;

pub use config::{Config, EncoderChoice};
use engine::{Engine, EngineSettings};
use service::{Arrival, Service, State};

/// The gRPC name of the reconstruction service (for health checks).
pub const SERVICE_NAME: &str = "facerecon.v1.Reconstructor";
/// Most render jobs the wgpu thread merges into one submission (a side-by-side is four per
/// face, an overlay one).
const RENDER_BATCH_JOBS: usize = 32;

/// Loads the pipeline the server runs (called once, off the async runtime).
pub type Loader = Box<dyn FnOnce() -> anyhow::Result<Arc<Pipeline>> + Send>;

/// The default loader: the model file (or the default ICT model) and the standard front
/// end, with the configuration's decode limits.
pub fn default_loader(config: &Config) -> Loader {
    let config = config.clone();
    Box::new(move || {
        let model = match &config.model {
            Some(p) => Arc::new(
                facerecon_model::MorphableModel::load(p).with_context(|| format!("loading model {}", p.display()))?,
            ),
            None => facerecon_model::ict::load_default().context("building the default ICT model")?,
        };
        let front = facerecon_vision::pipeline::FrontEnd::load_standard(&config.landmark_model)?;
        let mut pipeline = Pipeline::new(model, front)?;
        // ONNX Runtime's own threads for one batch; batches run one at a time.
        let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
        let load = |w: &std::path::Path| {
            facerecon_nn::encoder::load(w, config.encoder_device, config.encoder_precision, threads).with_context(
                || {
                    format!(
                        "loading the encoder {} ({}, {})",
                        w.display(),
                        config.encoder_device,
                        config.encoder_precision
                    )
                },
            )
        };
        match &config.encoder {
            EncoderChoice::None => {}
            EncoderChoice::File(w) => {
                let encoder = load(w)?;
                tracing::info!(weights = %w.display(), path = %encoder.describe(), "encoder loaded");
                pipeline.set_encoder(encoder)?;
            }
            // The default: the released weights when they fit the model's coefficient
            // layout. A server that cannot use them still serves the landmark start, and
            // says why.
            EncoderChoice::Released => {
                let w = facerecon_nn::released::path();
                let fits = facerecon_nn::weights::read_config(&w)
                    .map(|c| c.layout == pipeline.model().layout())
                    .map_err(anyhow::Error::from);
                match fits.and_then(|fits| {
                    anyhow::ensure!(fits, "the released weights are for another model's coefficients");
                    let encoder = load(&w)?;
                    let describe = encoder.describe();
                    pipeline.set_encoder(encoder)?;
                    Ok(describe)
                }) {
                    Ok(path) => tracing::info!(weights = %w.display(), %path, "released encoder loaded"),
                    Err(e) => tracing::warn!(weights = %w.display(), "no encoder: {e:#}"),
                }
            }
        }
        pipeline.limits.max_pixels = config.max_image_pixels;
        pipeline.limits.max_encoded_bytes = pipeline.limits.max_encoded_bytes.min(config.max_message_bytes);
        Ok(Arc::new(pipeline))
    })
}

/// tonic answers a message over the size limit with OUT_OF_RANGE; the contract (and gRPC's
/// own guidance) says RESOURCE_EXHAUSTED.
pub fn fix_size_status(s: Status) -> Status {
    if s.code() == tonic::Code::OutOfRange && s.message().contains("message length too large") {
        Status::resource_exhausted(s.message().to_string())
    } else {
        s
    }
}

/// The same for trailers-only HTTP responses (a unary request refused while decoding).
fn fix_size_response<B>(mut r: http::Response<B>) -> http::Response<B> {
    let h = r.headers_mut();
    if h.get("grpc-status").is_some_and(|v| v == "11")
        && h.get("grpc-message")
            .and_then(|v| v.to_str().ok())
            .is_some_and(|m| m.contains("message%20length%20too%20large"))
    {
        h.insert("grpc-status", http::HeaderValue::from_static("8"));
    }
    r
}

/// Serves until `shutdown` resolves, then stops accepting calls, reports NOT_SERVING, and
/// gives in-flight work `shutdown_grace_s` to finish. The listener is served at once:
/// health answers NOT_SERVING (and reconstruction calls UNAVAILABLE) until `load` has
/// finished; a failed load ends the server with its error.
pub async fn serve(
    config: Config,
    listener: tokio::net::TcpListener,
    load: Loader,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> anyhow::Result<()> {
    config.validate()?;
    let pool = Arc::new(engine::cpu_pool(config.cpu_threads).context("starting the CPU pool")?);
    let threads = pool.current_num_threads();
    let state = Arc::new(State { engine: OnceLock::new(), model_info: OnceLock::new(), max_faces: config.max_faces });
    let (reporter, health) = tonic_health::server::health_reporter();
    reporter.set_service_status("", ServingStatus::NotServing).await;
    reporter.set_service_status(SERVICE_NAME, ServingStatus::NotServing).await;

    let settings = EngineSettings {
        max_batch_size: config.max_batch_size,
        max_queue_delay: (config.max_queue_delay_ms > 0).then(|| Duration::from_millis(config.max_queue_delay_ms)),
        queue_capacity: config.queue_capacity,
    };
    let (failed_tx, failed_rx) = tokio::sync::oneshot::channel::<anyhow::Error>();
    let renderer = config.renderer;
    {
        let state = state.clone();
        let reporter = reporter.clone();
        tokio::spawn(async move {
            let t = Instant::now();
            match tokio::task::spawn_blocking(load).await {
                Ok(Ok(pipeline)) => {
                    let choice = renderer.into();
                    let draw = match tokio::task::spawn_blocking(move || {
                        facerecon_raster::draw::open(choice, RENDER_BATCH_JOBS)
                    })
                    .await
                    {
                        Ok(Ok((draw, why))) => {
                            tracing::info!(renderer = %why, "pictures drawn by");
                            Arc::<dyn facerecon_raster::Draw>::from(draw)
                        }
                        Ok(Err(e)) => {
                            let _ = failed_tx.send(anyhow::anyhow!("opening the renderer: {e}"));
                            return;
                        }
                        Err(e) => {
                            let _ = failed_tx.send(anyhow::anyhow!("opening the renderer panicked: {e}"));
                            return;
                        }
                    };
                    let engine = match Engine::start(pipeline.clone(), pool, settings, draw) {
                        Ok(e) => e,
                        Err(e) => {
                            let _ = failed_tx.send(anyhow::anyhow!("starting the backend threads: {e}"));
                            return;
                        }
                    };
                    let _ = state.model_info.set(convert::model_info(pipeline.model()));
                    let _ = state.engine.set(engine);
                    reporter.set_service_status("", ServingStatus::Serving).await;
                    reporter.set_service_status(SERVICE_NAME, ServingStatus::Serving).await;
                    tracing::info!(seconds = t.elapsed().as_secs_f64(), threads, "model loaded; serving");
                }
                Ok(Err(e)) => {
                    let _ = failed_tx.send(e);
                }
                Err(e) => {
                    let _ = failed_tx.send(anyhow::anyhow!("loading the model panicked: {e}"));
                }
            }
        });
    }

    let token = config.auth_token.clone().map(|t| format!("Bearer {}", t.trim()));
    let interceptor = move |mut req: tonic::Request<()>| {
        req.extensions_mut().insert(Arrival(Instant::now()));
        if let Some(expected) = &token {
            let given = req.metadata().get("authorization").and_then(|v| v.to_str().ok());
            if !given.is_some_and(|g| constant_time_eq(g.as_bytes(), expected.as_bytes())) {
                return Err(Status::unauthenticated("missing or wrong bearer token"));
            }
        }
        Ok(req)
    };
    let reconstructor = pb::reconstructor_server::ReconstructorServer::new(Service { state: state.clone() })
        .max_decoding_message_size(config.max_message_bytes)
        .max_encoding_message_size(config.max_message_bytes);
    let reconstructor = tonic::service::interceptor::InterceptedService::new(reconstructor, interceptor);
    let reflection = tonic_reflection::server::Builder::configure()
        .register_encoded_file_descriptor_set(pb::FILE_DESCRIPTOR_SET)
        .register_encoded_file_descriptor_set(tonic_health::pb::FILE_DESCRIPTOR_SET);
    let reflection_v1 = reflection.build_v1().context("building the reflection service")?;
    let reflection_v1alpha = tonic_reflection::server::Builder::configure()
        .register_encoded_file_descriptor_set(pb::FILE_DESCRIPTOR_SET)
        .register_encoded_file_descriptor_set(tonic_health::pb::FILE_DESCRIPTOR_SET)
        .build_v1alpha()
        .context("building the reflection service")?;

    let mut builder = Server::builder().tcp_nodelay(true).http2_keepalive_interval(Some(Duration::from_secs(30)));
    if let (Some(cert), Some(key)) = (&config.tls_cert, &config.tls_key) {
        let cert = std::fs::read(cert).with_context(|| format!("reading {}", cert.display()))?;
        let key = std::fs::read(key).with_context(|| format!("reading {}", key.display()))?;
        builder = builder
            .tls_config(ServerTlsConfig::new().identity(Identity::from_pem(cert, key)))
            .context("configuring TLS")?;
    }
    let router = builder
        .layer(tower::util::MapResponseLayer::new(fix_size_response::<tonic::body::Body>))
        .add_service(health)
        .add_service(reflection_v1)
        .add_service(reflection_v1alpha)
        .add_service(reconstructor);

    let (stopping_tx, stopping_rx) = tokio::sync::oneshot::channel::<()>();
    let on_shutdown = {
        let reporter = reporter.clone();
        async move {
            shutdown.await;
            tracing::info!("shutting down: no new calls; draining in-flight work");
            reporter.set_service_status("", ServingStatus::NotServing).await;
            reporter.set_service_status(SERVICE_NAME, ServingStatus::NotServing).await;
            let _ = stopping_tx.send(());
        }
    };
    let incoming = tokio_stream::wrappers::TcpListenerStream::new(listener);
    let serving = router.serve_with_incoming_shutdown(incoming, on_shutdown);
    let grace = Duration::from_secs(config.shutdown_grace_s);
    let grace_over = async move {
        if stopping_rx.await.is_ok() {
            tokio::time::sleep(grace).await;
        } else {
            std::future::pending::<()>().await;
        }
    };
    tokio::select! {
        r = serving => r.context("serving")?,
        _ = grace_over => tracing::warn!(seconds = grace.as_secs(), "grace period over; in-flight work dropped"),
        Ok(e) = failed_rx => return Err(e.context("loading the pipeline")),
    }
    tracing::info!("stopped");
    Ok(())
}

/// Compares secrets without an early exit on the first differing byte.
fn constant_time_eq(a: &[u8], b: &[u8]) -> bool {
    a.len() == b.len() && a.iter().zip(b).fold(0u8, |acc, (x, y)| acc | (x ^ y)) == 0
}
