//! One synthetic sample: draw the scene, render the full head over a background, and
//! derive the ground truth (mask, landmarks, boxes) from the same numbers the renderer used.

use facerecon_model::morphable::{Extent, Prior};
use facerecon_model::scene::{self, Camera, Pose, pixel_to_ndc};
use facerecon_model::{Coefficients, MorphableModel};
use facerecon_raster::visibility::{BACKGROUND, VisibilityBuffer};
use facerecon_raster::{Frame, cpu, job::RenderJob};
use image::{GrayImage, RgbImage};

use crate::SynthError;
use crate::background::random_background;
use crate::config::SynthConfig;
use crate::expression::random_expression;
use crate::head::{HeadStyle, PartColors};
use crate::light::random_light;
use crate::pose::Euler;
use crate::rng::Rng;
use crate::truth::{CameraTruth, Crop, FaceBox, GroundTruth, Landmark, TRUTH_FORMAT};
use facerecon_vision::crop::Bucket;

/// Coefficients with a Gaussian prior are drawn N(0, 1) and clamped to ±this many σ
/// (a 1-in-1.7-million tail; keeps extreme, implausible heads out).
const GAUSSIAN_CLAMP: f64 = 5.0;

/// A rendered sample with its ground truth.
#[derive(Clone, Debug)]
pub struct Sample {
    pub image: RgbImage,
    /// 255 where the face area is visible, 0 elsewhere.
    pub mask: GrayImage,
    pub truth: GroundTruth,
    /// The renderer's pass-1 output (triangle ids index [`HeadStyle::triangles`]).
    pub visibility: VisibilityBuffer,
}

/// Draws and renders samples of one model.
pub struct Generator<'m> {
    model: &'m MorphableModel,
    style: HeadStyle,
    config: SynthConfig,
}

impl<'m> Generator<'m> {
    pub fn new(model: &'m MorphableModel, config: SynthConfig) -> Result<Self, SynthError> {
        config.validate()?;
        if model.landmarks().is_empty() {
            return Err(SynthError::Config("the model has no landmarks".into()));
        }
        Ok(Self { style: HeadStyle::new(model), model, config })
    }

    pub fn config(&self) -> &SynthConfig {
        &self.config
    }

    pub fn style(&self) -> &HeadStyle {
        &self.style
    }

    pub fn model(&self) -> &MorphableModel {
        self.model
    }

    /// Sample `index` of a run seeded with `seed` (independent of every other sample).
    pub fn sample(&self, seed: u64, index: u64) -> Result<Sample, SynthError> {
        let mut rng = Rng::for_sample(seed, index);
        let mut bg_rng = rng.fork(1);
        let model = self.model;
        let meta = model.meta();
        let cfg = &self.config;

        // --- coefficients -------------------------------------------------------------
        let gaussian = |rng: &mut Rng, n: usize| -> Vec<f32> {
            (0..n).map(|_| rng.normal().clamp(-GAUSSIAN_CLAMP, GAUSSIAN_CLAMP) as f32).collect()
        };
        let identity = gaussian(&mut rng, meta.identity.count);
        let (expression, actions) = match meta.expression.prior {
            Prior::Blendshape => random_expression(&meta.expression_names, true, &mut rng),
            Prior::Gaussian => {
                let (w, a) = random_expression(&vec![String::new(); meta.expression.count], false, &mut rng);
                (w, a)
            }
        };
        let albedo = gaussian(&mut rng, meta.albedo.count);
        let light = random_light(&mut rng);
        let drawn_yaw = rng.range(-cfg.yaw_max_deg as f64, cfg.yaw_max_deg as f64) as f32;
        let euler = Euler {
            yaw_deg: cfg.yaw_deg.unwrap_or(drawn_yaw),
            pitch_deg: rng.normal_clamped(cfg.pitch_sd_deg as f64, cfg.pitch_max_deg as f64) as f32,
            roll_deg: rng.normal_clamped(cfg.roll_sd_deg as f64, cfg.roll_max_deg as f64) as f32,
        };
        let part_colors = PartColors::random(&mut rng);

        // --- size and placement ---------------------------------------------------------
        let (width, height, side, cx, cy) = match cfg.crop_frame {
            // The crop itself: the crop square fills the image, centred.
            Some(s) => (s, s, s as f32, 0.5 * s as f32 - 0.5, 0.5 * s as f32 - 0.5),
            None => {
                let bucket = cfg.buckets[rng.below(cfg.buckets.len() as u64) as usize] as usize;
                let (lo, hi) = Bucket::from_index(bucket)
                    .and_then(Bucket::side_range)
                    .ok_or_else(|| SynthError::Config(format!("no bucket {bucket}")))?;
                let hi = hi.min(cfg.max_crop_side);
                let mut side = rng.log_range(lo as f64 * 1.03, hi as f64 * 0.97) as f32;
                let (width, height) = match cfg.image_size {
                    Some(s) => s,
                    None => {
                        let min_side = (side * 1.1).ceil().max(64.0);
                        let max_side = (cfg.max_image_side as f32).max(min_side);
                        let long = rng.log_range(min_side.max(96.0).min(max_side) as f64, max_side as f64 + 1.0) as f32;
                        let aspect = rng.range(0.6, 1.0) as f32;
                        let short = (long * aspect).max(min_side);
                        if rng.chance(0.5) { (long as u32, short as u32) } else { (short as u32, long as u32) }
                    }
                };
                side = side.min(0.95 * width.min(height) as f32);
                let margin = 0.45 * side;
                let cx = rng.range(
                    margin.min(width as f32 / 2.0) as f64,
                    (width as f32 - margin).max(width as f32 / 2.0) as f64,
                ) as f32;
                let cy = rng.range(
                    margin.min(height as f32 / 2.0) as f64,
                    (height as f32 - margin).max(height as f32 / 2.0) as f64,
                ) as f32;
                (width, height, side, cx, cy)
            }
        };

        let shape = model.shape(&identity, &expression, Extent::Face).map_err(SynthError::model)?;
        let rotation = euler.axis_angle();
        let lm_idx = model.landmarks();
        let (camera, translation) = frame_face(model, &shape, rotation, width, height, [cx, cy], side);

        // --- render ------------------------------------------------------------------------
        let coefficients = Coefficients { identity, expression, albedo, light, rotation, translation };
        let (frame, positions) = self.render(&coefficients, &part_colors, camera, width, height)?;
        let vb = frame.visibility;

        let mut image = random_background(width, height, &mut bg_rng);
        let mut mask = GrayImage::new(width, height);
        let (mut face_pixels, mut head_pixels) = (0u64, 0u64);
        let mut face_px = Vec::new();
        for (i, &t) in vb.triangle.iter().enumerate() {
            if t == BACKGROUND {
                continue;
            }
            head_pixels += 1;
            let (x, y) = ((i % width as usize) as u32, (i / width as usize) as u32);
            let c = frame.color[i];
            image.put_pixel(x, y, image::Rgb([c[0], c[1], c[2]]));
            if (t as usize) < self.style.face_triangle_count {
                face_pixels += 1;
                mask.put_pixel(x, y, image::Luma([255]));
                face_px.push([x as f32, y as f32]);
            }
        }

        // --- ground truth --------------------------------------------------------------------
        let landmarks: Vec<Landmark> = lm_idx
            .iter()
            .map(|&v| {
                let xyz = positions[v as usize];
                let xy = camera.project(xyz, width, height).unwrap_or([f32::NAN; 2]);
                let visible = landmark_visible(&vb, &self.style.lash_triangle, &camera, xy, -xyz[2]);
                Landmark { xy, xyz, visible }
            })
            .collect();
        let landmark_box = FaceBox::of_points(landmarks.iter().map(|l| l.xy))
            .ok_or_else(|| SynthError::Config("the model has no landmarks".into()))?;
        let crop = Crop::of_box(&landmark_box);
        let stem = format!("{index:06}");
        let truth = GroundTruth {
            format: TRUTH_FORMAT.into(),
            index,
            seed,
            model: meta.name.clone(),
            image: format!("{stem}.png"),
            mask: format!("{stem}_mask.png"),
            width,
            height,
            coefficients,
            expression_actions: actions.iter().map(|s| s.to_string()).collect(),
            euler,
            camera: CameraTruth {
                fov_y_deg: camera.fov_y.to_degrees(),
                aspect: camera.aspect,
                near_mm: camera.near,
                far_mm: camera.far,
                focal_px: 0.5 * height as f32 * camera.focal(),
            },
            part_colors,
            landmarks,
            landmark_box,
            crop,
            face_box: FaceBox::of_points(face_px),
            face_pixels,
            head_pixels,
        };
        Ok(Sample { image, mask, truth, visibility: vb })
    }
}

impl Generator<'_> {
    /// Renders the full head of `c` (its pose, light and albedo) with `colors` for the
    /// non-face parts: the frame (triangle ids index [`HeadStyle::triangles`]) and the
    /// camera-space positions of every vertex.
    pub fn render(
        &self,
        c: &Coefficients,
        colors: &PartColors,
        camera: Camera,
        width: u32,
        height: u32,
    ) -> Result<(Frame, Vec<[f32; 3]>), SynthError> {
        let model = self.model;
        let shape = model.shape(&c.identity, &c.expression, Extent::Full).map_err(SynthError::model)?;
        let positions = Pose::from_coefficients(c).apply(&shape);
        let normals = scene::vertex_normals(&positions, &self.style.triangles);
        let face_albedo = model.albedo(&c.albedo, Extent::Face).map_err(SynthError::model)?;
        let head_albedo = self.style.albedo(&face_albedo, colors);
        let shaded = scene::shade(&head_albedo, &normals, &c.light);
        let job = RenderJob {
            positions: &positions,
            triangles: &self.style.triangles,
            colors: &shaded,
            normals: &normals,
            camera,
            width,
            height,
        };
        Ok((cpu::render(&job)?, positions))
    }
}

impl Generator<'_> {
    /// The face of `c` drawn again under `rotation`, as the front end's crop of it (`side`
    /// px square, framed by its landmarks as [`SynthConfig::crop_frame`] frames samples),
    /// with hair and clothes colours and a background drawn from `rng`. `c`'s own pose is
    /// replaced. The cross-pose branch of training (DESIGN §7) encodes this beside the
    /// photo `c` was predicted from.
    pub fn render_crop(
        &self,
        c: &Coefficients,
        rotation: [f32; 3],
        side: u32,
        rng: &mut Rng,
    ) -> Result<RgbImage, SynthError> {
        if side == 0 || !rotation.iter().all(|r| r.is_finite()) {
            return Err(SynthError::Config(format!("re-rendering at {side} px, rotation {rotation:?}")));
        }
        let model = self.model;
        let shape = model.shape(&c.identity, &c.expression, Extent::Face).map_err(SynthError::model)?;
        let centre = 0.5 * side as f32 - 0.5;
        let (camera, translation) = frame_face(model, &shape, rotation, side, side, [centre, centre], side as f32);
        let posed = Coefficients { rotation, translation, ..c.clone() };
        let colors = PartColors::random(rng);
        let (frame, _) = self.render(&posed, &colors, camera, side, side)?;
        let mut image = random_background(side, side, rng);
        for (i, &t) in frame.visibility.triangle.iter().enumerate() {
            if t != BACKGROUND {
                let col = frame.color[i];
                image.put_pixel(i as u32 % side, i as u32 / side, image::Rgb([col[0], col[1], col[2]]));
            }
        }
        Ok(image)
    }
}

/// The camera and translation that frame a face of face-area `shape` under `rotation` in a
/// `w`×`h` image: its landmarks' crop centred on `centre`, `side` px (via [`place_face`]),
/// with tight clip planes around the head (depth precision at any distance; x, y and the
/// pixel mapping do not depend on them). Samples and re-renderings share it, so both are
/// framed alike.
fn frame_face(
    model: &MorphableModel,
    shape: &[[f32; 3]],
    rotation: [f32; 3],
    w: u32,
    h: u32,
    centre: [f32; 2],
    side: f32,
) -> (Camera, [f32; 3]) {
    let lm: Vec<[f32; 3]> = model.landmarks().iter().map(|&i| shape[i as usize]).collect();
    let mut camera = Camera { aspect: w as f32 / h as f32, ..Camera::default() };
    let translation = place_face(&lm, rotation, &camera, w, h, centre, side);
    let depth = -translation[2];
    camera.near = (depth - 600.0).max(1.0);
    camera.far = depth + 600.0;
    (camera, translation)
}

/// Translation that puts the landmarks' centroid on the ray through pixel `centre` at the
/// distance where their crop (see [`Crop`]) is `side` pixels: solved on the projection
/// itself (fixed-point rounds until within 0.01 px: the crop side is ∝ 1/distance up to
/// perspective).
pub fn place_face(
    lm: &[[f32; 3]],
    rotation: [f32; 3],
    camera: &Camera,
    w: u32,
    h: u32,
    centre: [f32; 2],
    side: f32,
) -> [f32; 3] {
    let r = scene::rotation_matrix(rotation);
    let n = lm.len() as f32;
    let anchor = lm.iter().fold(glam::Vec3::ZERO, |a, p| a + glam::Vec3::from(*p)) / n;
    let ra = r * anchor;
    let tan = (0.5 * camera.fov_y).tan();
    let at = |px: [f32; 2], d: f32| {
        let ndc = pixel_to_ndc(px, w, h);
        glam::Vec3::new(ndc[0] * d * tan * camera.aspect, ndc[1] * d * tan, -d) - ra
    };
    let crop_of = |t: glam::Vec3| {
        let pose = Pose::new(rotation, t.to_array());
        let pts = pose.apply(lm);
        let b = FaceBox::of_points(pts.iter().filter_map(|p| camera.project(*p, w, h))).expect("landmarks in front");
        Crop::of_box(&b)
    };
    let mut d = 1000.0f32;
    let mut aim = centre;
    let mut t = at(aim, d);
    // Converges in 2–3 rounds for a face small in its image; a face filling it (crop
    // framing, strong yaw) needs more, perspective bending the offset.
    for _ in 0..16 {
        let c = crop_of(t);
        if (c.side / side - 1.0).abs() < 1e-5 && (centre[0] - c.cx).abs() < 0.01 && (centre[1] - c.cy).abs() < 0.01 {
            break;
        }
        d *= c.side / side;
        // Move the aim point by the remaining offset of the crop centre.
        aim = [aim[0] + centre[0] - c.cx, aim[1] + centre[1] - c.cy];
        t = at(aim, d);
    }
    t.to_array()
}

/// A landmark is visible when it projects inside the image and, in its 3×3 pixel
/// neighbourhood, some pixel shows a surface no nearer than the landmark minus a tolerance
/// (3 mm plus two pixel footprints: a pixel centre samples the surface up to half a pixel
/// away, and grazing surfaces change depth fast). Eyelash pixels count as see-through.
fn landmark_visible(vb: &VisibilityBuffer, lash: &[bool], camera: &Camera, xy: [f32; 2], depth: f32) -> bool {
    let (w, h) = (vb.width as i64, vb.height as i64);
    if !(xy[0].is_finite() && xy[1].is_finite()) {
        return false;
    }
    let (px, py) = (xy[0].round() as i64, xy[1].round() as i64);
    if px < 0 || py < 0 || px >= w || py >= h {
        return false;
    }
    let footprint = depth * 2.0 * (0.5 * camera.fov_y).tan() / vb.height as f32;
    let tol = 3.0 + 2.0 * footprint;
    for y in (py - 1).max(0)..=(py + 1).min(h - 1) {
        for x in (px - 1).max(0)..=(px + 1).min(w - 1) {
            let i = (y * w + x) as usize;
            let t = vb.triangle[i];
            if t == BACKGROUND {
                continue;
            }
            if lash[t as usize] || vb.depth[i] >= depth - tol {
                return true;
            }
        }
    }
    false
}
