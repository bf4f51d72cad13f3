//! Writing samples: per sample `NNNNNN.png` (image), `NNNNNN_mask.png` (face-area mask),
//! `NNNNNN.json` ([`GroundTruth`]); per run `manifest.jsonl` (one [`ManifestEntry`] per
//! line, in index order) and `run.json` (how the run was made).
//!
//! Samples are generated in parallel (rayon) in chunks; each chunk's manifest lines are
//! appended in index order once the chunk is written, so the manifest lists only complete
//! samples even if a run stops early.

use std::io::Write;
use std::path::{Path, PathBuf};

use image::ImageEncoder;
use rayon::prelude::*;

use crate::{Generator, GroundTruth, Sample, SynthConfig, SynthError};

pub const MANIFEST: &str = "manifest.jsonl";
pub const RUN_FILE: &str = "run.json";

/// One line of `manifest.jsonl`.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ManifestEntry {
    pub index: u64,
    pub image: String,
    pub mask: String,
    pub truth: String,
    pub width: u32,
    pub height: u32,
    pub crop_side: f32,
    pub bucket: Option<u8>,
    pub yaw_deg: f32,
    pub visible_landmarks: u32,
}

/// `run.json`.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct RunInfo {
    pub generator: String,
    pub model: String,
    pub seed: u64,
    pub count: u64,
    pub config: SynthConfig,
}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> SynthError + '_ {
    move |source| SynthError::Io { path: path.to_owned(), source }
}

/// PNG bytes of an 8-bit image (deterministic: fixed encoder settings).
pub fn png_bytes(
    data: &[u8],
    width: u32,
    height: u32,
    color: image::ExtendedColorType,
) -> Result<Vec<u8>, image::ImageError> {
    let mut out = Vec::new();
    image::codecs::png::PngEncoder::new_with_quality(
        &mut out,
        image::codecs::png::CompressionType::Default,
        image::codecs::png::FilterType::Adaptive,
    )
    .write_image(data, width, height, color)?;
    Ok(out)
}

/// Writes one sample's three files into `dir`.
pub fn write_sample(dir: &Path, sample: &Sample) -> Result<ManifestEntry, SynthError> {
    let t = &sample.truth;
    let img = png_bytes(sample.image.as_raw(), t.width, t.height, image::ExtendedColorType::Rgb8)
        .map_err(|source| SynthError::Image { path: dir.join(&t.image), source })?;
    let mask = png_bytes(sample.mask.as_raw(), t.width, t.height, image::ExtendedColorType::L8)
        .map_err(|source| SynthError::Image { path: dir.join(&t.mask), source })?;
    let truth_file = format!("{:06}.json", t.index);
    let json = serde_json::to_vec_pretty(t).expect("ground truth serialises");
    for (name, bytes) in [(&t.image, &img), (&t.mask, &mask), (&truth_file, &json)] {
        let path = dir.join(name);
        std::fs::write(&path, bytes).map_err(io(&path))?;
    }
    Ok(ManifestEntry {
        index: t.index,
        image: t.image.clone(),
        mask: t.mask.clone(),
        truth: truth_file,
        width: t.width,
        height: t.height,
        crop_side: t.crop.side,
        bucket: t.crop.bucket,
        yaw_deg: t.euler.yaw_deg,
        visible_landmarks: t.landmarks.iter().filter(|l| l.visible).count() as u32,
    })
}

/// Generates samples `0..count` of `seed` into `dir` (created if missing; existing sample
/// files are overwritten). `progress` is called with the number of samples finished.
pub fn generate_to_dir(
    generator: &Generator,
    seed: u64,
    count: u64,
    dir: &Path,
    progress: &(dyn Fn(u64) + Sync),
) -> Result<Vec<ManifestEntry>, SynthError> {
    std::fs::create_dir_all(dir).map_err(io(dir))?;
    let info = RunInfo {
        generator: concat!("facerecon-synth ", env!("CARGO_PKG_VERSION")).into(),
        model: generator.model().meta().name.clone(),
        seed,
        count,
        config: generator.config().clone(),
    };
    let run_path = dir.join(RUN_FILE);
    std::fs::write(&run_path, serde_json::to_vec_pretty(&info).expect("run info serialises")).map_err(io(&run_path))?;
    let manifest_path = dir.join(MANIFEST);
    let mut manifest = std::io::BufWriter::new(std::fs::File::create(&manifest_path).map_err(io(&manifest_path))?);
    let chunk = (rayon::current_num_threads() as u64 * 4).max(1);
    let mut entries = Vec::with_capacity(count.min(1 << 20) as usize);
    let mut start = 0;
    while start < count {
        let end = (start + chunk).min(count);
        let done: Vec<ManifestEntry> = (start..end)
            .into_par_iter()
            .map(|i| write_sample(dir, &generator.sample(seed, i)?))
            .collect::<Result<_, _>>()?;
        for e in &done {
            serde_json::to_writer(&mut manifest, e).expect("manifest entries serialise");
            manifest.write_all(b"\n").map_err(io(&manifest_path))?;
        }
        manifest.flush().map_err(io(&manifest_path))?;
        entries.extend(done);
        start = end;
        progress(start);
    }
    Ok(entries)
}

/// Reads a sample's ground truth back.
pub fn read_truth(path: &Path) -> Result<GroundTruth, SynthError> {
    let bytes = std::fs::read(path).map_err(io(path))?;
    serde_json::from_slice(&bytes).map_err(|e| SynthError::Io {
        path: PathBuf::from(path),
        source: std::io::Error::new(std::io::ErrorKind::InvalidData, e),
    })
}
