//! What `reconstruct` and `bulk` share: the server flags, the connection, the request
//! options, and writing an answer in `fit`'s file layout.

use std::path::{Path, PathBuf};
use std::time::Duration;

use anyhow::Context;
use facerecon_client::{Client, ConnectOptions, ModelTopology, Reconstruction, proto as pb};

use super::files;

#[derive(clap::Args, Clone)]
pub struct ServerArgs {
    /// Server address(es): `host:port`, `http://…` or `https://…`. Several (or a name that
    /// resolves to several, e.g. a headless Kubernetes service) are balanced.
    #[arg(long, env = "FACERECON_SERVER", value_delimiter = ',', default_value = "http://127.0.0.1:50051")]
    pub server: Vec<String>,
    /// Bearer token, when the server asks for one.
    #[arg(long, env = "FACERECON_AUTH_TOKEN", hide_env_values = true)]
    pub token: Option<String>,
    /// PEM root certificate for an `https://` server.
    #[arg(long)]
    pub ca: Option<PathBuf>,
    /// Deadline per photo (seconds) for `reconstruct`, per run for `bulk`.
    #[arg(long)]
    pub timeout: Option<f64>,
}

#[derive(clap::Args, Clone)]
pub struct RequestArgs {
    /// Where each face's fit starts: `landmarks` (the landmark fit) or `encoder` (the
    /// server's learned encoder, in one pass per batch; a server started without one
    /// answers UNIMPLEMENTED).
    #[arg(long, value_enum, default_value = "landmarks")]
    pub start: StartArg,
    /// `landmarks` (milliseconds per face), `coarse` (the photometric fit, about a second)
    /// or `full` (then a displacement map, seconds; its 16-bit PNG is written beside the
    /// record); with `--start encoder`, `none` is the encoder's answer alone (and the
    /// default).
    #[arg(long, value_enum)]
    pub refine: Option<RefineArg>,
    /// At most this many faces per photo (0: the server's default).
    #[arg(long, default_value_t = 0)]
    pub max_faces: u32,
    /// Write JSON records and pictures only, no mesh files.
    #[arg(long)]
    pub no_meshes: bool,
    /// Skip the overlay and side-by-side pictures.
    #[arg(long)]
    pub no_pictures: bool,
}

#[derive(Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum StartArg {
    Landmarks,
    Encoder,
}

#[derive(Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum RefineArg {
    None,
    Landmarks,
    Coarse,
    Full,
}

impl RequestArgs {
    /// The request's options; a start and refinement that do not go together (refining
    /// the encoder's answer by the landmark fit, or the landmark start unrefined) are an
    /// error here, before any photo is sent.
    pub fn options(&self) -> anyhow::Result<pb::Options> {
        let refine = match (self.start, self.refine) {
            (StartArg::Encoder, None) => RefineArg::None,
            (StartArg::Landmarks, None) => RefineArg::Landmarks,
            (StartArg::Encoder, Some(RefineArg::Landmarks)) => {
                anyhow::bail!("--start encoder refines with none, coarse or full, not landmarks")
            }
            (StartArg::Landmarks, Some(RefineArg::None)) => {
                anyhow::bail!("--refine none is the encoder alone: add --start encoder")
            }
            (_, Some(r)) => r,
        };
        Ok(pb::Options {
            start: match self.start {
                StartArg::Landmarks => pb::Start::Landmarks,
                StartArg::Encoder => pb::Start::Encoder,
            } as i32,
            refine: match refine {
                RefineArg::None => pb::Refine::None,
                RefineArg::Landmarks => pb::Refine::Landmarks,
                RefineArg::Coarse => pb::Refine::Coarse,
                RefineArg::Full => pb::Refine::Full,
            } as i32,
            max_faces: self.max_faces,
            outputs: Some(pb::Outputs {
                mesh_arrays: !self.no_meshes,
                overlay: !self.no_pictures,
                side_by_side: !self.no_pictures,
                displacement_map: refine == RefineArg::Full,
                texture: !self.no_meshes,
                ..Default::default()
            }),
            ..Default::default()
        })
    }
}

pub async fn connect(args: &ServerArgs, whole_run_timeout: bool) -> anyhow::Result<Client> {
    let ca_pem = match &args.ca {
        Some(p) => Some(std::fs::read(p).with_context(|| format!("reading {}", p.display()))?),
        None => None,
    };
    let options = ConnectOptions {
        token: args.token.clone(),
        ca_pem,
        timeout: match (args.timeout, whole_run_timeout) {
            (Some(t), _) if t > 0.0 && t.is_finite() => Some(Duration::from_secs_f64(t)),
            (Some(t), _) => anyhow::bail!("--timeout {t}: must be a positive number of seconds"),
            (None, _) => None,
        },
        ..ConnectOptions::default()
    };
    Ok(Client::connect(&args.server, options).await?)
}

/// Writes an answer in `fit`'s layout; returns (faces, fitted).
pub fn write(model: &ModelTopology, answer: &Reconstruction, out: &Path, stem: &str) -> anyhow::Result<(usize, usize)> {
    let mut fitted = 0;
    for (k, face) in answer.faces.iter().enumerate() {
        let Some(record) = face.record(&model.info) else { continue };
        fitted += 1;
        let fit = face.fit.as_ref().ok();
        let mesh = match fit.and_then(|f| f.mesh.as_ref()) {
            Some(arrays) => Some(model.mesh(arrays)?),
            None => None,
        };
        let face_files = files::FaceFiles {
            record: &record,
            mesh: mesh.as_ref(),
            texture_png: fit.and_then(|f| f.texture_png.as_deref()),
            displacement_png: fit.and_then(|f| f.displacement_png.as_deref()),
        };
        files::write_face(&face_files, &out.join(format!("{stem}-face{}", k + 1)))?;
    }
    if let Some(png) = &answer.overlay_png {
        files::write_picture(out, stem, files::OVERLAY, png)?;
    }
    if let Some(png) = &answer.side_by_side_png {
        files::write_picture(out, stem, files::SIDE_BY_SIDE, png)?;
    }
    Ok((answer.faces.len(), fitted))
}

/// A tokio runtime for the remote subcommands (the local ones need none).
pub fn runtime() -> anyhow::Result<tokio::runtime::Runtime> {
    tokio::runtime::Builder::new_multi_thread().enable_all().build().context("starting the async runtime")
}
