//! Server configuration. Sources, each overriding the one before: built-in defaults, a
//! TOML file (`--config FILE` / `FACERECON_CONFIG`), environment variables
//! (`FACERECON_*`), command-line flags. `facerecon-server --help` lists every setting with
//! its variable and default; `deploy/facerecon.toml` is a commented example file.

use std::net::SocketAddr;
use std::path::{Path, PathBuf};

use anyhow::Context;
use facerecon_nn::{Compute, InferencePrecision};

/// Everything the server is configured with.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Config {
    /// gRPC address. Default `127.0.0.1:50051` (use `0.0.0.0:50051` in a container).
    pub listen: SocketAddr,
    /// Prometheus `/metrics` address; `None` turns the exporter off. Default `127.0.0.1:9464`.
    pub metrics_listen: Option<SocketAddr>,
    /// Model file; `None`: the ICT model built from the shared ICT-FaceKit folder.
    pub model: Option<PathBuf>,
    /// dlib 68-point shape predictor.
    pub landmark_model: PathBuf,
    /// The encoder requests may start from: the weights released with this version (the
    /// default, for the default model), a weights file (`facerecon-train`'s
    /// `encoder-f16.safetensors`), or none (requests start from the landmark fit only).
    pub encoder: EncoderChoice,
    /// Where the encoder runs: `cpu` (ONNX Runtime, the default), `gpu` (burn's Vulkan
    /// backend; servers built with `--features gpu`, decision 0901) or `wgsl` (the encoder's
    /// own compute shaders on the first Vulkan GPU, every build; decision 0906).
    pub encoder_device: Compute,
    /// What the CPU encoder computes in: `fp32` (the default) or `int8` (needs the
    /// calibration file beside the weights, `<weights>.int8.json`; decision 0903).
    pub encoder_precision: InferencePrecision,
    /// What draws the pictures (overlay, side-by-side): `auto` (the default: the wgpu
    /// renderer on a thread of its own when a Vulkan device that is not a CPU
    /// implementation is there, else the CPU rasteriser, the faster on lavapipe), `cpu`, or
    /// `gpu` (the wgpu thread on whatever adapter there is, lavapipe included).
    pub renderer: RendererChoice,
    /// Faces per batch handed to the backend at most.
    pub max_batch_size: usize,
    /// How long the batcher waits for a batch to fill, ms. 0 (default): greedy, a batch is
    /// whatever is queued when the backend is free (docs/BENCHMARKS.md measures both).
    pub max_queue_delay_ms: u64,
    /// Photos admitted at once (queued or in work). A unary call beyond it gets
    /// RESOURCE_EXHAUSTED at once; a stream waits.
    pub queue_capacity: usize,
    /// Threads for decoding, detection, fitting and outputs; 0: one per core.
    pub cpu_threads: usize,
    /// Largest gRPC message accepted or sent, bytes (photos exceed tonic's 4 MiB default).
    /// Default 32 MiB.
    pub max_message_bytes: usize,
    /// Largest decoded photo, pixels (width × height, read from the header). Default 50 M.
    pub max_image_pixels: u64,
    /// Upper bound of a request's `max_faces`; also its default when the request gives 0.
    pub max_faces: u32,
    /// PEM certificate chain and key: serve TLS when both are set.
    pub tls_cert: Option<PathBuf>,
    pub tls_key: Option<PathBuf>,
    /// When set, reconstruction calls need `authorization: Bearer <token>`. Health and
    /// reflection stay open (probes). Prefer the environment variable to the file.
    pub auth_token: Option<String>,
    /// On SIGTERM/SIGINT, in-flight work gets this long to finish, seconds.
    pub shutdown_grace_s: u64,
    /// `text` or `json` log lines on stderr (level from `RUST_LOG`, default `info`).
    pub log_format: LogFormat,
    /// OTLP/gRPC collector to export trace spans to, e.g. `http://otel-collector:4317`;
    /// `None` (the default): no export.
    pub otlp_endpoint: Option<String>,
}

/// Which encoder the server loads. Written `released`, `none`, or a path.
#[derive(Clone, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(from = "String", into = "String")]
pub enum EncoderChoice {
    /// No encoder: START_ENCODER requests are answered UNIMPLEMENTED.
    None,
    /// [`facerecon_nn::released::path`], when the file is there, ONNX Runtime (or the GPU
    /// backend) loads, and its coefficient layout is the model's (it was trained for the
    /// default model); otherwise the server logs why and serves without an encoder.
    #[default]
    Released,
    File(PathBuf),
}

impl From<String> for EncoderChoice {
    fn from(s: String) -> Self {
        match s.as_str() {
            "none" | "" => EncoderChoice::None,
            "released" => EncoderChoice::Released,
            _ => EncoderChoice::File(PathBuf::from(s)),
        }
    }
}

impl From<EncoderChoice> for String {
    fn from(c: EncoderChoice) -> String {
        match c {
            EncoderChoice::None => "none".into(),
            EncoderChoice::Released => "released".into(),
            EncoderChoice::File(p) => p.to_string_lossy().into_owned(),
        }
    }
}

impl std::str::FromStr for EncoderChoice {
    type Err = std::convert::Infallible;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Ok(EncoderChoice::from(s.to_string()))
    }
}

/// Which producer draws the pictures (see [`Config::renderer`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum RendererChoice {
    #[default]
    Auto,
    Cpu,
    Gpu,
}

impl From<RendererChoice> for facerecon_raster::draw::Choice {
    fn from(c: RendererChoice) -> Self {
        match c {
            RendererChoice::Auto => facerecon_raster::draw::Choice::Auto,
            RendererChoice::Cpu => facerecon_raster::draw::Choice::Cpu,
            RendererChoice::Gpu => facerecon_raster::draw::Choice::Gpu,
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum LogFormat {
    Text,
    Json,
}

impl Default for Config {
    fn default() -> Self {
        Config {
            listen: SocketAddr::from(([127, 0, 0, 1], 50051)),
            metrics_listen: Some(SocketAddr::from(([127, 0, 0, 1], 9464))),
            model: None,
            landmark_model: PathBuf::from(facerecon_vision::landmarks::DEFAULT_MODEL_PATH),
            encoder: EncoderChoice::Released,
            encoder_device: Compute::Cpu,
            encoder_precision: InferencePrecision::Fp32,
            renderer: RendererChoice::Auto,
            max_batch_size: 16,
            max_queue_delay_ms: 0,
            queue_capacity: 64,
            cpu_threads: 0,
            max_message_bytes: 32 << 20,
            max_image_pixels: facerecon_vision::decode::DecodeLimits::DEFAULT_MAX_PIXELS,
            max_faces: 16,
            tls_cert: None,
            tls_key: None,
            auth_token: None,
            shutdown_grace_s: 30,
            log_format: LogFormat::Text,
            otlp_endpoint: None,
        }
    }
}

impl Config {
    /// Reads a TOML file over the defaults (unknown keys are an error).
    pub fn from_file(path: &Path) -> anyhow::Result<Config> {
        let text = std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
        toml::from_str(&text).with_context(|| format!("parsing {}", path.display()))
    }

    /// Checks values that the types allow but the server cannot run with.
    pub fn validate(&self) -> anyhow::Result<()> {
        anyhow::ensure!(self.max_batch_size >= 1, "max_batch_size must be at least 1");
        anyhow::ensure!(self.queue_capacity >= 1, "queue_capacity must be at least 1");
        anyhow::ensure!(self.max_faces >= 1, "max_faces must be at least 1");
        anyhow::ensure!(self.max_message_bytes >= 1024, "max_message_bytes must be at least 1024");
        anyhow::ensure!(
            self.tls_cert.is_some() == self.tls_key.is_some(),
            "tls_cert and tls_key go together: set both or neither"
        );
        anyhow::ensure!(
            self.encoder_precision == InferencePrecision::Fp32 || self.encoder_device == Compute::Cpu,
            "encoder_precision = {} runs on the CPU (ONNX Runtime); the GPU encoder is fp32",
            self.encoder_precision
        );
        anyhow::ensure!(
            self.encoder_device != Compute::Gpu || Compute::GPU_BUILT,
            "encoder_device = gpu, but this server was built without the GPU backend (build with `--features gpu`)"
        );
        if let Some(e) = &self.otlp_endpoint {
            crate::telemetry::validate_endpoint(e)?;
        }
        if let Some(t) = &self.auth_token {
            anyhow::ensure!(!t.trim().is_empty(), "auth_token is empty");
        }
        Ok(())
    }
}

/// Command-line flags; each may also come from its environment variable.
#[derive(Debug, Default, clap::Parser)]
#[command(name = "facerecon-server", version, about = "The facerecon gRPC service: photos to 3D faces")]
pub struct Args {
    /// TOML configuration file (keys as the flags, with `_` for `-`).
    #[arg(long, env = "FACERECON_CONFIG")]
    pub config: Option<PathBuf>,
    /// gRPC address [default: 127.0.0.1:50051].
    #[arg(long, env = "FACERECON_LISTEN")]
    pub listen: Option<SocketAddr>,
    /// Prometheus address, or `off` [default: 127.0.0.1:9464].
    #[arg(long, env = "FACERECON_METRICS_LISTEN")]
    pub metrics_listen: Option<String>,
    /// Model file [default: the ICT model from the shared folder].
    #[arg(long, env = "FACERECON_MODEL")]
    pub model: Option<PathBuf>,
    /// dlib 68-point shape predictor [default: the shared folder's].
    #[arg(long, env = "FACERECON_LANDMARK_MODEL")]
    pub landmark_model: Option<PathBuf>,
    /// Encoder requests may start from: `released` (the weights released with this version,
    /// for the default model), a weights file, or `none` [default: released].
    #[arg(long, env = "FACERECON_ENCODER")]
    pub encoder: Option<EncoderChoice>,
    /// Where the encoder runs: cpu (ONNX Runtime), gpu (burn Vulkan; `--features gpu`) or
    /// wgsl (the encoder's own shaders on the first Vulkan GPU) [default: cpu].
    #[arg(long, env = "FACERECON_ENCODER_DEVICE")]
    pub encoder_device: Option<Compute>,
    /// What the CPU encoder computes in: fp32, or int8 with the calibration beside the
    /// weights [default: fp32].
    #[arg(long, env = "FACERECON_ENCODER_PRECISION")]
    pub encoder_precision: Option<InferencePrecision>,
    /// What draws the pictures: auto (wgpu on a real GPU, else the CPU rasteriser), cpu or
    /// gpu [default: auto].
    #[arg(long, env = "FACERECON_RENDERER", value_enum)]
    pub renderer: Option<RendererChoice>,
    /// Faces per batch at most [default: 16].
    #[arg(long, env = "FACERECON_MAX_BATCH_SIZE")]
    pub max_batch_size: Option<usize>,
    /// Batch fill wait, ms; 0 = greedy [default: 0].
    #[arg(long, env = "FACERECON_MAX_QUEUE_DELAY_MS")]
    pub max_queue_delay_ms: Option<u64>,
    /// Photos admitted at once [default: 64].
    #[arg(long, env = "FACERECON_QUEUE_CAPACITY")]
    pub queue_capacity: Option<usize>,
    /// CPU worker threads; 0 = one per core [default: 0].
    #[arg(long, env = "FACERECON_CPU_THREADS")]
    pub cpu_threads: Option<usize>,
    /// Largest message, bytes [default: 33554432].
    #[arg(long, env = "FACERECON_MAX_MESSAGE_BYTES")]
    pub max_message_bytes: Option<usize>,
    /// Largest photo, pixels [default: 50000000].
    #[arg(long, env = "FACERECON_MAX_IMAGE_PIXELS")]
    pub max_image_pixels: Option<u64>,
    /// Most faces per photo [default: 16].
    #[arg(long, env = "FACERECON_MAX_FACES")]
    pub max_faces: Option<u32>,
    /// PEM certificate chain (with --tls-key: serve TLS).
    #[arg(long, env = "FACERECON_TLS_CERT")]
    pub tls_cert: Option<PathBuf>,
    /// PEM private key.
    #[arg(long, env = "FACERECON_TLS_KEY")]
    pub tls_key: Option<PathBuf>,
    /// Bearer token required by reconstruction calls.
    #[arg(long, env = "FACERECON_AUTH_TOKEN", hide_env_values = true)]
    pub auth_token: Option<String>,
    /// Seconds in-flight work gets after SIGTERM [default: 30].
    #[arg(long, env = "FACERECON_SHUTDOWN_GRACE_S")]
    pub shutdown_grace_s: Option<u64>,
    /// Log line format [default: text].
    #[arg(long, env = "FACERECON_LOG_FORMAT", value_enum)]
    pub log_format: Option<LogFormat>,
    /// Export trace spans over OTLP/gRPC to this collector (e.g. http://otel-collector:4317)
    /// [default: none].
    #[arg(long, env = "FACERECON_OTLP_ENDPOINT")]
    pub otlp_endpoint: Option<String>,
}

impl Args {
    /// Defaults, then the file, then environment and flags (clap reads both).
    pub fn resolve(self) -> anyhow::Result<Config> {
        let mut c = match &self.config {
            Some(p) => Config::from_file(p)?,
            None => Config::default(),
        };
        macro_rules! set {
            ($($f:ident),*) => { $( if let Some(v) = self.$f { c.$f = v; } )* };
        }
        macro_rules! set_some {
            ($($f:ident),*) => { $( if let Some(v) = self.$f { c.$f = Some(v); } )* };
        }
        set!(
            listen,
            landmark_model,
            encoder,
            encoder_device,
            encoder_precision,
            max_batch_size,
            max_queue_delay_ms,
            queue_capacity
        );
        set!(cpu_threads, renderer);
        set!(max_message_bytes, max_image_pixels, max_faces, shutdown_grace_s, log_format);
        set_some!(model, tls_cert, tls_key, auth_token, otlp_endpoint);
        if let Some(m) = self.metrics_listen {
            c.metrics_listen = match m.as_str() {
                "off" | "" => None,
                a => Some(a.parse().with_context(|| format!("--metrics-listen {a:?}: not an address or `off`"))?),
            };
        }
        c.validate()?;
        Ok(c)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[test]
    fn layers_file_then_flags() {
        let dir = std::env::temp_dir().join(format!("facerecon-config-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("server.toml");
        std::fs::write(&file, "listen = \"0.0.0.0:6000\"\nmax_batch_size = 4\nmetrics_listen = \"127.0.0.1:7000\"\n")
            .unwrap();
        let args = Args::try_parse_from([
            "facerecon-server",
            "--config",
            file.to_str().unwrap(),
            "--max-batch-size",
            "8",
            "--metrics-listen",
            "off",
        ])
        .unwrap();
        let c = args.resolve().unwrap();
        assert_eq!(c.listen, "0.0.0.0:6000".parse().unwrap());
        assert_eq!(c.max_batch_size, 8, "a flag wins over the file");
        assert_eq!(c.metrics_listen, None);
        assert_eq!(c.queue_capacity, Config::default().queue_capacity);
    }

    #[test]
    fn the_encoder_is_released_none_or_a_file() {
        assert_eq!(Config::default().encoder, EncoderChoice::Released);
        let parse =
            |flag: &str| Args::try_parse_from(["facerecon-server", "--encoder", flag]).unwrap().resolve().unwrap();
        assert_eq!(parse("none").encoder, EncoderChoice::None);
        assert_eq!(parse("released").encoder, EncoderChoice::Released);
        assert_eq!(parse("runs/v2/w.safetensors").encoder, EncoderChoice::File("runs/v2/w.safetensors".into()));
        let c: Config = toml::from_str("encoder = \"none\"").unwrap();
        assert_eq!(c.encoder, EncoderChoice::None);
        assert_eq!(
            toml::to_string(&Config::default()).unwrap().lines().find(|l| l.starts_with("encoder =")),
            Some("encoder = \"released\"")
        );
    }

    /// The commented example file says the defaults.
    #[test]
    fn the_example_file_is_the_defaults() {
        let file = Path::new(env!("CARGO_MANIFEST_DIR")).join("../deploy/facerecon.toml");
        assert_eq!(Config::from_file(&file).unwrap(), Config::default());
    }

    #[test]
    fn rejects_unknown_keys_and_bad_values() {
        let dir = std::env::temp_dir().join(format!("facerecon-config-bad-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("server.toml");
        std::fs::write(&file, "listne = \"0.0.0.0:6000\"\n").unwrap();
        let e = Config::from_file(&file).unwrap_err();
        assert!(format!("{e:#}").contains("listne"), "{e:#}");
        let c = Config { max_batch_size: 0, ..Config::default() };
        assert!(c.validate().is_err());
        let c = Config { tls_cert: Some("a.pem".into()), ..Config::default() };
        assert!(c.validate().is_err());
        // The GPU path only where it is built in, said at start-up.
        let c = Config { encoder_device: Compute::Gpu, ..Config::default() };
        assert_eq!(c.validate().is_ok(), Compute::GPU_BUILT);
        let args = Args::try_parse_from(["facerecon-server", "--encoder-device", "gpu"]).unwrap();
        assert_eq!(args.encoder_device, Some(Compute::Gpu));
        assert!(Args::try_parse_from(["facerecon-server", "--encoder-device", "tpu"]).is_err());
        // int8 on the CPU only.
        let args = Args::try_parse_from(["facerecon-server", "--encoder-precision", "int8"]).unwrap();
        let c = args.resolve().unwrap();
        assert_eq!(c.encoder_precision, InferencePrecision::Int8);
        c.validate().unwrap();
        let c = Config { encoder_device: Compute::Gpu, ..c };
        assert!(format!("{:#}", c.validate().unwrap_err()).contains("CPU"));
        let c = Config { encoder_device: Compute::Wgsl, ..c };
        assert!(format!("{:#}", c.validate().unwrap_err()).contains("CPU"));
        // The shaders are in every build.
        let args = Args::try_parse_from(["facerecon-server", "--encoder-device", "wgsl"]).unwrap();
        args.resolve().unwrap().validate().unwrap();
        assert!(Args::try_parse_from(["facerecon-server", "--encoder-precision", "int4"]).is_err());
        // OTLP: a URL with a scheme and a host.
        for bad in ["collector:4317", "grpc://collector:4317", "http://", "not a url"] {
            let c = Config { otlp_endpoint: Some(bad.into()), ..Config::default() };
            assert!(c.validate().is_err(), "{bad}");
        }
        let c = Config { otlp_endpoint: Some("http://otel-collector:4317".into()), ..Config::default() };
        c.validate().unwrap();
        // The renderer, by file and by flag.
        let c: Config = toml::from_str("renderer = \"gpu\"").unwrap();
        assert_eq!(c.renderer, RendererChoice::Gpu);
        let args = Args::try_parse_from(["facerecon-server", "--renderer", "cpu"]).unwrap();
        assert_eq!(args.resolve().unwrap().renderer, RendererChoice::Cpu);
        assert!(Args::try_parse_from(["facerecon-server", "--renderer", "opengl"]).is_err());
    }
}
