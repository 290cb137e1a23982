//! Devices as users name them: "cpu", "cuda" (the first GPU) or "cuda:N" ([`parse_device`]),
//! and checked to exist on this machine ([`available_device`]). Every command that runs a
//! network finds its device here: training, evaluation, `rtf report`'s prediction grid.

use rtf_config::compute::DeviceName;

/// "cpu", "cuda" (first GPU) or "cuda:N" (rtf-config's [`DeviceName`], as libtorch's device).
pub fn parse_device(name: &str) -> Result<tch::Device, String> {
    Ok(match DeviceName::parse(name)? {
        DeviceName::Cpu => tch::Device::Cpu,
        DeviceName::Cuda(index) => tch::Device::Cuda(index),
    })
}

/// [`parse_device`], then checks libtorch can use it here, so a missing GPU is a clear error
/// rather than a libtorch panic at the first tensor. (cuDNN's autotuner is the caller's: `rtf`
/// turns it on for every command, `RTF_CUDNN_BENCHMARK=0` off: rtf-train's `cudnn_benchmark`.)
pub fn available_device(name: &str) -> Result<tch::Device, String> {
    let device = parse_device(name)?;
    if let tch::Device::Cuda(index) = device {
        let count = tch::Cuda::device_count();
        if index as i64 >= count {
            return Err(format!(
                "device `{name}` is not available: libtorch sees {count} CUDA device(s) here{}",
                if tch::Cuda::is_available() {
                    ""
                } else {
                    " (no usable NVIDIA driver, or a CPU-only libtorch)"
                }
            ));
        }
    }
    Ok(device)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn devices_parse() {
        assert_eq!(parse_device("cpu"), Ok(tch::Device::Cpu));
        assert_eq!(parse_device("cuda:1"), Ok(tch::Device::Cuda(1)));
        assert!(parse_device("tpu").is_err());
    }

    #[test]
    fn unavailable_gpus_are_a_clear_error() {
        assert_eq!(available_device("cpu"), Ok(tch::Device::Cpu));
        let count = tch::Cuda::device_count();
        let missing = format!("cuda:{count}");
        let err = available_device(&missing).unwrap_err();
        assert!(
            err.contains(&missing) && err.contains("not available"),
            "{err}"
        );
    }
}
