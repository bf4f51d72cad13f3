//! Writes the compact copy of a model file (F16 bases, about half the size): what a
//! training machine that cannot build the model itself is given.
//!
//! `cargo run --release -p facerecon-model --example compact_model -- OUT [IN]`
//! (IN: a model file; default: the default ICT model, built from the shared folder).

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let out = args.first().ok_or("usage: compact_model OUT [IN]")?;
    let model = match args.get(1) {
        Some(p) => std::sync::Arc::new(facerecon_model::MorphableModel::load(p)?),
        None => facerecon_model::ict::load_default()?,
    };
    let bytes = model.to_compact_bytes()?;
    std::fs::write(out, &bytes)?;
    eprintln!(
        "{out}: {:.1} MB (the F32 file: {:.1} MB)",
        bytes.len() as f64 / 1e6,
        model.to_bytes()?.len() as f64 / 1e6
    );
    Ok(())
}
