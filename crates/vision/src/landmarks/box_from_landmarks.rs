//! The box a landmark model's training detector would have drawn around a face, computed
//! from 68 landmarks of that face: what the front end's second landmark pass feeds back
//! to the predictor (DESIGN §3).
//!
//! dlib's 68-point model is about twice as accurate on the boxes of dlib's HOG detector as
//! on any other box; [`super::BoxCalibration`] maps detector boxes towards that convention,
//! but a box alone says little about where the face is inside it. The first pass's points
//! do: from the centre `(mx, my)` and extent `w × h` of [`REFERENCE_POINTS`], a linear map
//! gives the square box
//!
//! ```text
//! cx = mx + cx_w·w + cx_h·h + cx_1      cy = my + cy_w·w + cy_h·h + cy_1
//! side = s_w·w + s_h·h + s_1
//! ```
//!
//! fitted by least squares on pairs (dlib's points on dlib's HOG box, that box), so that a
//! face whose first pass already sits in its HOG box maps back onto that box (the map is
//! close to a fixed point of predictor ∘ map). Coefficients for dlib's model:
//! [`BoxFromLandmarks::dlib_68`]; fit: `examples/fit_box_from_landmarks.rs`.

use std::ops::Range;

use glam::{DMat3, DVec3};

use crate::face::FaceBox;

/// The iBUG points (0-based) whose centre and extent the map reads: contour, brows, nose
/// and eyes. The mouth (48–67) is left out: it opens and smiles without the face's box
/// changing.
pub const REFERENCE_POINTS: Range<usize> = 0..48;

/// Linear map from landmark statistics to a square face box (see the module doc).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct BoxFromLandmarks {
    /// Box centre x − points' mean x, as `[per w, per h, constant]`.
    pub cx: [f32; 3],
    /// Box centre y − points' mean y, as `[per w, per h, constant]`.
    pub cy: [f32; 3],
    /// Box side, as `[per w, per h, constant]`.
    pub side: [f32; 3],
}

/// Centre (mean) and extent (tight box width, height) of the reference points; `None` when
/// there are too few points or any is not finite.
pub fn reference_statistics(points: &[[f32; 2]]) -> Option<([f64; 2], [f64; 2])> {
    let pts = points.get(REFERENCE_POINTS)?;
    if !pts.iter().all(|p| p[0].is_finite() && p[1].is_finite()) {
        return None;
    }
    let n = pts.len() as f64;
    let mean = [pts.iter().map(|p| p[0] as f64).sum::<f64>() / n, pts.iter().map(|p| p[1] as f64).sum::<f64>() / n];
    let (mut lo, mut hi) = ([f64::MAX; 2], [f64::MIN; 2]);
    for p in pts {
        for k in 0..2 {
            lo[k] = lo[k].min(p[k] as f64);
            hi[k] = hi[k].max(p[k] as f64);
        }
    }
    Some((mean, [hi[0] - lo[0], hi[1] - lo[1]]))
}

impl BoxFromLandmarks {
    /// dlib's HOG-box convention for dlib's 68-point model.
    pub fn dlib_68() -> Self {
        default_coefficients::dlib_68()
    }

    /// The box for a face with these landmarks (iBUG order, at least
    /// `REFERENCE_POINTS.end` of them); `None` when the points are not usable (too few,
    /// not finite, or all in one place).
    pub fn apply(&self, points: &[[f32; 2]]) -> Option<FaceBox> {
        let ([mx, my], [w, h]) = reference_statistics(points)?;
        let lin = |c: &[f32; 3]| c[0] as f64 * w + c[1] as f64 * h + c[2] as f64;
        let (cx, cy, side) = (mx + lin(&self.cx), my + lin(&self.cy), lin(&self.side));
        if !(w > 0.0 && h > 0.0 && side > 0.0) {
            return None;
        }
        let r = 0.5 * side;
        Some(FaceBox { x0: (cx - r) as f32, y0: (cy - r) as f32, x1: (cx + r) as f32, y1: (cy + r) as f32 })
    }

    /// Least-squares fit on pairs (landmarks, box); the box's side is taken as the mean of
    /// its width and height. `None` with fewer than 3 usable pairs or degenerate statistics.
    pub fn fit(pairs: &[(&[[f32; 2]], FaceBox)]) -> Option<Self> {
        // Rows: features [w, h, 1] → targets [cx − mx, cy − my, side].
        let rows: Vec<([f64; 3], [f64; 3])> = pairs
            .iter()
            .filter_map(|(pts, b)| {
                let ([mx, my], [w, h]) = reference_statistics(pts)?;
                let [cx, cy] = b.center();
                let side = 0.5 * (b.width() + b.height()) as f64;
                Some(([w, h, 1.0], [cx as f64 - mx, cy as f64 - my, side]))
            })
            .collect();
        if rows.len() < 3 {
            return None;
        }
        let mut ata = [[0.0f64; 3]; 3];
        let mut atb = [[0.0f64; 3]; 3]; // [target][feature]
        for (f, t) in &rows {
            for i in 0..3 {
                for j in 0..3 {
                    ata[i][j] += f[i] * f[j];
                    atb[i][j] += t[i] * f[j];
                }
            }
        }
        let solve = |b: [f64; 3]| -> Option<[f32; 3]> {
            let x = solve3(ata, b)?;
            Some([x[0] as f32, x[1] as f32, x[2] as f32])
        };
        Some(BoxFromLandmarks { cx: solve(atb[0])?, cy: solve(atb[1])?, side: solve(atb[2])? })
    }
}

/// Solves the symmetric 3×3 system `a·x = b` (`None` when near-singular).
fn solve3(a: [[f64; 3]; 3], b: [f64; 3]) -> Option<[f64; 3]> {
    let m = DMat3::from_cols_array_2d(&a);
    let d = m.determinant();
    let scale = a.iter().flatten().fold(0.0f64, |s, v| s.max(v.abs()));
    if !d.is_finite() || d.abs() <= 1e-12 * scale.powi(3) {
        return None;
    }
    Some((m.inverse() * DVec3::from(b)).to_array())
}

/// Fitted coefficients, kept in code.
mod default_coefficients {
    use super::*;

    /// Fitted on faces-300w's `helen/trainset` and `lfpw/trainset` folders only (the folders
    /// the data's terms allow front-end calibrations on), 2026-11-23, printed by
    /// `cargo run --release -p facerecon-vision --example fit_box_from_landmarks`: dlib's
    /// own points on dlib's HOG box → that box, from `dlib_reference.csv`; 355 pairs (the
    /// square boxes). On the other folders it recovers dlib's box with mean IoU 0.84 (centre
    /// 5.1 % of the side off, side 6 % off): dlib's boxes come in scale steps of 1.2 and
    /// positions on an 8-cell grid, which no smooth map reproduces.
    pub fn dlib_68() -> BoxFromLandmarks {
        BoxFromLandmarks {
            cx: [-0.051881, 0.045199, 0.0671],
            cy: [0.131220, -0.110150, 3.0547],
            side: [0.656271, 0.339820, 11.8855],
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// 68 points: the 48 reference points on the corners of the rectangle
    /// `[x0, x1] × [y0, y1]` (12 on each corner, so their mean is the rectangle's centre),
    /// the 20 mouth points far away (they must not count).
    fn rectangle_points(x0: f32, y0: f32, x1: f32, y1: f32) -> Vec<[f32; 2]> {
        let corners = [[x0, y0], [x1, y0], [x1, y1], [x0, y1]];
        (0..68).map(|i| if i < 48 { corners[i % 4] } else { [1e4, -1e4] }).collect()
    }

    #[test]
    fn hand_made_points_give_the_hand_computed_box() {
        // Reference points: centre (100, 200), extent 80 × 60.
        let pts = rectangle_points(60.0, 170.0, 140.0, 230.0);
        let m = BoxFromLandmarks { cx: [0.1, 0.0, 2.0], cy: [0.0, 0.2, -3.0], side: [1.0, 0.5, 10.0] };
        // cx = 100 + 0.1·80 + 2 = 110, cy = 200 + 0.2·60 − 3 = 209, side = 80 + 30 + 10 = 120
        let b = m.apply(&pts).unwrap();
        let want = FaceBox { x0: 50.0, y0: 149.0, x1: 170.0, y1: 269.0 };
        for (g, w) in [(b.x0, want.x0), (b.y0, want.y0), (b.x1, want.x1), (b.y1, want.y1)] {
            assert!((g - w).abs() < 1e-4, "{b:?}");
        }
        // The mean, not the box centre: 47 points at (0, 0) and one at (48, 96) → (1, 2).
        let mut pts = vec![[0.0f32, 0.0]; 48];
        pts[7] = [48.0, 96.0];
        assert_eq!(reference_statistics(&pts), Some(([1.0, 2.0], [48.0, 96.0])));
    }

    #[test]
    fn unusable_points_give_no_box() {
        let m = BoxFromLandmarks::dlib_68();
        assert_eq!(m.apply(&rectangle_points(0.0, 0.0, 10.0, 10.0)[..47]), None);
        let mut pts = rectangle_points(0.0, 0.0, 10.0, 10.0);
        pts[5][1] = f32::NAN;
        assert_eq!(m.apply(&pts), None);
        assert_eq!(m.apply(&vec![[3.0, 4.0]; 68]), None); // all in one place
        // Mouth points may be anything.
        let mut pts = rectangle_points(0.0, 0.0, 100.0, 100.0);
        pts[60] = [f32::NAN, f32::INFINITY];
        assert!(m.apply(&pts).is_some());
    }

    #[test]
    fn fit_recovers_a_known_map() {
        let truth = BoxFromLandmarks { cx: [-0.05, 0.04, 0.5], cy: [0.13, -0.11, 3.0], side: [0.66, 0.34, 12.0] };
        let samples: Vec<(Vec<[f32; 2]>, FaceBox)> = (0..30)
            .map(|i| {
                let (x, y) = (20.0 + 13.0 * i as f32, 40.0 + 7.0 * (i % 5) as f32);
                let (w, h) = (50.0 + 9.0 * (i % 7) as f32, 60.0 + 11.0 * (i % 4) as f32);
                let pts = rectangle_points(x, y, x + w, y + h);
                let b = truth.apply(&pts).unwrap();
                (pts, b)
            })
            .collect();
        let pairs: Vec<(&[[f32; 2]], FaceBox)> = samples.iter().map(|(p, b)| (p.as_slice(), *b)).collect();
        let fit = BoxFromLandmarks::fit(&pairs).unwrap();
        for (g, w) in
            fit.cx.iter().chain(&fit.cy).chain(&fit.side).zip(truth.cx.iter().chain(&truth.cy).chain(&truth.side))
        {
            assert!((g - w).abs() < 1e-3 * w.abs().max(1.0), "{fit:?}");
        }
        // w and h always in the same ratio: the fit cannot separate them.
        let same_shape: Vec<(Vec<[f32; 2]>, FaceBox)> = (0..10)
            .map(|i| (rectangle_points(0.0, 0.0, 10.0 * (i + 1) as f32, 20.0 * (i + 1) as f32), samples[0].1))
            .collect();
        let pairs: Vec<(&[[f32; 2]], FaceBox)> = same_shape.iter().map(|(p, b)| (p.as_slice(), *b)).collect();
        assert_eq!(BoxFromLandmarks::fit(&pairs), None);
        assert_eq!(BoxFromLandmarks::fit(&[]), None);
    }

    #[test]
    fn dlib_map_is_square_upright_and_scales_with_the_face() {
        // A frontal-looking face: reference points 100 wide, 90 tall.
        let m = BoxFromLandmarks::dlib_68();
        let b = m.apply(&rectangle_points(100.0, 100.0, 200.0, 190.0)).unwrap();
        assert!((b.width() - b.height()).abs() < 1e-3);
        // dlib's boxes are a bit narrower than the contour and sit lower than the brows' top.
        assert!(b.width() > 80.0 && b.width() < 110.0, "{b:?}");
        let b2 = m.apply(&rectangle_points(200.0, 200.0, 400.0, 380.0)).unwrap();
        assert!((b2.width() - 2.0 * b.width()).abs() < 0.2 * b.width(), "{b:?} {b2:?}");
    }
}
