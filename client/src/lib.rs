//! The facerecon client library: talk to a `facerecon-server` from Rust, without the CLI.
//!
//! ```no_run
//! # async fn demo() -> Result<(), facerecon_client::ClientError> {
//! use facerecon_client::{Client, ConnectOptions, Request};
//! let client = Client::connect(&["http://127.0.0.1:50051"], ConnectOptions::default()).await?;
//! let photo = std::fs::read("photo.jpg").expect("photo");
//! let result = client.reconstruct(Request::new("photo.jpg", photo)).await?;
//! for face in &result.faces {
//!     if let Ok(fit) = &face.fit {
//!         println!("{:?} {:.2} px", face.face_box, fit.landmark_rms_px);
//!     }
//! }
//! # Ok(()) }
//! ```
//!
//! * [`connection`]: [`Client`] — one address or many, balanced (for a headless Kubernetes
//!   service, the name is re-resolved so that new pods join); TLS; bearer token; retries
//!   with backoff on UNAVAILABLE; bounded-concurrency streaming.
//! * [`results`]: typed results (coefficients, meshes, pictures) made from the messages.

pub mod connection;
pub mod results;

pub use connection::{Client, ClientError, ConnectOptions, Request};
pub use facerecon_proto::v1 as proto;
pub use results::{Face, Fit, ModelTopology, Reconstruction};
