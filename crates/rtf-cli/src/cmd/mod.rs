//! One module per subcommand: a clap `Args` struct and `run(args) -> anyhow::Result<()>`.

pub mod bench_data;
pub mod bench_model;
pub mod bench_train;
pub mod calibrate;
pub mod data;
pub mod eval;
pub mod export;
pub mod models;
pub mod predict;
pub mod recipes;
pub mod report;
pub mod synth;
pub mod train;

/// Parses `WxH` (e.g. `640x480`) into (width, height).
pub fn parse_size(text: &str) -> Result<(usize, usize), String> {
    let (w, h) = text
        .split_once(['x', 'X'])
        .ok_or_else(|| format!("`{text}` is not WxH (e.g. 640x480)"))?;
    let parse = |s: &str| s.trim().parse::<usize>().ok().filter(|&v| v > 0);
    match (parse(w), parse(h)) {
        (Some(w), Some(h)) => Ok((w, h)),
        _ => Err(format!(
            "`{text}` is not WxH with positive integers (e.g. 640x480)"
        )),
    }
}

/// The layout of a dataset root that `rtf train` / `rtf eval` read (MF or Freiburg Thermal);
/// anything else is an error naming the root. `purpose` words the error ("a training").
pub fn segmentation_format(
    root: &std::path::Path,
    purpose: &str,
) -> anyhow::Result<rtf_data::inspect::DatasetFormat> {
    use rtf_data::inspect::DatasetFormat;
    match rtf_data::inspect::detect_format(root) {
        Some(format @ (DatasetFormat::Mf | DatasetFormat::Freiburg)) => Ok(format),
        other => anyhow::bail!(
            "{}: not {purpose} dataset rtf can read ({}; expected the MF or the Freiburg \
             Thermal layout, see `rtf data check`)",
            root.display(),
            other.map_or("no known layout".to_string(), |f| format!("{f:?} layout"))
        ),
    }
}

/// Builds a network by name and loads weights (strict, reference names, checked against the
/// file's model metadata unless `foreign_weights`; a file without metadata loads with a
/// warning on stderr). With a precision, the network is wrapped in the fast inference path
/// (BatchNorm folded, channels-last).
pub fn load_network(
    name: &str,
    num_classes: i64,
    weights: &std::path::Path,
    device: tch::Device,
    precision: Option<rtf_models::fast::Precision>,
    foreign_weights: bool,
) -> anyhow::Result<(tch::nn::VarStore, Box<dyn rtf_models::Network>)> {
    let cfg = rtf_models::ModelConfig::from_name(name, num_classes)?;
    let mut vs = tch::nn::VarStore::new(device);
    let net = rtf_models::build(&vs.root(), &cfg)?;
    let provenance = rtf_models::weights::load_checked(&mut vs, &cfg, weights, foreign_weights)?;
    if let Some(warning) = rtf_models::weights::provenance_warning(weights, &provenance) {
        eprintln!("warning: {warning}");
    }
    let net = match precision {
        Some(p) => {
            Box::new(rtf_models::fast::InferenceNet::new(net, p)?) as Box<dyn rtf_models::Network>
        }
        None => net,
    };
    Ok((vs, net))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_parse() {
        assert_eq!(parse_size("640x480"), Ok((640, 480)));
        assert!(parse_size("640").is_err());
        assert!(parse_size("0x4").is_err());
    }
}
