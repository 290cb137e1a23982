//! `rtf export` of networks trained on own class sets (3 and 9 classes of dataset.yaml), to
//! a read-only place, over its own weights, onto a folder.

use std::path::{Path, PathBuf};

use crate::common::*;
use crate::owndata::{plain_root, YAML};
use crate::verdict::*;
use crate::Fixture;

/// dataset.yaml of `n` classes named `kind0`, `kind1`, …
fn yaml_of(n: u8) -> String {
    let mut text = String::from("classes:\n");
    for id in 0..n {
        text.push_str(&format!(
            "  - {{id: {id}, name: kind{id}, color: [{id}, {id}, {id}]}}\n"
        ));
    }
    text
}

/// One-step mfnet weights on an own dataset of `n` classes.
fn weights_of(f: &Fixture, n: u8) -> PathBuf {
    let yaml = if n == 3 { YAML.to_string() } else { yaml_of(n) };
    let root = plain_root(&f.t.join(format!("ex_data{n}")), &yaml, n);
    let run = f.t.join(format!("ex_run{n}"));
    ok(&short_train(&root, &run, "1", &["--val-split", "none"]));
    run.join("final.safetensors")
}

fn export(weights: &Path, out: &Path, classes: Option<&str>) -> Vec<String> {
    let mut args = strings(&[
        "export",
        "--model",
        "mfnet",
        "--weights",
        s(weights),
        "--out",
        s(out),
        "--format",
        "torchscript",
        "--size",
        "32x32",
    ]);
    if let Some(n) = classes {
        args.extend(strings(&["--classes", n]));
    }
    args
}

/// The exported file exists and does not carry MF's class names (the class count alone
/// does not tell them).
fn not_mf_names(out: &Path) -> Box<dyn Fn() -> bool> {
    let out = out.to_path_buf();
    Box::new(move || {
        let Ok(bytes) = std::fs::read(&out) else {
            return false;
        };
        !bytes.windows(8).any(|w| w == b"car_stop")
    })
}

/// A folder nobody may write to: a 0555 folder, or (as root, whom modes do not stop) /sys.
fn read_only(f: &Fixture) -> Option<PathBuf> {
    use std::os::unix::fs::PermissionsExt;
    let dir = f.t.join("ex_readonly");
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::set_permissions(&dir, std::fs::Permissions::from_mode(0o555)).unwrap();
    let writable = |d: &Path| std::fs::write(d.join("probe"), b"").is_ok();
    if !writable(&dir) {
        return Some(dir);
    }
    std::fs::remove_file(dir.join("probe")).unwrap();
    let sys = PathBuf::from("/sys");
    (!writable(&sys)).then_some(sys)
}

pub fn cases(f: &Fixture) -> Vec<Case> {
    let (three, nine) = (weights_of(f, 3), weights_of(f, 9));
    let out = |n: &str| f.t.join(format!("ex_{n}.pt"));
    let mut cases = vec![
        // The weights record their 3 classes (issue 26), so no --classes is needed.
        recovers_of(
            "export: 3-class weights without --classes (the weights' record)",
            export(&three, &out("a"), None),
            not_mf_names(&out("a")),
        ),
        recovers_of(
            "export: 3-class weights with --classes 3",
            export(&three, &out("b"), Some("3")),
            not_mf_names(&out("b")),
        ),
        recovers_of(
            "export: 9 own classes (not MF's) with --classes 9",
            export(&nine, &out("c"), Some("9")),
            not_mf_names(&out("c")),
        ),
        case_of(
            "export: --classes 5 for 3-class weights",
            export(&three, &out("d"), Some("5")),
            &["final.safetensors"],
        ),
    ];
    let original = std::fs::read(&three).unwrap();
    let kept = three.clone();
    cases.push(
        case_of(
            "export: --out is its own weights file",
            export(&three, &three, Some("3")),
            &["final.safetensors"],
        )
        .intact(move || std::fs::read(&kept).unwrap() == original),
    );
    cases.push(case_of(
        "export: --out is a folder",
        export(&three, &f.t, Some("3")),
        &[s(&f.t)],
    ));
    match read_only(f) {
        Some(dir) => {
            let target = dir.join("net.pt");
            let args = export(&three, &target, Some("3"));
            cases.push(case_of(
                "export: --out in a read-only folder",
                args,
                &[s(&target)],
            ));
        }
        None => {
            eprintln!("hostile: SKIP export into a read-only folder (no folder is read-only here)")
        }
    }
    cases
}

fn case_of(name: &str, args: Vec<String>, must: &[&str]) -> Case {
    let refs: Vec<&str> = args.iter().map(String::as_str).collect();
    case(name, &refs, must)
}

fn recovers_of(name: &str, args: Vec<String>, check: Box<dyn Fn() -> bool>) -> Case {
    let refs: Vec<&str> = args.iter().map(String::as_str).collect();
    recovers(name, &refs, &[], check)
}
