//! Fingerprints of the fast path's logits for every network family, precision, layout and
//! kernel choice, to show that a change to folding leaves them bit for bit as they were
//! (issue 61: "logits bit-identical to today's fast path").
//!
//! `cargo run --release -p rtf-lab --bin fold_golden -- write FILE` records them (seeded
//! weights and input, 2 threads); `... -- check FILE` recomputes and lists every case whose
//! logits differ in any bit. Both on the same machine: oneDNN picks kernels per CPU kind.
use std::collections::BTreeMap;
use std::hash::{Hash, Hasher};

use rtf_amp::Bf16Convolutions;
use rtf_kernels::winograd::Forms;
use rtf_models::fast::{FoldOptions, InferenceKernels, InferenceNet, Layout, Precision};
use rtf_models::ModelConfig;
use tch::{Device, Kind, Tensor};

const NETWORKS: [&str; 15] = [
    "mfnet",
    "rtfnet18",
    "rtfnet18-nub",
    "rtfnet18-fci",
    "rtfnet50",
    "heatnet",
    "heatnet-ir",
    "unet-4c",
    "pspnet-4c",
    "segnet-4c",
    "duchdc-4c",
    "fusenet",
    "erfnet-4c",
    "enet-4c",
    "cmx-mit-b0",
];

/// The bits of `t` (float32 NCHW logits), hashed.
fn fingerprint(t: &Tensor) -> String {
    let t = t.to_kind(Kind::Float).contiguous();
    let values = Vec::<f32>::try_from(t.flatten(0, -1)).expect("float logits");
    let mut h = std::collections::hash_map::DefaultHasher::new();
    for v in &values {
        v.to_bits().hash(&mut h);
    }
    format!("{:016x} n={}", h.finish(), values.len())
}

/// The cases: precision × layout × kernels (bf16 convolutions emulated or native), released
/// or not.
fn cases() -> Vec<(String, FoldOptions, bool)> {
    let mut out = Vec::new();
    let mut push = |precision, layout, winograd, bf16_winograd, emulated, release| {
        let bf16_convolutions = match emulated {
            true => Bf16Convolutions::Emulated,
            false => Bf16Convolutions::Native,
        };
        let kernels = InferenceKernels {
            winograd,
            bf16_winograd,
            bf16_convolutions,
        };
        let options = FoldOptions::new(precision).layout(layout).kernels(kernels);
        let name = format!(
            "{precision} {layout:?} {winograd:?} bf16w={bf16_winograd} emulated={emulated} release={release}"
        );
        out.push((name, options, release));
    };
    for layout in [Layout::ChannelsLast, Layout::Nchw] {
        for winograd in [Forms::All, Forms::Off] {
            push(Precision::Fp32, layout, winograd, false, false, false);
        }
    }
    push(
        Precision::Fp32,
        Layout::ChannelsLast,
        Forms::All,
        false,
        false,
        true,
    );
    for winograd in [Forms::All, Forms::Off] {
        for bf16_winograd in [false, true] {
            for emulated in [false, true] {
                push(
                    Precision::Bf16,
                    Layout::ChannelsLast,
                    winograd,
                    bf16_winograd,
                    emulated,
                    false,
                );
            }
        }
    }
    push(
        Precision::Bf16,
        Layout::Nchw,
        Forms::All,
        false,
        false,
        false,
    );
    push(
        Precision::Bf16,
        Layout::ChannelsLast,
        Forms::All,
        false,
        false,
        true,
    );
    push(
        Precision::Bf16,
        Layout::ChannelsLast,
        Forms::All,
        true,
        true,
        true,
    );
    out
}

/// One network's logits under `options`: built with seeded weights, folded, released or not.
fn logits(name: &str, options: &FoldOptions, release: bool) -> Tensor {
    tch::manual_seed(7);
    let cfg = ModelConfig::from_name(name, 9).expect("known network");
    let vs = tch::nn::VarStore::new(Device::Cpu);
    let net = rtf_models::build(&vs.root(), &cfg).expect("builds");
    let m = net.size_multiple().max(16);
    let x = Tensor::rand([1, 4, 2 * m, 3 * m], (Kind::Float, Device::Cpu));
    let fast = if release {
        InferenceNet::releasing_plain_weights(net, options, &vs)
            .expect("folds")
            .0
    } else {
        InferenceNet::fold(net, options).expect("folds")
    };
    fast.forward(&x).expect("forward")
}

fn compute() -> BTreeMap<String, String> {
    let mut out = BTreeMap::new();
    for name in NETWORKS {
        for (case, options, release) in cases() {
            let fp = std::panic::catch_unwind(|| fingerprint(&logits(name, &options, release)))
                .unwrap_or_else(|_| "refused".into());
            out.insert(format!("{name} | {case}"), fp);
        }
        eprintln!("{name} done");
    }
    out
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let (mode, file) = match args.as_slice() {
        [mode, file] if mode == "write" || mode == "check" => (mode.as_str(), file),
        _ => return Err("usage: fold_golden write|check FILE".into()),
    };
    tch::set_num_threads(1);
    let now = compute();
    if mode == "write" {
        std::fs::write(file, serde_json::to_string_pretty(&now)?)?;
        println!("{} cases written to {file}", now.len());
        return Ok(());
    }
    let before: BTreeMap<String, String> = serde_json::from_str(&std::fs::read_to_string(file)?)?;
    let differ: Vec<_> = before
        .iter()
        .filter(|(case, fp)| now.get(*case) != Some(*fp))
        .collect();
    for (case, fp) in &differ {
        println!("DIFFERS {case}: {fp} -> {:?}", now.get(*case));
    }
    println!("{} of {} cases differ", differ.len(), before.len());
    if differ.is_empty() {
        Ok(())
    } else {
        Err("logits changed".into())
    }
}
