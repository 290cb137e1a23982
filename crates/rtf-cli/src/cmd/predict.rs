use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use rtf_core::ClassSet;
use rtf_data::pngio::{read_png, Samples};
use rtf_train::config::parse_device;
use tch::Kind;

use super::load_network;

#[derive(clap::Args)]
pub struct Args {
    /// Network name (see `rtf models`).
    #[arg(long, default_value = "mfnet")]
    pub model: String,
    /// Weights (safetensors, reference names).
    #[arg(long)]
    pub weights: PathBuf,
    /// Output folder: <stem>.png (class ids), <stem>_color.png (palette), <stem>.npy (--logits).
    #[arg(long)]
    pub out: PathBuf,
    /// Also write the logits as float32 .npy of shape [classes, H, W].
    #[arg(long)]
    pub logits: bool,
    #[arg(long, default_value = "cpu")]
    pub device: String,
    /// RGBA PNGs, thermal in the alpha channel (MF layout).
    #[arg(required = true)]
    pub images: Vec<PathBuf>,
}

/// Reads an MF-style RGBA PNG into an unlabelled frame.
fn read_rgbt(path: &Path) -> Result<rtf_data::Frame> {
    let png = read_png(path)?;
    let Samples::U8(rgba) = png.samples else {
        bail!("{}: 16-bit PNG, expected 8-bit RGBA with thermal in alpha", path.display());
    };
    if png.channels != 4 || png.indexed {
        bail!("{}: {} channel(s), expected 4 (RGBA with thermal in alpha)", path.display(), png.channels);
    }
    let rgb = rgba.chunks_exact(4).flat_map(|p| [p[0], p[1], p[2]]).collect();
    let thermal = rgba.chunks_exact(4).map(|p| p[3] as f32 / 255.0).collect();
    let name = path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    Ok(rtf_data::Frame { daytime: rtf_core::Daytime::from_mf_name(&name), name, width: png.width, height: png.height, rgb, thermal, label: None })
}

pub fn run(args: Args) -> Result<()> {
    let device = parse_device(&args.device).map_err(anyhow::Error::msg)?;
    let classes = ClassSet::mf();
    let (_vs, network) = load_network(&args.model, classes.len() as i64, &args.weights, device)?;
    // Read every input first: a bad file stops the run before anything is written.
    let frames = args.images.iter().map(|p| read_rgbt(p)).collect::<Result<Vec<_>>>()?;
    std::fs::create_dir_all(&args.out).with_context(|| format!("cannot create {}", args.out.display()))?;
    let _guard = tch::no_grad_guard();
    for (frame, path) in frames.iter().zip(&args.images) {
        let input = rtf_eval::figure::frame_input(frame, network.input_convention()).to_device(device);
        let logits = rtf_eval::evaluate::logits(network.as_ref(), &input)?.get(0).to_kind(Kind::Float).to_device(tch::Device::Cpu);
        let ids = Vec::<u8>::try_from(logits.argmax(0, false).to_kind(Kind::Uint8).flatten(0, -1))?;
        let (w, h) = (frame.width as u32, frame.height as u32);
        let stem = &frame.name;
        let ids_path = args.out.join(format!("{stem}.png"));
        let color_path = args.out.join(format!("{stem}_color.png"));
        save_png(&ids_path, image::DynamicImage::ImageLuma8(image::GrayImage::from_raw(w, h, ids.clone()).expect("sized")))?;
        save_png(&color_path, image::DynamicImage::ImageRgb8(image::RgbImage::from_raw(w, h, classes.colorize(&ids)).expect("sized")))?;
        if args.logits {
            let shape: Vec<usize> = logits.size().iter().map(|&d| d as usize).collect();
            let values = Vec::<f32>::try_from(logits.flatten(0, -1))?;
            let npy = args.out.join(format!("{stem}.npy"));
            rtf_core::npy::write_f32(&npy, &shape, &values).with_context(|| format!("writing {}", npy.display()))?;
        }
        println!("{} -> {}", path.display(), ids_path.display());
    }
    Ok(())
}

fn save_png(path: &Path, image: image::DynamicImage) -> Result<()> {
    rtf_core::write_atomic(path, |tmp| image.save_with_format(tmp, image::ImageFormat::Png))
        .with_context(|| format!("writing {}", path.display()))
}
