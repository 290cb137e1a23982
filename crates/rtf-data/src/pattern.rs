//! Where one kind of file of a split is: a folder and a path template with named fields, as
//! public RGB-T releases name their files per modality, in the file name
//! (`color/{seq}_eo-{n}.jpg`, `thermal16/{seq}_thermal-{n}.tiff`) or in folders too, as sets
//! recorded as driving sequences store them (`images/{set}/{video}/visible/{frame}.jpg`). A
//! frame is the tuple of its fields' values: found by walking the folders that match the RGB
//! pattern, its partners by filling theirs. A frame's name is its values joined by `/` in the
//! RGB pattern's order (one field: the value).
//!
//! A folder given without a template holds `{name}.<ext>` for every extension of the role's
//! formats (RGB: png, jpg, jpeg; thermal: png, jpg, jpeg, tif, tiff, npy; labels: png).

use std::path::{Path, PathBuf};

use crate::images::Format;
use crate::DataError;

/// One field's value per field, in a pattern's field order.
pub type Fields = Vec<(String, String)>;

#[derive(Debug, Clone, PartialEq, Eq)]
enum Piece {
    Literal(String),
    Field(String),
}

/// One path component of a template: literals and fields.
type Segment = Vec<Piece>;

/// A folder and a path template (module docs).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FilePattern {
    /// The fixed folder the template starts in (no field in it).
    pub dir: PathBuf,
    /// The template's path components below `dir`; the last is the file name.
    segments: Vec<Segment>,
    /// A folder pattern's extensions (the template is then `{name}`, the extension one of
    /// these); empty for a written template, whose extension is part of it.
    extensions: Vec<&'static str>,
}

impl FilePattern {
    /// `dir/{name}.<ext>` for every extension of `formats`.
    pub fn folder(dir: PathBuf, formats: &[Format]) -> Self {
        Self {
            dir,
            segments: vec![vec![Piece::Field("name".into())]],
            extensions: Format::all_extensions(formats),
        }
    }

    /// Parses the path template `template` below folder `dir`: components separated by `/`,
    /// each of literals and `{field}`s; each field once in the whole template, no two fields
    /// side by side, at least one field. The error says what is wrong.
    pub fn parse(dir: PathBuf, template: &str) -> Result<Self, String> {
        let mut segments: Vec<Segment> = Vec::new();
        for component in template.split('/') {
            if component.is_empty() || component == "." || component == ".." {
                return Err(format!(
                    "'{template}': '{component}' is not a folder or file name"
                ));
            }
            let segment = parse_segment(component, template)?;
            for piece in &segment {
                if let Piece::Field(name) = piece {
                    if segments.iter().flatten().any(|p| p == piece) {
                        return Err(format!("'{template}': field {{{name}}} is used twice"));
                    }
                }
            }
            segments.push(segment);
        }
        if !segments
            .iter()
            .flatten()
            .any(|p| matches!(p, Piece::Field(_)))
        {
            return Err(format!("'{template}': no {{field}} in the path"));
        }
        Ok(Self {
            dir,
            segments,
            extensions: Vec::new(),
        })
    }

    /// The pattern as a user reads it: `dir/{set}/{seq}_eo-{n}.jpg`, or `dir/{name}.png|jpg`.
    pub fn describe(&self) -> String {
        let template: Vec<String> = self.segments.iter().map(written).collect();
        let ext = match self.extensions.is_empty() {
            true => String::new(),
            false => format!(".{}", self.extensions.join("|")),
        };
        self.dir
            .join(template.join("/") + &ext)
            .display()
            .to_string()
    }

    /// The field names, in order.
    pub fn fields(&self) -> Vec<&str> {
        self.segments
            .iter()
            .flatten()
            .filter_map(|p| match p {
                Piece::Field(f) => Some(f.as_str()),
                Piece::Literal(_) => None,
            })
            .collect()
    }

    /// Whether a field is in a folder of the template (not only in the file name).
    pub fn has_folder_fields(&self) -> bool {
        let folders = &self.segments[..self.segments.len() - 1];
        folders
            .iter()
            .flatten()
            .any(|p| matches!(p, Piece::Field(_)))
    }

    /// The path of `fields` below `dir`, without a folder pattern's extension.
    fn fill(&self, fields: &Fields) -> PathBuf {
        let mut path = self.dir.clone();
        for segment in &self.segments {
            let part: String = segment
                .iter()
                .map(|p| match p {
                    Piece::Literal(l) => l.as_str(),
                    Piece::Field(f) => value(fields, f),
                })
                .collect();
            path.push(part);
        }
        path
    }

    /// The file of a frame: a folder pattern's first extension whose file exists (else its
    /// first extension, to name in a message).
    pub fn path(&self, fields: &Fields) -> PathBuf {
        let stem = self.fill(fields);
        if self.extensions.is_empty() {
            return stem;
        }
        let stem = stem.into_os_string().into_string().unwrap_or_default();
        let candidates = self
            .extensions
            .iter()
            .flat_map(|e| [e.to_string(), e.to_ascii_uppercase()].map(|e| format!("{stem}.{e}")));
        let mut first = None;
        for path in candidates.map(PathBuf::from) {
            if path.is_file() {
                return path;
            }
            first.get_or_insert(path);
        }
        first.unwrap_or_else(|| PathBuf::from(stem))
    }

    /// The fields of a file name, if it matches the template's file name (fields in folders
    /// stay unbound). Several readings of one name are an error naming them.
    pub fn match_name(&self, file_name: &str) -> Result<Option<Fields>, String> {
        self.match_tail(&[file_name])
    }

    /// The fields of a relative path whose components are the last components of the
    /// pattern (its folder's included): `visible/I00050.jpg`, `set00/V000/visible/I00050.jpg`,
    /// a bare file name. Fields of components the path does not reach stay unbound, so the
    /// result may hold only some of the pattern's fields. Several readings of one component
    /// are an error naming them.
    pub fn match_tail(&self, components: &[&str]) -> Result<Option<Fields>, String> {
        let fixed: Vec<String> = self
            .dir
            .components()
            .map(|c| c.as_os_str().to_string_lossy().into_owned())
            .collect();
        let total = fixed.len() + self.segments.len();
        let Some(start) = total.checked_sub(components.len()) else {
            return Ok(None);
        };
        let mut bound = Fields::new();
        for (k, component) in components.iter().enumerate() {
            let at = start + k;
            if at < fixed.len() {
                if fixed[at] != *component {
                    return Ok(None);
                }
                continue;
            }
            let last = at + 1 == total;
            let segment = &self.segments[at - fixed.len()];
            match self.match_component(segment, component, last)? {
                Some(fields) => bound.extend(fields),
                None => return Ok(None),
            }
        }
        Ok(Some(bound))
    }

    /// The one reading of `name` by `segment` (the file name's extension checked when `last`).
    fn match_component(
        &self,
        segment: &Segment,
        name: &str,
        last: bool,
    ) -> Result<Option<Fields>, String> {
        let stem = match last && !self.extensions.is_empty() {
            false => Some(name),
            true => self.extensions.iter().find_map(|e| {
                let (stem, ext) = name.rsplit_once('.')?;
                ext.eq_ignore_ascii_case(e).then_some(stem)
            }),
        };
        let Some(stem) = stem else {
            return Ok(None);
        };
        let mut readings = Vec::new();
        match_pieces(segment, stem, &mut Vec::new(), &mut readings);
        match readings.len() {
            0 => Ok(None),
            1 => Ok(readings.pop()),
            _ => Err(format!(
                "'{name}' matches '{}' in {} ways ({})",
                written(segment),
                readings.len(),
                readings
                    .iter()
                    .map(frame_name)
                    .collect::<Vec<_>>()
                    .join(" or ")
            )),
        }
    }

    /// The frames of the files that match, found by walking the folders that match, sorted by
    /// name: (fields, file). Two files of one frame (`a.png` and `a.jpg`) are an error naming
    /// both.
    pub fn find(&self) -> Result<Vec<(Fields, PathBuf)>, DataError> {
        let mut found: Vec<(String, Fields, PathBuf)> = Vec::new();
        self.walk(&self.dir, 0, &mut Vec::new(), &mut found)?;
        found.sort_unstable_by(|a, b| a.0.cmp(&b.0).then_with(|| a.2.cmp(&b.2)));
        if let Some(pair) = found.windows(2).find(|w| w[0].0 == w[1].0) {
            return Err(DataError::Format {
                path: pair[1].2.clone(),
                message: format!(
                    "and {} are the same frame '{}': keep one",
                    pair[0].2.display(),
                    pair[0].0
                ),
            });
        }
        Ok(found.into_iter().map(|(_, f, p)| (f, p)).collect())
    }

    /// Lists `dir` for segment `depth`: files matching the last segment, folders matching a
    /// folder segment (walked in turn).
    fn walk(
        &self,
        dir: &Path,
        depth: usize,
        bound: &mut Fields,
        out: &mut Vec<(String, Fields, PathBuf)>,
    ) -> Result<(), DataError> {
        let segment = &self.segments[depth];
        let last = depth + 1 == self.segments.len();
        if let [Piece::Literal(name)] = segment.as_slice() {
            let next = dir.join(name);
            match last {
                true if next.is_file() => out.push((frame_name(bound), bound.clone(), next)),
                false if next.is_dir() => self.walk(&next, depth + 1, bound, out)?,
                _ => {}
            }
            return Ok(());
        }
        let entries = std::fs::read_dir(dir).map_err(|e| DataError::io(dir, e))?;
        for entry in entries.flatten() {
            let Some(name) = entry.file_name().to_str().map(str::to_string) else {
                continue;
            };
            if name.starts_with('.') || !is_kind(&entry, last) {
                continue;
            }
            let path = entry.path();
            let fields = self
                .match_component(segment, &name, last)
                .map_err(|message| DataError::Format {
                    path: path.clone(),
                    message,
                })?;
            let Some(fields) = fields else { continue };
            let n = bound.len();
            bound.extend(fields);
            match last {
                true => out.push((frame_name(bound), bound.clone(), path)),
                false => self.walk(&path, depth + 1, bound, out)?,
            }
            bound.truncate(n);
        }
        Ok(())
    }
}

/// Whether a listed entry is a file (`file`) or a folder, following a symbolic link.
fn is_kind(entry: &std::fs::DirEntry, file: bool) -> bool {
    let Ok(kind) = entry.file_type() else {
        return false;
    };
    let (is_file, is_dir) = match kind.is_symlink() {
        true => {
            let path = entry.path();
            (path.is_file(), path.is_dir())
        }
        false => (kind.is_file(), kind.is_dir()),
    };
    if file {
        is_file
    } else {
        is_dir
    }
}

/// One component of a template: literals and `{field}`s, no two fields side by side.
fn parse_segment(component: &str, template: &str) -> Result<Segment, String> {
    let mut pieces = Vec::new();
    let mut rest = component;
    while let Some(open) = rest.find('{') {
        if open > 0 {
            pieces.push(Piece::Literal(rest[..open].to_string()));
        }
        let close = rest[open..]
            .find('}')
            .ok_or_else(|| format!("'{template}': a '{{' without its '}}'"))?;
        let name = &rest[open + 1..open + close];
        if name.is_empty() || !name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_') {
            return Err(format!(
                "'{template}': '{{{name}}}' is not a field name (letters, digits, _)"
            ));
        }
        if matches!(pieces.last(), Some(Piece::Field(_))) {
            return Err(format!(
                "'{template}': two fields side by side cannot be told apart"
            ));
        }
        if pieces.contains(&Piece::Field(name.to_string())) {
            return Err(format!("'{template}': field {{{name}}} is used twice"));
        }
        pieces.push(Piece::Field(name.to_string()));
        rest = &rest[open + close + 1..];
    }
    if rest.contains('}') {
        return Err(format!("'{template}': a '}}' without its '{{'"));
    }
    if !rest.is_empty() {
        pieces.push(Piece::Literal(rest.to_string()));
    }
    Ok(pieces)
}

/// A segment as written.
fn written(segment: &Segment) -> String {
    segment
        .iter()
        .map(|p| match p {
            Piece::Literal(l) => l.clone(),
            Piece::Field(f) => format!("{{{f}}}"),
        })
        .collect()
}

/// The value of field `name` ("" when absent: patterns are checked to share their fields).
pub fn value<'a>(fields: &'a Fields, name: &str) -> &'a str {
    fields
        .iter()
        .find(|(f, _)| f == name)
        .map_or("", |(_, v)| v.as_str())
}

/// A frame's name: its values joined by `/`.
pub fn frame_name(fields: &Fields) -> String {
    fields
        .iter()
        .map(|(_, v)| v.as_str())
        .collect::<Vec<_>>()
        .join("/")
}

/// A frame's identity whatever order a pattern names its fields in.
pub fn frame_key(fields: &Fields) -> String {
    let mut sorted = fields.clone();
    sorted.sort();
    frame_name(&sorted)
}

/// Every reading of `text` by `pieces` (fields non-empty).
fn match_pieces(pieces: &[Piece], text: &str, bound: &mut Fields, out: &mut Vec<Fields>) {
    let Some((first, rest)) = pieces.split_first() else {
        if text.is_empty() {
            out.push(bound.clone());
        }
        return;
    };
    match first {
        Piece::Literal(l) => {
            if let Some(after) = text.strip_prefix(l.as_str()) {
                match_pieces(rest, after, bound, out);
            }
        }
        Piece::Field(f) => {
            for end in text
                .char_indices()
                .map(|(i, _)| i)
                .skip(1)
                .chain([text.len()])
            {
                bound.push((f.clone(), text[..end].to_string()));
                match_pieces(rest, &text[end..], bound, out);
                bound.pop();
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    fn fields(pairs: &[(&str, &str)]) -> Fields {
        pairs
            .iter()
            .map(|(f, v)| (f.to_string(), v.to_string()))
            .collect()
    }

    #[test]
    fn named_fields_match_and_fill_back() {
        let p = FilePattern::parse("color".into(), "{seq}_eo-{n}.jpg").unwrap();
        assert_eq!(p.fields(), ["seq", "n"]);
        let got = p.match_name("set_01_eo-17.jpg").unwrap().unwrap();
        assert_eq!(got, fields(&[("seq", "set_01"), ("n", "17")]));
        assert_eq!(frame_name(&got), "set_01/17");
        assert_eq!(p.path(&got), Path::new("color/set_01_eo-17.jpg"));
        assert_eq!(p.match_name("set_01_thermal-17.tiff").unwrap(), None);
        let t = FilePattern::parse("thermal16".into(), "{seq}_thermal-{n}.tiff").unwrap();
        assert_eq!(t.path(&got), Path::new("thermal16/set_01_thermal-17.tiff"));
    }

    #[test]
    fn fields_in_folders_are_found_by_walking_and_a_path_tail_binds_some_fields() {
        let dir = tempfile::tempdir().unwrap();
        for f in [
            "s0/V0/visible/I1.jpg",
            "s0/V1/visible/I1.jpg",
            "s0/V1/lwir/I1.jpg",
            "x.jpg",
        ] {
            let path = dir.path().join(f);
            std::fs::create_dir_all(path.parent().unwrap()).unwrap();
            std::fs::write(path, b"x").unwrap();
        }
        let p = FilePattern::parse(dir.path().into(), "{set}/{video}/visible/{frame}.jpg").unwrap();
        assert_eq!(p.fields(), ["set", "video", "frame"]);
        assert!(p.has_folder_fields());
        let found = p.find().unwrap();
        let names: Vec<String> = found.iter().map(|(f, _)| frame_name(f)).collect();
        assert_eq!(names, ["s0/V0/I1", "s0/V1/I1"]);
        assert_eq!(p.path(&found[1].0), dir.path().join("s0/V1/visible/I1.jpg"));
        let tail = p.match_tail(&["V1", "visible", "I1.jpg"]).unwrap().unwrap();
        assert_eq!(tail, fields(&[("video", "V1"), ("frame", "I1")]));
        assert_eq!(p.match_tail(&["lwir", "I1.jpg"]).unwrap(), None);
        assert_eq!(p.match_name("I1.png").unwrap(), None);
        for (template, says) in [
            ("{a}/../{b}.png", "not a folder"),
            ("{a}/{a}.png", "used twice"),
        ] {
            let err = FilePattern::parse(".".into(), template).unwrap_err();
            assert!(err.contains(says), "{template}: {err}");
        }
    }

    #[test]
    fn bad_templates_say_what_is_wrong() {
        for (template, says) in [
            ("{seq}_{seq}.png", "used twice"),
            ("{a}{b}.png", "side by side"),
            ("frame.png", "no {field} in the path"),
            ("{seq.png", "without its"),
            ("{se q}.png", "not a field name"),
        ] {
            let err = FilePattern::parse(".".into(), template).unwrap_err();
            assert!(err.contains(says), "{template}: {err}");
        }
    }

    #[test]
    fn a_name_with_several_readings_is_an_error() {
        let p = FilePattern::parse(".".into(), "{a}_{b}.png").unwrap();
        let err = p.match_name("x_y_z.png").unwrap_err();
        assert!(
            err.contains("2 ways") && err.contains("x/y_z") && err.contains("x_y/z"),
            "{err}"
        );
    }

    #[test]
    fn folder_patterns_take_every_extension_of_the_role_and_refuse_a_frame_twice() {
        let dir = tempfile::tempdir().unwrap();
        for f in ["a.png", "b.JPG", "c.txt", ".hidden.png"] {
            std::fs::write(dir.path().join(f), b"x").unwrap();
        }
        let p = FilePattern::folder(dir.path().to_path_buf(), Format::RGB);
        let found = p.find().unwrap();
        let names: Vec<String> = found.iter().map(|(f, _)| frame_name(f)).collect();
        assert_eq!(names, ["a", "b"]);
        assert_eq!(found[1].1, dir.path().join("b.JPG"));
        assert_eq!(p.path(&found[1].0), dir.path().join("b.JPG"));
        std::fs::write(dir.path().join("a.jpg"), b"x").unwrap();
        let err = p.find().unwrap_err().to_string();
        assert!(
            err.contains("a.png") && err.contains("a.jpg") && err.contains("same frame"),
            "{err}"
        );
    }
}
