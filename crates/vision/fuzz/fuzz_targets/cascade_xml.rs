//! Arbitrary text → cascade parser; every cascade it accepts is also run over a small
//! image (both orientations): never a panic, never an endless loop.
#![no_main]
use facerecon_vision::detect::cascade::Cascade;
use facerecon_vision::detect::{DetectorParams, NamedCascade, ViolaJones};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(xml) = std::str::from_utf8(data) else { return };
    let Ok(c) = Cascade::from_xml(xml) else { return };
    if c.width > 64 || c.height > 64 {
        return; // keeps each run short; window sizes are otherwise free
    }
    let mirrored = c.mirrored();
    let det = ViolaJones::new(
        vec![
            NamedCascade::new("c", c),
            NamedCascade::new("m", mirrored),
        ],
        DetectorParams { min_size: 1, min_neighbors: 1, scale_factor: 1.5, ..Default::default() },
    )
    .unwrap();
    let mut s = data.len() as u32;
    let img = image::RgbImage::from_fn(40, 30, |_, _| {
        s = s.wrapping_mul(1664525).wrapping_add(1013904223);
        image::Rgb([(s >> 24) as u8, (s >> 16) as u8, (s >> 8) as u8])
    });
    let _ = det.detect_faces(&img);
});
