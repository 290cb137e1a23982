//! RTFNet Fig. 3 drawn from measured numbers: two panels (mAcc left, mIoU right), ResNet-18,
//! 34, 50, 101, 152 along x, one line per variant (RTFNet red, NRE blue, NTE green, NUB
//! orange), y from 0 to 100 % with a grid line every 10 %. No text is drawn: the caption in the
//! Markdown names the axes and colours.

use anyhow::{Context, Result};
use std::path::Path;

pub const COLOURS: [(&str, [u8; 3]); 4] = [
    ("red", [220, 40, 40]),
    ("blue", [40, 80, 220]),
    ("green", [30, 160, 60]),
    ("orange", [240, 150, 20]),
];

const PANEL_W: usize = 420;
const PANEL_H: usize = 300;
const MARGIN: usize = 30;

struct Canvas {
    w: usize,
    h: usize,
    px: Vec<u8>,
}

impl Canvas {
    fn new(w: usize, h: usize) -> Self {
        Self {
            w,
            h,
            px: vec![255; w * h * 3],
        }
    }
    fn set(&mut self, x: i64, y: i64, c: [u8; 3]) {
        if x >= 0 && y >= 0 && (x as usize) < self.w && (y as usize) < self.h {
            let i = (y as usize * self.w + x as usize) * 3;
            self.px[i..i + 3].copy_from_slice(&c);
        }
    }
    fn dot(&mut self, x: i64, y: i64, r: i64, c: [u8; 3]) {
        for dy in -r..=r {
            for dx in -r..=r {
                self.set(x + dx, y + dy, c);
            }
        }
    }
    fn line(&mut self, (x0, y0): (i64, i64), (x1, y1): (i64, i64), r: i64, c: [u8; 3]) {
        let steps = (x1 - x0).abs().max((y1 - y0).abs()).max(1);
        for i in 0..=steps {
            let x = x0 + (x1 - x0) * i / steps;
            let y = y0 + (y1 - y0) * i / steps;
            self.dot(x, y, r, c);
        }
    }
}

/// `series[v][d]`: value (percent) of variant v at depth index d for each panel.
pub fn draw(panels: &[Vec<Vec<Option<f64>>>; 2], path: &Path) -> Result<()> {
    let mut cv = Canvas::new(2 * PANEL_W, PANEL_H);
    for (p, series) in panels.iter().enumerate() {
        let x0 = (p * PANEL_W + MARGIN) as i64;
        let x1 = ((p + 1) * PANEL_W - MARGIN / 2) as i64;
        let y0 = (PANEL_H - MARGIN) as i64;
        let y1 = (MARGIN / 2) as i64;
        let y_of = |v: f64| y0 - ((y0 - y1) as f64 * v.clamp(0.0, 100.0) / 100.0) as i64;
        for g in (0..=100).step_by(10) {
            let y = y_of(g as f64);
            cv.line((x0, y), (x1, y), 0, [225, 225, 225]);
        }
        cv.line((x0, y0), (x1, y0), 0, [0, 0, 0]);
        cv.line((x0, y0), (x0, y1), 0, [0, 0, 0]);
        let n = series.first().map_or(0, Vec::len).max(1);
        let x_of = |d: usize| x0 + 20 + (x1 - x0 - 40) * d as i64 / (n as i64 - 1).max(1);
        for d in 0..n {
            cv.line((x_of(d), y0), (x_of(d), y0 + 5), 0, [0, 0, 0]);
        }
        for (v, values) in series.iter().enumerate() {
            let c = COLOURS[v % COLOURS.len()].1;
            let mut prev: Option<(i64, i64)> = None;
            for (d, value) in values.iter().enumerate() {
                match value {
                    Some(val) => {
                        let pt = (x_of(d), y_of(*val));
                        if let Some(q) = prev {
                            cv.line(q, pt, 1, c);
                        }
                        cv.dot(pt.0, pt.1, 3, c);
                        prev = Some(pt);
                    }
                    None => prev = None,
                }
            }
        }
    }
    let mut bytes = Vec::new();
    {
        let mut enc = png::Encoder::new(&mut bytes, cv.w as u32, cv.h as u32);
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        let mut w = enc.write_header().context("PNG header")?;
        w.write_image_data(&cv.px).context("PNG data")?;
    }
    super::io::write_atomic(path, &bytes)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn draws_a_png_with_the_series_colours() {
        let tmp = tempfile::tempdir().unwrap();
        let path = tmp.path().join("fig.png");
        let series = vec![
            vec![Some(40.0), Some(45.0), Some(50.0), None, Some(52.0)],
            vec![Some(30.0); 5],
        ];
        draw(&[series.clone(), series], &path).unwrap();
        let dec = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(&path).unwrap()));
        let mut reader = dec.read_info().unwrap();
        let mut buf = vec![0; reader.output_buffer_size().unwrap()];
        let info = reader.next_frame(&mut buf).unwrap();
        assert_eq!(
            (info.width, info.height),
            (2 * PANEL_W as u32, PANEL_H as u32)
        );
        let count = |c: [u8; 3]| buf.chunks(3).filter(|p| *p == c).count();
        assert!(count(COLOURS[0].1) > 50 && count(COLOURS[1].1) > 50);
        assert_eq!(count(COLOURS[2].1), 0, "no third series");
    }
}
