//! The inference kernel policy (project issue 61): which kernels the fast path takes where
//! there is a choice, resolved once by the caller and passed into the fold
//! ([`rtf_models::fast::FoldOptions`]), so that `rtf predict`, `rtf eval`, `rtf bench model`
//! and a library caller (the Python package) fold the same network the same way.
//!
//! A [`KernelPolicy`] holds what the user decided and what the process's CPU arithmetic is
//! (rtf's binaries read both from their environment, [`KernelPolicy::from_vars`]: oneDNN's ISA
//! cap is one of its variables; the library never reads one); [`inference_kernels`]
//! resolves what it leaves open for a precision and device: bf16's wide 3×3 convolutions in the
//! Winograd forms or on oneDNN's bf16 kernels, by a measurement of both on this CPU, cached
//! ([`probe`]). Every way computes the same function (bf16 maps, float sums); only the speed
//! differs, and the rounding inside the kernels.

pub mod probe;
pub mod warning;

pub use warning::inference_warning;

use rtf_amp::{AmpError, Bf16Convolutions, Bf16Policy};
use rtf_kernels::winograd::Forms;
use rtf_models::fast::{InferenceKernels, Precision};
use tch::Device;

/// The variable that decides [`KernelPolicy::winograd`] in rtf's binaries.
pub const WINOGRAD_VAR: &str = "RTF_WINOGRAD";
/// The variable that decides [`KernelPolicy::bf16_winograd`] in rtf's binaries.
pub const BF16_WINOGRAD_VAR: &str = "RTF_BF16_WINOGRAD";

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum KernelError {
    #[error("{var}={value:?}: expected {expected}")]
    BadValue {
        var: &'static str,
        value: String,
        expected: &'static str,
    },
    #[error(transparent)]
    Bf16(#[from] AmpError),
}

/// The kernel choices a user made, and the CPU arithmetic they are made on; `None` leaves a
/// choice to [`inference_kernels`]. `Default`: nothing chosen, this CPU's flags without an ISA
/// cap.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize)]
pub struct KernelPolicy {
    /// The Winograd forms allowed (fp32 inference and training, bf16 inference).
    pub winograd: Forms,
    /// bf16 inference's wide 3×3 convolutions in the Winograd forms (`true`) or on oneDNN's
    /// bf16 kernels; `None`: measured on this CPU where it has bf16 arithmetic.
    pub bf16_winograd: Option<bool>,
    /// bf16 convolutions on the CPU: the user's choice (`RTF_BF16_CONVOLUTIONS`) and the CPU's
    /// bf16 arithmetic under oneDNN's ISA cap ([`Bf16Policy`]).
    pub bf16: Bf16Policy,
}

impl KernelPolicy {
    /// The policy from variables (`get(name)`, e.g. a process's environment):
    /// `RTF_WINOGRAD=on|f23|off`, `RTF_BF16_WINOGRAD=on|off`, `RTF_BF16_CONVOLUTIONS`
    /// and oneDNN's ISA cap ([`Bf16Policy::from_vars`]); a bad value is an error naming the
    /// variable.
    pub fn from_vars(get: impl Fn(&str) -> Option<String>) -> Result<Self, KernelError> {
        let bad = |var, value: &str, expected| KernelError::BadValue {
            var,
            value: value.to_owned(),
            expected,
        };
        let winograd = match get(WINOGRAD_VAR) {
            Some(v) => v
                .parse()
                .map_err(|_| bad(WINOGRAD_VAR, &v, "on, f23 or off"))?,
            None => Forms::All,
        };
        let bf16_winograd = match get(BF16_WINOGRAD_VAR).as_deref().map(str::trim) {
            Some("on") => Some(true),
            Some("off") => Some(false),
            Some(other) => return Err(bad(BF16_WINOGRAD_VAR, other, "on or off")),
            None => None,
        };
        Ok(Self {
            winograd,
            bf16_winograd,
            bf16: Bf16Policy::from_vars(&get)?,
        })
    }

    /// How bf16 folds on the CPU compute their convolutions: on fp32 kernels over bf16 maps
    /// where [`Bf16Convolutions::Emulated`] (the CPU has no bf16 arithmetic, or the user chose
    /// it), else on oneDNN's bf16 kernels. Inference measures nothing here: the measured
    /// mixed choice is training's (rtf-train `kernels`).
    pub fn inference_convolutions(&self) -> Bf16Convolutions {
        match self.bf16.in_force(None) {
            Bf16Convolutions::Emulated => Bf16Convolutions::Emulated,
            _ => Bf16Convolutions::Native,
        }
    }
}

/// How many times as long oneDNN's bf16 kernels must take as the Winograd form on the probe's
/// layer ([`probe::measure_conv3x3`]) for bf16 inference to take the Winograd forms. The probe
/// times one wide layer at a shape that suits Winograd, and the bf16 forms keep float32
/// transformed weights (more memory), so a narrow win on that layer is a loss on whole
/// networks: on AMD Zen 4 the layer was 7 % faster in the Winograd form and RTFNet-18 1.4×
/// slower. Without AMX on Intel, where oneDNN's bf16 3×3 kernels lose to fp32 ones, the layer
/// is 3× faster in the Winograd form (docs/src/benchmarks.md, "Who decides").
pub const BF16_WINOGRAD_MARGIN: f64 = 1.5;

/// Whether the probe's measurement `m` of the wide 3×3 layer says the Winograd forms win
/// clearly ([`BF16_WINOGRAD_MARGIN`]).
pub fn winograd_wins(m: &probe::Measured) -> bool {
    m.speedup() * BF16_WINOGRAD_MARGIN < 1.0
}

/// The kernels a fold for `precision` on `device` takes under `policy`, with the warnings to
/// give (a failed measurement). bf16 on a CPU with bf16 arithmetic and no choice made: the
/// Winograd forms where they are clearly faster on a wide 3×3 layer as measured here
/// ([`winograd_wins`]; [`probe::Work::Conv3x3`], cached in `probe`'s file), else oneDNN's
/// kernels; elsewhere the Winograd forms only where the CPU has no bf16 arithmetic (under the
/// policy's ISA cap).
pub fn inference_kernels(
    policy: &KernelPolicy,
    precision: Precision,
    device: Device,
    probe: &probe::Probe,
) -> (InferenceKernels, Vec<String>) {
    let native = policy.bf16.arithmetic.is_native();
    let mut kernels = InferenceKernels {
        winograd: policy.winograd,
        bf16_winograd: native == Some(false),
        bf16_convolutions: policy.inference_convolutions(),
    };
    let mut warnings = Vec::new();
    let measured_here =
        precision == Precision::Bf16 && device == Device::Cpu && native == Some(true);
    match policy.bf16_winograd {
        Some(on) => kernels.bf16_winograd = on,
        None if measured_here => match probe
            .measured(&probe.key(probe::Work::Conv3x3.name()), || {
                probe::measure_conv3x3(policy.winograd)
            }) {
            Ok((m, _)) => kernels.bf16_winograd = winograd_wins(&m),
            Err(e) => warnings.push(format!(
                "could not measure which bf16 3x3 convolutions are faster on this CPU ({e}); \
                 oneDNN's bf16 kernels run"
            )),
        },
        None => {}
    }
    (kernels, warnings)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_winograd_forms_run_only_where_they_win_clearly() {
        let wins =
            |winograd_s, onednn_s| winograd_wins(&probe::Measured::now(winograd_s, onednn_s));
        // Intel without AMX (8.2 against 24.6 ms), AMX (8.6 against 1.7 ms), AMD Zen 4 (11.5
        // against 12.3 ms: a narrow win on the layer, a loss on networks).
        assert!(wins(8.2, 24.6));
        assert!(!wins(8.6, 1.7));
        assert!(!wins(11.5, 12.3));
        assert!(!wins(1.0, BF16_WINOGRAD_MARGIN) && wins(1.0, BF16_WINOGRAD_MARGIN * 1.01));
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
    fn the_policy_reads_its_variables_and_names_a_bad_one() {
        assert_eq!(
            KernelPolicy::from_vars(vars(&[])),
            Ok(KernelPolicy::default())
        );
        let p = KernelPolicy::from_vars(vars(&[
            (WINOGRAD_VAR, "f23"),
            (BF16_WINOGRAD_VAR, "on"),
            ("RTF_BF16_CONVOLUTIONS", "emulated"),
        ]));
        assert_eq!(
            p,
            Ok(KernelPolicy {
                winograd: Forms::F23,
                bf16_winograd: Some(true),
                bf16: Bf16Policy {
                    asked: Some(Bf16Convolutions::Emulated),
                    ..Bf16Policy::default()
                },
            })
        );
        assert_eq!(
            p.unwrap().inference_convolutions(),
            Bf16Convolutions::Emulated
        );
        let e = KernelPolicy::from_vars(vars(&[("RTF_BF16_CONVOLUTIONS", "fast")])).unwrap_err();
        assert!(
            e.to_string().contains("RTF_BF16_CONVOLUTIONS=`fast`"),
            "{e}"
        );
        let e = KernelPolicy::from_vars(vars(&[(BF16_WINOGRAD_VAR, "maybe")])).unwrap_err();
        assert_eq!(
            e.to_string(),
            "RTF_BF16_WINOGRAD=\"maybe\": expected on or off"
        );
        let e = KernelPolicy::from_vars(vars(&[(WINOGRAD_VAR, "fast")])).unwrap_err();
        assert!(e.to_string().contains("RTF_WINOGRAD=\"fast\""), "{e}");
    }

    /// A choice made is taken as made, without a measurement (no cache written); fp32 and
    /// other devices measure nothing.
    #[test]
    fn a_choice_made_is_not_measured() {
        let dir = tempfile::tempdir().unwrap();
        let probe = probe::Probe::cached_in(dir.path().join("p.json"), Vec::new());
        for on in [true, false] {
            let policy = KernelPolicy {
                bf16_winograd: Some(on),
                ..Default::default()
            };
            let (k, w) = inference_kernels(&policy, Precision::Bf16, Device::Cpu, &probe);
            assert_eq!((k.bf16_winograd, w.len()), (on, 0));
        }
        let policy = KernelPolicy {
            winograd: Forms::Off,
            ..Default::default()
        };
        let (k, _) = inference_kernels(&policy, Precision::Fp32, Device::Cpu, &probe);
        assert_eq!(k.winograd, Forms::Off);
        assert!(!dir.path().join("p.json").exists());
    }

    /// Where the policy's ISA cap takes bf16 arithmetic away, bf16 takes the Winograd forms and
    /// emulated folds without a measurement, whatever the CPU's own flags.
    #[test]
    fn a_cap_below_bf16_takes_the_winograd_forms_and_emulated_folds() {
        let policy = KernelPolicy::from_vars(vars(&[("ONEDNN_MAX_CPU_ISA", "AVX2")])).unwrap();
        let probe = probe::Probe::uncached(Vec::new());
        let (k, w) = inference_kernels(&policy, Precision::Bf16, Device::Cpu, &probe);
        assert!(k.bf16_winograd && w.is_empty());
        assert_eq!(policy.inference_convolutions(), Bf16Convolutions::Emulated);
        let mixed = KernelPolicy {
            bf16: Bf16Policy {
                asked: Some(Bf16Convolutions::Mixed),
                ..policy.bf16
            },
            ..policy
        };
        assert_eq!(mixed.inference_convolutions(), Bf16Convolutions::Native);
    }
}
