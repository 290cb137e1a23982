//! The page's small HTML pieces: escaping, embedded images (`data:` URIs), percentages.

use base64::Engine;

pub(crate) fn esc(text: &str) -> String {
    text.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// An `<img>` with `bytes` embedded.
pub(crate) fn img(mime: &str, bytes: &[u8], alt: &str) -> String {
    format!(
        "<img alt=\"{}\" src=\"data:{mime};base64,{}\">",
        esc(alt),
        base64::engine::general_purpose::STANDARD.encode(bytes)
    )
}

pub(crate) fn svg_img(svg: &str, alt: &str) -> String {
    img("image/svg+xml", svg.as_bytes(), alt)
}

/// A fraction as a percentage with one decimal; `–` for none.
pub(crate) fn pct(v: Option<f64>) -> String {
    v.map_or("–".to_string(), |v| format!("{:.1}", 100.0 * v))
}

/// An epoch number as people write it (`80`, not `80.0`).
pub(crate) fn epoch_text(epoch: f64) -> String {
    crate::charts::epoch_label(&epoch)
}
