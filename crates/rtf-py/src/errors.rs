//! rtf's errors as Python exceptions: `rtf.Error` and one subclass per library error kind,
//! each carrying the message the CLI prints (the error and its causes, `: `-joined, as
//! `rtf`'s `error: {err:#}` line reads).

use pyo3::create_exception;
use pyo3::exceptions::PyException;
use pyo3::prelude::*;

create_exception!(rtf, Error, PyException, "Every error rtf raises.");
create_exception!(
    rtf,
    DataError,
    Error,
    "A dataset, image or label that cannot be read as asked (rtf_data)."
);
create_exception!(
    rtf,
    ModelError,
    Error,
    "A network or weights file that cannot be built or loaded as asked (rtf_models)."
);
create_exception!(
    rtf,
    EvalError,
    Error,
    "An evaluation or inference that cannot run (rtf_eval), e.g. out of memory."
);
create_exception!(
    rtf,
    InputError,
    Error,
    "An argument from Python of the wrong type, dtype, shape or device, refused before \
     anything runs."
);
create_exception!(rtf, TorchError, Error, "An error libtorch reported (tch).");
create_exception!(
    rtf,
    TrainError,
    Error,
    "A training run that cannot be set up, continued or finished (rtf_train): a bad \
     configuration, a run folder of another run, a diverged loss."
);
create_exception!(
    rtf,
    CalibrationError,
    Error,
    "A rig, its images or a calibration that cannot be read, solved or written (rtf_calib)."
);

/// Adds the exception classes to the module.
pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    m.add("Error", py.get_type::<Error>())?;
    m.add("DataError", py.get_type::<DataError>())?;
    m.add("ModelError", py.get_type::<ModelError>())?;
    m.add("EvalError", py.get_type::<EvalError>())?;
    m.add("InputError", py.get_type::<InputError>())?;
    m.add("TorchError", py.get_type::<TorchError>())?;
    m.add("TrainError", py.get_type::<TrainError>())?;
    m.add("CalibrationError", py.get_type::<CalibrationError>())?;
    Ok(())
}

/// The error and its causes as `rtf` prints them: `outer: inner: innermost`, each cause once
/// (a transparent wrapper's message is its source's, not repeated).
pub fn message(err: &(dyn std::error::Error + 'static)) -> String {
    let mut text = err.to_string();
    let mut source = err.source();
    while let Some(cause) = source {
        let line = cause.to_string();
        if !text.ends_with(&line) {
            text.push_str(": ");
            text.push_str(&line);
        }
        source = cause.source();
    }
    text
}

/// A bad argument from Python, as `rtf.InputError`.
pub fn input(text: impl Into<String>) -> PyErr {
    InputError::new_err(text.into())
}

/// Library errors to their exception class.
pub trait ToPy {
    fn to_py(self) -> PyErr;
}

impl ToPy for rtf_data::DataError {
    fn to_py(self) -> PyErr {
        DataError::new_err(message(&self))
    }
}

impl ToPy for rtf_models::ModelError {
    fn to_py(self) -> PyErr {
        ModelError::new_err(message(&self))
    }
}

impl ToPy for tch::TchError {
    fn to_py(self) -> PyErr {
        TorchError::new_err(message(&self))
    }
}

impl ToPy for rtf_eval::EvalError {
    fn to_py(self) -> PyErr {
        match self {
            rtf_eval::EvalError::Data(e) => e.to_py(),
            rtf_eval::EvalError::Torch(e) => e.to_py(),
            other => EvalError::new_err(message(&other)),
        }
    }
}

impl ToPy for rtf_eval::predict::PredictError {
    fn to_py(self) -> PyErr {
        use rtf_eval::predict::PredictError as E;
        match self {
            E::Data(e) => e.to_py(),
            E::Eval(e) => e.to_py(),
            E::Tensor(e) => e.to_py(),
            E::Request(e) => InputError::new_err(message(&e)),
        }
    }
}

impl ToPy for rtf_calib::error::CalibError {
    fn to_py(self) -> PyErr {
        match self {
            rtf_calib::error::CalibError::Torch(e) => e.to_py(),
            other => CalibrationError::new_err(message(&other)),
        }
    }
}

impl ToPy for rtf_train::TrainError {
    fn to_py(self) -> PyErr {
        use rtf_train::TrainError as E;
        match self {
            E::Data(e) => e.to_py(),
            E::Model(e) => e.to_py(),
            E::Eval(e) => e.to_py(),
            other => TrainError::new_err(message(&other)),
        }
    }
}

impl ToPy for rtf_train::setup::SetupError {
    fn to_py(self) -> PyErr {
        use rtf_train::setup::SetupError as E;
        match self {
            E::Train(e) => e.to_py(),
            E::Data(e) => e.to_py(),
            E::Model(e) => e.to_py(),
            E::Request(e) => InputError::new_err(message(&e)),
            other => TrainError::new_err(message(&other)),
        }
    }
}

impl ToPy for rtf_amp::AmpError {
    fn to_py(self) -> PyErr {
        TrainError::new_err(message(&self))
    }
}

/// `result.py()`: the library error as its Python exception.
pub trait PyResultExt<T> {
    fn py(self) -> PyResult<T>;
}

impl<T, E: ToPy> PyResultExt<T> for Result<T, E> {
    fn py(self) -> PyResult<T> {
        self.map_err(ToPy::to_py)
    }
}
