//! Data-parallel training on PyTorch's own distributed runtime, c10d: a TCPStore rendezvous
//! and a gloo (CPU) or NCCL (CUDA) process group, reached through a small C++ shim compiled
//! against the libtorch headers tch builds with (tch itself does not expose c10d).
//!
//! Semantics follow `torch.nn.parallel.DistributedDataParallel` (Li et al., "PyTorch
//! Distributed: Experiences on Accelerating Data Parallel Training", VLDB 2020): rank 0's
//! parameters are broadcast once, every rank computes gradients on its own shard of the batch,
//! gradients are averaged by bucketed all-reduce (flat buckets of about 25 MiB, DDP's default)
//! and every rank then takes the same optimiser step. Processes are launched as PyTorch users
//! launch them (`torchrun`, Slurm, a Kubernetes PyTorchJob): [`DistEnv::from_vars`] reads
//! `RANK`, `LOCAL_RANK`, `WORLD_SIZE`, `MASTER_ADDR` and `MASTER_PORT`.
//!
//! Every collective runs under a timeout: a dead peer gives an error, never a hang.

use std::ffi::{c_char, c_int, c_void, CStr, CString};
use std::ptr::NonNull;
use std::time::Duration;

use tch::{Device, Kind, Tensor};

mod ffi {
    use std::ffi::{c_char, c_int, c_void};
    extern "C" {
        #[allow(clippy::too_many_arguments)]
        pub fn rtf_c10d_new(
            addr: *const c_char,
            port: u16,
            rank: c_int,
            world: c_int,
            store_is_server: c_int,
            prefix: *const c_char,
            timeout_ms: i64,
            nccl: c_int,
            device_index: c_int,
            out: *mut *mut c_void,
        ) -> *mut c_char;
        pub fn rtf_c10d_free(group: *mut c_void);
        pub fn rtf_c10d_free_error(error: *mut c_char);
        pub fn rtf_c10d_allreduce_sum(
            group: *mut c_void,
            t: *mut torch_sys::C_tensor,
        ) -> *mut c_char;
        pub fn rtf_c10d_broadcast(
            group: *mut c_void,
            t: *mut torch_sys::C_tensor,
            root: c_int,
        ) -> *mut c_char;
        pub fn rtf_c10d_barrier(group: *mut c_void) -> *mut c_char;
        pub fn rtf_c10d_allreduce_sum_autograd(
            group: *mut c_void,
            t: *mut torch_sys::C_tensor,
            out: *mut *mut torch_sys::C_tensor,
        ) -> *mut c_char;
        pub fn rtf_c10d_take_backward_error(group: *mut c_void) -> *mut c_char;
    }
}

#[derive(Debug, thiserror::Error)]
pub enum DistError {
    #[error("distributed environment: {0}")]
    Env(String),
    #[error("c10d {op} failed on rank {rank} of {world}: {message}")]
    Collective {
        op: &'static str,
        rank: usize,
        world: usize,
        message: String,
    },
}

/// DDP's default bucket size (`bucket_cap_mb=25`).
pub const BUCKET_BYTES: usize = 25 * 1024 * 1024;
/// The default timeout of every collective (torch.distributed's default is 30 minutes for
/// gloo; a training step here is far shorter, so a dead rank is noticed sooner).
pub const DEFAULT_TIMEOUT: Duration = Duration::from_secs(300);

/// Where this process stands in a job, as a launcher (torchrun, Slurm via torchrun or srun with
/// these variables, a PyTorchJob) describes it in the environment.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DistEnv {
    pub rank: usize,
    pub local_rank: usize,
    pub world_size: usize,
    pub master_addr: String,
    pub master_port: u16,
    /// torchrun (torch >= 2.4) hosts the TCPStore in its agent at MASTER_ADDR:MASTER_PORT
    /// (`TORCHELASTIC_USE_AGENT_STORE=True`): every rank is then a client of it.
    pub agent_store: bool,
    /// `TORCHELASTIC_RESTART_COUNT`: keys of a restarted attempt never meet the previous one's.
    pub attempt: u64,
}

impl DistEnv {
    /// The launcher's variables through `var` (a binary passes a lookup of its own
    /// environment; this crate reads none). `Ok(None)` when `WORLD_SIZE` is unset (a plain
    /// run); an error naming the variable when one is missing or malformed.
    pub fn from_vars(var: impl Fn(&str) -> Option<String>) -> Result<Option<Self>, DistError> {
        let Some(world) = var("WORLD_SIZE") else {
            return Ok(None);
        };
        fn parse<T: std::str::FromStr>(name: &str, value: &str) -> Result<T, DistError> {
            value
                .trim()
                .parse()
                .map_err(|_| DistError::Env(format!("{name}={value:?} is not a valid number")))
        }
        let required = |name: &str| {
            var(name).ok_or_else(|| {
                DistError::Env(format!(
                    "WORLD_SIZE is set but {name} is not; launch with torchrun (or set RANK, \
                     WORLD_SIZE, MASTER_ADDR and MASTER_PORT)"
                ))
            })
        };
        let world_size: usize = parse("WORLD_SIZE", &world)?;
        let rank: usize = parse("RANK", &required("RANK")?)?;
        let local_rank: usize = match var("LOCAL_RANK") {
            Some(v) => parse("LOCAL_RANK", &v)?,
            None => rank,
        };
        let master_addr = required("MASTER_ADDR")?;
        let master_port: u16 = parse("MASTER_PORT", &required("MASTER_PORT")?)?;
        if world_size == 0 || rank >= world_size {
            return Err(DistError::Env(format!(
                "RANK={rank} is not below WORLD_SIZE={world_size}"
            )));
        }
        let agent_store = var("TORCHELASTIC_USE_AGENT_STORE")
            .is_some_and(|v| v.eq_ignore_ascii_case("true") || v == "1");
        let attempt = match var("TORCHELASTIC_RESTART_COUNT") {
            Some(v) => parse("TORCHELASTIC_RESTART_COUNT", &v)?,
            None => 0,
        };
        Ok(Some(Self {
            rank,
            local_rank,
            world_size,
            master_addr,
            master_port,
            agent_store,
            attempt,
        }))
    }
}

/// The collective backend: gloo for CPU tensors, NCCL for CUDA ones (as torch.distributed
/// picks them).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Backend {
    Gloo,
    Nccl,
}

impl Backend {
    pub fn for_device(device: Device) -> Self {
        match device {
            Device::Cuda(_) => Backend::Nccl,
            _ => Backend::Gloo,
        }
    }
    pub fn name(self) -> &'static str {
        match self {
            Backend::Gloo => "gloo",
            Backend::Nccl => "nccl",
        }
    }
}

/// A c10d process group over every rank of the job.
pub struct ProcessGroup {
    raw: NonNull<c_void>,
    rank: usize,
    world: usize,
    backend: Backend,
    device: Device,
}

// SAFETY: the group is a heap object of the shim owned by this value alone; c10d process
// groups may be used from any thread (one at a time, which `&mut`/ownership ensures for
// collectives issued through this API in order).
unsafe impl Send for ProcessGroup {}

fn take_error(raw: *mut c_char) -> Option<String> {
    if raw.is_null() {
        return None;
    }
    // SAFETY: a non-null return of the shim is a NUL-terminated string it malloc'd (strdup);
    // it is read once here and freed by the shim's own `free`.
    unsafe {
        let message = CStr::from_ptr(raw).to_string_lossy().into_owned();
        ffi::rtf_c10d_free_error(raw);
        Some(message)
    }
}

impl ProcessGroup {
    /// Joins the job `env` describes: rendezvous on its TCPStore (rank 0 hosts it unless
    /// torchrun's agent does), then the `backend` process group. Blocks until every rank has
    /// joined or `timeout` passes.
    pub fn new(
        env: &DistEnv,
        backend: Backend,
        device: Device,
        timeout: Duration,
    ) -> Result<Self, DistError> {
        let addr = CString::new(env.master_addr.clone())
            .map_err(|_| DistError::Env("MASTER_ADDR holds a NUL byte".into()))?;
        let prefix = CString::new(format!("rtf/attempt_{}/", env.attempt)).expect("no NUL");
        let device_index = match device {
            Device::Cuda(i) => i as c_int,
            _ => -1,
        };
        let mut raw: *mut c_void = std::ptr::null_mut();
        // SAFETY: the strings outlive the call; `raw` is a valid out-pointer; the shim catches
        // every C++ exception and reports it as the returned string.
        let error = unsafe {
            ffi::rtf_c10d_new(
                addr.as_ptr(),
                env.master_port,
                env.rank as c_int,
                env.world_size as c_int,
                (!env.agent_store && env.rank == 0) as c_int,
                prefix.as_ptr(),
                timeout.as_millis().min(i64::MAX as u128) as i64,
                (backend == Backend::Nccl) as c_int,
                device_index,
                &mut raw,
            )
        };
        if let Some(message) = take_error(error) {
            return Err(DistError::Collective {
                op: "rendezvous",
                rank: env.rank,
                world: env.world_size,
                message: format!(
                    "{message} (store {}:{}, backend {})",
                    env.master_addr,
                    env.master_port,
                    backend.name()
                ),
            });
        }
        let raw = NonNull::new(raw).ok_or_else(|| DistError::Collective {
            op: "rendezvous",
            rank: env.rank,
            world: env.world_size,
            message: "the shim returned no group".into(),
        })?;
        Ok(Self {
            raw,
            rank: env.rank,
            world: env.world_size,
            backend,
            device: match backend {
                Backend::Gloo => Device::Cpu,
                Backend::Nccl => device,
            },
        })
    }

    pub fn rank(&self) -> usize {
        self.rank
    }
    pub fn world_size(&self) -> usize {
        self.world
    }
    pub fn backend(&self) -> Backend {
        self.backend
    }

    fn check(&self, op: &'static str, error: *mut c_char) -> Result<(), DistError> {
        match take_error(error) {
            None => Ok(()),
            Some(message) => Err(DistError::Collective {
                op,
                rank: self.rank,
                world: self.world,
                message,
            }),
        }
    }

    /// In-place sum of `tensor` over every rank (it must be contiguous, of the same shape and
    /// kind on every rank).
    pub fn all_reduce_sum(&self, tensor: &mut Tensor) -> Result<(), DistError> {
        // SAFETY: `as_mut_ptr` is tch's `*mut C_tensor`, a live `torch::Tensor*` for the
        // duration of the call (the `&mut` borrow); the shim copies the handle, never frees it.
        let error = unsafe { ffi::rtf_c10d_allreduce_sum(self.raw.as_ptr(), tensor.as_mut_ptr()) };
        self.check("all_reduce", error)
    }

    /// In-place broadcast of rank `root`'s `tensor` (contiguous) to every rank.
    pub fn broadcast(&self, tensor: &mut Tensor, root: usize) -> Result<(), DistError> {
        // SAFETY: as in `all_reduce_sum`.
        let error = unsafe {
            ffi::rtf_c10d_broadcast(self.raw.as_ptr(), tensor.as_mut_ptr(), root as c_int)
        };
        self.check("broadcast", error)
    }

    /// Σ over every rank of `tensor`, as a new tensor in the autograd graph: its backward sums
    /// the gradient over the ranks too (every rank must then run the same backward). For
    /// statistics of a data-parallel batch, as synchronised BatchNorm needs. A failure of the
    /// backward's all-reduce is kept for [`Self::take_backward_error`] (the local gradient is
    /// used meanwhile, and every later differentiable all-reduce fails at once).
    pub fn all_reduce_sum_differentiable(&self, tensor: &Tensor) -> Result<Tensor, DistError> {
        let mut out: *mut torch_sys::C_tensor = std::ptr::null_mut();
        // SAFETY: `as_ptr` is a live `torch::Tensor*` for the call (the borrow); the shim copies
        // the handle and, on success, stores a new heap `torch::Tensor*` in `out`, which
        // `Tensor::from_ptr` then owns (tch frees it with `delete`, as it was made by `new`).
        // The autograd node keeps the group's address for the backward: the group must outlive
        // the graph, which it does as the trainer holds it for the whole run.
        let error = unsafe {
            ffi::rtf_c10d_allreduce_sum_autograd(
                self.raw.as_ptr(),
                tensor.as_ptr() as *mut torch_sys::C_tensor,
                &mut out,
            )
        };
        self.check("all_reduce (differentiable)", error)?;
        // SAFETY: success means `out` is the shim's new tensor (see above).
        Ok(unsafe { Tensor::from_ptr(out) })
    }

    /// The first failure of a collective inside a backward pass since the last call.
    pub fn take_backward_error(&self) -> Option<DistError> {
        // SAFETY: the group pointer is live while `self` is.
        let error = unsafe { ffi::rtf_c10d_take_backward_error(self.raw.as_ptr()) };
        self.check("all_reduce (in the backward)", error).err()
    }

    pub fn barrier(&self) -> Result<(), DistError> {
        // SAFETY: the group pointer is live while `self` is.
        let error = unsafe { ffi::rtf_c10d_barrier(self.raw.as_ptr()) };
        self.check("barrier", error)
    }

    /// Whether any rank raised `flag` (an all-reduced stop flag: Ctrl-C on one rank stops
    /// every rank at the same step).
    pub fn any(&self, flag: bool) -> Result<bool, DistError> {
        let mut t = Tensor::from_slice(&[flag as i64]).to_device(self.device);
        self.all_reduce_sum(&mut t)?;
        Ok(t.int64_value(&[0]) > 0)
    }

    /// Where tensors of collectives live: CPU for gloo, this rank's GPU for NCCL.
    pub fn device(&self) -> Device {
        self.device
    }

    /// DDP's gradient averaging: the defined gradients of `vars`, in order, packed into flat
    /// buckets of at most `bucket_bytes` (a bucket holds one kind on one device), each bucket
    /// summed over the ranks, divided by the world size and copied back. Every rank must pass
    /// the same variables with the same gradients defined.
    pub fn average_gradients(&self, vars: &[Tensor], bucket_bytes: usize) -> Result<(), DistError> {
        if self.world == 1 {
            return Ok(());
        }
        let grads: Vec<Tensor> = vars
            .iter()
            .map(Tensor::grad)
            .filter(Tensor::defined)
            .collect();
        tch::no_grad(|| {
            for bucket in buckets(&grads, bucket_bytes) {
                let flat: Vec<Tensor> = bucket.iter().map(|g| g.reshape([-1])).collect();
                let mut flat = Tensor::cat(&flat, 0);
                self.all_reduce_sum(&mut flat)?;
                let _ = flat.divide_scalar_(self.world as f64);
                let mut offset = 0;
                for g in bucket {
                    let n = g.numel() as i64;
                    let mut g = g.shallow_clone();
                    g.copy_(&flat.narrow(0, offset, n).view_as(&g));
                    offset += n;
                }
            }
            Ok(())
        })
    }

    /// Rank 0's values of `vars` on every rank (DDP's initial parameter and buffer broadcast).
    pub fn broadcast_from_rank0(&self, vars: &[Tensor]) -> Result<(), DistError> {
        if self.world == 1 {
            return Ok(());
        }
        tch::no_grad(|| {
            for v in vars {
                let mut flat = v.contiguous();
                self.broadcast(&mut flat, 0)?;
                let mut v = v.shallow_clone();
                if flat.data_ptr() != v.data_ptr() {
                    v.copy_(&flat);
                }
            }
            Ok(())
        })
    }
}

/// Consecutive runs of `grads` with one kind and device, each at most `max_bytes` (a single
/// larger gradient gets a bucket of its own).
fn buckets(grads: &[Tensor], max_bytes: usize) -> Vec<&[Tensor]> {
    let mut out = Vec::new();
    let mut start = 0;
    let mut bytes = 0usize;
    let key = |t: &Tensor| (t.kind(), t.device());
    for (i, g) in grads.iter().enumerate() {
        let size = g.numel() * elem_size(g.kind());
        let fits = i > start && key(g) == key(&grads[start]) && bytes + size <= max_bytes;
        if i > start && !fits {
            out.push(&grads[start..i]);
            start = i;
            bytes = 0;
        }
        bytes += size;
    }
    if start < grads.len() {
        out.push(&grads[start..]);
    }
    out
}

fn elem_size(kind: Kind) -> usize {
    kind.elt_size_in_bytes()
}

impl Drop for ProcessGroup {
    fn drop(&mut self) {
        // SAFETY: `raw` came from `rtf_c10d_new` and is freed once, here.
        unsafe { ffi::rtf_c10d_free(self.raw.as_ptr()) }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn env_absent_is_a_plain_run() {
        assert_eq!(DistEnv::from_vars(|_| None).unwrap(), None);
    }

    #[test]
    fn env_reads_torchrun_variables() {
        let vars = |n: &str| {
            Some(
                match n {
                    "WORLD_SIZE" => "4",
                    "RANK" => "3",
                    "LOCAL_RANK" => "1",
                    "MASTER_ADDR" => "node0",
                    "MASTER_PORT" => "29500",
                    "TORCHELASTIC_USE_AGENT_STORE" => "True",
                    "TORCHELASTIC_RESTART_COUNT" => "2",
                    _ => return None,
                }
                .to_string(),
            )
        };
        let env = DistEnv::from_vars(vars).unwrap().unwrap();
        assert_eq!(
            env,
            DistEnv {
                rank: 3,
                local_rank: 1,
                world_size: 4,
                master_addr: "node0".into(),
                master_port: 29500,
                agent_store: true,
                attempt: 2,
            }
        );
    }

    #[test]
    fn env_errors_name_the_variable() {
        let missing = DistEnv::from_vars(|n| (n == "WORLD_SIZE").then(|| "2".to_string()));
        assert!(missing.unwrap_err().to_string().contains("RANK"));
        let bad = DistEnv::from_vars(|n| match n {
            "WORLD_SIZE" => Some("2".into()),
            "RANK" => Some("2".into()),
            "MASTER_ADDR" => Some("x".into()),
            "MASTER_PORT" => Some("70000".into()),
            _ => None,
        });
        assert!(bad.unwrap_err().to_string().contains("MASTER_PORT"));
    }

    #[test]
    fn buckets_split_by_size_and_kind() {
        let g = |n: i64, k: Kind| Tensor::zeros([n], (k, Device::Cpu));
        let grads = vec![
            g(10, Kind::Float),
            g(10, Kind::Float),
            g(30, Kind::Float),
            g(5, Kind::Double),
        ];
        let sizes: Vec<usize> = buckets(&grads, 80).iter().map(|b| b.len()).collect();
        assert_eq!(sizes, vec![2, 1, 1]);
    }

    /// A one-rank group over loopback: collectives are identities, and the group tears down.
    #[test]
    fn single_rank_group_on_loopback() {
        let port = free_port();
        let env = DistEnv {
            rank: 0,
            local_rank: 0,
            world_size: 1,
            master_addr: "127.0.0.1".into(),
            master_port: port,
            agent_store: false,
            attempt: 0,
        };
        let pg =
            ProcessGroup::new(&env, Backend::Gloo, Device::Cpu, Duration::from_secs(30)).unwrap();
        let mut t = Tensor::from_slice(&[1.0f32, 2.0, 3.0]);
        pg.all_reduce_sum(&mut t).unwrap();
        assert_eq!(Vec::<f32>::try_from(&t).unwrap(), vec![1.0, 2.0, 3.0]);
        pg.barrier().unwrap();
        assert!(pg.any(true).unwrap());
        assert!(!pg.any(false).unwrap());
    }

    #[test]
    fn nccl_without_the_feature_is_a_clear_error() {
        if cfg!(feature = "nccl") {
            return;
        }
        let env = DistEnv {
            rank: 0,
            local_rank: 0,
            world_size: 1,
            master_addr: "127.0.0.1".into(),
            master_port: free_port(),
            agent_store: false,
            attempt: 0,
        };
        let err = ProcessGroup::new(
            &env,
            Backend::Nccl,
            Device::Cuda(0),
            Duration::from_secs(10),
        )
        .err()
        .expect("no NCCL in this build");
        assert!(err.to_string().contains("NCCL"), "{err}");
    }

    fn free_port() -> u16 {
        std::net::TcpListener::bind("127.0.0.1:0")
            .unwrap()
            .local_addr()
            .unwrap()
            .port()
    }
}
