//! rtf-eval
