//! An MF image/label pair split from the input at a position given by its first two bytes.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if data.len() < 2 {
        return;
    }
    let cut = (u16::from_le_bytes([data[0], data[1]]) as usize).min(data.len() - 2);
    let (image, label) = data[2..].split_at(cut);
    if let Ok(frame) = rtf_data::fuzzing::mf_pair(image, label) {
        assert_eq!(frame.rgb.len(), 3 * frame.width * frame.height);
        assert_eq!(frame.thermal.len(), frame.width * frame.height);
    }
});
