//! A client nobody here wrote: `tests/python/grpcio_client.py` generates Python stubs from
//! `proto/` with grpcio-tools and calls a server on loopback through grpcio (health,
//! reflection, GetModel, Reconstruct, an error, a deadline, a stream). The Python packages
//! are `tests/python/requirements.txt`, installed by `scripts/setup`.

use facerecon_server::Config;
use facerecon_tests::{TestServer, photos};

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn grpcio_client_generated_from_the_proto() {
    let s = TestServer::start(Config::default()).await;
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let out = std::env::temp_dir().join(format!("facerecon-grpcio-{}", std::process::id()));
    let photo = photos(1)[0].clone();
    let addr = s.addr.to_string();
    let output = tokio::process::Command::new("python3")
        .arg(root.join("python/grpcio_client.py"))
        .args(["--server", &addr, "--photo"])
        .arg(&photo)
        .arg("--out")
        .arg(&out)
        .arg("--proto")
        .arg(root.join("../proto"))
        .output()
        .await
        .expect("python3 runs");
    let stdout = String::from_utf8_lossy(&output.stdout);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(
        output.status.success(),
        "the grpcio client failed (are tests/python/requirements.txt installed? scripts/setup --deps-only does it)\n\
         stdout: {stdout}\nstderr: {stderr}"
    );
    let report: serde_json::Value = serde_json::from_str(stdout.trim()).expect("one JSON object");
    assert_eq!(report["reconstruct"]["faces"], 1);
    assert_eq!(report["deadline"], "DEADLINE_EXCEEDED");
    assert!(report["reflection"].as_array().unwrap().iter().any(|s| s == "facerecon.v1.Reconstructor"));
    s.stop().await.unwrap();
}
