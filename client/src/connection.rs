//! [`Client`]: a connection to one `facerecon-server` or to many, balanced.
//!
//! gRPC keeps one long-lived HTTP/2 connection, so a plain Kubernetes ClusterIP service
//! pins a client to one pod. Given a name that resolves to many addresses (a headless
//! service), the client connects to each address and spreads calls over them
//! (power-of-two-choices on in-flight calls, tower's balancer), re-resolving the name every
//! [`ConnectOptions::resolve_interval`] so that new pods join and gone ones leave.

use std::collections::HashMap;
use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;

use tokio::sync::{Semaphore, mpsc};
use tokio_stream::{Stream, StreamExt};
use tonic::metadata::{Ascii, MetadataValue};
use tonic::service::interceptor::InterceptedService;
use tonic::transport::channel::Change;
use tonic::transport::{Certificate, Channel, ClientTlsConfig, Endpoint};

use crate::results::{ModelTopology, Reconstruction};
use facerecon_proto::v1 as pb;

/// Why a call failed.
#[derive(Debug, thiserror::Error)]
pub enum ClientError {
    #[error("invalid server address {0}")]
    InvalidAddress(String),
    #[error("cannot reach the server: {0}")]
    Connect(String),
    /// The server's status (code and message).
    #[error("{}: {}", .0.code(), .0.message())]
    Status(tonic::Status),
    /// The server's answer does not fit the contract.
    #[error("malformed answer: {0}")]
    Malformed(String),
}

impl ClientError {
    /// The gRPC code, for errors that carry one.
    pub fn code(&self) -> Option<tonic::Code> {
        match self {
            ClientError::Status(s) => Some(s.code()),
            _ => None,
        }
    }
}

/// How to connect and call.
#[derive(Clone, Debug)]
pub struct ConnectOptions {
    /// Sent as `authorization: Bearer <token>`.
    pub token: Option<String>,
    /// PEM root certificate for `https://` addresses (the system's roots are not used).
    pub ca_pem: Option<Vec<u8>>,
    /// TLS server name, when it differs from the address's host.
    pub tls_domain: Option<String>,
    /// Deadline of each unary call (sent as `grpc-timeout`); whole-stream deadline for streams.
    pub timeout: Option<Duration>,
    pub connect_timeout: Duration,
    /// Largest message sent or received (meshes and pictures exceed tonic's 4 MiB).
    pub max_message_bytes: usize,
    /// Retries of a unary call answered UNAVAILABLE or cut off by the transport (server
    /// starting, pod gone, restart).
    pub retries: u32,
    /// First retry delay; doubled each retry, with jitter.
    pub backoff: Duration,
    /// How often names are re-resolved; `None`: resolve once.
    pub resolve_interval: Option<Duration>,
}

impl Default for ConnectOptions {
    fn default() -> Self {
        ConnectOptions {
            token: None,
            ca_pem: None,
            tls_domain: None,
            timeout: None,
            connect_timeout: Duration::from_secs(5),
            max_message_bytes: 64 << 20,
            retries: 5,
            backoff: Duration::from_millis(100),
            resolve_interval: Some(Duration::from_secs(30)),
        }
    }
}

/// One photo to reconstruct.
#[derive(Clone, Debug, Default)]
pub struct Request {
    pub id: String,
    pub image: Vec<u8>,
    pub options: pb::Options,
}

impl Request {
    pub fn new(id: impl Into<String>, image: Vec<u8>) -> Self {
        Request { id: id.into(), image, options: pb::Options::default() }
    }

    pub fn with_options(mut self, options: pb::Options) -> Self {
        self.options = options;
        self
    }

    fn into_message(self) -> pb::ReconstructRequest {
        pb::ReconstructRequest { id: self.id, image: self.image, options: Some(self.options) }
    }
}

/// tonic's channel enforces a call's `grpc-timeout` on the client side too and reports its
/// own expiry as CANCELLED ("Timeout expired"); it is the caller's deadline, so it is
/// reported as DEADLINE_EXCEEDED, the code the server gives for the same deadline.
fn local_deadline(s: tonic::Status) -> tonic::Status {
    if s.code() == tonic::Code::Cancelled && s.message().contains("Timeout expired") {
        tonic::Status::deadline_exceeded(format!("deadline exceeded ({})", s.message()))
    } else {
        s
    }
}

/// UNAVAILABLE, and a connection broken before any answer: tonic reports that as UNKNOWN
/// "transport error", or as CANCELLED "operation was canceled" when the connection closes
/// under a request it has not answered (e.g. a container's port proxy accepting before the
/// server listens). A deadline's own expiry, also CANCELLED, is not retried.
fn retriable(s: &tonic::Status) -> bool {
    s.code() == tonic::Code::Unavailable
        || (s.code() == tonic::Code::Unknown && s.message().contains("transport error"))
        || (s.code() == tonic::Code::Cancelled
            && s.message().contains("operation was canceled")
            && !s.message().contains("Timeout expired"))
}

#[derive(Clone)]
struct Auth(Option<MetadataValue<Ascii>>);

impl tonic::service::Interceptor for Auth {
    fn call(&mut self, mut req: tonic::Request<()>) -> Result<tonic::Request<()>, tonic::Status> {
        if let Some(v) = &self.0 {
            req.metadata_mut().insert("authorization", v.clone());
        }
        Ok(req)
    }
}

type Stub = pb::reconstructor_client::ReconstructorClient<InterceptedService<Channel, Auth>>;

/// A connection to the service; cheap to clone (clones share the connections).
#[derive(Clone)]
pub struct Client {
    stub: Stub,
    options: ConnectOptions,
    _resolver: Option<Arc<ResolverGuard>>,
}

struct ResolverGuard(tokio::task::JoinHandle<()>);
impl Drop for ResolverGuard {
    fn drop(&mut self) {
        self.0.abort();
    }
}

struct Target {
    tls: bool,
    host: String,
    port: u16,
}

fn parse_target(addr: &str) -> Result<Target, ClientError> {
    let with_scheme = if addr.contains("://") { addr.to_string() } else { format!("http://{addr}") };
    let uri: http::Uri = with_scheme.parse().map_err(|_| ClientError::InvalidAddress(addr.into()))?;
    let tls = match uri.scheme_str() {
        Some("http") => false,
        Some("https") => true,
        _ => return Err(ClientError::InvalidAddress(format!("{addr} (use http:// or https://)"))),
    };
    let host = uri.host().ok_or_else(|| ClientError::InvalidAddress(addr.into()))?;
    let host = host.trim_start_matches('[').trim_end_matches(']').to_string();
    let port = uri.port_u16().unwrap_or(50051);
    Ok(Target { tls, host, port })
}

async fn resolve(targets: &[Target]) -> HashMap<SocketAddr, usize> {
    let mut out = HashMap::new();
    for (k, t) in targets.iter().enumerate() {
        if let Ok(addrs) = tokio::net::lookup_host((t.host.as_str(), t.port)).await {
            for a in addrs {
                out.entry(a).or_insert(k);
            }
        }
    }
    out
}

fn endpoint(t: &Target, addr: SocketAddr, o: &ConnectOptions) -> Result<Endpoint, ClientError> {
    let scheme = if t.tls { "https" } else { "http" };
    let mut e = Endpoint::from_shared(format!("{scheme}://{addr}"))
        .map_err(|e| ClientError::InvalidAddress(e.to_string()))?
        .connect_timeout(o.connect_timeout)
        .tcp_nodelay(true)
        .http2_keep_alive_interval(Duration::from_secs(30))
        .keep_alive_while_idle(true);
    if t.tls {
        let mut tls = ClientTlsConfig::new().domain_name(o.tls_domain.clone().unwrap_or_else(|| t.host.clone()));
        if let Some(ca) = &o.ca_pem {
            tls = tls.ca_certificate(Certificate::from_pem(ca));
        }
        e = e.tls_config(tls).map_err(|e| ClientError::Connect(format!("TLS: {e}")))?;
    }
    Ok(e)
}

impl Client {
    /// Connects to every address the given ones resolve to (`host:port`,
    /// `http://host:port` or `https://host:port`; port 50051 by default) and balances calls
    /// over them. Fails when no address resolves; a server that is not up yet is retried
    /// by the calls.
    pub async fn connect(addrs: &[impl AsRef<str>], options: ConnectOptions) -> Result<Client, ClientError> {
        if addrs.is_empty() {
            return Err(ClientError::InvalidAddress("no address given".into()));
        }
        let targets: Vec<Target> = addrs.iter().map(|a| parse_target(a.as_ref())).collect::<Result<_, _>>()?;
        let found = resolve(&targets).await;
        if found.is_empty() {
            let names: Vec<&str> = addrs.iter().map(|a| a.as_ref()).collect();
            return Err(ClientError::Connect(format!("{} did not resolve to any address", names.join(", "))));
        }
        let (channel, tx) = Channel::balance_channel::<SocketAddr>(64);
        for (&a, &k) in &found {
            let e = endpoint(&targets[k], a, &options)?;
            tx.send(Change::Insert(a, e)).await.map_err(|_| ClientError::Connect("balancer closed".into()))?;
        }
        let resolver = options.resolve_interval.map(|every| {
            let o = options.clone();
            let mut known: Vec<SocketAddr> = found.keys().copied().collect();
            Arc::new(ResolverGuard(tokio::spawn(async move {
                loop {
                    tokio::time::sleep(every).await;
                    let now = resolve(&targets).await;
                    // A failed lookup keeps the last known addresses.
                    if now.is_empty() {
                        continue;
                    }
                    for (&a, &k) in &now {
                        if !known.contains(&a)
                            && let Ok(e) = endpoint(&targets[k], a, &o)
                            && tx.send(Change::Insert(a, e)).await.is_err()
                        {
                            return;
                        }
                    }
                    for a in known.iter().filter(|a| !now.contains_key(a)) {
                        if tx.send(Change::Remove(*a)).await.is_err() {
                            return;
                        }
                    }
                    known = now.keys().copied().collect();
                }
            })))
        });
        let token = match &options.token {
            Some(t) => Some(
                format!("Bearer {}", t.trim())
                    .parse::<MetadataValue<Ascii>>()
                    .map_err(|_| ClientError::InvalidAddress("the token is not valid header text".into()))?,
            ),
            None => None,
        };
        let stub = pb::reconstructor_client::ReconstructorClient::with_interceptor(channel, Auth(token))
            .max_decoding_message_size(options.max_message_bytes)
            .max_encoding_message_size(options.max_message_bytes);
        Ok(Client { stub, options, _resolver: resolver })
    }

    fn request<T>(&self, msg: T) -> tonic::Request<T> {
        let mut r = tonic::Request::new(msg);
        if let Some(t) = self.options.timeout {
            r.set_timeout(t);
        }
        r
    }

    /// Retries `call` on UNAVAILABLE or a broken connection, with exponential backoff and jitter.
    async fn with_retries<T, F, Fut>(&self, mut call: F) -> Result<T, ClientError>
    where
        F: FnMut() -> Fut,
        Fut: std::future::Future<Output = Result<T, tonic::Status>>,
    {
        let mut attempt = 0u32;
        loop {
            match call().await {
                Ok(v) => return Ok(v),
                Err(s) if retriable(&s) && attempt < self.options.retries => {
                    let base = self.options.backoff.saturating_mul(1 << attempt.min(10));
                    // Jitter from the clock's low bits: spreads many clients' retries apart.
                    let nanos = std::time::SystemTime::now()
                        .duration_since(std::time::UNIX_EPOCH)
                        .map_or(0, |d| d.subsec_nanos());
                    let jitter = 0.5 + (nanos % 1000) as f64 / 1000.0;
                    tokio::time::sleep(base.mul_f64(jitter)).await;
                    attempt += 1;
                }
                Err(s) => return Err(ClientError::Status(local_deadline(s))),
            }
        }
    }

    /// The model's topology and coefficient layout.
    pub async fn model(&self) -> Result<ModelTopology, ClientError> {
        let info = self
            .with_retries(|| {
                let mut stub = self.stub.clone();
                let req = self.request(pb::GetModelRequest {});
                async move { stub.get_model(req).await.map(|r| r.into_inner()) }
            })
            .await?;
        ModelTopology::from_message(info)
    }

    /// Reconstructs one photo.
    pub async fn reconstruct(&self, request: Request) -> Result<Reconstruction, ClientError> {
        let msg = request.into_message();
        let answer = self
            .with_retries(|| {
                let mut stub = self.stub.clone();
                let req = self.request(msg.clone());
                async move { stub.reconstruct(req).await.map(|r| r.into_inner()) }
            })
            .await?;
        Reconstruction::from_message(answer)
    }

    /// Reconstructs many photos over one stream, at most `concurrency` unanswered at a
    /// time. Yields `(id, result)` as each photo finishes (not in request order); a photo
    /// the server refused yields its own error and the stream goes on. A stream-level
    /// failure yields one `Err` and ends the stream: the photos not yet answered are the
    /// caller's to send again.
    pub async fn reconstruct_stream<S>(
        &self,
        requests: S,
        concurrency: usize,
    ) -> Result<
        impl Stream<Item = Result<(String, Result<Reconstruction, ClientError>), ClientError>> + use<S>,
        ClientError,
    >
    where
        S: Stream<Item = Request> + Send + 'static,
    {
        let window = Arc::new(Semaphore::new(concurrency.max(1)));
        let (tx, rx) = mpsc::channel::<pb::ReconstructRequest>(1);
        let feeder_window = window.clone();
        tokio::spawn(async move {
            tokio::pin!(requests);
            while let Some(r) = requests.next().await {
                let Ok(permit) = feeder_window.acquire().await else { return };
                permit.forget();
                if tx.send(r.into_message()).await.is_err() {
                    return;
                }
            }
        });
        let req = self.request(tokio_stream::wrappers::ReceiverStream::new(rx));
        let inbound = self
            .stub
            .clone()
            .reconstruct_stream(req)
            .await
            .map_err(|s| ClientError::Status(local_deadline(s)))?
            .into_inner();
        Ok(inbound.map(move |item| match item {
            Ok(m) => {
                window.add_permits(1);
                let id = m.id.clone();
                Ok((id, Reconstruction::from_message(m)))
            }
            Err(s) => Err(ClientError::Status(local_deadline(s))),
        }))
    }
}

#[cfg(test)]
mod retry_tests {
    use super::*;

    #[test]
    fn broken_connections_are_retried_and_callers_mistakes_and_deadlines_are_not() {
        use tonic::{Code, Status};
        // As tonic words them (seen against a container whose server was still starting).
        assert!(retriable(&Status::new(Code::Cancelled, "The operation was cancelled: operation was canceled")));
        assert!(retriable(&Status::new(Code::Unknown, "transport error")));
        assert!(retriable(&Status::unavailable("connection refused")));
        assert!(!retriable(&Status::new(Code::Cancelled, "Timeout expired")));
        assert!(!retriable(&Status::invalid_argument("not an image")));
        assert!(!retriable(&Status::new(Code::Cancelled, "the caller went away")));
    }
}
