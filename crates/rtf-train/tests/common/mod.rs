//! The tiny dataset the training tests share.

use std::path::Path;

/// Writes `count` random 32×32 MF-layout frames (RGBA, thermal in alpha; label "hot pixel =
/// person"), even indices day (`D`), odd night (`N`), from `seed`; returns their names. With
/// `undecodable_night_labels` the night label files are not PNGs, so a run that decodes one
/// fails. The caller writes the split files.
pub fn write_frames(
    root: &Path,
    count: usize,
    seed: u32,
    undecodable_night_labels: bool,
) -> Vec<String> {
    std::fs::create_dir_all(root.join("images")).unwrap();
    std::fs::create_dir_all(root.join("labels")).unwrap();
    let mut state = seed;
    let mut next = move || {
        state = state.wrapping_mul(1664525).wrapping_add(1013904223);
        (state >> 24) as u8
    };
    let names: Vec<String> = (0..count)
        .map(|i| format!("{i:05}{}", if i % 2 == 0 { 'D' } else { 'N' }))
        .collect();
    for name in &names {
        let mut image = image::RgbaImage::new(32, 32);
        let mut label = image::GrayImage::new(32, 32);
        for (x, y, p) in image.enumerate_pixels_mut() {
            *p = image::Rgba([next(), next(), next(), next()]);
            label.put_pixel(x, y, image::Luma([if p.0[3] > 128 { 2 } else { 0 }]));
        }
        image
            .save(root.join("images").join(format!("{name}.png")))
            .unwrap();
        let label_path = root.join("labels").join(format!("{name}.png"));
        if undecodable_night_labels && name.ends_with('N') {
            std::fs::write(&label_path, b"not a png: night labels must not be read").unwrap();
        } else {
            label.save(&label_path).unwrap();
        }
    }
    names
}

/// A randomly initialised MFNet saved as an RGB teacher (its file records the inputs).
#[allow(dead_code)] // not every test binary has a teacher
pub fn teacher(dir: &Path, seed: i64) -> rtf_train::config::TeacherRef {
    tch::manual_seed(seed);
    let vs = tch::nn::VarStore::new(tch::Device::Cpu);
    let model = rtf_models::ModelConfig::from_name("mfnet", 9).unwrap();
    rtf_models::build(&vs.root(), &model).unwrap();
    let path = dir.join(format!("teacher{seed}.safetensors"));
    rtf_models::io::weights::save_safetensors(&vs, &model, rtf_train::Modality::Rgb, &path)
        .unwrap();
    rtf_train::config::TeacherRef::Weights {
        path,
        model,
        inputs: rtf_train::Modality::Rgb,
    }
}

/// `count` frames from `seed` in `root`, the first `train` of them the `train` split and the
/// rest `val`.
#[allow(dead_code)]
pub fn write_split_dataset(root: &Path, count: usize, seed: u32, train: usize) {
    let names = write_frames(root, count, seed, false);
    std::fs::write(root.join("train.txt"), names[..train].join("\n")).unwrap();
    std::fs::write(root.join("val.txt"), names[train..].join("\n")).unwrap();
}

/// Every tensor of a safetensors file as bytes, by name (the metadata, which holds the run's
/// config, left out): two runs are bit-identical when these are equal.
#[allow(dead_code)]
pub fn weights(path: &Path) -> Vec<(String, Vec<u8>)> {
    let bytes = std::fs::read(path).unwrap();
    let st = safetensors::SafeTensors::deserialize(&bytes).unwrap();
    let mut named: Vec<_> = st
        .tensors()
        .into_iter()
        .map(|(n, v)| (n, v.data().to_vec()))
        .collect();
    named.sort_by(|a, b| a.0.cmp(&b.0));
    named
}

/// The bf16 convolutions this test process is asked to train with: `RTF_BF16_CONVOLUTIONS` and
/// oneDNN's ISA cap (`cargo xtask test` sets them for its passes), resolved as rtf's binaries
/// resolve them at their edge. The test reads its environment; the library does not.
#[allow(dead_code)] // not every test binary trains bf16
pub fn bf16_convolutions() -> rtf_amp::Bf16Convolutions {
    rtf_amp::Bf16Policy::from_vars(|var| std::env::var(var).ok())
        .expect("RTF_BF16_CONVOLUTIONS")
        .in_force(None)
}
