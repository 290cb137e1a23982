//! `rtf models [--json]`: every constructible network with its parameter count and size.

use anyhow::Result;

#[derive(clap::Args)]
pub struct Args {
    /// Print a JSON array of {name, params, megabytes} instead of a table.
    #[arg(long)]
    pub json: bool,
}

/// `1234567` -> `1,234,567`.
fn thousands(n: i64) -> String {
    let reversed: Vec<char> = n.unsigned_abs().to_string().chars().rev().collect();
    let groups: Vec<String> = reversed
        .chunks(3)
        .map(|g| g.iter().rev().collect())
        .collect();
    let digits = groups.into_iter().rev().collect::<Vec<_>>().join(",");
    if n < 0 {
        format!("-{digits}")
    } else {
        digits
    }
}

pub fn run(args: Args) -> Result<()> {
    let infos = rtf_models::model_infos()?;
    if args.json {
        println!("{}", serde_json::to_string_pretty(&infos)?);
        return Ok(());
    }
    println!(
        "{:<18} {:>13} {:>10}  classes",
        "model", "parameters", "MiB (f32)"
    );
    for info in &infos {
        println!(
            "{:<18} {:>13} {:>10.2}  {}",
            info.name,
            thousands(info.params),
            info.megabytes,
            rtf_models::default_num_classes(&info.name)
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn thousands_separators() {
        assert_eq!(thousands(736_275), "736,275");
        assert_eq!(thousands(254_510_053), "254,510,053");
        assert_eq!(thousands(12), "12");
        assert_eq!(thousands(-1000), "-1,000");
    }
}
