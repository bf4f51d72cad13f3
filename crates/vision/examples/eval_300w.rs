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
//!   port on the same boxes.
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
use std::time::Instant;

use facerecon_vision::detect::ViolaJones;
use facerecon_vision::face::{Detection, FaceBox, FaceDetector};
use facerecon_vision::landmarks::box_convention::BoxMap;
use facerecon_vision::landmarks::{BoxCalibration, ShapePredictor};

struct PhotoResult {
    path: String,
    detected: bool,
    nme_pipeline: Option<f64>,
    nme_refit: Option<f64>,
    nme_uncalibrated: Option<f64>,
    nme_dlib_ref: Option<f64>,
    nme_port_on_hog: Option<f64>,
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
    let sp = ShapePredictor::load_default().expect("dlib model");
    eprintln!("dlib model loaded in {:.3} s", t.elapsed().as_secs_f64());
    let cal = BoxCalibration::viola_jones_to_dlib();
    let t = Instant::now();
    let done = std::sync::atomic::AtomicUsize::new(0);
    // Phase 1: detections (the slow part), best-overlapping detection per photo.
    let detected: Vec<(usize, Option<Detection>)> = parallel(&(0..photos.len()).collect::<Vec<_>>(), |&i| {
        let p = &photos[i];
        let tbox = faces300w::landmark_box(&faces300w::read_pts(&dir, &p.path));
        let img = faces300w::load_rgb(&dir, &p.path);
        let dets = detector.detect(&img).expect("detector");
        let n = done.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1;
        if n % 25 == 0 {
            eprintln!("{n} photos detected, {:.0} s", t.elapsed().as_secs_f64());
        }
        let best = dets
            .iter()
            .map(|d| (d.face_box.iou(&tbox), d))
            .filter(|(iou, _)| *iou > 0.3)
            .max_by(|a, b| a.0.total_cmp(&b.0))
            .map(|x| x.1.clone());
        Some((i, best))
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
            println!("  {s:?}: {} pairs, uses the fallback", v.len());
        }
    }
    // Phase 2: landmarks.
    let results = parallel(&detected, |(i, best)| {
        let p = &photos[*i];
        let truth = faces300w::read_pts(&dir, &p.path);
        let img = faces300w::load_rgb(&dir, &p.path);
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
        })
    });
    eprintln!("{} photos in {:.1} s", results.len(), t.elapsed().as_secs_f64());
    // NME_DUMP=file: per-photo pipeline NME (calibration in code), for paired comparisons
    // of two detector settings.
    if let Some(path) = std::env::var_os("NME_DUMP") {
        let lines: String = results
            .iter()
            .map(|r| format!("{},{}\n", r.path, r.nme_pipeline.map_or(String::new(), |v| v.to_string())))
            .collect();
        std::fs::write(&path, lines).expect("NME_DUMP file");
    }

    let groups: Vec<(&str, Box<dyn Fn(&str) -> bool>)> = vec![
        ("afw", Box::new(|p: &str| faces300w::folder_of(p) == "afw")),
        ("helen/testset", Box::new(|p: &str| faces300w::folder_of(p) == "helen/testset")),
        ("helen/trainset", Box::new(|p: &str| faces300w::folder_of(p) == "helen/trainset")),
        ("lfpw/testset", Box::new(|p: &str| faces300w::folder_of(p) == "lfpw/testset")),
        ("lfpw/trainset", Box::new(|p: &str| faces300w::folder_of(p) == "lfpw/trainset")),
        ("afw + testset (held out)", Box::new(|p: &str| !faces300w::is_trainset(p))),
        ("trainset (calibration fit)", Box::new(|p: &str| faces300w::is_trainset(p))),
        ("all 700", Box::new(|_: &str| true)),
    ];
    println!("| photos | n | detection rate | NME pipeline (calibration in code) | NME pipeline (refit) | NME without calibration | dlib on its HOG boxes (ref.) | our port on dlib's HOG boxes |");
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
}

/// Maps `f` over `items` on all cores, keeping the order and dropping `None`s.
fn parallel<T: Sync, R: Send>(items: &[T], f: impl Fn(&T) -> Option<R> + Sync) -> Vec<R> {
    let threads = std::thread::available_parallelism().map_or(2, |n| n.get());
    std::thread::scope(|s| {
        let hs: Vec<_> = items.chunks(items.len().div_ceil(threads).max(1)).map(|c| s.spawn(|| c.iter().filter_map(&f).collect::<Vec<_>>())).collect();
        hs.into_iter().flat_map(|h| h.join().unwrap()).collect()
    })
}
