//! Kernel measurements, made once per machine and cached (project issues 41 and 61; in the
//! library, so that the CLI and the Python package share them).
//!
//! A measurement times two ways of the same bf16 work and is cached in a JSON file (rtf's
//! binaries: `$RTF_CACHE_DIR/bf16-probe.json`, else `$XDG_CACHE_HOME/rtf/…`, else
//! `~/.cache/rtf/…`; the caller passes the path in) under a key naming what decides which
//! kernels run: the work, the CPU (vendor, family, model, name), the instruction-set caps the
//! caller names, the libtorch build, the revision of rtf's Winograd forms and the thread count.
//! A cache that cannot be read or written costs a measurement, never the work.

use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// One measurement: seconds per unit of the work in each way. Where the work compares two ways
/// of bf16 (`conv3x3`, `conv3x3-training`), `fp32_s` is the way with fp32 arithmetic (Winograd,
/// emulated) and `bf16_s` oneDNN's bf16 kernels.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Measured {
    pub fp32_s: f64,
    pub bf16_s: f64,
    /// When it was measured (seconds since the Unix epoch).
    pub unix_time: u64,
}

impl Measured {
    /// Two times measured now.
    pub fn now(fp32_s: f64, bf16_s: f64) -> Self {
        let unix_time = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_secs());
        Self {
            fp32_s,
            bf16_s,
            unix_time,
        }
    }

    /// bf16's speed as a multiple of fp32's (below 1: bf16, oneDNN's kernels, is slower).
    pub fn speedup(&self) -> f64 {
        self.fp32_s / self.bf16_s
    }
}

/// The cache file: measurements by key.
#[derive(Serialize, Deserialize, Default, Debug)]
#[serde(deny_unknown_fields)]
struct Cache {
    measurements: BTreeMap<String, Measured>,
}

/// The work the library measures.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Work {
    /// MFNet's fast-path forward at 320×240, batch 1, in fp32 (`fp32_s`) and bf16 (`bf16_s`):
    /// whether bf16 inference pays on a CPU with bf16 arithmetic ([`crate::kernels::inference_warning`]).
    Inference,
    /// An MFNet training step at 320×240, batch 2, in fp32 and bf16 (rtf-train `kernels`).
    Training,
    /// One wide 3×3 convolution over bf16 maps: the Winograd form (fp32 arithmetic) against
    /// oneDNN's bf16 kernels. Decides [`rtf_models::fast::InferenceKernels::bf16_winograd`].
    Conv3x3,
    /// One wide 3×3 convolution's forward and backward over bf16 operands, as training runs
    /// it: fp32 kernels (rtf's emulated convolutions) against oneDNN's bf16 kernels. Decides
    /// whether bf16 training takes `rtf_amp::Bf16Convolutions::Mixed` (rtf-train `kernels`).
    Conv3x3Training,
}

impl Work {
    pub fn name(self) -> &'static str {
        match self {
            Work::Inference => "inference",
            Work::Training => "training",
            Work::Conv3x3 => "conv3x3",
            Work::Conv3x3Training => "conv3x3-training",
        }
    }

    /// What is timed, for messages.
    pub fn workload(self) -> &'static str {
        match self {
            Work::Inference => "MFNet's fast-path forward at 320x240, batch 1",
            Work::Training => "an MFNet training step at 320x240, batch 2",
            Work::Conv3x3 => "a 3x3 convolution of 256 channels at 80x60, batch 1, folded",
            Work::Conv3x3Training => {
                "a 3x3 convolution of 256 channels at 80x60, batch 2, forward and backward"
            }
        }
    }
}

/// The variables that cap the instruction sets libtorch, oneDNN and MKL dispatch to.
const CAP_VARS: [&str; 3] = [
    "ATEN_CPU_CAPABILITY",
    "ONEDNN_MAX_CPU_ISA",
    "MKL_ENABLE_INSTRUCTIONS",
];

/// Where measurements are cached and what, besides the machine, tells them apart.
#[derive(Clone, Debug, Default)]
pub struct Probe {
    file: Option<PathBuf>,
    /// `VAR=value` of the settings that change the kernels (instruction-set caps), as the
    /// caller read them.
    caps: Vec<String>,
}

impl Probe {
    /// Measurements cached in `file`, told apart by `caps` too.
    pub fn cached_in(file: PathBuf, caps: Vec<String>) -> Self {
        Self {
            file: Some(file),
            caps,
        }
    }

    /// Measurements made every time (no cache file).
    pub fn uncached(caps: Vec<String>) -> Self {
        Self { file: None, caps }
    }

    /// The probe of a process whose variables `get` reads (rtf's binaries and the Python
    /// package pass their environment): cached in `$RTF_CACHE_DIR/bf16-probe.json`, else
    /// `$XDG_CACHE_HOME/rtf/…`, else `$HOME/.cache/rtf/…` (uncached without any of them);
    /// told apart by the instruction-set caps set (`ATEN_CPU_CAPABILITY`,
    /// `ONEDNN_MAX_CPU_ISA`, `MKL_ENABLE_INSTRUCTIONS`).
    pub fn from_vars(get: impl Fn(&str) -> Option<std::ffi::OsString>) -> Self {
        let caps: Vec<String> = CAP_VARS
            .iter()
            .filter_map(|var| get(var).map(|v| format!("{var}={}", v.to_string_lossy())))
            .collect();
        let dir = get("RTF_CACHE_DIR")
            .map(PathBuf::from)
            .or_else(|| get("XDG_CACHE_HOME").map(|d| PathBuf::from(d).join("rtf")))
            .or_else(|| get("HOME").map(|d| PathBuf::from(d).join(".cache/rtf")));
        match dir {
            Some(dir) => Self::cached_in(dir.join("bf16-probe.json"), caps),
            None => Self::uncached(caps),
        }
    }

    /// The cache file, if any.
    pub fn file(&self) -> Option<&Path> {
        self.file.as_deref()
    }

    /// The key of `work` (a work's name, and whatever else tells its kernels apart) here.
    pub fn key(&self, work: &str) -> String {
        format!(
            "{work} | {} | caps [{}] | libtorch {} | winograd r{} | {} threads",
            cpu_identity(&std::fs::read_to_string("/proc/cpuinfo").unwrap_or_default()),
            self.caps.join(" "),
            libtorch_identity(),
            rtf_kernels::winograd::REVISION,
            tch::get_num_threads()
        )
    }

    /// The cached measurement under `key`, measuring (and caching) it first where there is
    /// none; with the cache file it was read from or written to.
    pub fn measured(
        &self,
        key: &str,
        measure: impl FnOnce() -> Result<Measured, String>,
    ) -> Result<(Measured, Option<PathBuf>), String> {
        let mut cache = self.file().map(read_cache).unwrap_or_default();
        if let Some(m) = cache.measurements.get(key) {
            return Ok((m.clone(), self.file.clone()));
        }
        let m = measure()?;
        cache.measurements.insert(key.to_owned(), m.clone());
        let written = self.file.clone().filter(|p| write_cache(p, &cache).is_ok());
        Ok((m, written))
    }
}

fn read_cache(path: &Path) -> Cache {
    std::fs::read_to_string(path)
        .ok()
        .and_then(|text| serde_json::from_str(&text).ok())
        .unwrap_or_default()
}

fn write_cache(path: &Path, cache: &Cache) -> std::io::Result<()> {
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir)?;
    }
    let text = serde_json::to_string_pretty(cache).map_err(std::io::Error::other)?;
    rtf_core::write_bytes_atomic(path, text.as_bytes()).map_err(std::io::Error::other)
}

/// "vendor family/model name" of the first processor in `/proc/cpuinfo`.
pub fn cpu_identity(cpuinfo: &str) -> String {
    let field = |name: &str| {
        cpuinfo
            .lines()
            .find(|l| l.split(':').next().is_some_and(|k| k.trim() == name))
            .and_then(|l| l.split_once(':'))
            .map_or("?", |(_, v)| v.trim())
            .to_string()
    };
    format!(
        "{} family {} model {} {}",
        field("vendor_id"),
        field("cpu family"),
        field("model"),
        field("model name")
    )
}

/// The libtorch this process runs: the version next to the loaded `libtorch_cpu.so` (a PyPI
/// wheel's `version.py`, a libtorch archive's `build-version`), else its path.
pub fn libtorch_identity() -> String {
    let maps = std::fs::read_to_string("/proc/self/maps").unwrap_or_default();
    let Some(lib) = maps
        .lines()
        .filter_map(|l| l.split_whitespace().nth(5))
        .find(|p| p.ends_with("/libtorch_cpu.so"))
        .map(PathBuf::from)
    else {
        return "?".into();
    };
    let root = lib
        .parent()
        .and_then(Path::parent)
        .unwrap_or(Path::new("/"));
    if let Ok(text) = std::fs::read_to_string(root.join("version.py")) {
        if let Some(line) = text.lines().find(|l| l.starts_with("__version__")) {
            return line.split('\'').nth(1).unwrap_or(line).to_string();
        }
    }
    std::fs::read_to_string(root.join("build-version"))
        .map(|v| v.trim().to_string())
        .unwrap_or_else(|_| lib.display().to_string())
}

/// The key of [`Work::Inference`] with `kernels` ([`Probe::key`]): what besides the machine
/// decides which kernels it runs, the kernels of its wide 3×3 convolutions.
pub fn inference_key(probe: &Probe, kernels: &rtf_models::fast::InferenceKernels) -> String {
    match kernels.bf16_winograd {
        true => probe.key("inference | winograd 3x3"),
        false => probe.key(Work::Inference.name()),
    }
}

/// [`Work::Inference`] timed in this process with `kernels` (bf16 on oneDNN's kernels, not
/// emulated: the work is measured where bf16 is native): MFNet's fast path at 320×240, batch
/// 1, median of 5 after 2, fp32 then bf16.
pub fn measure_inference(kernels: rtf_models::fast::InferenceKernels) -> Result<Measured, String> {
    use rtf_models::fast::Precision;
    let seconds = |precision| -> Result<f64, String> {
        let opts = crate::speed::BenchOptions {
            kernels,
            precision,
            width: 320,
            height: 240,
            warmup: 2,
            iterations: 5,
            agreement: false,
            bf16_convolutions: rtf_amp::Bf16Convolutions::Native,
            ..Default::default()
        };
        let report = crate::speed::bench_model(&opts).map_err(|e| e.to_string())?;
        Ok(report.median_ms / 1000.0)
    };
    let fp32 = seconds(Precision::Fp32)?;
    Ok(Measured::now(fp32, seconds(Precision::Bf16)?))
}

/// [`Work::Inference`] with `kernels`, cached by `probe` under [`inference_key`] (the key `rtf`
/// uses, so both share the measurement), measured in this process where there is none.
pub fn measured_inference(
    probe: &Probe,
    kernels: rtf_models::fast::InferenceKernels,
) -> Result<(Measured, Option<PathBuf>), String> {
    probe.measured(&inference_key(probe, &kernels), || {
        measure_inference(kernels)
    })
}

/// [`Work::Conv3x3`] timed in this process: a 3×3 convolution of 256 channels at 80×60 (+
/// bias, ReLU, folded as inference folds it) over bf16 maps, in the Winograd form (`fp32_s`)
/// and on oneDNN's bf16 kernels (`bf16_s`); median of 7 after 2. Its weights and input are
/// fixed, not drawn, so the caller's random stream is untouched.
pub fn measure_conv3x3(forms: rtf_kernels::winograd::Forms) -> Result<Measured, String> {
    let winograd = conv3x3_s(true, forms)?;
    Ok(Measured::now(winograd, conv3x3_s(false, forms)?))
}

fn conv3x3_s(winograd: bool, forms: rtf_kernels::winograd::Forms) -> Result<f64, String> {
    use rtf_models::fast::{FoldOptions, InferenceKernels, Precision};
    use rtf_models::layers::{Act, BuildOptions, ConvBnAct, ConvSpec, Fold, Folder, Path};
    use tch::{Device, Kind, Tensor};
    let _guard = tch::no_grad_guard();
    let vs = tch::nn::VarStore::new(Device::Cpu);
    let root = Path::new(vs.root(), &BuildOptions::uninitialised());
    let unit = ConvBnAct::new(
        &root / "conv",
        None,
        256,
        256,
        ConvSpec::new(3).bias(true),
        Act::Relu,
    );
    for (_, mut var) in vs.variables() {
        let _ = var.fill_(0.01);
    }
    let kernels = InferenceKernels {
        winograd: forms,
        bf16_winograd: winograd,
        ..InferenceKernels::unmeasured()
    };
    let unit = unit.folded(&Folder::new(
        &FoldOptions::new(Precision::Bf16).kernels(kernels),
    ));
    let n = 256 * 60 * 80;
    let xs = Tensor::arange(n, (Kind::Float, Device::Cpu))
        .remainder(17)
        .f_view([1, 256, 60, 80])
        .map_err(|e| e.to_string())?;
    let xs = rtf_models::layers::to_channels_last(&(xs * 0.05).to_kind(Kind::BFloat16));
    let times: Vec<f64> = (0..9)
        .map(|_| {
            let start = std::time::Instant::now();
            let _ = tch::nn::ModuleT::forward_t(&unit, &xs, false);
            start.elapsed().as_secs_f64()
        })
        .skip(2)
        .collect();
    Ok(crate::speed::median_min(&times).0)
}

/// [`Work::Conv3x3Training`] timed in this process: the convolution's forward and backward
/// over bf16 operands, channels-last as bf16 training lays its maps out, on fp32 kernels
/// (`fp32_s`, rtf's emulated convolution) and on oneDNN's bf16 kernels (`bf16_s`); median of
/// 5 after 2. Fixed weights and input, so the caller's random stream is untouched.
pub fn measure_conv3x3_training() -> Result<Measured, String> {
    let emulated = conv3x3_training_s(true)?;
    Ok(Measured::now(emulated, conv3x3_training_s(false)?))
}

fn conv3x3_training_s(emulated: bool) -> Result<f64, String> {
    use rtf_kernels::onednn::Geometry;
    use rtf_models::layers::{bf16_emulated_convolution, to_channels_last};
    use tch::{Device, Kind, Tensor};
    let fixed = |shape: [i64; 4], scale: f64| -> Result<Tensor, String> {
        let n = shape.iter().product::<i64>();
        let t = Tensor::arange(n, (Kind::Float, Device::Cpu))
            .remainder(13)
            .f_view(shape)
            .map_err(|e| e.to_string())?;
        Ok(to_channels_last(&((t - 6.0) * scale).to_kind(Kind::BFloat16)).set_requires_grad(true))
    };
    let xs = fixed([2, 256, 60, 80], 0.1)?;
    let w = fixed([256, 256, 3, 3], 0.002)?;
    let times: Vec<f64> = (0..7)
        .map(|_| {
            let start = std::time::Instant::now();
            let ys = match emulated {
                true => bf16_emulated_convolution(&xs, &w, None, Geometry::SAME_3X3),
                false => xs.conv2d(&w, None::<Tensor>, [1, 1], [1, 1], [1, 1], 1),
            };
            ys.sum(Kind::Float).backward();
            start.elapsed().as_secs_f64()
        })
        .skip(2)
        .collect();
    Ok(crate::speed::median_min(&times).0)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn m(fp32_s: f64, bf16_s: f64) -> Measured {
        Measured {
            fp32_s,
            bf16_s,
            unix_time: 0,
        }
    }

    #[test]
    fn the_cache_and_caps_come_from_the_variables_given() {
        let vars = |pairs: &'static [(&'static str, &'static str)]| {
            move |name: &str| {
                pairs
                    .iter()
                    .find(|(k, _)| *k == name)
                    .map(|(_, v)| std::ffi::OsString::from(v))
            }
        };
        let p = Probe::from_vars(vars(&[
            ("RTF_CACHE_DIR", "/c"),
            ("HOME", "/h"),
            ("ONEDNN_MAX_CPU_ISA", "AVX2"),
        ]));
        assert_eq!(p.file(), Some(Path::new("/c/bf16-probe.json")));
        assert!(p.key("w").contains("caps [ONEDNN_MAX_CPU_ISA=AVX2]"));
        let p = Probe::from_vars(vars(&[("XDG_CACHE_HOME", "/x"), ("HOME", "/h")]));
        assert_eq!(p.file(), Some(Path::new("/x/rtf/bf16-probe.json")));
        let p = Probe::from_vars(vars(&[("HOME", "/h")]));
        assert_eq!(p.file(), Some(Path::new("/h/.cache/rtf/bf16-probe.json")));
        assert_eq!(Probe::from_vars(vars(&[])).file(), None);
    }

    #[test]
    fn the_cpu_is_named_by_vendor_family_model_and_name() {
        let info = "processor\t: 0\nvendor_id\t: GenuineIntel\ncpu family\t: 6\nmodel\t\t: 167\n\
                    model name\t: Intel(R) Xeon(R) Processor\nflags\t\t: avx2\nprocessor\t: 1\n\
                    vendor_id\t: Other\n";
        assert_eq!(
            cpu_identity(info),
            "GenuineIntel family 6 model 167 Intel(R) Xeon(R) Processor"
        );
        assert_eq!(cpu_identity(""), "? family ? model ? ?");
    }

    #[test]
    fn the_key_names_the_work_the_caps_and_libtorch() {
        let probe = Probe::uncached(vec!["ONEDNN_MAX_CPU_ISA=AVX2".into()]);
        let (a, b) = (probe.key("conv3x3"), probe.key("inference"));
        assert_ne!(a, b);
        assert!(
            a.starts_with("conv3x3 | ")
                && a.contains("caps [ONEDNN_MAX_CPU_ISA=AVX2]")
                && a.contains(&format!("winograd r{}", rtf_kernels::winograd::REVISION)),
            "{a}"
        );
        assert!(!a.contains("libtorch ?"), "libtorch_cpu.so is mapped: {a}");
    }

    /// Measured once, then read back (the second measure is never called); a broken file
    /// costs a measurement and is written anew.
    #[test]
    fn a_measurement_is_cached_and_a_broken_cache_measured_again() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("sub/bf16-probe.json");
        let probe = Probe::cached_in(file.clone(), Vec::new());
        let (first, written) = probe.measured("k", || Ok(m(1.0, 0.5))).unwrap();
        assert_eq!(
            (first, written.as_deref()),
            (m(1.0, 0.5), Some(file.as_path()))
        );
        let (again, _) = probe.measured("k", || panic!("measured twice")).unwrap();
        assert_eq!(again, m(1.0, 0.5));
        std::fs::write(&file, "{ not json").unwrap();
        let (fresh, _) = probe.measured("k", || Ok(m(2.0, 1.0))).unwrap();
        assert_eq!(fresh, m(2.0, 1.0));
        assert_eq!(read_cache(&file).measurements["k"], m(2.0, 1.0));
    }

    #[test]
    fn the_conv3x3_measurement_times_both_ways() {
        let _memory = crate::memory_lock();
        let m = measure_conv3x3(rtf_kernels::winograd::Forms::All).unwrap();
        assert!(m.fp32_s > 0.0 && m.bf16_s > 0.0, "{m:?}");
    }
}
