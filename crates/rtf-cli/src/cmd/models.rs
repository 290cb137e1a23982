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
    let digits = n.abs().to_string();
    let mut out = String::new();
    for (i, c) in digits.chars().enumerate() {
        if i > 0 && (digits.len() - i) % 3 == 0 {
            out.push(',');
        }
        out.push(c);
    }
    if n < 0 {
        format!("-{out}")
    } else {
        out
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
