//! rtf-models: networks on tch.
