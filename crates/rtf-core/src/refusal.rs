//! Why a command's library layer did not do what was asked, said as the command says it.
//!
//! `rtf_train::setup`, `rtf_eval::predict` and `rtf_models::io::export` each do a command's work
//! for a thin CLI; their error enums wrap a [`Refusal`] (`#[from]`) beside the typed errors
//! of the crates below them, so the message a user reads is written once, where the check is.

use std::error::Error;

/// What was asked cannot be done (nothing was written), or failed on something the message
/// names first (a file, a flag, a frame) with the underlying error kept as the source.
#[derive(Debug, thiserror::Error)]
pub enum Refusal {
    /// The request itself cannot be carried out.
    #[error("{0}")]
    Refused(String),
    /// An error with what it concerns said first.
    #[error("{message}")]
    Because {
        message: String,
        #[source]
        source: Box<dyn Error + Send + Sync>,
    },
}

impl Refusal {
    /// [`Refusal::Because`]: `message` names what failed, `source` says how.
    pub fn because(message: impl Into<String>, source: impl Error + Send + Sync + 'static) -> Self {
        Self::Because {
            message: message.into(),
            source: Box::new(source),
        }
    }
}

/// [`Refusal::Refused`] as the caller's error type (`return Err(refused(…))`).
pub fn refused<E: From<Refusal>>(message: impl Into<String>) -> E {
    Refusal::Refused(message.into()).into()
}

/// `anyhow::ensure!` for a [`Refusal::Refused`]: the message is built only when refused.
pub fn ensure(condition: bool, message: impl FnOnce() -> String) -> Result<(), Refusal> {
    match condition {
        true => Ok(()),
        false => Err(Refusal::Refused(message())),
    }
}

/// `error` and its sources, `: `-joined: one line for a caller that shows only the top of an
/// error (the atomic writer's closure does).
pub fn flattened(error: &(dyn Error + 'static)) -> String {
    let mut text = error.to_string();
    let mut source = error.source();
    while let Some(e) = source {
        text += &format!(": {e}");
        source = e.source();
    }
    text
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Debug, thiserror::Error)]
    enum CommandError {
        #[error(transparent)]
        Request(#[from] Refusal),
    }

    #[test]
    fn a_wrapped_refusal_says_its_message_and_keeps_its_source() {
        let io = std::io::Error::new(std::io::ErrorKind::NotFound, "no such file");
        let error = CommandError::from(Refusal::because("weights.ot: cannot read", io));
        assert_eq!(error.to_string(), "weights.ot: cannot read");
        assert_eq!(error.source().unwrap().to_string(), "no such file");
        assert_eq!(flattened(&error), "weights.ot: cannot read: no such file");
    }

    #[test]
    fn refused_and_ensure_carry_the_message_alone() {
        let error: CommandError = refused("--data is required");
        assert_eq!(error.to_string(), "--data is required");
        assert!(error.source().is_none());
        assert!(ensure(true, || unreachable!()).is_ok());
        let refusal = ensure(false, || "--epochs 0: at least 1".into()).unwrap_err();
        assert_eq!(refusal.to_string(), "--epochs 0: at least 1");
    }
}
