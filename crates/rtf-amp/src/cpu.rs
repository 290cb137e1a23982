//! Whether this process's CPU arithmetic has bf16 instructions ([`Bf16Arithmetic`]): the CPU's
//! flags (`/proc/cpuinfo`) under the instruction-set cap oneDNN was given ([`IsaCap`]).
//!
//! oneDNN (inside libtorch) reads its cap from the process's environment when it starts, and
//! libtorch does not export oneDNN's query of the ISA in force; so the cap is a value the
//! caller passes: rtf's binaries and the Python package read it at their edge
//! ([`IsaCap::from_vars`]), the library never reads the environment.

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

/// oneDNN's instruction-set cap where it keeps oneDNN below `AVX512_CORE_BF16`: the variable
/// that set it and the ISA named. Any other value (none, `AVX512_CORE_BF16`, `ALL`, a name
/// oneDNN does not know) caps nothing that matters here and is [`IsaCap::NONE`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize)]
pub struct IsaCap(Option<(&'static str, &'static str)>);

impl IsaCap {
    /// No cap below bf16.
    pub const NONE: IsaCap = IsaCap(None);

    /// The cap of a process whose variables `get` reads (rtf's binaries pass their
    /// environment, the Python package `os.environ`): the first of [`ONEDNN_ISA_VARS`] set.
    /// oneDNN compares the value with its upper-case names exactly (`strcmp` in
    /// `cpu_isa_traits.cpp`), so anything else (`avx2`, `ALL`, `DEFAULT`) caps nothing.
    pub fn from_vars(get: impl Fn(&str) -> Option<String>) -> Self {
        let Some((var, value)) = ONEDNN_ISA_VARS
            .iter()
            .find_map(|var| Some((*var, get(var)?)))
        else {
            return Self::NONE;
        };
        let isa = ISAS_WITHOUT_BF16.iter().find(|isa| **isa == value);
        IsaCap(isa.map(|isa| (var, *isa)))
    }

    /// `(variable, ISA)` where the cap keeps oneDNN below `AVX512_CORE_BF16`.
    pub fn below_bf16(self) -> Option<(&'static str, &'static str)> {
        self.0
    }
}

/// Whether the CPU arithmetic of this process has bf16 instructions, and if not, why.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Bf16Arithmetic {
    /// x86 `avx512_bf16` or `amx_bf16`, Arm `bf16` in `/proc/cpuinfo`, and no oneDNN ISA cap
    /// below them.
    Native,
    /// The CPU lacks the flags (e.g. an AVX2-only x86).
    MissingFromCpu,
    /// The CPU has them, but `var=isa` caps oneDNN below `AVX512_CORE_BF16` (how the AVX2 path
    /// is exercised on an AVX-512 machine).
    CappedBy {
        var: &'static str,
        isa: &'static str,
    },
    /// `/proc/cpuinfo` is unreadable or names no flags.
    Unknown,
}

impl Bf16Arithmetic {
    /// This CPU's: the flags of `/proc/cpuinfo` under `cap` (the process's oneDNN cap, read by
    /// the caller: [`IsaCap::from_vars`]). Without bf16 arithmetic, oneDNN emulates bf16
    /// convolutions and CPU mixed precision is far slower than fp32, in PyTorch and rtf alike
    /// (measured: docs/src/benchmarks.md, section "Round 3: the issue's size on a quiet
    /// machine").
    pub fn of_cpu(cap: IsaCap) -> Self {
        let flags = std::fs::read_to_string("/proc/cpuinfo")
            .ok()
            .and_then(|info| cpuinfo_has_native_bf16(&info));
        Self::from_flags(flags, cap)
    }

    /// [`of_cpu`](Self::of_cpu) under the cap of the variables `get` reads.
    pub fn from_vars(get: impl Fn(&str) -> Option<String>) -> Self {
        Self::of_cpu(IsaCap::from_vars(get))
    }

    /// From the CPU's flag (`None`: unknown) and oneDNN's cap.
    pub fn from_flags(cpu_flags: Option<bool>, cap: IsaCap) -> Self {
        match (cpu_flags, cap.below_bf16()) {
            (Some(false), _) => Bf16Arithmetic::MissingFromCpu,
            (None, _) => Bf16Arithmetic::Unknown,
            (Some(true), Some((var, isa))) => Bf16Arithmetic::CappedBy { var, isa },
            (Some(true), None) => Bf16Arithmetic::Native,
        }
    }

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

#[cfg(test)]
mod tests {
    use super::*;

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

    fn vars<'a>(pairs: &'a [(&'a str, &'a str)]) -> impl Fn(&str) -> Option<String> + 'a {
        move |name| {
            pairs
                .iter()
                .find(|(k, _)| *k == name)
                .map(|(_, v)| v.to_string())
        }
    }

    #[test]
    fn the_cap_is_the_first_variable_set_and_only_below_bf16() {
        let cap = IsaCap::from_vars(vars(&[("ONEDNN_MAX_CPU_ISA", "AVX2")]));
        assert_eq!(cap.below_bf16(), Some(("ONEDNN_MAX_CPU_ISA", "AVX2")));
        let cap = IsaCap::from_vars(vars(&[("DNNL_MAX_CPU_ISA", "AVX512_CORE_VNNI")]));
        assert_eq!(
            cap.below_bf16(),
            Some(("DNNL_MAX_CPU_ISA", "AVX512_CORE_VNNI"))
        );
        // oneDNN reads ONEDNN_ first: a value there that caps nothing wins over DNNL_'s.
        let both = [("ONEDNN_MAX_CPU_ISA", "ALL"), ("DNNL_MAX_CPU_ISA", "AVX2")];
        assert_eq!(IsaCap::from_vars(vars(&both)), IsaCap::NONE);
        for isa in [
            "AVX512_CORE_BF16",
            "AVX512_CORE_AMX",
            "ALL",
            "DEFAULT",
            "avx2",
            "x",
        ] {
            let cap = IsaCap::from_vars(vars(&[("ONEDNN_MAX_CPU_ISA", isa)]));
            assert_eq!(cap, IsaCap::NONE, "{isa}");
        }
        assert_eq!(IsaCap::from_vars(vars(&[])), IsaCap::NONE);
    }

    #[test]
    fn a_onednn_isa_cap_below_avx512_core_bf16_makes_bf16_not_native() {
        use Bf16Arithmetic::*;
        let cap = |isa: &str| IsaCap::from_vars(vars(&[("ONEDNN_MAX_CPU_ISA", isa)]));
        assert_eq!(Bf16Arithmetic::from_flags(Some(true), IsaCap::NONE), Native);
        assert_eq!(
            Bf16Arithmetic::from_flags(Some(false), IsaCap::NONE),
            MissingFromCpu
        );
        assert_eq!(Bf16Arithmetic::from_flags(None, cap("AVX2")), Unknown);
        let capped = Bf16Arithmetic::from_flags(Some(true), cap("AVX2"));
        assert_eq!(capped.is_native(), Some(false));
        assert_eq!(
            capped.reason(),
            "ONEDNN_MAX_CPU_ISA=AVX2 keeps oneDNN below AVX512_CORE_BF16"
        );
        let vnni = Bf16Arithmetic::from_flags(Some(true), cap("AVX512_CORE_VNNI"));
        assert_eq!(vnni.is_native(), Some(false));
        for isa in ["AVX512_CORE_BF16", "ALL", "avx2"] {
            assert_eq!(
                Bf16Arithmetic::from_flags(Some(true), cap(isa)),
                Native,
                "{isa}"
            );
        }
        // A CPU without the flags stays without them, whatever the cap.
        assert_eq!(
            Bf16Arithmetic::from_flags(Some(false), cap("ALL")),
            MissingFromCpu
        );
        assert!(MissingFromCpu.reason().contains("avx512_bf16"));
        // The cap given is the cap taken: this CPU's arithmetic under AVX2 is never native.
        assert_ne!(Bf16Arithmetic::of_cpu(cap("AVX2")).is_native(), Some(true));
    }
}
