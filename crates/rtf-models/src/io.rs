//! A network's weights in and out, apart from the networks themselves: safetensors
//! state_dicts under the reference names ([`weights`]), a network ready for inference from a
//! weights file ([`loaded`]), deployment files ([`export`], with the ONNX exporter script it
//! runs, `io/export_onnx.py`, beside it) and SegFormer's pretrained Mix Transformer for CMX
//! ([`mit_pretrained`]).

pub mod export;
pub mod loaded;
pub mod mit_pretrained;
pub mod weights;
