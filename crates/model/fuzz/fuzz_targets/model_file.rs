//! The model-file loader must refuse any invalid input with an error, never panic or
//! allocate without bound. Seed corpus: `cargo test -p facerecon-model --test format -- --ignored write_fuzz_seed`.
#![no_main]

use facerecon_model::MorphableModel;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(m) = MorphableModel::from_bytes(data) {
        // Whatever loads must evaluate and re-encode.
        let layout = m.layout();
        let c = facerecon_model::Coefficients::neutral(layout, 500.0);
        let _ = m.instance_full(&c).expect("a valid model evaluates its mean");
        let bytes = m.to_bytes().expect("a valid model re-encodes");
        assert!(MorphableModel::from_bytes(&bytes).expect("re-encoded model loads") == m);
    }
});
