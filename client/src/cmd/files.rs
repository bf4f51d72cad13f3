//! The files a reconstruction is written as, one layout for `fit` (in-process) and
//! `reconstruct` / `bulk` (through a server). In `DIR`, per face `K` (1-based, largest
//! first) of `<stem>`: `<stem>-face<K>.json` (the coefficient record), `.glb`, `.ply`,
//! `.obj` + `.mtl`, `<stem>-face<K>-texture.png` (the photo projected into UV space, see
//! `facerecon_recon::texture`; the `.glb` embeds it, the `.mtl` names it), and at the full
//! level `<stem>-face<K>-displacement.png` (16-bit, see
//! `facerecon_model::displacement::to_png`); per photo `<stem>-overlay.png` and
//! `<stem>-sidebyside.png`.

use std::path::{Path, PathBuf};

use anyhow::Context;
use facerecon_model::Mesh;
use facerecon_model::mesh::{glb, obj, ply};
use facerecon_recon::outputs::FaceRecord;

pub const OVERLAY: &str = "overlay";
pub const SIDE_BY_SIDE: &str = "sidebyside";

/// What is written for one fitted face.
pub struct FaceFiles<'a> {
    pub record: &'a FaceRecord,
    /// The mesh, in every format (none: the record only).
    pub mesh: Option<&'a Mesh>,
    /// The face's UV texture (PNG), embedded in the `.glb` and named by the `.mtl`.
    pub texture_png: Option<&'a [u8]>,
    /// The displacement map (16-bit PNG).
    pub displacement_png: Option<&'a [u8]>,
}

/// Writes `files` under `base` (`<dir>/<stem>-face<K>`).
pub fn write_face(files: &FaceFiles, base: &Path) -> anyhow::Result<()> {
    let with = |ext: &str| PathBuf::from(format!("{}.{ext}", base.display()));
    let beside = |suffix: &str| PathBuf::from(format!("{}-{suffix}", base.display()));
    let json = with("json");
    std::fs::write(&json, serde_json::to_vec_pretty(files.record)?)
        .with_context(|| format!("writing {}", json.display()))?;
    let write =
        |p: PathBuf, bytes: &[u8]| std::fs::write(&p, bytes).with_context(|| format!("writing {}", p.display()));
    if let Some(png) = files.displacement_png {
        write(beside("displacement.png"), png)?;
    }
    let Some(mesh) = files.mesh else { return Ok(()) };
    let create = |p: &Path| {
        std::fs::File::create(p).map(std::io::BufWriter::new).with_context(|| format!("creating {}", p.display()))
    };
    match files.texture_png {
        Some(png) => glb::write_glb_textured(mesh, png, create(&with("glb"))?)?,
        None => glb::write_glb(mesh, create(&with("glb"))?)?,
    }
    ply::write_ply(mesh, create(&with("ply"))?)?;
    let mtl = with("mtl");
    let mtl_name = mtl.file_name().map(|n| n.to_string_lossy().into_owned());
    obj::write_obj(mesh, create(&with("obj"))?, mtl_name.as_deref())?;
    match files.texture_png {
        Some(png) => {
            let texture = beside("texture.png");
            write(texture.clone(), png)?;
            let name = texture.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
            obj::write_mtl_textured(create(&mtl)?, &name)?;
        }
        None => obj::write_mtl(create(&mtl)?)?,
    }
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
