//! Logs and traces: `tracing` events as text or JSON lines on stderr (level from
//! `RUST_LOG`, default `info`), and, when `otlp_endpoint` is set, the same spans (one per
//! request, with its id; one per stream and per stream item) exported over OTLP/gRPC to a
//! collector (Jaeger, Tempo, the OpenTelemetry Collector …) in batches, off the request
//! path.
//!
//! The exporter's tonic client needs the tokio runtime: [`init`] is called inside it, and
//! [`Telemetry::shutdown`] (which flushes the spans still batched) before it is dropped.
//! The resource's `service.name` is `facerecon-server` unless `OTEL_SERVICE_NAME` says
//! otherwise; `OTEL_RESOURCE_ATTRIBUTES` adds attributes (the SDK's own detectors).

use anyhow::Context;
use opentelemetry::trace::TracerProvider as _;
use opentelemetry_otlp::WithExportConfig;
use opentelemetry_sdk::trace::SdkTracerProvider;
use tracing_subscriber::Layer;
use tracing_subscriber::layer::SubscriberExt;
use tracing_subscriber::util::SubscriberInitExt;

use crate::config::LogFormat;

/// What [`init`] started; keep it until the server has stopped.
#[must_use = "dropping it without shutdown() may lose the last spans"]
pub struct Telemetry {
    provider: Option<SdkTracerProvider>,
}

impl Telemetry {
    /// Exports the spans still batched and stops the exporter (blocking; at most the
    /// exporter's timeout). Call it from outside the runtime's tasks, before the runtime
    /// is dropped.
    pub fn shutdown(mut self) {
        if let Some(p) = self.provider.take()
            && let Err(e) = p.shutdown()
        {
            eprintln!("warning: flushing the OTLP spans: {e}");
        }
    }
}

/// Checks an OTLP endpoint: an `http://` or `https://` URL with a host.
pub fn validate_endpoint(endpoint: &str) -> anyhow::Result<()> {
    let uri: http::Uri = endpoint.parse().with_context(|| format!("otlp_endpoint {endpoint:?} is not a URL"))?;
    anyhow::ensure!(
        matches!(uri.scheme_str(), Some("http" | "https")) && uri.host().is_some(),
        "otlp_endpoint {endpoint:?}: expected http://HOST:PORT or https://HOST:PORT (OTLP over gRPC, usually port 4317)"
    );
    Ok(())
}

/// Installs the global subscriber: stderr lines in `format`, plus OTLP export to
/// `otlp_endpoint` when given. Must run inside the tokio runtime. A second call (tests)
/// leaves the first subscriber in place.
pub fn init(format: LogFormat, otlp_endpoint: Option<&str>) -> anyhow::Result<Telemetry> {
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info"));
    let lines = tracing_subscriber::fmt::layer().with_writer(std::io::stderr);
    let lines = match format {
        LogFormat::Text => lines.boxed(),
        LogFormat::Json => lines.json().boxed(),
    };
    let (otel, provider) = match otlp_endpoint {
        None => (None, None),
        Some(endpoint) => {
            validate_endpoint(endpoint)?;
            let exporter = opentelemetry_otlp::SpanExporter::builder()
                .with_tonic()
                .with_endpoint(endpoint)
                .build()
                .with_context(|| format!("the OTLP exporter for {endpoint}"))?;
            let mut resource = opentelemetry_sdk::Resource::builder();
            if std::env::var_os("OTEL_SERVICE_NAME").is_none() {
                resource = resource.with_service_name("facerecon-server");
            }
            let provider =
                SdkTracerProvider::builder().with_batch_exporter(exporter).with_resource(resource.build()).build();
            let tracer = provider.tracer("facerecon-server");
            (Some(tracing_opentelemetry::layer().with_tracer(tracer)), Some(provider))
        }
    };
    let _ = tracing_subscriber::registry().with(filter).with(lines).with(otel).try_init();
    Ok(Telemetry { provider })
}
