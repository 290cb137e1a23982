//! `rtf recipes`: the papers' training recipes `rtf train --recipe` takes.

use anyhow::Result;
use rtf_train::recipe::RECIPES;

#[derive(clap::Args)]
pub struct Args {
    /// JSON: an array of {name, procedure, description, source, schedule, stages, …}.
    #[arg(long)]
    pub json: bool,
}

pub fn run(args: Args) -> Result<()> {
    if args.json {
        println!("{}", serde_json::to_string_pretty(RECIPES)?);
        return Ok(());
    }
    let width = RECIPES.iter().map(|r| r.name.len()).max().unwrap_or(0);
    for r in RECIPES {
        let stages: Vec<&str> = r.stages.iter().map(|s| s.name).collect();
        println!(
            "{:width$}  {:16} {} [{}; stages: {}]",
            r.name,
            r.procedure,
            r.description,
            r.source,
            stages.join(" → ")
        );
    }
    Ok(())
}
