//! Where one kind of file of a split is: a folder and a file-name template with named fields,
//! as public RGB-T releases name their files per modality (`color/{seq}_eo-{n}.jpg`,
//! `thermal16/{seq}_thermal-{n}.tiff`, `annotations/{seq}_mask-{n}.png`). A frame is the tuple
//! of its fields' values: found by matching the RGB pattern, its partners by filling theirs.
//! A frame's name is its values joined by `/` in the RGB pattern's order (one field: the value).
//!
//! A folder given without a template holds `{name}.<ext>` for every extension of the role's
//! formats (RGB: png, jpg, jpeg; thermal: png, tif, tiff, npy; labels: png).

use std::path::PathBuf;

use crate::images::Format;
use crate::DataError;

/// One field's value per field, in a pattern's field order.
pub type Fields = Vec<(String, String)>;

#[derive(Debug, Clone, PartialEq, Eq)]
enum Piece {
    Literal(String),
    Field(String),
}

/// A folder and a file-name template (module docs).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FilePattern {
    pub dir: PathBuf,
    pieces: Vec<Piece>,
    /// A folder pattern's extensions (the template is then `{name}`, the extension one of
    /// these); empty for a written template, whose extension is part of it.
    extensions: Vec<&'static str>,
}

impl FilePattern {
    /// `dir/{name}.<ext>` for every extension of `formats`.
    pub fn folder(dir: PathBuf, formats: &[Format]) -> Self {
        Self {
            dir,
            pieces: vec![Piece::Field("name".into())],
            extensions: Format::all_extensions(formats),
        }
    }

    /// Parses the file-name template `template` (in folder `dir`): literals and `{field}`s, each
    /// field once, no two fields side by side. The error says what is wrong.
    pub fn parse(dir: PathBuf, template: &str) -> Result<Self, String> {
        let mut pieces = Vec::new();
        let mut rest = template;
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
        if !pieces.iter().any(|p| matches!(p, Piece::Field(_))) {
            return Err(format!("'{template}': no {{field}} in the file name"));
        }
        Ok(Self {
            dir,
            pieces,
            extensions: Vec::new(),
        })
    }

    /// The pattern as a user reads it: `dir/{seq}_eo-{n}.jpg`, or `dir/{name}.png|jpg|jpeg`.
    pub fn describe(&self) -> String {
        let template: String = self
            .pieces
            .iter()
            .map(|p| match p {
                Piece::Literal(l) => l.clone(),
                Piece::Field(f) => format!("{{{f}}}"),
            })
            .collect();
        let ext = match self.extensions.is_empty() {
            true => String::new(),
            false => format!(".{}", self.extensions.join("|")),
        };
        self.dir.join(template + &ext).display().to_string()
    }

    /// The field names, in order.
    pub fn fields(&self) -> Vec<&str> {
        self.pieces
            .iter()
            .filter_map(|p| match p {
                Piece::Field(f) => Some(f.as_str()),
                Piece::Literal(_) => None,
            })
            .collect()
    }

    /// The file name of `fields` without a folder pattern's extension.
    fn fill(&self, fields: &Fields) -> String {
        self.pieces
            .iter()
            .map(|p| match p {
                Piece::Literal(l) => l.as_str(),
                Piece::Field(f) => value(fields, f),
            })
            .collect()
    }

    /// The file of a frame: a folder pattern's first extension whose file exists (else its
    /// first extension, to name in a message).
    pub fn path(&self, fields: &Fields) -> PathBuf {
        let stem = self.fill(fields);
        if self.extensions.is_empty() {
            return self.dir.join(stem);
        }
        let candidates = self.extensions.iter().flat_map(|e| {
            [e.to_string(), e.to_ascii_uppercase()].map(|e| self.dir.join(format!("{stem}.{e}")))
        });
        let mut first = None;
        for path in candidates {
            if path.is_file() {
                return path;
            }
            first.get_or_insert(path);
        }
        first.unwrap_or_else(|| self.dir.join(stem))
    }

    /// The fields of a file name, if it matches. Several readings of one name (a literal the
    /// field values could also contain) are an error naming them.
    pub fn match_name(&self, file_name: &str) -> Result<Option<Fields>, String> {
        let stem = match self.extensions.is_empty() {
            true => Some(file_name),
            false => self.extensions.iter().find_map(|e| {
                let (stem, ext) = file_name.rsplit_once('.')?;
                ext.eq_ignore_ascii_case(e).then_some(stem)
            }),
        };
        let Some(stem) = stem else {
            return Ok(None);
        };
        let mut readings = Vec::new();
        match_pieces(&self.pieces, stem, &mut Vec::new(), &mut readings);
        match readings.len() {
            0 => Ok(None),
            1 => Ok(readings.pop()),
            _ => Err(format!(
                "'{file_name}' matches the pattern in {} ways ({})",
                readings.len(),
                readings
                    .iter()
                    .map(frame_name)
                    .collect::<Vec<_>>()
                    .join(" or ")
            )),
        }
    }

    /// The frames of the files in the folder that match, sorted by name: (fields, file). Two
    /// files of one frame (`a.png` and `a.jpg`) are an error naming both.
    pub fn find(&self) -> Result<Vec<(Fields, PathBuf)>, DataError> {
        let entries = std::fs::read_dir(&self.dir).map_err(|e| DataError::io(&self.dir, e))?;
        let mut found: Vec<(Fields, PathBuf)> = Vec::new();
        for entry in entries.flatten() {
            let path = entry.path();
            let Some(name) = entry.file_name().to_str().map(str::to_string) else {
                continue;
            };
            if name.starts_with('.') || !path.is_file() {
                continue;
            }
            let fields = self
                .match_name(&name)
                .map_err(|message| DataError::Format {
                    path: path.clone(),
                    message,
                })?;
            found.extend(fields.map(|f| (f, path)));
        }
        found.sort_by(|a, b| frame_name(&a.0).cmp(&frame_name(&b.0)).then(a.1.cmp(&b.1)));
        if let Some(pair) = found.windows(2).find(|w| w[0].0 == w[1].0) {
            return Err(DataError::Format {
                path: pair[1].1.clone(),
                message: format!(
                    "and {} are the same frame '{}': keep one",
                    pair[0].1.display(),
                    frame_name(&pair[0].0)
                ),
            });
        }
        Ok(found)
    }
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
    fn bad_templates_say_what_is_wrong() {
        for (template, says) in [
            ("{seq}_{seq}.png", "used twice"),
            ("{a}{b}.png", "side by side"),
            ("frame.png", "no {field}"),
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
