//! What `rtf data check` says of a tree that is no layout rtf knows: each layout tried and why
//! it does not match, and a dataset.yaml skeleton filled with what the tree holds — the
//! folders and extensions per role, a guessed pattern per role (folders whose names vary
//! become fields), the label values seen and the list files at the root — for the user to
//! finish (docs/src/bring-your-data.md).

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// Files looked at, at most (a skeleton needs a sample, not the whole tree).
const MAX_FILES: usize = 200_000;
/// Label files decoded for their values, at most.
const LABELS_READ: usize = 16;

/// Each layout rtf recognises and why `root` is not it.
pub fn layouts_tried(root: &Path) -> Vec<(&'static str, String)> {
    let has = |p: &str| root.join(p).is_dir();
    let mf = match (has("images"), has("labels")) {
        (false, _) => "no images/ folder".to_string(),
        (true, false) => "images/ without labels/".to_string(),
        (true, true) => {
            "images/ holds folders, not MF's RGBA PNGs (and no train.txt names them)".to_string()
        }
    };
    let described = ["train", "test"].iter().any(|s| has(s));
    let split_folders = match described {
        true => "{train,test}/ without vi+ir, rgb+thermal or Visible+Infrared folders",
        false => "no train/ or test/ folder",
    };
    vec![
        (
            "plain",
            format!("no {}", crate::description::DESCRIPTION_FILE),
        ),
        ("MF", mf),
        (
            "BDD100K night",
            "no images/<split>/ folder with a labels/<split>/ beside it".into(),
        ),
        ("Freiburg Thermal", "no fl_rgb/ or ImagesRGB/ folder".into()),
        ("MSRS, PST900, FMB", split_folders.into()),
    ]
}

/// The one-line verdict: no known layout, each tried with its reason.
pub fn verdict(root: &Path) -> String {
    let tried: Vec<String> = layouts_tried(root)
        .into_iter()
        .map(|(name, why)| format!("{name}: {why}"))
        .collect();
    format!("no layout rtf knows (tried {})", tried.join("; "))
}

/// One kind of file: its path with the components that vary across files generalised.
#[derive(Default)]
struct Group {
    files: Vec<Vec<String>>,
}

/// A dataset.yaml skeleton for `root` (module docs).
pub fn skeleton(root: &Path) -> String {
    let mut files = Vec::new();
    walk(root, &mut Vec::new(), &mut files);
    let mut groups: BTreeMap<String, Group> = BTreeMap::new();
    for parts in files {
        let shape: Vec<String> = parts.iter().map(|c| digits_as_hash(c)).collect();
        groups.entry(shape.join("/")).or_default().files.push(parts);
    }
    let mut roles: BTreeMap<&str, (String, &Group)> = BTreeMap::new();
    for (shape, group) in &groups {
        if let Some(role) = role_of(shape) {
            roles.entry(role).or_insert((shape.clone(), group));
        }
    }
    let rgb = roles.get("rgb").map(|(_, g)| pattern(g, None));
    let fields = rgb.as_ref().map(|(_, values)| values.clone());
    let line = |role: &str| match roles.get(role) {
        Some((_, g)) => format!("\"{}\"", pattern(g, fields.as_ref()).0),
        None => format!("\"?\"   # no {role} files recognised"),
    };
    let values = roles.get("labels").map(|(_, g)| label_values(root, g));
    let mut out = classes_part(values.as_ref());
    let lists = root_lists(root);
    out += &splits_part(&lists, &[line("rgb"), line("thermal"), line("labels")]);
    out
}

fn walk(dir: &Path, prefix: &mut Vec<String>, out: &mut Vec<Vec<String>>) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    let mut entries: Vec<_> = entries.flatten().collect();
    entries.sort_by_key(|e| e.file_name());
    for entry in entries {
        let Some(name) = entry.file_name().to_str().map(String::from) else {
            continue;
        };
        if out.len() >= MAX_FILES || name.starts_with('.') {
            continue;
        }
        let path = entry.path();
        prefix.push(name.clone());
        if path.is_dir() {
            walk(&path, prefix, out);
        } else if crate::images::Format::of_extension(&path).is_some() {
            out.push(prefix.clone());
        }
        prefix.pop();
    }
}

fn digits_as_hash(component: &str) -> String {
    component
        .chars()
        .map(|c| if c.is_ascii_digit() { '#' } else { c })
        .collect()
}

/// The role a group's path names by its folders and extension, if any.
fn role_of(shape: &str) -> Option<&'static str> {
    let lower = shape.to_ascii_lowercase();
    let words: BTreeSet<&str> = lower.split(['/', '_', '-', '.']).collect();
    let any = |names: &[&str]| names.iter().any(|n| words.contains(n));
    if any(&[
        "label",
        "labels",
        "annotations",
        "annotation",
        "mask",
        "masks",
        "gt",
        "segmentation",
    ]) {
        return lower.ends_with(".png").then_some("labels");
    }
    if any(&["lwir", "thermal", "ir", "infrared", "thermal16", "t"]) {
        return Some("thermal");
    }
    any(&[
        "visible", "rgb", "color", "colour", "vi", "eo", "images", "image",
    ])
    .then_some("rgb")
}

/// A group's pattern: components that vary become fields, named by their letters (`set00` →
/// `{set}`); the file name `{frame}`. With `rgb` (the RGB pattern's fields and one frame's
/// values), a file name holding all those values joined by one separator becomes them.
fn pattern(group: &Group, rgb: Option<&Vec<(String, String)>>) -> (String, Vec<(String, String)>) {
    let first = &group.files[0];
    let mut parts = Vec::new();
    let mut fields: Vec<(String, String)> = Vec::new();
    for (k, component) in first.iter().enumerate() {
        let last = k + 1 == first.len();
        let varies = group.files.iter().any(|f| f.get(k) != Some(component));
        if !varies {
            parts.push(component.clone());
            continue;
        }
        let (stem, ext) = match last {
            true => component.rsplit_once('.').unwrap_or((component, "")),
            false => (component.as_str(), ""),
        };
        let joined = rgb.and_then(|values| joined_fields(group, k, values));
        let name = match (last, joined) {
            (true, Some(template)) => {
                parts.push(format!("{template}.{ext}"));
                continue;
            }
            (true, None) => "frame".to_string(),
            (false, _) => field_name(stem, &fields),
        };
        fields.push((name.clone(), stem.to_string()));
        parts.push(match ext {
            "" => format!("{{{name}}}"),
            ext => format!("{{{name}}}.{ext}"),
        });
    }
    (parts.join("/"), fields)
}

/// A field name from a component's letters, unique among `taken`.
fn field_name(value: &str, taken: &[(String, String)]) -> String {
    let letters: String = value
        .chars()
        .take_while(|c| c.is_ascii_alphabetic())
        .collect::<String>()
        .to_ascii_lowercase();
    let base = if letters.is_empty() {
        "f".to_string()
    } else {
        letters
    };
    let mut name = base.clone();
    let mut n = 2;
    while taken.iter().any(|(t, _)| *t == name) || name == "frame" {
        name = format!("{base}{n}");
        n += 1;
    }
    name
}

/// The file-name template of a group whose names join the RGB fields' values (`set00_V000_I1`
/// → `{set}_{video}_{frame}`), if one of its files does.
fn joined_fields(group: &Group, k: usize, values: &[(String, String)]) -> Option<String> {
    let all: Vec<&str> = values.iter().map(|(_, v)| v.as_str()).collect();
    let stems: BTreeSet<&str> = group
        .files
        .iter()
        .filter_map(|f| f.get(k)?.rsplit_once('.').map(|(s, _)| s))
        .collect();
    let names: Vec<String> = values.iter().map(|(n, _)| format!("{{{n}}}")).collect();
    ["_", "-", ""].iter().find_map(|sep| {
        stems
            .contains(all.join(sep).as_str())
            .then(|| names.join(sep))
    })
}

/// The distinct values of up to [`LABELS_READ`] label files.
fn label_values(root: &Path, group: &Group) -> BTreeSet<u8> {
    let mut seen = BTreeSet::new();
    for parts in group.files.iter().take(LABELS_READ) {
        let path: PathBuf = parts.iter().fold(root.to_path_buf(), |p, c| p.join(c));
        if let Ok(png) = crate::images::read_label(&path) {
            if let crate::pngio::Samples::U8(v) = &png.samples {
                seen.extend(v.iter().step_by(png.channels.max(1)).copied());
            }
        }
    }
    seen
}

fn classes_part(values: Option<&BTreeSet<u8>>) -> String {
    let mut out =
        String::from("classes:   # one entry per class: id = label value; name; colour\n");
    let ids: Vec<u8> = values
        .map(|v| v.iter().copied().filter(|&v| v != 255).collect())
        .unwrap_or_default();
    match (ids.first(), ids.last()) {
        (Some(lo), Some(hi)) => {
            out += &format!(
                "  # label values seen in {} label file(s): {lo}-{hi} ({} values): one may be void\n",
                LABELS_READ.min(values.map_or(0, |v| v.len().max(1))),
                ids.len()
            );
            for &id in &ids {
                out += &format!(
                    "  - {{id: {id}, name: class{id}, color: [{}, {}, {}]}}\n",
                    id.wrapping_mul(37),
                    id.wrapping_mul(91),
                    id.wrapping_mul(53)
                );
            }
        }
        _ => out += "  - {id: 0, name: background, color: [0, 0, 0]}\n",
    }
    if values.is_some_and(|v| v.contains(&255)) {
        out += "ignore_id: 255\n";
    } else {
        out += "# ignore_id: N   # the void value, if one of the values above is void\n";
    }
    out
}

/// The `.txt` files at the root, by stem.
fn root_lists(root: &Path) -> Vec<String> {
    let mut out: Vec<String> = std::fs::read_dir(root)
        .map(|rd| {
            rd.flatten()
                .filter_map(|e| e.file_name().to_str().map(String::from))
                .filter(|n| n.ends_with(".txt"))
                .collect()
        })
        .unwrap_or_default();
    out.sort();
    out
}

/// `splits:` (one per list prefix, `train_day.txt` → train, each the union of its lists) and
/// `day:`/`night:` from lists named so.
fn splits_part(lists: &[String], patterns: &[String; 3]) -> String {
    let mut splits: BTreeMap<String, Vec<&str>> = BTreeMap::new();
    for list in lists {
        let stem = list.trim_end_matches(".txt");
        let split = stem.split(['_', '-']).next().unwrap_or(stem);
        splits.entry(split.to_string()).or_default().push(list);
    }
    if splits.is_empty() {
        splits.insert("train".into(), Vec::new());
    }
    let mut out = String::from("splits:\n");
    for (name, files) in &splits {
        out += &format!(
            "  {name}:\n    rgb: {}\n    thermal: {}\n    labels: {}\n",
            patterns[0], patterns[1], patterns[2]
        );
        if !files.is_empty() {
            out += &format!("    list: [{}]\n", files.join(", "));
        }
    }
    for condition in ["day", "night"] {
        let named: Vec<&str> = lists
            .iter()
            .filter(|l| {
                l.trim_end_matches(".txt")
                    .to_ascii_lowercase()
                    .split(['_', '-'])
                    .any(|w| w == condition)
            })
            .map(String::as_str)
            .collect();
        if !named.is_empty() {
            out += &format!("{condition}: {{list: [{}]}}\n", named.join(", "));
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sequence_tests::sequence_root;

    #[test]
    fn a_sequence_tree_gets_its_patterns_lists_and_label_values_guessed() {
        let dir = sequence_root("");
        std::fs::remove_file(dir.path().join(crate::description::DESCRIPTION_FILE)).unwrap();
        let text = skeleton(dir.path());
        for want in [
            "rgb: \"images/{set}/{v}/visible/{frame}.jpg\"",
            "thermal: \"images/{set}/{v}/lwir/{frame}.jpg\"",
            "labels: \"labels/{set}_{v}_{frame}.png\"",
            "list: [train_day.txt, train_night.txt]",
            "night: {list: [test_night.txt, train_night.txt]}",
            "0-19 (20 values)",
        ] {
            assert!(text.contains(want), "{want}:\n{text}");
        }
        let verdict = verdict(dir.path());
        assert!(
            verdict.contains("MF: images/ holds folders") && !verdict.contains('\n'),
            "{verdict}"
        );
    }
}
