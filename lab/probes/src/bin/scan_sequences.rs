//! How long opening a split of a sequence-recorded dataset takes (docs/src/bring-your-data.md,
//! "Scan speed"): writes a tree of FRAMES frames (default 100 000) in the sequence layout —
//! `images/{set}/{video}/visible/{frame}.jpg`, `.../lwir/{frame}.jpg`,
//! `labels/{set}_{video}_{frame}.png`, empty files: the scan lists folders, it decodes nothing
//! — and times opening the split by walking the folders, then by the release's per-condition
//! lists (every line resolved, day/night from the lists).
//!
//! ```sh
//! cargo run --release -p rtf-lab --bin scan_sequences -- [FRAMES] [DIR]
//! ```

use std::path::Path;
use std::time::Instant;

use rtf_data::description::read_description;
use rtf_data::{DescribedDataset, FrameSource};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let frames: usize = args.next().map_or(Ok(100_000), |a| a.parse())?;
    let keep = args.next();
    let temp = tempfile::tempdir()?;
    let root = keep.as_deref().map_or(temp.path(), Path::new);
    let start = Instant::now();
    write_tree(root, frames)?;
    println!(
        "wrote {frames} frames (3 files each) in {:.1} s",
        start.elapsed().as_secs_f64()
    );
    for (yaml, what) in [
        (yaml(false), "walking the folders"),
        (yaml(true), "by the day/night lists"),
    ] {
        std::fs::write(root.join("dataset.yaml"), yaml)?;
        let description = read_description(&root.join("dataset.yaml"))?;
        let start = Instant::now();
        let split = DescribedDataset::new(description).split("train")?;
        let took = start.elapsed().as_secs_f64();
        let night = (0..split.len())
            .filter(|&i| split.daytime(i) == Some(rtf_core::Daytime::Night))
            .count();
        println!(
            "opened split 'train' {what}: {} frames ({night} night) in {took:.2} s ({:.0} frames/s)",
            split.len(),
            split.len() as f64 / took
        );
    }
    Ok(())
}

fn yaml(lists: bool) -> String {
    let list = match lists {
        true => ", list: [train_day.txt, train_night.txt]",
        false => "",
    };
    let conditions = match lists {
        true => "day: {list: [train_day.txt]}\nnight: {list: [train_night.txt]}\n",
        false => "",
    };
    format!(
        "classes:\n  - {{id: 0, name: road, color: [128, 64, 128]}}\n  - {{id: 1, name: car, color: [0, 0, 142]}}\nignore_id: 19\nsplits:\n  train: {{rgb: \"images/{{set}}/{{video}}/visible/{{frame}}.jpg\", thermal: \"images/{{set}}/{{video}}/lwir/{{frame}}.jpg\", labels: \"labels/{{set}}_{{video}}_{{frame}}.png\"{list}}}\n{conditions}"
    )
}

/// 10 sets of 10 videos, frames spread over them; odd videos at night.
fn write_tree(root: &Path, frames: usize) -> std::io::Result<()> {
    let per_video = frames.div_ceil(100);
    let (mut day, mut night) = (String::new(), String::new());
    std::fs::create_dir_all(root.join("labels"))?;
    for k in 0..frames {
        let (set, video, frame) = (k / per_video / 10, (k / per_video) % 10, k % per_video);
        let (set, video, frame) = (
            format!("set{set:02}"),
            format!("V{video:03}"),
            format!("I{frame:05}"),
        );
        let seq = root.join("images").join(&set).join(&video);
        if frame == "I00000" {
            std::fs::create_dir_all(seq.join("visible"))?;
            std::fs::create_dir_all(seq.join("lwir"))?;
        }
        std::fs::write(seq.join("visible").join(format!("{frame}.jpg")), b"")?;
        std::fs::write(seq.join("lwir").join(format!("{frame}.jpg")), b"")?;
        let label = format!("{set}_{video}_{frame}.png");
        std::fs::write(root.join("labels").join(&label), b"")?;
        let list = if (k / per_video) % 2 == 1 {
            &mut night
        } else {
            &mut day
        };
        list.push_str(&label);
        list.push('\n');
    }
    std::fs::write(root.join("train_day.txt"), day)?;
    std::fs::write(root.join("train_night.txt"), night)
}
