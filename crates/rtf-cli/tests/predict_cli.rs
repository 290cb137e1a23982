//! `rtf predict` over a folder: streamed with progress lines and an ETA, killed mid-way and
//! re-run with `--skip-existing` (the finished frames are not redone, the result is the same
//! as one uninterrupted run), and never a temporary or half-written file left behind.

mod common;

use common::*;
use std::io::BufRead;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::SystemTime;

const FRAMES: usize = 48;

/// Tiny weights and a folder of `FRAMES` distinct MF images (copies of 8 synthetic ones).
fn weights_and_images(dir: &Path) -> (PathBuf, PathBuf) {
    let (data, run, images) = (dir.join("data"), dir.join("run"), dir.join("in"));
    synth_mf(&data, "8", "4", "32x32");
    ok(&short_train(&data, &run, "1", &["--val-split", "none"]));
    let mut synthetic: Vec<PathBuf> = std::fs::read_dir(data.join("images"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    synthetic.sort();
    std::fs::create_dir_all(&images).unwrap();
    for i in 0..FRAMES {
        let from = &synthetic[i % synthetic.len()];
        std::fs::copy(from, images.join(format!("f{i:03}.png"))).unwrap();
    }
    (run.join("final.safetensors"), images)
}

/// File name → (bytes, modification time) of every file in `dir`.
fn listing(dir: &Path) -> std::collections::BTreeMap<String, (Vec<u8>, SystemTime)> {
    std::fs::read_dir(dir)
        .unwrap()
        .map(|e| {
            let e = e.unwrap();
            let modified = e.metadata().unwrap().modified().unwrap();
            let name = e.file_name().to_string_lossy().into_owned();
            (name, (std::fs::read(e.path()).unwrap(), modified))
        })
        .collect()
}

fn predict_args<'a>(weights: &'a Path, out: &'a Path, images: &'a Path) -> Vec<&'a str> {
    vec![
        "predict",
        "--weights",
        s(weights),
        "--out",
        s(out),
        "--logits",
        "--progress-every",
        "10",
        s(images),
    ]
}

/// Starts `rtf predict`, kills it (SIGKILL) once it has reported `after` frames on stdout.
fn predict_killed_after(args: &[&str], after: usize) {
    let mut child = Command::new(env!("CARGO_BIN_EXE_rtf"))
        .args(args)
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let stdout = std::io::BufReader::new(child.stdout.take().unwrap());
    let mut reported = 0;
    for line in stdout.lines() {
        assert!(line.unwrap().contains(" -> "));
        reported += 1;
        if reported == after {
            child.kill().unwrap();
            break;
        }
    }
    child.wait().unwrap();
    assert_eq!(reported, after, "predict ended before {after} frames");
}

#[test]
fn predict_over_a_folder_restarts_without_redoing_finished_frames() {
    let tmp = tempfile::tempdir().unwrap();
    let (weights, images) = weights_and_images(tmp.path());
    // One uninterrupted run: every frame, progress lines with an ETA, a summary.
    let whole = tmp.path().join("whole");
    let run = rtf(&predict_args(&weights, &whole, &images));
    assert!(run.status.success(), "{}", text(&run));
    let stderr = String::from_utf8_lossy(&run.stderr);
    for done in [10, 20, 30, 40, FRAMES] {
        let line = format!("predict: {done}/{FRAMES} frames");
        assert!(stderr.contains(&line), "no `{line}` in:\n{stderr}");
    }
    assert_eq!(stderr.matches("ETA").count(), 5, "{stderr}");
    assert!(
        stderr.contains(&format!("predicted {FRAMES} frame(s)")),
        "{stderr}"
    );
    let expected = listing(&whole);
    assert_eq!(
        expected.len(),
        3 * FRAMES,
        "png, colour png and npy per frame"
    );

    // Killed after 5 frames, then re-run with --skip-existing.
    let out = tmp.path().join("out");
    let args = predict_args(&weights, &out, &images);
    predict_killed_after(&args, 5);
    let before = listing(&out);
    let complete: Vec<&String> = before.keys().filter(|n| !n.starts_with('.')).collect();
    assert!(complete.len() >= 15, "5 frames' outputs: {complete:?}");
    // A temporary file of a writer that is gone (as a kill during a write leaves).
    let gone = Command::new("true").spawn().unwrap();
    let pid = gone.id();
    drop(gone.wait_with_output());
    let stale = out.join(format!(".f047.png.tmp-{pid}.png"));
    std::fs::write(&stale, b"half a PNG").unwrap();
    let mut again = args.clone();
    again.push("--skip-existing");
    let rerun = rtf(&again);
    assert!(rerun.status.success(), "{}", text(&rerun));
    let stderr = String::from_utf8_lossy(&rerun.stderr);
    let skipped: usize = stderr
        .split("skipped ")
        .nth(1)
        .and_then(|t| t.split(' ').next())
        .and_then(|k| k.parse().ok())
        .unwrap_or_else(|| panic!("no `skipped K` in:\n{stderr}"));
    assert!((5..FRAMES).contains(&skipped), "{stderr}");
    assert!(
        stderr.contains("already predicted") && stderr.contains("ETA"),
        "{stderr}"
    );
    assert!(stderr.contains("removed"), "{stderr}");
    let redone = String::from_utf8_lossy(&rerun.stdout).lines().count();
    assert_eq!(
        redone,
        FRAMES - skipped,
        "only the frames not finished are predicted"
    );

    // Same files as the uninterrupted run, no temporary left, finished frames untouched.
    let after = listing(&out);
    assert_eq!(
        after.keys().collect::<Vec<_>>(),
        expected.keys().collect::<Vec<_>>(),
        "no temporary files, every output"
    );
    for (name, (bytes, modified)) in &after {
        if name.ends_with(".png") {
            assert_eq!(
                bytes, &expected[name].0,
                "{name} differs from the whole run"
            );
        }
        if let Some((old_bytes, old_modified)) = before.get(name) {
            let frame = name.split(['.', '_']).next().unwrap();
            let finished = before.contains_key(&format!("{frame}.npy"))
                && before.contains_key(&format!("{frame}_color.png"))
                && before.contains_key(&format!("{frame}.png"));
            if finished {
                assert_eq!(
                    (old_bytes, old_modified),
                    (bytes, modified),
                    "{name} redone"
                );
            }
        }
    }
}

#[test]
fn skip_existing_redoes_a_frame_with_a_missing_output() {
    let tmp = tempfile::tempdir().unwrap();
    let (weights, images) = weights_and_images(tmp.path());
    let out = tmp.path().join("out");
    ok(&predict_args(&weights, &out, &images));
    std::fs::remove_file(out.join("f007_color.png")).unwrap();
    let mut again = predict_args(&weights, &out, &images);
    again.push("--skip-existing");
    let rerun = rtf(&again);
    assert!(rerun.status.success(), "{}", text(&rerun));
    let stdout = String::from_utf8_lossy(&rerun.stdout);
    assert_eq!(stdout.lines().count(), 1, "{stdout}");
    assert!(stdout.contains("f007.png"), "{stdout}");
    let stderr = String::from_utf8_lossy(&rerun.stderr);
    assert!(
        stderr.contains(&format!("skipped {} already predicted", FRAMES - 1)),
        "{stderr}"
    );
    assert!(out.join("f007_color.png").is_file());
    // An empty folder is refused, naming it.
    let empty = tmp.path().join("empty");
    std::fs::create_dir_all(&empty).unwrap();
    let err = fails(&predict_args(&weights, &out, &empty));
    assert!(
        err.contains("empty") && err.contains("without .png"),
        "{err}"
    );
}
