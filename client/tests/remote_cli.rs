//! The remote side of the `facerecon` command against a server on loopback:
//! `reconstruct` writes exactly the files `fit` writes in-process (at the full level: meshes
//! with the displacement map, the map's PNG, the texture), and `bulk` streams a
//! folder with a bad file in it, resumes, and splits into shards.

use std::path::{Path, PathBuf};
use std::process::Command;

use facerecon_server::Config;
use facerecon_tests::{TestServer, photos};

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("facerecon-remote-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn facerecon(args: &[&str], paths: &[&Path]) -> std::process::Output {
    let mut c = Command::new(env!("CARGO_BIN_EXE_facerecon"));
    c.args(args);
    for p in paths {
        c.arg(p);
    }
    c.output().unwrap()
}

/// [`facerecon`] off the runtime's threads (the server under test runs on them).
async fn facerecon_off_runtime(args: Vec<String>, paths: &[PathBuf]) -> std::process::Output {
    let paths = paths.to_vec();
    tokio::task::spawn_blocking(move || {
        let a: Vec<&str> = args.iter().map(|a| a.as_str()).collect();
        let p: Vec<&Path> = paths.iter().map(|p| p.as_path()).collect();
        facerecon(&a, &p)
    })
    .await
    .unwrap()
}

fn sorted_files(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> =
        std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
    v.sort();
    v
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn reconstruct_writes_the_files_fit_writes() {
    let s = TestServer::start(Config::default()).await;
    let pics = photos(2);
    let (remote, local) = (tmp("reconstruct"), tmp("fit"));
    let args = ["reconstruct", "--refine", "full", "--server", &s.url(), "-o", remote.to_str().unwrap()];
    let out = facerecon_off_runtime(args.map(String::from).to_vec(), &pics).await;
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let p: Vec<&Path> = pics.iter().map(|p| p.as_path()).collect();
    let out = facerecon(&["fit", "--refine", "full", "-o", local.to_str().unwrap()], &p);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let files = sorted_files(&remote);
    assert_eq!(files, sorted_files(&local));
    assert_eq!(files.len(), 2 * 9, "{files:?}");
    assert!(files.iter().any(|f| f.ends_with("-face1-displacement.png")), "{files:?}");
    assert!(files.iter().any(|f| f.ends_with("-face1-texture.png")), "{files:?}");
    for f in files {
        assert_eq!(std::fs::read(remote.join(&f)).unwrap(), std::fs::read(local.join(&f)).unwrap(), "{f} differs");
    }
    s.stop().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bulk_streams_resumes_and_shards() {
    let s = TestServer::start(Config::default()).await;
    let input = tmp("bulk-in");
    std::fs::create_dir_all(input.join("sub")).unwrap();
    for (k, p) in photos(5).iter().enumerate() {
        let dest =
            if k < 3 { input.join(p.file_name().unwrap()) } else { input.join("sub").join(p.file_name().unwrap()) };
        std::fs::copy(p, dest).unwrap();
    }
    std::fs::write(input.join("broken.jpg"), b"\xff\xd8\xff\xe0 not a jpeg").unwrap();
    let out = tmp("bulk-out");
    let url = s.url();
    let run = move |extra: Vec<String>| {
        let (input, out, url) = (input.clone(), out.clone(), url.clone());
        tokio::task::spawn_blocking(move || {
            let mut args = vec!["bulk".to_string(), input.display().to_string(), "--server".into(), url];
            args.extend(["-o".into(), out.display().to_string(), "--no-meshes".into(), "--no-pictures".into()]);
            args.extend(extra);
            let a: Vec<&str> = args.iter().map(|s| s.as_str()).collect();
            let o = facerecon(&a, &[]);
            let summary: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap_or_else(|e| {
                panic!("{e}: {}\n{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr))
            });
            (o.status.success(), summary)
        })
    };
    // Two shards, then the whole list: the second run skips what the shards wrote.
    let (ok0, s0) = run(vec!["--shard".into(), "0/2".into()]).await.unwrap();
    let (ok1, s1) = run(vec!["--shard".into(), "1/2".into()]).await.unwrap();
    assert!(ok0 && ok1, "{s0} {s1}");
    assert_eq!(s0["written"].as_u64().unwrap() + s1["written"].as_u64().unwrap(), 5, "{s0} {s1}");
    assert_eq!(s0["failed"].as_u64().unwrap() + s1["failed"].as_u64().unwrap(), 1, "{s0} {s1}");
    let (ok, again) = run(vec![]).await.unwrap();
    assert!(ok, "{again}");
    assert_eq!(again["written"], 0, "{again}");
    assert_eq!(again["skipped"], 5, "{again}");
    assert_eq!(again["failed"], 1, "the bad file is tried again and logged again: {again}");
    let out = std::path::PathBuf::from(again["errors"].as_str().unwrap()).parent().unwrap().to_path_buf();
    let log = std::fs::read_to_string(out.join("errors.jsonl")).unwrap();
    let line: serde_json::Value = serde_json::from_str(log.lines().next().unwrap()).unwrap();
    assert!(line["input"].as_str().unwrap().ends_with("broken.jpg"), "{line}");
    assert_eq!(line["code"], "InvalidArgument");
    // Names keep the folder; records are complete.
    let files = sorted_files(&out);
    assert!(files.iter().any(|f| f.starts_with("sub__") && f.ends_with("-face1.json")), "{files:?}");
    // A changed input is done again.
    let first = files.iter().find(|f| f.ends_with(".done") && !f.starts_with("sub__")).unwrap().clone();
    let stem = first.trim_end_matches(".done");
    let input_file =
        std::fs::read_dir(out.parent().unwrap().join(format!("facerecon-remote-bulk-in-{}", std::process::id())))
            .unwrap()
            .map(|e| e.unwrap().path())
            .find(|p| p.file_stem().is_some_and(|s| s == stem))
            .unwrap();
    let img = image::open(&input_file).unwrap().to_rgb8();
    image::imageops::flip_horizontal(&img).save(&input_file).unwrap();
    let (ok, third) = run(vec![]).await.unwrap();
    assert!(ok, "{third}");
    assert_eq!(third["written"], 1, "{third}");
    assert_eq!(third["skipped"], 4, "{third}");
    s.stop().await.unwrap();
}

#[test]
fn an_unreachable_server_is_a_clear_error() {
    let out = facerecon(
        &["reconstruct", "--server", "http://127.0.0.1:1", "-o", tmp("unreachable").to_str().unwrap()],
        &[photos(1)[0].as_path()],
    );
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("127.0.0.1:1"), "{err}");
}

/// `--start encoder` asks the server's learned encoder (here the released one, which the
/// server loads by default); `--refine none` without it is refused before anything is sent.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn reconstruct_can_start_from_the_servers_encoder() {
    let config = Config::default();
    let s = TestServer::start_with(config.clone(), facerecon_server::default_loader(&config)).await;
    s.wait_serving(std::time::Duration::from_secs(120)).await;
    let pics = photos(1);
    let out_dir = tmp("encoder");
    let args = ["reconstruct", "--start", "encoder", "--server", &s.url(), "-o", out_dir.to_str().unwrap()];
    let out = facerecon_off_runtime(args.map(String::from).to_vec(), &pics).await;
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let record = sorted_files(&out_dir).into_iter().find(|f| f.ends_with("-face1.json")).expect("a face record");
    let json: serde_json::Value = serde_json::from_slice(&std::fs::read(out_dir.join(record)).unwrap()).unwrap();
    let text = json.to_string();
    assert!(
        text.contains("\"encoder\"") || text.contains("\"Encoder\""),
        "the record must say it started from the encoder: {text:.300}"
    );

    let p: Vec<&Path> = pics.iter().map(|p| p.as_path()).collect();
    let bad =
        facerecon(&["reconstruct", "--refine", "none", "--server", &s.url(), "-o", out_dir.to_str().unwrap()], &p);
    assert!(!bad.status.success());
    assert!(
        String::from_utf8_lossy(&bad.stderr).contains("--start encoder"),
        "{}",
        String::from_utf8_lossy(&bad.stderr)
    );
    s.stop().await.unwrap();
    let _ = std::fs::remove_dir_all(&out_dir);
}
