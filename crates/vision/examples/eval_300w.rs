//! Evaluates the front end on faces-300w (700 photos; see the data's README):
//!
//!     cargo run --release -p facerecon-vision --example eval_300w
//!
//! * detection rate: a photo counts as detected when a detection's box has IoU > 0.3 with
//!   the annotated landmark box (the best-overlapping detection is the one used);
//! * NME of the full pipeline (our Viola–Jones → box calibration → our dlib port), mean
//!   point error / √(w·h) of the annotated landmark box, `.pts` converted to 0-based;
//!   also without the calibration, to show what it buys;
//! * reference lines: dlib's own points on dlib's HOG boxes (`dlib_reference.csv`), and our
//!   port on the same boxes;
//! * the front end's refinement passes ([`FrontEnd::with_refinement`] with
//!   [`BoxFromLandmarks::dlib_68`]): NME after 1 (no refinement) to 4 landmark passes, from
//!   the calibrated detector box, from the raw detector box, and from dlib's HOG box; and
//!   the worst `afw` photos with what they show (detector source, overlap of the detection
//!   with the annotated box, yaw).
//!
//! Landmarks run through [`FrontEnd::face`], the product's code path: only the detection
//! goes in; the annotation serves to pick which detection is the annotated face and to
//! score the result.
//!
//! `FACERECON_EVAL_DETECTIONS=FILE` keeps the detections in FILE (JSON, written when FILE
//! does not exist, read when it does), so that landmark-side changes can be re-evaluated
//! without the slow detection phase. `FACERECON_EVAL_PER_PHOTO=FILE.csv` writes the
//! per-photo figures. Keep such files outside the repository (they are made from the data
//! set).
//!
//! Figures per folder, on all 700, on `afw` + `testset` folders (not used for the
//! calibration fit) and on the `trainset` folders (used for it).
//!
//! Detection is the slow part, so this run also refits the box calibration on the
//! `trainset` detections (the procedure of `fit_box_calibration`) and reports the NME with
//! both the coefficients in code and the refitted ones.

#[path = "../tests/support/faces300w.rs"]
mod faces300w;

use std::collections::BTreeMap;
use std::sync::Arc;
use std::time::Instant;

use facerecon_vision::detect::ViolaJones;
use facerecon_vision::face::{Detection, FaceBox, FaceDetector, LandmarkPredictor, Landmarks, ModelRunError};
use facerecon_vision::landmarks::box_convention::BoxMap;
use facerecon_vision::landmarks::box_from_landmarks::BoxFromLandmarks;
use facerecon_vision::landmarks::{BoxCalibration, ShapePredictor};
use facerecon_vision::pipeline::FrontEnd;

struct PhotoResult {
    path: String,
    detected: bool,
    nme_pipeline: Option<f64>,
    nme_refit: Option<f64>,
    nme_uncalibrated: Option<f64>,
    nme_dlib_ref: Option<f64>,
    nme_port_on_hog: Option<f64>,
    /// NME after 1, 2, 3, 4 landmark passes from the calibrated detector box.
    nme_passes: Option<[f64; 4]>,
    /// After 1 and 3 passes from the raw detector box.
    nme_uncalibrated_passes: Option<[f64; 2]>,
    /// After 1 and 2 passes from dlib's HOG box.
    nme_hog_passes: Option<[f64; 2]>,
    source: Option<String>,
    /// IoU of the detection with the annotated landmark box.
    iou: Option<f32>,
    /// IoU of the last pass's input box (3 passes) with dlib's HOG box, when dlib found the face.
    final_box_iou_hog: Option<f32>,
    /// Landmark passes the product setting (up to 3) ran before the box settled.
    passes_run: Option<usize>,
    /// NME with all 3 passes run (no settling), to show what settling costs.
    nme_every_pass: Option<f64>,
    yaw: f32,
}

/// A detector that finds nothing: the evaluation hands detections to [`FrontEnd::face`].
struct NoDetector;
impl FaceDetector for NoDetector {
    fn detect(&self, _: &image::RgbImage) -> Result<Vec<Detection>, ModelRunError> {
        Ok(Vec::new())
    }
}

/// One loaded model shared by several front ends.
struct SharedPredictor(Arc<ShapePredictor>);
impl LandmarkPredictor for SharedPredictor {
    fn predict(&self, image: &image::RgbImage, face: &Detection) -> Result<Landmarks, ModelRunError> {
        LandmarkPredictor::predict(&*self.0, image, face)
    }
}

/// Rough yaw from the annotation: horizontal offset of the nose tip (point 30) from the
/// middle of the jaw ends (0, 16), over the jaw width; 0 frontal, ±0.5 about profile.
fn yaw(pts: &[[f32; 2]]) -> f32 {
    let w = pts[16][0] - pts[0][0];
    (pts[30][0] - 0.5 * (pts[0][0] + pts[16][0])) / w.abs().max(1.0)
}

/// Phase 1, or its saved result.
fn detections_cached(
    path: Option<std::path::PathBuf>,
    run: impl FnOnce() -> Vec<(usize, Option<Detection>)>,
) -> Vec<(usize, Option<Detection>)> {
    if let Some((p, text)) = path.as_ref().and_then(|p| Some((p, std::fs::read_to_string(p).ok()?))) {
        eprintln!("detections read from {}", p.display());
        return serde_json::from_str(&text).expect("detections file");
    }
    let d = run();
    if let Some(p) = &path {
        std::fs::write(p, serde_json::to_string(&d).unwrap()).expect("writing the detections file");
    }
    d
}

fn main() {
    let dir = faces300w::dataset_dir();
    let photos = faces300w::read_manifest(&dir);
    let refs: BTreeMap<String, faces300w::DlibReference> = faces300w::read_dlib_reference(&dir)
        .into_iter()
        .filter(|r| r.box_kind == "dlib_hog")
        .map(|r| (r.path.clone(), r))
        .collect();
    let mut detector = ViolaJones::load_default().expect("cascades");
    // Smallest face sought: 10 % of the image's shorter side (99 % of the annotated faces
    // here are wider than 12.6 % of it, the smallest 6.4 %); the product default (24 px at
    // any image size) scans far more windows, which a shared 2-core machine could not
    // afford over 700 photos in the time available. Override: MIN_FACE_FRACTION=0.
    let fraction: f32 = std::env::var("MIN_FACE_FRACTION").ok().and_then(|v| v.parse().ok()).unwrap_or(0.1);
    let mut params = detector.params().clone();
    params.min_size_fraction = fraction;
    // DETECT_C2F=f: coarse-to-fine stage fraction (`off`: scan every window, the detector
    // before docs/decisions/0401-detector-speed.md).
    if let Ok(v) = std::env::var("DETECT_C2F") {
        params.coarse_to_fine = if v == "off" { None } else { Some(v.parse().expect("DETECT_C2F: a number or off")) };
    }
    detector.set_params(params).expect("detector parameters");
    println!("detector: product cascades, {:?}", detector.params());
    let t = Instant::now();
    let sp = Arc::new(ShapePredictor::load_default().expect("dlib model"));
    eprintln!("dlib model loaded in {:.3} s", t.elapsed().as_secs_f64());
    let cal = BoxCalibration::viola_jones_to_dlib();
    let t = Instant::now();
    let done = std::sync::atomic::AtomicUsize::new(0);
    // Phase 1: detections (the slow part), best-overlapping detection per photo.
    let cache = std::env::var_os("FACERECON_EVAL_DETECTIONS").map(std::path::PathBuf::from);
    let detected = detections_cached(cache, || {
        parallel(&(0..photos.len()).collect::<Vec<_>>(), |&i| {
            let p = &photos[i];
            let tbox = faces300w::landmark_box(&faces300w::read_pts(&dir, &p.path));
            let img = faces300w::load_rgb(&dir, &p.path);
            let dets = detector.detect(&img).expect("detector");
            let n = done.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1;
            if n.is_multiple_of(25) {
                eprintln!("{n} photos detected, {:.0} s", t.elapsed().as_secs_f64());
            }
            let best = dets
                .iter()
                .map(|d| (d.face_box.iou(&tbox), d))
                .filter(|(iou, _)| *iou > 0.3)
                .max_by(|a, b| a.0.total_cmp(&b.0))
                .map(|x| x.1.clone());
            Some((i, best))
        })
    });
    eprintln!("detection on {} photos in {:.1} s", photos.len(), t.elapsed().as_secs_f64());
    // Refit of the calibration on trainset pairs (detection, dlib HOG box).
    let mut pairs: BTreeMap<String, Vec<(FaceBox, FaceBox)>> = BTreeMap::new();
    for (i, d) in &detected {
        let p = &photos[*i];
        if let (true, Some(d), Some(r)) = (faces300w::is_trainset(&p.path), d, refs.get(&p.path)) {
            pairs.entry(d.source.clone()).or_default().push((d.face_box, r.face_box()));
        }
    }
    let all: Vec<_> = pairs.values().flatten().copied().collect();
    let mut refit = BoxCalibration::identity();
    refit.fallback = BoxMap::fit(&all).expect("pairs");
    println!("refit on {} trainset pairs: fallback {:?}", all.len(), refit.fallback);
    for (s, v) in &pairs {
        if v.len() >= 10 {
            let m = BoxMap::fit(v).unwrap();
            println!("  {s:?} ({} pairs): {m:?}", v.len());
            refit.by_source.insert(s.clone(), m);
        } else {
            println!(
                "  {s:?}: {} pairs, uses {:?}",
                v.len(),
                s.strip_suffix("-mirrored").map_or("the fallback".to_string(), |b| format!("{b}'s map mirrored"))
            );
        }
    }
    // Phase 2: landmarks, through the front end.
    let front = |cal: &BoxCalibration, passes: usize| {
        FrontEnd::new(Box::new(NoDetector), Box::new(SharedPredictor(sp.clone())))
            .with_calibration(cal.clone())
            .with_refinement(BoxFromLandmarks::dlib_68(), passes)
    };
    let fronts: Vec<FrontEnd> = (0..4).map(|k| front(&cal, k)).collect();
    let every_pass = front(&cal, 2).with_settle(0.0);
    let uncal = [front(&BoxCalibration::identity(), 0), front(&BoxCalibration::identity(), 2)];
    let hog = [front(&BoxCalibration::identity(), 0), front(&BoxCalibration::identity(), 1)];
    let results = parallel(&detected, |(i, best)| {
        let p = &photos[*i];
        let truth = faces300w::read_pts(&dir, &p.path);
        let img = faces300w::load_rgb(&dir, &p.path);
        let through = |fe: &FrontEnd, d: &Detection| {
            let f = fe.face(&img, d.clone()).expect("front end");
            (faces300w::nme(&f.landmarks.points, &truth), f.landmark_input_box)
        };
        let nme_passes = best.as_ref().map(|d| [0, 1, 2, 3].map(|k| through(&fronts[k], d).0));
        let nme_uncalibrated_passes = best.as_ref().map(|d| [0, 1].map(|k| through(&uncal[k], d).0));
        let hog_det =
            refs.get(&p.path).map(|r| Detection { face_box: r.face_box(), score: 1.0, source: "dlib-hog".into() });
        let nme_hog_passes = hog_det.as_ref().map(|d| [0, 1].map(|k| through(&hog[k], d).0));
        let passes_run = best.as_ref().map(|d| fronts[2].face(&img, d.clone()).expect("front end").landmark_passes);
        let nme_every_pass = best.as_ref().map(|d| through(&every_pass, d).0);
        let final_box_iou_hog = match (best, &hog_det) {
            (Some(d), Some(h)) => Some(through(&fronts[2], d).1.iou(&h.face_box)),
            _ => None,
        };
        let tbox = faces300w::landmark_box(&truth);
        let nme_box = |b: &FaceBox| faces300w::nme(&sp.predict(&img, b), &truth);
        let with = |c: &BoxCalibration| best.as_ref().map(|d| nme_box(&c.apply(&d.source, &d.face_box)));
        let r = refs.get(&p.path);
        let nme_dlib_ref = r.map(|r| {
            let pts: Vec<[f32; 2]> = r.points.iter().map(|q| [q[0] as f32, q[1] as f32]).collect();
            faces300w::nme(&pts, &truth)
        });
        Some(PhotoResult {
            path: p.path.clone(),
            detected: best.is_some(),
            nme_pipeline: with(&cal),
            nme_refit: with(&refit),
            nme_uncalibrated: best.as_ref().map(|d| nme_box(&d.face_box)),
            nme_dlib_ref,
            nme_port_on_hog: r.map(|r| nme_box(&r.face_box())),
            nme_passes,
            nme_uncalibrated_passes,
            nme_hog_passes,
            source: best.as_ref().map(|d| d.source.clone()),
            iou: best.as_ref().map(|d| d.face_box.iou(&tbox)),
            final_box_iou_hog,
            passes_run,
            nme_every_pass,
            yaw: yaw(&truth),
        })
    });
    eprintln!("{} photos in {:.1} s", results.len(), t.elapsed().as_secs_f64());

    type Group<'a> = (&'a str, Box<dyn Fn(&str) -> bool>);
    let groups: Vec<Group> = vec![
        ("afw", Box::new(|p: &str| faces300w::folder_of(p) == "afw")),
        ("helen/testset", Box::new(|p: &str| faces300w::folder_of(p) == "helen/testset")),
        ("helen/trainset", Box::new(|p: &str| faces300w::folder_of(p) == "helen/trainset")),
        ("lfpw/testset", Box::new(|p: &str| faces300w::folder_of(p) == "lfpw/testset")),
        ("lfpw/trainset", Box::new(|p: &str| faces300w::folder_of(p) == "lfpw/trainset")),
        ("afw + testset (held out)", Box::new(|p: &str| !faces300w::is_trainset(p))),
        ("trainset (calibration fit)", Box::new(|p: &str| faces300w::is_trainset(p))),
        ("all 700", Box::new(|_: &str| true)),
    ];
    println!(
        "| photos | n | detection rate | NME 1 pass (calibration in code) | NME 1 pass (refit calibration) | NME 1 pass without calibration | dlib on its HOG boxes (ref.) | our port on dlib's HOG boxes |"
    );
    println!("| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |");
    for (name, f) in &groups {
        let rs: Vec<&PhotoResult> = results.iter().filter(|r| f(&r.path)).collect();
        let det = rs.iter().filter(|r| r.detected).count();
        let mean = |g: &dyn Fn(&PhotoResult) -> Option<f64>| {
            let v: Vec<f64> = rs.iter().filter_map(|r| g(r)).collect();
            format!("{:.2} % ({})", 100.0 * v.iter().sum::<f64>() / v.len().max(1) as f64, v.len())
        };
        println!(
            "| {name} | {} | {:.1} % | {} | {} | {} | {} | {} |",
            rs.len(),
            100.0 * det as f64 / rs.len() as f64,
            mean(&|r| r.nme_pipeline),
            mean(&|r| r.nme_refit),
            mean(&|r| r.nme_uncalibrated),
            mean(&|r| r.nme_dlib_ref),
            mean(&|r| r.nme_port_on_hog)
        );
    }

    println!();
    let runs: Vec<usize> = results.iter().filter_map(|r| r.passes_run).collect();
    let count = |k: usize| runs.iter().filter(|&&n| n == k).count();
    println!(
        "Passes run with up to 3 (box settled at {} of its side): mean {:.2}; 1 pass {}, 2 passes {}, 3 passes {} faces",
        facerecon_vision::pipeline::Refinement::DEFAULT_SETTLE,
        runs.iter().sum::<usize>() as f64 / runs.len().max(1) as f64,
        count(1),
        count(2),
        count(3)
    );
    let every = |keep: &dyn Fn(&str) -> bool| {
        let v: Vec<f64> = results.iter().filter(|r| keep(&r.path)).filter_map(|r| r.nme_every_pass).collect();
        100.0 * v.iter().sum::<f64>() / v.len().max(1) as f64
    };
    println!(
        "With all 3 passes run (no settling): NME {:.2} % all, {:.2} % afw + testset",
        every(&|_| true),
        every(&|p| !faces300w::is_trainset(p))
    );
    println!(
        "Refinement passes (calibration in code, map `BoxFromLandmarks::dlib_68()`, a pass skipped once the box settles):"
    );
    println!(
        "| photos | 1 pass (no refinement) | 2 passes | 3 passes | 4 passes | raw detector box, 1 pass | raw detector box, 3 passes | dlib HOG box, 1 pass | dlib HOG box, 2 passes |"
    );
    println!("| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |");
    for (name, f) in &groups {
        let rs: Vec<&PhotoResult> = results.iter().filter(|r| f(&r.path)).collect();
        let mean = |g: &dyn Fn(&PhotoResult) -> Option<f64>| {
            let v: Vec<f64> = rs.iter().filter_map(|r| g(r)).collect();
            format!("{:.2} % ({})", 100.0 * v.iter().sum::<f64>() / v.len().max(1) as f64, v.len())
        };
        let mut cells: Vec<String> = (0..4).map(|k| mean(&|r| r.nme_passes.map(|v| v[k]))).collect();
        cells.extend((0..2).map(|k| mean(&|r| r.nme_uncalibrated_passes.map(|v| v[k]))));
        cells.extend((0..2).map(|k| mean(&|r| r.nme_hog_passes.map(|v| v[k]))));
        println!("| {name} | {} |", cells.join(" | "));
    }

    if let Some(p) = std::env::var_os("FACERECON_EVAL_PER_PHOTO") {
        let mut csv = String::from("path,source,iou,yaw,nme_1,nme_2,nme_3,nme_4,raw_1,raw_3,hog_1,hog_2,dlib_ref\n");
        let f = |v: Option<f64>| v.map_or(String::new(), |v| format!("{v:.5}"));
        for r in &results {
            let n = r.nme_passes.map(|v| v.map(Some)).unwrap_or([None; 4]);
            let u = r.nme_uncalibrated_passes.map(|v| v.map(Some)).unwrap_or([None; 2]);
            let h = r.nme_hog_passes.map(|v| v.map(Some)).unwrap_or([None; 2]);
            csv += &format!(
                "{},{},{},{:.3},{},{},{},{},{},{},{},{},{}\n",
                r.path,
                r.source.as_deref().unwrap_or(""),
                r.iou.map_or(String::new(), |v| format!("{v:.3}")),
                r.yaw,
                f(n[0]),
                f(n[1]),
                f(n[2]),
                f(n[3]),
                f(u[0]),
                f(u[1]),
                f(h[0]),
                f(h[1]),
                f(r.nme_dlib_ref)
            );
        }
        std::fs::write(p, csv).expect("writing the per-photo file");
    }

    println!();
    println!("Worst 15 afw photos (3 passes, as `facerecon detect`):");
    println!(
        "| photo | NME 1 pass | NME 2 passes | NME 3 passes | source | IoU detection / annotated box | final box IoU with dlib's HOG box | yaw | dlib on its HOG box |"
    );
    println!("| --- | ---: | ---: | ---: | --- | ---: | ---: | ---: | ---: |");
    let mut afw: Vec<&PhotoResult> =
        results.iter().filter(|r| faces300w::folder_of(&r.path) == "afw" && r.nme_passes.is_some()).collect();
    afw.sort_by(|a, b| b.nme_passes.unwrap()[2].total_cmp(&a.nme_passes.unwrap()[2]));
    let opt = |v: Option<f64>, scale: f64| v.map_or("–".to_string(), |v| format!("{:.2}", scale * v));
    for r in afw.iter().take(15) {
        let n = r.nme_passes.unwrap();
        println!(
            "| {} | {:.2} % | {:.2} % | {:.2} % | {} | {:.2} | {} | {:+.2} | {} |",
            r.path,
            100.0 * n[0],
            100.0 * n[1],
            100.0 * n[2],
            r.source.as_deref().unwrap_or("–"),
            r.iou.unwrap_or(0.0),
            opt(r.final_box_iou_hog.map(f64::from), 1.0),
            r.yaw,
            opt(r.nme_dlib_ref, 100.0).replace("–", "not found") + if r.nme_dlib_ref.is_some() { " %" } else { "" }
        );
    }
}

/// Maps `f` over `items` on all cores, keeping the order and dropping `None`s.
fn parallel<T: Sync, R: Send>(items: &[T], f: impl Fn(&T) -> Option<R> + Sync) -> Vec<R> {
    let threads = std::thread::available_parallelism().map_or(2, |n| n.get());
    std::thread::scope(|s| {
        let hs: Vec<_> = items
            .chunks(items.len().div_ceil(threads).max(1))
            .map(|c| s.spawn(|| c.iter().filter_map(&f).collect::<Vec<_>>()))
            .collect();
        hs.into_iter().flat_map(|h| h.join().unwrap()).collect()
    })
}
