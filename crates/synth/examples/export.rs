//! Writes the lit face of a synthetic sample as `.glb`, `.ply` and `.obj` + `.mtl`
//! (camera space, mm, shaded vertex colours) — e.g. to open in a viewer or check with a
//! glTF validator.
//!
//! `cargo run -p facerecon-synth --example export -- OUT_DIR [SEED]`

use facerecon_model::lit::LitFace;
use facerecon_model::mesh::{glb, obj, ply};
use facerecon_synth::{Generator, SynthConfig};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let out = std::path::PathBuf::from(args.next().ok_or("usage: export OUT_DIR [SEED]")?);
    let seed: u64 = args.next().map(|s| s.parse()).transpose()?.unwrap_or(0);
    std::fs::create_dir_all(&out)?;
    let model = facerecon_model::ict::load_default()?;
    let g = Generator::new(&model, SynthConfig::default())?;
    let c = g.sample(seed, 0)?.truth.coefficients;
    let mut lit = LitFace::default();
    lit.update(&model, &c)?;
    let mesh = lit.to_mesh(&model);
    let file = |name: &str| std::fs::File::create(out.join(name)).map(std::io::BufWriter::new);
    glb::write_glb(&mesh, file("face.glb")?)?;
    ply::write_ply(&mesh, file("face.ply")?)?;
    obj::write_obj(&mesh, file("face.obj")?, Some("face.mtl"))?;
    obj::write_mtl(file("face.mtl")?)?;
    eprintln!("{} vertices, {} triangles → {}", mesh.positions.len(), mesh.triangles.len(), out.display());
    Ok(())
}
