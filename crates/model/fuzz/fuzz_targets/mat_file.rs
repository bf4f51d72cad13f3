//! The MATLAB v5 reader must refuse malformed files with an error, never panic.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let _ = facerecon_model::mat::read(data, "fuzz.mat", &[]);
});
