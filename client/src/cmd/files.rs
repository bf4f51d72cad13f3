//! The files a reconstruction is written as, one layout for `fit` (in-process) and
//! `reconstruct` / `bulk` (through a server). In `DIR`, per face `K` (1-based, largest
//! first) of `<stem>`: `<stem>-face<K>.json` (the coefficient record), `.glb`, `.ply`,
//! `.obj` + `.mtl`, and at the full level `<stem>-face<K>-displacement.png` (16-bit, see
//! `facerecon_recon::outputs::displacement_png`); per photo `<stem>-overlay.png` and
//! `<stem>-sidebyside.png`.

use std::path::{Path, PathBuf};

use anyhow::Context;
use facerecon_model::Mesh;
use facerecon_model::mesh::{glb, obj, ply};
use facerecon_recon::outputs::FaceRecord;

pub const OVERLAY: &str = "overlay";
pub const SIDE_BY_SIDE: &str = "sidebyside";

/// The record as JSON, the displacement map's PNG when there is one, and, with a mesh, the
/// mesh in every format.
pub fn write_face(
    record: &FaceRecord,
    mesh: Option<&Mesh>,
    displacement_png: Option<&[u8]>,
    base: &Path,
) -> anyhow::Result<()> {
    let with = |ext: &str| PathBuf::from(format!("{}.{ext}", base.display()));
    let json = with("json");
    std::fs::write(&json, serde_json::to_vec_pretty(record)?).with_context(|| format!("writing {}", json.display()))?;
    if let Some(png) = displacement_png {
        let p = PathBuf::from(format!("{}-displacement.png", base.display()));
        std::fs::write(&p, png).with_context(|| format!("writing {}", p.display()))?;
    }
    let Some(mesh) = mesh else { return Ok(()) };
    let create = |p: &Path| {
        std::fs::File::create(p).map(std::io::BufWriter::new).with_context(|| format!("creating {}", p.display()))
    };
    glb::write_glb(mesh, create(&with("glb"))?)?;
    ply::write_ply(mesh, create(&with("ply"))?)?;
    let mtl = with("mtl");
    let mtl_name = mtl.file_name().map(|n| n.to_string_lossy().into_owned());
    obj::write_obj(mesh, create(&with("obj"))?, mtl_name.as_deref())?;
    obj::write_mtl(create(&mtl)?)?;
    Ok(())
}

/// `<dir>/<stem>-<kind>.png`.
pub fn write_picture(dir: &Path, stem: &str, kind: &str, png: &[u8]) -> anyhow::Result<()> {
    let p = dir.join(format!("{stem}-{kind}.png"));
    std::fs::write(&p, png).with_context(|| format!("writing {}", p.display()))
}

pub fn png(image: &image::RgbImage) -> anyhow::Result<Vec<u8>> {
    Ok(facerecon_recon::outputs::png(image)?)
}
