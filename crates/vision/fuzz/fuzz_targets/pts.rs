//! Arbitrary bytes → `.pts` reader: never a panic; what it accepts is 68 finite points.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(points) = facerecon_vision::pts::read(data) {
        assert_eq!(points.len(), 68);
        assert!(points.iter().all(|p| p[0].is_finite() && p[1].is_finite()));
    }
});
