use super::cascade::{Cascade, FeatureType};
use super::integral::Integral;
use super::pyramid::Grey;
use super::scan::{Compiled, Outcome};
use super::*;

/// A hand-built Haar cascade on a 6 × 6 window:
/// feature 0 = −Σ(whole window) + 2·Σ(right half), feature 1 = Σ(left half);
/// stage 0: one stump on feature 0 (< 1.5 → −1, else +1), threshold 0.5;
/// stage 1: a two-node tree — feature 0 < 2.0 → leaf 0 (−5); else feature 1 < 0 → leaf 1
/// (−3), else leaf 2 (0.7); threshold 0.6.
const TINY_HAAR: &str = r#"<?xml version="1.0"?>
<opencv_storage>
<cascade type_id="opencv-cascade-classifier">
  <stageType>BOOST</stageType>
  <featureType>HAAR</featureType>
  <height>6</height>
  <width>6</width>
  <stageParams><maxWeakCount>1</maxWeakCount></stageParams>
  <featureParams><maxCatCount>0</maxCatCount></featureParams>
  <stageNum>2</stageNum>
  <stages>
    <_>
      <maxWeakCount>1</maxWeakCount>
      <stageThreshold>0.5</stageThreshold>
      <weakClassifiers>
        <_><internalNodes>0 -1 0 1.5</internalNodes><leafValues>-1. 1.</leafValues></_>
      </weakClassifiers>
    </_>
    <_>
      <maxWeakCount>1</maxWeakCount>
      <stageThreshold>6.0000000000000000e-01</stageThreshold>
      <weakClassifiers>
        <_><internalNodes>0 1 0 2.0 -1 -2 1 0.0</internalNodes>
           <leafValues>-5. -3. 0.7</leafValues></_>
      </weakClassifiers>
    </_>
  </stages>
  <features>
    <_><rects><_>0 0 6 6 -1.</_><_>3 0 3 6 2.</_></rects><tilted>0</tilted></_>
    <_><rects><_>0 0 3 6 1.</_></rects></_>
  </features>
</cascade>
</opencv_storage>
"#;

fn grey6(f: impl Fn(usize, usize) -> u8) -> Grey {
    Grey { width: 6, height: 6, pixels: (0..36).map(|i| f(i % 6, i / 6)).collect() }
}

fn run_one(c: &Cascade, g: &Grey) -> Outcome {
    let ii = Integral::new(&g.pixels, g.width, g.height, true, c.has_tilted());
    Compiled::new(c, ii.stride).eval(&ii, 0)
}

#[test]
fn tiny_haar_cascade_outcomes_computed_by_hand() {
    let c = Cascade::from_xml(TINY_HAAR).unwrap();
    assert_eq!(c.feature_type, FeatureType::Haar);
    assert_eq!(c.stages.len(), 2);
    // Left half 0, right half 200. Normalisation window = the inner 4 × 4: 8 pixels of each
    // value, Σ = 1600, Σ² = 320000, area 16: nf = √(16·320000 − 1600²) = 1600.
    // Feature 0 = −3600 + 2·3600 = 3600 → 3600 / 1600 = 2.25 ≥ 1.5 → +1 ≥ 0.5: stage 0 passes.
    // Stage 1: 2.25 ≥ 2.0 → node 1: feature 1 = 0 → 0/1600 = 0, not < 0 → leaf 2 = 0.7 ≥ 0.6.
    let g = grey6(|x, _| if x < 3 { 0 } else { 200 });
    match run_one(&c, &g) {
        Outcome::Accepted(m) => assert!((m - (0.7 - (0.6 - 1e-5))).abs() < 1e-6, "margin {m}"),
        o => panic!("expected accepted, got {o:?}"),
    }
    // Mirrored picture: feature 0 = −2.25 < 1.5 → −1 < 0.5: rejected by stage 0.
    let g = grey6(|x, _| if x < 3 { 200 } else { 0 });
    assert_eq!(run_one(&c, &g), Outcome::Rejected(0));
    // Column 5 (outside the normalisation window) dark: feature 0 = −2400 + 4800 = 2400 →
    // 1.5, not < 1.5 → +1 passes stage 0; stage 1: 1.5 < 2.0 → leaf 0 = −5: rejected there.
    let g = grey6(|x, _| if (3..5).contains(&x) { 200 } else { 0 });
    assert_eq!(run_one(&c, &g), Outcome::Rejected(1));
    // A flat window (σ ≤ 10) is refused before any stage, as in OpenCV.
    assert_eq!(run_one(&c, &grey6(|_, _| 90)), Outcome::Flat);
    assert_eq!(run_one(&c, &grey6(|x, _| if x < 3 { 90 } else { 100 })), Outcome::Flat); // σ = 5
    // The mirrored cascade accepts the mirrored picture and rejects the original.
    let m = c.mirrored();
    assert!(matches!(run_one(&m, &grey6(|x, _| if x < 3 { 200 } else { 0 })), Outcome::Accepted(_)));
    assert_eq!(run_one(&m, &grey6(|x, _| if x < 3 { 0 } else { 200 })), Outcome::Rejected(0));
}

/// An LBP cascade on a 3 × 3 window of 1-pixel blocks: accepts exactly LBP code 128
/// (only the top-left neighbour ≥ the centre): subset word 4, bit 0.
const TINY_LBP: &str = r#"<opencv_storage><cascade>
  <stageType>BOOST</stageType><featureType>LBP</featureType>
  <height>3</height><width>3</width>
  <featureParams><maxCatCount>256</maxCatCount></featureParams>
  <stageNum>1</stageNum>
  <stages><_>
    <maxWeakCount>1</maxWeakCount><stageThreshold>0.</stageThreshold>
    <weakClassifiers><_>
      <internalNodes>0 -1 0 0 0 0 0 1 0 0 0</internalNodes>
      <leafValues>1. -1.</leafValues></_></weakClassifiers></_></stages>
  <features><_><rect>0 0 1 1</rect></_></features>
</cascade></opencv_storage>"#;

#[test]
fn tiny_lbp_cascade_outcomes_computed_by_hand() {
    let c = Cascade::from_xml(TINY_LBP).unwrap();
    let g = |px: [u8; 9]| Grey { width: 3, height: 3, pixels: px.to_vec() };
    // Top-left 200 ≥ centre 100, all others 0 < 100: code 128 → in the subset → +1 ≥ 0.
    let tl = g([200, 0, 0, 0, 100, 0, 0, 0, 0]);
    assert!(matches!(run_one(&c, &tl), Outcome::Accepted(_)));
    // Top-right instead: code 32 → not in the subset → −1 < 0.
    let tr = g([0, 0, 200, 0, 100, 0, 0, 0, 0]);
    assert_eq!(run_one(&c, &tr), Outcome::Rejected(0));
    // Equal to the centre counts as set (≥): every neighbour 100 → code 255 → rejected.
    assert_eq!(run_one(&c, &g([100; 9])), Outcome::Rejected(0));
    // Mirrored cascade: top-right is the mirror of top-left.
    let m = c.mirrored();
    assert!(matches!(run_one(&m, &tr), Outcome::Accepted(_)));
    assert_eq!(run_one(&m, &tl), Outcome::Rejected(0));
}

#[test]
fn malformed_cascades_are_refused_with_reasons() {
    let bad = |xml: &str, needle: &str| {
        let e = Cascade::from_xml(xml).expect_err("must fail").to_string();
        assert!(e.contains(needle), "`{e}` does not mention `{needle}`");
    };
    bad("not xml at all <", "not valid XML");
    bad("<root/>", "expected <opencv_storage>");
    bad("<opencv_storage/>", "empty");
    bad(
        r#"<opencv_storage><haarcascade type_id="opencv-haar-classifier"><size>20 20</size></haarcascade></opencv_storage>"#,
        "old-format",
    );
    bad(&TINY_HAAR.replace("<featureType>HAAR", "<featureType>HOG"), "HOG");
    bad(&TINY_HAAR.replace("<stageType>BOOST", "<stageType>GAB"), "GAB");
    bad(&TINY_HAAR.replace("<width>6</width>", "<width>0</width>"), "window");
    bad(&TINY_HAAR.replace("<width>6</width>", ""), "<width>");
    bad(&TINY_HAAR.replace("0 -1 0 1.5", "0 -1 7 1.5"), "feature index 7");
    bad(&TINY_HAAR.replace("0 -1 0 1.5", "0 -1 0"), "multiple of 4");
    bad(&TINY_HAAR.replace("0 -1 0 1.5", "0 -1 0 abc"), "`abc` is not a number");
    // A child pointing back at its own node would loop forever.
    bad(&TINY_HAAR.replace("0 1 0 2.0 -1 -2 1 0.0", "0 1 0 2.0 1 -2 1 0.0"), "child 1");
    bad(&TINY_HAAR.replace("-1 -2 1 0.0", "-1 -3 1 0.0"), "child -3");
    bad(&TINY_HAAR.replace("3 0 3 6 2.", "4 0 3 6 2."), "outside");
    bad(&TINY_HAAR.replace("<stageNum>2", "<stageNum>3"), "stageNum");
    bad(&TINY_HAAR.replace("<maxCatCount>0", "<maxCatCount>256"), "maxCatCount");
    bad(&TINY_LBP.replace("<rect>0 0 1 1", "<rect>1 0 1 1"), "outside");
    bad(&TINY_LBP.replace("<rect>0 0 1 1", "<rect>0 0 1"), "4 numbers");
}

fn opencv_dir() -> PathBuf {
    PathBuf::from(OPENCV_DATA_DIR)
}

#[test]
fn every_installed_cascade_loads_or_is_refused_clearly() {
    // Needs Debian's opencv-data (set-up installs it).
    let mut loaded = 0;
    for sub in ["haarcascades", "lbpcascades"] {
        let dir = opencv_dir().join(sub);
        let entries =
            std::fs::read_dir(&dir).unwrap_or_else(|e| panic!("{}: {e} (install opencv-data)", dir.display()));
        for e in entries {
            let path = e.unwrap().path();
            let xml = std::fs::read_to_string(&path).unwrap();
            match Cascade::from_xml(&xml) {
                Ok(c) => {
                    loaded += 1;
                    assert!(!c.stages.is_empty());
                    let m = c.mirrored();
                    assert_eq!(m.mirrored(), c, "mirroring twice is the identity: {}", path.display());
                }
                Err(e) => {
                    assert!(xml.contains("opencv-haar-classifier"), "{}: {e}", path.display());
                    assert!(e.to_string().contains("old-format"));
                }
            }
        }
    }
    assert!(loaded >= 20, "{loaded}");
}

#[test]
fn missing_cascades_name_the_package() {
    let e = ViolaJones::load_default_from(Path::new("/nonexistent")).unwrap_err().to_string();
    assert!(e.contains("opencv-data"), "{e}");
}

fn shared_dir() -> PathBuf {
    std::env::var_os("FACERECON_SHARED")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../../../shared")))
}

fn photo(rel: &str) -> RgbImage {
    let p = shared_dir().join("data/faces-300w").join(rel);
    crate::decode::decode(&std::fs::read(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()))).unwrap()
}

/// The mirrored cascade on an image answers exactly what the cascade answers on the
/// flipped image, window for window (Haar and LBP profile cascades on a real photo).
#[test]
fn mirrored_cascade_equals_cascade_on_flipped_image() {
    let img = photo("lfpw/testset/image_0003.png");
    let grey = Grey::from_rgb(&img);
    let small = grey.resize(grey.width / 4, grey.height / 4);
    let flipped = small.flipped();
    let ii = Integral::new(&small.pixels, small.width, small.height, true, false);
    let iif = Integral::new(&flipped.pixels, flipped.width, flipped.height, true, false);
    for file in [PROFILE_HAAR, PROFILE_LBP] {
        let c = Cascade::from_xml(&std::fs::read_to_string(opencv_dir().join(file)).unwrap()).unwrap();
        let m = c.mirrored();
        let (cc, mc) = (Compiled::new(&c, ii.stride), Compiled::new(&m, ii.stride));
        let (ww, wh) = (c.width as usize, c.height as usize);
        let mut deep = 0;
        for y in 0..=small.height - wh {
            for x in 0..=small.width - ww {
                let a = mc.eval(&ii, y * ii.stride + x);
                let b = cc.eval(&iif, y * iif.stride + (small.width - ww - x));
                assert_eq!(a, b, "{file} at ({x},{y})");
                if matches!(a, Outcome::Rejected(s) if s >= 3) || matches!(a, Outcome::Accepted(_)) {
                    deep += 1;
                }
            }
        }
        assert!(deep > 10, "{file}: the photo should exercise deeper stages ({deep})");
    }
}

fn manifest_box(rel: &str) -> FaceBox {
    let m = std::fs::read_to_string(shared_dir().join("data/faces-300w/manifest.csv")).unwrap();
    let line = m.lines().find(|l| l.starts_with(&format!("{rel},"))).unwrap();
    let v: Vec<f32> = line.split(',').skip(4).map(|t| t.parse().unwrap()).collect();
    // .pts are 1-based.
    FaceBox { x0: v[0] - 1.0, y0: v[1] - 1.0, x1: v[2] - 1.0, y1: v[3] - 1.0 }
}

#[test]
fn finds_the_annotated_face_in_real_photos() {
    let mut det = ViolaJones::load_default().unwrap();
    // Faces of at least a fifth of the photo keep this test fast in debug builds.
    det.set_params(DetectorParams { min_size_fraction: 0.2, ..Default::default() }).unwrap();
    for rel in ["lfpw/testset/image_0003.png", "helen/testset/296814969_3.jpg"] {
        let path = shared_dir().join("data/faces-300w").join(rel);
        if !path.exists() {
            panic!("{} missing", path.display());
        }
        let img = photo(rel);
        let truth = manifest_box(rel);
        let faces = det.detect(&img).unwrap();
        let best = faces.iter().map(|d| d.face_box.iou(&truth)).fold(0.0, f32::max);
        assert!(best > 0.3, "{rel}: best IoU {best} among {faces:?}");
    }
}

#[test]
fn tiny_and_empty_images_give_no_faces() {
    let det = ViolaJones::load_default().unwrap();
    assert!(det.detect(&RgbImage::new(0, 0)).unwrap().is_empty());
    assert!(det.detect(&RgbImage::new(10, 10)).unwrap().is_empty());
    assert!(det.detect(&RgbImage::from_pixel(200, 100, image::Rgb([128, 128, 128]))).unwrap().is_empty());
}

#[test]
fn bad_params_are_refused() {
    let mut det = ViolaJones::load_default().unwrap();
    assert!(det.set_params(DetectorParams { scale_factor: 1.0, ..Default::default() }).is_err());
    assert!(det.set_params(DetectorParams { min_size_fraction: 2.0, ..Default::default() }).is_err());
    assert!(det.set_params(DetectorParams { fixed_step: Some(0), ..Default::default() }).is_err());
    assert!(det.set_params(DetectorParams { coarse_to_fine: Some(1.5), ..Default::default() }).is_err());
    assert!(det.set_params(DetectorParams { coarse_grid: 1, ..Default::default() }).is_err());
    assert!(
        det.set_params(DetectorParams { fixed_step: Some(2), coarse_to_fine: Some(0.3), ..Default::default() }).is_ok()
    );
    assert_eq!(DetectorParams::opencv().coarse_to_fine, None);
    assert_eq!(DetectorParams::opencv().min_size_fraction, 0.0);
    assert!(det.set_params(DetectorParams::opencv()).is_ok());
    // A cascade's own coarse grid is checked like the parameters' one.
    let mut cascades = det.cascades().to_vec();
    assert_eq!(cascades.iter().filter(|c| c.coarse_grid == Some(PROFILE_COARSE_GRID)).count(), 2);
    cascades[0].coarse_grid = Some(9);
    assert!(ViolaJones::new(cascades.clone(), DetectorParams::default()).is_err());
    cascades[0].coarse_grid = Some(3);
    assert!(ViolaJones::new(cascades, DetectorParams::default()).is_ok());
}

/// The inlined-stump evaluation (the fast path of every installed stump cascade) gives
/// exactly the outcomes of the generic node-table path, window for window, on a real photo.
#[test]
fn inlined_stumps_match_the_generic_path() {
    let rel = "helen/testset/296814969_3.jpg";
    let grey = Grey::from_rgb(&photo(rel));
    for file in [FRONTAL_HAAR, FRONTAL_LBP_IMPROVED, PROFILE_HAAR] {
        let c = Cascade::from_xml(&std::fs::read_to_string(opencv_dir().join(file)).unwrap()).unwrap();
        let small = face_level(&grey, rel, &c);
        let ii = Integral::new(&small.pixels, small.width, small.height, true, false);
        for c in [c.mirrored(), c] {
            let cc = Compiled::new(&c, ii.stride);
            let (ex, ey) = c.extent();
            let (mut deep, mut accepted) = (0, 0);
            for y in 0..=small.height - ey as usize {
                for x in 0..=small.width - ex as usize {
                    let base = y * ii.stride + x;
                    let a = cc.eval(&ii, base);
                    assert_eq!(a, cc.eval_generic(&ii, base), "{file} at ({x},{y})");
                    deep += usize::from(matches!(a, Outcome::Rejected(s) if s >= 3));
                    accepted += usize::from(matches!(a, Outcome::Accepted(_)));
                }
            }
            assert!(deep > 10, "{file}: the photo should exercise deeper stages ({deep})");
            if file != PROFILE_HAAR {
                assert!(accepted > 0, "{file}: the frontal face should be accepted somewhere");
            }
        }
    }
}

/// The photo shrunk so that its annotated face (landmark box) is 0.5–1.0 of the cascade
/// window wide, the ratio (in steps of 0.1) at which the cascade accepts most windows.
fn face_level(grey: &Grey, rel: &str, c: &Cascade) -> Grey {
    let truth = manifest_box(rel);
    let (ex, ey) = c.extent();
    let mut best = (0, None);
    for ratio in [0.5f32, 0.6, 0.7, 0.8, 0.9, 1.0] {
        let f = (truth.x1 - truth.x0) / (ratio * c.width as f32);
        let g = grey.resize((grey.width as f32 / f).round() as usize, (grey.height as f32 / f).round() as usize);
        let ii = Integral::new(&g.pixels, g.width, g.height, true, false);
        let cc = Compiled::new(c, ii.stride);
        let mut accepted = 0;
        for y in 0..=g.height - ey as usize {
            for x in 0..=g.width - ex as usize {
                accepted += usize::from(matches!(cc.eval_generic(&ii, y * ii.stride + x), Outcome::Accepted(_)));
            }
        }
        if best.1.is_none() || accepted > best.0 {
            best = (accepted, Some(g));
        }
    }
    best.1.unwrap()
}

/// Every window of the regular grid (no skip after a first-stage rejection), as a sorted
/// list of hits: the oracle of the coarse-to-fine scan.
fn all_windows(c: &Compiled<'_>, ii: &Integral, ex: usize, ey: usize, step: usize) -> Vec<(scan::Rect, f32)> {
    let mut out = Vec::new();
    for y in (0..=ii.height - ey).step_by(step) {
        for x in (0..=ii.width - ex).step_by(step) {
            if let Outcome::Accepted(m) = c.eval(ii, y * ii.stride + x) {
                out.push((scan::Rect { x: x as i32, y: y as i32, w: c.cascade().width, h: c.cascade().height }, m));
            }
        }
    }
    out
}

fn sorted(mut v: Vec<(scan::Rect, f32)>) -> Vec<(scan::Rect, f32)> {
    v.sort_by_key(|(r, _)| (r.y, r.x));
    v
}

/// The coarse-to-fine scan, in bands as the detector runs it: with `min_stages` 0 every
/// coarse window marks its neighbourhood, so it must find exactly the full grid's hits
/// (LBP: no flat windows); with a real threshold its hits are a subset of them that still
/// holds at least half the face's hits.
#[test]
fn coarse_to_fine_scan_matches_the_full_grid() {
    let rel = "helen/testset/296814969_3.jpg";
    let grey = Grey::from_rgb(&photo(rel));
    let (mut found, mut total) = (0, 0);
    for (file, step) in [(FRONTAL_LBP_IMPROVED, 1), (FRONTAL_LBP_IMPROVED, 2), (FRONTAL_HAAR, 1), (FRONTAL_HAAR, 2)] {
        let c = Cascade::from_xml(&std::fs::read_to_string(opencv_dir().join(file)).unwrap()).unwrap();
        let small = face_level(&grey, rel, &c);
        let ii = Integral::new(&small.pixels, small.width, small.height, true, false);
        let cc = Compiled::new(&c, ii.stride);
        let (ex, ey) = c.extent();
        let full = sorted(all_windows(&cc, &ii, ex as usize, ey as usize, step));
        assert!(!full.is_empty(), "{file} step {step}: the face should give hits");
        let banded = |grid: usize, min_stages: usize| {
            let mut out = Vec::new();
            for y in (0..small.height).step_by(13) {
                let coarse = scan::Coarse { grid, min_stages };
                scan::scan_rows_coarse_to_fine(&cc, &ii, 1.0, step, coarse, y..(y + 13).min(small.height), &mut out);
            }
            sorted(out)
        };
        if c.feature_type == FeatureType::Lbp {
            for grid in [2, 3] {
                assert_eq!(banded(grid, 0), full, "{file} step {step} grid {grid}");
            }
        }
        let half = banded(2, c.stages.len() / 2);
        assert!(half.iter().all(|h| full.contains(h)), "{file} step {step}: hits outside the full grid");
        found += half.len();
        total += full.len();
    }
    assert!(2 * found >= total, "coarse to fine found {found} of {total} hits");
}

#[test]
fn window_step_follows_opencvs_rule_or_the_fixed_step() {
    let opencv = DetectorParams::opencv();
    assert_eq!(opencv.window_step(1.0, 1), 2);
    assert_eq!(opencv.window_step(1.99, 1), 2);
    assert_eq!(opencv.window_step(2.0, 1), 1);
    // OpenCV's rule looks at the source scale even when the pyramid was prefiltered by 2…
    assert_eq!(opencv.window_step(2.5, 2), 1);
    // …the product's at the scale relative to the prefiltered image.
    let product = DetectorParams::default();
    assert_eq!(product.window_step(2.5, 2), 2);
    assert_eq!(product.window_step(4.0, 2), 1);
    let fixed = DetectorParams { fixed_step: Some(3), ..Default::default() };
    assert_eq!(fixed.window_step(1.0, 1), 3);
    assert_eq!(fixed.window_step(9.0, 2), 3);
}
