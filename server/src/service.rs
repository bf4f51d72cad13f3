//! The RPC handlers: deadlines, admission, stream driving and per-call metrics. The work
//! itself is the [`Engine`]'s.

use std::pin::Pin;
use std::sync::{Arc, OnceLock};
use std::time::{Duration, Instant};

use tokio::sync::mpsc;
use tokio::task::JoinSet;
use tokio_stream::Stream;
use tokio_stream::wrappers::ReceiverStream;
use tonic::{Code, Request, Response, Status, Streaming};
use tracing::Instrument;

use crate::convert;
use crate::engine::{Engine, Job, deadline_exceeded};
use crate::metrics as m;
use facerecon_proto::v1 as pb;

/// Shared by the handlers; filled once the model is loaded.
pub struct State {
    pub engine: OnceLock<Arc<Engine>>,
    pub model_info: OnceLock<pb::ModelInfo>,
    pub max_faces: u32,
}

#[derive(Clone)]
pub struct Service {
    pub state: Arc<State>,
}

/// When the call arrived (stamped by the interceptor, before the body is read): the start
/// of its deadline.
#[derive(Clone, Copy)]
pub struct Arrival(pub Instant);

/// Our own deadline fires this much before tonic's: tonic answers an expired
/// `grpc-timeout` with CANCELLED, the contract says DEADLINE_EXCEEDED.
const DEADLINE_MARGIN: Duration = Duration::from_millis(2);

/// The call's deadline from its `grpc-timeout` header, if any.
fn deadline_of<T>(req: &Request<T>) -> Option<Instant> {
    let start = req.extensions().get::<Arrival>().map_or_else(Instant::now, |a| a.0);
    let timeout = parse_grpc_timeout(req.metadata().get("grpc-timeout")?.to_str().ok()?)?;
    Some(start + timeout.saturating_sub(DEADLINE_MARGIN))
}

/// `grpc-timeout`: at most 8 digits and a unit (H, M, S, m, u, n).
pub fn parse_grpc_timeout(v: &str) -> Option<Duration> {
    if v.len() < 2 || v.len() > 9 {
        return None;
    }
    let (digits, unit) = v.split_at(v.len() - 1);
    let n: u64 = digits.parse().ok()?;
    Some(match unit {
        "H" => Duration::from_secs(n * 3600),
        "M" => Duration::from_secs(n * 60),
        "S" => Duration::from_secs(n),
        "m" => Duration::from_millis(n),
        "u" => Duration::from_micros(n),
        "n" => Duration::from_nanos(n),
        _ => return None,
    })
}

struct InFlight;
impl InFlight {
    fn new() -> Self {
        metrics::gauge!(m::IN_FLIGHT).increment(1.0);
        InFlight
    }
}
impl Drop for InFlight {
    fn drop(&mut self) {
        metrics::gauge!(m::IN_FLIGHT).decrement(1.0);
    }
}

fn code_label(code: Code) -> String {
    format!("{code:?}")
}

fn record(rpc: &'static str, start: Instant, code: Code) {
    let code = code_label(code);
    metrics::histogram!(m::REQUEST_SECONDS, "rpc" => rpc, "code" => code.clone()).record(start.elapsed().as_secs_f64());
    metrics::counter!(m::REQUESTS, "rpc" => rpc, "code" => code).increment(1);
}

/// One call's metrics, recorded once: with its status, or as CANCELLED when dropped unfinished.
struct Call {
    rpc: &'static str,
    start: Instant,
    done: bool,
}

impl Call {
    fn finish(&mut self, code: Code) {
        self.done = true;
        record(self.rpc, self.start, code);
    }
}

impl Drop for Call {
    fn drop(&mut self) {
        if !self.done {
            record(self.rpc, self.start, Code::Cancelled);
        }
    }
}

impl Service {
    fn engine(&self) -> Result<Arc<Engine>, Status> {
        self.state.engine.get().cloned().ok_or_else(|| Status::unavailable("the model is still loading; retry shortly"))
    }

    async fn reconstruct_one(&self, req: Request<pb::ReconstructRequest>) -> Result<pb::ReconstructResponse, Status> {
        let engine = self.engine()?;
        let deadline = deadline_of(&req);
        let v = convert::validate(req.into_inner(), self.state.max_faces, engine.has_encoder())?;
        let span = tracing::info_span!("reconstruct", id = %v.id, bytes = v.image.len());
        async move {
            let admitted = engine.try_admit()?;
            let job = Job { id: v.id, image: v.image, options: v.options, wanted: v.wanted, deadline };
            let work = engine.run(job, &admitted);
            let r = match deadline {
                Some(d) => tokio::time::timeout_at(d.into(), work).await.map_err(|_| deadline_exceeded())?,
                None => work.await,
            };
            match &r {
                Ok(resp) => tracing::info!(faces = resp.faces.len(), "done"),
                Err(s) => tracing::info!(code = ?s.code(), message = s.message(), "failed"),
            }
            r
        }
        .instrument(span)
        .await
    }
}

type ResponseStream = Pin<Box<dyn Stream<Item = Result<pb::ReconstructResponse, Status>> + Send>>;

/// Responses buffered per stream before its tasks wait for the client to read.
const STREAM_WINDOW: usize = 32;

#[tonic::async_trait]
impl pb::reconstructor_server::Reconstructor for Service {
    async fn reconstruct(
        &self,
        req: Request<pb::ReconstructRequest>,
    ) -> Result<Response<pb::ReconstructResponse>, Status> {
        let _f = InFlight::new();
        // Records CANCELLED if the caller goes away first (tonic then drops this future).
        let mut call = Call { rpc: "Reconstruct", start: Instant::now(), done: false };
        let r = self.reconstruct_one(req).await;
        call.finish(r.as_ref().err().map_or(Code::Ok, |s| s.code()));
        r.map(Response::new)
    }

    type ReconstructStreamStream = ResponseStream;

    async fn reconstruct_stream(
        &self,
        req: Request<Streaming<pb::ReconstructRequest>>,
    ) -> Result<Response<ResponseStream>, Status> {
        let engine = self.engine()?;
        let deadline = deadline_of(&req);
        let max_faces = self.state.max_faces;
        let inbound = req.into_inner();
        let (tx, rx) = mpsc::channel(STREAM_WINDOW);
        let span = tracing::info_span!("stream");
        tokio::spawn(drive_stream(engine, inbound, tx, deadline, max_faces).instrument(span));
        Ok(Response::new(Box::pin(ReceiverStream::new(rx))))
    }

    async fn get_model(&self, _req: Request<pb::GetModelRequest>) -> Result<Response<pb::ModelInfo>, Status> {
        let start = Instant::now();
        let r = self
            .state
            .model_info
            .get()
            .cloned()
            .ok_or_else(|| Status::unavailable("the model is still loading; retry shortly"));
        record("GetModel", start, r.as_ref().err().map_or(Code::Ok, |s| s.code()));
        r.map(Response::new)
    }
}

fn item_error(id: String, s: &Status) -> pb::ReconstructResponse {
    pb::ReconstructResponse {
        id,
        error: Some(pb::Error { code: s.code() as i32, message: s.message().to_string() }),
        ..Default::default()
    }
}

/// Reads a stream's requests, runs each as its own task (admission waits: back-pressure),
/// and sends each response as it finishes. Ends when the client has sent everything and
/// every answer is out, or at once when the client goes away (remaining work dropped) or
/// the deadline passes (DEADLINE_EXCEEDED).
async fn drive_stream(
    engine: Arc<Engine>,
    mut inbound: Streaming<pb::ReconstructRequest>,
    tx: mpsc::Sender<Result<pb::ReconstructResponse, Status>>,
    deadline: Option<Instant>,
    max_faces: u32,
) {
    let _f = InFlight::new();
    let start = Instant::now();
    let expired = async move {
        match deadline {
            Some(d) => tokio::time::sleep_until(d.into()).await,
            None => std::future::pending().await,
        }
    };
    tokio::pin!(expired);
    let mut tasks = JoinSet::new();
    let mut reading = true;
    let code = loop {
        tokio::select! {
            _ = tx.closed() => break Code::Cancelled,
            _ = &mut expired => {
                let _ = tx.send(Err(deadline_exceeded())).await;
                break Code::DeadlineExceeded;
            }
            Some(_) = tasks.join_next(), if !tasks.is_empty() => {}
            msg = inbound.message(), if reading => match msg {
                Ok(Some(req)) => {
                    let id = req.id.clone();
                    let v = match convert::validate(req, max_faces, engine.has_encoder()) {
                        Ok(v) => v,
                        Err(s) => {
                            record("ReconstructStream.item", Instant::now(), s.code());
                            if tx.send(Ok(item_error(id, &s))).await.is_err() {
                                break Code::Cancelled;
                            }
                            continue;
                        }
                    };
                    // Back-pressure: wait for room, unless the client leaves or time runs out.
                    let admitted = tokio::select! {
                        a = engine.admit() => a,
                        _ = tx.closed() => break Code::Cancelled,
                        _ = &mut expired => {
                            let _ = tx.send(Err(deadline_exceeded())).await;
                            break Code::DeadlineExceeded;
                        }
                    };
                    let engine = engine.clone();
                    let tx = tx.clone();
                    let span = tracing::info_span!("item", id = %v.id);
                    tasks.spawn(
                        async move {
                            let t = Instant::now();
                            let job = Job { id: v.id, image: v.image, options: v.options, wanted: v.wanted, deadline };
                            let r = engine.run(job, &admitted).await;
                            drop(admitted);
                            record("ReconstructStream.item", t, r.as_ref().err().map_or(Code::Ok, |s| s.code()));
                            let item = r.unwrap_or_else(|s| item_error(id, &s));
                            let _ = tx.send(Ok(item)).await;
                        }
                        .instrument(span),
                    );
                }
                Ok(None) => reading = false,
                Err(s) => {
                    // The stream itself is broken (a message over the size limit, a
                    // malformed frame): nothing after it can be read.
                    let s = crate::fix_size_status(s);
                    let code = s.code();
                    let _ = tx.send(Err(s)).await;
                    break code;
                }
            },
            else => break Code::Ok,
        }
        if !reading && tasks.is_empty() {
            break Code::Ok;
        }
    };
    // Dropping the JoinSet aborts what is left (its work is dropped before it starts).
    drop(tasks);
    record("ReconstructStream", start, code);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn grpc_timeout_header() {
        assert_eq!(parse_grpc_timeout("100m"), Some(Duration::from_millis(100)));
        assert_eq!(parse_grpc_timeout("2S"), Some(Duration::from_secs(2)));
        assert_eq!(parse_grpc_timeout("1H"), Some(Duration::from_secs(3600)));
        assert_eq!(parse_grpc_timeout("5"), None);
        assert_eq!(parse_grpc_timeout("123456789m"), None, "at most 8 digits");
        assert_eq!(parse_grpc_timeout("-1m"), None);
        assert_eq!(parse_grpc_timeout("1x"), None);
    }
}
