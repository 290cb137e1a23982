//! The prediction grid: the same frames for every run with weights, RGB | thermal | truth |
//! each run's prediction, with column titles and the class legend
//! ([`rtf_eval::figure::annotated_grid`]), as a PNG. Without one, the page says why.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use rtf_data::FrameSource;
use rtf_eval::figure::{self, GridRow, PredictionColumn};

use crate::runs::Run;
use crate::ReportOptions;

/// Whatever stops the grid: it ends up as a sentence on the page.
type GridError = Box<dyn std::error::Error + Send + Sync>;

/// A run's masked network and the (width, height) it was trained at.
type RunNetwork = (Box<dyn rtf_models::Network>, Option<(usize, usize)>);

/// An error and its causes, as one line (`outer: cause: cause`).
fn sentence(e: &(dyn std::error::Error + 'static)) -> String {
    let mut text = e.to_string();
    let mut source = e.source();
    while let Some(cause) = source {
        text.push_str(&format!(": {cause}"));
        source = cause.source();
    }
    text
}

/// The prediction grid as PNG bytes (None: none asked for), or why there is none; notes (the
/// dataset's announcement) go to `notes`.
pub(crate) fn prediction_grid(
    options: &ReportOptions,
    runs: &[Run],
    notes: &mut Vec<String>,
) -> Result<Option<Vec<u8>>, String> {
    if options.frames == 0 {
        return Ok(None);
    }
    // The final weights, else the best (a run stopped before its last epoch).
    let with_weights: Vec<(&Run, PathBuf)> = runs
        .iter()
        .filter_map(|r| {
            let weights = r.weights();
            weights.last.or(weights.best).map(|p| (r, p))
        })
        .collect();
    if with_weights.is_empty() {
        return Err("no run folder holds final.safetensors or best.safetensors".into());
    }
    let (root, split) = grid_dataset(options, with_weights[0].0)?;
    if !root.exists() {
        return Err(format!(
            "dataset {} not found (give --data)",
            root.display()
        ));
    }
    draw_prediction_grid(options, &with_weights, &root, &split, notes)
        .map(Some)
        .map_err(|e| sentence(e.as_ref()))
}

/// The dataset the grid is drawn from: `--data` and `--split`, else the first run's dataset
/// root and validation split.
fn grid_dataset(options: &ReportOptions, run: &Run) -> Result<(PathBuf, String), String> {
    if let Some(root) = &options.data {
        return Ok((root.clone(), options.split.clone()));
    }
    let training = run
        .config
        .as_ref()
        .ok_or("no --data, and no dataset root read from the run's config (give --data)")?;
    let split = training
        .val_split
        .clone()
        .unwrap_or_else(|| options.split.clone());
    Ok((training.dataset_root.clone(), split))
}

/// The labelled frames of `split` under `root` (its layout recognised once).
fn open_split(
    root: &Path,
    split: &str,
    notes: &mut Vec<String>,
) -> Result<Arc<dyn FrameSource>, GridError> {
    let dataset = rtf_data::dataset::open_for(root, "an evaluation")?;
    if let Some(line) = dataset.announcement() {
        notes.push(format!("data: {line}"));
    }
    Ok(dataset.split(split, true)?)
}

/// The PNG: the same frames for every run, one prediction column per run.
fn draw_prediction_grid(
    options: &ReportOptions,
    with_weights: &[(&Run, PathBuf)],
    root: &Path,
    split: &str,
    notes: &mut Vec<String>,
) -> Result<Vec<u8>, GridError> {
    let device = rtf_eval::device::available_device(&options.device)?;
    let source = open_split(root, split, notes)?;
    let mut rows: Option<Vec<GridRow>> = None;
    let mut columns = Vec::new();
    for (run, weights) in with_weights {
        let (net, resize) = run_network(run, weights, device)?;
        let rows = match &mut rows {
            Some(rows) => rows,
            None => rows.insert(figure::rows_for(
                net.as_ref(),
                source.as_ref(),
                options.frames,
                resize,
                device,
            )?),
        };
        let ids = rows
            .iter()
            .map(|row| figure::predict_row(net.as_ref(), row, device))
            .collect::<Result<Vec<_>, _>>()?;
        columns.push(PredictionColumn {
            title: run.label.clone(),
            ids,
        });
    }
    let classes = source.class_set().clone();
    let image = figure::annotated_grid(rows.as_deref().unwrap_or(&[]), &columns, &classes);
    let mut png = Vec::new();
    image.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)?;
    Ok(png)
}

/// A run's network with its weights, behind the input mask it was trained with (RGB-only,
/// thermal-only runs), and the resize it was trained at.
fn run_network(run: &Run, weights: &Path, device: tch::Device) -> Result<RunNetwork, GridError> {
    let cfg = run.config.as_ref().ok_or_else(|| {
        format!(
            "{}: `model` is not a network configuration",
            run.folder.config_path().display()
        )
    })?;
    let mut vs = tch::nn::VarStore::new(device);
    let net = rtf_models::build(&vs.root(), &cfg.model)?;
    rtf_models::io::weights::load_safetensors(&mut vs, weights)?;
    Ok((rtf_models::masked(net, cfg.inputs), cfg.resize))
}
