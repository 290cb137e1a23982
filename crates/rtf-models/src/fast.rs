//! The fast inference path: no autograd, BatchNorm folded into the convolutions, channels-last
//! activations, in-place activations and residual adds, optional bfloat16.
//!
//! [`InferenceNet::fold`] builds it as a new network from a trained one
//! ([`crate::Network::folded`], [`folder::Fold`]), its convolutions [`unit::FoldedConv`]s, as
//! the [`FoldOptions`] passed in say; nothing is read from the process.

pub mod folder;
pub mod unit;

use rtf_amp::PrecisionOnDevice;
use serde::{Deserialize, Serialize};
use tch::{Device, Kind, Tensor};

use crate::error::ModelError;
use crate::layers::to_channels_last;
use crate::release::PlainWeights;
pub use crate::release::Released;
use crate::Network;
use folder::Folder;

/// Arithmetic precision of inference: fp32, bf16, or fp16 on CUDA (one type with training's;
/// the CLI parses inference precisions with [`Precision::parse_inference`]).
pub use rtf_amp::Precision;

/// Refuses fp16 inference off CUDA: libtorch's CPU convolutions have no fast fp16 kernels on
/// most CPUs, and bf16 is the CPU's half-width type. Called where the device is known (the
/// loaders, `rtf bench model`) and again by [`InferenceNet::forward`] on its input.
pub fn check_precision_on(precision: Precision, device: Device) -> Result<(), ModelError> {
    if precision == Precision::Fp16 && !device.is_cuda() {
        return Err(ModelError::InvalidConfig {
            network: "fast inference".into(),
            reason: "fp16 runs on CUDA only: use bf16 (or fp32) on the CPU".into(),
        });
    }
    Ok(())
}

/// Memory layout of activations (and weights) on the fast path.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq, Default)]
#[serde(rename_all = "lowercase")]
pub enum Layout {
    /// NHWC in memory: no reorders around oneDNN convolutions (the default).
    #[default]
    ChannelsLast,
    /// Plain NCHW, as PyTorch eager by default.
    Nchw,
}

impl std::str::FromStr for Layout {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "nhwc" | "channels_last" | "channels-last" => Ok(Layout::ChannelsLast),
            "nchw" => Ok(Layout::Nchw),
            other => Err(format!("unknown layout {other:?} (expected nhwc or nchw)")),
        }
    }
}

/// The kernels a fold takes where there is a choice (issue 61): chosen by the caller (rtf's
/// commands and the Python package through `rtf_eval::kernels`, from a measurement, their
/// flags or, in the CLI, its environment), passed in and recorded, never read from the
/// process.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq)]
pub struct InferenceKernels {
    /// The Winograd forms the fp32 (and, with `bf16_winograd`, bf16) 3×3 convolutions may take.
    pub winograd: rtf_kernels::winograd::Forms,
    /// bf16's wide 3×3 convolutions in the Winograd forms (fp32 arithmetic over bf16 maps)
    /// rather than on oneDNN's bf16 kernels.
    pub bf16_winograd: bool,
    /// How bf16 convolutions on the CPU are computed: [`rtf_amp::Bf16Convolutions::Emulated`]
    /// folds them for float32 kernels over bf16 maps (CPUs without bf16 arithmetic).
    #[serde(default = "native")]
    pub bf16_convolutions: rtf_amp::Bf16Convolutions,
}

fn native() -> rtf_amp::Bf16Convolutions {
    rtf_amp::Bf16Convolutions::Native
}

impl InferenceKernels {
    /// Without a measurement: every form, and bf16 in the Winograd forms only where the CPU
    /// has no bf16 arithmetic ([`rtf_kernels::winograd::bf16_default`]), its bf16 convolutions
    /// emulated there.
    pub fn unmeasured() -> Self {
        Self {
            winograd: rtf_kernels::winograd::Forms::All,
            bf16_winograd: rtf_kernels::winograd::bf16_default(),
            bf16_convolutions: rtf_amp::Bf16Policy::default().in_force(None),
        }
    }
}

/// How a network is folded for inference: precision, activation layout and kernels.
#[derive(Serialize, Deserialize, Clone, Copy, Debug, PartialEq, Eq)]
pub struct FoldOptions {
    pub precision: Precision,
    pub layout: Layout,
    pub kernels: InferenceKernels,
}

impl FoldOptions {
    /// `precision`, channels-last, [`InferenceKernels::unmeasured`].
    pub fn new(precision: Precision) -> Self {
        Self {
            precision,
            layout: Layout::ChannelsLast,
            kernels: InferenceKernels::unmeasured(),
        }
    }

    pub fn layout(self, layout: Layout) -> Self {
        Self { layout, ..self }
    }

    pub fn kernels(self, kernels: InferenceKernels) -> Self {
        Self { kernels, ..self }
    }
}

/// A network prepared for inference. Build the network, load its weights, then wrap it.
#[derive(Debug)]
pub struct InferenceNet {
    net: Box<dyn Network>,
    options: FoldOptions,
    fused: bool,
}

impl InferenceNet {
    /// Fuses `net` for `precision` ([`FoldOptions::new`]). Networks without a fused path run
    /// their plain eval forward (still without autograd) in fp32 only.
    pub fn new(net: Box<dyn Network>, precision: Precision) -> Result<Self, ModelError> {
        Self::fold(net, &FoldOptions::new(precision))
    }

    /// [`new`](Self::new) with a chosen activation layout.
    pub fn with_layout(
        net: Box<dyn Network>,
        precision: Precision,
        layout: Layout,
    ) -> Result<Self, ModelError> {
        Self::fold(net, &FoldOptions::new(precision).layout(layout))
    }

    /// The inference form of `net` as `options` say ([`crate::Network::folded`]), which takes
    /// the place of the trained network. Networks without a folded path run their plain eval
    /// forward (still without autograd), in fp32 only.
    pub fn fold(net: Box<dyn Network>, options: &FoldOptions) -> Result<Self, ModelError> {
        let folded = net.folded(&Folder::new(options));
        Self::of(net, folded, options)
    }

    /// The inference net of a trained `net` and its `folded` form, if it has one (else `net`
    /// itself, in fp32 only).
    fn of(
        net: Box<dyn Network>,
        folded: Option<Box<dyn Network>>,
        options: &FoldOptions,
    ) -> Result<Self, ModelError> {
        let (net, fused) = match folded {
            Some(folded) => (folded, true),
            None if options.precision != Precision::Fp32 => {
                return Err(ModelError::InvalidConfig {
                    network: net.name(),
                    reason: format!(
                        "no fused inference path, so no {} inference",
                        options.precision
                    ),
                })
            }
            None => (net, false),
        };
        Ok(Self {
            net,
            options: *options,
            fused,
        })
    }

    /// [`fold`](Self::fold) over a network whose weights are `vs`'s, freeing every plain
    /// variable the folded network does not hold ([`crate::release`]): each unit's as it folds,
    /// the rest after. A network kept for inference alone, as rtf's commands load one: `vs`
    /// must not be used afterwards (e.g. for saving). A network without a folded path runs on
    /// its plain weights, so nothing is released from it.
    pub fn releasing_plain_weights(
        net: Box<dyn Network>,
        options: &FoldOptions,
        vs: &tch::nn::VarStore,
    ) -> Result<(Self, Released), ModelError> {
        let plain = PlainWeights::record(vs);
        let recorded = plain.recorded();
        let folded = net.folded(&Folder::releasing(options, &recorded));
        // Released while the trained network still holds its handles, as recorded; a network
        // without a folded form runs on its plain weights, so nothing is released from it.
        let released = match folded.is_some() {
            true => plain.release_unheld(),
            false => Released::default(),
        };
        let fast = Self::of(net, folded, options)?;
        Ok((fast, released))
    }

    pub fn network(&self) -> &dyn Network {
        &*self.net
    }

    pub fn precision(&self) -> Precision {
        self.options.precision
    }

    pub fn layout(&self) -> Layout {
        self.options.layout
    }

    /// How this network was folded (precision, layout, kernels).
    pub fn options(&self) -> &FoldOptions {
        &self.options
    }

    /// Whether the folded path is in use.
    pub fn is_fused(&self) -> bool {
        self.fused
    }

    /// [B, 4, H, W] float input (already scaled) -> float logits [B, classes, H, W].
    pub fn forward(&self, xs: &Tensor) -> Result<Tensor, ModelError> {
        self.net.check_input(&xs.size())?;
        self.forward_unchecked(xs)
    }

    /// [`forward`](Self::forward) without the shape check (for inputs already checked).
    pub fn forward_unchecked(&self, xs: &Tensor) -> Result<Tensor, ModelError> {
        check_precision_on(self.options.precision, xs.device())?;
        let _guard = tch::no_grad_guard();
        let xs = xs
            .f_to_kind(self.options.precision.kind())
            .map_err(|source| ModelError::Torch {
                context: format!("{}: input conversion", self.net.name()),
                source,
            })?;
        let xs = if self.fused {
            to_channels_last(&xs)
        } else {
            xs
        };
        let logits = self.net.forward_t(&xs, false);
        if logits.kind() == Kind::Float && logits.is_contiguous() {
            // Some networks write their logits in this form (MFNet's decode1).
            return Ok(logits);
        }
        // Float and NCHW in one pass (to_kind keeps channels-last; contiguous would copy again).
        let out = Tensor::empty(logits.size(), (Kind::Float, logits.device()));
        let mut out_ = out.shallow_clone();
        out_.copy_(&logits);
        Ok(out)
    }
}

/// An inference net is a network too, so evaluation and prediction take either. Its forward
/// is eval-only: the fused weights carry no gradients.
impl tch::nn::ModuleT for InferenceNet {
    fn forward_t(&self, xs: &Tensor, train: bool) -> Tensor {
        assert!(
            !train,
            "{}: the fast inference path cannot train",
            self.net.name()
        );
        self.forward_unchecked(xs).unwrap_or_else(|e| panic!("{e}"))
    }
}

impl Network for InferenceNet {
    fn input_convention(&self) -> rtf_core::InputConvention {
        self.net.input_convention()
    }
    fn num_classes(&self) -> i64 {
        self.net.num_classes()
    }
    fn size_multiple(&self) -> i64 {
        self.net.size_multiple()
    }
    fn name(&self) -> String {
        self.net.name()
    }
}

/// Fraction of pixels whose arg-max class agrees between two logits tensors [B, C, H, W].
pub fn argmax_agreement(a: &Tensor, b: &Tensor) -> f64 {
    let same = a.argmax(1, false).eq_tensor(&b.argmax(1, false));
    same.to_kind(Kind::Double)
        .mean(Kind::Double)
        .double_value(&[])
}

/// Largest |a − b| over all logits, relative to the largest |a|: how far a fused fp32 path is
/// from the plain one. Folding BatchNorm and fusing activations reorders float sums, so the
/// two differ by rounding only (≈ 1e-6 here). This, not arg-max agreement, is what tests
/// compare in fp32: a randomly initialised network has near-tied classes that rounding flips
/// (stop 36's CI: PSPNet, 4 of 2048 pixels), so agreement depends on the drawn weights.
pub fn max_relative_difference(a: &Tensor, b: &Tensor) -> f64 {
    let scale = a.abs().max().double_value(&[]).max(f64::MIN_POSITIVE);
    (a - b).abs().max().double_value(&[]) / scale
}

/// The models' tests' bound on [`max_relative_difference`] between a fused fp32 path and its
/// plain path.
#[cfg(test)]
pub(crate) const FUSED_FP32_TOLERANCE: f64 = 1e-4;

#[cfg(test)]
mod tests {
    use super::*;

    const FLOAT_CPU: (Kind, Device) = (Kind::Float, Device::Cpu);

    /// Builds `name` twice with the same weights (copied: other tests draw from the global
    /// generator meanwhile): folded for `precision` as it is, and folded while releasing (as
    /// rtf's commands load a network). Their logits on one input, what the release freed, and
    /// the plain weights' bytes.
    fn fold_and_release(name: &str, options: &FoldOptions) -> (Tensor, Tensor, Released, i64) {
        let cfg = crate::ModelConfig::from_name(name, 5).unwrap();
        let kept_vs = tch::nn::VarStore::new(Device::Cpu);
        let net = crate::build(&kept_vs.root(), &cfg).unwrap();
        let side = 2 * net.size_multiple().max(16);
        let x = Tensor::rand([1, 4, side, side + net.size_multiple()], FLOAT_CPU);
        let kept = InferenceNet::fold(net, options)
            .unwrap()
            .forward(&x)
            .unwrap();
        let mut vs = tch::nn::VarStore::new(Device::Cpu);
        let net = crate::build(&vs.root(), &cfg).unwrap();
        vs.copy(&kept_vs).unwrap();
        let total = vs.variables().values().map(|t| t.numel() as i64 * 4).sum();
        let (fast, released) = InferenceNet::releasing_plain_weights(net, options, &vs).unwrap();
        (kept, fast.forward(&x).unwrap(), released, total)
    }

    /// One network of each family the fast path folds, in fp32 and bf16: folded while releasing,
    /// it gives the logits of the same network folded without, bit for bit (a weight a fold or
    /// the folded forward still reads, emptied, would fail or change them), and the plain
    /// weights' memory went (most of it: what is kept is what a fold returned as is). Networks
    /// without a folded path keep everything.
    #[test]
    fn released_networks_give_the_same_logits_and_free_the_plain_weights() {
        let folded = [
            "mfnet",
            "rtfnet18",
            "rtfnet18-nub",
            "rtfnet18-fci",
            "heatnet",
            "heatnet-ir",
            "unet-4c",
            "pspnet-4c",
            "segnet-4c",
            "duchdc-4c",
            "fusenet",
            "cmx-mit-b0",
        ];
        for name in folded {
            let each = [Precision::Fp32, Precision::Bf16].map(crate::test_util::fold_options_each);
            for options in each.iter().flatten() {
                let (kept, released_logits, released, total) = fold_and_release(name, options);
                let precision = format!(
                    "{} {:?}",
                    options.precision, options.kernels.bf16_convolutions
                );
                eprintln!("{name} {precision}: {released:?} of {total} bytes");
                assert!(
                    kept.equal(&released_logits),
                    "{name} {precision}: the release changed the logits"
                );
                // CMX's linear layers and LayerNorms run on the plain weights (kept); the
                // convolutional networks' folds take little as it is.
                let least = if name.starts_with("cmx") {
                    total / 5
                } else {
                    total / 2
                };
                assert!(
                    released.bytes > least,
                    "{name} {precision}: released {released:?} of {total} bytes"
                );
            }
        }
        for name in ["erfnet-4c", "enet-4c"] {
            let fp32 = FoldOptions::new(Precision::Fp32);
            let (kept, released_logits, released, _) = fold_and_release(name, &fp32);
            assert_eq!(released, Released::default(), "{name}");
            assert!(kept.equal(&released_logits), "{name}");
        }
    }

    /// fp16 is CUDA's: on the CPU it is refused with the reason, by the check the loaders run
    /// and by the forward itself.
    #[test]
    fn fp16_is_refused_on_the_cpu_with_the_reason() {
        let err = check_precision_on(Precision::Fp16, Device::Cpu)
            .unwrap_err()
            .to_string();
        assert!(err.contains("fp16 runs on CUDA only"), "{err}");
        assert!(check_precision_on(Precision::Fp16, Device::Cuda(0)).is_ok());
        assert!(check_precision_on(Precision::Bf16, Device::Cpu).is_ok());
        let vs = tch::nn::VarStore::new(Device::Cpu);
        let cfg = crate::ModelConfig::from_name("mfnet", 9).unwrap();
        let net = crate::build(&vs.root(), &cfg).unwrap();
        let fast = InferenceNet::new(net, Precision::Fp16).unwrap();
        let err = fast
            .forward(&Tensor::zeros([1, 4, 32, 32], (Kind::Float, Device::Cpu)))
            .unwrap_err()
            .to_string();
        assert!(err.contains("fp16 runs on CUDA only"), "{err}");
    }
}
