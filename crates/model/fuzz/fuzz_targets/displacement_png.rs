//! The displacement map's PNG reader must refuse any invalid input with an error, never
//! panic or allocate without bound; whatever it reads must re-encode and read back within
//! one quantisation step. Seed: any map written by `facerecon fit --refine full`
//! (`<stem>-face<K>-displacement.png`).
#![no_main]

use facerecon_model::displacement::{from_png, to_png};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(map) = from_png(data) {
        let png = to_png(&map).expect("a map read re-encodes");
        let back = from_png(&png.bytes).expect("a re-encoded map reads back");
        let step = png.scale_mm.max(f32::EPSILON) * 1.01;
        assert!(back.values().iter().zip(map.values()).all(|(a, b)| (a - b).abs() <= step + 1e-6 * b.abs()));
    }
});
