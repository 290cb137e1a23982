//! One module per subcommand: a clap `Args` struct and `run(args) -> anyhow::Result<()>`.

pub mod bench_model;
pub mod calibrate;
pub mod models;
pub mod synth;
