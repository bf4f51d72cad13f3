//! The loss plot of a run (PNG): every loss term against the step, log scale. Labels are
//! drawn with the system's DejaVu Sans (Debian `fonts-dejavu-core`, installed by
//! `scripts/setup`); without it the plot is not drawn and the run says so.

use std::path::Path;
use std::sync::OnceLock;

use plotters::prelude::*;

use crate::TrainError;
use crate::run::LogEntry;

const FONT_PATHS: [&str; 3] = [
    "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf",
    "/usr/share/fonts/dejavu/DejaVuSans.ttf",
    "/usr/share/fonts/TTF/DejaVuSans.ttf",
];

fn font() -> Result<(), TrainError> {
    static REGISTERED: OnceLock<Result<(), String>> = OnceLock::new();
    REGISTERED
        .get_or_init(|| {
            let path = std::env::var("FACERECON_PLOT_FONT")
                .ok()
                .or_else(|| FONT_PATHS.iter().find(|p| Path::new(p).is_file()).map(|p| p.to_string()))
                .ok_or("no DejaVuSans.ttf found (install fonts-dejavu-core or set FACERECON_PLOT_FONT)")?;
            let bytes = std::fs::read(&path).map_err(|e| format!("{path}: {e}"))?;
            // plotters keeps fonts for the life of the process.
            let bytes: &'static [u8] = Box::leak(bytes.into_boxed_slice());
            plotters::style::register_font("sans-serif", FontStyle::Normal, bytes)
                .map_err(|_| format!("{path}: not a usable font"))
        })
        .clone()
        .map_err(TrainError::Plot)
}

/// Draws the loss curves of `entries` into `path` (960×540).
pub fn loss_plot(entries: &[LogEntry], path: &Path) -> Result<(), TrainError> {
    font()?;
    if entries.is_empty() {
        return Err(TrainError::Plot("no log entries".into()));
    }
    let (w, h) = (960u32, 540u32);
    let mut buf = vec![0u8; (w * h * 3) as usize];
    type Series = (&'static str, fn(&LogEntry) -> f64, RGBColor);
    let series: [Series; 8] = [
        ("total", |e| e.total, BLACK),
        ("coefficients", |e| e.coef, RGBColor(31, 119, 180)),
        ("shape (per 5 mm)", |e| e.shape, RGBColor(44, 160, 44)),
        ("landmarks (per 4 px)", |e| e.landmarks, RGBColor(214, 39, 40)),
        ("resolution ℓs", |e| e.resolution, RGBColor(148, 103, 189)),
        ("features ℓf", |e| e.feature, RGBColor(255, 127, 14)),
        ("photos: photometric", |e| e.photometric, RGBColor(23, 190, 207)),
        ("photos: landmarks (L1 px)", |e| e.photo_landmarks, RGBColor(140, 86, 75)),
    ];
    let positive = |v: f64| v.is_finite() && v > 0.0;
    let values = entries.iter().flat_map(|e| series.iter().map(move |s| (s.1)(e))).filter(|&v| positive(v));
    let (lo, hi) = values.fold((f64::INFINITY, 0.0f64), |(lo, hi), v| (lo.min(v), hi.max(v)));
    let (lo, hi) = if lo < hi { (lo * 0.8, hi * 1.25) } else { (1e-3, 1.0) };
    let last_step = entries.iter().map(|e| e.step).max().unwrap_or(1).max(2);
    let draw = |e: String| TrainError::Plot(e);
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| draw(e.to_string()))?;
        let mut chart = ChartBuilder::on(&root)
            .caption("encoder training loss", ("sans-serif", 22))
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(64)
            .build_cartesian_2d(1u64..last_step, (lo..hi).log_scale())
            .map_err(|e| draw(e.to_string()))?;
        chart
            .configure_mesh()
            .x_desc("step")
            .y_desc("loss")
            .label_style(("sans-serif", 14))
            .draw()
            .map_err(|e| draw(e.to_string()))?;
        for (name, f, color) in series {
            let pts: Vec<(u64, f64)> = entries.iter().map(|e| (e.step, f(e))).filter(|p| positive(p.1)).collect();
            if pts.is_empty() {
                continue;
            }
            chart
                .draw_series(LineSeries::new(pts, color.stroke_width(2)))
                .map_err(|e| draw(e.to_string()))?
                .label(name)
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], color.stroke_width(2)));
        }
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .label_font(("sans-serif", 14))
            .draw()
            .map_err(|e| draw(e.to_string()))?;
        root.present().map_err(|e| draw(e.to_string()))?;
    }
    let img = image::RgbImage::from_raw(w, h, buf).ok_or_else(|| draw("plot buffer".into()))?;
    img.save(path).map_err(|e| draw(format!("{}: {e}", path.display())))
}
