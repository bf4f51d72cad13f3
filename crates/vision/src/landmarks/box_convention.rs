//! Mapping a detector's boxes onto the box convention of a landmark model.
//!
//! dlib's 68-point model was trained on the boxes of dlib's HOG face detector; given other
//! boxes it is about twice as wrong (faces-300w: NME 1.68 % on HOG boxes, 3.37 % on tight
//! landmark boxes). Each detector source gets a small linear model from its box (centre
//! `c`, width `w`, height `h`) to the HOG box of the same face:
//!
//! ```text
//! cx' = cx + ax·w + bx      cy' = cy + ay·h + by      w' = sw·w + tw      h' = sh·h + th
//! ```
//!
//! fitted by least squares on matched pairs (see `examples/fit_box_calibration.rs`).
//! On faces-300w it brings the pipeline's one-pass NME from 3.42 % to 2.17 % (all 700
//! photos; 3.66 % → 2.28 % on the folders not used for the fit); the front end's refinement
//! passes ([`super::box_from_landmarks`]) then take it to 1.95 % / 2.02 %:
//! `docs/bench/vision-landmarks.md`.

use std::collections::BTreeMap;

use crate::face::FaceBox;

/// Coefficients for one detector source.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct BoxMap {
    pub ax: f32,
    pub bx: f32,
    pub ay: f32,
    pub by: f32,
    pub sw: f32,
    pub tw: f32,
    pub sh: f32,
    pub th: f32,
}

impl BoxMap {
    pub const IDENTITY: BoxMap = BoxMap { ax: 0.0, bx: 0.0, ay: 0.0, by: 0.0, sw: 1.0, tw: 0.0, sh: 1.0, th: 0.0 };

    pub fn apply(&self, b: &FaceBox) -> FaceBox {
        let [cx, cy] = b.center();
        let (w, h) = (b.width(), b.height());
        let cx = cx + self.ax * w + self.bx;
        let cy = cy + self.ay * h + self.by;
        let w = (self.sw * w + self.tw).max(0.0);
        let h = (self.sh * h + self.th).max(0.0);
        FaceBox { x0: cx - 0.5 * w, y0: cy - 0.5 * h, x1: cx + 0.5 * w, y1: cy + 0.5 * h }
    }

    /// The same map for horizontally mirrored boxes (x offsets change sign).
    pub fn mirrored(&self) -> BoxMap {
        BoxMap { ax: -self.ax, bx: -self.bx, ..*self }
    }

    /// Least-squares fit from pairs (detector box, target box).
    pub fn fit(pairs: &[(FaceBox, FaceBox)]) -> Option<BoxMap> {
        if pairs.len() < 3 {
            return None;
        }
        // Each coordinate: y = a·u + b by least squares on (u, y).
        let line = |f: &dyn Fn(&FaceBox, &FaceBox) -> (f64, f64)| -> Option<(f32, f32)> {
            let n = pairs.len() as f64;
            let (mut su, mut sy, mut suu, mut suy) = (0.0, 0.0, 0.0, 0.0);
            for (d, t) in pairs {
                let (u, y) = f(d, t);
                su += u;
                sy += y;
                suu += u * u;
                suy += u * y;
            }
            let den = n * suu - su * su;
            if den.abs() < 1e-9 {
                return None;
            }
            let a = (n * suy - su * sy) / den;
            Some((a as f32, ((sy - a * su) / n) as f32))
        };
        let (ax, bx) = line(&|d, t| (d.width() as f64, (t.center()[0] - d.center()[0]) as f64))?;
        let (ay, by) = line(&|d, t| (d.height() as f64, (t.center()[1] - d.center()[1]) as f64))?;
        let (sw, tw) = line(&|d, t| (d.width() as f64, t.width() as f64))?;
        let (sh, th) = line(&|d, t| (d.height() as f64, t.height() as f64))?;
        Some(BoxMap { ax, bx, ay, by, sw, tw, sh, th })
    }
}

/// Per-detector-source box maps (keyed by [`crate::face::Detection::source`]); sources
/// without an entry use `fallback`.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct BoxCalibration {
    pub by_source: BTreeMap<String, BoxMap>,
    pub fallback: BoxMap,
}

impl BoxCalibration {
    /// No change to any box.
    pub fn identity() -> Self {
        BoxCalibration { by_source: BTreeMap::new(), fallback: BoxMap::IDENTITY }
    }

    /// The map for a source: its own; else, for `NAME-mirrored` (a cascade run mirrored,
    /// [`crate::detect`]), `NAME`'s map mirrored; else the fallback.
    pub fn map_for(&self, source: &str) -> BoxMap {
        if let Some(m) = self.by_source.get(source) {
            return *m;
        }
        match source.strip_suffix("-mirrored").and_then(|base| self.by_source.get(base)) {
            Some(m) => m.mirrored(),
            None => self.fallback,
        }
    }

    pub fn apply(&self, source: &str, b: &FaceBox) -> FaceBox {
        self.map_for(source).apply(b)
    }

    /// Viola–Jones boxes of [`crate::detect`] → dlib HOG boxes, for the dlib 68-point model.
    pub fn viola_jones_to_dlib() -> Self {
        default_coefficients::viola_jones_to_dlib()
    }
}

/// Fitted coefficients, kept in code (see each for how they were fitted).
mod default_coefficients {
    use super::*;

    /// Fitted on faces-300w's `helen/trainset` and `lfpw/trainset` folders only (the two
    /// folders the data's terms allow front-end calibrations on), 2026-11-23, printed by
    /// `cargo run --release -p facerecon-vision --example eval_300w` (the same procedure as
    /// `--example fit_box_calibration`): per photo, the Viola–Jones detection that best
    /// overlaps the annotated landmark box (IoU > 0.3) paired with dlib's HOG box for that
    /// photo from `dlib_reference.csv`; 362 pairs; least squares per detector source with
    /// ≥ 10 pairs (haar-frontal 238, lbp-frontal 97, haar-profile 20), the fit on all pairs
    /// for the rest (haar-profile-mirrored had 7; it now uses haar-profile's map mirrored,
    /// see [`BoxCalibration::map_for`]). Detector: product cascades, smallest face
    /// 10 % of the shorter side.
    pub fn viola_jones_to_dlib() -> BoxCalibration {
        let fallback = BoxMap {
            ax: -0.022252448,
            bx: 3.7253146,
            ay: 0.052395754,
            by: 0.24760456,
            sw: 0.86494243,
            tw: 33.4239,
            sh: 0.8710626,
            th: 31.817225,
        };
        let haar_frontal = BoxMap {
            ax: 0.0013332064,
            bx: -0.23612197,
            ay: 0.06295136,
            by: 2.5278344,
            sw: 0.83808666,
            tw: 12.984389,
            sh: 0.83818126,
            th: 12.975257,
        };
        let haar_profile = BoxMap {
            ax: -0.1603347,
            bx: -5.50259,
            ay: 0.041583166,
            by: 8.17743,
            sw: 0.7813841,
            tw: 21.246582,
            sh: 0.7734077,
            th: 19.009928,
        };
        let lbp_frontal = BoxMap {
            ax: -0.013871939,
            bx: 0.353067,
            ay: -0.01379415,
            by: 4.0870247,
            sw: 1.2231499,
            tw: 15.262857,
            sh: 1.2654889,
            th: 5.714596,
        };
        BoxCalibration {
            by_source: [
                ("haar-frontal".to_string(), haar_frontal),
                ("haar-profile".to_string(), haar_profile),
                ("lbp-frontal".to_string(), lbp_frontal),
            ]
            .into_iter()
            .collect(),
            fallback,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fit_recovers_a_known_map() {
        let truth = BoxMap { ax: 0.05, bx: 2.0, ay: 0.1, by: -1.0, sw: 0.8, tw: 3.0, sh: 0.85, th: 1.0 };
        let pairs: Vec<_> = (0..20)
            .map(|i| {
                let (x, y, w) = (10.0 + 7.0 * i as f32, 5.0 + 3.0 * i as f32, 40.0 + 11.0 * (i % 7) as f32);
                let d = FaceBox { x0: x, y0: y, x1: x + w, y1: y + w * 1.1 };
                (d, truth.apply(&d))
            })
            .collect();
        let fit = BoxMap::fit(&pairs).unwrap();
        for (a, b) in [
            (fit.ax, truth.ax),
            (fit.bx, truth.bx),
            (fit.ay, truth.ay),
            (fit.by, truth.by),
            (fit.sw, truth.sw),
            (fit.tw, truth.tw),
            (fit.sh, truth.sh),
            (fit.th, truth.th),
        ] {
            assert!((a - b).abs() < 1e-3, "{fit:?}");
        }
    }

    #[test]
    fn default_calibration_shrinks_frontal_boxes_towards_dlibs() {
        // dlib's HOG boxes are tighter than Viola–Jones frontal boxes and sit lower.
        let cal = BoxCalibration::viola_jones_to_dlib();
        let b = FaceBox { x0: 100.0, y0: 100.0, x1: 300.0, y1: 300.0 };
        let m = cal.apply("haar-frontal", &b);
        assert!(m.width() < b.width() && m.width() > 0.8 * b.width(), "{m:?}");
        assert!(m.center()[1] > b.center()[1]);
        assert_eq!(cal.map_for("unknown"), cal.fallback);
        // A mirrored cascade without a map of its own: its base's map, mirrored.
        let profile = cal.map_for("haar-profile");
        assert_eq!(cal.map_for("haar-profile-mirrored"), profile.mirrored());
        assert_ne!(profile.ax, 0.0);
        assert_eq!(cal.map_for("unknown-mirrored"), cal.fallback);
    }

    #[test]
    fn mirrored_map_mirrors_boxes() {
        let m = BoxMap { ax: 0.1, bx: 2.0, ..BoxMap::IDENTITY };
        let b = FaceBox { x0: 10.0, y0: 0.0, x1: 30.0, y1: 20.0 };
        // mirror about x = 0: [-30, -10]
        let mb = FaceBox { x0: -30.0, y0: 0.0, x1: -10.0, y1: 20.0 };
        let (r, rm) = (m.apply(&b), m.mirrored().apply(&mb));
        assert!((r.x0 + rm.x1).abs() < 1e-5 && (r.x1 + rm.x0).abs() < 1e-5);
        assert_eq!(BoxMap::IDENTITY.apply(&b), b);
    }
}
