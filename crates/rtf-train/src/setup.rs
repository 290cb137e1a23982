//! A new run's configuration from what its user asked (`rtf train`'s flags, typed in
//! [`NewRun`]): a `--config` file, a recipe's stages or one plain training, on a dataset
//! root, with the teachers resolved and every value given over the recipe's or file's.
//! Everything that can refuse the run is checked here, before a run folder exists: the
//! dataset's splits and frames, the teachers, `--init` weights that must fit the network.
//! It lives in the training crate so that the command only parses and prints; it sits above
//! [`crate::recipe`], [`crate::folder`] and [`crate::init`], which it calls.

use std::path::{Path, PathBuf};

use rtf_core::refusal::{ensure, refused, Refusal};
use rtf_core::ClassSet;
use rtf_data::inspect::DatasetFormat;
use rtf_models::{Modality, ModelConfig};

use crate::config::{
    CriticInput, CriticOptions, DatasetConfig, LrSchedule, OptimizerConfig, OptimizerKind,
    Precision, Procedure, RunConfig, SelectMetric, TeacherRef, TrainConfig, WeightsRef,
};
use crate::error::TrainError;
use crate::recipe::{self, RecipeInputs};

/// Why a new run's configuration could not be made. Each message reads as `rtf train`
/// says it (the flags are named); a wrapped error keeps its own message as the source.
#[derive(Debug, thiserror::Error)]
pub enum SetupError {
    /// What was asked cannot make a run, or failed on the file or flag the message names.
    #[error(transparent)]
    Request(#[from] Refusal),
    #[error(transparent)]
    Train(#[from] TrainError),
    #[error(transparent)]
    Data(#[from] rtf_data::DataError),
    #[error(transparent)]
    Model(#[from] rtf_models::ModelError),
    #[error(transparent)]
    Config(#[from] crate::config::ConfigError),
    #[error(transparent)]
    Recipe(#[from] recipe::RecipeError),
    #[error(transparent)]
    Io(#[from] std::io::Error),
}

/// An unknown or invalid network name, as the networks' error.
impl From<rtf_models::NetworkConfigError> for SetupError {
    fn from(e: rtf_models::NetworkConfigError) -> Self {
        SetupError::Model(e.into())
    }
}

/// A run folder that cannot be read (a resume's), as the trainer's error.
impl From<rtf_run::RunError> for SetupError {
    fn from(e: rtf_run::RunError) -> Self {
        SetupError::Train(e.into())
    }
}

/// A teacher given on the command line (`--teacher`, `--teacher-model`, `--teacher-inputs`).
#[derive(Debug, Clone, Default)]
pub struct TeacherArg {
    /// A run folder, or a weights file (then `model` names its network).
    pub path: Option<PathBuf>,
    pub model: Option<String>,
    pub inputs: Option<Modality>,
}

/// What a new run was asked: where its configuration comes from, and the values given over
/// it.
#[derive(Debug, Clone, Default)]
pub struct NewRun {
    /// `--recipe`: one of the papers' recipes ([`crate::recipe`]).
    pub recipe: Option<String>,
    /// `--config`: a file of config.json's schema (YAML or JSON).
    pub config: Option<PathBuf>,
    /// `--data`: the dataset root (required but with `--config`, which may name it).
    pub data: Option<PathBuf>,
    pub train_split: Option<String>,
    /// `none`: no validation.
    pub val_split: Option<String>,
    pub teacher: TeacherArg,
    pub night_teacher: TeacherArg,
    /// `--init`: starting weights of a single-stage run, checked now.
    pub init: Option<PathBuf>,
    /// `--reset-head`: the classifier head starts fresh (the class count may differ).
    pub reset_head: bool,
    pub overrides: Overrides,
}

/// The values given over a recipe's or config's, applied to every stage (None / false:
/// keep the stage's).
#[derive(Debug, Clone, Default)]
pub struct Overrides {
    /// The network (every role of a recipe: see [`RecipeInputs::model`]).
    pub model: Option<String>,
    pub inputs: Option<Modality>,
    pub threshold: Option<f64>,
    pub soft: bool,
    pub lambda: Option<f64>,
    pub critic_input: Option<CriticInput>,
    pub multidir: bool,
    pub critic_steps: Option<usize>,
    pub critic_init: Option<PathBuf>,
    /// The reference code's critic (logits, flipped targets, day term, alternating steps).
    pub critic_code: bool,
    pub select_by: Option<SelectMetric>,
    pub epochs: Option<usize>,
    pub batch_size: Option<usize>,
    /// The paper's optimiser of that kind, under the single values below.
    pub optimizer: Option<OptimizerKind>,
    pub lr: Option<f64>,
    pub lr_decay: Option<f64>,
    pub decay_every: Option<usize>,
    pub warmup_epochs: Option<usize>,
    pub momentum: Option<f64>,
    pub weight_decay: Option<f64>,
    pub no_flip: bool,
    pub no_augment: bool,
    pub no_shuffle: bool,
    pub seed: Option<u64>,
    pub resize: Option<(usize, usize)>,
    pub max_steps: Option<usize>,
    pub checkpoint_every: Option<usize>,
    pub workers: Option<usize>,
    pub device: Option<String>,
    pub precision: Option<Precision>,
    pub sync_bn: bool,
    /// A TensorBoard prediction grid every N epochs (0: never); always set.
    pub tb_images_every: usize,
    pub backbone_weights: Option<PathBuf>,
}

/// The configuration of a new run, checked ([`RunConfig::validate`]).
pub fn new_run(asked: &NewRun) -> Result<RunConfig, SetupError> {
    Ok(new_run_opened(asked)?.0)
}

/// [`new_run`], and the `--data` root it opened (None without `--data`): the trainer's run
/// plan takes it instead of opening the root again ([`crate::plan::RunPlan::resolve_opened`]).
pub fn new_run_opened(
    asked: &NewRun,
) -> Result<(RunConfig, Option<rtf_data::Dataset>), SetupError> {
    let (mut cfg, mut opened) = match (&asked.recipe, &asked.config) {
        (_, Some(path)) => (config_file_run(path)?, None),
        (Some(name), None) => recipe_run(name, asked).map(|(c, d)| (c, Some(d)))?,
        (None, None) => plain_run(asked).map(|(c, d)| (c, Some(d)))?,
    };
    if asked.config.is_some() {
        if let Some(data) = &asked.data {
            let (dataset, _, root) = dataset_of(data, asked)?;
            cfg.stages_mut()
                .into_iter()
                .for_each(|c| c.data.dataset = dataset.clone());
            opened = Some(root);
        }
        ensure(
            asked.teacher.path.is_none() && asked.night_teacher.path.is_none(),
            || {
                "--teacher and --night-teacher go with --recipe (a --config names its teachers)"
                    .into()
            },
        )?;
    }
    let recipe_networks = asked.recipe.is_some() || asked.config.is_some();
    for stage in cfg.stages_mut() {
        apply_flags(stage, &asked.overrides, recipe_networks)?;
        apply_parity_controls(stage, &asked.overrides);
    }
    if let Some(path) = &asked.init {
        apply_init(&mut cfg, path, asked.reset_head)?;
    }
    cfg.validate()?;
    Ok((cfg, opened))
}

/// A dataset root that `rtf train` reads, opened once (rtf_data::dataset), a described
/// layout announced on stderr (which layout, classes and thermal rule rtf inferred).
fn open_dataset(root: &Path) -> Result<rtf_data::Dataset, SetupError> {
    let dataset = rtf_data::dataset::open_for(root, "a training")?;
    if let Some(line) = dataset.announcement() {
        eprintln!("data: {line}");
    }
    Ok(dataset)
}

/// The dataset a `--data` root holds, its class set, resolved to an absolute path (a resume
/// from another directory finds it), and the root opened.
fn dataset_of(data: &Path, asked: &NewRun) -> Result<DataOf, SetupError> {
    let root = std::fs::canonicalize(data).map_err(|e| {
        Refusal::because(
            format!("{}: cannot open the dataset root", data.display()),
            e,
        )
    })?;
    let dataset = open_dataset(&root)?;
    let (config, classes) = match dataset.description() {
        None => built_in_dataset(root, &dataset, asked, data)?,
        Some(description) => described_dataset(root, description, asked)?,
    };
    Ok((config, classes, dataset))
}

/// What a `--data` root gives a new run: its dataset configuration, its class set, and the
/// root opened.
type DataOf = (DatasetConfig, ClassSet, rtf_data::Dataset);

/// An MF or Freiburg Thermal root: the layout fixes the class set and the splits (Freiburg:
/// none to name).
fn built_in_dataset(
    root: PathBuf,
    dataset: &rtf_data::Dataset,
    asked: &NewRun,
    data: &Path,
) -> Result<(DatasetConfig, ClassSet), SetupError> {
    let val = asked.val_split.clone().unwrap_or_else(|| "val".into());
    let validate = val != "none";
    if dataset.format() == DatasetFormat::Mf {
        let config = DatasetConfig::Mf {
            root,
            train_split: asked.train_split.clone().unwrap_or_else(|| "train".into()),
            val_split: validate.then_some(val),
        };
        return Ok((config, dataset.class_set()));
    }
    ensure(
        asked.train_split.is_none() && ["val", "none"].contains(&val.as_str()),
        || {
            format!(
                "{}: a Freiburg Thermal root has no named splits (training tree, val and test \
                 layouts); drop --train-split, and use --val-split only as \"none\"",
                data.display()
            )
        },
    )?;
    Ok((DatasetConfig::freiburg(root, validate), dataset.class_set()))
}

/// The validation split of a described root: `--val-split` (`none`: none), else `val` if it
/// has one (without it validation is skipped, said on stderr).
fn described_val_split(
    description: &rtf_data::DatasetDescription,
    asked: &NewRun,
) -> Option<String> {
    let val_split = match asked.val_split.as_deref() {
        Some("none") => None,
        Some(name) => Some(name.to_string()),
        None if description.split("val").is_some() => Some("val".to_string()),
        None => {
            eprintln!("data: no `val` split: validation skipped (name one with --val-split)");
            None
        }
    };
    if val_split.as_deref() == Some("test") {
        eprintln!("data: validating on the `test` split, as --val-split asks: best-epoch selection then sees test data");
    }
    val_split
}

/// A described root (dataset.yaml, MSRS, PST900, FMB): its class set sizes the network. The
/// public sets ship only train and test, so without a `val` split validation is skipped (said
/// on stderr); validating on test happens only when named, and is announced.
fn described_dataset(
    root: PathBuf,
    description: &rtf_data::DatasetDescription,
    asked: &NewRun,
) -> Result<(DatasetConfig, ClassSet), SetupError> {
    let train_split = asked.train_split.clone().unwrap_or_else(|| "train".into());
    let val_split = described_val_split(description, asked);
    let holdout = val_split
        .as_deref()
        .and_then(rtf_data::described::parse_holdout);
    if let Some(every) = holdout {
        eprintln!(
            "data: validating on 1 in {every} frames of `{train_split}`, held out of training"
        );
    }
    let named = val_split.iter().filter(|_| holdout.is_none());
    let read: Vec<&String> = std::iter::once(&train_split).chain(named).collect();
    for name in &read {
        ensure(description.split(name).is_some(), || {
            format!(
                "{}: no split `{name}` (available: {})",
                root.display(),
                description.split_names().join(", ")
            )
        })?;
    }
    // Every frame the run reads decoded now: bad data stops it before a run folder exists.
    let dataset = rtf_data::DescribedDataset::new(description.clone());
    for name in read {
        let frames = rtf_data::described::check_frames(&dataset.split(name)?)?;
        eprintln!("data: `{name}`: {frames} frames decoded, no problem");
    }
    let classes = description.class_set.clone();
    let dataset = DatasetConfig::Described {
        root,
        train_split,
        val_split,
        trained_on: Some(rtf_data::trained_on::of(description)),
    };
    Ok((dataset, classes))
}

/// A teacher given on the command line: a run folder (its network, channels and selected
/// weights), or a weights file with its network named.
fn teacher_ref(
    path: &Path,
    teacher: &TeacherArg,
    num_classes: i64,
    flag: &str,
) -> Result<TeacherRef, SetupError> {
    if path.is_dir() {
        return run_teacher(path, teacher.inputs, flag);
    }
    ensure(path.is_file(), || {
        format!(
            "{}: {flag} is neither a run folder nor a weights file",
            path.display()
        )
    })?;
    let name = teacher.model.as_ref().ok_or_else(|| {
        Refusal::Refused(format!(
            "{flag} {} is a weights file: name its network with {flag}-model",
            path.display()
        ))
    })?;
    Ok(TeacherRef::Weights {
        path: std::fs::canonicalize(path)?,
        model: ModelConfig::from_name(name, num_classes)?,
        inputs: teacher.inputs.unwrap_or_default(),
    })
}

/// A teacher that is a run folder: its network, channels and selected weights.
fn run_teacher(
    path: &Path,
    inputs: Option<Modality>,
    flag: &str,
) -> Result<TeacherRef, SetupError> {
    let run = crate::TrainedRun::open(path)
        .map_err(|e| Refusal::because(format!("{flag} {}: not a run folder", path.display()), e))?;
    let last = run.last_training();
    let weights = run.folder().weights();
    let weights = weights.selected().ok_or_else(|| {
        Refusal::Refused(format!(
            "{}: the run has no best.safetensors or final.safetensors yet ({flag})",
            path.display()
        ))
    })?;
    Ok(TeacherRef::Weights {
        path: std::fs::canonicalize(weights)?,
        model: last.network.model.clone(),
        inputs: inputs.unwrap_or(last.network.inputs),
    })
}

/// A `--config` file (YAML or JSON, the schema of config.json).
fn config_file_run(path: &Path) -> Result<RunConfig, SetupError> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| Refusal::because(format!("{}: cannot read", path.display()), e))?;
    let yaml = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("yaml") || e.eq_ignore_ascii_case("yml"));
    RunConfig::parse(&text, yaml).map_err(|e| refused(format!("{}: {e}", path.display())))
}

/// The `--teacher` or `--night-teacher` given, resolved.
fn given_teacher(
    teacher: &TeacherArg,
    num_classes: i64,
    flag: &str,
) -> Result<Option<TeacherRef>, SetupError> {
    teacher
        .path
        .as_ref()
        .map(|p| teacher_ref(p, teacher, num_classes, flag))
        .transpose()
}

/// A recipe's stages on the `--data` root, with the teachers given on the command line, and
/// the root opened.
fn recipe_run(name: &str, asked: &NewRun) -> Result<(RunConfig, rtf_data::Dataset), SetupError> {
    let recipe = recipe::recipe(name)?;
    let (dataset, classes, opened) = dataset_of(required_data(asked)?, asked)?;
    let n = classes.len() as i64;
    let cfg = recipe::instantiate(
        recipe,
        &RecipeInputs {
            dataset,
            num_classes: n,
            model: asked.overrides.model.clone(),
            teacher: given_teacher(&asked.teacher, n, "--teacher")?,
            night_teacher: given_teacher(&asked.night_teacher, n, "--night-teacher")?,
        },
    )?;
    Ok((cfg, opened))
}

fn required_data(asked: &NewRun) -> Result<&Path, SetupError> {
    asked
        .data
        .as_deref()
        .ok_or_else(|| refused("--data is required"))
}

/// One supervised (or, with `--teacher`, teacher-student) training on the `--data` root, and
/// the root opened.
fn plain_run(asked: &NewRun) -> Result<(RunConfig, rtf_data::Dataset), SetupError> {
    let (dataset, classes, opened) = dataset_of(required_data(asked)?, asked)?;
    let mut single = TrainConfig::mfnet_paper(PathBuf::new());
    let model = asked.overrides.model.as_deref().unwrap_or("mfnet");
    single.network.model = ModelConfig::from_name(model, classes.len() as i64)?;
    // The reference preprocessing leaves 700×320; HeatNet trains on a 640×320 window.
    if matches!(dataset, DatasetConfig::Freiburg { .. }) && asked.overrides.resize.is_none() {
        single.data.augment.window = Some((640, 320));
    }
    single.data.dataset = dataset;
    if let Some(teacher) = &asked.teacher.path {
        let n = single.network.model.num_classes();
        single.learning.procedure = Procedure::TeacherStudent {
            day_teacher: teacher_ref(teacher, &asked.teacher, n, "--teacher")?,
            night_teacher: given_teacher(&asked.night_teacher, n, "--night-teacher")?,
            targets: Default::default(),
        };
    }
    Ok((RunConfig::Single(Box::new(single)), opened))
}

/// `--no-augment` and `--no-shuffle` (issue 27's controls for parity runs).
fn apply_parity_controls(cfg: &mut TrainConfig, flags: &Overrides) {
    if flags.no_augment {
        cfg.data.augment = Default::default();
    }
    if flags.no_shuffle {
        cfg.data.shuffle = false;
    }
}

/// `--init WEIGHTS`: the single stage starts from this file, checked now so that weights that
/// do not fit leave no run folder behind.
fn apply_init(cfg: &mut RunConfig, path: &Path, reset_head: bool) -> Result<(), SetupError> {
    // A single run, or a recipe left with one stage (its teachers given as weights).
    let mut stages = cfg.stages_mut();
    let [single] = stages.as_mut_slice() else {
        return Err(refused(
            "--init goes with a single-stage run (a pipeline's stages start from their own weights)",
        ));
    };
    let single = &mut **single;
    let path = std::fs::canonicalize(path).map_err(|e| {
        Refusal::because(
            format!("{}: cannot open the --init weights", path.display()),
            e,
        )
    })?;
    single.network.init_from = Some(WeightsRef::File(path));
    single.network.init_reset_head = reset_head;
    crate::init::check_init_weights(single).map_err(|e| match e {
        TrainError::Model(m @ rtf_models::ModelError::Mismatch { .. }) if !reset_head => {
            SetupError::from(Refusal::because(
                "--init: these weights do not fit the network (--reset-head starts the \
                 classifier head fresh when only the class count differs)",
                m,
            ))
        }
        other => other.into(),
    })?;
    Ok(())
}

/// `--optimizer` (the paper's optimiser of that kind), then the single values over it.
fn apply_optimizer_flags(o: &mut OptimizerConfig, flags: &Overrides) -> Result<(), SetupError> {
    if let Some(kind) = flags.optimizer {
        *o = OptimizerConfig::paper_default(kind);
    }
    o.lr = flags.lr.unwrap_or(o.lr);
    o.lr_decay = flags.lr_decay.unwrap_or(o.lr_decay);
    o.decay_every = flags.decay_every.unwrap_or(o.decay_every);
    o.momentum = flags.momentum.unwrap_or(o.momentum);
    o.weight_decay = flags.weight_decay.unwrap_or(o.weight_decay);
    if let Some(epochs) = flags.warmup_epochs {
        let LrSchedule::WarmupPoly { warmup_epochs, .. } = &mut o.schedule else {
            return Err(refused("--warmup-epochs goes with a warm-up-then-poly schedule (--optimizer adamw, --recipe cmx-mf)"));
        };
        *warmup_epochs = epochs;
    }
    Ok(())
}

/// Flags the user gave override the recipe's or config's values, in every stage.
fn apply_flags(
    cfg: &mut TrainConfig,
    flags: &Overrides,
    recipe_networks: bool,
) -> Result<(), SetupError> {
    if let (Some(model), false) = (&flags.model, recipe_networks) {
        cfg.network.model = ModelConfig::from_name(model, cfg.network.model.num_classes())?;
    }
    apply_optimizer_flags(&mut cfg.learning.optimizer, flags)?;
    apply_schedule_flags(cfg, flags);
    apply_data_flags(cfg, flags);
    if let Some(v) = &flags.device {
        cfg.compute.device = v.clone();
    }
    if let Some(v) = flags.precision {
        cfg.learning.precision = v;
    }
    if flags.sync_bn {
        cfg.network.sync_batch_norm = true;
    }
    if flags.backbone_weights.is_some() {
        cfg.network.backbone_weights = flags.backbone_weights.clone();
    }
    if let (Some(v), false) = (flags.inputs, recipe_networks) {
        cfg.network.inputs = v;
    }
    apply_procedure_flags(&mut cfg.learning.procedure, flags);
    Ok(())
}

/// `--epochs`, `--batch-size`, `--seed`, `--max-steps`, `--checkpoint-every`, `--select-by`
/// and `--tb-images-every`.
fn apply_schedule_flags(cfg: &mut TrainConfig, flags: &Overrides) {
    let schedule = &mut cfg.schedule;
    if let Some(v) = flags.epochs {
        schedule.epochs = v;
    }
    if let Some(v) = flags.batch_size {
        schedule.batch_size = v;
    }
    if let Some(v) = flags.seed {
        schedule.seed = v;
    }
    if flags.max_steps.is_some() {
        schedule.max_steps_per_epoch = flags.max_steps;
    }
    if flags.checkpoint_every.is_some() {
        schedule.checkpoint_every = flags.checkpoint_every;
    }
    if flags.select_by.is_some() {
        schedule.select_by = flags.select_by;
    }
    schedule.tb_images_every = Some(flags.tb_images_every);
}

/// `--no-flip`, `--resize` (no crop window then) and `--workers`.
fn apply_data_flags(cfg: &mut TrainConfig, flags: &Overrides) {
    if flags.no_flip {
        cfg.data.augment.hflip = false;
    }
    if flags.resize.is_some() {
        cfg.data.resize = flags.resize;
        cfg.data.augment.window = None;
    }
    if let Some(v) = flags.workers {
        cfg.data.workers = v;
    }
}

/// The pseudo-label flags (`--threshold`, `--soft`) and the critic's.
fn apply_procedure_flags(procedure: &mut Procedure, flags: &Overrides) {
    match procedure {
        Procedure::Supervised => {}
        Procedure::TeacherStudent { targets, .. } => {
            targets.threshold = flags.threshold.or(targets.threshold);
            targets.soft |= flags.soft;
        }
        Procedure::Adversarial {
            targets, critic, ..
        } => {
            targets.threshold = flags.threshold.or(targets.threshold);
            targets.soft |= flags.soft;
            apply_critic_flags(critic, flags);
        }
    }
}

/// The critic's flags (--lambda, --critic-*, --multidir) over a recipe's or config's values.
fn apply_critic_flags(critic: &mut CriticOptions, flags: &Overrides) {
    critic.lambda = flags.lambda.unwrap_or(critic.lambda);
    critic.input = flags.critic_input.unwrap_or(critic.input);
    critic.multidir |= flags.multidir;
    critic.steps = flags.critic_steps.unwrap_or(critic.steps);
    critic.init = flags.critic_init.clone().or(critic.init.take());
    if flags.critic_code {
        critic.input = CriticInput::Logits;
        critic.flip_targets = true;
        critic.day_term = true;
        critic.alternate = true;
    }
}
