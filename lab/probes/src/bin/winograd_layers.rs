//! Where the F(4×4, 3×3) form's time goes, per layer shape: one 3×3 convolution (stride 1,
//! padding 1, C → C channels, batch 1, channels-last float32) by libtorch's convolution
//! (oneDNN's direct kernels, what the fast path runs below `winograd::MIN_CHANNELS_F43`)
//! against `winograd::conv3x3`, and the form's 36 products alone (`bmm` of the transformed
//! maps by the transformed weights). The shapes are RTFNet-18's and RTFNet-50's 3×3 layers at
//! 480×640 (64 channels at 120×160 down to 512 at 15×20). Best of 20 passes, three rounds
//! interleaved; the largest difference from the direct convolution is printed beside.
//!
//! `cargo run --release -p rtf-lab --bin winograd_layers [-- THREADS] [bf16]` (default
//! 2 threads; `bf16` adds each shape over bf16 maps: oneDNN's bf16 kernels against the form).
//! Results and the machine they came from: docs/src/speed-by-kind.md (issue 41).
use std::time::Instant;

use rtf_kernels::winograd::{self, Form};
use tch::{Device, Kind, Tensor};

/// Best wall time of `reps` calls, in ms.
fn best_ms(f: &dyn Fn() -> Tensor, reps: usize) -> f64 {
    (0..reps)
        .map(|_| {
            let t = Instant::now();
            let _ = f();
            t.elapsed().as_secs_f64() * 1e3
        })
        .fold(f64::MAX, f64::min)
}

/// A random [1, C, H, W] map laid out channels-last, as the fast path keeps its maps.
fn channels_last(size: [i64; 4]) -> Tensor {
    let [n, c, h, w] = size;
    Tensor::randn([n, h, w, c], (Kind::Float, Device::Cpu)).permute([0, 3, 1, 2])
}

fn main() {
    let threads = std::env::args()
        .nth(1)
        .and_then(|t| t.parse().ok())
        .unwrap_or(2);
    tch::set_num_threads(threads);
    let bf16 = std::env::args().any(|a| a == "bf16");
    let _no_grad = tch::no_grad_guard();
    println!(
        "{threads} threads; ms, best of 20; direct | F(4x4,3x3) (max |diff|) | products alone"
    );
    for (c, h, w) in [(64, 120, 160), (128, 60, 80), (256, 30, 40), (512, 15, 20)] {
        let x = channels_last([1, c, h, w]);
        let weight = channels_last([c, c, 3, 3]) * (2.0 / (9.0 * c as f64)).sqrt();
        let u = winograd::weight_transform(&weight, Form::F43);
        let tiles = ((h + 3) / 4) * ((w + 3) / 4);
        let v = Tensor::randn([36, tiles, c], (Kind::Float, Device::Cpu));
        let direct = || x.conv2d(&weight, None::<Tensor>, [1, 1], [1, 1], [1, 1], 1);
        let form = || winograd::conv3x3(&x, &u, None, None, false);
        let products = || v.bmm(&u);
        let diff = (form() - direct()).abs().max().double_value(&[]);
        let rounds: Vec<String> = (0..3)
            .map(|_| {
                let (d, f, p) = (
                    best_ms(&direct, 20),
                    best_ms(&form, 20),
                    best_ms(&products, 20),
                );
                format!("{d:.2} | {f:.2} | {p:.2}")
            })
            .collect();
        println!(
            "{c:>3} ch {h}x{w} (max |diff| {diff:.1e}): {}",
            rounds.join("   ")
        );
        if bf16 {
            // Over bf16 maps: oneDNN's bf16 kernels against the form (float arithmetic).
            let (xb, wb) = (x.to_kind(Kind::BFloat16), weight.to_kind(Kind::BFloat16));
            let direct = || xb.conv2d(&wb, None::<Tensor>, [1, 1], [1, 1], [1, 1], 1);
            let form = || winograd::conv3x3(&xb, &u, None, None, false);
            let rounds: Vec<String> = (0..3)
                .map(|_| format!("{:.2} | {:.2}", best_ms(&direct, 20), best_ms(&form, 20)))
                .collect();
            println!("    bf16 maps: {}", rounds.join("   "));
        }
    }
}
