//! BatchNorm hyper-parameters of every reference network (PyTorch's `nn.BatchNorm2d` defaults,
//! which the MFNet, RTFNet and HeatNet reference code all keep). They live below both
//! [`crate::layers`] (which builds the BatchNorms) and [`crate::sync_bn`] (which normalises with
//! them across ranks), so neither module has to import the other for them.

/// BatchNorm epsilon of every reference network (PyTorch's default).
pub const BN_EPS: f64 = rtf_config::network::BN_EPS;
/// BatchNorm momentum of every reference network (PyTorch's default).
pub const BN_MOMENTUM: f64 = 0.1;
