//! Split files as datasets ship them: each line a frame name, or one to three relative paths
//! (the frame's RGB, thermal and label files, in any order) separated by commas, tabs or
//! spaces (`color/a_eo-1.jpg,annotations/a_mask-1.png`). A path is matched against the split's
//! patterns to identify its frame; a path that matches none, paths of one line naming
//! different frames, or a line of more than three paths is an error naming the list and line.

use std::path::{Component, Path};

use crate::description::SplitSpec;
use crate::pattern::{frame_key, frame_name, value, Fields, FilePattern};
use crate::DataError;

/// The frames of `list` for `spec`: (1-based line, fields in the RGB pattern's order).
pub fn read_split_list(spec: &SplitSpec, list: &Path) -> Result<Vec<(usize, Fields)>, DataError> {
    let bytes = std::fs::read(list).map_err(|e| DataError::io(list, e))?;
    let text = String::from_utf8(bytes).map_err(|_| DataError::Format {
        path: list.to_path_buf(),
        message: "split file is not UTF-8 text".into(),
    })?;
    let mut frames = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let tokens: Vec<&str> = line
            .split([',', '\t', ' '])
            .map(str::trim)
            .filter(|t| !t.is_empty())
            .collect();
        if tokens.is_empty() {
            continue;
        }
        let error = |message: String| DataError::Format {
            path: list.to_path_buf(),
            message: format!("line {}: {message}", i + 1),
        };
        frames.push((i + 1, frame_of_line(spec, &tokens).map_err(error)?));
    }
    if frames.is_empty() {
        return Err(DataError::EmptySplit {
            path: list.to_path_buf(),
        });
    }
    Ok(frames)
}

/// The frame a line names (module docs).
fn frame_of_line(spec: &SplitSpec, tokens: &[&str]) -> Result<Fields, String> {
    if tokens.len() > 3 {
        return Err(format!(
            "{} entries; a line holds a frame name or one to three paths (RGB, thermal, label)",
            tokens.len()
        ));
    }
    let mut frame: Option<(Fields, &str)> = None;
    for token in tokens {
        let fields = match match_path(spec, token)? {
            Some(fields) => fields,
            None if tokens.len() == 1 => frame_name_fields(spec, token)?,
            None => return Err(no_match(spec, token)),
        };
        match &frame {
            Some((first, by)) if frame_key(first) != frame_key(&fields) => {
                return Err(format!(
                    "'{by}' is frame '{}' but '{token}' is frame '{}'",
                    frame_name(first),
                    frame_name(&fields)
                ))
            }
            Some(_) => {}
            None => frame = Some((fields, token)),
        }
    }
    let (fields, _) = frame.expect("a line has a token");
    Ok(spec
        .rgb
        .fields()
        .into_iter()
        .map(|f| (f.to_string(), value(&fields, f).to_string()))
        .collect())
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

/// The fields of a path written in a list, by the first pattern whose folder ends with the
/// path's folders and whose template matches its file name.
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
    let (Some(file), parent) = (path.file_name().and_then(|f| f.to_str()), path.parent()) else {
        return Ok(None);
    };
    for pattern in patterns(spec) {
        if !parent.is_none_or(|p| pattern.dir.ends_with(p)) {
            continue;
        }
        if let Some(fields) = pattern
            .match_name(file)
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
            list: None,
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
            list: None,
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
