//! Autocast regions (automatic mixed precision) on every libtorch device, CPU included.
//!
//! Inside a region, libtorch's autocast dispatch runs the ops that profit from lower precision
//! (convolutions, matrix products) in a reduced float type and keeps the precision-sensitive
//! ones (reductions, losses, BatchNorm statistics) in fp32, with fp32 master weights cast once
//! per region (PyTorch's `torch.autocast`, "Automatic Mixed Precision" in the PyTorch docs;
//! Micikevicius et al., "Mixed Precision Training", ICLR 2018). tch 0.26's `tch::autocast`
//! drives only CUDA's state, so the state of any device type is set through a small C++ shim
//! (`csrc/amp_shim.cpp`) over `at::autocast::{set_autocast_enabled, set_autocast_dtype}`.
//!
//! [`autocast`] enters a region for one closure; [`AutocastGuard`] restores the previous state
//! when dropped, also when the closure panics.

use std::ffi::c_int;

mod precision;
pub use precision::Precision;

use tch::{Device, Kind};

extern "C" {
    fn rtf_amp_get(device_type: c_int, enabled: *mut c_int, dtype: *mut c_int) -> c_int;
    fn rtf_amp_set(device_type: c_int, enabled: c_int, dtype: c_int) -> c_int;
    fn rtf_amp_enter() -> c_int;
    fn rtf_amp_exit() -> c_int;
}

/// Errors of the autocast shim.
#[derive(Debug, thiserror::Error)]
pub enum AmpError {
    #[error("libtorch refused to {0} autocast")]
    Refused(&'static str),
    #[error("autocast to {kind:?} is not supported on {device:?} (CPU: bf16; CUDA: bf16, fp16)")]
    Unsupported { device: Device, kind: Kind },
    #[error("environment variable {BF16_CONVOLUTIONS_VAR}=`{0}`: expected `native`, `emulated` or `mixed`")]
    BadConvolutionChoice(String),
}

/// c10::DeviceType code of `device` (c10/core/DeviceType.h: CPU = 0, CUDA = 1, MPS = 13,
/// Vulkan = 10).
fn device_type(device: Device) -> c_int {
    match device {
        Device::Cpu => 0,
        Device::Cuda(_) => 1,
        Device::Vulkan => 10,
        Device::Mps => 13,
    }
}

/// c10::ScalarType code of the float kinds autocast casts to (torch/headeronly/core/ScalarType.h).
fn scalar_type(kind: Kind) -> c_int {
    match kind {
        Kind::Half => 5,
        Kind::Float => 6,
        Kind::BFloat16 => 15,
        // Never reached: only supported kinds are set, and Float is the neutral value.
        _ => 6,
    }
}

fn kind_of(code: c_int) -> Option<Kind> {
    match code {
        5 => Some(Kind::Half),
        6 => Some(Kind::Float),
        15 => Some(Kind::BFloat16),
        _ => None,
    }
}

/// Autocast state of one device type.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct State {
    pub enabled: bool,
    /// The reduced type autocast casts to (libtorch's defaults: bf16 on CPU, fp16 on CUDA;
    /// Float for a type this crate does not name).
    pub dtype: Kind,
}

/// The calling thread's autocast state for `device`'s type.
pub fn state(device: Device) -> Result<State, AmpError> {
    let (mut enabled, mut dtype) = (0, 0);
    // SAFETY: the shim writes two ints through valid pointers and catches every C++ exception.
    let status = unsafe { rtf_amp_get(device_type(device), &mut enabled, &mut dtype) };
    if status != 0 {
        return Err(AmpError::Refused("read"));
    }
    Ok(State {
        enabled: enabled != 0,
        dtype: kind_of(dtype).unwrap_or(Kind::Float),
    })
}

fn set_state(device: Device, state: State) -> Result<(), AmpError> {
    // SAFETY: plain values in; the shim catches every C++ exception.
    let status = unsafe {
        rtf_amp_set(
            device_type(device),
            c_int::from(state.enabled),
            scalar_type(state.dtype),
        )
    };
    if status != 0 {
        return Err(AmpError::Refused("set"));
    }
    Ok(())
}

/// Whether `kind` is an autocast type libtorch supports on `device`.
pub fn supported(device: Device, kind: Kind) -> bool {
    match device {
        Device::Cpu => kind == Kind::BFloat16,
        Device::Cuda(_) => matches!(kind, Kind::BFloat16 | Kind::Half),
        _ => false,
    }
}

/// Whether this process has native bf16 arithmetic on the CPU ([`cpu_bf16_arithmetic`]);
/// `None` where that cannot be told. Without it, oneDNN emulates bf16 convolutions and CPU
/// mixed precision is far slower than fp32 (MFNet training at 640×480 on an AVX2 EPYC: 0.14
/// against 1.42 images/s, docs/src/benchmarks.md), in PyTorch and rtf alike: worth a warning
/// before hours of training.
pub fn cpu_has_native_bf16() -> Option<bool> {
    cpu_bf16_arithmetic().is_native()
}

/// The environment variables by which oneDNN caps the instruction set it uses, in the order it
/// reads them (oneDNN's "CPU Dispatcher Control": `ONEDNN_` first, then the older `DNNL_`).
pub const ONEDNN_ISA_VARS: [&str; 2] = ["ONEDNN_MAX_CPU_ISA", "DNNL_MAX_CPU_ISA"];

/// oneDNN's ISA names (`dnnl_cpu_isa_t`) below `AVX512_CORE_BF16`: capped to one of these,
/// oneDNN has no bf16 instructions even on a CPU that has them.
const ISAS_WITHOUT_BF16: [&str; 7] = [
    "SSE41",
    "AVX",
    "AVX2",
    "AVX2_VNNI",
    "AVX2_VNNI_2",
    "AVX512_CORE",
    "AVX512_CORE_VNNI",
];

/// Whether the CPU arithmetic of this process has bf16 instructions, and if not, why.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Bf16Arithmetic {
    /// x86 `avx512_bf16` or `amx_bf16`, Arm `bf16` in `/proc/cpuinfo`, and no oneDNN ISA cap
    /// below them.
    Native,
    /// The CPU lacks the flags (e.g. an AVX2-only x86).
    MissingFromCpu,
    /// The CPU has them, but `var=isa` caps oneDNN below `AVX512_CORE_BF16` (how the AVX2 path
    /// is exercised on an AVX-512 machine).
    CappedBy { var: &'static str, isa: String },
    /// `/proc/cpuinfo` is unreadable or names no flags.
    Unknown,
}

impl Bf16Arithmetic {
    /// `Some(true)` for native, `None` for unknown.
    pub fn is_native(&self) -> Option<bool> {
        match self {
            Bf16Arithmetic::Native => Some(true),
            Bf16Arithmetic::MissingFromCpu | Bf16Arithmetic::CappedBy { .. } => Some(false),
            Bf16Arithmetic::Unknown => None,
        }
    }

    /// Why bf16 is not native, in words for a warning ("" when it is or cannot be told).
    pub fn reason(&self) -> String {
        match self {
            Bf16Arithmetic::MissingFromCpu => {
                "no avx512_bf16, amx_bf16 or bf16 in /proc/cpuinfo".to_owned()
            }
            Bf16Arithmetic::CappedBy { var, isa } => {
                format!("{var}={isa} keeps oneDNN below AVX512_CORE_BF16")
            }
            Bf16Arithmetic::Native | Bf16Arithmetic::Unknown => String::new(),
        }
    }
}

/// This process's [`Bf16Arithmetic`]: the CPU flags of `/proc/cpuinfo`, capped by
/// [`ONEDNN_ISA_VARS`] where set.
pub fn cpu_bf16_arithmetic() -> Bf16Arithmetic {
    let flags = std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|info| cpuinfo_has_native_bf16(&info));
    let cap = ONEDNN_ISA_VARS
        .iter()
        .find_map(|var| Some((*var, std::env::var(var).ok()?)));
    bf16_arithmetic(flags, cap)
}

/// [`cpu_bf16_arithmetic`] from the CPU's flag (`None`: unknown) and the first oneDNN ISA
/// variable set, if any. oneDNN compares the value with its upper-case names exactly (`strcmp`
/// in `cpu_isa_traits.cpp`), so anything else (`avx2`, `ALL`, `DEFAULT`) caps nothing.
fn bf16_arithmetic(cpu_flags: Option<bool>, cap: Option<(&'static str, String)>) -> Bf16Arithmetic {
    match cpu_flags {
        Some(false) => return Bf16Arithmetic::MissingFromCpu,
        None => return Bf16Arithmetic::Unknown,
        Some(true) => {}
    }
    match cap {
        Some((var, isa)) if ISAS_WITHOUT_BF16.contains(&isa.as_str()) => {
            Bf16Arithmetic::CappedBy { var, isa }
        }
        _ => Bf16Arithmetic::Native,
    }
}

/// Whether a `/proc/cpuinfo` names native bf16 arithmetic (x86: `avx512_bf16` or `amx_bf16`;
/// Arm: `bf16`); `None` where it names no flags.
fn cpuinfo_has_native_bf16(info: &str) -> Option<bool> {
    // x86 lists "flags", Arm "Features"; the first such line speaks for every core.
    let line = info
        .lines()
        .find(|l| l.starts_with("flags") || l.starts_with("Features"))?;
    let (_, flags) = line.split_once(':')?;
    Some(
        flags
            .split_whitespace()
            .any(|f| matches!(f, "avx512_bf16" | "amx_bf16" | "bf16")),
    )
}

/// The environment variable that overrides [`cpu_bf16_convolutions`]'s choice.
pub const BF16_CONVOLUTIONS_VAR: &str = "RTF_BF16_CONVOLUTIONS";

/// How convolutions inside a CPU bf16 autocast region are computed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Bf16Convolutions {
    /// libtorch's own bf16 kernels (oneDNN's where the CPU has bf16 arithmetic).
    Native,
    /// Operands rounded to bf16, multiply-accumulated by fp32 kernels, outputs and operand
    /// gradients rounded to bf16: a native kernel's numbers (bf16 products are exact in fp32,
    /// native kernels accumulate in fp32) at fp32 kernels' speed, on CPUs whose libtorch bf16
    /// kernels are generic (no avx512_bf16 / AMX: ~10× slower than fp32). rtf's networks route
    /// their convolutions through it (rtf-models `layers`).
    Emulated,
    /// Spatial convolutions (3×3 and larger, not transposed) emulated, the others (1×1,
    /// transposed) on libtorch's bf16 kernels: on Intel AVX-512 without AMX, oneDNN's bf16 3×3
    /// kernels lose to its fp32 ones while its 1×1 kernels do not (issue 41; chosen there by
    /// measurement, rtf-cli `bf16_kernels`).
    Mixed,
}

impl Bf16Convolutions {
    pub fn name(self) -> &'static str {
        match self {
            Bf16Convolutions::Native => "native",
            Bf16Convolutions::Emulated => "emulated",
            Bf16Convolutions::Mixed => "mixed",
        }
    }

    /// Whether a convolution with a spatial kernel (`spatial`: larger than 1×1, not transposed)
    /// or not is computed emulated under this choice.
    pub fn emulates(self, spatial: bool) -> bool {
        match self {
            Bf16Convolutions::Native => false,
            Bf16Convolutions::Emulated => true,
            Bf16Convolutions::Mixed => spatial,
        }
    }
}

/// This process's choice where the environment leaves it open and the CPU has bf16
/// arithmetic: made once, by a measurement or from a run's record ([`choose_process_bf16_convolutions`]).
static PROCESS_CHOICE: std::sync::OnceLock<Bf16Convolutions> = std::sync::OnceLock::new();

/// The choice in force: `RTF_BF16_CONVOLUTIONS=native|emulated|mixed` if set, else emulated
/// where the CPU is known to lack bf16 arithmetic ([`cpu_has_native_bf16`]), else this
/// process's choice if one was made ([`choose_process_bf16_convolutions`]), else native. The
/// variable and the CPU's flags are read once.
pub fn cpu_bf16_convolutions() -> Result<Bf16Convolutions, AmpError> {
    static FROM_ENV: std::sync::OnceLock<Result<Option<Bf16Convolutions>, String>> =
        std::sync::OnceLock::new();
    let from_env = FROM_ENV
        .get_or_init(|| {
            parse_bf16_convolutions(std::env::var(BF16_CONVOLUTIONS_VAR).ok().as_deref())
        })
        .clone()
        .map_err(AmpError::BadConvolutionChoice)?;
    Ok(choose_bf16_convolutions(
        from_env,
        PROCESS_CHOICE.get().copied(),
        cpu_has_native_bf16(),
    ))
}

/// Whether `RTF_BF16_CONVOLUTIONS` makes the choice (set, to a valid value or not).
pub fn bf16_convolutions_set_by_env() -> bool {
    std::env::var_os(BF16_CONVOLUTIONS_VAR).is_some()
}

/// Makes this process's choice (the first call's stands) and returns the choice then in force
/// ([`cpu_bf16_convolutions`]: the variable and a CPU without bf16 arithmetic still decide).
pub fn choose_process_bf16_convolutions(
    choice: Bf16Convolutions,
) -> Result<Bf16Convolutions, AmpError> {
    let _ = PROCESS_CHOICE.set(choice);
    cpu_bf16_convolutions()
}

/// The variable's value: `None` where unset, an error naming the value where it is neither
/// `native`, `emulated` nor `mixed`.
fn parse_bf16_convolutions(var: Option<&str>) -> Result<Option<Bf16Convolutions>, String> {
    match var.map(str::trim) {
        None => Ok(None),
        Some("native") => Ok(Some(Bf16Convolutions::Native)),
        Some("emulated") => Ok(Some(Bf16Convolutions::Emulated)),
        Some("mixed") => Ok(Some(Bf16Convolutions::Mixed)),
        Some(other) => Err(other.to_owned()),
    }
}

/// [`cpu_bf16_convolutions`] from the variable's choice, the process's and the CPU's bf16 flag.
fn choose_bf16_convolutions(
    from_env: Option<Bf16Convolutions>,
    process: Option<Bf16Convolutions>,
    native_bf16: Option<bool>,
) -> Bf16Convolutions {
    match (from_env, process) {
        (Some(choice), _) => choice,
        _ if native_bf16 == Some(false) => Bf16Convolutions::Emulated,
        (None, Some(choice)) => choice,
        (None, None) => Bf16Convolutions::Native,
    }
}

/// Whether bf16 convolutions on `device` are the emulated ones: a CPU, with
/// [`Bf16Convolutions::Emulated`] chosen.
pub fn emulates_bf16_convolutions_on(device: Device) -> bool {
    device == Device::Cpu && matches!(cpu_bf16_convolutions(), Ok(Bf16Convolutions::Emulated))
}

/// Whether a convolution of an input on `device` made now, on this thread, should be the
/// emulated bf16 one: inside a CPU bf16 autocast region, where the choice in force
/// ([`cpu_bf16_convolutions`]) emulates such a convolution (`spatial`: a kernel larger than
/// 1×1, not transposed; [`Bf16Convolutions::emulates`]).
pub fn emulates_bf16_convolution(device: Device, spatial: bool) -> bool {
    device == Device::Cpu
        && cpu_bf16_convolutions().is_ok_and(|c| c.emulates(spatial))
        && state(Device::Cpu).is_ok_and(|s| s.enabled && s.dtype == Kind::BFloat16)
}

/// An open autocast region on one device type; dropping it leaves the region and restores the
/// state before it (the weight-cast cache is dropped when the outermost region ends).
#[derive(Debug)]
pub struct AutocastGuard {
    device: Device,
    previous: State,
}

impl AutocastGuard {
    /// Enters an autocast region to `kind` on `device`'s type for this thread.
    pub fn enter(device: Device, kind: Kind) -> Result<Self, AmpError> {
        if !supported(device, kind) {
            return Err(AmpError::Unsupported { device, kind });
        }
        let previous = state(device)?;
        set_state(
            device,
            State {
                enabled: true,
                dtype: kind,
            },
        )?;
        // SAFETY: no arguments; the shim catches every C++ exception.
        if unsafe { rtf_amp_enter() } != 0 {
            let _ = set_state(device, previous);
            return Err(AmpError::Refused("enter"));
        }
        Ok(Self { device, previous })
    }
}

impl Drop for AutocastGuard {
    fn drop(&mut self) {
        // SAFETY: no arguments; the shim catches every C++ exception. Failures cannot be
        // reported from drop; the state setter below is the part that matters.
        let _ = unsafe { rtf_amp_exit() };
        let _ = set_state(self.device, self.previous);
    }
}

/// `f` inside an autocast region to `kind` on `device` (`None`: `f` as is, no region).
pub fn autocast<T>(
    device: Device,
    kind: Option<Kind>,
    f: impl FnOnce() -> T,
) -> Result<T, AmpError> {
    let _guard = match kind {
        Some(kind) => Some(AutocastGuard::enter(device, kind)?),
        None => None,
    };
    Ok(f())
}

#[cfg(test)]
mod tests {
    use super::*;
    use tch::Tensor;

    #[test]
    fn native_bf16_is_read_from_the_cpu_flags() {
        let x86 = "processor\t: 0\nflags\t\t: fpu sse2 avx2 fma\n";
        assert_eq!(cpuinfo_has_native_bf16(x86), Some(false));
        let zen5 = "flags\t\t: fpu avx2 avx512f avx512_bf16 avx512_vnni\n";
        assert_eq!(cpuinfo_has_native_bf16(zen5), Some(true));
        let arm = "processor\t: 0\nFeatures\t: fp asimd sve bf16 i8mm\n";
        assert_eq!(cpuinfo_has_native_bf16(arm), Some(true));
        assert_eq!(cpuinfo_has_native_bf16("processor\t: 0\n"), None);
    }

    #[test]
    fn a_onednn_isa_cap_below_avx512_core_bf16_makes_bf16_not_native() {
        use Bf16Arithmetic::*;
        let cap = |isa: &str| Some(("ONEDNN_MAX_CPU_ISA", isa.to_owned()));
        assert_eq!(bf16_arithmetic(Some(true), None), Native);
        assert_eq!(bf16_arithmetic(Some(false), None), MissingFromCpu);
        assert_eq!(bf16_arithmetic(None, cap("AVX2")), Unknown);
        let capped = bf16_arithmetic(Some(true), cap("AVX2"));
        assert_eq!(capped.is_native(), Some(false));
        assert_eq!(
            capped.reason(),
            "ONEDNN_MAX_CPU_ISA=AVX2 keeps oneDNN below AVX512_CORE_BF16"
        );
        assert_eq!(
            bf16_arithmetic(Some(true), cap("AVX512_CORE_VNNI")).is_native(),
            Some(false)
        );
        for isa in [
            "AVX512_CORE_BF16",
            "AVX512_CORE_AMX",
            "ALL",
            "DEFAULT",
            "avx2",
            "nonsense",
        ] {
            assert_eq!(bf16_arithmetic(Some(true), cap(isa)), Native, "{isa}");
        }
        // A CPU without the flags stays without them, whatever the cap.
        assert_eq!(bf16_arithmetic(Some(false), cap("ALL")), MissingFromCpu);
        assert!(MissingFromCpu.reason().contains("avx512_bf16"));
    }

    #[test]
    fn bf16_convolutions_are_emulated_where_the_cpu_lacks_bf16_unless_told() {
        use Bf16Convolutions::*;
        let choose = choose_bf16_convolutions;
        assert_eq!(choose(None, None, Some(false)), Emulated);
        assert_eq!(choose(None, None, Some(true)), Native);
        assert_eq!(choose(None, None, None), Native);
        // The process's choice (measured, or a run's record) where the CPU has bf16 ...
        assert_eq!(choose(None, Some(Emulated), Some(true)), Emulated);
        assert_eq!(choose(None, Some(Emulated), None), Emulated);
        // ... but not where it has none: libtorch's generic kernels only when told.
        assert_eq!(choose(None, Some(Native), Some(false)), Emulated);
        // The variable over both.
        assert_eq!(choose(Some(Native), Some(Emulated), Some(false)), Native);
        assert_eq!(choose(Some(Emulated), Some(Native), Some(true)), Emulated);
        assert_eq!(choose(None, Some(Mixed), Some(true)), Mixed);
        assert_eq!(choose(None, Some(Mixed), Some(false)), Emulated);
        assert_eq!(parse_bf16_convolutions(Some("mixed")), Ok(Some(Mixed)));
        // Mixed: spatial kernels emulated, 1×1 and transposed on the bf16 kernels.
        assert!(Mixed.emulates(true) && !Mixed.emulates(false));
        assert!(Emulated.emulates(false) && !Native.emulates(true));
        assert_eq!(parse_bf16_convolutions(Some(" native")), Ok(Some(Native)));
        assert_eq!(
            parse_bf16_convolutions(Some("emulated")),
            Ok(Some(Emulated))
        );
        assert_eq!(parse_bf16_convolutions(None), Ok(None));
        let err = parse_bf16_convolutions(Some("fast")).unwrap_err();
        let message = AmpError::BadConvolutionChoice(err).to_string();
        assert!(
            message.contains("RTF_BF16_CONVOLUTIONS=`fast`"),
            "{message}"
        );
    }

    #[test]
    fn the_choice_is_recorded_by_its_name() {
        let text = serde_json::to_string(&Bf16Convolutions::Emulated).unwrap();
        assert_eq!(text, "\"emulated\"");
        let back: Bf16Convolutions = serde_json::from_str("\"native\"").unwrap();
        assert_eq!(back, Bf16Convolutions::Native);
    }

    #[test]
    fn only_cpu_bf16_regions_emulate_and_only_if_chosen() {
        let chosen = cpu_bf16_convolutions().unwrap();
        assert!(
            !emulates_bf16_convolution(Device::Cpu, true),
            "no region open"
        );
        autocast(Device::Cpu, Some(Kind::BFloat16), || {
            for spatial in [true, false] {
                assert_eq!(
                    emulates_bf16_convolution(Device::Cpu, spatial),
                    chosen.emulates(spatial)
                );
                assert!(!emulates_bf16_convolution(Device::Cuda(0), spatial));
            }
        })
        .unwrap();
    }

    fn conv_output_kind() -> Kind {
        let x = Tensor::ones([1, 2, 5, 5], (Kind::Float, Device::Cpu));
        let w = Tensor::ones([3, 2, 3, 3], (Kind::Float, Device::Cpu));
        x.conv2d(&w, None::<Tensor>, [1, 1], [1, 1], [1, 1], 1)
            .kind()
    }

    #[test]
    fn cpu_region_runs_convolutions_in_bf16_and_restores_the_state() {
        let before = state(Device::Cpu).unwrap();
        assert!(!before.enabled);
        assert_eq!(conv_output_kind(), Kind::Float);
        let inside = autocast(Device::Cpu, Some(Kind::BFloat16), || {
            assert!(state(Device::Cpu).unwrap().enabled);
            conv_output_kind()
        })
        .unwrap();
        assert_eq!(inside, Kind::BFloat16);
        assert_eq!(state(Device::Cpu).unwrap(), before);
        assert_eq!(conv_output_kind(), Kind::Float);
    }

    #[test]
    fn nested_regions_restore_the_outer_one() {
        let outer = AutocastGuard::enter(Device::Cpu, Kind::BFloat16).unwrap();
        {
            let _inner = AutocastGuard::enter(Device::Cpu, Kind::BFloat16).unwrap();
        }
        assert!(
            state(Device::Cpu).unwrap().enabled,
            "outer region still open"
        );
        drop(outer);
        assert!(!state(Device::Cpu).unwrap().enabled);
    }

    #[test]
    fn a_panic_inside_the_region_still_restores_the_state() {
        let result = std::panic::catch_unwind(|| {
            autocast(Device::Cpu, Some(Kind::BFloat16), || panic!("inside")).unwrap()
        });
        assert!(result.is_err());
        assert!(!state(Device::Cpu).unwrap().enabled);
    }

    #[test]
    fn no_kind_means_no_region() {
        let kind = autocast(Device::Cpu, None, conv_output_kind).unwrap();
        assert_eq!(kind, Kind::Float);
    }

    #[test]
    fn fp16_on_cpu_is_refused() {
        let err = AutocastGuard::enter(Device::Cpu, Kind::Half).unwrap_err();
        assert!(matches!(err, AmpError::Unsupported { .. }), "{err}");
    }
}
