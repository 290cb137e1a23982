//! The teachers of a run, checked once against its student before anything is written
//! ([`Teachers`]): the class count, the input convention, the file, and the network and inputs
//! its metadata records. The procedures load a [`CheckedTeacher`] without checking it again.
use std::path::{Path, PathBuf};

use rtf_models::{Modality, ModelConfig};

use crate::config::{Procedure as ProcedureConfig, TeacherRef};
use crate::error::TrainError;

/// A teacher given as a weights file, checked to be able to teach the student.
#[derive(Debug, Clone, PartialEq)]
pub struct CheckedTeacher {
    pub model: ModelConfig,
    pub path: PathBuf,
    pub inputs: Modality,
}

/// The day and night teachers of a procedure, checked (none for supervised training).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Teachers {
    pub day: Option<CheckedTeacher>,
    pub night: Option<CheckedTeacher>,
}

#[cfg(test)]
thread_local! {
    /// How many teachers this thread checked (the plan's tests).
    pub(super) static CHECKED: std::cell::Cell<usize> = const { std::cell::Cell::new(0) };
}

impl Teachers {
    /// The teachers of `procedure`, each checked against `student`. A teacher that names a
    /// stage is refused: only a multi-stage run resolves it to its weights.
    pub fn check(procedure: &ProcedureConfig, student: &ModelConfig) -> Result<Self, TrainError> {
        let (day, night) = match procedure {
            ProcedureConfig::Supervised => return Ok(Self::default()),
            ProcedureConfig::TeacherStudent {
                day_teacher,
                night_teacher,
                ..
            }
            | ProcedureConfig::Adversarial {
                day_teacher,
                night_teacher,
                ..
            } => (day_teacher, night_teacher.as_ref()),
        };
        let check = |teacher: &TeacherRef| match teacher {
            TeacherRef::Weights {
                path,
                model,
                inputs,
            } => CheckedTeacher::check(model, path, *inputs, student),
            TeacherRef::Stage(name) => Err(TrainError::Config(format!(
                "teacher stage `{name}` was not resolved to its weights (a stage teacher only \
                 works inside a multi-stage run)"
            ))),
        };
        Ok(Self {
            day: Some(check(day)?),
            night: night.map(check).transpose()?,
        })
    }
}

/// Checks, before anything is written, that the teachers of `procedure` given as files can
/// teach its `student` (stage teachers are checked by their stage).
pub fn check_teachers(
    procedure: &ProcedureConfig,
    student: &ModelConfig,
) -> Result<(), TrainError> {
    for teacher in procedure.teachers() {
        if let TeacherRef::Weights {
            path,
            model,
            inputs,
        } = teacher
        {
            CheckedTeacher::check(model, path, *inputs, student)?;
        }
    }
    Ok(())
}

impl CheckedTeacher {
    /// Checks that `weights`, a `model` network seeing `inputs`, can teach `student`: same
    /// class count and input convention (the batch is scaled once, for the student), and the
    /// network and inputs the file records, where it records them.
    pub fn check(
        model: &ModelConfig,
        weights: &Path,
        inputs: Modality,
        student: &ModelConfig,
    ) -> Result<Self, TrainError> {
        #[cfg(test)]
        CHECKED.with(|n| n.set(n.get() + 1));
        let bad = |message: String| TrainError::Run {
            path: weights.to_path_buf(),
            message,
        };
        if model.num_classes() != student.num_classes() {
            return Err(bad(format!(
                "the teacher ({}) predicts {} classes, the student ({}) {}",
                model.name(),
                model.num_classes(),
                student.name(),
                student.num_classes()
            )));
        }
        if model.input_convention() != student.input_convention() {
            return Err(bad(format!(
                "the teacher ({}) takes inputs scaled as {:?}, the student ({}) as {:?}; \
                 pick a teacher and student of the same input convention",
                model.name(),
                model.input_convention(),
                student.name(),
                student.input_convention()
            )));
        }
        if !weights.is_file() {
            return Err(bad("teacher weights not found".into()));
        }
        // The file's own record of its network and inputs (absent in converted weights): a
        // teacher behind another mask than it was trained with labels garbage, silently.
        let meta = rtf_models::io::weights::read_weights_metadata(weights)?;
        if let Some(saved) = meta.saved_config(weights)?.filter(|saved| saved != model) {
            return Err(bad(format!(
                "the file holds a {} network, the teacher is declared as {}",
                saved.name(),
                model.name()
            )));
        }
        if let Some(saved) = meta.saved_inputs(weights)?.filter(|saved| *saved != inputs) {
            return Err(bad(format!(
                "the teacher was trained on `{saved}` inputs and would label frames seeing \
                 `{inputs}`; give it its own inputs (`inputs: {saved}`, --teacher-inputs {saved})"
            )));
        }
        Ok(Self {
            model: model.clone(),
            path: weights.to_path_buf(),
            inputs,
        })
    }
}
