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
        // Each recipe as data, plus the network its run ends with and the channels it sees
        // (what `rtf eval --model … --inputs …` needs for its final weights).
        let listed = RECIPES
            .iter()
            .map(|r| {
                let mut value = serde_json::to_value(r)?;
                let (model, inputs) = r.final_network();
                value["model"] = serde_json::json!(model);
                value["inputs"] = serde_json::json!(inputs.name());
                Ok(value)
            })
            .collect::<Result<Vec<_>, serde_json::Error>>()?;
        println!("{}", serde_json::to_string_pretty(&listed)?);
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
