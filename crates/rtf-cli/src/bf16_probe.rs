//! Whether bf16 pays on this CPU where it has bf16 arithmetic, measured once (project issue 41).
//!
//! bf16 instructions do not make bf16 fast everywhere. On an Intel AVX-512 CPU without AMX
//! (oneDNN's `avx512_core_bf16` / `avx10_1_512` kernels), measured on family 6 model 167 with
//! AMX capped off by `ONEDNN_MAX_CPU_ISA`, rtf's bf16 inference ran at 0.72× (MFNet) and 0.54×
//! (RTFNet-50) of its fp32 speed, and PyTorch's bf16 autocast was slower than its fp32 too: the
//! bf16 dot-product instruction there has the throughput of the fp32 FMAs it replaces, so bf16
//! saves memory traffic only and pays for conversions and reorders (the wide 3×3 layers now
//! take fp32 Winograd over bf16 maps there, below, which left RTFNet-50 at 0.86× its fp32).
//! With AMX on the same CPU bf16 ran 2.7× and 4.4× faster
//! than fp32; on AMD Zen 4 with `avx512_bf16` 1.6–1.9× (docs/src/benchmarks.md).
//!
//! So where bf16 is native, `--precision bf16` on the CPU times a small fixed workload once in
//! each precision — MFNet at 320×240: the fast path's forward for inference, a training step
//! (batch 2) for training — and caches the result per CPU model, oneDNN/libtorch/MKL caps,
//! libtorch build, revision of rtf's Winograd forms and thread count in `$RTF_CACHE_DIR`
//! (default `$XDG_CACHE_HOME/rtf`, else `~/.cache/rtf`), `bf16-probe.json`. The probe runs in
//! a child process (about a second for inference, a few for training), so the command's own
//! memory peak and state are untouched. Where bf16 measured slower, the command says so on
//! stderr with the measured times before its work; the precision stays what the user typed.
//!
//! Before bf16 inference a third measurement, cached the same way, picks the kernels of the
//! wide 3×3 convolutions ([`Work::Conv3x3`], [`choose_bf16_winograd`]): the fp32 Winograd form
//! over bf16 maps, or oneDNN's bf16 kernels, whichever ran one such layer faster here. Both
//! compute bf16 inference (bf16 maps and weights, float sums); only the speed differs.
//!
//! Before bf16 training a fourth, [`Work::Conv3x3Training`], times such a layer's forward and
//! backward on fp32 kernels over bf16 operands against oneDNN's bf16 kernels and so picks the
//! run's convolution kernels ([`choose_training_convolutions`], crate::bf16_kernels).

use anyhow::{Context, Result};
use rtf_amp::Bf16Convolutions;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// Which kind of work the probe times (`rtf bench bf16-probe --work inference|training|conv3x3`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Work {
    Inference,
    Training,
    /// One wide 3×3 convolution over bf16 maps: fp32 arithmetic (the Winograd form,
    /// `rtf_models::winograd`) against oneDNN's bf16 kernels. Decides which of the two bf16
    /// inference takes for such layers ([`choose_bf16_winograd`]).
    Conv3x3,
    /// One wide 3×3 convolution's forward and backward over bf16 operands, as training runs
    /// it: fp32 kernels (rtf's emulated convolutions) against oneDNN's bf16 kernels. Decides
    /// whether bf16 training takes [`rtf_amp::Bf16Convolutions::Mixed`]
    /// ([`choose_training_convolutions`]).
    Conv3x3Training,
}

impl Work {
    fn name(self) -> &'static str {
        match self {
            Work::Inference => "inference",
            Work::Training => "training",
            Work::Conv3x3 => "conv3x3",
            Work::Conv3x3Training => "conv3x3-training",
        }
    }

    /// What was timed, for the message.
    pub fn workload(self) -> &'static str {
        match self {
            Work::Inference => "MFNet's fast-path forward at 320x240, batch 1",
            Work::Training => "an MFNet training step at 320x240, batch 2",
            Work::Conv3x3 => "a 3x3 convolution of 256 channels at 80x60 over bf16 maps",
            Work::Conv3x3Training => {
                "a 3x3 convolution of 256 channels at 80x60, batch 2, forward and backward"
            }
        }
    }
}

/// One measurement: seconds per unit of the work in each precision. Where the work compares
/// two ways of bf16 ([`Work::Conv3x3`], [`Work::Conv3x3Training`]), `fp32_s` is the way with
/// fp32 kernels (Winograd, emulated) and `bf16_s` oneDNN's bf16 kernels.
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Measured {
    pub fp32_s: f64,
    pub bf16_s: f64,
    /// When it was measured (seconds since the Unix epoch).
    pub unix_time: u64,
}

impl Measured {
    /// bf16's speed as a multiple of fp32's (below 1: bf16 is slower).
    pub fn speedup(&self) -> f64 {
        self.fp32_s / self.bf16_s
    }
}

/// The cache file: measurements by [`key`].
#[derive(Serialize, Deserialize, Default, Debug)]
#[serde(deny_unknown_fields)]
struct Cache {
    measurements: BTreeMap<String, Measured>,
}

/// The cache file's path (`$RTF_CACHE_DIR`, `$XDG_CACHE_HOME/rtf` or `~/.cache/rtf`).
pub fn cache_path() -> Option<PathBuf> {
    let dir = std::env::var_os("RTF_CACHE_DIR")
        .map(PathBuf::from)
        .or_else(|| std::env::var_os("XDG_CACHE_HOME").map(|d| PathBuf::from(d).join("rtf")))
        .or_else(|| std::env::var_os("HOME").map(|d| PathBuf::from(d).join(".cache/rtf")))?;
    Some(dir.join("bf16-probe.json"))
}

/// What decides which kernels run: the CPU (vendor, family, model, name), the caps set in the
/// environment, the libtorch build, rtf's Winograd forms ([`rtf_models::winograd::REVISION`])
/// and the thread count; for [`Work::Training`], the bf16 convolutions in force
/// (crate::bf16_kernels has made the run's choice by then).
pub fn key(work: Work) -> String {
    let caps: Vec<String> = [
        "ATEN_CPU_CAPABILITY",
        "ONEDNN_MAX_CPU_ISA",
        "MKL_ENABLE_INSTRUCTIONS",
        rtf_models::winograd::BF16_VAR,
    ]
    .iter()
    .filter_map(|var| std::env::var(var).ok().map(|v| format!("{var}={v}")))
    .collect();
    let convolutions = match (work, rtf_amp::cpu_bf16_convolutions()) {
        (Work::Training, Ok(choice)) => format!(" | {} convolutions", choice.name()),
        _ => String::new(),
    };
    format!(
        "{}{convolutions} | {} | caps [{}] | libtorch {} | winograd r{} | {} threads",
        work.name(),
        cpu_identity(&std::fs::read_to_string("/proc/cpuinfo").unwrap_or_default()),
        caps.join(" "),
        libtorch_identity(),
        rtf_models::winograd::REVISION,
        tch::get_num_threads()
    )
}

/// "vendor family/model name" of the first processor in `/proc/cpuinfo`.
fn cpu_identity(cpuinfo: &str) -> String {
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
fn libtorch_identity() -> String {
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

/// The cached measurement for `work` on this machine, measuring (and caching) it first if
/// there is none. A cache that cannot be read or written costs a measurement, never the run.
pub fn measured(work: Work) -> Result<(Measured, Option<PathBuf>)> {
    let key = key(work);
    let path = cache_path();
    let mut cache = path.as_deref().map(read_cache).unwrap_or_default();
    if let Some(m) = cache.measurements.get(&key) {
        return Ok((m.clone(), path));
    }
    let m = measure_in_child(work)?;
    cache.measurements.insert(key, m.clone());
    let written = path.filter(|p| write_cache(p, &cache).is_ok());
    Ok((m, written))
}

fn read_cache(path: &Path) -> Cache {
    std::fs::read_to_string(path)
        .ok()
        .and_then(|text| serde_json::from_str(&text).ok())
        .unwrap_or_default()
}

fn write_cache(path: &Path, cache: &Cache) -> Result<()> {
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    }
    let text = serde_json::to_string_pretty(cache)?;
    rtf_core::write_bytes_atomic(path, text.as_bytes())
        .with_context(|| format!("cannot write {}", path.display()))?;
    Ok(())
}

/// [`measure`] in a child process (`rtf bench bf16-probe`), so this process's peak memory,
/// allocator, oneDNN caches and random state are what they would be without the probe. The
/// child inherits the environment and runs with this process's thread count.
fn measure_in_child(work: Work) -> Result<Measured> {
    let exe = std::env::current_exe().context("cannot find the rtf binary for the bf16 probe")?;
    let mut child = std::process::Command::new(&exe);
    child
        .args(["bench", "bf16-probe", "--work", work.name()])
        .env("OMP_NUM_THREADS", tch::get_num_threads().to_string())
        .stderr(std::process::Stdio::inherit());
    // Inference runs with this process's choice of bf16 3×3 kernels, training with its bf16
    // convolutions (the 3×3 probes set each way themselves).
    if let (Work::Training, Ok(choice)) = (work, rtf_amp::cpu_bf16_convolutions()) {
        child.env(rtf_amp::BF16_CONVOLUTIONS_VAR, choice.name());
    }
    if let (Work::Inference, Ok(on)) = (work, rtf_models::winograd::bf16_applies()) {
        child.env(
            rtf_models::winograd::BF16_VAR,
            if on { "on" } else { "off" },
        );
    }
    let out = child
        .output()
        .with_context(|| format!("cannot start {}", exe.display()))?;
    anyhow::ensure!(
        out.status.success(),
        "the bf16 probe failed ({})",
        out.status
    );
    serde_json::from_slice(&out.stdout).context("the bf16 probe printed no measurement")
}

/// Times the work once in each precision (seconds per unit, median).
pub fn measure(work: Work) -> Result<Measured> {
    let (fp32_s, bf16_s) = match work {
        Work::Inference => (inference_s(false)?, inference_s(true)?),
        Work::Training => (training_s(false)?, training_s(true)?),
        Work::Conv3x3 => (conv3x3_s(true)?, conv3x3_s(false)?),
        Work::Conv3x3Training => (conv3x3_training_s(true), conv3x3_training_s(false)),
    };
    let unix_time = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs());
    Ok(Measured {
        fp32_s,
        bf16_s,
        unix_time,
    })
}

fn inference_s(bf16: bool) -> Result<f64> {
    use rtf_models::fast::Precision;
    let opts = rtf_eval::speed::BenchOptions {
        precision: if bf16 {
            Precision::Bf16
        } else {
            Precision::Fp32
        },
        width: 320,
        height: 240,
        warmup: 2,
        iterations: 5,
        agreement: false,
        ..Default::default()
    };
    Ok(rtf_eval::speed::bench_model(&opts)?.median_ms / 1000.0)
}

fn training_s(bf16: bool) -> Result<f64> {
    use rtf_train::config::Precision;
    let opts = rtf_train::bench::TrainBenchOptions {
        model: "mfnet".into(),
        batch: 2,
        size: (320, 240),
        precision: if bf16 {
            Precision::Bf16
        } else {
            Precision::Fp32
        },
        device: tch::Device::Cpu,
        warmup: 1,
        steps: 3,
        optimizer: rtf_train::OptimizerConfig::mfnet_paper(),
        count_ops: false,
    };
    Ok(rtf_train::bench::bench_train(&opts)?.step_s)
}

/// Seconds per pass of [`Work::Conv3x3`]'s convolution (+ bias, ReLU, folded as inference
/// folds it), in the Winograd form or with oneDNN's bf16 kernels; median of 7 after 2.
fn conv3x3_s(winograd: bool) -> Result<f64> {
    use rtf_models::layers::{Act, ConvBnAct, ConvSpec, Fuse};
    use tch::{Device, Kind, Tensor};
    let _guard = tch::no_grad_guard();
    let vs = tch::nn::VarStore::new(Device::Cpu);
    let mut unit = ConvBnAct::new(
        vs.root() / "conv",
        None,
        256,
        256,
        ConvSpec::new(3).bias(true),
        Act::Relu,
    );
    rtf_models::winograd::with_bf16(winograd, || {
        rtf_models::layers::with_fused_layout(true, || unit.fuse(Kind::BFloat16))
    });
    let xs = rtf_models::layers::to_channels_last(
        &Tensor::randn([1, 256, 60, 80], (Kind::Float, Device::Cpu)).to_kind(Kind::BFloat16),
    );
    let times: Vec<f64> = (0..9)
        .map(|_| {
            let start = std::time::Instant::now();
            let _ = tch::nn::ModuleT::forward_t(&unit, &xs, false);
            start.elapsed().as_secs_f64()
        })
        .skip(2)
        .collect();
    Ok(rtf_eval::speed::median_min(&times).0)
}

/// Seconds per forward and backward of [`Work::Conv3x3Training`]'s convolution over bf16
/// operands, on fp32 kernels (`emulated`, as rtf's emulated convolutions run it) or oneDNN's
/// bf16 kernels; channels-last, as bf16 training lays its maps out; median of 5 after 2.
fn conv3x3_training_s(emulated: bool) -> f64 {
    use rtf_models::layers::{bf16_emulated_convolution, to_channels_last};
    use rtf_models::onednn::Geometry;
    use tch::{Device, Kind, Tensor};
    let bf16 = (Kind::BFloat16, Device::Cpu);
    let xs = to_channels_last(&Tensor::randn([2, 256, 60, 80], bf16)).set_requires_grad(true);
    let w =
        to_channels_last(&(Tensor::randn([256, 256, 3, 3], bf16) * 0.02)).set_requires_grad(true);
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
    rtf_eval::speed::median_min(&times).0
}

/// Before bf16 training on the CPU: where bf16 is native and
/// [`rtf_amp::BF16_CONVOLUTIONS_VAR`] is unset, [`rtf_amp::Bf16Convolutions::Mixed`] if the
/// cached [`Work::Conv3x3Training`] measurement found fp32 kernels faster for a wide 3×3 layer
/// here (measured first where there is none; with AMX capped off on an Intel Xeon, RTFNet-50's
/// bf16 step ran 1.12–1.17× faster and MFNet's 1.12× so, docs/src/benchmarks.md), else native;
/// with the line that says a mixed choice. `None` where nothing is measured (the choice in force
/// stands); a failed measurement is a warning, and the bf16 kernels run.
pub fn choose_training_convolutions() -> Option<(Bf16Convolutions, Option<String>)> {
    if rtf_amp::bf16_convolutions_set_by_env() || rtf_amp::cpu_has_native_bf16() != Some(true) {
        return None;
    }
    match measured(Work::Conv3x3Training) {
        // `fp32_s` is the emulated layer's: below 1, the fp32 kernels were the faster.
        Ok((m, cache)) if m.speedup() < 1.0 => Some((
            Bf16Convolutions::Mixed,
            Some(mixed_choice_message(&m, cache.as_deref())),
        )),
        Ok(_) => Some((Bf16Convolutions::Native, None)),
        Err(e) => Some((
            Bf16Convolutions::Native,
            Some(format!(
                "warning: could not measure which bf16 convolutions train faster on this CPU \
                 ({e:#}); oneDNN's bf16 kernels run"
            )),
        )),
    }
}

/// The line that says bf16 training runs its spatial convolutions on fp32 kernels.
fn mixed_choice_message(m: &Measured, cache: Option<&Path>) -> String {
    let cached = cache.map_or("not cached".to_string(), |p| {
        format!("cached in {}", p.display())
    });
    format!(
        "bf16 training runs its 3x3 and larger convolutions on fp32 kernels over bf16 operands \
         here ({}=mixed): {} took {:.1} ms so against {:.1} ms on oneDNN's bf16 kernels (bf16 \
         operands, float sums either way; {cached}; {}=native|emulated|mixed decides instead)",
        rtf_amp::BF16_CONVOLUTIONS_VAR,
        Work::Conv3x3Training.workload(),
        1000.0 * m.fp32_s,
        1000.0 * m.bf16_s,
        rtf_amp::BF16_CONVOLUTIONS_VAR
    )
}

/// Before bf16 inference on the CPU (`eval`, `predict`, `bench model`, `export`): where bf16 is
/// native and [`rtf_models::winograd::BF16_VAR`] is unset, makes this process's choice between
/// the Winograd form and oneDNN's bf16 kernels for the wide 3×3 convolutions, by the cached
/// [`Work::Conv3x3`] measurement (measured first where there is none; on an Intel Xeon with AMX
/// oneDNN's kernels won 5×, with AMX capped off the Winograd form 3×: docs/src/benchmarks.md). Returns a
/// warning where the measurement failed (then oneDNN's kernels run, rtf-models' default).
pub fn choose_bf16_winograd() -> Option<String> {
    if std::env::var_os(rtf_models::winograd::BF16_VAR).is_some()
        || rtf_amp::cpu_has_native_bf16() != Some(true)
    {
        return None;
    }
    match measured(Work::Conv3x3) {
        Ok((m, _)) => {
            rtf_models::winograd::choose_bf16(m.speedup() < 1.0);
            None
        }
        Err(e) => Some(format!(
            "could not measure which bf16 3x3 convolutions are faster on this CPU ({e:#}); \
             oneDNN's bf16 kernels run"
        )),
    }
}

/// The warning for a measurement, if bf16 measured slower than fp32.
pub fn slower_message(work: Work, m: &Measured, cache: Option<&Path>) -> Option<String> {
    (m.speedup() < 1.0).then(|| {
        let cached = cache.map_or("not cached".to_string(), |p| {
            format!("cached in {}", p.display())
        });
        format!(
            "bf16 measured slower than fp32 on this CPU: {} took {:.1} ms in bf16 against {:.1} ms \
             in fp32 ({:.2}x fp32's speed; measured once for this CPU model, libtorch and thread \
             count, {cached}); use --precision fp32",
            work.workload(),
            1000.0 * m.bf16_s,
            1000.0 * m.fp32_s,
            m.speedup()
        )
    })
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
    fn only_a_slower_bf16_is_a_warning_and_it_names_the_times_and_the_cache() {
        let line = slower_message(
            Work::Inference,
            &m(0.060, 0.084),
            Some(Path::new("/c/p.json")),
        )
        .unwrap();
        assert!(
            line.contains("84.0 ms in bf16 against 60.0 ms in fp32 (0.71x"),
            "{line}"
        );
        assert!(line.contains("cached in /c/p.json") && line.ends_with("use --precision fp32"));
        assert!(!line.contains('\n'));
        let line = slower_message(Work::Training, &m(1.0, 2.0), None).unwrap();
        assert!(
            line.contains("training step") && line.contains("not cached"),
            "{line}"
        );
        assert_eq!(
            slower_message(Work::Inference, &m(0.060, 0.020), None),
            None
        );
        assert_eq!(
            slower_message(Work::Inference, &m(0.060, 0.060), None),
            None
        );
    }

    #[test]
    fn a_mixed_choice_is_said_with_both_times_and_the_way_to_decide_instead() {
        let line = mixed_choice_message(&m(0.120, 0.180), Some(Path::new("/c/p.json")));
        assert!(
            line.contains("forward and backward took 120.0 ms so against 180.0 ms"),
            "{line}"
        );
        assert!(
            line.contains("cached in /c/p.json") && line.contains("(RTF_BF16_CONVOLUTIONS=mixed)")
        );
        assert!(!line.contains('\n'));
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
    fn the_key_tells_the_works_apart_and_names_libtorch() {
        let (i, t) = (key(Work::Inference), key(Work::Training));
        assert_ne!(i, t);
        assert!(
            i.starts_with("inference | ")
                && i.contains("libtorch ")
                && i.contains(&format!("winograd r{}", rtf_models::winograd::REVISION)),
            "{i}"
        );
        assert!(
            !i.contains("libtorch ?"),
            "libtorch_cpu.so is mapped in a test: {i}"
        );
    }

    #[test]
    fn a_cache_round_trips_and_a_broken_one_reads_as_empty() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("sub/bf16-probe.json");
        let mut cache = Cache::default();
        cache.measurements.insert("k".into(), m(1.0, 0.5));
        write_cache(&path, &cache).unwrap();
        assert_eq!(read_cache(&path).measurements["k"], m(1.0, 0.5));
        std::fs::write(&path, "{ not json").unwrap();
        assert!(read_cache(&path).measurements.is_empty());
    }
}
