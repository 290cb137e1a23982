//! Outputs never land on the data (issue 43): before a command writes a file it checks that
//! the file is not one it reads (never allowed), and that an existing file it would replace
//! is rtf's own output — a prediction PNG carrying rtf's `Software` text, its logits beside
//! it, an `rtf eval --json` file — and not a file of a dataset the command was given.
//! Replacing anything else takes `--overwrite`. New files may go anywhere (pseudo-labelling
//! into an empty `Label/` folder keeps working); a training run's folder never is, or is
//! inside, the dataset it trains on (rtf_train::launch::check_run_folder).

use std::path::{Path, PathBuf};

use anyhow::{bail, Result};

/// What a command reads and was given, and whether the user asked to overwrite.
#[derive(Debug, Default)]
pub struct OutputGuard {
    inputs: Vec<PathBuf>,
    datasets: Vec<PathBuf>,
    overwrite: bool,
}

pub use rtf_core::resolved;

impl OutputGuard {
    pub fn new(overwrite: bool) -> Self {
        Self {
            overwrite,
            ..Self::default()
        }
    }

    /// Files the command reads: never written.
    pub fn reading<'a>(mut self, files: impl IntoIterator<Item = &'a Path>) -> Self {
        self.inputs.extend(files.into_iter().map(resolved));
        self
    }

    /// A dataset root the command was given: none of its files is replaced without
    /// `--overwrite`.
    pub fn dataset(mut self, root: &Path) -> Self {
        self.datasets.push(resolved(root));
        self
    }

    /// Checks `path` before `what` writes it (module docs); the error names the file, why, and
    /// what to do.
    pub fn check(&self, path: &Path, what: &str) -> Result<()> {
        let target = resolved(path);
        if self.inputs.contains(&target) {
            bail!(
                "{}: {what} would overwrite a file this command reads; choose another path (nothing was written)",
                path.display()
            );
        }
        if !path.exists() || self.overwrite {
            return Ok(());
        }
        if let Some(root) = self.datasets.iter().find(|root| target.starts_with(root)) {
            bail!(
                "{}: {what} would replace a file of the dataset {}; choose another path, or give --overwrite to replace it (nothing was written)",
                path.display(),
                root.display()
            );
        }
        if !written_by_rtf(path) {
            bail!(
                "{}: exists and was not written by rtf; {what} would replace it: choose another path, or give --overwrite (nothing was written)",
                path.display()
            );
        }
        Ok(())
    }
}

/// Whether rtf wrote the file at `path`, by its content: a PNG with rtf's `Software` text, a
/// `.npy` whose `<stem>.png` beside it is one (predict's logits), an `rtf-…` schema JSON.
pub fn written_by_rtf(path: &Path) -> bool {
    let ext = path
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase());
    match ext.as_deref() {
        Some("png") => rtf_data::pngio::written_by_rtf(path),
        Some("npy") => rtf_data::pngio::written_by_rtf(&path.with_extension("png")),
        Some("json") => std::fs::read(path)
            .ok()
            .and_then(|b| serde_json::from_slice::<serde_json::Value>(&b).ok())
            .and_then(|v| v.get("schema")?.as_str().map(|s| s.starts_with("rtf-")))
            .unwrap_or(false),
        _ => false,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn inputs_dataset_files_and_foreign_files_are_refused_rtf_outputs_are_not() {
        let dir = tempfile::tempdir().unwrap();
        let root = dir.path().join("data");
        std::fs::create_dir_all(root.join("labels")).unwrap();
        let label = root.join("labels/a.png");
        std::fs::write(
            &label,
            rtf_data::pngio::encode_png_u8(1, 1, 1, &[0]).unwrap(),
        )
        .unwrap();
        let ours = dir.path().join("ours.png");
        std::fs::write(
            &ours,
            rtf_data::pngio::encode_png_u8_tagged(1, 1, 1, &[0]).unwrap(),
        )
        .unwrap();
        let foreign = dir.path().join("notes.json");
        std::fs::write(&foreign, b"{\"mine\": 1}").unwrap();
        let eval = dir.path().join("eval.json");
        std::fs::write(&eval, b"{\"schema\": \"rtf-eval/1\"}").unwrap();
        let weights = dir.path().join("w.safetensors");
        let guard = OutputGuard::new(false)
            .reading([weights.as_path()])
            .dataset(&root);
        let err = |p: &Path| guard.check(p, "predict").unwrap_err().to_string();
        assert!(err(&weights).contains("reads"));
        assert!(err(&root.join("labels/../labels/a.png")).contains("file of the dataset"));
        assert!(err(&foreign).contains("not written by rtf"));
        guard.check(&ours, "predict").unwrap();
        guard.check(&eval, "eval --json").unwrap();
        guard
            .check(&root.join("labels/new.png"), "predict")
            .unwrap();
        let asked = OutputGuard::new(true)
            .reading([weights.as_path()])
            .dataset(&root);
        asked.check(&label, "predict").unwrap();
        asked.check(&foreign, "predict").unwrap();
        assert!(
            asked.check(&weights, "predict").is_err(),
            "an input, even with --overwrite"
        );
    }
}
