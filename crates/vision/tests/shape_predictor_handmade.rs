//! A hand-built dlib model (3 points, 1 cascade level, 1 tree of depth 1) written byte by
//! byte in dlib's serialisation by an encoder independent of the parser, with outputs
//! computed by hand; and malformed files that must be refused with errors, not panics.

use facerecon_vision::face::FaceBox;
use facerecon_vision::landmarks::{ShapePredictor, ShapePredictorError};
use image::{Rgb, RgbImage};

/// dlib's integer encoding: control byte (size | 0x80 if negative), magnitude bytes LE.
fn int(out: &mut Vec<u8>, v: i64) {
    let mut mag = v.unsigned_abs();
    let mut bytes = vec![];
    loop {
        bytes.push((mag & 0xff) as u8);
        mag >>= 8;
        if mag == 0 {
            break;
        }
    }
    out.push(bytes.len() as u8 | if v < 0 { 0x80 } else { 0 });
    out.extend(bytes);
}

/// dlib's float: mantissa and exponent (value = m·2^e), from the IEEE bits.
fn float(out: &mut Vec<u8>, v: f32) {
    let bits = v.to_bits();
    let (exp, frac) = (((bits >> 23) & 0xff) as i64, (bits & 0x7f_ffff) as i64);
    let (m, e) = if exp == 0 { (frac, -149) } else { (frac | 0x80_0000, exp - 150) };
    int(out, if v < 0.0 { -m } else { m });
    int(out, e);
}

fn column(out: &mut Vec<u8>, v: &[f32]) {
    int(out, -(v.len() as i64));
    int(out, -1);
    for &x in v {
        float(out, x);
    }
}

struct Model {
    version: i64,
    initial: Vec<f32>,
    /// one level, one tree: (idx1, idx2, thresh) and two leaves
    split: (i64, i64, f32),
    leaves: Vec<Vec<f32>>,
    anchors: Vec<i64>,
    deltas: Vec<[f32; 2]>,
}

fn base() -> Model {
    Model {
        version: 1,
        // p0 = (0.2, 0.3), p1 = (0.8, 0.3), p2 = (0.5, 0.8) in box coordinates
        initial: vec![0.2, 0.3, 0.8, 0.3, 0.5, 0.8],
        // left when I(f0) − I(f1) > 10
        split: (0, 1, 10.0),
        // left leaf: every x + 0.1; right leaf: every y + 0.05
        leaves: vec![vec![0.1, 0.0, 0.1, 0.0, 0.1, 0.0], vec![0.0, 0.05, 0.0, 0.05, 0.0, 0.05]],
        // feature 0 at p0 + (0.013, 0), feature 1 at p1
        anchors: vec![0, 1],
        deltas: vec![[0.013, 0.0], [0.0, 0.0]],
    }
}

fn encode(m: &Model) -> Vec<u8> {
    let mut o = vec![];
    int(&mut o, m.version);
    column(&mut o, &m.initial);
    int(&mut o, 1); // levels
    int(&mut o, 1); // trees
    int(&mut o, 1); // splits
    int(&mut o, m.split.0);
    int(&mut o, m.split.1);
    float(&mut o, m.split.2);
    int(&mut o, m.leaves.len() as i64);
    for l in &m.leaves {
        column(&mut o, l);
    }
    int(&mut o, 1);
    int(&mut o, m.anchors.len() as i64);
    for &a in &m.anchors {
        int(&mut o, a);
    }
    int(&mut o, 1);
    int(&mut o, m.deltas.len() as i64);
    for d in &m.deltas {
        float(&mut o, d[0]);
        float(&mut o, d[1]);
    }
    o
}

fn image_with(pixels: &[(u32, u32, [u8; 3])]) -> RgbImage {
    let mut img = RgbImage::new(200, 200);
    for &(x, y, c) in pixels {
        img.put_pixel(x, y, Rgb(c));
    }
    img
}

fn close(a: &[[f32; 2]], b: &[[f32; 2]]) -> bool {
    a.len() == b.len() && a.iter().zip(b).all(|(p, q)| (p[0] - q[0]).abs() < 1e-4 && (p[1] - q[1]).abs() < 1e-4)
}

#[test]
fn handmade_model_gives_hand_computed_points() {
    let sp = ShapePredictor::from_bytes(&encode(&base())).unwrap();
    assert_eq!(sp.num_parts(), 3);
    assert_eq!(sp.size(), (1, 1));
    // Box (10, 20)–(110, 120): box coordinates scale by 100. At the first level the
    // current shape is the mean shape, so feature 0 sits at p0 + (0.013, 0) → (31.3, 50)
    // → pixel (31, 50), feature 1 at p1 → (90, 50).
    let b = FaceBox { x0: 10.0, y0: 20.0, x1: 110.0, y1: 120.0 };

    // I(31,50) = ⌊(100+100+101)/3⌋ = 100, I(90,50) = 50: 100 − 50 > 10 → left leaf, x + 10 px.
    let img = image_with(&[(31, 50, [100, 100, 101]), (90, 50, [50, 50, 50])]);
    assert!(close(&sp.predict(&img, &b), &[[40.0, 50.0], [100.0, 50.0], [70.0, 100.0]]));

    // The brightness at the anchor point itself (30, 50) must not matter: the offset moved
    // the feature to pixel 31. Here I(31,50) = 55, 55 − 50 ≤ 10 → right leaf, y + 5 px.
    let img = image_with(&[(30, 50, [255, 255, 255]), (31, 50, [55, 55, 55]), (90, 50, [50, 50, 50])]);
    assert!(close(&sp.predict(&img, &b), &[[30.0, 55.0], [90.0, 55.0], [60.0, 105.0]]));

    // Box (−50, 20)–(50, 120): feature 0 at (−28.7, 50), outside the image → 0;
    // feature 1 at (30, 50) with I = 100: 0 − 100 ≤ 10 → right leaf.
    let b2 = FaceBox { x0: -50.0, y0: 20.0, x1: 50.0, y1: 120.0 };
    let img = image_with(&[(30, 50, [100, 100, 100])]);
    assert!(close(&sp.predict(&img, &b2), &[[-30.0, 55.0], [30.0, 55.0], [0.0, 105.0]]));
    // …whereas a dark feature 1 and the out-of-image 0: 0 − 0 ≤ 10 → right as well, while
    // a negative threshold sends it left.
    let mut m = base();
    m.split.2 = -1.0;
    let sp_neg = ShapePredictor::from_bytes(&encode(&m)).unwrap();
    let img = image_with(&[]);
    assert!(close(&sp_neg.predict(&img, &b2), &[[-30.0 + 10.0, 50.0], [30.0 + 10.0, 50.0], [0.0 + 10.0, 100.0]]));
}

#[test]
fn every_truncation_is_an_error_not_a_panic() {
    let bytes = encode(&base());
    for len in 0..bytes.len() {
        assert!(ShapePredictor::from_bytes(&bytes[..len]).is_err(), "prefix of {len} bytes accepted");
    }
    let mut longer = bytes.clone();
    longer.push(0);
    assert!(matches!(ShapePredictor::from_bytes(&longer), Err(ShapePredictorError::TrailingData(1))));
}

#[test]
fn malformed_models_are_refused_with_reasons() {
    let check = |m: Model, want: &str| {
        let err = ShapePredictor::from_bytes(&encode(&m)).unwrap_err().to_string();
        assert!(err.contains(want), "{err:?} does not mention {want:?}");
    };
    check(Model { version: 2, ..base() }, "version 2");
    check(Model { initial: vec![0.1, 0.2, 0.3], ..base() }, "even count");
    check(Model { split: (0, 2, 1.0), ..base() }, "feature pixel 2 of 2");
    check(Model { anchors: vec![0, 3], ..base() }, "anchor index 3");
    check(Model { deltas: vec![[0.0, 0.0]], ..base() }, "2 anchors but 1 deltas");
    check(Model { leaves: vec![vec![0.0; 6]], ..base() }, "1 splits and 1 leaves");
    check(Model { leaves: vec![vec![0.0; 6], vec![0.0; 4]], ..base() }, "a leaf holds 4 values");
    check(Model { leaves: vec![vec![0.0; 6], vec![f32::INFINITY; 6]], ..base() }, "non-finite leaf value");
    // A count far beyond the file's size is refused before allocating.
    let mut bytes = vec![];
    int(&mut bytes, 1);
    column(&mut bytes, &[0.5, 0.5]);
    int(&mut bytes, 1 << 50);
    let err = ShapePredictor::from_bytes(&bytes).unwrap_err().to_string();
    assert!(err.contains("cannot fit"), "{err}");
}
