//! Pose consistency over a yaw sweep (DESIGN §8, thesis §4.3): the same synthetic faces
//! (bucket 0, the default distribution otherwise) rendered at each yaw of 0–60°, each
//! reconstructed from its crop at the exact landmarks, by the landmark fit and (with
//! `--encoder W`) by the learned encoder alone; `--coarse` adds the coarse fit after each.
//!
//! Per yaw and method:
//! * geometry error against the ground truth (mm, point-to-plane after similarity ICP, as
//!   `synth_geometry` measures it);
//! * identity drift: per face, the RMS difference of its identity coefficients (σ units)
//!   from the same method's answer for the same face at yaw 0 — what a pose-consistent
//!   method keeps near zero; beside it, the same divided by the spread of the method's own
//!   identity answers at yaw 0 (RMS about their mean), since a method that answers near
//!   the mean face drifts little in absolute terms;
//! * D_JS: the Jensen–Shannon divergence (bits, 0–1) between the distribution of each
//!   identity coefficient over the faces at this yaw and at yaw 0 (histograms of 12 bins on
//!   [−3, 3], add-one smoothed), averaged over the coefficients
//!   ([`facerecon_eval::consistency::d_js`], our reading of Eq. 4.4). With few faces it has a
//!   floor: the same measure between two halves of the faces at yaw 0 is printed beside it.
//!
//! Per method, over the whole sweep: D_con, each face's sweep taken as a video of a head
//! turning ([`facerecon_eval::consistency::d_con`], our reading of Eq. 4.5: the mean distance,
//! σ units, of each yaw's identity answer from the face's mean answer over the sweep),
//! averaged over the faces answered at every yaw.
//!
//! ```text
//! cargo run --release -p facerecon-eval --example yaw_sweep -- [--faces N] [--seed S] \
//!     [--yaws 0,15,30,45,60] [--encoder WEIGHTS] [--coarse]
//! ```

use facerecon_eval::align::Metric;

use facerecon_model::{Coefficients, MorphableModel};
use facerecon_recon::{FaceSource, Options, Pipeline, Refine, Start};
use facerecon_synth::{Generator, SynthConfig};
use facerecon_vision::pipeline::FrontEnd;
use glam::DVec3;
use rayon::prelude::*;

/// One method's answer for one face: its coefficients and their geometry error (mm).
type Answer = Option<(Coefficients, f64)>;

mod shape_error;

fn truth_shape(model: &MorphableModel, c: &Coefficients) -> (Vec<DVec3>, Vec<DVec3>) {
    shape_error::shape(model, &c.identity, &c.expression, None)
}

fn geometry_error(model: &MorphableModel, pred: &Coefficients, truth: &(Vec<DVec3>, Vec<DVec3>)) -> f64 {
    shape_error::error(model, &truth_shape(model, pred), truth, Metric::PointToPlane)
}

/// D_JS between two sets of answers, over their identity coefficients
/// ([`facerecon_eval::consistency::d_js`]); NaN when it is undefined.
fn d_js(a: &[&Coefficients], b: &[&Coefficients]) -> f64 {
    fn ids<'a>(s: &[&'a Coefficients]) -> Vec<&'a [f32]> {
        s.iter().map(|c| c.identity.as_slice()).collect()
    }
    facerecon_eval::consistency::d_js(&ids(a), &ids(b)).unwrap_or(f64::NAN)
}

fn main() {
    let mut faces = 24u64;
    let mut seed = 11u64;
    let mut yaws: Vec<f32> = vec![0.0, 15.0, 30.0, 45.0, 60.0];
    let mut encoder: Option<String> = None;
    let mut coarse = false;
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        if a == "--coarse" {
            coarse = true;
            continue;
        }
        let v = args.next().unwrap_or_else(|| panic!("{a} needs a value"));
        match a.as_str() {
            "--faces" => faces = v.parse().expect("number"),
            "--seed" => seed = v.parse().expect("number"),
            "--yaws" => yaws = v.split(',').map(|s| s.trim().parse().expect("degrees")).collect(),
            "--encoder" => encoder = Some(v),
            _ => panic!("unknown argument {a}"),
        }
    }
    assert!(yaws.first() == Some(&0.0), "the sweep starts at yaw 0 (the reference)");
    let model = facerecon_model::ict::load_default().expect("default model");
    let front = FrontEnd::load_standard(facerecon_vision::landmarks::DEFAULT_MODEL_PATH.as_ref()).expect("front end");
    let mut pipeline = Pipeline::new(model.clone(), front).expect("pipeline");
    if let Some(w) = &encoder {
        let runtime = facerecon_vision::onnx::OnnxRuntimeConfig { intra_op_threads: 1, ..Default::default() };
        let e = facerecon_nn::OrtEncoder::load(w.as_ref(), &runtime).expect("encoder weights");
        pipeline.set_encoder(std::sync::Arc::new(e)).expect("encoder matches the model");
    }
    let mut methods: Vec<(&str, Start, Refine)> = vec![("landmark fit", Start::Landmarks, Refine::Landmarks)];
    if coarse {
        methods.push(("landmark + coarse fit", Start::Landmarks, Refine::Coarse));
    }
    if encoder.is_some() {
        methods.push(("encoder alone", Start::Encoder, Refine::None));
        if coarse {
            methods.push(("encoder + coarse fit", Start::Encoder, Refine::Coarse));
        }
    }
    let started = std::time::Instant::now();
    // answers[yaw][face][method], and the truth's error inputs per face (pose-free shape).
    let mut answers: Vec<Vec<Vec<Answer>>> = Vec::new();
    for &yaw in &yaws {
        let config = SynthConfig { buckets: vec![0], yaw_deg: Some(yaw), ..SynthConfig::default() };
        let generator = Generator::new(&model, config).expect("generator");
        let per_face: Vec<Vec<Answer>> = (0..faces)
            .into_par_iter()
            .map(|i| {
                let s = generator.sample(seed, i).expect("sample");
                let truth = truth_shape(&model, &s.truth.coefficients);
                let exact: Vec<[f32; 2]> = s.truth.landmarks.iter().map(|l| l.xy).collect();
                methods
                    .iter()
                    .map(|&(_, start, refine)| {
                        let o = Options {
                            faces: FaceSource::Landmarks(vec![exact.clone()]),
                            start,
                            refine,
                            ..Default::default()
                        };
                        let r = pipeline.reconstruct_image(s.image.clone(), &o).ok()?;
                        let f = r.faces.into_iter().next()?.fit.ok()?;
                        let e = geometry_error(&model, &f.coefficients, &truth);
                        Some((f.coefficients, e))
                    })
                    .collect()
            })
            .collect();
        answers.push(per_face);
    }
    println!(
        "yaw sweep: {faces} synthetic faces (seed {seed}, bucket 0) at yaw {yaws:?}, from the exact landmarks ({:.0} s)",
        started.elapsed().as_secs_f64()
    );
    println!(
        "method | yaw | geometry p2plane mm, mean | identity drift from yaw 0, RMS σ (÷ spread at yaw 0) | D_JS vs yaw 0, bits (floor: halves at yaw 0)"
    );
    for (m, (name, _, _)) in methods.iter().enumerate() {
        let at = |y: usize| -> Vec<Option<&(Coefficients, f64)>> { answers[y].iter().map(|f| f[m].as_ref()).collect() };
        let base = at(0);
        let base_coeffs: Vec<&Coefficients> = base.iter().flatten().map(|(c, _)| c).collect();
        let half = base_coeffs.len() / 2;
        let floor = d_js(&base_coeffs[..half], &base_coeffs[half..]);
        let spread = {
            let k = base_coeffs.first().map_or(0, |c| c.identity.len());
            let n = base_coeffs.len().max(1) as f64;
            let mut sq = 0.0;
            for i in 0..k {
                let m = base_coeffs.iter().map(|c| c.identity[i] as f64).sum::<f64>() / n;
                sq += base_coeffs.iter().map(|c| (c.identity[i] as f64 - m).powi(2)).sum::<f64>() / n;
            }
            (sq / k.max(1) as f64).sqrt()
        };
        for (y, yaw) in yaws.iter().enumerate() {
            let here = at(y);
            let errs: Vec<f64> = here.iter().flatten().map(|(_, e)| *e).collect();
            let drift: Vec<f64> = here
                .iter()
                .zip(&base)
                .filter_map(|(a, b)| {
                    let (a, b) = (&a.as_ref()?.0, &b.as_ref()?.0);
                    let sq: f64 = a.identity.iter().zip(&b.identity).map(|(x, y)| ((x - y) as f64).powi(2)).sum();
                    Some((sq / a.identity.len().max(1) as f64).sqrt())
                })
                .collect();
            let coeffs: Vec<&Coefficients> = here.iter().flatten().map(|(c, _)| c).collect();
            let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
            println!(
                "{name} | {yaw:>4.0}° | {:.2} ({} faces) | {:.3} ({:.2}) | {:.3} ({floor:.3})",
                mean(&errs),
                errs.len(),
                mean(&drift),
                mean(&drift) / spread.max(1e-9),
                d_js(&coeffs, &base_coeffs)
            );
        }
        let d_con: Vec<f64> = (0..faces as usize)
            .filter_map(|f| {
                let frames: Option<Vec<&[f32]>> =
                    answers.iter().map(|y| y[f][m].as_ref().map(|(c, _)| c.identity.as_slice())).collect();
                facerecon_eval::consistency::d_con(&frames?)
            })
            .collect();
        println!(
            "{name} | D_con over the sweep: {:.3} σ (mean of {} faces)",
            d_con.iter().sum::<f64>() / d_con.len().max(1) as f64,
            d_con.len()
        );
    }
}
