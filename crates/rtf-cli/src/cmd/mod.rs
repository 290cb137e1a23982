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

pub use rtf_core::parse_size;

/// A dataset root that `rtf train` / `rtf eval` read, opened once (rtf_data::dataset): MF,
/// Freiburg Thermal, or a described layout (dataset.yaml, MSRS, PST900, FMB), the last
/// announced on stderr (rtf says which layout, classes and thermal rule it inferred);
/// anything else is an error naming the root. `purpose` words the error ("a training").
pub fn open_dataset(root: &std::path::Path, purpose: &str) -> anyhow::Result<rtf_data::Dataset> {
    let dataset = rtf_data::dataset::open_for(root, purpose)?;
    if let Some(line) = dataset.announcement() {
        eprintln!("data: {line}");
    }
    Ok(dataset)
}

/// How `rtf eval` and `rtf predict` run a weights file: the device, the inference path, the
/// channels the network sees, and whether a file made for another network may load.
#[derive(clap::Args)]
pub struct RunFlags {
    /// cpu, cuda or cuda:N.
    #[arg(long, default_value = "cpu")]
    pub device: String,
    /// Run the fast inference path (BatchNorm folded, channels-last) in fp32, bf16 or fp16
    /// (CUDA only); default: the plain path.
    #[arg(long, value_parser = rtf_models::fast::Precision::parse_inference)]
    pub precision: Option<rtf_models::fast::Precision>,
    /// Channels the network sees (rgb_t, rgb, thermal; the others zeroed). Default: what the
    /// weights file records (rtf writes it), else all four; needed only for files without it.
    #[arg(long, value_parser = rtf_models::Modality::parse)]
    pub inputs: Option<rtf_models::Modality>,
    /// Load weights whose metadata names another network (e.g. renamed or converted files);
    /// names and shapes must still match.
    #[arg(long)]
    pub foreign_weights: bool,
}

impl RunFlags {
    /// The device, checked to be usable here (a clear error rather than libtorch's panic).
    pub fn device(&self) -> anyhow::Result<tch::Device> {
        rtf_train::config::available_device(&self.device).map_err(anyhow::Error::msg)
    }

    /// The loader's request for network `name` with `weights` and `num_classes` outputs on
    /// `device` (from [`device`](Self::device)).
    pub fn request<'a>(
        &self,
        name: &'a str,
        weights: &'a std::path::Path,
        num_classes: i64,
        device: tch::Device,
    ) -> rtf_models::io::loaded::NetworkRequest<'a> {
        rtf_models::io::loaded::NetworkRequest {
            name,
            num_classes,
            weights,
            device,
            precision: self.precision,
            kernels: rtf_models::fast::InferenceKernels::unmeasured(),
            foreign_weights: self.foreign_weights,
            inputs: self.inputs,
        }
    }
}

/// Before folding a network for inference in `precision` (None: the plain path): the kernels
/// the fold takes, chosen by the library as for any caller ([`rtf_eval::kernels`]) under this
/// process's policy ([`crate::bf16_probe::policy`]: a bad `RTF_BF16_WINOGRAD` is refused here);
/// then the library's warning where bf16 is slow or emulated here
/// ([`rtf_eval::kernels::inference_warning`], measured in a child process), on stderr.
pub fn prepare_inference(
    precision: Option<rtf_models::fast::Precision>,
    device: tch::Device,
) -> anyhow::Result<rtf_models::fast::InferenceKernels> {
    let policy = crate::bf16_probe::policy()?;
    let (kernels, warnings) = match precision {
        Some(p) => {
            rtf_eval::kernels::inference_kernels(&policy, p, device, &crate::bf16_probe::probe())
        }
        None => (rtf_models::fast::InferenceKernels::unmeasured(), Vec::new()),
    };
    for warning in warnings {
        eprintln!("warning: {warning}");
    }
    let measured = || crate::bf16_probe::measured_inference(&kernels);
    let warning =
        precision.and_then(|p| rtf_eval::kernels::inference_warning(&policy, p, device, measured));
    if let Some(warning) = warning {
        eprintln!("warning: {warning}");
    }
    Ok(kernels)
}

/// [`rtf_models::io::loaded::load_network`] for a command: the kernels chosen first
/// ([`prepare_inference`]), the loader's warnings printed on stderr.
pub fn load_network(
    request: &rtf_models::io::loaded::NetworkRequest,
) -> anyhow::Result<rtf_models::io::loaded::LoadedNetwork> {
    let kernels = prepare_inference(request.precision, request.device)?;
    let request = rtf_models::io::loaded::NetworkRequest {
        kernels,
        ..*request
    };
    let loaded = rtf_models::io::loaded::load_network(&request)?;
    for warning in &loaded.warnings {
        eprintln!("warning: {warning}");
    }
    Ok(loaded)
}

/// The network configuration recorded in a weights file (`rtf.config`); None for weights
/// without it (converted published weights).
pub fn weights_config(
    weights: &std::path::Path,
) -> anyhow::Result<Option<rtf_models::ModelConfig>> {
    let file = rtf_models::io::weights::read_weights_metadata(weights)?;
    Ok(file.saved_config(weights)?)
}

/// The class set and thermal rule recorded in a weights file (`rtf.data`,
/// rtf_data::trained_on); None for weights without it (converted published weights, runs
/// of older builds: MF's 9 classes unless told otherwise).
pub fn trained_on(weights: &std::path::Path) -> anyhow::Result<Option<rtf_data::TrainedOn>> {
    let file = rtf_models::io::weights::read_weights_metadata(weights)?;
    Ok(rtf_data::trained_on::from_metadata(
        &file.metadata,
        weights,
    )?)
}

/// Refuses data whose class set is not the one `weights` were trained on (when they record
/// it), naming the weights, the data and both class lists.
pub fn check_classes(
    weights: &std::path::Path,
    data: &std::path::Path,
    classes: &rtf_core::ClassSet,
) -> anyhow::Result<Option<rtf_data::TrainedOn>> {
    let trained = trained_on(weights)?;
    if let Some(t) = &trained {
        rtf_data::trained_on::check_data(
            t,
            weights,
            data,
            classes,
            rtf_data::trained_on::WEIGHTS_HINT,
        )?;
    }
    Ok(trained)
}
