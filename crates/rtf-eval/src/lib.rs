//! rtf-eval

pub mod speed;
