//! Every byte reader of rtf-data (PNG, MF pair, Freiburg triple, label .npy, split text) on
//! arbitrary input: errors are fine, panics are bugs.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    rtf_data::fuzzing::all_readers(data);
});
