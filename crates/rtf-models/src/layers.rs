//! Small building blocks shared by the networks.

use tch::nn;
use tch::Tensor;

/// BatchNorm2d initialised as PyTorch's (weight 1, bias 0; tch's default weight is U(0, 1)).
pub fn bn2d(p: nn::Path, c: i64) -> nn::BatchNorm {
    let cfg = nn::BatchNormConfig {
        ws_init: nn::Init::Const(1.0),
        bs_init: nn::Init::Const(0.0),
        ..Default::default()
    };
    nn::batch_norm2d(p, c, cfg)
}

/// LeakyReLU with a given slope (tch's `leaky_relu` fixes it at 0.01). For 0 < slope < 1,
/// max(x, slope·x) equals the piecewise definition.
pub fn leaky_relu(xs: &Tensor, slope: f64) -> Tensor {
    xs.maximum(&(xs * slope))
}
