//! Paper-budget training time, estimated from a quick run's training rates.
//!
//! CPU: each cell's quick rate (images/s at the quick size) scaled by pixel count to 480×640.
//! The quick epochs are short and their frames small, so fixed per-step costs weigh more than
//! at full size: an upper bound.
//!
//! GPU: the H100 rates measured at 480×640 (docs/src/getting-started.md: MFNet 108, RTFNet-50
//! 42, RTFNet-152 22 images/s) for those networks; every other network gets the measured
//! range, 108 to 22 images/s, so its time is a range too. A GPU rate is never derived from a
//! CPU rate: the quick rates are taken at 96×64 under fixed per-step costs and another job's
//! load, so a ratio of such a rate to a full-size one is no speed ratio (the earlier method
//! divided the pixel-scaled quick rate by MFNet's full-size CPU rate, 1.25 images/s, and
//! made every network without a GPU rate tens of times slower than MFNet on the GPU: 435.6 h
//! for RTFNet Tab. VI's 14 cells instead of a few hours).

/// H100 training rates at 480×640, images/s, by network-name prefix.
const GPU_RATES: &[(&str, f64)] = &[("mfnet", 108.0), ("rtfnet50", 42.0), ("rtfnet152", 22.0)];

/// The fastest and slowest measured H100 rate: the range of a network without a rate.
const GPU_RANGE: (f64, f64) = (108.0, 22.0);

/// (fast, slow) H100 rate of a network, images/s: its measured rate twice, or the range.
/// MFNet's variants (`mfnet-b`, ...) count as unmeasured: some are wider (MFNet_2x).
pub fn gpu_rates(network: &str) -> (f64, f64) {
    GPU_RATES
        .iter()
        .find(|(name, _)| {
            // RTFNet's ablations (`rtfnet50-nre`) are RTFNet-50 at most.
            let ablation = || {
                network
                    .strip_prefix(name)
                    .is_some_and(|r| r.starts_with('-'))
            };
            network == *name || (*name != "mfnet" && ablation())
        })
        .map_or(GPU_RANGE, |&(_, rate)| (rate, rate))
}

/// The paper budget's hours for a table's cells.
#[derive(Debug, Clone, PartialEq)]
pub struct Estimate {
    pub cells: usize,
    pub cpu_hours: f64,
    /// (with the fast end of each range, with the slow end).
    pub gpu_hours: (f64, f64),
}

/// Hours for `cells` (network, quick training rate in images/s) trained on `images` images
/// each at 480×640, from rates measured at `quick_pixels` pixels per frame.
pub fn estimate(cells: &[(&str, f64)], quick_pixels: f64, images: f64) -> Estimate {
    let scale = quick_pixels / (640.0 * 480.0);
    let (mut cpu, mut fast, mut slow) = (0.0, 0.0, 0.0);
    for &(network, rate) in cells {
        cpu += images / (rate * scale);
        let (hi, lo) = gpu_rates(network);
        fast += images / hi;
        slow += images / lo;
    }
    Estimate {
        cells: cells.len(),
        cpu_hours: cpu / 3600.0,
        gpu_hours: (fast / 3600.0, slow / 3600.0),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn measured_networks_keep_their_rate_and_others_get_the_range() {
        assert_eq!(gpu_rates("mfnet"), (108.0, 108.0));
        assert_eq!(gpu_rates("rtfnet50"), (42.0, 42.0));
        assert_eq!(gpu_rates("rtfnet50-nre"), (42.0, 42.0));
        assert_eq!(gpu_rates("rtfnet152-nte"), (22.0, 22.0));
        for other in [
            "mfnet-b",
            "rtfnet18",
            "rtfnet101",
            "segnet-4c",
            "pspnet-3c",
            "rtfnet500",
        ] {
            assert_eq!(gpu_rates(other), (108.0, 22.0), "{other}");
        }
    }

    /// RTFNet Tab. VI's 14 cells (100 epochs × 784 frames = 1.1 M images): with the measured
    /// H100 rates the table takes hours, not the 435.6 h the CPU-rate scaling gave; the GPU
    /// time does not depend on the CPU rates.
    #[test]
    fn rtfnet_table_six_takes_hours_on_one_h100() {
        let baselines = ["erfnet", "unet", "pspnet", "segnet", "duc-hdc"];
        let mut names: Vec<String> = baselines
            .iter()
            .flat_map(|b| [format!("{b}-4c"), format!("{b}-3c")])
            .collect();
        names.extend(["mfnet", "fusenet", "rtfnet50", "rtfnet152"].map(String::from));
        let slow_cpu: Vec<(&str, f64)> = names.iter().map(|n| (n.as_str(), 0.3)).collect();
        let e = estimate(&slow_cpu, 96.0 * 64.0, 100.0 * 784.0);
        assert_eq!(e.cells, 14);
        let per = |rate: f64| 78_400.0 / rate / 3600.0;
        let fixed = per(108.0) + per(42.0) + per(22.0);
        let close = |a: f64, b: f64| (a - b).abs() < 1e-9;
        assert!(close(e.gpu_hours.0, fixed + 11.0 * per(108.0)), "{e:?}");
        assert!(close(e.gpu_hours.1, fixed + 11.0 * per(22.0)), "{e:?}");
        assert!((3.9..4.0).contains(&e.gpu_hours.0), "{e:?}");
        assert!((12.5..12.7).contains(&e.gpu_hours.1), "{e:?}");
        // 0.3 images/s at 96×64 is 0.006 at 480×640: 78 400 images take 3630 h per cell.
        assert!(
            close(e.cpu_hours, 14.0 * 78_400.0 / 0.006 / 3600.0),
            "{e:?}"
        );
        let fast_cpu: Vec<(&str, f64)> = names.iter().map(|n| (n.as_str(), 30.0)).collect();
        let f = estimate(&fast_cpu, 96.0 * 64.0, 100.0 * 784.0);
        assert_eq!(
            f.gpu_hours, e.gpu_hours,
            "GPU time independent of CPU rates"
        );
        assert!(close(f.cpu_hours * 100.0, e.cpu_hours));
    }
}
