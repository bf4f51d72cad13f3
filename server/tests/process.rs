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
        let c = Client::connect(
            &[format!("http://127.0.0.1:{port}")],
            ConnectOptions { retries: 12, backoff: Duration::from_millis(250), ..Default::default() },
        )
        .await
        .unwrap();
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
