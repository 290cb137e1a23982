use std::time::Instant;
use tch::{Device, Kind, Tensor};
fn cl(x: Tensor) -> Tensor {
    rtf_models::layers::to_channels_last(&x)
}
fn time<F: FnMut()>(name: &str, mut f: F) {
    for _ in 0..5 {
        f();
    }
    let n = 50;
    let t = Instant::now();
    for _ in 0..n {
        f();
    }
    println!(
        "{name}: {:.3} ms",
        t.elapsed().as_secs_f64() * 1e3 / n as f64
    );
}
fn main() {
    tch::set_num_threads(2);
    let _g = tch::no_grad_guard();
    for k in [Kind::BFloat16, Kind::Float] {
        for (c, ca, h, w) in [(64i64, 48i64, 240i64, 320i64), (64, 48, 120, 160)] {
            let x = cl(Tensor::randn([1, c, h / 2, w / 2], (k, Device::Cpu)));
            let a = cl(Tensor::randn([1, ca, h, w], (k, Device::Cpu)));
            let b = cl(Tensor::randn([1, c - ca, h, w], (k, Device::Cpu)));
            let r1 = x.upsample_nearest2d([h, w], 2.0, 2.0) + Tensor::cat(&[&a, &b], 1);
            let f2 = || {
                let y = Tensor::cat(&[&a, &b], 1);
                let mut v = y.view([1, c, h / 2, 2, w / 2, 2]);
                let _ = v.g_add_(&x.unsqueeze(3).unsqueeze(5));
                y
            };
            assert!(f2().equal(&r1));
            time(&format!("{k:?} {h}x{w} up+cat+add"), || {
                let _ = x.upsample_nearest2d([h, w], 2.0, 2.0) + Tensor::cat(&[&a, &b], 1);
            });
            time(&format!("{k:?} {h}x{w} cat then broadcast add_"), || {
                let _ = f2();
            });
        }
    }
}
