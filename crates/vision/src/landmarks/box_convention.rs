//! Mapping detector boxes onto dlib's box convention (being written).

/// Placeholder type, replaced below.
#[derive(Clone, Debug)]
pub struct BoxCalibration;
