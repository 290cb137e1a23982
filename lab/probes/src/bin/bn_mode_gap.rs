//! Research probe: does a trained network predict the same in training mode (BatchNorm on the
//! batch's statistics) as in evaluation mode (running statistics) on the frames it trained on?
//! A large gap says the evaluation, not the learning, is what fails (docs/src/quick-budget.md).
//!
//! `cargo run --release -p rtf-lab --bin bn_mode_gap -- MODEL WEIGHTS DATA [SPLIT] [BATCH]`
use std::sync::Arc;

use rtf_data::{AugmentConfig, FrameSource, Loader, LoaderConfig, MfDataset};
use rtf_eval::metrics::ConfusionMatrix;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.len() < 3 {
        return Err("usage: bn_mode_gap MODEL WEIGHTS DATA [SPLIT] [BATCH]".into());
    }
    let [model, weights, data] = [&args[0], &args[1], &args[2]];
    let split = args.get(3).map_or("train", String::as_str);
    let batch_size: usize = args.get(4).map_or(Ok(4), |b| b.parse())?;
    let source: Arc<dyn FrameSource> =
        Arc::new(MfDataset::open(std::path::Path::new(data))?.split(split)?);
    let classes = source.class_set().clone();
    let cfg = rtf_models::ModelConfig::from_name(model, classes.len() as i64)?;
    let mut vs = tch::nn::VarStore::new(tch::Device::Cpu);
    let net = rtf_models::build(&vs.root(), &cfg)?;
    let loaded =
        rtf_models::io::weights::load_checked(&mut vs, &cfg, std::path::Path::new(weights), false)?;
    let net = rtf_models::masked(net, loaded.inputs.unwrap_or(rtf_models::Modality::RgbT));
    let loader = Loader::new(
        source.clone(),
        LoaderConfig {
            batch_size,
            shuffle: false,
            drop_last: false,
            seed: 0,
            workers: 0,
            prefetch: 1,
            augment: AugmentConfig::default(),
            resize: None,
        },
        net.input_convention(),
    );
    let names = classes.names();
    let _guard = tch::no_grad_guard();
    for train in [false, true] {
        let mut matrix = ConfusionMatrix::new(classes.len(), classes.ignore_id);
        let mut foreground = (0i64, 0i64);
        for batch in loader.epoch(0) {
            let batch = batch?;
            let ids = net.forward_t(&batch.input, train).argmax(1, false);
            foreground.0 += ids.ne(0).sum(tch::Kind::Int64).int64_value(&[]);
            foreground.1 += ids.numel() as i64;
            for i in 0..batch.names.len() as i64 {
                matrix.update(&batch.target.get(i), &ids.get(i));
            }
        }
        let scores = matrix.compute(&names);
        println!(
            "{:<5} mode on {split}: mIoU {:.1} %, predicted non-background {:.2} % of pixels",
            if train { "train" } else { "eval" },
            100.0 * scores.miou,
            100.0 * foreground.0 as f64 / foreground.1 as f64
        );
    }
    Ok(())
}
