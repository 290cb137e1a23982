//! Channels-last layout of 4-D maps (NHWC in memory, NCHW logical shape), the layout libtorch's
//! CPU convolutions, pools and pointwise ops keep and oneDNN's fast kernels want.

use tch::Tensor;

/// Re-lays a 4-D tensor out channels-last (NHWC in memory, NCHW logical shape); libtorch's
/// CPU convolutions, pools and pointwise ops keep that layout.
pub fn to_channels_last(xs: &Tensor) -> Tensor {
    if xs.dim() != 4 {
        return xs.shallow_clone();
    }
    xs.permute([0, 2, 3, 1]).contiguous().permute([0, 3, 1, 2])
}

/// Whether a 4-D tensor is laid out channels-last.
pub fn is_channels_last(xs: &Tensor) -> bool {
    let (size, stride) = (xs.size(), xs.stride());
    size.len() == 4 && (size[1] == 1 || stride[1] == 1) && stride[0] == size[1] * size[2] * size[3]
}

#[cfg(test)]
mod tests {
    use super::*;
    use tch::{Device, Kind};

    #[test]
    fn channels_last_keeps_values_and_is_recognised() {
        let xs = Tensor::randn([2, 3, 4, 5], (Kind::Float, Device::Cpu));
        assert!(!is_channels_last(&xs));
        let cl = to_channels_last(&xs);
        assert!(is_channels_last(&cl));
        assert_eq!(cl.size(), xs.size());
        assert!(cl.equal(&xs));
        let flat = Tensor::randn([6], (Kind::Float, Device::Cpu));
        assert!(to_channels_last(&flat).equal(&flat));
    }
}
