//! The Prometheus metrics the server exports (through the `metrics` facade and
//! `metrics-exporter-prometheus` on their own port), one name each.

use std::net::SocketAddr;

use metrics_exporter_prometheus::{Matcher, PrometheusBuilder};

/// Per RPC and final status code: latency of whole calls (`rpc`, `code` labels).
pub const REQUEST_SECONDS: &str = "facerecon_request_seconds";
/// Calls by RPC and status code (stream items count under `ReconstructStream.item`).
pub const REQUESTS: &str = "facerecon_requests_total";
/// Per stage (`decode_detect`, `encode` (the encoder pass of a batch), `fit_batch`, `outputs`).
pub const STAGE_SECONDS: &str = "facerecon_stage_seconds";
/// From a face entering the batcher's queue to its batch starting.
pub const QUEUE_SECONDS: &str = "facerecon_queue_seconds";
/// Faces per batch handed to the backend.
pub const BATCH_SIZE: &str = "facerecon_batch_size";
/// Photos admitted (queued or in work).
pub const QUEUE_DEPTH: &str = "facerecon_queue_depth";
/// Calls being handled.
pub const IN_FLIGHT: &str = "facerecon_in_flight_requests";
pub const FACES_PER_IMAGE: &str = "facerecon_faces_per_image";
/// Faces fitted, by resolution bucket.
pub const FACES: &str = "facerecon_faces_total";
/// Unary calls refused because the queue was full.
pub const REJECTED: &str = "facerecon_rejected_total";
/// Work dropped before it started (caller gone, deadline passed), by stage.
pub const DROPPED: &str = "facerecon_dropped_total";

const SECONDS: &[f64] = &[0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0, 30.0, 60.0];
const COUNTS: &[f64] = &[0.0, 1.0, 2.0, 3.0, 4.0, 6.0, 8.0, 12.0, 16.0, 24.0, 32.0, 64.0];

/// Starts the exporter's HTTP listener (`GET /metrics`) on the current tokio runtime.
pub fn install(addr: SocketAddr) -> anyhow::Result<()> {
    PrometheusBuilder::new()
        .with_http_listener(addr)
        .set_buckets_for_metric(Matcher::Suffix("_seconds".into()), SECONDS)?
        .set_buckets_for_metric(Matcher::Full(BATCH_SIZE.into()), COUNTS)?
        .set_buckets_for_metric(Matcher::Full(FACES_PER_IMAGE.into()), COUNTS)?
        .install()?;
    describe();
    Ok(())
}

fn describe() {
    use metrics::{describe_counter, describe_gauge, describe_histogram};
    describe_histogram!(REQUEST_SECONDS, metrics::Unit::Seconds, "Latency of whole calls, by rpc and status code");
    describe_counter!(REQUESTS, "Calls by rpc and status code");
    describe_histogram!(STAGE_SECONDS, metrics::Unit::Seconds, "Time per pipeline stage");
    describe_histogram!(QUEUE_SECONDS, metrics::Unit::Seconds, "Time a face waits for its batch");
    describe_histogram!(BATCH_SIZE, "Faces per batch");
    describe_gauge!(QUEUE_DEPTH, "Photos admitted (queued or in work)");
    describe_gauge!(IN_FLIGHT, "Calls being handled");
    describe_histogram!(FACES_PER_IMAGE, "Faces found per photo");
    describe_counter!(FACES, "Faces fitted, by resolution bucket");
    describe_counter!(REJECTED, "Unary calls refused with RESOURCE_EXHAUSTED because the queue was full");
    describe_counter!(DROPPED, "Work dropped before it started (caller gone or deadline passed)");
}
