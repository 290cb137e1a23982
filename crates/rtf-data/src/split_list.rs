//! Split and condition lists as datasets ship them: each line a frame name, or one to three
//! relative paths (the frame's RGB, thermal and label files, in any order) separated by
//! commas, tabs or spaces (`color/a_eo-1.jpg,annotations/a_mask-1.png`), or a bare file name
//! (`set00_V000_I00050.png`). A path is matched against the end of the split's patterns to
//! identify its frame; a path that stops short of a pattern's folder fields names only some
//! fields (the frames that agree are looked up by the caller). A path that matches none, paths
//! of one line naming different frames, or a line of more than three paths is an error naming
//! the list and line.

use std::path::{Component, Path};

use crate::description::SplitSpec;
use crate::pattern::{frame_name, value, Fields, FilePattern};
use crate::DataError;

/// A list file's lines that are not empty: (1-based line, its paths or name).
pub fn read_list_lines(list: &Path) -> Result<Vec<(usize, Vec<String>)>, DataError> {
    let bytes = std::fs::read(list).map_err(|e| DataError::io(list, e))?;
    let text = String::from_utf8(bytes).map_err(|_| DataError::Format {
        path: list.to_path_buf(),
        message: "list file is not UTF-8 text".into(),
    })?;
    let lines: Vec<(usize, Vec<String>)> = text
        .lines()
        .enumerate()
        .map(|(i, line)| {
            let tokens = line.split([',', '\t', ' ']).map(str::trim);
            (
                i + 1,
                tokens
                    .filter(|t| !t.is_empty())
                    .map(String::from)
                    .collect::<Vec<_>>(),
            )
        })
        .filter(|(_, tokens)| !tokens.is_empty())
        .collect();
    if lines.is_empty() {
        return Err(DataError::EmptySplit {
            path: list.to_path_buf(),
        });
    }
    Ok(lines)
}

/// The error of `list`'s line `line`.
pub fn line_error(list: &Path, line: usize, message: impl std::fmt::Display) -> DataError {
    DataError::Format {
        path: list.to_path_buf(),
        message: format!("line {line}: {message}"),
    }
}

/// The frames of `list` for `spec`: (1-based line, fields in the RGB pattern's order; only
/// some of them when a line's path stops short of folder fields).
pub fn read_split_list(spec: &SplitSpec, list: &Path) -> Result<Vec<(usize, Fields)>, DataError> {
    read_list_lines(list)?
        .into_iter()
        .map(|(line, tokens)| {
            let fields = line_fields(spec, &tokens)
                .and_then(|f| f.ok_or_else(|| unmatched(spec, &tokens)))
                .map_err(|message| line_error(list, line, message))?;
            Ok((line, fields))
        })
        .collect()
}

/// Why a line whose entries match none of `spec`'s patterns names no frame.
fn unmatched(spec: &SplitSpec, tokens: &[String]) -> String {
    match tokens {
        [one] => frame_name_fields(spec, one)
            .err()
            .unwrap_or_else(|| no_match(spec, one)),
        _ => no_match(spec, &tokens[0]),
    }
}

/// Whether every field of `partial` has the same value in `fields`.
pub fn agrees(partial: &Fields, fields: &Fields) -> bool {
    partial.iter().all(|(f, v)| value(fields, f) == v)
}

/// Frames looked up by the values of some of their fields (a list line that stops short of
/// folder fields): one table per set of fields, built on first use, so a list of N such lines
/// over N frames costs O(N), not O(N²).
#[derive(Default)]
pub struct PartialIndex {
    tables:
        std::collections::HashMap<Vec<String>, std::collections::HashMap<Vec<String>, Vec<usize>>>,
}

impl PartialIndex {
    /// The indices of the frames of `frames` that agree with `partial` ([`agrees`]).
    pub fn lookup<'f>(
        &mut self,
        frames: impl Iterator<Item = &'f Fields>,
        partial: &Fields,
    ) -> &[usize] {
        let names: Vec<String> = partial.iter().map(|(f, _)| f.clone()).collect();
        let table = self.tables.entry(names.clone()).or_insert_with(|| {
            let mut table: std::collections::HashMap<Vec<String>, Vec<usize>> = Default::default();
            for (i, fields) in frames.enumerate() {
                let key = names.iter().map(|n| value(fields, n).to_string()).collect();
                table.entry(key).or_default().push(i);
            }
            table
        });
        let key: Vec<String> = partial.iter().map(|(_, v)| v.clone()).collect();
        table.get(&key).map_or(&[], Vec::as_slice)
    }
}

/// The fields of the frame a line names by `spec`'s patterns (module docs), in the RGB
/// pattern's order; `None` when no entry of the line matches them (nor is a frame name).
pub fn line_fields(spec: &SplitSpec, tokens: &[String]) -> Result<Option<Fields>, String> {
    if tokens.len() > 3 {
        return Err(format!(
            "{} entries; a line holds a frame name or one to three paths (RGB, thermal, label)",
            tokens.len()
        ));
    }
    let mut frame: Option<(Fields, &str)> = None;
    let mut missed = None;
    for token in tokens {
        let fields = match match_path(spec, token)? {
            Some(fields) => fields,
            None if tokens.len() == 1 => match frame_name_fields(spec, token) {
                Ok(fields) => fields,
                Err(_) => return Ok(None),
            },
            None => {
                missed = Some(token);
                continue;
            }
        };
        match &frame {
            Some((first, by)) if !agrees(first, &fields) || !agrees(&fields, first) => {
                return Err(format!(
                    "'{by}' is frame '{}' but '{token}' is frame '{}'",
                    frame_name(first),
                    frame_name(&fields)
                ))
            }
            Some((first, by)) if first.len() < fields.len() => frame = Some((fields, by)),
            Some(_) => {}
            None => frame = Some((fields, token)),
        }
    }
    match (frame, missed) {
        (None, _) => Ok(None),
        (Some(_), Some(token)) => Err(no_match(spec, token)),
        (Some((fields, _)), None) => Ok(Some(
            spec.rgb
                .fields()
                .into_iter()
                .filter_map(|f| fields.iter().find(|(n, _)| n == f).cloned())
                .collect(),
        )),
    }
}

fn patterns(spec: &SplitSpec) -> impl Iterator<Item = &FilePattern> {
    [Some(&spec.rgb), Some(&spec.thermal), spec.labels.as_ref()]
        .into_iter()
        .flatten()
}

fn no_match(spec: &SplitSpec, token: &str) -> String {
    let written: Vec<String> = patterns(spec).map(FilePattern::describe).collect();
    format!(
        "'{token}' matches none of the split's patterns ({})",
        written.join(", ")
    )
}

/// The fields of a path written in a list, by the first pattern whose end it matches
/// ([`FilePattern::match_tail`]).
fn match_path(spec: &SplitSpec, token: &str) -> Result<Option<Fields>, String> {
    let path = Path::new(token);
    if path.is_absolute()
        || path
            .components()
            .any(|c| !matches!(c, Component::Normal(_)))
    {
        return Err(format!(
            "'{token}' is not a relative path inside the dataset"
        ));
    }
    let components: Vec<&str> = token.split('/').collect();
    for pattern in patterns(spec) {
        if let Some(fields) = pattern
            .match_tail(&components)
            .map_err(|e| format!("'{token}': {e}"))?
        {
            return Ok(Some(fields));
        }
    }
    Ok(None)
}

/// A bare frame name: the RGB pattern's field values joined by `/`.
fn frame_name_fields(spec: &SplitSpec, token: &str) -> Result<Fields, String> {
    let names = spec.rgb.fields();
    let values: Vec<&str> = token.split('/').collect();
    let bad = values
        .iter()
        .any(|v| v.is_empty() || *v == "." || *v == ".." || v.contains(['\\', '\0']));
    if values.len() != names.len() || bad {
        return Err(if names.len() == 1 {
            no_match(spec, token)
        } else {
            format!(
                "'{token}' is not a frame name ({} values joined by '/': {{{}}}) and matches none of the split's patterns",
                names.len(),
                names.join("}/{")
            )
        });
    }
    Ok(names
        .into_iter()
        .zip(values)
        .map(|(n, v)| (n.to_string(), v.to_string()))
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spec(root: &Path) -> SplitSpec {
        let pattern = |dir: &str, t: &str| FilePattern::parse(root.join(dir), t).unwrap();
        SplitSpec {
            name: "train".into(),
            rgb: pattern("color", "{seq}_eo-{n}.jpg"),
            thermal: pattern("thermal16", "{seq}_thermal-{n}.tiff"),
            labels: Some(pattern("annotations", "{seq}_mask-{n}.png")),
            lists: Vec::new(),
        }
    }

    fn lines(text: &str) -> Result<Vec<(usize, String)>, String> {
        let dir = tempfile::tempdir().unwrap();
        let list = dir.path().join("train.txt");
        std::fs::write(&list, text).unwrap();
        read_split_list(&spec(dir.path()), &list)
            .map(|v| v.into_iter().map(|(l, f)| (l, frame_name(&f))).collect())
            .map_err(|e| e.to_string())
    }

    #[test]
    fn paths_in_any_order_and_separator_and_bare_names_identify_frames() {
        let got = lines(
            "color/a_eo-1.jpg,annotations/a_mask-1.png\n\n\
             annotations/b_mask-7.png\tthermal16/b_thermal-7.tiff color/b_eo-7.jpg\n\
             c/3\n\
             d_eo-4.jpg\n",
        )
        .unwrap();
        let want = [(1, "a/1"), (3, "b/7"), (4, "c/3"), (5, "d/4")];
        let want: Vec<(usize, String)> = want.iter().map(|(l, n)| (*l, n.to_string())).collect();
        assert_eq!(got, want);
    }

    #[test]
    fn bad_lines_name_the_list_the_line_and_the_path() {
        for (text, says) in [
            ("color/a_eo-1.jpg,annotations/b_mask-1.png\n", "line 1: 'color/a_eo-1.jpg' is frame 'a/1' but 'annotations/b_mask-1.png' is frame 'b/1'"),
            ("x\ncolor/a.png,thermal16/a.tiff\n", "line 1: 'x' is not a frame name"),
            ("a/1\nrgb/a_eo-1.jpg,thermal16/a_thermal-1.tiff\n", "line 2: 'rgb/a_eo-1.jpg' matches none"),
            ("a/1 a/1 a/1 a/1\n", "line 1: 4 entries"),
            ("../color/a_eo-1.jpg\n", "not a relative path"),
        ] {
            let err = lines(text).unwrap_err();
            assert!(err.contains("train.txt") && err.contains(says), "{text:?}: {err}");
        }
        assert!(lines("\n\n").unwrap_err().contains("empty"));
    }

    #[test]
    fn a_single_field_split_takes_names_as_before() {
        let dir = tempfile::tempdir().unwrap();
        let folder = |d: &str, f| FilePattern::folder(dir.path().join(d), f);
        let spec = SplitSpec {
            name: "test".into(),
            rgb: folder("rgb", crate::images::Format::RGB),
            thermal: folder("thermal", crate::images::Format::THERMAL),
            labels: None,
            lists: Vec::new(),
        };
        let list = dir.path().join("test.txt");
        std::fs::write(&list, "00012N\nrgb/00013D.jpg\n").unwrap();
        let got: Vec<String> = read_split_list(&spec, &list)
            .unwrap()
            .iter()
            .map(|(_, f)| frame_name(f))
            .collect();
        assert_eq!(got, ["00012N", "00013D"]);
    }
}
