//! One module per subcommand.
pub mod detect;
pub mod model;
pub mod synth;
