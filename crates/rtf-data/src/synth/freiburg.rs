//! The synthetic Freiburg Thermal layout (spec §5): a training tree of sequences
//! (`train/seq_*/00/{fl_rgb,fl_ir_aligned,fl_rgb_labels}`) and the test layout
//! (`{val,test}/{day,night}/{ImagesRGB,ImagesIR,SegmentationClass}`) with `.npy` labels.

use super::{render_frame, write_provenance, SynthConfig, SynthFrame, SynthSummary};
use crate::pngio::{write_png_u16, write_png_u8};
use crate::DataError;
use rayon::prelude::*;
use std::path::Path;

/// Writes the synthetic Freiburg layout: train frames as a training tree (day labelled, night
/// unlabelled as in the real data); val and test frames as `val/{day,night}` and
/// `test/{day,night}` in the test layout with `.npy` labels (validation never looks at test/).
pub(super) fn write_synthetic(
    out: &Path,
    cfg: &SynthConfig,
    splits: &[(&'static str, Vec<usize>)],
) -> Result<SynthSummary, DataError> {
    let get = |name: &str| {
        splits
            .iter()
            .find(|(n, _)| *n == name)
            .map(|(_, v)| v.clone())
            .unwrap_or_default()
    };
    // Where a frame goes: the training tree, or a labelled layout folder (val/, test/).
    let mut jobs: Vec<(usize, Option<&str>)> =
        get("train").into_iter().map(|i| (i, None)).collect();
    jobs.extend(get("val").into_iter().map(|i| (i, Some("val"))));
    jobs.extend(get("test").into_iter().map(|i| (i, Some("test"))));
    jobs.par_iter().try_for_each(|&(i, layout)| {
        let f = render_frame(cfg, i);
        match layout {
            Some(layout) => write_test_layout_frame(out, layout, &f),
            None => write_training_tree_frame(out, &f),
        }
    })?;
    write_provenance(out, cfg)?;
    let night = |split: &str| get(split).iter().filter(|&&i| i % 2 == 1).count();
    let day = |split: &str| get(split).len() - night(split);
    Ok(SynthSummary {
        frames: cfg.count,
        splits: vec![
            ("train".into(), get("train").len()),
            ("val/day".into(), day("val")),
            ("val/night".into(), night("val")),
            ("test/day".into(), get("test_day").len()),
            ("test/night".into(), get("test_night").len()),
        ],
    })
}

/// One frame of the test layout: `<layout>/{day,night}/ImagesRGB/<name>_rgb.png`,
/// `ImagesIR/<name>_ir.png` (16-bit) and `SegmentationClass/<name>.npy`.
fn write_test_layout_frame(out: &Path, layout: &str, f: &SynthFrame) -> Result<(), DataError> {
    let (w, h) = (f.width, f.height);
    let dir = out.join(layout).join(if f.night { "night" } else { "day" });
    let rgb_path = dir.join("ImagesRGB").join(format!("{}_rgb.png", f.name));
    write_png_u8(&rgb_path, w, h, 3, &f.rgb)?;
    let ir_path = dir.join("ImagesIR").join(format!("{}_ir.png", f.name));
    write_png_u16(&ir_path, w, h, 1, &f.thermal_u16())?;
    let label_path = dir
        .join("SegmentationClass")
        .join(format!("{}.npy", f.name));
    let label = crate::npy::encode_u8(w, h, &f.freiburg_label());
    rtf_core::write_bytes_atomic(&label_path, &label)?;
    Ok(())
}

/// One frame of the training tree: `train/seq_00_day/00/...` (labelled) or
/// `train/seq_01_night/00/...` (unlabelled, as in the real data).
fn write_training_tree_frame(out: &Path, f: &SynthFrame) -> Result<(), DataError> {
    let (w, h) = (f.width, f.height);
    let sequence = if f.night {
        "seq_01_night"
    } else {
        "seq_00_day"
    };
    let seq = out.join("train").join(sequence).join("00");
    let rgb_path = seq.join("fl_rgb").join(format!("fl_rgb_{}.png", f.name));
    write_png_u8(&rgb_path, w, h, 3, &f.rgb)?;
    let ir_path = seq
        .join("fl_ir_aligned")
        .join(format!("fl_ir_aligned_{}.png", f.name));
    write_png_u16(&ir_path, w, h, 1, &f.thermal_u16())?;
    if !f.night {
        let label_path = seq
            .join("fl_rgb_labels")
            .join(format!("fl_rgb_labels_{}.png", f.name));
        write_png_u8(&label_path, w, h, 1, &f.freiburg_label())?;
    }
    Ok(())
}
