//! Which input channels a network sees. HeatNet's unimodal roles (the RGB teacher, the thermal
//! teacher, the distilled RGB-only student; heatnet.txt §III-B/C, Tab. II's check marks) and
//! the papers' 3-channel baselines are one network behind a mask: the channels it does not
//! see are set to 0 in the network's input space (after its input convention), so any
//! network plays any role. A network trained behind a mask must be scored behind the same
//! mask, so the mask travels with the weights (`rtf.inputs` in their metadata, see
//! [`crate::io::weights`]).

use tch::Tensor;

use crate::Network;

/// The modalities of the 4-channel input (R, G, B, T) a network sees: the schema's
/// (rtf-config).
pub use rtf_config::network::Modality;

/// `x` [B, 4, H, W] with the channels `inputs` does not see set to 0: a copy with those
/// channels zeroed on `x`'s device (no mask from host memory, which would be a copy to a GPU at
/// every forward pass).
pub fn mask(inputs: Modality, x: &Tensor) -> Tensor {
    let (start, len) = match inputs {
        Modality::RgbT => return x.shallow_clone(),
        Modality::Rgb => (3, 1),
        Modality::Thermal => (0, 3),
    };
    let mut masked = x.empty_like();
    masked.copy_(x);
    let _ = masked.narrow(1, start, len).zero_();
    masked
}

/// A network behind its input mask: it sees only the channels of `inputs`.
#[derive(Debug)]
pub struct Masked {
    pub inner: Box<dyn Network>,
    pub inputs: Modality,
}

/// `net` behind the mask of `inputs` (unchanged for RGB-T).
pub fn masked(net: Box<dyn Network>, inputs: Modality) -> Box<dyn Network> {
    match inputs {
        Modality::RgbT => net,
        inputs => Box::new(Masked { inner: net, inputs }),
    }
}

impl tch::nn::ModuleT for Masked {
    fn forward_t(&self, xs: &Tensor, train: bool) -> Tensor {
        self.inner.forward_t(&mask(self.inputs, xs), train)
    }
}

impl Network for Masked {
    fn input_convention(&self) -> rtf_core::InputConvention {
        self.inner.input_convention()
    }
    fn num_classes(&self) -> i64 {
        self.inner.num_classes()
    }
    fn size_multiple(&self) -> i64 {
        self.inner.size_multiple()
    }
    fn name(&self) -> String {
        self.inner.name()
    }
    fn folded(&self, folder: &crate::fast::folder::Folder) -> Option<Box<dyn Network>> {
        let inner = self.inner.folded(folder)?;
        Some(Box::new(Masked {
            inner,
            inputs: self.inputs,
        }))
    }
    fn check_input(&self, shape: &[i64]) -> Result<(), crate::ModelError> {
        self.inner.check_input(shape)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_mask_zeroes_exactly_the_unseen_channels() {
        let x = Tensor::ones([1, 4, 2, 2], (tch::Kind::Float, tch::Device::Cpu));
        let seen = |m: Modality| -> Vec<f64> {
            let s = mask(m, &x).sum_dim_intlist([0i64, 2, 3].as_slice(), false, None);
            Vec::<f64>::try_from(s).unwrap()
        };
        assert_eq!(seen(Modality::RgbT), vec![4.0; 4]);
        assert_eq!(seen(Modality::Rgb), vec![4.0, 4.0, 4.0, 0.0]);
        assert_eq!(seen(Modality::Thermal), vec![0.0, 0.0, 0.0, 4.0]);
    }
}
