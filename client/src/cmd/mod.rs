//! One module per subcommand.
pub mod bulk;
pub mod detect;
pub mod files;
pub mod fit;
pub mod model;
pub mod reconstruct;
pub mod remote;
pub mod synth;

/// One photo's line of `--json` output (`detect` and `fit`): the image as named on the
/// command line, its size after EXIF orientation, and its faces.
#[derive(serde::Serialize)]
pub struct ImageJson<'a, F> {
    pub image: &'a str,
    pub width: u32,
    pub height: u32,
    pub faces: Vec<F>,
}
