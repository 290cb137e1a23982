//! The procedure's networks built from the parts of a run plan ([`Spec`]): the student from
//! its network, learning and compute sections, the teachers from those checked once by the
//! plan ([`crate::plan::Teachers`]), loaded here without checking them again.
use tch::Device;

use super::{Adversarial, Frozen, Labeller, Procedure, Student, Supervised, TeacherStudent};
use crate::config::{
    ComputeConfig, LearningConfig, NetworkConfig, Procedure as ProcedureConfig, TrainConfig,
};
use crate::error::TrainError;
use crate::plan::{CheckedTeacher, Teachers};
use std::sync::Arc;

use rtf_models::{ModelConfig, StatsAllReduce, UnitKernels};

/// What a procedure's networks are built from: the student's sections and the checked
/// teachers.
pub struct Spec<'a> {
    pub network: &'a NetworkConfig,
    pub learning: &'a LearningConfig,
    pub compute: &'a ComputeConfig,
    pub teachers: &'a Teachers,
    /// Data-parallel with synchronised BatchNorm: the sum over the ranks the trained networks'
    /// BatchNorms take their statistics with.
    pub sync: Option<Arc<dyn StatsAllReduce>>,
}

impl<'a> Spec<'a> {
    /// The spec of `cfg` with its `teachers` (checked: [`Teachers::check`]).
    pub fn of(cfg: &'a TrainConfig, teachers: &'a Teachers) -> Self {
        Self {
            network: &cfg.network,
            learning: &cfg.learning,
            compute: &cfg.compute,
            teachers,
            sync: None,
        }
    }
}

impl Student {
    /// The student `network` learning as `learning` says on `device` (its fp32 layout and
    /// kernels from `compute`; its BatchNorms synchronised by `sync` in a data-parallel run that
    /// asks for it), built under the seed the caller set, as the supervised loop always did
    /// (same initial weights).
    pub fn of(
        network: &NetworkConfig,
        learning: &LearningConfig,
        compute: &ComputeConfig,
        sync: Option<Arc<dyn StatsAllReduce>>,
        device: Device,
    ) -> Result<Self, TrainError> {
        // Convolutional networks train channels-last in fp32 too; CMX (attention) was not
        // measured so and keeps NCHW.
        let convolutional = !matches!(network.model, ModelConfig::Cmx(_));
        let layout = compute
            .fp32_layout
            .unwrap_or_else(|| crate::config::fp32_layout_faster_on(device));
        let kernels = UnitKernels {
            winograd: compute.winograd,
            bf16_convolutions: crate::config::bf16_convolutions_in_force(compute),
            sync,
        };
        let trained = super::Trained::new(super::STUDENT, device, &learning.optimizer)
            .fp32_layout(convolutional, layout)
            .computing(kernels)
            .mixed(learning.precision)?;
        let inner =
            rtf_models::build_with(&trained.vs.root(), &network.model, &trained.build_options())?;
        trained.channels_last_weights();
        Ok(Self {
            trained,
            net: rtf_models::Masked {
                inner,
                inputs: network.inputs,
            },
        })
    }
}

/// Builds the procedure `spec` names. The student is built first, right after the caller
/// seeded libtorch, so supervised runs start from the weights they always did.
pub fn build_from(
    spec: &Spec,
    ignore_id: Option<u8>,
    device: Device,
) -> Result<Box<dyn Procedure>, TrainError> {
    let student = || {
        let sync = spec.sync.clone();
        Student::of(spec.network, spec.learning, spec.compute, sync, device)
    };
    Ok(match &spec.learning.procedure {
        ProcedureConfig::Supervised => Box::new(Supervised {
            student: student()?,
            loss: crate::loss::build(&spec.learning.loss, ignore_id, device),
        }),
        ProcedureConfig::TeacherStudent { targets, .. } => {
            let student = student()?;
            let (day, night) = labellers(spec, ignore_id, device)?;
            Box::new(TeacherStudent {
                student,
                day_teacher: day,
                night_teacher: night,
                targets: targets.clone(),
            })
        }
        ProcedureConfig::Adversarial { .. } => Box::new(adversarial_from(spec, ignore_id, device)?),
    })
}

/// [`build_from`] of an adversarial procedure, as its own type (whose two step halves can be
/// driven one at a time).
pub fn adversarial_from(
    spec: &Spec,
    ignore_id: Option<u8>,
    device: Device,
) -> Result<Adversarial, TrainError> {
    let ProcedureConfig::Adversarial {
        targets, critic, ..
    } = &spec.learning.procedure
    else {
        return Err(TrainError::Config(
            "not an adversarial configuration".into(),
        ));
    };
    let sync = spec.sync.clone();
    let student = Student::of(spec.network, spec.learning, spec.compute, sync, device)?;
    let (day, night) = labellers(spec, ignore_id, device)?;
    Adversarial::new(student, day, night, targets.clone(), critic.clone(), device)
}

/// The day teacher and the night teacher (if any) loaded to label frames, live or into the
/// label cache as the procedure's targets say.
fn labellers(
    spec: &Spec,
    ignore_id: Option<u8>,
    device: Device,
) -> Result<(Labeller, Option<Labeller>), TrainError> {
    let cached = match &spec.learning.procedure {
        ProcedureConfig::TeacherStudent { targets, .. }
        | ProcedureConfig::Adversarial { targets, .. } => targets.cache,
        ProcedureConfig::Supervised => false,
    };
    let labeller = |teacher: &CheckedTeacher| -> Result<Labeller, TrainError> {
        Ok(Labeller {
            teacher: Frozen::load(teacher, device)?,
            cached: cached.then(|| ignore_id.map_or(crate::loss::PSEUDO_IGNORE, i64::from)),
        })
    };
    let day = spec.teachers.day.as_ref().ok_or_else(|| {
        TrainError::Config(format!(
            "the {} procedure has no checked day teacher",
            spec.learning.procedure.name()
        ))
    })?;
    Ok((
        labeller(day)?,
        spec.teachers.night.as_ref().map(labeller).transpose()?,
    ))
}
