//! The request decoding path: bytes of a gRPC message → protobuf `ReconstructRequest` →
//! the validated job (`convert::validate`). Neither step may panic or allocate beyond the
//! message; an accepted request must satisfy what the engine relies on.
//!
//!   cd server/fuzz && RUSTC_BOOTSTRAP=1 cargo fuzz run request -- -max_total_time=600
#![no_main]

use facerecon_proto::v1::ReconstructRequest;
use libfuzzer_sys::fuzz_target;
use prost::Message;

fuzz_target!(|data: &[u8]| {
    let Ok(req) = ReconstructRequest::decode(data) else { return };
    let image_len = req.image.len();
    if let Ok(v) = facerecon_server::convert::validate(req, 16) {
        assert!(image_len > 0);
        assert!(v.options.max_faces >= 1 && v.options.max_faces <= 16);
        assert!(v.id.len() <= facerecon_server::convert::MAX_ID_BYTES);
    }
});
