//! ONNX detector and landmarker plug-ins on small graphs the tests write, with expected
//! outputs worked out by hand from the contract (crates/vision/src/onnx.rs). Needs the
//! ONNX Runtime library: see tests/support/ort_env.rs.

#[path = "support/ort_env.rs"]
mod ort_env;

use facerecon_vision::face::{Detection, FaceBox, FaceDetector, LandmarkPredictor};
use facerecon_vision::onnx::graph::*;
use facerecon_vision::onnx::{
    BoxUnits, OnnxDetector, OnnxDetectorConfig, OnnxError, OnnxLandmarker, OnnxLandmarkerConfig, PointUnits, ResizeMode,
};
use image::{Rgb, RgbImage};

const OPSET: i64 = 13;

// ---------------------------------------------------------------- graphs

/// Five constant boxes (input pixels, edges, 64×64 input); scores `w·mean(input) + b`.
const CONST_BOXES: [[f32; 4]; 5] = [
    [16.0, 16.0, 48.0, 48.0],
    [18.0, 16.0, 50.0, 48.0],
    [0.0, 0.0, 8.0, 8.0],
    [40.0, 0.0, 64.0, 16.0],
    [4.0, 20.0, 14.0, 30.0],
];
const SCORE_W: [f32; 5] = [3.0, 0.0, 0.0, 0.0, 0.0];
const SCORE_B: [f32; 5] = [0.0, 0.9, 0.3, 0.7, 0.6];

fn mean_score_detector<const C: usize>(
    boxes: &[[f32; C]],
    w: &[f32],
    b: &[f32],
    boxes_dims: &[Dim],
    scores_dims: &[Dim],
) -> Graph {
    let n = boxes.len() as i64;
    let flat: Vec<f32> = boxes.iter().flatten().copied().collect();
    Graph {
        nodes: vec![
            node("ReduceMean", &["image"], &["m"]).attr("keepdims", Attr::Int(0)),
            node("Mul", &["m", "w"], &["mw"]),
            node("Add", &["mw", "b"], &["scores"]),
            node("Identity", &["box_const"], &["boxes"]),
        ],
        inputs: vec![value("image", FLOAT, &[Fixed(1), Fixed(3), Fixed(64), Fixed(64)])],
        outputs: vec![value("boxes", FLOAT, boxes_dims), value("scores", FLOAT, scores_dims)],
        initializers: vec![
            init_f32("box_const", &[n, C as i64], &flat),
            init_f32("w", &[w.len() as i64], w),
            init_f32("b", &[b.len() as i64], b),
        ],
    }
}

fn const_detector() -> Graph {
    mean_score_detector(&CONST_BOXES, &SCORE_W, &SCORE_B, &[Named("N"), Fixed(4)], &[Named("N")])
}

/// Nodes that find the brightest pixel of `image` ([1, 3, side, side]): `uf`, `vf` float [1],
/// the column and row of the first maximum of the channel sum.
fn argmax_nodes(side: i64) -> (Vec<Node>, Vec<Initializer>) {
    (
        vec![
            node("ReduceSum", &["image", "axis1"], &["lum"]).attr("keepdims", Attr::Int(0)),
            node("Reshape", &["lum", "flat_shape"], &["flat"]),
            node("ArgMax", &["flat"], &["idx"]).attr("axis", Attr::Int(1)).attr("keepdims", Attr::Int(0)),
            node("Mod", &["idx", "side"], &["u"]),
            node("Div", &["idx", "side"], &["v"]),
            node("Cast", &["u"], &["uf"]).attr("to", Attr::Int(FLOAT as i64)),
            node("Cast", &["v"], &["vf"]).attr("to", Attr::Int(FLOAT as i64)),
        ],
        vec![
            init_i64("axis1", &[1], &[1]),
            init_i64("flat_shape", &[2], &[1, side * side]),
            init_i64("side", &[1], &[side]),
        ],
    )
}

/// A detector that puts a 9×9 box (input pixels) around the brightest input pixel.
fn dot_detector() -> Graph {
    let (mut nodes, mut inits) = argmax_nodes(64);
    nodes.extend([
        node("Concat", &["uf", "vf", "uf", "vf"], &["c"]).attr("axis", Attr::Int(0)),
        node("Add", &["c", "grow"], &["g"]),
        node("Reshape", &["g", "box_shape"], &["boxes"]),
        node("Identity", &["score_const"], &["scores"]),
    ]);
    inits.extend([
        init_f32("grow", &[4], &[-4.0, -4.0, 5.0, 5.0]),
        init_i64("box_shape", &[2], &[1, 4]),
        init_f32("score_const", &[1], &[0.95]),
    ]);
    Graph {
        nodes,
        inputs: vec![value("image", FLOAT, &[Fixed(1), Fixed(3), Fixed(64), Fixed(64)])],
        outputs: vec![value("boxes", FLOAT, &[Fixed(1), Fixed(4)]), value("scores", FLOAT, &[Fixed(1)])],
        initializers: inits,
    }
}

/// Per-point offsets of the landmarker: point k gets (0.001·k, −0.002·k).
fn point_offsets() -> Vec<f32> {
    (0..68).flat_map(|k| [0.001 * k as f32, -0.002 * k as f32]).collect()
}

/// A landmarker over a `side`² crop: every point is the brightest crop pixel plus its
/// offset, in crop-normalised units (`(u + 0.5)/side`) or, with `pixels`, input pixels
/// (offsets scaled by `side` to the same place); confidences the constant `conf`.
fn dot_landmarker(side: i64, pixels: bool, conf: f32) -> Graph {
    let (mut nodes, mut inits) = argmax_nodes(side);
    nodes.extend([
        node("Concat", &["uf", "vf"], &["uv"]).attr("axis", Attr::Int(0)),
        node("Add", &["uv", "half"], &["uvh"]),
        node("Div", &["uvh", "scale"], &["q"]),
        node("Reshape", &["q", "pt_shape"], &["q3"]),
        node("Tile", &["q3", "reps"], &["tiled"]),
        node("Add", &["tiled", "offsets"], &["landmarks"]),
        node("Identity", &["conf_const"], &["confidence"]),
    ]);
    let (half, scale) = if pixels { (0.0, 1.0) } else { (0.5, side as f32) };
    inits.extend([
        init_f32("half", &[1], &[half]),
        init_f32("scale", &[1], &[scale]),
        init_i64("pt_shape", &[3], &[1, 1, 2]),
        init_i64("reps", &[3], &[1, 68, 1]),
        init_f32(
            "offsets",
            &[1, 68, 2],
            &point_offsets().iter().map(|o| o * if pixels { side as f32 } else { 1.0 }).collect::<Vec<f32>>(),
        ),
        init_f32("conf_const", &[1, 68], &[conf; 68]),
    ]);
    Graph {
        nodes,
        inputs: vec![value("image", FLOAT, &[Fixed(1), Fixed(3), Fixed(side), Fixed(side)])],
        outputs: vec![
            value("landmarks", FLOAT, &[Fixed(1), Fixed(68), Fixed(2)]),
            value("confidence", FLOAT, &[Fixed(1), Fixed(68)]),
        ],
        initializers: inits,
    }
}

// ---------------------------------------------------------------- helpers

fn detector(graph: &Graph, config: OnnxDetectorConfig) -> Result<OnnxDetector, OnnxError> {
    OnnxDetector::from_bytes(config, &graph.to_model(OPSET, "facerecon-tests").unwrap(), "test-detector")
}

fn landmarker(graph: &Graph, config: OnnxLandmarkerConfig) -> Result<OnnxLandmarker, OnnxError> {
    OnnxLandmarker::from_bytes(config, &graph.to_model(OPSET, "facerecon-tests").unwrap(), "test-landmarker")
}

fn det_config() -> OnnxDetectorConfig {
    OnnxDetectorConfig::default()
}

fn lm_config() -> OnnxLandmarkerConfig {
    OnnxLandmarkerConfig { confidence_output: Some("confidence".into()), ..OnnxLandmarkerConfig::default() }
}

fn assert_box(d: &Detection, want: [f32; 4], score: f32) {
    let b = d.face_box;
    let got = [b.x0, b.y0, b.x1, b.y1];
    for k in 0..4 {
        assert!((got[k] - want[k]).abs() < 1e-3, "box {got:?}, expected {want:?}");
    }
    assert!((d.score - score).abs() < 1e-5, "score {}, expected {score}", d.score);
}

fn contract_error(e: OnnxError, needle: &str) {
    let msg = e.to_string();
    assert!(matches!(e, OnnxError::Contract { .. }), "expected a contract error, got: {msg}");
    assert!(msg.contains(needle), "error `{msg}` does not mention `{needle}`");
}

#[track_caller]
fn load_err<T: std::fmt::Debug>(r: Result<T, OnnxError>) -> OnnxError {
    r.expect_err("the model loaded, but it breaks the contract")
}

// ---------------------------------------------------------------- detector

/// 200×100 photo letterboxed into 64×64: scale 0.32, photo rows 16..48 of the input, bars
/// of pad (0) above and below. Tensor mean = ½ · mean of the photo's normalised channels.
#[test]
fn detector_thresholds_suppresses_and_maps_letterboxed_boxes() {
    require_ort!();
    let det = detector(&const_detector(), det_config()).unwrap();
    assert_eq!(det.input_size(), [64, 64]);

    // White photo: mean 0.5, score of box 0 = 1.5. Box 1 (0.9) overlaps box 0 by IoU
    // 30·32/(34·32) = 0.88 > 0.4: suppressed. Box 2 (0.3) is under the threshold 0.5.
    // Box 3 (0.7) lies in the top bar (input y 0..16 → photo y −50..0): dropped.
    // Box 0: x 16/0.32 = 50 .. 48/0.32 = 150, y (16−16)/0.32 = 0 .. (48−16)/0.32 = 100,
    // edges → pixel centres: (50, 0, 149, 99). Box 4: x 4/0.32 = 12.5 .. 14/0.32 = 43.75,
    // y (20−16)/0.32 = 12.5 .. (30−16)/0.32 = 43.75 → (12.5, 12.5, 42.75, 42.75).
    let white = RgbImage::from_pixel(200, 100, Rgb([255, 255, 255]));
    let found = det.detect(&white).unwrap();
    assert_eq!(found.len(), 2, "{found:?}");
    assert_box(&found[0], [50.0, 0.0, 149.0, 99.0], 1.5);
    assert_box(&found[1], [12.5, 12.5, 42.75, 42.75], 0.6);
    assert_eq!(found[0].source, "onnx:test-detector");

    // Photo (204, 102, 51): channel means 0.8, 0.4, 0.2 over half the tensor → mean 0.2333,
    // box 0 scores 0.7 < box 1's 0.9: now box 1 wins and suppresses box 0.
    // Box 1: x 18/0.32 = 56.25 .. 50/0.32 = 156.25 → (56.25, 0, 155.25, 99).
    let tinted = RgbImage::from_pixel(200, 100, Rgb([204, 102, 51]));
    let found = det.detect(&tinted).unwrap();
    assert_eq!(found.len(), 2, "{found:?}");
    assert_box(&found[0], [56.25, 0.0, 155.25, 99.0], 0.9);
    assert_box(&found[1], [12.5, 12.5, 42.75, 42.75], 0.6);

    // Threshold and NMS from the config: IoU limit 0.95 keeps both overlapping boxes,
    // threshold 0.65 drops box 4, max_detections 1 keeps the best only.
    let loose =
        detector(&const_detector(), OnnxDetectorConfig { nms_iou: 0.95, score_threshold: 0.65, ..det_config() })
            .unwrap();
    let found = loose.detect(&tinted).unwrap();
    let scores: Vec<f32> = found.iter().map(|d| d.score).collect();
    assert_eq!(found.len(), 2, "{found:?}");
    assert!((scores[0] - 0.9).abs() < 1e-5 && (scores[1] - 0.7).abs() < 1e-5, "{scores:?}");
    let one = detector(&const_detector(), OnnxDetectorConfig { max_detections: 1, ..det_config() }).unwrap();
    assert_eq!(one.detect(&white).unwrap().len(), 1);

    // Black photo: box 0 scores 0, below the threshold; box 1 is kept.
    let black = RgbImage::new(200, 100);
    let found = det.detect(&black).unwrap();
    assert_box(&found[0], [56.25, 0.0, 155.25, 99.0], 0.9);
}

/// Dynamic input size, stretch resize, `[1, N, 4]` boxes normalised to the input, `[1, N]` scores.
#[test]
fn detector_with_dynamic_input_stretch_and_normalised_boxes() {
    require_ort!();
    let mut g = mean_score_detector(
        &[[0.25, 0.5, 0.75, 1.0]],
        &[0.0],
        &[0.8],
        &[Fixed(1), Named("N"), Fixed(4)],
        &[Fixed(1), Named("N")],
    );
    g.inputs = vec![value("image", FLOAT, &[Named("batch"), Fixed(3), Named("h"), Named("w")])];
    g.initializers[0] = init_f32("box_const", &[1, 1, 4], &[0.25, 0.5, 0.75, 1.0]);
    g.initializers[2] = init_f32("b", &[1, 1], &[0.8]);
    // Without input_size the dynamic model cannot be fed.
    contract_error(load_err(detector(&g, det_config())), "input_size");

    let config = OnnxDetectorConfig {
        input_size: Some([80, 40]),
        resize: ResizeMode::Stretch,
        box_units: BoxUnits::Normalized,
        ..det_config()
    };
    let det = detector(&g, config).unwrap();
    // 200×100 → 80×40: 0.4 per axis. Box (0.25, 0.5, 0.75, 1.0)·(80, 40) = (20, 20, 60, 40)
    // → photo edges (50, 50, 150, 100) → pixel centres (50, 50, 149, 99).
    let found = det.detect(&RgbImage::new(200, 100)).unwrap();
    assert_eq!(found.len(), 1);
    assert_box(&found[0], [50.0, 50.0, 149.0, 99.0], 0.8);
}

/// The photo's content reaches the model where the transform says: a bright spot at photo
/// pixel (120, 40) of a 300×150 photo comes back as a box around it.
#[test]
fn detector_finds_a_bright_spot_through_the_letterbox() {
    require_ort!();
    let det = detector(&dot_detector(), det_config()).unwrap();
    let mut photo = RgbImage::new(300, 150);
    for y in 39..=41 {
        for x in 119..=121 {
            photo.put_pixel(x, y, Rgb([255, 255, 255]));
        }
    }
    // Letterbox: s = 64/300, resized 64×32, pad_y = 16. Input pixel centre u ↦ photo
    // (u + 0.5)/s − 0.5: u = 25 ↦ 119.03 (nearest to 120; u = 26 ↦ 123.7), row v = 24 ↦
    // (24.5 − 16)/s − 0.5 = 39.34. The model's box [21, 20, 30, 29] (edges) maps to
    // x 21/s = 98.4375 .. 30/s = 140.625, y (20 − 16)/s = 18.75 .. (29 − 16)/s = 60.9375.
    let s = 64.0f32 / 300.0;
    let found = det.detect(&photo).unwrap();
    assert_eq!(found.len(), 1);
    assert_box(&found[0], [21.0 / s, 4.0 / s, 30.0 / s - 1.0, 13.0 / s - 1.0], 0.95);
    let [cx, cy] = found[0].face_box.center();
    assert!((cx - 120.0).abs() <= 0.5 / s && (cy - 40.0).abs() <= 0.5 / s, "centre ({cx}, {cy})");
}

#[test]
fn detector_refuses_models_that_break_the_contract() {
    require_ort!();
    let boxes_dims = [Named("N"), Fixed(4)];
    // Wrong input rank.
    let mut g = const_detector();
    g.inputs = vec![value("image", FLOAT, &[Fixed(1), Fixed(3), Fixed(64)])];
    g.nodes[0] = node("ReduceMean", &["image"], &["m"]).attr("keepdims", Attr::Int(0));
    contract_error(load_err(detector(&g, det_config())), "[1, 3, H, W]");
    // Wrong input element type.
    let mut g = const_detector();
    g.inputs = vec![value("image", DOUBLE, &[Fixed(1), Fixed(3), Fixed(64), Fixed(64)])];
    g.nodes[0] = node("Cast", &["image"], &["imf"]).attr("to", Attr::Int(FLOAT as i64));
    g.nodes.insert(1, node("ReduceMean", &["imf"], &["m"]).attr("keepdims", Attr::Int(0)));
    contract_error(load_err(detector(&g, det_config())), "float32");
    // Three channels only.
    let mut g = const_detector();
    g.inputs = vec![value("image", FLOAT, &[Fixed(1), Fixed(1), Fixed(64), Fixed(64)])];
    contract_error(load_err(detector(&g, det_config())), "[1, 3, H, W]");
    // Declared boxes of 5 columns.
    let g = mean_score_detector(&[[0.0, 0.0, 8.0, 8.0, 1.0]], &[0.0], &[0.9], &[Named("N"), Fixed(5)], &[Named("N")]);
    contract_error(load_err(detector(&g, det_config())), "[N, 4] or [1, N, 4]");
    // Scores of rank 3, [1, 1, 5]. (ONNX Runtime reports the shapes it infers, so the
    // graphs of these cases really compute the wrong shapes.)
    let mut g = mean_score_detector(&CONST_BOXES, &SCORE_W, &SCORE_B, &boxes_dims, &[Fixed(1), Fixed(1), Named("N")]);
    g.initializers[1] = init_f32("w", &[1, 1, 5], &SCORE_W);
    g.initializers[2] = init_f32("b", &[1, 1, 5], &SCORE_B);
    contract_error(load_err(detector(&g, det_config())), "scores");
    // An output name the model does not have: the error lists the ones it has.
    let config = OnnxDetectorConfig { scores_output: "confidence".into(), ..det_config() };
    contract_error(load_err(detector(&const_detector(), config)), "`boxes`, `scores`");
    // A fixed input size the config contradicts.
    let config = OnnxDetectorConfig { input_size: Some([64, 48]), ..det_config() };
    contract_error(load_err(detector(&const_detector(), config)), "disagrees");
    // Two inputs.
    let mut g = const_detector();
    g.inputs.push(value("extra", FLOAT, &[Fixed(1)]));
    contract_error(load_err(detector(&g, det_config())), "2 inputs");
}

#[test]
fn detector_reports_bad_outputs_at_run_time() {
    require_ort!();
    let photo = RgbImage::from_pixel(64, 64, Rgb([128, 128, 128]));
    let run_error = |g: Graph, needle: &str| {
        let det = detector(&g, det_config()).expect("declared shapes are dynamic: loads");
        let e = det.detect(&photo).expect_err("bad output accepted");
        assert!(e.to_string().contains(needle), "error `{e}` does not mention `{needle}`");
        assert!(e.model.contains("test-detector"), "{e}");
    };
    // Boxes whose shape follows the input size (ONNX Runtime reports shapes it can infer
    // as declared, so this one is only known at run time): [1, H, W] = [1, 2, 3].
    let mut g = const_detector();
    g.inputs = vec![value("image", FLOAT, &[Fixed(1), Fixed(3), Named("h"), Named("w")])];
    g.nodes[3] =
        node("ReduceMean", &["image"], &["boxes"]).attr("axes", Attr::Ints(vec![1])).attr("keepdims", Attr::Int(0));
    g.outputs[0] = value_unknown_shape("boxes", FLOAT);
    let det = detector(&g, OnnxDetectorConfig { input_size: Some([3, 2]), ..det_config() }).unwrap();
    let e = det.detect(&photo).unwrap_err();
    assert!(e.to_string().contains("boxes output has shape [1, 2, 3]"), "{e}");
    // 5 boxes, 4 scores.
    let g = mean_score_detector(&CONST_BOXES, &[0.0; 4], &[0.9; 4], &[Named("N"), Fixed(4)], &[Named("M")]);
    run_error(g, "5 boxes but 4 scores");
    // NaN scores.
    let g = mean_score_detector(&CONST_BOXES, &[f32::NAN; 5], &SCORE_B, &[Named("N"), Fixed(4)], &[Named("N")]);
    run_error(g, "non-finite");
    // Infinite box coordinates.
    let mut boxes = CONST_BOXES;
    boxes[3][2] = f32::INFINITY;
    let g = mean_score_detector(&boxes, &SCORE_W, &SCORE_B, &[Named("N"), Fixed(4)], &[Named("N")]);
    run_error(g, "non-finite");
}

#[test]
fn garbage_and_missing_model_files_are_clear_errors() {
    require_ort!();
    let garbage = ort_env::temp_path("garbage.onnx");
    let bytes: Vec<u8> = (0u32..4096).map(|i| (i.wrapping_mul(2654435761) >> 13) as u8).collect();
    std::fs::write(&garbage, &bytes).unwrap();
    let e = OnnxDetector::new(OnnxDetectorConfig::new(&garbage)).unwrap_err();
    assert!(matches!(e, OnnxError::ModelLoad { .. }), "{e}");
    assert!(e.to_string().contains("cannot load the model"), "{e}");
    let e = OnnxLandmarker::new(OnnxLandmarkerConfig::new(&garbage)).unwrap_err();
    assert!(matches!(e, OnnxError::ModelLoad { .. }), "{e}");
    std::fs::remove_file(&garbage).ok();
    // Truncated real model.
    let model = const_detector().to_model(OPSET, "facerecon-tests").unwrap();
    let e = OnnxDetector::from_bytes(det_config(), &model[..model.len() / 2], "half").unwrap_err();
    assert!(matches!(e, OnnxError::ModelLoad { .. }), "{e}");

    let missing = ort_env::temp_path("no-such-model.onnx");
    let e = OnnxDetector::new(OnnxDetectorConfig::new(&missing)).unwrap_err();
    assert!(matches!(e, OnnxError::ModelRead { .. }), "{e}");
    let e = OnnxDetector::new(OnnxDetectorConfig::default()).unwrap_err();
    assert!(matches!(e, OnnxError::Config(_)), "{e}");
}

/// A config file loads and a model file beside it runs.
#[test]
fn detector_from_a_config_file() {
    require_ort!();
    let dir = ort_env::temp_path("config-dir");
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(dir.join("det.onnx"), const_detector().to_model(OPSET, "facerecon-tests").unwrap()).unwrap();
    let file = dir.join("detector.json");
    std::fs::write(
        &file,
        r#"{ "model": "det.onnx", "score_threshold": 0.65, "pixels": { "order": "bgr", "std": [255, 255, 255] } }"#,
    )
    .unwrap();
    let config = OnnxDetectorConfig::from_json_file(&file).unwrap();
    assert_eq!(config.model, dir.join("det.onnx"));
    assert_eq!(config.score_threshold, 0.65);
    assert_eq!(config.nms_iou, 0.4); // default
    let det = OnnxDetector::new(config).unwrap();
    let found = det.detect(&RgbImage::from_pixel(200, 100, Rgb([255, 255, 255]))).unwrap();
    assert_eq!(found.len(), 1); // box 4 (0.6) under 0.65
    std::fs::write(&file, r#"{ "model": "det.onnx", "scores_threshold": 0.65 }"#).unwrap();
    let e = OnnxDetectorConfig::from_json_file(&file).unwrap_err();
    assert!(e.to_string().contains("unknown field"), "{e}");
    std::fs::remove_dir_all(&dir).ok();
}

// ---------------------------------------------------------------- landmarker

/// A 1-pixel bright spot at photo (80, 120); face box over pixels 60..=99 × 100..=139
/// (extents 40, centre (79.5, 119.5)); crop_scale 1.6 → side 64, left 47.5, top 87.5;
/// 32² input → 2 photo px per input px, input pixel u centred at 48.5 + 2u. The spot is
/// nearest u = 16 (80.5; weight 0.75 vs 0.25 for u = 15), likewise row 16 (120.5), so
/// point k is at crop fraction (16.5/32 + 0.001k, 16.5/32 − 0.002k) → photo
/// (47.5 + 64·(16.5/32 + 0.001k), 87.5 + 64·(16.5/32 − 0.002k)) = (80.5 + 0.064k, 120.5 − 0.128k).
fn spot_case() -> (RgbImage, Detection) {
    let mut photo = RgbImage::new(200, 200);
    photo.put_pixel(80, 120, Rgb([255, 255, 255]));
    let face = Detection {
        face_box: FaceBox { x0: 60.0, y0: 100.0, x1: 99.0, y1: 139.0 },
        score: 1.0,
        source: "given".into(),
    };
    (photo, face)
}

fn assert_spot_points(points: &[[f32; 2]]) {
    assert_eq!(points.len(), 68);
    for (k, p) in points.iter().enumerate() {
        let want = [80.5 + 0.064 * k as f32, 120.5 - 0.128 * k as f32];
        assert!((p[0] - want[0]).abs() < 1e-3 && (p[1] - want[1]).abs() < 1e-3, "point {k}: {p:?}, expected {want:?}");
    }
}

#[test]
fn landmarker_maps_crop_points_back_to_photo_pixels() {
    require_ort!();
    let (photo, face) = spot_case();
    let lm =
        landmarker(&dot_landmarker(32, false, 0.75), OnnxLandmarkerConfig { crop_scale: 1.6, ..lm_config() }).unwrap();
    assert_eq!(lm.input_size(), 32);
    let out = lm.predict(&photo, &face).unwrap();
    assert_spot_points(&out.points);
    assert_eq!(out.confidence, vec![0.75; 68]);

    // The same model giving input pixels (centres at integers) instead of fractions.
    let config = OnnxLandmarkerConfig { crop_scale: 1.6, point_units: PointUnits::Pixels, ..lm_config() };
    let lm = landmarker(&dot_landmarker(32, true, 0.75), config).unwrap();
    assert_spot_points(&lm.predict(&photo, &face).unwrap().points);

    // Without a confidence output every confidence is 1.
    let config = OnnxLandmarkerConfig { crop_scale: 1.6, confidence_output: None, ..lm_config() };
    let lm = landmarker(&dot_landmarker(32, false, 0.75), config).unwrap();
    assert_eq!(lm.predict(&photo, &face).unwrap().confidence, vec![1.0; 68]);
}

/// A crop reaching past the photo's corner: the part outside is padding, the spot is
/// still found and mapped back.
#[test]
fn landmarker_crop_past_the_border() {
    require_ort!();
    let mut photo = RgbImage::new(40, 30);
    photo.put_pixel(2, 3, Rgb([255, 255, 255]));
    // Box over pixels 0..=9 × 0..=9, centre (4.5, 4.5), crop_scale 3.2 → side 32,
    // left = top = −11.5; 32² input → 1 px per px, input pixel u centred at u − 11:
    // the spot (2, 3) is input pixel (13, 14) → fraction (13.5/32, 14.5/32) → photo (2, 3).
    let face =
        Detection { face_box: FaceBox { x0: 0.0, y0: 0.0, x1: 9.0, y1: 9.0 }, score: 1.0, source: "given".into() };
    let lm =
        landmarker(&dot_landmarker(32, false, 1.0), OnnxLandmarkerConfig { crop_scale: 3.2, ..lm_config() }).unwrap();
    let out = lm.predict(&photo, &face).unwrap();
    assert!((out.points[0][0] - 2.0).abs() < 1e-4 && (out.points[0][1] - 3.0).abs() < 1e-4, "{:?}", out.points[0]);
}

#[test]
fn landmarker_refuses_bad_models_and_outputs() {
    require_ort!();
    // Non-square input.
    let mut g = dot_landmarker(32, false, 1.0);
    g.inputs = vec![value("image", FLOAT, &[Fixed(1), Fixed(3), Fixed(32), Fixed(16)])];
    contract_error(load_err(landmarker(&g, lm_config())), "square");
    // 67 points declared.
    let mut g = dot_landmarker(32, false, 1.0);
    g.outputs[0] = value("landmarks", FLOAT, &[Fixed(1), Fixed(67), Fixed(2)]);
    g.initializers.retain(|t| t.name != "reps" && t.name != "offsets");
    g.initializers.push(init_i64("reps", &[3], &[1, 67, 1]));
    g.initializers.push(init_f32("offsets", &[1, 67, 2], &point_offsets()[..134]));
    contract_error(load_err(landmarker(&g, lm_config())), "[1, 68, 2]");
    // Integer input.
    let mut g = dot_landmarker(32, false, 1.0);
    g.inputs = vec![value("image", UINT8, &[Fixed(1), Fixed(3), Fixed(32), Fixed(32)])];
    g.nodes.insert(0, node("Cast", &["image"], &["imf"]).attr("to", Attr::Int(FLOAT as i64)));
    g.nodes[1].inputs[0] = "imf".into();
    contract_error(load_err(landmarker(&g, lm_config())), "float32");
    // Missing confidence output.
    let config = OnnxLandmarkerConfig { confidence_output: Some("conf".into()), ..lm_config() };
    contract_error(load_err(landmarker(&dot_landmarker(32, false, 1.0), config)), "no output named `conf`");
    // Dynamic side without input_size, then with it.
    let mut g = dot_landmarker(32, false, 1.0);
    g.inputs = vec![value("image", FLOAT, &[Fixed(1), Fixed(3), Named("s"), Named("s")])];
    contract_error(load_err(landmarker(&g, lm_config())), "input_size");
    assert!(landmarker(&g, OnnxLandmarkerConfig { input_size: Some(32), ..lm_config() }).is_ok());

    let (photo, face) = spot_case();
    // Confidences above 1.
    let lm = landmarker(&dot_landmarker(32, false, 1.5), lm_config()).unwrap();
    let e = lm.predict(&photo, &face).unwrap_err();
    assert!(e.to_string().contains("outside [0, 1]"), "{e}");
    // NaN points.
    let mut g = dot_landmarker(32, false, 1.0);
    let nan_offsets: Vec<f32> =
        point_offsets().iter().enumerate().map(|(i, &v)| if i == 7 { f32::NAN } else { v }).collect();
    g.initializers.retain(|t| t.name != "offsets");
    g.initializers.push(init_f32("offsets", &[1, 68, 2], &nan_offsets));
    let lm = landmarker(&g, lm_config()).unwrap();
    let e = lm.predict(&photo, &face).unwrap_err();
    assert!(e.to_string().contains("non-finite"), "{e}");
    // An invalid face box is an error, not a crash.
    let lm = landmarker(&dot_landmarker(32, false, 1.0), lm_config()).unwrap();
    let bad = Detection { face_box: FaceBox { x0: 10.0, y0: 0.0, x1: f32::INFINITY, y1: 5.0 }, ..face };
    assert!(lm.predict(&photo, &bad).is_err());
}
