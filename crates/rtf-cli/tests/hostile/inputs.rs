//! The catalogue of issue 15: bad images, outputs, weights and datasets for `predict`,
//! `eval` and `data`, and huge frames under `ulimit -v`.

use std::path::{Path, PathBuf};

use crate::common::*;
use crate::verdict::{case, copy_dir, run_limited, Case};
use crate::Fixture;

/// The check of a refusal: nothing written into `dir`.
pub fn nothing_written(dir: PathBuf) -> Box<dyn Fn() -> bool> {
    Box::new(move || !dir.exists() || std::fs::read_dir(&dir).unwrap().count() == 0)
}

/// A copy of the fixture's dataset at `t/name`, changed by `mutate`.
fn variant(f: &Fixture, name: &str, mutate: &dyn Fn(&Path)) -> PathBuf {
    let root = f.t.join(name);
    copy_dir(&f.data, &root);
    mutate(&root);
    root
}

/// A copy of a safetensors file with its header edited by `edit` (JSON) and its data by
/// `data` (given the header); the header keeps its byte length where the edit does.
fn edit_safetensors(
    from: &Path,
    to: &Path,
    edit: impl Fn(&mut serde_json::Value),
    data: impl Fn(&serde_json::Value, &mut [u8]),
) {
    let bytes = std::fs::read(from).unwrap();
    let n = u64::from_le_bytes(bytes[..8].try_into().unwrap()) as usize;
    let mut header: serde_json::Value = serde_json::from_slice(&bytes[8..8 + n]).unwrap();
    let mut body = bytes[8 + n..].to_vec();
    data(&header, &mut body);
    edit(&mut header);
    let mut text = serde_json::to_vec(&header).unwrap();
    while text.len() & 7 != 0 {
        text.push(b' ');
    }
    let mut out = (text.len() as u64).to_le_bytes().to_vec();
    out.extend(text);
    out.extend(body);
    std::fs::write(to, out).unwrap();
}

/// An RGBA PNG of constant colour (compresses to almost nothing, however large).
fn flat_rgba(path: &Path, w: u32, h: u32) {
    image::RgbaImage::from_pixel(w, h, image::Rgba([90, 120, 150, 100]))
        .save(path)
        .unwrap();
}

/// The smallest address-space limit (of a few) under which a tiny predict runs: libtorch's
/// own mappings (CUDA builds map several GB) come first.
fn working_limit(weights: &Path, image: &Path, out: &Path) -> Option<u64> {
    (2..=16)
        .map(|half_gib| half_gib as u64 * (1 << 29))
        .find(|&limit| {
            let args: Vec<String> = [
                "predict",
                "--weights",
                s(weights),
                "--out",
                s(out),
                s(image),
            ]
            .iter()
            .map(|a| a.to_string())
            .collect();
            run_limited(&args, Some(limit)).status.success()
        })
}

fn first_line(path: &Path) -> String {
    std::fs::read_to_string(path)
        .unwrap()
        .lines()
        .next()
        .unwrap()
        .trim()
        .to_string()
}

/// predict: images (truncated, text, empty, channels, 16-bit, directory, missing, thermal partners)
pub fn predict_images(f: &Fixture) -> Vec<Case> {
    let (t, data, weights, good_image, frame) =
        (&f.t, &f.data, &f.weights, &f.good_image, f.frame.clone());
    let _ = (data, &frame, t);
    let p = |name: &str| t.join(name);
    let out = p("out");
    let w = s(weights);
    let o = s(&out);
    let _ = (w, o, good_image);
    let mut cases: Vec<Case> = Vec::new();
    // --- predict: images ---
    let bytes = std::fs::read(good_image).unwrap();
    std::fs::write(p("truncated.png"), &bytes[..bytes.len() / 2]).unwrap();
    std::fs::write(p("text.png"), b"this is not a PNG").unwrap();
    std::fs::write(p("empty.png"), b"").unwrap();
    image::RgbImage::new(32, 32).save(p("rgb3.png")).unwrap();
    image::GrayImage::new(32, 32).save(p("grey.png")).unwrap();
    image::ImageBuffer::<image::Rgba<u16>, Vec<u16>>::new(32, 32)
        .save(p("rgba16.png"))
        .unwrap();
    std::fs::create_dir_all(p("dir.png")).unwrap();
    let w = s(weights);
    let o = s(&out);
    for (name, file) in [
        ("predict: truncated PNG", "truncated.png"),
        ("predict: text named .png", "text.png"),
        ("predict: empty file", "empty.png"),
        ("predict: RGB (3 channels) where RGBA", "rgb3.png"),
        ("predict: grey (1 channel) where RGBA", "grey.png"),
        ("predict: 16-bit RGBA", "rgba16.png"),
        ("predict: directory named .png", "dir.png"),
        ("predict: missing image", "absent.png"),
    ] {
        let path = p(file);
        cases.push(case(
            name,
            &["predict", "--weights", w, "--out", o, s(&path)],
            &[file],
        ));
    }
    // Separate RGB + thermal files.
    image::RgbImage::new(32, 32).save(p("cam_rgb.png")).unwrap();
    image::GrayImage::new(16, 16)
        .save(p("small_ir.png"))
        .unwrap();
    // Colour (channels differ): a colour-mapped rendering; grey stored as RGB is read.
    image::RgbImage::from_fn(32, 32, |x, y| image::Rgb([x as u8, y as u8, 7]))
        .save(p("rgb_ir.png"))
        .unwrap();
    cases.push(case(
        "predict: thermal of another size",
        &[
            "predict",
            "--weights",
            w,
            "--out",
            o,
            "--rgb",
            s(&p("cam_rgb.png")),
            "--thermal",
            s(&p("small_ir.png")),
        ],
        &["small_ir.png", "cam_rgb.png"],
    ));
    cases.push(case(
        "predict: colour-mapped 3-channel thermal",
        &[
            "predict",
            "--weights",
            w,
            "--out",
            o,
            "--rgb",
            s(&p("cam_rgb.png")),
            "--thermal",
            s(&p("rgb_ir.png")),
        ],
        &["rgb_ir.png", "differ"],
    ));
    cases
}

/// predict: outputs (same stem twice, overlapping outputs, the input folder, a file)
pub fn predict_outputs(f: &Fixture) -> Vec<Case> {
    let (t, data, weights, good_image, frame) =
        (&f.t, &f.data, &f.weights, &f.good_image, f.frame.clone());
    let _ = (data, &frame, t);
    let p = |name: &str| t.join(name);
    let out = p("out");
    let w = s(weights);
    let o = s(&out);
    let _ = (w, o, good_image);
    let mut cases: Vec<Case> = Vec::new();
    // Outputs: name collisions and inputs overwritten.
    for d in ["a", "b"] {
        std::fs::create_dir_all(p(d)).unwrap();
        std::fs::copy(good_image, p(d).join("x.png")).unwrap();
    }
    std::fs::copy(good_image, p("a").join("x_color.png")).unwrap();
    let mut c = case(
        "predict: two inputs with one stem",
        &[
            "predict",
            "--weights",
            w,
            "--out",
            s(&p("o1")),
            s(&p("a/x.png")),
            s(&p("b/x.png")),
        ],
        &["a/x.png", "b/x.png", "o1/x.png"],
    );
    c.intact = Some(nothing_written(p("o1")));
    cases.push(c);
    let mut c = case(
        "predict: x.png + x_color.png (outputs overlap)",
        &[
            "predict",
            "--weights",
            w,
            "--out",
            s(&p("o2")),
            s(&p("a/x.png")),
            s(&p("a/x_color.png")),
        ],
        &["x_color.png"],
    );
    c.intact = Some(nothing_written(p("o2")));
    cases.push(c);
    let original = std::fs::read(p("a/x.png")).unwrap();
    let a_x = p("a/x.png");
    let mut c = case(
        "predict: --out = the input's folder",
        &["predict", "--weights", w, "--out", s(&p("a")), s(&a_x)],
        &["a/x.png", "overwrite"],
    );
    c.intact = Some(Box::new(move || {
        std::fs::read(&a_x).unwrap() == original && !a_x.with_file_name("x_color.png.tmp").exists()
    }));
    cases.push(c);
    std::fs::write(p("outfile"), b"").unwrap();
    cases.push(case(
        "predict: --out is a file",
        &[
            "predict",
            "--weights",
            w,
            "--out",
            s(&p("outfile")),
            s(good_image),
        ],
        &["outfile"],
    ));

    cases
}

/// predict + eval: weights (NaN, -inf, I32, another network, truncated, zip, empty, directory, missing)
pub fn weights(f: &Fixture) -> Vec<Case> {
    let (t, data, weights, good_image, frame) =
        (&f.t, &f.data, &f.weights, &f.good_image, f.frame.clone());
    let _ = (data, &frame, t);
    let p = |name: &str| t.join(name);
    let out = p("out");
    let w = s(weights);
    let o = s(&out);
    let _ = (w, o, good_image);
    let mut cases: Vec<Case> = Vec::new();
    // --- weights (predict and eval) ---
    let nan = p("nan.safetensors");
    let target = "decode1.conv.weight";
    let poison = |value: f32| {
        move |h: &serde_json::Value, body: &mut [u8]| {
            let start = h[target]["data_offsets"][0].as_u64().unwrap() as usize;
            body[start..start + 4].copy_from_slice(&value.to_le_bytes());
        }
    };
    edit_safetensors(weights, &nan, |_| {}, poison(f32::NAN));
    let inf = p("inf.safetensors");
    edit_safetensors(weights, &inf, |_| {}, poison(f32::NEG_INFINITY));
    let int = p("int.safetensors");
    edit_safetensors(
        weights,
        &int,
        |h| h[target]["dtype"] = "I32".into(),
        |_, _| {},
    );
    let bytes = std::fs::read(weights).unwrap();
    std::fs::write(p("truncated.safetensors"), &bytes[..bytes.len() - 4096]).unwrap();
    std::fs::write(p("cut_header.safetensors"), &bytes[..100]).unwrap();
    std::fs::write(
        p("zip.safetensors"),
        b"PK\x03\x04\x14\x00\x00\x00\x08\x00 archive",
    )
    .unwrap();
    std::fs::write(p("empty.safetensors"), b"").unwrap();
    std::fs::create_dir_all(p("dir.safetensors")).unwrap();
    let weight_cases: Vec<(&str, PathBuf, Vec<&str>, &str)> = vec![
        (
            "one NaN weight",
            nan,
            vec!["nan.safetensors", target, "NaN"],
            "mfnet",
        ),
        (
            "one -inf weight",
            inf,
            vec!["inf.safetensors", target, "infinite"],
            "mfnet",
        ),
        (
            "integer (I32) tensor",
            int,
            vec!["int.safetensors", target, "I32"],
            "mfnet",
        ),
        (
            "mfnet weights as mfnet-f",
            weights.clone(),
            vec!["final.safetensors", "`mfnet`", "`mfnet-f`"],
            "mfnet-f",
        ),
        (
            "mfnet weights as mfnet-j",
            weights.clone(),
            vec!["final.safetensors", "`mfnet-j`"],
            "mfnet-j",
        ),
        (
            "truncated safetensors",
            p("truncated.safetensors"),
            vec!["truncated.safetensors", "truncated"],
            "mfnet",
        ),
        (
            "header cut short",
            p("cut_header.safetensors"),
            vec!["cut_header.safetensors", "truncated"],
            "mfnet",
        ),
        (
            "HeaderTooLarge (a zip / .pth)",
            p("zip.safetensors"),
            vec!["zip.safetensors", "not a safetensors file", "convert-pth"],
            "mfnet",
        ),
        (
            "empty weights file",
            p("empty.safetensors"),
            vec!["empty.safetensors"],
            "mfnet",
        ),
        (
            "weights path is a directory",
            p("dir.safetensors"),
            vec!["dir.safetensors", "directory"],
            "mfnet",
        ),
        (
            "missing weights",
            p("absent.safetensors"),
            vec!["absent.safetensors"],
            "mfnet",
        ),
        (
            "weights of another network",
            weights.clone(),
            vec!["final.safetensors"],
            "rtfnet18",
        ),
    ];
    let ow = p("ow");
    for (what, file, names, model) in &weight_cases {
        for command in ["predict", "eval"] {
            let mut args = vec![command, "--model", model, "--weights", s(file)];
            match command {
                "predict" => args.extend(["--out", s(&ow), s(good_image)]),
                _ => args.extend(["--data", s(data)]),
            }
            let mut c = case(&format!("{command}: {what}"), &args, names);
            if command == "predict" {
                c.intact = Some(nothing_written(ow.clone()));
            }
            cases.push(c);
        }
    }

    cases
}

/// eval + data check + fingerprint: datasets
pub fn datasets(f: &Fixture) -> Vec<Case> {
    let (t, data, weights, good_image, frame) =
        (&f.t, &f.data, &f.weights, &f.good_image, f.frame.clone());
    let _ = (data, &frame, t);
    let p = |name: &str| t.join(name);
    let out = p("out");
    let w = s(weights);
    let o = s(&out);
    let _ = (w, o, good_image);
    let mut cases: Vec<Case> = Vec::new();
    // --- eval and data check: datasets ---
    let variant = |name: &str, mutate: &dyn Fn(&Path)| variant(f, name, mutate);
    let test_frame = frame.clone();
    let odd = variant("odd", &|r| {
        let img = r.join("images").join(format!("{test_frame}.png"));
        flat_rgba(&img, 48, 32);
        image::GrayImage::new(48, 32)
            .save(r.join("labels").join(format!("{test_frame}.png")))
            .unwrap();
    });
    let odd_image = format!("images/{frame}.png");
    cases.push(case(
        "data check: one odd-sized frame",
        &["data", "check", s(&odd)],
        &[&odd_image, "48x32"],
    ));
    cases.push(case(
        "eval: one odd-sized frame",
        &["eval", "--weights", w, "--data", s(&odd)],
        &[&frame, "48x32"],
    ));
    let broken = variant("broken", &|r| {
        std::fs::write(
            r.join("images").join(format!("{test_frame}.png")),
            b"\x89PNG\r\n\x1a\nno",
        )
        .unwrap();
    });
    cases.push(case(
        "data check: truncated image",
        &["data", "check", s(&broken)],
        &[&odd_image],
    ));
    cases.push(case(
        "eval: truncated image",
        &["eval", "--weights", w, "--data", s(&broken)],
        &[&odd_image],
    ));
    let split_dir = variant("splitdir", &|r| {
        std::fs::remove_file(r.join("val.txt")).unwrap();
        std::fs::create_dir(r.join("val.txt")).unwrap();
    });
    cases.push(case(
        "data check: split file is a directory",
        &["data", "check", s(&split_dir)],
        &["val.txt", "directory"],
    ));
    cases.push(case(
        "eval: split file is a directory",
        &[
            "eval",
            "--weights",
            w,
            "--data",
            s(&split_dir),
            "--split",
            "val",
        ],
        &["val"],
    ));
    let image_dir = variant("imagedir", &|r| {
        let img = r.join("images").join(format!("{test_frame}.png"));
        std::fs::remove_file(&img).unwrap();
        std::fs::create_dir(&img).unwrap();
    });
    cases.push(case(
        "data check: image path is a directory",
        &["data", "check", s(&image_dir)],
        &[&odd_image, "directory"],
    ));
    cases.push(case(
        "eval: image path is a directory",
        &["eval", "--weights", w, "--data", s(&image_dir)],
        &[&odd_image],
    ));
    let leak = variant("leak", &|r| {
        let train = first_line(&r.join("train.txt"));
        let mut test = std::fs::read_to_string(r.join("test.txt")).unwrap();
        test.push_str(&format!("{train}\n"));
        std::fs::write(r.join("test.txt"), test).unwrap();
    });
    cases.push(case(
        "data check: a train frame also in test",
        &["data", "check", s(&leak)],
        &["test.txt", "shared between splits"],
    ));
    let copied = variant("copied", &|r| {
        let names: Vec<String> = std::fs::read_to_string(r.join("train.txt"))
            .unwrap()
            .lines()
            .map(|l| l.trim().to_string())
            .collect();
        std::fs::copy(
            r.join("images").join(format!("{}.png", names[0])),
            r.join("images").join(format!("{}.png", names[1])),
        )
        .unwrap();
    });
    cases.push(case(
        "data check: one frame under two names",
        &["data", "check", s(&copied)],
        &["same bytes as"],
    ));
    cases.push(case(
        "data check: a file, not a root",
        &["data", "check", s(weights)],
        &["final.safetensors"],
    ));
    cases.push(case(
        "data fingerprint: not a dataset",
        &["data", "fingerprint", s(&p("a"))],
        &["not a dataset root"],
    ));
    cases.push(case(
        "data fingerprint: a listed frame's image is a directory",
        &["data", "fingerprint", s(&image_dir)],
        &[&frame],
    ));
    cases.push(case(
        "eval: unknown split",
        &[
            "eval",
            "--weights",
            w,
            "--data",
            s(data),
            "--split",
            "nosuch",
        ],
        &["nosuch"],
    ));

    cases
}

/// huge frames under an address-space limit (with RTF_HOSTILE_MEMORY)
pub fn memory(f: &Fixture) -> Vec<Case> {
    let (t, data, weights, good_image, frame) =
        (&f.t, &f.data, &f.weights, &f.good_image, f.frame.clone());
    let _ = (data, &frame, t);
    let p = |name: &str| t.join(name);
    let out = p("out");
    let w = s(weights);
    let o = s(&out);
    let _ = (w, o, good_image);
    let mut cases: Vec<Case> = Vec::new();
    let variant = |name: &str, mutate: &dyn Fn(&Path)| variant(f, name, mutate);
    // --- memory: huge frames under an address-space limit ---
    if std::env::var_os("RTF_HOSTILE_MEMORY").is_some() {
        let base = working_limit(weights, good_image, &p("ok_out"))
            .expect("a tiny predict runs under some limit up to 8 GiB");
        let limit = base + (1 << 30);
        let huge = p("huge_4000x3000.png");
        flat_rgba(&huge, 4000, 3000);
        let mut c = case(
            "predict: 4000x3000 under ulimit -v",
            &["predict", "--weights", w, "--out", s(&p("oh")), s(&huge)],
            &["huge_4000x3000.png", "4000x3000", "--resize"],
        );
        c.limit_as = Some(limit);
        cases.push(c);
        // 2048×2048 is below the size that gets estimated first: libtorch's allocation fails
        // inside the forward pass and is reported, not panicked.
        let big = p("big_2048.png");
        flat_rgba(&big, 2048, 2048);
        let mut c = case(
            "predict: 2048x2048 failing inside the forward pass",
            &["predict", "--weights", w, "--out", s(&p("ob")), s(&big)],
            &["big_2048.png", "2048x2048", "out of memory"],
        );
        c.limit_as = Some(base + (1 << 28));
        cases.push(c);
        let huge_data = variant("hugedata", &|r| {
            for name in std::fs::read_to_string(r.join("test.txt")).unwrap().lines() {
                flat_rgba(
                    &r.join("images").join(format!("{}.png", name.trim())),
                    4000,
                    3000,
                );
                image::GrayImage::new(4000, 3000)
                    .save(r.join("labels").join(format!("{}.png", name.trim())))
                    .unwrap();
            }
        });
        let mut c = case(
            "eval: 4000x3000 frames under ulimit -v",
            &[
                "eval",
                "--weights",
                w,
                "--data",
                s(&huge_data),
                "--split",
                "test",
            ],
            &["4000x3000", "--batch-size"],
        );
        c.limit_as = Some(limit);
        cases.push(c);
    }

    cases
}
