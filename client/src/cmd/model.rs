//! `facerecon model …`: build morphable-model files from upstream data and inspect them.

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

use anyhow::{Context, bail};
use facerecon_model::{MorphableModel, format, ict};

/// Default output of `import-ict`, relative to the repository root.
const DEFAULT_ICT_OUTPUT: &str = "models/ict-face-light.safetensors";
/// Default ICT-FaceKit folder, relative to the current directory.
const DEFAULT_ICT_SOURCE: &str = "../shared/models/ICT-FaceKit";

#[derive(clap::Subcommand)]
pub enum ModelCommand {
    /// Build the default model file from an ICT-FaceKit folder (ICT Face Model Light).
    ImportIct {
        /// ICT-FaceKit folder (the one holding FaceXModel/), relative to the current directory.
        #[arg(long, default_value = DEFAULT_ICT_SOURCE)]
        source: PathBuf,
        /// Output file [default: models/ict-face-light.safetensors under the repository].
        #[arg(short, long)]
        output: Option<PathBuf>,
    },
    /// Build a model file from BFM 2009 (01_MorphableModel.mat) and Guo et al.'s Exp_Pca.bin
    /// (identity 80, expression 64, albedo 80; front-face crop).
    ImportBfm {
        /// `01_MorphableModel.mat` (MATLAB v5).
        #[arg(long)]
        mat: PathBuf,
        /// `Exp_Pca.bin`.
        #[arg(long)]
        exp: PathBuf,
        /// `std_exp.txt`: the standard deviation of each expression mode.
        #[arg(long)]
        exp_std: PathBuf,
        /// `BFM_exp_idx.mat` (`trimIndex`): the BFM vertex of each expression vertex; needed
        /// when Exp_Pca.bin has fewer vertices than the BFM (53,215 vs 53,490).
        #[arg(long)]
        exp_index: Option<PathBuf>,
        /// 68 landmark vertex indices (0-based BFM vertex ids, iBUG order, whitespace-separated).
        #[arg(long)]
        landmarks: Option<PathBuf>,
        #[arg(short, long)]
        output: PathBuf,
    },
    /// Print a model file's metadata, counts and sizes.
    Info { file: PathBuf },
}

pub fn run(c: ModelCommand) -> anyhow::Result<ExitCode> {
    match c {
        ModelCommand::ImportIct { source, output } => import_ict(&source, output),
        ModelCommand::ImportBfm { mat, exp, exp_std, exp_index, landmarks, output } => import_bfm(
            &facerecon_model::bfm::BfmSources {
                mat: &mat,
                exp: &exp,
                exp_std: &exp_std,
                exp_index: exp_index.as_deref(),
                landmarks: landmarks.as_deref(),
            },
            &output,
        ),
        ModelCommand::Info { file } => info(&file),
    }
}

/// The repository root: the nearest ancestor of the current directory holding
/// `crates/model/Cargo.toml`, else the current directory.
fn repository_root() -> PathBuf {
    let cwd = std::env::current_dir().unwrap_or_else(|_| PathBuf::from("."));
    cwd.ancestors().find(|a| a.join("crates/model/Cargo.toml").is_file()).map(Path::to_path_buf).unwrap_or(cwd)
}

fn import_ict(source: &Path, output: Option<PathBuf>) -> anyhow::Result<ExitCode> {
    let abs = std::path::absolute(source).unwrap_or_else(|_| source.to_path_buf());
    if !abs.join("FaceXModel").is_dir() {
        bail!(
            "no ICT-FaceKit folder at {} (looked for {}); pass --source DIR",
            abs.display(),
            abs.join("FaceXModel").display()
        );
    }
    let output = output.unwrap_or_else(|| repository_root().join(DEFAULT_ICT_OUTPUT));
    let t0 = Instant::now();
    let (model, report) =
        ict::import_with_report(&abs).with_context(|| format!("importing ICT-FaceKit from {}", abs.display()))?;
    let import_s = t0.elapsed().as_secs_f64();
    model.save(&output).with_context(|| format!("writing {}", output.display()))?;
    println!("imported {} in {import_s:.2} s", abs.display());
    println!(
        "  albedo GP: {} modes from {} inducing vertices in {:.2} s, explained variance {:.1} % (Nyström {:.1} %)",
        report.albedo.modes,
        report.albedo.inducing,
        report.albedo.seconds,
        100.0 * report.albedo.explained_variance,
        100.0 * report.albedo.nystrom_variance
    );
    println!(
        "  mirror distance (neutral, x → −x): face max {:.3} mm, mean {:.3} mm; whole mesh max {:.3} mm",
        report.max_mirror_distance_face_mm, report.mean_mirror_distance_face_mm, report.max_mirror_distance_mm
    );
    print_summary(&model);
    println!("wrote {}", output.display());
    Ok(ExitCode::SUCCESS)
}

fn import_bfm(src: &facerecon_model::bfm::BfmSources, output: &Path) -> anyhow::Result<ExitCode> {
    let t0 = Instant::now();
    let model = facerecon_model::bfm::import(src)
        .with_context(|| format!("importing BFM from {} and {}", src.mat.display(), src.exp.display()))?;
    model.save(output).with_context(|| format!("writing {}", output.display()))?;
    println!("imported in {:.2} s", t0.elapsed().as_secs_f64());
    print_summary(&model);
    println!("wrote {}", output.display());
    Ok(ExitCode::SUCCESS)
}

fn print_summary(m: &MorphableModel) {
    let meta = m.meta();
    println!("  name:       {}", meta.name);
    println!("  source:     {}", meta.source);
    println!("  licence:    {}", meta.licence);
    println!("  units:      {}   format version {}", meta.units, meta.format_version);
    for (n, b) in [("identity", meta.identity), ("expression", meta.expression), ("albedo", meta.albedo)] {
        println!("  {n:<11} {} modes, prior {}", b.count, b.prior.as_str());
    }
    println!(
        "  vertices:   {} ({} in the face area)   triangles: {} ({} in the face area)",
        meta.vertex_count, meta.face_vertex_count, meta.triangle_count, meta.face_triangle_count
    );
    println!("  UVs:        {}   landmarks: {}", m.uvs().0.len(), m.landmarks().len());
    println!("  regions:    {}", meta.region_names.join(", "));
    if !meta.expression_names.is_empty() {
        println!("  expressions: {}", meta.expression_names.join(" "));
    }
}

fn info(file: &Path) -> anyhow::Result<ExitCode> {
    let bytes = std::fs::read(file).with_context(|| format!("reading {}", file.display()))?;
    let model =
        MorphableModel::from_bytes(&bytes).with_context(|| format!("{} is not a valid model file", file.display()))?;
    println!("{}: {:.1} MB", file.display(), bytes.len() as f64 / 1e6);
    print_summary(&model);
    println!("  tensors:");
    for t in format::tensor_summary(&bytes)? {
        println!("    {:<18} {:<4} {:?}  {:.2} MB", t.name, t.dtype, t.shape, t.bytes as f64 / 1e6);
    }
    Ok(ExitCode::SUCCESS)
}
