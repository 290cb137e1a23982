//! How convolutions inside a CPU bf16 autocast region are computed ([`Bf16Convolutions`]), and
//! what decides it ([`Bf16Policy`]): the user's choice where one was made (rtf's binaries:
//! `RTF_BF16_CONVOLUTIONS`, read at their edge), else emulated where the CPU has no bf16
//! arithmetic, else the choice a run made (measured or recorded), else native. The choice
//! travels as a value: into a run's configuration, and from there into the network built for
//! the run (rtf-models' `UnitKernels`), whose convolutions ask
//! [`crate::emulates_bf16_convolution`] with it.

use crate::cpu::{Bf16Arithmetic, IsaCap};
use crate::AmpError;

/// The environment variable by which rtf's binaries let the user choose [`Bf16Convolutions`].
pub const BF16_CONVOLUTIONS_VAR: &str = "RTF_BF16_CONVOLUTIONS";

/// How convolutions inside a CPU bf16 autocast region are computed (the schema's, rtf-config).
pub use rtf_config::Bf16Convolutions;

/// What decides a process's [`Bf16Convolutions`]: the user's choice, if any, and the CPU's
/// bf16 arithmetic. Resolved once at the edge (rtf's binaries, the Python package, a test) and
/// passed in; the library reads no variable.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub struct Bf16Policy {
    /// The user's choice (`RTF_BF16_CONVOLUTIONS` for rtf's binaries); None leaves it open.
    pub asked: Option<Bf16Convolutions>,
    /// This process's CPU arithmetic ([`Bf16Arithmetic::of_cpu`] under its oneDNN cap).
    pub arithmetic: Bf16Arithmetic,
}

impl Bf16Policy {
    /// The policy of a process whose variables `get` reads: [`BF16_CONVOLUTIONS_VAR`] (a bad
    /// value is an error naming it) and oneDNN's cap ([`IsaCap::from_vars`]) over this CPU.
    pub fn from_vars(get: impl Fn(&str) -> Option<String>) -> Result<Self, AmpError> {
        let asked = get(BF16_CONVOLUTIONS_VAR)
            .map(|v| {
                Bf16Convolutions::from_name(&v)
                    .ok_or_else(|| AmpError::BadConvolutionChoice(v.trim().to_owned()))
            })
            .transpose()?;
        Ok(Self {
            asked,
            arithmetic: Bf16Arithmetic::of_cpu(IsaCap::from_vars(get)),
        })
    }

    /// Nothing asked, this CPU's arithmetic under `cap`.
    pub fn of_cpu(cap: IsaCap) -> Self {
        Self {
            asked: None,
            arithmetic: Bf16Arithmetic::of_cpu(cap),
        }
    }

    /// The choice in force given the choice a run `made` (measured or recorded), if any: the
    /// user's where asked, else emulated where the CPU is known to lack bf16 arithmetic (its
    /// generic kernels only when asked for), else `made`, else native.
    pub fn in_force(&self, made: Option<Bf16Convolutions>) -> Bf16Convolutions {
        match (self.asked, made) {
            (Some(choice), _) => choice,
            _ if self.arithmetic.is_native() == Some(false) => Bf16Convolutions::Emulated,
            (None, Some(choice)) => choice,
            (None, None) => Bf16Convolutions::Native,
        }
    }

    /// Whether a run may measure and make its own choice: the user left it open and the CPU
    /// has bf16 arithmetic.
    pub fn open_to_measure(&self) -> bool {
        self.asked.is_none() && self.arithmetic.is_native() == Some(true)
    }
}

impl Default for Bf16Policy {
    /// Nothing asked, this CPU's arithmetic without a cap ([`IsaCap::NONE`]).
    fn default() -> Self {
        Self::of_cpu(IsaCap::NONE)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use Bf16Convolutions::*;

    fn policy(asked: Option<Bf16Convolutions>, native: Option<bool>) -> Bf16Policy {
        let flags = Bf16Arithmetic::from_flags(native, IsaCap::NONE);
        Bf16Policy {
            asked,
            arithmetic: flags,
        }
    }

    #[test]
    fn bf16_convolutions_are_emulated_where_the_cpu_lacks_bf16_unless_told() {
        assert_eq!(policy(None, Some(false)).in_force(None), Emulated);
        assert_eq!(policy(None, Some(true)).in_force(None), Native);
        assert_eq!(policy(None, None).in_force(None), Native);
        // The run's choice (measured, or a run's record) where the CPU has bf16 ...
        assert_eq!(policy(None, Some(true)).in_force(Some(Emulated)), Emulated);
        assert_eq!(policy(None, None).in_force(Some(Emulated)), Emulated);
        // ... but not where it has none: libtorch's generic kernels only when told.
        assert_eq!(policy(None, Some(false)).in_force(Some(Native)), Emulated);
        // The user's choice over both.
        assert_eq!(
            policy(Some(Native), Some(false)).in_force(Some(Emulated)),
            Native
        );
        assert_eq!(
            policy(Some(Emulated), Some(true)).in_force(Some(Native)),
            Emulated
        );
        assert_eq!(policy(None, Some(true)).in_force(Some(Mixed)), Mixed);
        assert_eq!(policy(None, Some(false)).in_force(Some(Mixed)), Emulated);
        assert!(policy(None, Some(true)).open_to_measure());
        assert!(!policy(Some(Native), Some(true)).open_to_measure());
        assert!(!policy(None, Some(false)).open_to_measure());
    }

    #[test]
    fn the_policy_reads_the_variables_given_and_names_a_bad_choice() {
        let vars = |pairs: &'static [(&'static str, &'static str)]| {
            move |name: &str| {
                pairs
                    .iter()
                    .find(|(k, _)| *k == name)
                    .map(|(_, v)| v.to_string())
            }
        };
        let p = Bf16Policy::from_vars(vars(&[
            ("RTF_BF16_CONVOLUTIONS", "emulated"),
            ("ONEDNN_MAX_CPU_ISA", "AVX2"),
        ]))
        .unwrap();
        assert_eq!(p.asked, Some(Emulated));
        assert_ne!(p.arithmetic.is_native(), Some(true), "capped at AVX2");
        let none = Bf16Policy::from_vars(vars(&[])).unwrap();
        assert_eq!(
            (none.asked, none.arithmetic),
            (None, Bf16Policy::default().arithmetic)
        );
        let err = Bf16Policy::from_vars(vars(&[("RTF_BF16_CONVOLUTIONS", "fast")])).unwrap_err();
        assert!(
            err.to_string().contains("RTF_BF16_CONVOLUTIONS=`fast`"),
            "{err}"
        );
    }
}
