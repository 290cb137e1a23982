//! The machine a measurement ran on, for the benchmarks: the CPU's identity and the flags that
//! decide which kernels libtorch and oneDNN run (every speed number is given beside them: the
//! same network runs 4× faster or 2× slower in bf16 depending on them), and this process's
//! peak resident memory.

use serde::{Deserialize, Serialize};

/// The CPU flags that decide the kernels (x86 `/proc/cpuinfo` names), in the order reported.
pub const KERNEL_FLAGS: [&str; 5] = ["avx2", "avx512f", "avx512_bf16", "avx512_fp16", "amx_bf16"];

/// Identity and kernel-deciding flags of the CPU (its first processor in `/proc/cpuinfo`).
#[derive(Serialize, Deserialize, Clone, Debug, PartialEq, Eq, Default)]
pub struct CpuInfo {
    /// `vendor_id` (e.g. GenuineIntel, AuthenticAMD); "?" where unknown.
    pub vendor: String,
    /// `model name`.
    pub model_name: String,
    /// `cpu family` and `model`, as printed.
    pub family: String,
    pub model: String,
    /// The [`KERNEL_FLAGS`] this CPU has.
    pub flags: Vec<String>,
}

impl CpuInfo {
    /// This machine's, from `/proc/cpuinfo` (every field "?" and no flags where unreadable).
    pub fn read() -> Self {
        Self::parse(&std::fs::read_to_string("/proc/cpuinfo").unwrap_or_default())
    }

    /// From the text of `/proc/cpuinfo`: the first processor's fields.
    pub fn parse(cpuinfo: &str) -> Self {
        let field = |name: &str| {
            cpuinfo
                .lines()
                .filter_map(|l| l.split_once(':'))
                .find(|(k, _)| k.trim() == name)
                .map_or("?", |(_, v)| v.trim())
                .to_string()
        };
        let all_flags = field("flags");
        let present: Vec<&str> = all_flags.split_whitespace().collect();
        Self {
            vendor: field("vendor_id"),
            model_name: field("model name"),
            family: field("cpu family"),
            model: field("model"),
            flags: KERNEL_FLAGS
                .iter()
                .filter(|f| present.contains(f))
                .map(|f| f.to_string())
                .collect(),
        }
    }

    /// `GenuineIntel Intel(R) Xeon(R) Processor (family 6, model 167): avx2 … amx_bf16`.
    pub fn label(&self) -> String {
        let flags = if self.flags.is_empty() {
            format!("none of {}", KERNEL_FLAGS.join(", "))
        } else {
            self.flags.join(" ")
        };
        format!(
            "{} {} (family {}, model {}): {flags}",
            self.vendor, self.model_name, self.family, self.model
        )
    }
}

/// Peak resident set size of this process in MiB (`VmHWM` of /proc/self/status); None where
/// unknown.
pub fn peak_rss_mb() -> Option<f64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kib: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib / 1024.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    const CPUINFO: &str = "processor\t: 0\nvendor_id\t: GenuineIntel\ncpu family\t: 6\n\
        model\t\t: 167\nmodel name\t: Intel(R) Xeon(R) Processor\n\
        flags\t\t: fpu sse avx2 avx512f avx512_bf16 amx_bf16 amx_tile\n\n\
        processor\t: 1\nvendor_id\t: Other\n";

    #[test]
    fn the_first_processor_and_its_kernel_flags_are_read() {
        let cpu = CpuInfo::parse(CPUINFO);
        assert_eq!(cpu.vendor, "GenuineIntel");
        assert_eq!((cpu.family.as_str(), cpu.model.as_str()), ("6", "167"));
        assert_eq!(cpu.flags, ["avx2", "avx512f", "avx512_bf16", "amx_bf16"]);
        assert_eq!(
            cpu.label(),
            "GenuineIntel Intel(R) Xeon(R) Processor (family 6, model 167): \
             avx2 avx512f avx512_bf16 amx_bf16"
        );
    }

    #[test]
    fn an_unreadable_cpu_says_so() {
        let cpu = CpuInfo::parse("");
        assert_eq!(cpu.vendor, "?");
        assert!(cpu.label().contains("none of avx2"), "{}", cpu.label());
    }

    #[test]
    fn peak_memory_is_read_on_linux() {
        if cfg!(target_os = "linux") {
            assert!(peak_rss_mb().is_some_and(|m| m > 0.0));
        }
    }
}
