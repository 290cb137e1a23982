//! Data-parallel training (PyTorch DDP semantics, Li et al., VLDB 2020) on c10d through
//! [`rtf_dist`]: rank 0's weights broadcast at the start, each rank a disjoint shard of every
//! epoch's deterministic order ([`EpochShard`], `DistributedSampler`'s scheme), gradients
//! averaged by bucketed all-reduce in [`crate::procedure::Trained::minimise`], BatchNorm
//! statistics per rank with rank 0's broadcast after every step (DDP's `broadcast_buffers`),
//! and one small all-reduce per step that agrees on stopping and averages the logged losses.
//! Only rank 0 writes the run folder. See `docs/src/distributed.md`.

use std::sync::{Arc, Mutex, RwLock};

use rtf_core::{ClassSet, Daytime};
use rtf_data::{DataError, Frame, FrameSource, Loader, LoaderConfig};
use rtf_dist::{DistError, ProcessGroup, BUCKET_BYTES};
use tch::nn::VarStore;
use tch::Tensor;

use crate::error::TrainError;

/// This process's place in a data-parallel job and its process group.
pub struct Ddp {
    group: Mutex<ProcessGroup>,
    rank: usize,
    world: usize,
    /// The first failure of a collective inside [`crate::procedure::Trained::minimise`] (which
    /// returns nothing); the trainer stops with it after the step.
    failed: Mutex<Option<DistError>>,
}

impl std::fmt::Debug for Ddp {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Ddp(rank {} of {})", self.rank, self.world)
    }
}

/// Joins a launcher's job (torchrun, Slurm, a PyTorchJob: `env`) for `cfg`: each rank on the
/// GPU of its `LOCAL_RANK`, every stage of a pipeline on the same kind of device (one process
/// group serves them all); gloo on CPU, NCCL on CUDA. Rank 0 says so on stderr.
pub fn join(
    env: &rtf_dist::DistEnv,
    cfg: &mut crate::config::RunConfig,
    timeout: std::time::Duration,
) -> Result<Arc<Ddp>, TrainError> {
    let mut devices = Vec::new();
    for stage in cfg.stages_mut() {
        if stage.compute.device.starts_with("cuda") {
            stage.compute.device = format!("cuda:{}", env.local_rank);
        }
        devices.push(
            crate::config::available_device(&stage.compute.device).map_err(TrainError::Config)?,
        );
    }
    let device = devices[0];
    if devices.iter().any(|d| d.is_cuda() != device.is_cuda()) {
        return Err(TrainError::Config(
            "a data-parallel multi-stage run needs every stage on the same kind of device".into(),
        ));
    }
    let backend = rtf_dist::Backend::for_device(device);
    let group = ProcessGroup::new(env, backend, device, timeout)?;
    if env.rank == 0 {
        eprintln!(
            "data-parallel: {} processes ({}, store {}:{})",
            env.world_size,
            backend.name(),
            env.master_addr,
            env.master_port
        );
    }
    Ok(Ddp::new(group))
}

impl Ddp {
    pub fn new(group: ProcessGroup) -> Arc<Self> {
        Arc::new(Self {
            rank: group.rank(),
            world: group.world_size(),
            group: Mutex::new(group),
            failed: Mutex::new(None),
        })
    }

    pub fn rank(&self) -> usize {
        self.rank
    }
    pub fn world_size(&self) -> usize {
        self.world
    }
    /// Rank 0 writes the run folder.
    pub fn is_root(&self) -> bool {
        self.rank == 0
    }

    fn group(&self) -> std::sync::MutexGuard<'_, ProcessGroup> {
        self.group.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Averages the gradients of `vs`'s trainable variables over the ranks (DDP's bucketed
    /// all-reduce); false when it failed (the error is kept for [`Self::check`]) or an earlier
    /// one of this step did: the caller must then not update its network.
    pub fn average_gradients(&self, vs: &VarStore) -> bool {
        let mut failed = self.failed.lock().unwrap_or_else(|e| e.into_inner());
        if failed.is_some() {
            return false;
        }
        let group = self.group();
        // A collective of synchronised BatchNorm's backward that failed (autograd could not
        // say so) fails the step here.
        if let Some(e) = group.take_backward_error() {
            *failed = Some(e);
            return false;
        }
        match group.average_gradients(&vs.trainable_variables(), BUCKET_BYTES) {
            Ok(()) => true,
            Err(e) => {
                *failed = Some(e);
                false
            }
        }
    }

    /// The error of a collective inside a step, if any (gradient averaging, or synchronised
    /// BatchNorm's statistics in the forward or backward).
    pub fn check(&self) -> Result<(), TrainError> {
        match self.failed.lock().unwrap_or_else(|e| e.into_inner()).take() {
            Some(e) => Err(e.into()),
            None => Ok(()),
        }
    }

    /// Rank 0's value of every variable of `vs` (trainable or not) on every rank.
    pub fn broadcast_all(&self, vs: &VarStore) -> Result<(), TrainError> {
        Ok(self.group().broadcast_from_rank0(&sorted(vs, |_| true))?)
    }

    /// Rank 0's non-trainable variables (BatchNorm running statistics) on every rank.
    pub fn broadcast_buffers(&self, vs: &VarStore) -> Result<(), TrainError> {
        let buffers = sorted(vs, |t| !t.requires_grad());
        if buffers.is_empty() {
            return Ok(());
        }
        Ok(self.group().broadcast_from_rank0(&buffers)?)
    }

    /// One all-reduce per step: whether any rank asked to stop, and the sum over the ranks of
    /// `values` (the step's losses, to log their mean over every rank's batch).
    pub fn agree(&self, stop: bool, values: &[f64]) -> Result<(bool, Vec<f64>), TrainError> {
        let mut all = vec![stop as u8 as f64];
        all.extend_from_slice(values);
        let group = self.group();
        let mut t = Tensor::from_slice(&all).to_device(group.device());
        group.all_reduce_sum(&mut t)?;
        drop(group);
        let summed = Vec::<f64>::try_from(&t.to_device(tch::Device::Cpu))
            .map_err(|e| TrainError::Config(format!("reading an all-reduced tensor: {e}")))?;
        Ok((summed[0] > 0.0, summed[1..].to_vec()))
    }

    /// Checks that every rank ends with the same weights (every variable of every trained
    /// network, bit for bit): rank 0's digest is broadcast and every rank compares its own.
    /// Returns the digest. `trained`: the VarStore of every trained network, in role order.
    pub fn check_identical<'a>(
        &self,
        trained: impl IntoIterator<Item = &'a VarStore>,
    ) -> Result<u64, TrainError> {
        let digest = weights_digest(trained);
        // Two exact halves: all-reduced values are i64 tensors.
        let group = self.group();
        let mut t = Tensor::from_slice(&[(digest >> 32) as i64, (digest & 0xffff_ffff) as i64])
            .to_device(group.device());
        group.broadcast(&mut t, 0)?;
        drop(group);
        let root = Vec::<i64>::try_from(&t.to_device(tch::Device::Cpu))
            .map_err(|e| TrainError::Config(format!("reading a broadcast tensor: {e}")))?;
        let root = ((root[0] as u64) << 32) | root[1] as u64;
        let (differs, _) = self.agree(root != digest, &[])?;
        if differs {
            return Err(TrainError::Config(format!(
                "the ranks of this data-parallel run ended with different weights (rank {} \
                 digest {digest:016x}, rank 0 {root:016x})",
                self.rank
            )));
        }
        Ok(digest)
    }

    pub fn barrier(&self) -> Result<(), TrainError> {
        Ok(self.group().barrier()?)
    }
}

/// Synchronised BatchNorm's sum over the ranks ([`rtf_models::SyncBatchNorm`]). A failed
/// collective is kept for [`Ddp::check`] (the step is then abandoned) and the local value used.
impl rtf_models::StatsAllReduce for Ddp {
    fn all_reduce_sum(&self, t: &Tensor) -> Tensor {
        let mut failed = self.failed.lock().unwrap_or_else(|e| e.into_inner());
        if failed.is_some() {
            return t.shallow_clone();
        }
        match self.group().all_reduce_sum_differentiable(t) {
            Ok(sum) => sum,
            Err(e) => {
                *failed = Some(e);
                t.shallow_clone()
            }
        }
    }
}

/// A digest of the variables of `stores` (names, shapes, kinds and bytes), the same in every
/// process of one build.
pub fn weights_digest<'a>(stores: impl IntoIterator<Item = &'a VarStore>) -> u64 {
    use std::hash::{Hash, Hasher};
    let mut h = std::collections::hash_map::DefaultHasher::new();
    for vs in stores {
        let mut vars: Vec<(String, Tensor)> = vs.variables().into_iter().collect();
        vars.sort_by(|a, b| a.0.cmp(&b.0));
        for (name, t) in vars {
            name.hash(&mut h);
            t.size().hash(&mut h);
            let t = t.to_device(tch::Device::Cpu).contiguous();
            let bytes = t.numel() * t.kind().elt_size_in_bytes();
            let mut buf = vec![0u8; bytes];
            t.copy_data_u8(&mut buf, t.numel());
            buf.hash(&mut h);
        }
    }
    h.finish()
}

/// Variables of `vs` that pass `keep`, in name order (the same on every rank).
fn sorted(vs: &VarStore, keep: impl Fn(&Tensor) -> bool) -> Vec<Tensor> {
    let mut vars: Vec<(String, Tensor)> = vs
        .variables()
        .into_iter()
        .filter(|(_, t)| keep(t))
        .collect();
    vars.sort_by(|a, b| a.0.cmp(&b.0));
    vars.into_iter().map(|(_, t)| t).collect()
}

/// This rank's share of a stream: epoch `e`'s frames are the ones at positions `rank`,
/// `rank + world`, ... of the whole stream's order for `e` (the order a single-process run
/// uses), the tail that does not divide evenly left out (so every rank takes the same number
/// of steps), as `torch.utils.data.DistributedSampler` shards. A loader over it must not
/// shuffle; [`EpochShard::set_epoch`] picks the epoch before that epoch's batches are drawn.
pub struct EpochShard {
    inner: Arc<dyn FrameSource>,
    order: Loader,
    rank: usize,
    world: usize,
    map: RwLock<Vec<usize>>,
}

impl EpochShard {
    /// `order` is the loader of the whole stream (its seed and shuffling give each epoch's
    /// order). Errors when the stream has fewer frames than ranks.
    pub fn new(order: Loader, rank: usize, world: usize) -> Result<Arc<Self>, TrainError> {
        let inner = order.source().clone();
        if inner.len() < world {
            return Err(TrainError::Config(format!(
                "{} training frames cannot be shared among {world} ranks",
                inner.len()
            )));
        }
        let shard = Arc::new(Self {
            inner,
            order,
            rank,
            world,
            map: RwLock::new(Vec::new()),
        });
        shard.set_epoch(0);
        Ok(shard)
    }

    /// Frames per rank and epoch.
    pub fn per_rank(&self) -> usize {
        self.inner.len() / self.world
    }

    pub fn set_epoch(&self, epoch: u64) {
        let order = self.order.epoch_order(epoch);
        let mine: Vec<usize> = order
            .into_iter()
            .skip(self.rank)
            .step_by(self.world)
            .take(self.per_rank())
            .collect();
        *self.map.write().unwrap_or_else(|e| e.into_inner()) = mine;
    }

    fn index(&self, i: usize) -> usize {
        self.map.read().unwrap_or_else(|e| e.into_inner())[i]
    }
}

impl FrameSource for EpochShard {
    fn len(&self) -> usize {
        self.per_rank()
    }
    fn frame_name(&self, index: usize) -> &str {
        self.inner.frame_name(self.index(index))
    }
    fn daytime(&self, index: usize) -> Option<Daytime> {
        self.inner.daytime(self.index(index))
    }
    fn class_set(&self) -> &ClassSet {
        self.inner.class_set()
    }
    fn load(&self, index: usize) -> Result<Frame, DataError> {
        self.inner.load(self.index(index))
    }
    fn load_unlabelled(&self, index: usize) -> Result<Frame, DataError> {
        self.inner.load_unlabelled(self.index(index))
    }
}

/// The loader of this rank's shard of `source`: the whole stream's order from `cfg` (its seed),
/// no shuffling of its own, and augmentation drawn from a seed of its own rank.
pub fn shard_loader(
    source: Arc<dyn FrameSource>,
    cfg: LoaderConfig,
    input: rtf_core::InputConvention,
    ddp: &Ddp,
) -> Result<(Loader, Arc<EpochShard>), TrainError> {
    let whole = Loader::new(
        source,
        LoaderConfig {
            workers: 0,
            ..cfg.clone()
        },
        input,
    );
    let shard = EpochShard::new(whole, ddp.rank, ddp.world)?;
    let loader = Loader::new(
        shard.clone(),
        LoaderConfig {
            shuffle: false,
            seed: rtf_data::loader::mix(cfg.seed, 0x7368617264, ddp.rank as u64),
            ..cfg
        },
        input,
    );
    Ok((loader, shard))
}

/// A folder of this process's own under the system's temporary folder, removed on drop (the
/// label caches of ranks other than 0, which never write the run folder).
pub struct ScratchDir(std::path::PathBuf);

impl ScratchDir {
    pub fn new() -> Self {
        Self(std::env::temp_dir().join(format!("rtf-rank-labels-{}", std::process::id())))
    }
    pub fn path(&self) -> &std::path::Path {
        &self.0
    }
}

impl Default for ScratchDir {
    fn default() -> Self {
        Self::new()
    }
}

impl Drop for ScratchDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}
