//! The `facerecon-server` process: configuration errors, the metrics endpoint, and SIGTERM
//! draining the work in flight before the process exits.

use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpListener;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use facerecon_client::{Client, ConnectOptions, Request, proto as pb};

fn free_port() -> u16 {
    TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port()
}

#[test]
fn bad_configuration_exits_with_a_clear_message() {
    let out = Command::new(env!("CARGO_BIN_EXE_facerecon-server")).args(["--max-batch-size", "0"]).output().unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("max_batch_size"));
    let out =
        Command::new(env!("CARGO_BIN_EXE_facerecon-server")).args(["--metrics-listen", "nowhere"]).output().unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("--metrics-listen"));
    let out = Command::new(env!("CARGO_BIN_EXE_facerecon-server"))
        .args(["--model", "/nonexistent/model.safetensors", "--metrics-listen", "off", "--listen"])
        .arg(format!("127.0.0.1:{}", free_port()))
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("/nonexistent/model.safetensors"));
}

/// A client of the server on `port`; its calls retry UNAVAILABLE while the model loads.
async fn client(port: u16) -> Client {
    Client::connect(
        &[format!("http://127.0.0.1:{port}")],
        ConnectOptions { retries: 12, backoff: Duration::from_millis(250), ..Default::default() },
    )
    .await
    .unwrap()
}

fn scrape(port: u16) -> String {
    let mut s = std::net::TcpStream::connect(("127.0.0.1", port)).unwrap();
    write!(s, "GET /metrics HTTP/1.1\r\nHost: localhost\r\nConnection: close\r\n\r\n").unwrap();
    let mut body = String::new();
    s.read_to_string(&mut body).unwrap();
    body
}

#[test]
fn sigterm_drains_in_flight_work_and_metrics_are_exported() {
    let (port, metrics) = (free_port(), free_port());
    let mut child = Command::new(env!("CARGO_BIN_EXE_facerecon-server"))
        .args(["--listen", &format!("127.0.0.1:{port}"), "--metrics-listen", &format!("127.0.0.1:{metrics}")])
        .env("FACERECON_SHUTDOWN_GRACE_S", "30")
        .env("RUST_LOG", "info")
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let stderr = child.stderr.take().unwrap();
    let log = std::thread::spawn(move || BufReader::new(stderr).lines().map_while(Result::ok).collect::<Vec<_>>());
    let rt = tokio::runtime::Builder::new_multi_thread().enable_all().build().unwrap();
    let photo = std::fs::read(&facerecon_tests::photos(1)[0]).unwrap();
    rt.block_on(async {
        let c = client(port).await;
        // Retries while the model loads.
        let r = c.reconstruct(Request::new("warm", photo.clone())).await.unwrap();
        assert_eq!(r.faces.len(), 1);
        // A coarse fit (about a second) in flight when SIGTERM arrives still answers.
        let coarse = pb::Options { refine: pb::Refine::Coarse as i32, ..Default::default() };
        let call = tokio::spawn({
            let c = c.clone();
            let photo = photo.clone();
            async move { c.reconstruct(Request::new("in-flight", photo).with_options(coarse)).await }
        });
        tokio::time::sleep(Duration::from_millis(300)).await;
        let body = scrape(metrics);
        assert!(body.contains("facerecon_request_seconds_bucket{rpc=\"Reconstruct\",code=\"Ok\""), "{body}");
        assert!(body.contains("facerecon_batch_size_bucket"), "{body}");
        assert!(body.contains("facerecon_stage_seconds_bucket{stage=\"decode_detect\""), "{body}");
        let t = Instant::now();
        let kill = Command::new("kill").args(["-TERM", &child.id().to_string()]).status().unwrap();
        assert!(kill.success());
        let r = call.await.unwrap().expect("the in-flight call is answered");
        assert_eq!(r.faces.len(), 1);
        assert!(r.faces[0].fit.as_ref().unwrap().photometric.is_some());
        assert!(t.elapsed() < Duration::from_secs(20));
    });
    let status = child.wait().unwrap();
    assert!(status.success(), "{status:?}");
    let lines = log.join().unwrap();
    assert!(lines.iter().any(|l| l.contains("draining")), "{lines:?}");
    assert!(lines.iter().any(|l| l.contains("stopped")), "{lines:?}");
}

/// A span as the collector received it: name, attributes, the resource's `service.name`.
#[derive(Clone, Debug)]
struct Received {
    name: String,
    attributes: Vec<(String, String)>,
    service: String,
}

/// A stand-in OTLP collector: records the name and attributes of every span it is sent.
#[derive(Default, Clone)]
struct Collector {
    spans: std::sync::Arc<std::sync::Mutex<Vec<Received>>>,
}

#[tonic::async_trait]
impl opentelemetry_proto::tonic::collector::trace::v1::trace_service_server::TraceService for Collector {
    async fn export(
        &self,
        request: tonic::Request<opentelemetry_proto::tonic::collector::trace::v1::ExportTraceServiceRequest>,
    ) -> Result<
        tonic::Response<opentelemetry_proto::tonic::collector::trace::v1::ExportTraceServiceResponse>,
        tonic::Status,
    > {
        use opentelemetry_proto::tonic::common::v1::any_value::Value;
        let text = |v: &Option<opentelemetry_proto::tonic::common::v1::AnyValue>| match v
            .as_ref()
            .and_then(|v| v.value.as_ref())
        {
            Some(Value::StringValue(s)) => s.clone(),
            Some(Value::IntValue(i)) => i.to_string(),
            other => format!("{other:?}"),
        };
        let mut spans = self.spans.lock().unwrap();
        for rs in request.into_inner().resource_spans {
            let service = rs
                .resource
                .iter()
                .flat_map(|r| &r.attributes)
                .find(|a| a.key == "service.name")
                .map(|a| text(&a.value))
                .unwrap_or_default();
            for ss in rs.scope_spans {
                for s in ss.spans {
                    let attributes = s.attributes.iter().map(|a| (a.key.clone(), text(&a.value))).collect();
                    spans.push(Received { name: s.name, attributes, service: service.clone() });
                }
            }
        }
        Ok(tonic::Response::new(Default::default()))
    }
}

/// `--otlp-endpoint`: the request's span, with its id, reaches an OTLP/gRPC collector (by
/// SIGTERM at the latest: the batch is flushed on the way out), under the service's name.
#[test]
fn spans_are_exported_over_otlp() {
    use opentelemetry_proto::tonic::collector::trace::v1::trace_service_server::TraceServiceServer;
    let rt = tokio::runtime::Builder::new_multi_thread().enable_all().build().unwrap();
    let collector = Collector::default();
    let otlp = rt.block_on(async {
        let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
        let addr = listener.local_addr().unwrap();
        let svc = TraceServiceServer::new(collector.clone());
        tokio::spawn(
            tonic::transport::Server::builder()
                .add_service(svc)
                .serve_with_incoming(tokio_stream::wrappers::TcpListenerStream::new(listener)),
        );
        addr
    });
    // A bad endpoint is a configuration error, said before anything starts.
    let out = Command::new(env!("CARGO_BIN_EXE_facerecon-server"))
        .args(["--otlp-endpoint", "collector:4317"])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("otlp_endpoint"), "{}", String::from_utf8_lossy(&out.stderr));

    let port = free_port();
    let mut child = Command::new(env!("CARGO_BIN_EXE_facerecon-server"))
        .args(["--listen", &format!("127.0.0.1:{port}"), "--metrics-listen", "off"])
        .args(["--otlp-endpoint", &format!("http://{otlp}")])
        .env_remove("OTEL_SERVICE_NAME")
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let photo = std::fs::read(&facerecon_tests::photos(1)[0]).unwrap();
    rt.block_on(async {
        let c = client(port).await;
        let r = c.reconstruct(Request::new("otlp-42", photo)).await.unwrap();
        assert_eq!(r.faces.len(), 1);
    });
    let kill = Command::new("kill").args(["-TERM", &child.id().to_string()]).status().unwrap();
    assert!(kill.success());
    assert!(child.wait().unwrap().success());
    let spans = collector.spans.lock().unwrap().clone();
    let mine: Vec<_> = spans
        .iter()
        .filter(|s| s.name == "reconstruct" && s.attributes.iter().any(|(k, v)| k == "id" && v == "otlp-42"))
        .collect();
    assert_eq!(mine.len(), 1, "spans received: {spans:?}");
    assert_eq!(mine[0].service, "facerecon-server");
    rt.shutdown_timeout(Duration::from_secs(1));
}
