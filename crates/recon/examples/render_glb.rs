//! Renders a textured `.glb` as `facerecon fit` writes it, read back by the `gltf` crate
//! (an independent parser): positions, UVs, triangles and the embedded base-colour texture,
//! turned about the face's centre by each yaw and seen straight on from a distance where it
//! fills the view (the mesh is in the photo camera's space, where a face may be small and
//! off-axis), in a row.
//!
//!     cargo run --release -p facerecon-recon --example render_glb -- FACE.glb OUT.png [YAW_DEG …]

use facerecon_raster::Camera;
use facerecon_recon::texture;
use glam::{Mat3, Vec3};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let (Some(glb), Some(out)) = (args.next(), args.next()) else {
        return Err("usage: render_glb FACE.glb OUT.png [YAW_DEG …]".into());
    };
    let yaws: Vec<f32> = args.map(|a| a.parse()).collect::<Result<_, _>>()?;
    let yaws = if yaws.is_empty() { vec![0.0, 30.0, -50.0] } else { yaws };

    let bytes = std::fs::read(&glb)?;
    let gltf = gltf::Gltf::from_slice(&bytes)?;
    let blob = gltf.blob.clone().ok_or("no BIN chunk")?;
    let prim = gltf.meshes().next().ok_or("no mesh")?.primitives().next().ok_or("no primitive")?;
    let reader = prim.reader(|_| Some(&blob[..]));
    let positions: Vec<[f32; 3]> = reader.read_positions().ok_or("no positions")?.collect();
    // glTF's UV origin is the top left; the renderer takes the OBJ convention (v up).
    let uvs: Vec<[f32; 2]> = reader.read_tex_coords(0).ok_or("no UVs")?.into_f32().map(|[u, v]| [u, 1.0 - v]).collect();
    let indices: Vec<u32> = reader.read_indices().ok_or("no indices")?.into_u32().collect();
    let triangles: Vec<[u32; 3]> = indices.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
    let info = prim.material().pbr_metallic_roughness().base_color_texture().ok_or("no base colour texture")?;
    let gltf::image::Source::View { view, .. } = info.texture().source().source() else {
        return Err("the texture is not embedded".into());
    };
    let image = image::load_from_memory(&blob[view.offset()..view.offset() + view.length()])?.to_rgb8();

    let centre = positions.iter().map(|p| Vec3::from(*p)).sum::<Vec3>() / positions.len().max(1) as f32;
    let size = 512;
    let camera = Camera::default();
    let radius = positions.iter().map(|p| (Vec3::from(*p) - centre).length()).fold(0.0f32, f32::max);
    let view_centre = Vec3::new(0.0, 0.0, -1.1 * radius * camera.focal());
    let mut row = image::RgbImage::from_pixel(size * yaws.len() as u32, size, image::Rgb([255, 255, 255]));
    for (k, yaw) in yaws.iter().enumerate() {
        let r = Mat3::from_rotation_y(yaw.to_radians());
        let turned: Vec<[f32; 3]> =
            positions.iter().map(|p| (r * (Vec3::from(*p) - centre) + view_centre).to_array()).collect();
        let view = texture::render_textured(&turned, &triangles, &uvs, &image, camera, size)?;
        image::imageops::replace(&mut row, &view, (k as u32 * size) as i64, 0);
    }
    row.save(&out)?;
    println!(
        "{} vertices, {} triangles, texture {}×{} → {out}",
        positions.len(),
        triangles.len(),
        image.width(),
        image.height()
    );
    Ok(())
}
