//! Entry points shared by the cargo-fuzz targets (`fuzz/`) and the in-test mutation loop:
//! every reader of untrusted bytes, which must return errors and never panic.

use crate::DataError;
use rtf_core::{ClassSet, Daytime};
use std::path::Path;

/// Runs every byte reader on `data` (split between image and label at `data[0]`).
pub fn all_readers(data: &[u8]) {
    let _ = crate::pngio::decode_png(data, Path::new("fuzz.png"));
    let cut = data.first().map_or(0, |&b| b as usize * data.len() / 256);
    let (a, b) = data.split_at(cut.min(data.len()));
    let _ = mf_pair(a, b);
    let _ = freiburg_triple(a, b, b);
    let _ = crate::npy::decode_label_npy(data, Path::new("fuzz.npy"));
    let _ = crate::mf::parse_split(&String::from_utf8_lossy(data), Path::new("fuzz.txt"));
}

/// Decodes an MF image/label pair from bytes.
pub fn mf_pair(image: &[u8], label: &[u8]) -> Result<crate::Frame, DataError> {
    crate::mf::decode_mf_frame(
        "00001D",
        image,
        Path::new("images/00001D.png"),
        label,
        Path::new("labels/00001D.png"),
        &ClassSet::mf(),
    )
}

/// Decodes a Freiburg RGB/IR/label(.npy) triple from bytes.
pub fn freiburg_triple(
    rgb: &[u8],
    ir: &[u8],
    label_npy: &[u8],
) -> Result<crate::freiburg::RawFreiburgFrame, DataError> {
    crate::freiburg::decode_raw(
        "fuzz",
        Daytime::Day,
        rgb,
        Path::new("ImagesRGB/x_rgb.png"),
        ir,
        Path::new("ImagesIR/x_ir.png"),
        Some((label_npy, Path::new("SegmentationClass/x.npy"), true)),
        &ClassSet::freiburg(),
    )
}

/// `cases` inputs for a reader made from a valid file, the same for a given `seed`: one in
/// eight random bytes, the others the file with bit flips, a truncation, an inserted, an
/// overwritten or a removed run of bytes (half of the edits in the first 512 bytes, where
/// headers are).
pub fn mutations(valid: &[u8], seed: u64, cases: usize) -> impl Iterator<Item = Vec<u8>> {
    use rand::{Rng, SeedableRng};
    let valid = valid.to_vec();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    (0..cases).map(move |_| {
        let mut b = valid.clone();
        let kind = rng.random_range(0..8);
        if kind == 0 || b.is_empty() {
            let mut random = vec![0u8; rng.random_range(0..2 * valid.len().clamp(16, 4096))];
            rng.fill(random.as_mut_slice());
            return random;
        }
        let at = |rng: &mut rand_chacha::ChaCha8Rng, len: usize| match rng.random_bool(0.5) {
            true => rng.random_range(0..len.min(512)),
            false => rng.random_range(0..len),
        };
        match kind {
            1 | 2 => {
                for _ in 0..rng.random_range(1..9) {
                    let i = at(&mut rng, b.len());
                    b[i] ^= 1 << rng.random_range(0..8);
                }
            }
            3 => b.truncate(at(&mut rng, b.len())),
            4 => {
                let i = at(&mut rng, b.len());
                let mut run = vec![0u8; rng.random_range(1..64)];
                rng.fill(run.as_mut_slice());
                b.splice(i..i, run);
            }
            5 => {
                let i = at(&mut rng, b.len());
                let n = rng.random_range(1..64).min(b.len() - i);
                rng.fill(&mut b[i..i + n]);
            }
            6 => {
                let i = at(&mut rng, b.len());
                let n = rng.random_range(1..64).min(b.len() - i);
                b.drain(i..i + n);
            }
            _ => {
                // A number-like or delimiter byte: what text formats (JSON, YAML) turn on.
                const TOKENS: &[u8] = b"0123456789-.:,[]{}\"' \n#e";
                let i = at(&mut rng, b.len());
                b[i] = TOKENS[rng.random_range(0..TOKENS.len())];
            }
        }
        b
    })
}

/// How a reader fared in [`check_reader`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ReaderOutcome {
    pub accepted: usize,
    pub refused: usize,
}

/// Runs `read` on `valid` (which it must accept) and on its `cases` [`mutations`] from `seed`:
/// every input must give a value or an error whose text contains `names` (the file's name;
/// "" for readers of bytes without one); a panic fails with the case's number and seed.
pub fn check_reader<T, E: std::fmt::Display>(
    what: &str,
    valid: &[u8],
    seed: u64,
    cases: usize,
    names: &str,
    read: impl Fn(&[u8]) -> Result<T, E>,
) -> ReaderOutcome {
    if let Err(e) = read(valid) {
        panic!("{what}: the valid input is refused: {e}");
    }
    let mut outcome = ReaderOutcome {
        accepted: 0,
        refused: 0,
    };
    for (case, bytes) in mutations(valid, seed, cases).enumerate() {
        let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            read(&bytes).map(|_| ()).map_err(|e| e.to_string())
        }));
        match result {
            Err(_) => panic!(
                "{what}: case {case} of seed {seed} panicked ({} bytes)",
                bytes.len()
            ),
            Ok(Ok(())) => outcome.accepted += 1,
            Ok(Err(text)) => {
                assert!(
                    text.contains(names),
                    "{what}: case {case} of seed {seed}: error without `{names}`: {text}"
                );
                outcome.refused += 1;
            }
        }
    }
    outcome
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testutil::*;
    use rand::{Rng, SeedableRng};

    fn mutate(bytes: &[u8], rng: &mut impl Rng) -> Vec<u8> {
        let mut b = bytes.to_vec();
        match rng.random_range(0..4) {
            0 => b.truncate(rng.random_range(0..b.len())),
            1 => {
                for _ in 0..rng.random_range(1..9) {
                    let i = rng.random_range(0..b.len());
                    b[i] ^= 1 << rng.random_range(0..8);
                }
            }
            2 => {
                let i = rng.random_range(0..b.len());
                let n = rng.random_range(1..16).min(b.len() - i);
                rng.fill(&mut b[i..i + n]);
            }
            _ => {
                // Header fields (width/height/depth/colour type) live in the first 33 bytes.
                let i = rng.random_range(8..33.min(b.len()));
                b[i] = rng.random();
            }
        }
        b
    }

    /// A quick fuzz-like loop: random truncations and bit flips of valid files must give
    /// errors (naming the file) or valid frames, never a panic or a huge allocation.
    #[test]
    fn mutated_pngs_and_npys_never_panic() {
        let (w, h) = (16, 12);
        let image = png_u8(w, h, 4, &rgba(w, h, 3));
        let label = png_u8(w, h, 1, &ids(w, h, 9));
        let rgb = png_u8(w, h, 3, &vec![100; 3 * w * h]);
        let ir = png_u16(w, h, 1, &vec![23000; w * h]);
        let npy = crate::npy::encode_u8(w, h, &ids(w, h, 13));
        assert!(mf_pair(&image, &label).is_ok());
        assert!(freiburg_triple(&rgb, &ir, &npy).is_ok());
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1234);
        let (mut errors, mut oks) = (0, 0);
        for _ in 0..1500 {
            let (mi, ml) = (mutate(&image, &mut rng), mutate(&label, &mut rng));
            let (mr, mir, mn) = (
                mutate(&rgb, &mut rng),
                mutate(&ir, &mut rng),
                mutate(&npy, &mut rng),
            );
            let outcome = std::panic::catch_unwind(|| {
                all_readers(&mi);
                (
                    mf_pair(&mi, &ml).map(|_| ()),
                    freiburg_triple(&mr, &mir, &mn).map(|_| ()),
                )
            });
            let (mf, fr) = outcome.expect("a reader panicked on mutated bytes");
            for r in [mf, fr] {
                match r {
                    Ok(()) => oks += 1,
                    Err(e) => {
                        let text = e.to_string();
                        assert!(
                            text.contains(".png") || text.contains(".npy"),
                            "error without a file name: {text}"
                        );
                        errors += 1;
                    }
                }
            }
        }
        assert!(
            errors > 1000,
            "mutations were mostly rejected ({errors} errors, {oks} ok)"
        );
    }
}
