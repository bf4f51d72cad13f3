//! Fuzzes the dlib shape-predictor parser: any bytes must give a model or an error, never
//! a panic or an unbounded allocation; a model that loads must predict without panicking.
#![no_main]

use facerecon_vision::face::FaceBox;
use facerecon_vision::landmarks::ShapePredictor;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(sp) = ShapePredictor::from_bytes(data) {
        let img = image::RgbImage::from_fn(16, 16, |x, y| image::Rgb([(x * 16) as u8, (y * 16) as u8, 7]));
        let b = FaceBox { x0: 2.0, y0: 3.0, x1: 13.0, y1: 12.0 };
        let pts = sp.predict(&img, &b);
        assert_eq!(pts.len(), sp.num_parts());
    }
});
