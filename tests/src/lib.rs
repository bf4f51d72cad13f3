//! Helpers of the end-to-end tests (`tests/*.rs`) and the load tool (`src/bin/load.rs`):
//! a `facerecon-server` on a loopback socket in this process, sharing one loaded pipeline,
//! and the test photos from the shared faces-300w folder.

use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::{Arc, OnceLock};
use std::time::Duration;

use facerecon_recon::Pipeline;
use facerecon_server::Config;
use tokio::sync::oneshot;

/// The shared folder (`../shared` beside the repository).
pub fn shared_dir() -> PathBuf {
    facerecon_model::ict::shared_dir()
}

/// `n` annotated LFPW test photos (PNG), sorted.
pub fn photos(n: usize) -> Vec<PathBuf> {
    let dir = shared_dir().join("data/faces-300w/lfpw/testset");
    let mut v: Vec<PathBuf> = std::fs::read_dir(&dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e == "png"))
        .collect();
    v.sort();
    v.truncate(n);
    v
}

/// The standard pipeline (default ICT model, standard front end), loaded once per process.
pub fn pipeline() -> Arc<Pipeline> {
    static P: OnceLock<Arc<Pipeline>> = OnceLock::new();
    P.get_or_init(|| {
        let model = facerecon_model::ict::load_default().expect("the default ICT model");
        let front = facerecon_vision::pipeline::FrontEnd::load_standard(
            facerecon_vision::landmarks::DEFAULT_MODEL_PATH.as_ref(),
        )
        .expect("the standard front end");
        Arc::new(Pipeline::new(model, front).expect("the pipeline"))
    })
    .clone()
}

/// A server on `127.0.0.1:<free port>`, stopped (gracefully) when dropped.
pub struct TestServer {
    pub addr: SocketAddr,
    stop: Option<oneshot::Sender<()>>,
    done: Option<tokio::task::JoinHandle<anyhow::Result<()>>>,
}

impl TestServer {
    /// Starts a server with `config` (its listen and metrics addresses are ignored) on the
    /// current tokio runtime and waits until it reports SERVING.
    pub async fn start(config: Config) -> TestServer {
        let p = tokio::task::spawn_blocking(pipeline).await.expect("loading the pipeline");
        let s = Self::start_with(config, Box::new(move || Ok(p))).await;
        s.wait_serving(Duration::from_secs(60)).await;
        s
    }

    /// The same with a custom loader (which may be slow or fail); does not wait.
    pub async fn start_with(config: Config, load: facerecon_server::Loader) -> TestServer {
        let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.expect("binding a loopback port");
        let addr = listener.local_addr().expect("local address");
        let (stop, stopped) = oneshot::channel::<()>();
        let config = Config { metrics_listen: None, ..config };
        let done = tokio::spawn(facerecon_server::serve(config, listener, load, async move {
            let _ = stopped.await;
        }));
        TestServer { addr, stop: Some(stop), done: Some(done) }
    }

    pub fn url(&self) -> String {
        format!("http://{}", self.addr)
    }

    /// Waits until the standard health check says SERVING (at most `limit`).
    pub async fn wait_serving(&self, limit: Duration) {
        let deadline = tokio::time::Instant::now() + limit;
        loop {
            if self.health("").await == Some(tonic_health::pb::health_check_response::ServingStatus::Serving) {
                return;
            }
            assert!(tokio::time::Instant::now() < deadline, "the server did not report SERVING within {limit:?}");
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
    }

    /// The standard health protocol's answer for `service` (`None` when unreachable).
    pub async fn health(&self, service: &str) -> Option<tonic_health::pb::health_check_response::ServingStatus> {
        let channel = tonic::transport::Endpoint::from_shared(self.url()).ok()?.connect().await.ok()?;
        let mut c = tonic_health::pb::health_client::HealthClient::new(channel);
        let r = c.check(tonic_health::pb::HealthCheckRequest { service: service.into() }).await.ok()?;
        tonic_health::pb::health_check_response::ServingStatus::try_from(r.into_inner().status).ok()
    }

    /// Waits for the server to end by itself (a failed load) and returns its result.
    pub async fn finished(mut self) -> anyhow::Result<()> {
        match self.done.take() {
            Some(d) => d.await?,
            None => Ok(()),
        }
    }

    /// Stops accepting calls, drains, and returns the server's result.
    pub async fn stop(mut self) -> anyhow::Result<()> {
        if let Some(s) = self.stop.take() {
            let _ = s.send(());
        }
        match self.done.take() {
            Some(d) => d.await?,
            None => Ok(()),
        }
    }
}

impl Drop for TestServer {
    fn drop(&mut self) {
        if let Some(s) = self.stop.take() {
            let _ = s.send(());
        }
    }
}

/// A PNG whose header claims `width` × `height` (valid signature and CRCs, no pixel data
/// beyond a stub): what a decoder must refuse before allocating.
pub fn png_header_claiming(width: u32, height: u32) -> Vec<u8> {
    let mut out = b"\x89PNG\r\n\x1a\n".to_vec();
    let mut chunk = |kind: &[u8], data: &[u8]| {
        out.extend_from_slice(&(data.len() as u32).to_be_bytes());
        let mut body = kind.to_vec();
        body.extend_from_slice(data);
        out.extend_from_slice(&body);
        out.extend_from_slice(&crc32fast::hash(&body).to_be_bytes());
    };
    let mut ihdr = Vec::new();
    ihdr.extend_from_slice(&width.to_be_bytes());
    ihdr.extend_from_slice(&height.to_be_bytes());
    ihdr.extend_from_slice(&[8, 2, 0, 0, 0]);
    chunk(b"IHDR", &ihdr);
    chunk(b"IDAT", &[0x78, 0x9c, 0x03, 0x00, 0x00, 0x00, 0x00, 0x01]);
    chunk(b"IEND", &[]);
    out
}

pub fn png(img: &image::RgbImage) -> Vec<u8> {
    facerecon_recon::outputs::png(img).expect("encoding a PNG")
}
