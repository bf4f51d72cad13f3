//! Compiles `proto/facerecon/v1` with a vendored `protoc`, so that no system protobuf
//! compiler is needed, and writes the descriptor set that server reflection serves.

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../proto");
    let file = root.join("facerecon/v1/facerecon.proto");
    println!("cargo:rerun-if-changed={}", file.display());
    let out = std::path::PathBuf::from(std::env::var("OUT_DIR")?);
    let mut config = prost_build::Config::new();
    config.protoc_executable(protoc_bin_vendored::protoc_bin_path()?);
    tonic_prost_build::configure()
        .file_descriptor_set_path(out.join("facerecon_v1_descriptor.bin"))
        .compile_with_config(config, &[file], &[root])?;
    Ok(())
}
