//! Arbitrary bytes → decode with limits: never a panic, never an allocation beyond the
//! limits. Successful decodes are also cropped (crop + router on whatever came out).
#![no_main]
use facerecon_vision::crop::crop_face;
use facerecon_vision::decode::{DecodeLimits, decode_with_limits};
use facerecon_vision::face::FaceBox;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let limits = DecodeLimits { max_encoded_bytes: 1 << 20, max_pixels: 4_000_000 };
    if let Ok(img) = decode_with_limits(data, &limits) {
        assert!(u64::from(img.width()) * u64::from(img.height()) <= limits.max_pixels);
        let (w, h) = (img.width() as f32, img.height() as f32);
        let c = crop_face(&img, &FaceBox { x0: w * 0.25, y0: h * 0.25, x1: w * 0.75, y1: h * 0.75 });
        assert_eq!(c.image.dimensions(), (224, 224));
    }
});
