//! One module per subcommand.
pub mod detect;
pub mod fit;
pub mod model;
pub mod synth;
