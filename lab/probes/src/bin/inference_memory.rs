//! Where the fast path's memory goes, phase by phase: resident memory (Linux `VmRSS`) after
//! building the network, after folding it (releasing its plain weights as rtf's commands do,
//! `InferenceNet::releasing_plain_weights`), and after each forward pass (with its time), with
//! the process's peak (`VmHWM`). Random weights, a random input, batch 1.
//!
//! `cargo run --release -p rtf-lab --bin inference_memory -- MODEL [fp32|bf16]
//! [WIDTHxHEIGHT] [THREADS] [keep]` (default fp32, 640x480, 2 threads; `keep` skips the
//! release, for the same phases without it). Results: docs/src/speed-by-kind.md.
use rtf_models::fast::{FoldOptions, InferenceNet, Layout, Precision};
use rtf_models::ModelConfig;
use tch::{Device, Kind, Tensor};

/// (VmRSS, VmHWM) of this process in MiB.
fn rss_and_peak_mib() -> (f64, f64) {
    let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    let field = |name: &str| {
        status
            .lines()
            .find(|l| l.starts_with(name))
            .and_then(|l| l.split_whitespace().nth(1))
            .and_then(|kib| kib.parse::<f64>().ok())
            .map_or(f64::NAN, |kib| kib / 1024.0)
    };
    (field("VmRSS:"), field("VmHWM:"))
}

fn report(phase: &str) {
    let (rss, peak) = rss_and_peak_mib();
    println!("{phase:<28} RSS {rss:>7.0} MiB   peak {peak:>7.0} MiB");
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let model = args.first().map_or("rtfnet50", String::as_str);
    let precision = match args.get(1).map(String::as_str) {
        Some("bf16") => Precision::Bf16,
        _ => Precision::Fp32,
    };
    let (width, height) = args
        .get(2)
        .and_then(|s| s.split_once('x'))
        .and_then(|(w, h)| Some((w.parse::<i64>().ok()?, h.parse::<i64>().ok()?)))
        .unwrap_or((640, 480));
    tch::set_num_threads(args.get(3).and_then(|t| t.parse().ok()).unwrap_or(2));
    let keep = args.iter().any(|a| a == "keep");
    println!(
        "{model} {precision} {width}x{height}, plain weights {}",
        if keep { "kept" } else { "released" }
    );

    tch::manual_seed(0);
    let vs = tch::nn::VarStore::new(Device::Cpu);
    let cfg = ModelConfig::from_name(model, rtf_models::default_num_classes(model))?;
    let net = rtf_models::build(&vs.root(), &cfg)?;
    report("built");
    let fast = if keep {
        let fast = InferenceNet::with_layout(net, precision, Layout::ChannelsLast)?;
        report("folded");
        fast
    } else {
        let (fast, released) =
            InferenceNet::releasing_plain_weights(net, &FoldOptions::new(precision), &vs)?;
        report(&format!("folded, {:.0} MiB released", released.mib()));
        fast
    };
    let input = Tensor::rand([1, 4, height, width], (Kind::Float, Device::Cpu));
    for pass in 1..=5 {
        let start = std::time::Instant::now();
        let _ = fast.forward(&input)?;
        let ms = start.elapsed().as_secs_f64() * 1e3;
        report(&format!("after pass {pass} ({ms:.1} ms)"));
    }
    Ok(())
}
