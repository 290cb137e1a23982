//! The synthetic plain layout ("Your own data"): `dataset.yaml` beside
//! `{train,val,test}/{rgb,thermal,labels}/NAME.png`, 8-bit RGB, 16-bit radiometric thermal
//! (64 counts per kelvin, 21800 at −10 °C, as the synthetic Freiburg IR) described by
//! `thermal: {range: [21800, 25000]}`, MF's 9 classes as ids, night frames by the `N` suffix.
//! What a user's own recordings look like, for trying the plain layout and timing the
//! loader on 16-bit thermal.

use super::{render_frame, write_provenance, SynthConfig, SynthSummary};
use crate::pngio::{write_png_u16, write_png_u8};
use crate::DataError;
use rayon::prelude::*;
use std::path::Path;

/// Writes the plain layout; `val` and `test` come from the MF assignment's val and test.
pub(super) fn write_synthetic(
    out: &Path,
    cfg: &SynthConfig,
    splits: &[(&'static str, Vec<usize>)],
) -> Result<SynthSummary, DataError> {
    let jobs: Vec<(&str, usize)> = splits
        .iter()
        .filter(|(name, _)| ["train", "val", "test"].contains(name))
        .flat_map(|(name, idx)| idx.iter().map(move |&i| (*name, i)))
        .collect();
    jobs.par_iter().try_for_each(|&(split, i)| {
        let f = render_frame(cfg, i);
        let file = |folder: &str| out.join(split).join(folder).join(format!("{}.png", f.name));
        write_png_u8(&file("rgb"), f.width, f.height, 3, &f.rgb)?;
        write_png_u16(&file("thermal"), f.width, f.height, 1, &f.thermal_u16())?;
        write_png_u8(&file("labels"), f.width, f.height, 1, &f.mf_label())
    })?;
    rtf_core::write_bytes_atomic(
        &out.join(crate::description::DESCRIPTION_FILE),
        yaml().as_bytes(),
    )?;
    write_provenance(out, cfg)?;
    Ok(SynthSummary {
        frames: cfg.count,
        splits: splits
            .iter()
            .filter(|(name, _)| ["train", "val", "test"].contains(name))
            .map(|(n, v)| (n.to_string(), v.len()))
            .collect(),
    })
}

/// The dataset.yaml: MF's classes and palette, the radiometric range, night by suffix.
fn yaml() -> String {
    let mf = rtf_core::ClassSet::mf();
    let classes: String = mf
        .classes
        .iter()
        .map(|c| {
            let [r, g, b] = c.color;
            format!(
                "  - {{id: {}, name: {}, color: [{r}, {g}, {b}]}}\n",
                c.id, c.name
            )
        })
        .collect();
    format!(
        "# rtf synth --format plain: MF's classes, 16-bit radiometric thermal\nname: synth\n\
         classes:\n{classes}thermal:\n  range: [21800, 25000]\nnight: {{suffix: N}}\n"
    )
}

#[cfg(test)]
mod tests {
    use super::super::{generate, SynthFormat};
    use super::*;
    use crate::{DescribedDataset, FrameSource};

    #[test]
    fn writes_a_plain_root_that_reads_back_with_16_bit_thermal_and_mf_classes() {
        let dir = tempfile::tempdir().unwrap();
        let cfg = SynthConfig {
            count: 6,
            width: 32,
            height: 16,
            format: SynthFormat::Plain,
            ..SynthConfig::default()
        };
        generate(dir.path(), &cfg).unwrap();
        let description = crate::layouts::describe(dir.path()).unwrap().unwrap();
        assert_eq!(
            description.class_set.names(),
            rtf_core::ClassSet::mf().names()
        );
        assert_eq!(description.split_names(), ["train", "val", "test"]);
        let first = std::fs::read_dir(dir.path().join("train/thermal"))
            .unwrap()
            .next();
        let png = crate::pngio::read_png(&first.unwrap().unwrap().path()).unwrap();
        assert_eq!(png.bit_depth(), 16);
        let train = DescribedDataset::new(description).split("train").unwrap();
        let frame = train.load(0).unwrap();
        assert!(
            frame.daytime.is_some(),
            "night by the N suffix, day otherwise"
        );
        assert!(frame.thermal.iter().all(|t| (0.0..=1.0).contains(t)));
        assert!(
            frame.thermal.iter().any(|&t| t > 0.0 && t < 1.0),
            "in range"
        );
    }
}
