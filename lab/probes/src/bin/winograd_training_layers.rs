//! The training form per layer shape: one 3×3 convolution (stride 1, padding 1, C → C, batch
//! 4, channels-last float32) forward, and its backward pass (input and weight gradients), by
//! libtorch's convolution (oneDNN's direct kernels) against `winograd::conv3x3_f43_train`. The
//! shapes are RTFNet-50's 3×3 layers in training at 640×480: its encoders' (64 channels at
//! 120×160 to 512 at 15×20) and its decoder's Upception blocks (2048 at 15×20 to 128 at
//! 240×320). Best of 3 passes, two rounds interleaved; the largest relative difference of the
//! weight gradient from the direct one is printed beside.
//!
//! `cargo run --release -p rtf-lab --bin winograd_training_layers [-- THREADS]` (default 2
//! threads). Results and the machine they came from: docs/src/speed-by-kind.md (issue 41).
use std::time::Instant;

use rtf_kernels::winograd;
use tch::{Device, Kind, Tensor};

/// Best wall time of `reps` calls, in ms.
fn best_ms(f: &dyn Fn(), reps: usize) -> f64 {
    (0..reps)
        .map(|_| {
            let t = Instant::now();
            f();
            t.elapsed().as_secs_f64() * 1e3
        })
        .fold(f64::MAX, f64::min)
}

/// (forward ms, backward ms, weight gradient) of `conv` on fresh leaves (the timed backward
/// passes accumulate into the gradients, the same extra add for both).
fn time(
    conv: &dyn Fn(&Tensor, &Tensor) -> Tensor,
    x: &Tensor,
    w: &Tensor,
    upstream: &Tensor,
) -> (f64, f64, Tensor) {
    let leaf = |t: &Tensor| t.detach().copy().set_requires_grad(true);
    let (x, w) = (leaf(x), leaf(w));
    let forward = best_ms(&|| drop(tch::no_grad(|| conv(&x, &w))), 3);
    let loss = |x: &Tensor, w: &Tensor| (conv(x, w) * upstream).sum(Kind::Float);
    let backward = best_ms(&|| loss(&x, &w).backward(), 3) - forward;
    let (x, w) = (leaf(&x), leaf(&w));
    loss(&x, &w).backward();
    (forward, backward, w.grad())
}

fn main() {
    let threads = std::env::args()
        .nth(1)
        .and_then(|t| t.parse().ok())
        .unwrap_or(2);
    tch::set_num_threads(threads);
    let shapes = [
        (64, 120, 160),
        (128, 60, 80),
        (256, 30, 40),
        (512, 15, 20),
        (2048, 15, 20),
        (1024, 30, 40),
        (512, 60, 80),
        (256, 120, 160),
        (128, 240, 320),
    ];
    println!("C, HxW (batch 4): direct fwd / bwd ms | F(4x4,3x3) fwd / bwd ms | dW rel. diff");
    for round in 0..2 {
        for &(c, h, w) in &shapes {
            let x = Tensor::randn([4, h, w, c], (Kind::Float, Device::Cpu)).permute([0, 3, 1, 2]);
            let weight = Tensor::randn([c, c, 3, 3], (Kind::Float, Device::Cpu)) * 0.01;
            let direct = |x: &Tensor, w: &Tensor| x.conv2d(w, None::<Tensor>, [1], [1], [1], 1);
            let upstream = x.randn_like();
            let (df, db, dw) = time(&direct, &x, &weight, &upstream);
            let (wf, wb, ww) = time(&winograd::conv3x3_f43_train, &x, &weight, &upstream);
            let scale = dw.abs().max().double_value(&[]);
            let diff = (&dw - &ww).abs().max().double_value(&[]) / scale;
            println!(
                "round {round} {c:4} {h:3}x{w:<3}: {df:7.1} / {db:7.1} | {wf:7.1} / {wb:7.1} | {diff:.1e}"
            );
        }
    }
}
