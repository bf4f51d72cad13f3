//! `facerecon fit IMAGE… -o DIR [--refine landmarks] [--encoder W] [--json] [--pts]`: 3D
//! faces from photos, in-process. Per face `K` (1-based, largest first) of `<stem>`, in `DIR`:
//! `<stem>-face<K>.glb`, `.ply`, `.obj` (+ `.mtl`), `.json` (coefficients, landmarks,
//! residuals), `-texture.png` (the photo in UV space), `-displacement.png` at
//! `--refine full`, and per photo `<stem>-overlay.png` and `<stem>-sidebyside.png` (photo |
//! reconstruction | shape | albedo | shading, a row per face). `--json` prints one line per photo.

use std::path::{Path, PathBuf};

use std::process::ExitCode;

use anyhow::Context;

use super::{ImageJson, files};
use facerecon_model::MorphableModel;
use facerecon_recon::{FaceSource, Options, Pipeline, Refine, Start};
use facerecon_recon::{outputs, texture};
use facerecon_vision::pipeline::FrontEnd;

#[derive(clap::Args)]
pub struct FitArgs {
    /// Photos (JPEG, PNG, WebP).
    #[arg(required = true)]
    images: Vec<PathBuf>,
    /// Output folder (created if missing).
    #[arg(short, long)]
    out: PathBuf,
    /// How far to reconstruct: `landmarks` (pose, identity and expression from the 68
    /// landmarks, milliseconds) or `coarse` (then every coefficient, albedo and light
    /// included, by the photometric fit: about a second per face) or `full` (then a
    /// displacement map on the coarse surface, seconds per face; written as
    /// `<stem>-face<K>-displacement.png` and applied to the meshes). With `--encoder`:
    /// `none` (the encoder alone), `coarse` or `full` (the fits from the encoder's answer).
    /// Default: `landmarks`, or `none` with `--encoder`.
    #[arg(long, value_enum)]
    refine: Option<RefineArg>,
    /// Start from the learned encoder: `released` (the weights released with this version,
    /// for the default model), or a weights file (`facerecon-train` writes
    /// `encoder-f16.safetensors`).
    #[arg(long)]
    encoder: Option<PathBuf>,
    /// Where the encoder runs: `cpu` (ONNX Runtime), `gpu` (burn's Vulkan backend, in a
    /// build with `--features gpu`) or `wgsl` (the encoder's own shaders on the first Vulkan
    /// GPU).
    #[arg(long, default_value = "cpu")]
    encoder_device: facerecon_nn::Compute,
    /// What the CPU encoder computes in: `fp32`, or `int8` (needs `<weights>.int8.json`
    /// beside the weights, from `facerecon-calibrate`).
    #[arg(long, default_value = "fp32")]
    encoder_precision: facerecon_nn::InferencePrecision,
    /// One JSON object per photo on stdout (one per line).
    #[arg(long)]
    json: bool,
    /// Fit the iBUG `.pts` file beside each photo (same stem) instead of detecting.
    #[arg(long)]
    pts: bool,
    /// At most this many faces per photo (largest first).
    #[arg(long, default_value_t = 16)]
    max_faces: usize,
    /// Model file (default: the ICT model built from the shared ICT-FaceKit folder).
    #[arg(long)]
    model: Option<PathBuf>,
    /// dlib shape predictor file.
    #[arg(long, default_value = facerecon_vision::landmarks::DEFAULT_MODEL_PATH)]
    landmark_model: PathBuf,
    /// Write no mesh files (JSON and overlay only).
    #[arg(long)]
    no_meshes: bool,
}

#[derive(Clone, Copy, clap::ValueEnum)]
enum RefineArg {
    None,
    Landmarks,
    Coarse,
    Full,
}

#[derive(serde::Serialize)]
struct FaceJson {
    #[serde(rename = "box")]
    face_box: [f32; 4],
    landmarks: Vec<[f32; 2]>,
    fitted_landmarks: Option<Vec<[f32; 2]>>,
    coefficients: Option<facerecon_model::Coefficients>,
    residuals: Option<outputs::Residuals>,
    /// Why the face was not fitted (null when it was).
    error: Option<String>,
}

pub fn run(args: FitArgs) -> anyhow::Result<ExitCode> {
    let model: std::sync::Arc<MorphableModel> = match &args.model {
        Some(p) => {
            std::sync::Arc::new(MorphableModel::load(p).with_context(|| format!("loading model {}", p.display()))?)
        }
        None => facerecon_model::ict::load_default().context("building the default ICT model")?,
    };
    let front = FrontEnd::load_standard(&args.landmark_model)?;
    let mut pipeline = Pipeline::new(model, front)?;
    if let Some(w) = &args.encoder {
        let released = facerecon_nn::released::path();
        let w = if w.as_os_str() == "released" { &released } else { w };
        let encoder = facerecon_nn::encoder::load(w, args.encoder_device, args.encoder_precision, 2)
            .with_context(|| format!("loading the encoder {} ({})", w.display(), args.encoder_device))?;
        pipeline.set_encoder(encoder)?;
    }
    std::fs::create_dir_all(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
    let bar = (args.images.len() > 1).then(|| {
        indicatif::ProgressBar::new(args.images.len() as u64).with_style(
            indicatif::ProgressStyle::with_template("{bar:40} {pos}/{len} photos, {per_sec}, eta {eta}")
                .expect("valid progress template"),
        )
    });
    let mut failed = 0;
    for path in &args.images {
        if let Err(e) = one(&pipeline, &args, path) {
            let msg = format!("{}: {e:#}", path.display());
            // suspend, not println: println prints nothing when the bar is hidden (no TTY).
            match &bar {
                Some(b) => b.suspend(|| eprintln!("{msg}")),
                None => eprintln!("{msg}"),
            }
            failed += 1;
        }
        if let Some(b) = &bar {
            b.inc(1);
        }
    }
    if let Some(b) = bar {
        b.finish_and_clear();
    }
    if failed > 0 {
        eprintln!("{failed} of {} photos failed", args.images.len());
    }
    Ok(if failed == 0 { ExitCode::SUCCESS } else { ExitCode::FAILURE })
}

fn one(pipeline: &Pipeline, args: &FitArgs, path: &Path) -> anyhow::Result<()> {
    let bytes = std::fs::read(path).context("cannot read file")?;
    let faces = if args.pts {
        let pts_path = path.with_extension("pts");
        let text = std::fs::read(&pts_path).with_context(|| format!("cannot read {}", pts_path.display()))?;
        let points = facerecon_vision::pts::read(&text).with_context(|| format!("{}", pts_path.display()))?;
        FaceSource::Landmarks(vec![points])
    } else {
        FaceSource::Detect
    };
    let start = if args.encoder.is_some() { Start::Encoder } else { Start::Landmarks };
    let refine = match (args.refine, start) {
        (None, Start::Encoder) | (Some(RefineArg::None), _) => Refine::None,
        (None, Start::Landmarks) | (Some(RefineArg::Landmarks), _) => Refine::Landmarks,
        (Some(RefineArg::Coarse), _) => Refine::Coarse,
        (Some(RefineArg::Full), _) => Refine::Full,
    };
    let options = Options { start, refine, faces, max_faces: args.max_faces };
    let recon = pipeline.reconstruct(&bytes, &options)?;
    let model = pipeline.model();
    let stem = path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_else(|| "image".into());
    let mut faces_json = Vec::new();
    for (k, face) in recon.faces.iter().enumerate() {
        let base = args.out.join(format!("{stem}-face{}", k + 1));
        let record = outputs::face_record(model, face);
        if let (Some(r), Ok(fit)) = (&record, &face.fit) {
            let (mesh, texture) = match args.no_meshes {
                true => (None, None),
                false => {
                    let t = texture::face_texture(model, &recon.image, face, texture::TEXTURE_SIZE)?;
                    (Some(outputs::face_mesh(model, fit)?), t.map(|t| files::png(&t.image)).transpose()?)
                }
            };
            let displacement =
                fit.displacement.as_ref().map(|d| facerecon_model::displacement::to_png(&d.map)).transpose()?;
            let face_files = files::FaceFiles {
                record: r,
                mesh: mesh.as_ref(),
                texture_png: texture.as_deref(),
                displacement_png: displacement.as_ref().map(|d| &d.bytes[..]),
            };
            files::write_face(&face_files, &base)?;
        }
        let b = face.face.detection.face_box;
        faces_json.push(FaceJson {
            face_box: [b.x0, b.y0, b.x1, b.y1],
            landmarks: face.face.landmarks.points.clone(),
            fitted_landmarks: record.as_ref().map(|r| r.fitted_landmarks.clone()),
            coefficients: record.as_ref().map(|r| r.coefficients.clone()),
            residuals: record.as_ref().map(|r| r.residuals.clone()),
            error: face.fit.as_ref().err().map(|e| e.to_string()),
        });
    }
    let overlay = outputs::overlay(model, &recon, 0.85, &facerecon_raster::draw::Cpu)?;
    files::write_picture(&args.out, &stem, files::OVERLAY, &files::png(&overlay)?)?;
    if let Some(sbs) = outputs::side_by_side(model, &recon, &facerecon_raster::draw::Cpu)? {
        files::write_picture(&args.out, &stem, files::SIDE_BY_SIDE, &files::png(&sbs)?)?;
    }
    let name = path.display().to_string();
    if args.json {
        let obj =
            ImageJson { image: &name, width: recon.image.width(), height: recon.image.height(), faces: faces_json };
        println!("{}", serde_json::to_string(&obj)?);
    } else {
        let fitted = recon.faces.iter().filter(|f| f.fit.is_ok()).count();
        println!("{name}: {} face(s), {fitted} fitted → {}", recon.faces.len(), args.out.display());
        for (k, f) in recon.faces.iter().enumerate() {
            match &f.fit {
                Ok(fit) => println!("  face {}: landmark residual {:.2} px rms", k + 1, fit.landmark_rms_px),
                Err(e) => println!("  face {}: not fitted: {e}", k + 1),
            }
        }
    }
    Ok(())
}
