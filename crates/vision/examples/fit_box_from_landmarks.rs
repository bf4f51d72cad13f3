//! Fits the landmarks → dlib HOG box map ([`BoxFromLandmarks`]) of the front end's second
//! landmark pass, on faces-300w's `helen/trainset` and `lfpw/trainset` folders only, and
//! prints the coefficients as Rust. No detector runs: the pairs are dlib's own 68 points on
//! dlib's HOG box and that box, from `dlib_reference.csv`.
//!
//!     cargo run --release -p facerecon-vision --example fit_box_from_landmarks
//!
//! Boxes that are not square within 2 px (15 of the 671 HOG boxes, clipped at the photo's
//! border) are left out of the fit. Also prints how well the map recovers dlib's box from
//! dlib's points on the folders not used for the fit, and the map in code.

#[path = "../tests/support/faces300w.rs"]
mod faces300w;

use facerecon_vision::face::FaceBox;
use facerecon_vision::landmarks::box_from_landmarks::BoxFromLandmarks;

fn main() {
    let dir = faces300w::dataset_dir();
    let rows: Vec<(String, Vec<[f32; 2]>, FaceBox)> = faces300w::read_dlib_reference(&dir)
        .into_iter()
        .filter(|r| r.box_kind == "dlib_hog")
        .filter(|r| {
            let b = r.face_box();
            (b.width() - b.height()).abs() <= 2.0
        })
        .map(|r| {
            let pts = r.points.iter().map(|p| [p[0] as f32, p[1] as f32]).collect();
            (r.path.clone(), pts, r.face_box())
        })
        .collect();
    let train: Vec<(&[[f32; 2]], FaceBox)> =
        rows.iter().filter(|r| faces300w::is_trainset(&r.0)).map(|r| (r.1.as_slice(), r.2)).collect();
    let map = BoxFromLandmarks::fit(&train).expect("enough pairs");
    println!("// {} trainset pairs (dlib's points on dlib's HOG box → that box):", train.len());
    println!(
        "BoxFromLandmarks {{ cx: [{:.6}, {:.6}, {:.4}], cy: [{:.6}, {:.6}, {:.4}], side: [{:.6}, {:.6}, {:.4}] }}",
        map.cx[0], map.cx[1], map.cx[2], map.cy[0], map.cy[1], map.cy[2], map.side[0], map.side[1], map.side[2]
    );
    for (name, m) in [("fitted now", map), ("in code", BoxFromLandmarks::dlib_68())] {
        for (set, held_out) in [("trainset", false), ("afw + testset", true)] {
            let (mut n, mut iou, mut dc, mut ds) = (0usize, 0.0f64, 0.0f64, 0.0f64);
            for (path, pts, b) in &rows {
                if faces300w::is_trainset(path) == held_out {
                    continue;
                }
                let Some(p) = m.apply(pts) else { continue };
                let side = 0.5 * (b.width() + b.height()) as f64;
                n += 1;
                iou += p.iou(b) as f64;
                let (c, q) = (b.center(), p.center());
                dc += (((c[0] - q[0]) as f64).powi(2) + ((c[1] - q[1]) as f64).powi(2)).sqrt() / side;
                ds += (p.width() as f64 / side).ln().abs();
            }
            let n1 = n.max(1) as f64;
            println!(
                "{name}, {set} ({n} boxes): mean IoU with dlib's box {:.3}, centre error {:.2} % of the side, |log side ratio| {:.3}",
                iou / n1,
                100.0 * dc / n1,
                ds / n1
            );
        }
    }
}
