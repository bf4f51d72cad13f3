//! Every VJP against central finite differences in f64: for random inputs `x`, a random
//! upstream gradient `g` and random directions `d`,
//! `⟨vjp(g), d⟩ ≈ ⟨g, (f(x + h·d) − f(x − h·d)) / 2h⟩`.

use facerecon_model::{Extent, MorphableModel};
use glam::DVec3;

use super::*;
use crate::camera::CropCamera;

struct Lcg(u64);
impl Lcg {
    fn u(&mut self) -> f64 {
        self.0 = self.0.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        ((self.0 >> 11) as f64) / (1u64 << 53) as f64 * 2.0 - 1.0
    }
    fn v3(&mut self) -> DVec3 {
        DVec3::new(self.u(), self.u(), self.u())
    }
    fn vecs(&mut self, n: usize) -> Vec<DVec3> {
        (0..n).map(|_| self.v3()).collect()
    }
}

fn dot3(a: &[DVec3], b: &[DVec3]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x.dot(*y)).sum()
}

fn axpy(x: &[DVec3], h: f64, d: &[DVec3]) -> Vec<DVec3> {
    x.iter().zip(d).map(|(a, b)| *a + *b * h).collect()
}

/// Asserts `analytic ≈ numeric` relative to the larger magnitude.
fn close(what: &str, analytic: f64, numeric: f64) {
    let scale = analytic.abs().max(numeric.abs()).max(1e-8);
    assert!((analytic - numeric).abs() <= 1e-5 * scale, "{what}: analytic {analytic} vs finite difference {numeric}");
}

/// A small closed mesh: the model crate's UV sphere (6 rings × 8 segments) with jittered
/// radii, so that vertices have several incident triangles of different areas.
fn mesh(rng: &mut Lcg) -> (Vec<DVec3>, Vec<[u32; 3]>) {
    let (p, t) = facerecon_model::mesh::uv_sphere(6, 8);
    (p.iter().map(|x| glam::Vec3::from(*x).as_dvec3() * (1.0 + 0.1 * rng.u())).collect(), t)
}

#[test]
fn pose_vjp() {
    let mut rng = Lcg(1);
    for q in [DVec3::new(0.3, -0.5, 0.2), DVec3::new(1e-9, 0.0, -2e-9), DVec3::new(2.0, 1.0, -0.7)] {
        let x = rng.vecs(20);
        let t = rng.v3();
        let g = rng.vecs(20);
        let grad = pose::vjp(&x, q, &g);
        let h = 1e-6;
        let dx = rng.vecs(20);
        let f = |x: &[DVec3], q: DVec3, t: DVec3| dot3(&g, &pose::forward(x, q, t));
        close(
            "points",
            dot3(&grad.points, &dx),
            (f(&axpy(&x, h, &dx), q, t) - f(&axpy(&x, -h, &dx), q, t)) / (2.0 * h),
        );
        for k in 0..3 {
            let mut e = DVec3::ZERO;
            e[k] = h;
            close("rotation", grad.rotation[k], (f(&x, q + e, t) - f(&x, q - e, t)) / (2.0 * h));
            close("translation", grad.translation[k], (f(&x, q, t + e) - f(&x, q, t - e)) / (2.0 * h));
        }
    }
}

#[test]
fn projection_vjp() {
    let mut rng = Lcg(2);
    let cam = CropCamera::crop();
    let p: Vec<DVec3> = (0..30).map(|_| DVec3::new(60.0 * rng.u(), 60.0 * rng.u(), -450.0 + 50.0 * rng.u())).collect();
    let g: Vec<[f64; 2]> = (0..30).map(|_| [rng.u(), rng.u()]).collect();
    let f = |p: &[DVec3]| project::forward(&cam, p).iter().zip(&g).map(|(a, b)| a[0] * b[0] + a[1] * b[1]).sum::<f64>();
    let grad = project::vjp(&cam, &p, &g);
    let d = rng.vecs(30);
    let h = 1e-4;
    close("projection", dot3(&grad, &d), (f(&axpy(&p, h, &d)) - f(&axpy(&p, -h, &d))) / (2.0 * h));
}

#[test]
fn normals_vjp() {
    let mut rng = Lcg(3);
    let (p, t) = mesh(&mut rng);
    let g = rng.vecs(p.len());
    let grad = normals::vjp(&p, &t, &g);
    let h = 1e-6;
    for _ in 0..5 {
        let d = rng.vecs(p.len());
        let f = |p: &[DVec3]| dot3(&g, &normals::forward(p, &t));
        close("normals", dot3(&grad, &d), (f(&axpy(&p, h, &d)) - f(&axpy(&p, -h, &d))) / (2.0 * h));
    }
    // Against the model crate's f64 reference (an independent implementation).
    let n = normals::forward(&p, &t);
    let pf: Vec<[f32; 3]> = p.iter().map(|x| x.as_vec3().to_array()).collect();
    let reference = facerecon_model::scene::vertex_normals(&pf, &t);
    for (a, b) in n.iter().zip(&reference) {
        assert!(a.distance(glam::Vec3::from(*b).as_dvec3()) < 1e-6);
    }
}

#[test]
fn shading_vjp() {
    let mut rng = Lcg(4);
    let n = 25;
    let albedo: Vec<DVec3> = (0..n).map(|_| rng.v3() * 0.4 + DVec3::splat(0.5)).collect();
    let normals: Vec<DVec3> = (0..n).map(|_| rng.v3().normalize()).collect();
    let mut light = [[0.0; 3]; 25];
    for l in light.iter_mut() {
        *l = [rng.u(), rng.u(), rng.u()];
    }
    let g = rng.vecs(n);
    let grad = shading::vjp(&albedo, &normals, &light, &g);
    let f = |a: &[DVec3], nn: &[DVec3], l: &shading::Light| dot3(&g, &shading::forward(a, nn, l));
    let h = 1e-6;
    let d = rng.vecs(n);
    close(
        "albedo",
        dot3(&grad.albedo, &d),
        (f(&axpy(&albedo, h, &d), &normals, &light) - f(&axpy(&albedo, -h, &d), &normals, &light)) / (2.0 * h),
    );
    close(
        "normals",
        dot3(&grad.normals, &d),
        (f(&albedo, &axpy(&normals, h, &d), &light) - f(&albedo, &axpy(&normals, -h, &d), &light)) / (2.0 * h),
    );
    for k in [0, 3, 7, 24] {
        for c in 0..3 {
            let (mut lp, mut lm) = (light, light);
            lp[k][c] += h;
            lm[k][c] -= h;
            close("light", grad.light[k][c], (f(&albedo, &normals, &lp) - f(&albedo, &normals, &lm)) / (2.0 * h));
        }
    }
    // Forward against the model crate's f32 shading (an independent loop).
    let c = shading::forward(&albedo, &normals, &light);
    let lf: [[f32; 3]; 25] = std::array::from_fn(|k| light[k].map(|x| x as f32));
    for i in 0..n {
        let s = facerecon_model::scene::sh_shading(normals[i].as_vec3().to_array(), &lf);
        for ch in 0..3 {
            assert!((c[i][ch] - albedo[i][ch] * s[ch] as f64).abs() < 1e-4);
        }
    }
}

#[test]
fn interpolation_vjp() {
    let mut rng = Lcg(5);
    let mut vb = facerecon_raster::VisibilityBuffer::new(4, 3);
    let tris = vec![[0u32, 1, 2], [2, 3, 0]];
    for i in 0..12 {
        if i % 3 != 0 {
            vb.triangle[i] = (i % 2) as u32;
            vb.bary[i] = [(0.5 + 0.4 * rng.u()) as f32 * 0.5, (0.5 + 0.4 * rng.u()) as f32 * 0.5];
        }
    }
    let fp = interpolate::footprint(&vb, &tris);
    assert_eq!(fp.len(), 8);
    let attr = rng.vecs(4);
    let g = rng.vecs(fp.len());
    let grad = interpolate::vjp(&fp, 4, &g);
    let d = rng.vecs(4);
    let f = |a: &[DVec3]| dot3(&g, &interpolate::forward(&fp, a));
    let h = 1e-6;
    close("attributes", dot3(&grad, &d), (f(&axpy(&attr, h, &d)) - f(&axpy(&attr, -h, &d))) / (2.0 * h));
    // Barycentric weights sum to one: a constant attribute interpolates to itself.
    let one = vec![DVec3::splat(2.5); 4];
    assert!(interpolate::forward(&fp, &one).iter().all(|v| v.distance(DVec3::splat(2.5)) < 1e-6));
}

fn model() -> std::sync::Arc<MorphableModel> {
    facerecon_model::ict::load_default().unwrap()
}

#[test]
fn linear_vjp_on_the_model() {
    let model = model();
    let mut rng = Lcg(6);
    for block in [linear::Linear::Shape, linear::Linear::Albedo] {
        let k = block.coefficient_count(&model);
        let w: Vec<f64> = (0..k).map(|_| rng.u()).collect();
        let n = model.extent_vertices(Extent::Face);
        let g = rng.vecs(n);
        let grad = block.vjp(&model, &g);
        // The fast path (16-bit bases) agrees with the reference within the quantisation
        // bound: per mode, the model's per-value bound for a unit weight times Σ|g|.
        let fast = block.vjp_fast(&model, &g).unwrap();
        let g_abs: f64 = g.iter().map(|v| v.x.abs() + v.y.abs() + v.z.abs()).sum();
        for (m, (a, b)) in grad.iter().zip(&fast).enumerate() {
            let mut unit = vec![0.0f32; k];
            unit[m] = 1.0;
            let per_value = match block {
                linear::Linear::Shape => {
                    let ni = model.layout().identity;
                    model.shape_error_bound(&unit[..ni], &unit[ni..]) as f64
                }
                linear::Linear::Albedo => model.albedo_error_bound(&unit) as f64,
            };
            let bound = per_value * g_abs + 1e-5 * (1.0 + a.abs());
            assert!((a - b).abs() <= bound, "mode {m}: fast VJP {b} vs {a} (bound {bound})");
        }
        // And the bound is not what lets it pass: the worst error is small against the
        // gradient's own scale.
        let scale = grad.iter().fold(0.0f64, |m, a| m.max(a.abs()));
        let worst = grad.iter().zip(&fast).fold(0.0f64, |m, (a, b)| m.max((a - b).abs()));
        assert!(worst < 1e-3 * scale, "fast VJP off by {worst} against a gradient of {scale}");
        if block == linear::Linear::Albedo {
            let (x, y) = (block.forward(&model, &w), block.forward_fast(&model, &w).unwrap());
            let max = x.iter().zip(&y).map(|(a, b)| a.distance(*b)).fold(0.0, f64::max);
            assert!(max < 1e-3, "fast albedo off by {max}");
        }
        let f = |w: &[f64]| dot3(&g, &block.forward(&model, w));
        for idx in [0, k / 2, k - 1] {
            let h = 1e-3;
            let (mut wp, mut wm) = (w.clone(), w.clone());
            wp[idx] += h;
            wm[idx] -= h;
            close("linear", grad[idx], (f(&wp) - f(&wm)) / (2.0 * h));
        }
        // The forward against the model's own f32 evaluation (full-precision extent).
        if block == linear::Linear::Shape {
            let l = model.layout();
            let (id, ex): (Vec<f32>, Vec<f32>) = (
                w[..l.identity].iter().map(|x| *x as f32).collect(),
                w[l.identity..].iter().map(|x| (x.abs()) as f32).collect(),
            );
            let wabs: Vec<f64> = id.iter().chain(&ex).map(|x| *x as f64).collect();
            let ours = block.forward(&model, &wabs);
            let theirs = model.shape(&id, &ex, Extent::Full).unwrap();
            let max =
                ours.iter().zip(&theirs).map(|(a, b)| a.distance(glam::Vec3::from(*b).as_dvec3())).fold(0.0, f64::max);
            assert!(max < 1e-3, "{max} mm");
        }
    }
}

/// The chain coefficients → posed, lit vertex colours and projected landmarks, composed from
/// the primitives' VJPs, against finite differences of the whole chain.
#[test]
fn chained_decoder_vjp() {
    let model = model();
    let mut rng = Lcg(7);
    let l = model.layout();
    let ws: Vec<f64> = (0..l.identity + l.expression)
        .map(|i| if i < l.identity { 0.5 * rng.u() } else { 0.3 + 0.2 * rng.u() })
        .collect();
    let wa: Vec<f64> = (0..l.albedo).map(|_| 0.5 * rng.u()).collect();
    let q = DVec3::new(0.1, -0.3, 0.05);
    let t = DVec3::new(5.0, -3.0, -480.0);
    let mut light = [[0.0; 3]; 25];
    light[0] = [3.5; 3];
    light[2] = [0.4, 0.3, 0.2];
    let tris = model.extent_triangles(Extent::Face);
    let cam = CropCamera::crop();
    let lm: Vec<usize> = model.landmarks().iter().map(|&i| i as usize).collect();
    let n = model.extent_vertices(Extent::Face);
    let gc = rng.vecs(n);
    let gl: Vec<[f64; 2]> = (0..68).map(|_| [rng.u(), rng.u()]).collect();
    // L = ⟨gc, colours⟩ + ⟨gl, landmarks in pixels⟩.
    let loss = |ws: &[f64], q: DVec3| {
        let s = linear::Linear::Shape.forward(&model, ws);
        let y = pose::forward(&s, q, t);
        let nn = normals::forward(&y, tris);
        let a = linear::Linear::Albedo.forward(&model, &wa);
        let c = shading::forward(&a, &nn, &light);
        let lmk: Vec<DVec3> = lm.iter().map(|&i| y[i]).collect();
        let px = project::forward(&cam, &lmk);
        dot3(&gc, &c) + px.iter().zip(&gl).map(|(p, g)| p[0] * g[0] + p[1] * g[1]).sum::<f64>()
    };
    // Backward.
    let s = linear::Linear::Shape.forward(&model, &ws);
    let y = pose::forward(&s, q, t);
    let nn = normals::forward(&y, tris);
    let a = linear::Linear::Albedo.forward(&model, &wa);
    let gsh = shading::vjp(&a, &nn, &light, &gc);
    let mut gy = normals::vjp(&y, tris, &gsh.normals);
    let lmk: Vec<DVec3> = lm.iter().map(|&i| y[i]).collect();
    for (i, g) in lm.iter().zip(project::vjp(&cam, &lmk, &gl)) {
        gy[*i] += g;
    }
    let gp = pose::vjp(&s, q, &gy);
    let gws = linear::Linear::Shape.vjp(&model, &gp.points);
    let h = 1e-4;
    for idx in [0, 7, l.identity + 3, l.identity + l.expression - 1] {
        let (mut p, mut m) = (ws.clone(), ws.clone());
        p[idx] += h;
        m[idx] -= h;
        close("chain: shape coefficient", gws[idx], (loss(&p, q) - loss(&m, q)) / (2.0 * h));
    }
    for k in 0..3 {
        let mut e = DVec3::ZERO;
        e[k] = 1e-6;
        close("chain: rotation", gp.rotation[k], (loss(&ws, q + e) - loss(&ws, q - e)) / 2e-6);
    }
}

#[test]
fn barycentric_vjp_and_agreement_with_the_rasteriser() {
    let cam = facerecon_model::scene::Camera::default();
    barycentrics_against_the_rasteriser(cam);
    // An off-axis camera, as a face's window of a larger photo sees it.
    barycentrics_against_the_rasteriser(facerecon_model::scene::Camera { center: [0.3, -0.2], fov_y: 0.4, ..cam });
}

fn barycentrics_against_the_rasteriser(cam: facerecon_model::scene::Camera) {
    let clip = barycentric::Clip::new(&cam);
    let mut rng = Lcg(8);
    // A triangle 450 mm in front of the camera, filling part of a 64² image.
    let p = [DVec3::new(-40.0, -30.0, -450.0), DVec3::new(45.0, -20.0, -470.0), DVec3::new(0.0, 50.0, -430.0)];
    let (w, h) = (64u32, 64u32);
    let pf: Vec<[f32; 3]> = p.iter().map(|x| x.as_vec3().to_array()).collect();
    let tris = [[0u32, 1, 2]];
    let colors = [[1.0f32; 3]; 3];
    let job = facerecon_raster::RenderJob {
        positions: &pf,
        triangles: &tris,
        colors: &colors,
        normals: &colors,
        camera: cam,
        width: w,
        height: h,
    };
    let vb = facerecon_raster::cpu::rasterize(&job).unwrap();
    let mut checked = 0;
    for y in 0..h {
        for x in 0..w {
            let i = vb.index(x, y);
            if !vb.covered(i) {
                continue;
            }
            let s = barycentric::pixel_ray(x as f64, y as f64, w, h);
            let b = barycentric::forward(&clip, s, p).unwrap();
            // The rasteriser's barycentrics (an independent implementation, in f32).
            assert!((b[0] - vb.bary[i][0] as f64).abs() < 1e-4 && (b[1] - vb.bary[i][1] as f64).abs() < 1e-4);
            if checked % 37 == 0 {
                let g = [rng.u(), rng.u(), rng.u()];
                let grad = barycentric::vjp(&clip, s, p, g);
                let d = [rng.v3(), rng.v3(), rng.v3()];
                let hh = 1e-4;
                let f = |t: f64| {
                    let q = [p[0] + d[0] * t, p[1] + d[1] * t, p[2] + d[2] * t];
                    let b = barycentric::forward(&clip, s, q).unwrap();
                    g[0] * b[0] + g[1] * b[1] + g[2] * b[2]
                };
                let analytic: f64 = (0..3).map(|k| grad[k].dot(d[k])).sum();
                close("barycentrics", analytic, (f(hh) - f(-hh)) / (2.0 * hh));
            }
            checked += 1;
        }
    }
    assert!(checked > 150, "{checked} covered pixels");
}

#[test]
fn displacement_vjp() {
    // A map small enough that the vertices' taps overlap, the same chain as the
    // displacement fit: texels → displaced points → normals.
    let mut rng = Lcg(9);
    let (x, tris) = mesh(&mut rng);
    let n = normals::forward(&x, &tris);
    let map = facerecon_model::DisplacementMap::zeros(5).unwrap();
    let uvs: Vec<[f32; 2]> =
        (0..x.len()).map(|_| [(0.5 + 0.6 * rng.u()) as f32, (0.5 + 0.6 * rng.u()) as f32]).collect();
    let taps = displace::taps(&map, &uvs);
    let d: Vec<f64> = (0..25).map(|_| 0.05 * rng.u()).collect();
    let g = rng.vecs(x.len());
    let f = |d: &[f64]| dot3(&g, &normals::forward(&displace::forward(&x, &n, &taps, d), &tris));
    let y = displace::forward(&x, &n, &taps, &d);
    let grad = displace::vjp(&n, &taps, 25, &normals::vjp(&y, &tris, &g));
    let dir: Vec<f64> = (0..25).map(|_| rng.u()).collect();
    let h = 1e-6;
    let shift = |s: f64| d.iter().zip(&dir).map(|(a, b)| a + s * b).collect::<Vec<_>>();
    let analytic: f64 = grad.iter().zip(&dir).map(|(a, b)| a * b).sum();
    close("displacement", analytic, (f(&shift(h)) - f(&shift(-h))) / (2.0 * h));
}

#[test]
fn antialias_vjp() {
    let mut rng = Lcg(10);
    let centre = [10.0, 5.0];
    for (n, step) in [[1i8, 0], [-1, 0], [0, 1], [0, -1]].into_iter().cycle().take(24).enumerate() {
        // An edge through the segment at fraction c, leaning up to ½ pixel per pixel.
        let c = 0.5 + 0.42 * rng.u();
        let (s, perp) = ([step[0] as f64, step[1] as f64], [-(step[1] as f64), step[0] as f64]);
        let at = [centre[0] + c * s[0], centre[1] + c * s[1]];
        let lean = 0.5 * rng.u();
        let dir = [perp[0] + lean * s[0], perp[1] + lean * s[1]];
        let (ta, tb) = (-(1.75 + 1.25 * rng.u()), 1.75 + 1.25 * rng.u());
        let a = [at[0] + ta * dir[0], at[1] + ta * dir[1]];
        let b = [at[0] + tb * dir[0], at[1] + tb * dir[1]];
        let (front, back, g) = (rng.v3(), rng.v3(), rng.v3());
        let grad = antialias::vjp(centre, step, a, b, front, back, g);
        let (da, db, dfront, dback) = ([rng.u(), rng.u()], [rng.u(), rng.u()], rng.v3(), rng.v3());
        let f = |t: f64| {
            let shift = |p: [f64; 2], d: [f64; 2]| [p[0] + t * d[0], p[1] + t * d[1]];
            let (_, delta) =
                antialias::forward(centre, step, shift(a, da), shift(b, db), front + dfront * t, back + dback * t)
                    .unwrap();
            g.dot(delta)
        };
        let analytic = grad.a[0] * da[0]
            + grad.a[1] * da[1]
            + grad.b[0] * db[0]
            + grad.b[1] * db[1]
            + grad.front.dot(dfront)
            + grad.back.dot(dback);
        let h = 1e-6;
        close(&format!("antialias, case {n}"), analytic, (f(h) - f(-h)) / (2.0 * h));
    }
}

/// The visibility buffer of camera-space points `y` (about 450 mm away) seen by `camera`.
fn rasterize_in(camera: &CropCamera, y: &[DVec3], tris: &[[u32; 3]]) -> facerecon_raster::VisibilityBuffer {
    let yf: Vec<[f32; 3]> = y.iter().map(|v| v.as_vec3().to_array()).collect();
    let job = facerecon_raster::RenderJob {
        positions: &yf,
        triangles: tris,
        colors: &yf,
        normals: &yf,
        camera: camera.scene_camera(450.0),
        width: camera.size,
        height: camera.size,
    };
    facerecon_raster::cpu::rasterize(&job).unwrap()
}

/// A convex solid's antialiased coverage against the area of its outline, an independent
/// figure: the convex hull of its projected vertices (shoelace formula). Point sampling
/// is off by the pixels whose centres the outline happens to pass; the blend recovers the
/// fractions.
#[test]
fn antialiased_coverage_matches_the_outline_area() {
    let (p, tris) = facerecon_model::mesh::uv_sphere(10, 20);
    let size = 48u32;
    let camera = CropCamera { k: 900.0, c: [23.5, 23.5], size };
    let around = facerecon_model::morphable::VertexTriangles::new(p.len(), &tris);
    let adjacency = antialias::Adjacency::new(&tris, &around.inner_edges(&tris));
    let (mut worst_sampled, mut worst_aa) = (0.0f64, 0.0f64);
    for shift in 0..6 {
        let offset = DVec3::new(0.37 * shift as f64, -0.23 * shift as f64, -450.0);
        let y: Vec<DVec3> = p.iter().map(|v| glam::Vec3::from(*v).as_dvec3() * 7.5 + offset).collect();
        let vb = rasterize_in(&camera, &y, &tris);
        let pixels = project::forward(&camera, &y);
        let mut image: Vec<f64> = (0..vb.triangle.len()).map(|i| if vb.covered(i) { 1.0 } else { 0.0 }).collect();
        let sampled: f64 = image.iter().sum();
        let crossings = antialias::find(&vb, &tris, &adjacency, &pixels, |_| true);
        assert!(!crossings.is_empty());
        let colour = |i: usize| DVec3::splat(image[i]);
        let deltas: Vec<(usize, f64)> = crossings
            .iter()
            .filter_map(|x| {
                let centre = [(x.front % size as usize) as f64, (x.front / size as usize) as f64];
                let [a, b] = x.edge.map(|v| pixels[v as usize]);
                let (side, d) = antialias::forward(centre, x.step, a, b, colour(x.front), colour(x.back))?;
                Some((if side == antialias::Side::Front { x.front } else { x.back }, d.x))
            })
            .collect();
        for (i, d) in deltas {
            image[i] += d;
        }
        let aa: f64 = image.iter().sum();
        let area = hull_area(&pixels);
        worst_sampled = worst_sampled.max((sampled - area).abs());
        worst_aa = worst_aa.max((aa - area).abs());
    }
    eprintln!("outline area error, px²: point-sampled {worst_sampled:.2}, antialiased {worst_aa:.2}");
    // Measured: 7.3 px² point-sampled, 1.6 px² antialiased (0.2 % of the 695 px² outline; the
    // rest is where the outline turns, between the pairs of the two axes).
    assert!(worst_aa < 0.4 * worst_sampled && worst_aa < 2.5, "{worst_aa} vs {worst_sampled}");
}

/// Area of the convex hull of `pts` (monotone chain, then the shoelace formula).
fn hull_area(pts: &[[f64; 2]]) -> f64 {
    let mut p = pts.to_vec();
    p.sort_by(|a, b| a[0].total_cmp(&b[0]).then(a[1].total_cmp(&b[1])));
    let cross = |o: [f64; 2], a: [f64; 2], b: [f64; 2]| (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0]);
    let mut hull: Vec<[f64; 2]> = Vec::new();
    for pass in 0..2 {
        let start = hull.len();
        let iter: Box<dyn Iterator<Item = &[f64; 2]>> =
            if pass == 0 { Box::new(p.iter()) } else { Box::new(p.iter().rev()) };
        for &q in iter {
            while hull.len() >= start + 2 && cross(hull[hull.len() - 2], hull[hull.len() - 1], q) <= 0.0 {
                hull.pop();
            }
            hull.push(q);
        }
        hull.pop();
    }
    let n = hull.len();
    (0..n).map(|i| cross([0.0, 0.0], hull[i], hull[(i + 1) % n])).sum::<f64>().abs() / 2.0
}

/// An open sheet facing the camera has no outline: its border is not a silhouette
/// (`antialias` module docs), and its inner edges join triangles facing the same way. Folded
/// into a roof whose far side turns away, its ridge becomes one.
#[test]
fn antialias_finds_folds_not_borders() {
    let size = 32u32;
    let camera = CropCamera { k: 600.0, c: [15.5, 15.5], size };
    // A 2×2 grid of quads (3×3 vertices) 12 mm wide, 450 mm away; `lift` raises the middle
    // column towards the camera.
    let sheet = |lift: f64| -> Vec<DVec3> {
        (0..9)
            .map(|i| {
                let (cx, cy) = ((i % 3) as f64 - 1.0, (i / 3) as f64 - 1.0);
                DVec3::new(6.0 * cx, 6.0 * cy, -450.0 + if cx == 0.0 { lift } else { 0.0 })
            })
            .collect()
    };
    let mut tris = Vec::new();
    for qy in 0..2u32 {
        for qx in 0..2u32 {
            let v = qy * 3 + qx;
            tris.push([v, v + 1, v + 4]);
            tris.push([v, v + 4, v + 3]);
        }
    }
    let around = facerecon_model::morphable::VertexTriangles::new(9, &tris);
    let adjacency = antialias::Adjacency::new(&tris, &around.inner_edges(&tris));
    let crossings = |y: &[DVec3]| {
        let vb = rasterize_in(&camera, y, &tris);
        antialias::find(&vb, &tris, &adjacency, &project::forward(&camera, y), |_| true)
    };
    assert!(crossings(&sheet(0.0)).is_empty());
    // A gentle roof (the middle column 6 mm nearer): every face still turns towards the
    // camera, so no outline either.
    assert!(crossings(&sheet(6.0)).is_empty(), "a fold facing the camera has no outline");
    // A sharp one: the right column goes back and projects left of the ridge, so the right
    // quads turn away, hidden behind the left ones, and the ridge is the outline.
    let folded: Vec<DVec3> = sheet(10.0)
        .into_iter()
        .enumerate()
        .map(|(i, p)| if i % 3 == 2 { DVec3::new(-3.0, p.y, -500.0) } else { p })
        .collect();
    let found = crossings(&folded);
    // The ridge spans ≈ 16 pixel rows: one horizontal pair across it per row.
    assert!((12..=20).contains(&found.len()), "{} crossings", found.len());
    for x in &found {
        // Every silhouette edge is a ridge: the middle column's vertices (1, 4, 7).
        assert!(x.edge.iter().all(|v| v % 3 == 1), "{x:?}");
    }
}
