//! rtf-train
