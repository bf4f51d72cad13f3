//! The public contract of the service, `proto/facerecon/v1/facerecon.proto`, compiled:
//! the messages, the tonic client and server stubs, and the encoded descriptor set for
//! server reflection. Both the server and the client library build on this crate and on
//! nothing else of each other.

/// `facerecon.v1`: messages and stubs.
pub mod v1 {
    tonic::include_proto!("facerecon.v1");

    /// The encoded `FileDescriptorSet` of `facerecon.v1` (for gRPC server reflection).
    pub const FILE_DESCRIPTOR_SET: &[u8] = tonic::include_file_descriptor_set!("facerecon_v1_descriptor");
}
