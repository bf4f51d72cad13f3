//! The service end to end over loopback sockets: a `facerecon-server` in this process, the
//! client library and raw gRPC stubs on the other side. Every bad input gets its precise
//! status and the server goes on serving.

use std::time::Duration;

use facerecon_client::{Client, ClientError, ConnectOptions, Request, proto as pb};
use facerecon_server::Config;
use facerecon_tests::{TestServer, photos, png, png_header_claiming};
use tokio_stream::StreamExt;
use tonic::Code;

fn options() -> ConnectOptions {
    ConnectOptions { retries: 0, ..ConnectOptions::default() }
}

async fn client(s: &TestServer) -> Client {
    Client::connect(&[s.url()], options()).await.expect("connecting")
}

fn code(r: Result<facerecon_client::Reconstruction, ClientError>) -> Code {
    match r {
        Ok(_) => Code::Ok,
        Err(e) => e.code().unwrap_or_else(|| panic!("not a status: {e}")),
    }
}

fn photo(k: usize) -> Vec<u8> {
    std::fs::read(&photos(k + 1)[k]).unwrap()
}

fn pts(k: usize) -> Vec<[f32; 2]> {
    let p = photos(k + 1)[k].with_extension("pts");
    facerecon_vision::pts::read(&std::fs::read(p).unwrap()).unwrap()
}

fn with(options: pb::Options, bytes: Vec<u8>) -> Request {
    Request::new("t", bytes).with_options(options)
}

/// A good photo answers every output, consistent with the model's topology.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_photo_gets_coefficients_meshes_and_pictures() {
    let s = TestServer::start(Config::default()).await;
    let c = client(&s).await;
    let model = c.model().await.unwrap();
    assert_eq!(model.info.landmark_vertices.len(), 68);
    assert_eq!(model.uvs.len(), model.info.vertex_count as usize);
    let opts = pb::Options {
        outputs: Some(pb::Outputs {
            mesh_arrays: true,
            mesh_files: vec![pb::MeshFormat::Glb as i32, pb::MeshFormat::Ply as i32, pb::MeshFormat::Obj as i32],
            overlay: true,
            side_by_side: true,
            displacement_map: false,
            texture: true,
        }),
        ..Default::default()
    };
    let bytes = photo(0);
    let r = c.reconstruct(with(opts, bytes.clone()).clone()).await.unwrap();
    let img = image::load_from_memory(&bytes).unwrap();
    assert_eq!((r.width, r.height), (img.width(), img.height()));
    let t = r.timing.unwrap();
    assert!(t.decode_detect_s > 0.0 && t.fit_s > 0.0 && t.outputs_s > 0.0 && t.queue_s >= 0.0, "{t:?}");
    assert_eq!(r.faces.len(), 1);
    let face = &r.faces[0];
    assert_eq!(face.landmarks.len(), 68);
    assert!(face.bucket.is_some());
    let fit = face.fit.as_ref().unwrap();
    assert_eq!(fit.coefficients.identity.len(), model.info.identity_count as usize);
    assert_eq!(fit.coefficients.expression.len(), model.info.expression_count as usize);
    assert!(fit.landmark_rms_px < 10.0, "{}", fit.landmark_rms_px);
    // The record agrees with the in-process pipeline's.
    let local = facerecon_tests::pipeline().reconstruct(&bytes, &Default::default()).unwrap();
    let local_record =
        facerecon_recon::outputs::face_record(facerecon_tests::pipeline().model(), &local.faces[0]).unwrap();
    let remote_record = face.record(&model.info).unwrap();
    assert_eq!(serde_json::to_value(&local_record).unwrap(), serde_json::to_value(&remote_record).unwrap());
    // Meshes: arrays complete, files with their magic, pictures decodable.
    let mesh = model.mesh(fit.mesh.as_ref().unwrap()).unwrap();
    mesh.validate().unwrap();
    let files: Vec<_> = fit.mesh_files.iter().map(|(f, d)| (*f, d.clone())).collect();
    assert_eq!(files.len(), 3);
    assert_eq!(&files[0].1[..4], b"glTF");
    // The texture: a 512² PNG, embedded in the GLB as its material's base colour.
    let texture = fit.texture_png.as_ref().expect("the texture asked for");
    let decoded = image::load_from_memory(texture).unwrap();
    assert_eq!((decoded.width(), decoded.height()), (512, 512));
    let gltf = gltf::Gltf::from_slice(&files[0].1).unwrap();
    assert!(gltf.materials().next().unwrap().pbr_metallic_roughness().base_color_texture().is_some());
    assert!(files[1].1.starts_with(b"ply\n"));
    assert!(String::from_utf8_lossy(&files[2].1).contains(&format!("{} vertices", model.info.vertex_count)));
    let overlay = image::load_from_memory(r.overlay_png.as_ref().unwrap()).unwrap();
    assert_eq!((overlay.width(), overlay.height()), (img.width(), img.height()));
    assert!(image::load_from_memory(r.side_by_side_png.as_ref().unwrap()).is_ok());
    s.stop().await.unwrap();
}

/// The pictures drawn by the wgpu renderer on its own thread (`renderer = gpu`, lavapipe
/// here) against the CPU rasteriser's (`renderer = cpu`): two independent producers, the
/// same pictures up to edge pixels, for one face and for several requests at once.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn pictures_from_the_render_thread_match_the_cpu_rasteriser() {
    use facerecon_server::config::RendererChoice;
    let cpu = TestServer::start(Config { renderer: RendererChoice::Cpu, ..Config::default() }).await;
    let gpu = TestServer::start(Config { renderer: RendererChoice::Gpu, ..Config::default() }).await;
    let opts = pb::Options {
        outputs: Some(pb::Outputs { overlay: true, side_by_side: true, ..Default::default() }),
        ..Default::default()
    };
    let pictures = |r: &facerecon_client::Reconstruction| {
        [r.overlay_png.as_ref().unwrap(), r.side_by_side_png.as_ref().unwrap()]
            .map(|p| image::load_from_memory(p).unwrap().to_rgb8())
    };
    let (c, g) = (client(&cpu).await, client(&gpu).await);
    let photos: Vec<Vec<u8>> = (0..3).map(photo).collect();
    let want: Vec<_> = {
        let mut v = Vec::new();
        for p in &photos {
            v.push(pictures(&c.reconstruct(with(opts.clone(), p.clone())).await.unwrap()));
        }
        v
    };
    // All at once, so that the render thread merges requests.
    let calls: Vec<_> = photos
        .iter()
        .map(|p| {
            let (g, request) = (g.clone(), with(opts.clone(), p.clone()));
            tokio::spawn(async move { g.reconstruct(request).await })
        })
        .collect();
    for (k, (w, call)) in want.iter().zip(calls).enumerate() {
        let r = call.await.unwrap();
        for (name, (a, b)) in ["overlay", "side-by-side"].iter().zip(w.iter().zip(pictures(&r.unwrap()))) {
            assert_eq!(a.dimensions(), b.dimensions(), "photo {k} {name}");
            let n = a.as_raw().len() / 3;
            let px = |i: usize| a.as_raw()[3 * i..3 * i + 3].iter().zip(&b.as_raw()[3 * i..3 * i + 3]);
            let differ = (0..n).filter(|&i| px(i).any(|(x, y)| x.abs_diff(*y) > 2)).count();
            eprintln!("photo {k} {name}: {differ} of {n} pixels differ by more than 2/255");
            assert!((differ as f64) < 0.001 * n as f64, "photo {k} {name}: {differ} of {n} pixels differ");
        }
    }
    cpu.stop().await.unwrap();
    gpu.stop().await.unwrap();
}

/// REFINE_FULL: the displacement stage's summary, its map as a 16-bit PNG, and meshes that
/// carry the map, all as the in-process pipeline makes them.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_full_level_sends_its_displacement_map() {
    let s = TestServer::start(Config::default()).await;
    let c = client(&s).await;
    let model = c.model().await.unwrap();
    let truth = pts(0);
    let opts = pb::Options {
        refine: pb::Refine::Full as i32,
        landmarks: vec![pb::LandmarkSet { points: truth.iter().map(|p| pb::Point { x: p[0], y: p[1] }).collect() }],
        outputs: Some(pb::Outputs { mesh_arrays: true, displacement_map: true, ..Default::default() }),
        ..Default::default()
    };
    let bytes = photo(0);
    let r = c.reconstruct(with(opts, bytes.clone())).await.unwrap();
    let fit = r.faces[0].fit.as_ref().unwrap();
    assert_eq!(fit.refine, facerecon_recon::Refine::Full);
    let summary = fit.displacement.expect("displacement summary");
    assert!(summary.color_l1 < summary.color_l1_start, "{summary:?}");
    let map = facerecon_model::displacement::from_png(fit.displacement_png.as_ref().unwrap()).unwrap();

    let p = facerecon_tests::pipeline();
    let local_options = facerecon_recon::Options {
        refine: facerecon_recon::Refine::Full,
        faces: facerecon_recon::FaceSource::Landmarks(vec![truth]),
        ..Default::default()
    };
    let local = p.reconstruct(&bytes, &local_options).unwrap();
    let local_fit = local.faces[0].fit.as_ref().unwrap();
    let local_map = &local_fit.displacement.as_ref().unwrap().map;
    let step = (summary.max_mm - summary.min_mm) / 65535.0;
    assert!(map.values().iter().zip(local_map.values()).all(|(a, b)| (a - b).abs() <= step));
    let local_record = facerecon_recon::outputs::face_record(p.model(), &local.faces[0]).unwrap();
    let remote_record = r.faces[0].record(&model.info).unwrap();
    assert_eq!(serde_json::to_value(&local_record).unwrap(), serde_json::to_value(&remote_record).unwrap());
    let mesh = model.mesh(fit.mesh.as_ref().unwrap()).unwrap();
    assert_eq!(mesh.positions, facerecon_recon::outputs::face_mesh(p.model(), local_fit).unwrap().positions);
    s.stop().await.unwrap();
}

/// Each bad input gets its precise status; the server keeps serving after all of them.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bad_input_gets_its_precise_status() {
    let s = TestServer::start(Config { max_message_bytes: 4 << 20, ..Config::default() }).await;
    let c = client(&s).await;
    let good = photo(0);
    let truth = pts(0);
    let o = pb::Options::default;
    let jpeg = {
        let img = image::load_from_memory(&good).unwrap().to_rgb8();
        let mut out = std::io::Cursor::new(Vec::new());
        img.write_to(&mut out, image::ImageFormat::Jpeg).unwrap();
        out.into_inner()
    };
    let cases: Vec<(&str, Request, Code, &str)> = vec![
        ("garbage", with(o(), b"this is not an image".to_vec()), Code::InvalidArgument, "unknown image format"),
        ("0 bytes", with(o(), Vec::new()), Code::InvalidArgument, "empty"),
        ("JPEG cut in its headers", with(o(), jpeg[..200].to_vec()), Code::InvalidArgument, "corrupt or truncated"),
        ("truncated PNG", with(o(), good[..good.len() / 2].to_vec()), Code::InvalidArgument, "truncated"),
        ("50000×50000 PNG", with(o(), png_header_claiming(50_000, 50_000)), Code::ResourceExhausted, "too large"),
        ("over the message limit", with(o(), vec![0u8; 5 << 20]), Code::ResourceExhausted, "message length too large"),
        ("unknown refine", with(pb::Options { refine: 99, ..o() }, good.clone()), Code::InvalidArgument, "refine"),
        (
            "displacement map below refine FULL",
            with(
                pb::Options { outputs: Some(pb::Outputs { displacement_map: true, ..Default::default() }), ..o() },
                good.clone(),
            ),
            Code::InvalidArgument,
            "refine FULL only",
        ),
        (
            "unknown mesh format",
            with(
                pb::Options { outputs: Some(pb::Outputs { mesh_files: vec![0], ..Default::default() }), ..o() },
                good.clone(),
            ),
            Code::InvalidArgument,
            "mesh format",
        ),
        (
            "max_faces above the limit",
            with(pb::Options { max_faces: 1000, ..o() }, good.clone()),
            Code::InvalidArgument,
            "limit",
        ),
        (
            "boxes and landmarks",
            with(
                pb::Options {
                    boxes: vec![pb::Box { x0: 1.0, y0: 1.0, x1: 50.0, y1: 50.0 }],
                    landmarks: vec![pb::LandmarkSet {
                        points: truth.iter().map(|p| pb::Point { x: p[0], y: p[1] }).collect(),
                    }],
                    ..o()
                },
                good.clone(),
            ),
            Code::InvalidArgument,
            "not both",
        ),
        (
            "NaN box",
            with(
                pb::Options { boxes: vec![pb::Box { x0: f32::NAN, y0: 1.0, x1: 50.0, y1: 50.0 }], ..o() },
                good.clone(),
            ),
            Code::InvalidArgument,
            "box",
        ),
        (
            "box outside the image",
            with(
                pb::Options { boxes: vec![pb::Box { x0: 1e6, y0: 1e6, x1: 1e6 + 100.0, y1: 1e6 + 100.0 }], ..o() },
                good.clone(),
            ),
            Code::InvalidArgument,
            "box",
        ),
        (
            "NaN landmark",
            with(
                pb::Options {
                    landmarks: vec![pb::LandmarkSet {
                        points: truth
                            .iter()
                            .enumerate()
                            .map(|(i, p)| pb::Point { x: if i == 7 { f32::NAN } else { p[0] }, y: p[1] })
                            .collect(),
                    }],
                    ..o()
                },
                good.clone(),
            ),
            Code::InvalidArgument,
            "point 8",
        ),
        (
            "landmarks outside the image",
            with(
                pb::Options {
                    landmarks: vec![pb::LandmarkSet {
                        points: truth.iter().map(|p| pb::Point { x: p[0] + 1e5, y: p[1] }).collect(),
                    }],
                    ..o()
                },
                good.clone(),
            ),
            Code::InvalidArgument,
            "outside",
        ),
        (
            "67 landmarks",
            with(
                pb::Options {
                    landmarks: vec![pb::LandmarkSet {
                        points: truth[..67].iter().map(|p| pb::Point { x: p[0], y: p[1] }).collect(),
                    }],
                    ..o()
                },
                good.clone(),
            ),
            Code::InvalidArgument,
            "68",
        ),
    ];
    for (what, req, want, text) in cases {
        match c.reconstruct(req).await {
            Ok(_) => panic!("{what}: answered OK, wanted {want:?}"),
            Err(e) => {
                assert_eq!(e.code(), Some(want), "{what}: {e}");
                assert!(e.to_string().contains(text), "{what}: {e:?} lacks {text:?}");
            }
        }
    }
    // A JPEG cut inside its entropy-coded data decodes to its first part (libjpeg fills
    // the rest in grey, as OpenCV and browsers do): an answer, not an error.
    let r = c.reconstruct(with(o(), jpeg[..jpeg.len() * 9 / 10].to_vec())).await.unwrap();
    assert_eq!(r.width, image::load_from_memory(&good).unwrap().width());
    // No face is not an error.
    let blank = png(&image::RgbImage::from_pixel(320, 240, image::Rgb([128, 128, 128])));
    let r = c.reconstruct(with(o(), blank)).await.unwrap();
    assert!(r.faces.is_empty());
    // Client boxes and client landmarks.
    let b = facerecon_vision::face::FaceBox::of_points(truth.iter().copied()).unwrap();
    let r = c
        .reconstruct(with(
            pb::Options { boxes: vec![pb::Box { x0: b.x0, y0: b.y0, x1: b.x1, y1: b.y1 }], ..o() },
            good.clone(),
        ))
        .await
        .unwrap();
    assert_eq!(r.faces.len(), 1);
    assert!(r.faces[0].fit.is_ok());
    let set = pb::LandmarkSet { points: truth.iter().map(|p| pb::Point { x: p[0], y: p[1] }).collect() };
    let r = c.reconstruct(with(pb::Options { landmarks: vec![set], ..o() }, good.clone())).await.unwrap();
    assert_eq!(r.faces.len(), 1);
    assert_eq!(r.faces[0].landmarks, truth);
    // And still serving.
    assert_eq!(c.reconstruct(with(o(), good)).await.unwrap().faces.len(), 1);
    s.stop().await.unwrap();
}

/// Two photos side by side: two faces, largest first.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn several_faces() {
    let s = TestServer::start(Config::default()).await;
    let c = client(&s).await;
    let a = image::load_from_memory(&photo(0)).unwrap().to_rgb8();
    let b = image::load_from_memory(&photo(1)).unwrap().to_rgb8();
    let mut both = image::RgbImage::new(a.width() + b.width(), a.height().max(b.height()));
    image::imageops::replace(&mut both, &a, 0, 0);
    image::imageops::replace(&mut both, &b, a.width() as i64, 0);
    let r = c.reconstruct(Request::new("two", png(&both))).await.unwrap();
    assert_eq!(r.faces.len(), 2, "{:?}", r.faces.iter().map(|f| f.face_box).collect::<Vec<_>>());
    let area = |f: &facerecon_client::Face| (f.face_box[2] - f.face_box[0]) * (f.face_box[3] - f.face_box[1]);
    assert!(area(&r.faces[0]) >= area(&r.faces[1]));
    assert!(r.faces.iter().all(|f| f.fit.is_ok()));
    let r = c
        .reconstruct(Request::new("one", png(&both)).with_options(pb::Options { max_faces: 1, ..Default::default() }))
        .await
        .unwrap();
    assert_eq!(r.faces.len(), 1);
    s.stop().await.unwrap();
}

/// A deadline shorter than the work: DEADLINE_EXCEEDED (not CANCELLED), then more calls.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn deadlines_are_honoured() {
    let s = TestServer::start(Config::default()).await;
    let short = Client::connect(&[s.url()], ConnectOptions { timeout: Some(Duration::from_millis(30)), ..options() })
        .await
        .unwrap();
    let coarse = pb::Options { refine: pb::Refine::Coarse as i32, ..Default::default() };
    assert_eq!(code(short.reconstruct(with(coarse, photo(0))).await), Code::DeadlineExceeded);
    let c = client(&s).await;
    assert_eq!(code(c.reconstruct(with(Default::default(), photo(0))).await), Code::Ok);
    s.stop().await.unwrap();
}

/// The server's own answer to an expired deadline, without a client-side timer racing it.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_server_answers_deadline_exceeded_itself() {
    use facerecon_proto::v1::reconstructor_server::Reconstructor;
    let pool = std::sync::Arc::new(rayon_pool());
    let p = tokio::task::spawn_blocking(facerecon_tests::pipeline).await.unwrap();
    let engine = facerecon_server::engine::Engine::start(
        p,
        pool,
        facerecon_server::engine::EngineSettings { max_batch_size: 4, max_queue_delay: None, queue_capacity: 4 },
        std::sync::Arc::new(facerecon_raster::draw::Cpu),
    )
    .unwrap();
    let state = facerecon_server::service::State {
        engine: std::sync::OnceLock::from(engine),
        model_info: std::sync::OnceLock::new(),
        max_faces: 16,
    };
    let svc = facerecon_server::service::Service { state: std::sync::Arc::new(state) };
    let msg = pb::ReconstructRequest {
        id: "late".into(),
        image: photo(0),
        options: Some(pb::Options { refine: pb::Refine::Coarse as i32, ..Default::default() }),
    };
    let mut req = tonic::Request::new(msg);
    req.metadata_mut().insert("grpc-timeout", "50m".parse().unwrap());
    let t = std::time::Instant::now();
    let e = svc.reconstruct(req).await.unwrap_err();
    assert_eq!(e.code(), Code::DeadlineExceeded, "{e:?}");
    assert!(t.elapsed() < Duration::from_millis(500), "{:?}", t.elapsed());
}

fn rayon_pool() -> facerecon_server::engine::CpuPool {
    facerecon_server::engine::cpu_pool(2).unwrap()
}

/// 100 photos over one stream, every fifth one bad: every id answered once, bad ones with
/// their own error, good ones with their face.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_stream_of_100_mixed_photos() {
    let s = TestServer::start(Config::default()).await;
    let c = client(&s).await;
    let good: Vec<Vec<u8>> = (0..4).map(photo).collect();
    let requests: Vec<Request> = (0..100)
        .map(|k| {
            let bytes = if k % 5 == 4 { format!("bad {k}").into_bytes() } else { good[k % 4].clone() };
            Request::new(k.to_string(), bytes)
        })
        .collect();
    let stream = c.reconstruct_stream(tokio_stream::iter(requests), 8).await.unwrap();
    let answers: Vec<_> = stream.collect().await;
    assert_eq!(answers.len(), 100);
    let mut seen = [false; 100];
    for a in answers {
        let (id, r) = a.expect("no stream-level error");
        let k: usize = id.parse().unwrap();
        assert!(!std::mem::replace(&mut seen[k], true), "id {k} answered twice");
        if k % 5 == 4 {
            assert_eq!(code(r), Code::InvalidArgument, "item {k}");
        } else {
            let r = r.unwrap_or_else(|e| panic!("item {k}: {e}"));
            assert_eq!(r.faces.len(), 1, "item {k}");
        }
    }
    s.stop().await.unwrap();
}

/// A client that walks away mid-stream does not stop the server.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_client_cancelling_mid_stream() {
    let s = TestServer::start(Config::default()).await;
    let c = client(&s).await;
    let bytes = photo(0);
    let coarse = pb::Options { refine: pb::Refine::Coarse as i32, ..Default::default() };
    let requests: Vec<Request> =
        (0..20).map(|k| Request::new(k.to_string(), bytes.clone()).with_options(coarse.clone())).collect();
    let mut stream = Box::pin(c.reconstruct_stream(tokio_stream::iter(requests), 4).await.unwrap());
    let first = stream.next().await.unwrap().unwrap();
    assert!(first.1.is_ok());
    drop(stream);
    // The remaining work is dropped: a new call is answered well before 19 coarse fits
    // (about a second each) could have run.
    let t = std::time::Instant::now();
    let r = c.reconstruct(Request::new("after", bytes)).await.unwrap();
    assert_eq!(r.faces.len(), 1);
    assert!(t.elapsed() < Duration::from_secs(8), "{:?}", t.elapsed());
    s.stop().await.unwrap();
}

/// A burst beyond the queue: unary calls refused at once with RESOURCE_EXHAUSTED, the
/// admitted ones answered, a stream waits instead of failing, and the server recovers.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_burst_that_fills_the_queue() {
    let s = TestServer::start(Config { queue_capacity: 2, ..Config::default() }).await;
    let c = client(&s).await;
    let bytes = photo(0);
    let coarse = pb::Options { refine: pb::Refine::Coarse as i32, ..Default::default() };
    let calls: Vec<_> = (0..10)
        .map(|k| {
            let c = c.clone();
            let r = Request::new(k.to_string(), bytes.clone()).with_options(coarse.clone());
            tokio::spawn(async move {
                let t = std::time::Instant::now();
                (code(c.reconstruct(r).await), t.elapsed())
            })
        })
        .collect();
    let mut codes = Vec::new();
    for h in calls {
        codes.push(h.await.unwrap());
    }
    let ok = codes.iter().filter(|(c, _)| *c == Code::Ok).count();
    let refused: Vec<_> = codes.iter().filter(|(c, _)| *c == Code::ResourceExhausted).collect();
    assert!(ok >= 2, "{codes:?}");
    assert!(!refused.is_empty(), "{codes:?}");
    assert_eq!(ok + refused.len(), 10, "{codes:?}");
    assert!(refused.iter().all(|(_, t)| *t < Duration::from_millis(500)), "refused at once: {codes:?}");
    // A stream of 6 through a queue of 2: back-pressure, no refusals.
    let requests: Vec<Request> = (0..6).map(|k| Request::new(k.to_string(), bytes.clone())).collect();
    let answers: Vec<_> = c.reconstruct_stream(tokio_stream::iter(requests), 6).await.unwrap().collect().await;
    assert_eq!(answers.len(), 6);
    assert!(answers.into_iter().all(|a| a.unwrap().1.is_ok()));
    s.stop().await.unwrap();
}

/// Health says NOT_SERVING and calls UNAVAILABLE until the model is loaded.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn not_serving_until_loaded() {
    let (release, wait) = std::sync::mpsc::channel::<()>();
    let p = tokio::task::spawn_blocking(facerecon_tests::pipeline).await.unwrap();
    let load: facerecon_server::Loader = Box::new(move || {
        let _ = wait.recv();
        Ok(p)
    });
    let s = TestServer::start_with(Config::default(), load).await;
    use tonic_health::pb::health_check_response::ServingStatus;
    assert_eq!(s.health("").await, Some(ServingStatus::NotServing));
    assert_eq!(s.health(facerecon_server::SERVICE_NAME).await, Some(ServingStatus::NotServing));
    let c = client(&s).await;
    assert_eq!(code(c.reconstruct(Request::new("early", photo(0))).await), Code::Unavailable);
    release.send(()).unwrap();
    s.wait_serving(Duration::from_secs(10)).await;
    assert_eq!(s.health(facerecon_server::SERVICE_NAME).await, Some(ServingStatus::Serving));
    assert_eq!(code(c.reconstruct(Request::new("later", photo(0))).await), Code::Ok);
    s.stop().await.unwrap();
}

/// A failed load ends the server with the loader's error.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_failed_load_ends_the_server() {
    let s = TestServer::start_with(Config::default(), Box::new(|| anyhow::bail!("no such model file"))).await;
    let e = tokio::time::timeout(Duration::from_secs(10), s.finished()).await.unwrap().unwrap_err();
    assert!(format!("{e:#}").contains("no such model file"), "{e:#}");
}

/// With a token configured, reconstruction needs it; health stays open for probes.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bearer_token() {
    let s = TestServer::start(Config { auth_token: Some("s3cret".into()), ..Config::default() }).await;
    let none = client(&s).await;
    assert_eq!(code(none.reconstruct(Request::new("x", photo(0))).await), Code::Unauthenticated);
    let wrong = Client::connect(&[s.url()], ConnectOptions { token: Some("nope".into()), ..options() }).await.unwrap();
    assert_eq!(code(wrong.reconstruct(Request::new("x", photo(0))).await), Code::Unauthenticated);
    let right =
        Client::connect(&[s.url()], ConnectOptions { token: Some("s3cret".into()), ..options() }).await.unwrap();
    assert_eq!(code(right.reconstruct(Request::new("x", photo(0))).await), Code::Ok);
    s.stop().await.unwrap();
}

/// TLS with a self-signed certificate the client is given as its root.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn tls() {
    let dir = std::env::temp_dir().join(format!("facerecon-tls-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let cert = rcgen::generate_simple_self_signed(vec!["localhost".to_string()]).unwrap();
    let (cert_pem, key_pem) = (cert.cert.pem(), cert.signing_key.serialize_pem());
    std::fs::write(dir.join("cert.pem"), &cert_pem).unwrap();
    std::fs::write(dir.join("key.pem"), &key_pem).unwrap();
    let s = TestServer::start_with(
        Config { tls_cert: Some(dir.join("cert.pem")), tls_key: Some(dir.join("key.pem")), ..Config::default() },
        {
            let p = tokio::task::spawn_blocking(facerecon_tests::pipeline).await.unwrap();
            Box::new(move || Ok(p))
        },
    )
    .await;
    let url = format!("https://localhost:{}", s.addr.port());
    let c = Client::connect(&[url.as_str()], ConnectOptions { ca_pem: Some(cert_pem.into_bytes()), ..options() })
        .await
        .unwrap();
    let mut answered = false;
    for _ in 0..100 {
        match c.reconstruct(Request::new("tls", photo(0))).await {
            Ok(r) => {
                assert_eq!(r.faces.len(), 1);
                answered = true;
                break;
            }
            Err(e) if e.code() == Some(Code::Unavailable) => tokio::time::sleep(Duration::from_millis(100)).await,
            Err(e) => panic!("{e}"),
        }
    }
    assert!(answered);
    // A plain-text client gets no answer from a TLS server.
    let plain = Client::connect(&[format!("http://127.0.0.1:{}", s.addr.port())], options()).await.unwrap();
    assert!(plain.reconstruct(Request::new("plain", photo(0))).await.is_err());
    s.stop().await.unwrap();
}

/// A server started with an encoder answers START_ENCODER requests (NONE: the encoder's
/// answer, the same as in-process; COARSE: refined from it) for single photos and streams;
/// a server without one answers UNIMPLEMENTED, and start/refine pairs that make no sense
/// are INVALID_ARGUMENT.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_encoder_start() {
    use facerecon_nn::weights::{self, Precision};
    // Untrained weights: this checks the serving path, not accuracy.
    let model = facerecon_tests::pipeline().model().clone();
    let net_config = facerecon_nn::NetworkConfig::tiny(&model).unwrap();
    let device = burn::tensor::Device::default();
    let net = facerecon_nn::EncoderNet::new(&net_config, &device);
    let path = std::env::temp_dir().join(format!("facerecon-service-encoder-{}.safetensors", std::process::id()));
    weights::save(&net, &net_config, Precision::F16, &path).unwrap();

    let config = Config { encoder: facerecon_server::EncoderChoice::File(path.clone()), ..Config::default() };
    let s = TestServer::start_with(config.clone(), facerecon_server::default_loader(&config)).await;
    s.wait_serving(Duration::from_secs(120)).await;
    let c = client(&s).await;
    let enc = |refine: pb::Refine| pb::Options {
        start: pb::Start::Encoder as i32,
        refine: refine as i32,
        landmarks: vec![pb::LandmarkSet { points: pts(0).iter().map(|p| pb::Point { x: p[0], y: p[1] }).collect() }],
        ..Default::default()
    };
    let r = c.reconstruct(with(enc(pb::Refine::None), photo(0))).await.unwrap();
    let fit = r.faces[0].fit.as_ref().unwrap();
    assert_eq!((fit.start, fit.refine), (facerecon_recon::Start::Encoder, facerecon_recon::Refine::None));
    // The same as the encoder in-process on the same face.
    let mut local = facerecon_recon::Pipeline::new(
        model.clone(),
        facerecon_vision::pipeline::FrontEnd::load_standard(facerecon_vision::landmarks::DEFAULT_MODEL_PATH.as_ref())
            .unwrap(),
    )
    .unwrap();
    let burn_encoder = facerecon_nn::BurnEncoder::load(&path, device).unwrap();
    local.set_encoder(std::sync::Arc::new(burn_encoder)).unwrap();
    let options = facerecon_recon::Options {
        start: facerecon_recon::Start::Encoder,
        refine: facerecon_recon::Refine::None,
        faces: facerecon_recon::FaceSource::Landmarks(vec![pts(0)]),
        ..Default::default()
    };
    let want = local.reconstruct(&photo(0), &options).unwrap();
    let want = &want.faces[0].fit.as_ref().unwrap().coefficients;
    let d = want.identity.iter().zip(&fit.coefficients.identity).map(|(a, b)| (a - b).abs()).fold(0.0, f32::max);
    assert!(d < 1e-3, "server (ONNX Runtime) and in-process (burn) differ by {d}");

    let r = c.reconstruct(with(enc(pb::Refine::Coarse), photo(0))).await.unwrap();
    let fit = r.faces[0].fit.as_ref().unwrap();
    assert!(fit.photometric.is_some_and(|p| p.loss_end < p.loss_start));

    // A stream of photos, detected faces, all from the encoder (batched across photos).
    let detect =
        pb::Options { start: pb::Start::Encoder as i32, refine: pb::Refine::None as i32, ..Default::default() };
    let reqs: Vec<Request> =
        (0..6).map(|k| Request::new(format!("p{k}"), photo(k)).with_options(detect.clone())).collect();
    let answers: Vec<_> = c.reconstruct_stream(tokio_stream::iter(reqs), 6).await.unwrap().collect().await;
    assert_eq!(answers.len(), 6);
    for a in &answers {
        let (id, r) = a.as_ref().unwrap();
        let r = r.as_ref().unwrap_or_else(|e| panic!("{id}: {e}"));
        assert!(!r.faces.is_empty(), "{id}");
        assert!(r.faces.iter().all(|f| f.fit.as_ref().is_ok_and(|f| f.start == facerecon_recon::Start::Encoder)));
    }

    for (start, refine) in [(pb::Start::Encoder, pb::Refine::Landmarks), (pb::Start::Landmarks, pb::Refine::None)] {
        let o = pb::Options { start: start as i32, refine: refine as i32, ..Default::default() };
        assert_eq!(code(c.reconstruct(with(o, photo(0))).await), Code::InvalidArgument, "{start:?} {refine:?}");
    }
    s.stop().await.unwrap();

    // The same weights on the encoder's own shaders (lavapipe here) give the same answer.
    let config = Config { encoder_device: facerecon_nn::Compute::Wgsl, ..config };
    let s = TestServer::start_with(config.clone(), facerecon_server::default_loader(&config)).await;
    s.wait_serving(Duration::from_secs(120)).await;
    let c = client(&s).await;
    let r = c.reconstruct(with(enc(pb::Refine::None), photo(0))).await.unwrap();
    let fit = r.faces[0].fit.as_ref().unwrap();
    let d = want.identity.iter().zip(&fit.coefficients.identity).map(|(a, b)| (a - b).abs()).fold(0.0, f32::max);
    assert!(d < 1e-3, "server (wgsl) and in-process (burn) differ by {d}");
    s.stop().await.unwrap();

    let bare = TestServer::start(Config::default()).await;
    let c = client(&bare).await;
    assert_eq!(code(c.reconstruct(with(enc(pb::Refine::None), photo(0))).await), Code::Unimplemented);
    bare.stop().await.unwrap();
    let _ = std::fs::remove_file(&path);
}

/// By default the server loads the encoder released in `weights/` (the default model's), and
/// `encoder = "none"` turns it off.
#[test]
fn the_default_server_loads_the_released_encoder() {
    let with = facerecon_server::default_loader(&Config::default())().unwrap();
    assert!(with.encoder().is_some(), "the released encoder must load by default");
    let config = Config { encoder: facerecon_server::EncoderChoice::None, ..Config::default() };
    let without = facerecon_server::default_loader(&config)().unwrap();
    assert!(without.encoder().is_none());
}
