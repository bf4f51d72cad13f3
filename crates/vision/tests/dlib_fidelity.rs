//! Port fidelity: on every row of faces-300w's `dlib_reference.csv` (dlib's own output for
//! 700 photos × {dlib HOG box, landmark box}), our port of dlib's shape predictor, given
//! the same box, returns dlib's points (dlib rounds to integers; we round ours the same way).
//!
//! dlib's reference decoded the photos with OpenCV (libjpeg-turbo); the `image` crate's JPEG
//! decoder differs from it by ±1 grey level on ~10 % of pixels, which flips splits whose
//! threshold lies within a grey level, and errors then compound through the cascade. So:
//! * PNG photos (LFPW, 236 photos / 465 rows: identical pixels): every point must be
//!   exactly dlib's, up to a 0.1 % allowance for rounding ties;
//! * JPEG photos decoded by the `image` crate: reported, with a bar at the measured level;
//! * with `FACERECON_LIBJPEG_PPM_DIR` (JPEGs decoded by libjpeg-turbo, see
//!   `support/libjpeg_to_ppm.c`), all 1,371 rows must meet the PNG bar (measured: 100 %
//!   exact).

mod support;
use support::faces300w::*;

use std::collections::BTreeMap;
use std::time::Instant;

use facerecon_vision::landmarks::ShapePredictor;

#[test]
fn port_matches_dlib_on_faces_300w() {
    let dir = dataset_dir();
    let refs = read_dlib_reference(&dir);
    assert_eq!(refs.len(), 1371, "dlib_reference.csv rows");
    let t = Instant::now();
    let sp = ShapePredictor::load_default().expect("dlib model (Debian libdlib-data)");
    eprintln!("model loaded in {:.2} s", t.elapsed().as_secs_f64());

    let mut by_photo: BTreeMap<&str, Vec<&DlibReference>> = BTreeMap::new();
    for r in &refs {
        by_photo.entry(r.path.as_str()).or_default().push(r);
    }
    let photos: Vec<_> = by_photo.into_iter().collect();
    let t = Instant::now();
    let stats_png = fidelity(&sp, &dir, photos.iter().filter(|p| !p.0.ends_with(".jpg")).collect());
    let stats_jpg = fidelity(&sp, &dir, photos.iter().filter(|p| p.0.ends_with(".jpg")).collect());
    eprintln!("in {:.1} s", t.elapsed().as_secs_f64());
    stats_png.report("PNG photos");
    let libjpeg = std::env::var_os("FACERECON_LIBJPEG_PPM_DIR").is_some();
    stats_jpg.report(if libjpeg { "JPEG photos (libjpeg-turbo)" } else { "JPEG photos (image crate)" });
    let all = Stats {
        n: stats_png.n + stats_jpg.n,
        exact: stats_png.exact + stats_jpg.exact,
        within: stats_png.within + stats_jpg.within,
        max_err: stats_png.max_err.max(stats_jpg.max_err),
        rows: stats_png.rows + stats_jpg.rows,
        rows_exact: stats_png.rows_exact + stats_jpg.rows_exact,
        worst: vec![],
    };
    all.report("all photos");
    assert_eq!(all.n, 1371 * 68);
    assert_eq!(stats_png.rows, 465); // 236 LFPW photos, 229 with a dlib HOG box
    assert!(stats_png.exact as f64 >= 0.999 * stats_png.n as f64, "PNG: port differs from dlib");
    assert_eq!(stats_png.within, stats_png.n, "PNG: a point is more than 1 px from dlib's");
    if libjpeg {
        assert!(stats_jpg.exact as f64 >= 0.999 * stats_jpg.n as f64, "JPEG: port differs from dlib");
        assert_eq!(stats_jpg.within, stats_jpg.n, "JPEG: a point is more than 1 px from dlib's");
    } else {
        // Measured 2026-11-23: 17.9 % exact, 45.4 % within 1 px on JPEG rows; a port
        // error (rather than decoder noise) would drop far below this.
        assert!(stats_jpg.within as f64 >= 0.40 * stats_jpg.n as f64, "JPEG: far from dlib");
    }
}

struct Stats {
    n: usize,
    exact: usize,
    within: usize,
    max_err: f64,
    rows: usize,
    rows_exact: usize,
    worst: Vec<String>,
}

impl Stats {
    fn report(&self, what: &str) {
        eprintln!(
            "{what}: {} rows, {} points: exact {:.3} %, within 1 px {:.3} %, max error {:.2} px, \
             rows all exact {}/{}",
            self.rows,
            self.n,
            100.0 * self.exact as f64 / self.n as f64,
            100.0 * self.within as f64 / self.n as f64,
            self.max_err,
            self.rows_exact,
            self.rows
        );
        for w in self.worst.iter().take(5) {
            eprintln!("  {w}");
        }
    }
}

fn fidelity(sp: &ShapePredictor, dir: &std::path::Path, photos: Vec<&(&str, Vec<&DlibReference>)>) -> Stats {
    let threads = std::thread::available_parallelism().map_or(2, |n| n.get());
    let stats: Vec<(usize, usize, usize, f64, usize, Vec<String>)> = std::thread::scope(|s| {
        let chunks: Vec<_> = photos.chunks(photos.len().div_ceil(threads)).collect();
        let handles: Vec<_> = chunks
            .into_iter()
            .map(|chunk| {
                let (sp, dir) = (sp, dir);
                s.spawn(move || {
                    let (mut n, mut exact, mut within, mut max_err, mut rows_exact) = (0, 0, 0, 0.0f64, 0);
                    let mut worst = Vec::new();
                    for (path, rows) in chunk {
                        let img = load_rgb(dir, path);
                        for r in rows {
                            let pts = sp.predict_f64(&img, &r.face_box());
                            let mut row_exact = true;
                            let mut row_max = 0.0f64;
                            for (p, q) in pts.iter().zip(&r.points) {
                                let (rx, ry) = ((p[0] + 0.5).floor() as i64, (p[1] + 0.5).floor() as i64);
                                let e = (((rx - q[0]).pow(2) + (ry - q[1]).pow(2)) as f64).sqrt();
                                n += 1;
                                exact += (e == 0.0) as usize;
                                within += (e <= 1.0) as usize;
                                row_exact &= e == 0.0;
                                row_max = row_max.max(e);
                            }
                            max_err = max_err.max(row_max);
                            rows_exact += row_exact as usize;
                            if row_max > 1.0 {
                                worst.push(format!("{path} {} max {row_max:.1} px", r.box_kind));
                            }
                        }
                    }
                    (n, exact, within, max_err, rows_exact, worst)
                })
            })
            .collect();
        handles.into_iter().map(|h| h.join().unwrap()).collect()
    });
    Stats {
        n: stats.iter().map(|s| s.0).sum(),
        exact: stats.iter().map(|s| s.1).sum(),
        within: stats.iter().map(|s| s.2).sum(),
        max_err: stats.iter().map(|s| s.3).fold(0.0, f64::max),
        rows: photos.iter().map(|p| p.1.len()).sum(),
        rows_exact: stats.iter().map(|s| s.4).sum(),
        worst: stats.iter().flat_map(|s| s.5.clone()).collect(),
    }
}
