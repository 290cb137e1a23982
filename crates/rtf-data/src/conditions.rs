//! Day and night from a dataset's own condition lists (`day: {list: [...]}`,
//! `night: {list: [...]}`, [`NightRule::Lists`]): each line, in the formats of split lists
//! ([`crate::split_list`]), must name exactly one frame of the dataset — of the split being
//! opened or of another — so that a list in another naming (label file names where the frames
//! are named by their fields) is an error naming the list and the line, never a split with no
//! night frame. A line naming two frames (a bare file name that several sequences share) is an
//! error too, as is a frame both day and night.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use rtf_core::Daytime;

use crate::description::{DatasetDescription, NightRule, UnmatchedLines};
use crate::pattern::{frame_name, Fields};
use crate::split_list::{line_error, line_fields, read_list_lines, PartialIndex};
use crate::DataError;

/// The frames of the split being opened: names, fields, RGB files, in order.
pub(crate) struct SplitFrames<'a> {
    pub split: &'a str,
    pub names: Vec<&'a str>,
    pub fields: Vec<&'a Fields>,
    pub rgb: Vec<&'a Path>,
}

/// Each frame's condition by `description`'s night rule, and the warnings of lines skipped
/// (`unmatched_lines: warn`).
pub(crate) fn daytimes(
    description: &DatasetDescription,
    frames: &SplitFrames,
) -> Result<(Vec<Option<Daytime>>, Vec<String>), DataError> {
    let (day_lists, night_lists) = match &description.night {
        NightRule::None => return Ok((vec![None; frames.names.len()], Vec::new())),
        NightRule::Suffix(s) => {
            let of = |n: &&str| Some(night_if(n.ends_with(s.as_str())));
            return Ok((frames.names.iter().map(of).collect(), Vec::new()));
        }
        NightRule::Lists { day, night } => (day, night),
    };
    let mut lookup = Lookup::new(description, frames);
    let mut warnings = Vec::new();
    let day = lookup.listed(day_lists, &mut warnings)?;
    let night = lookup.listed(night_lists, &mut warnings)?;
    if let Some((i, day_list)) = day.iter().find(|(i, _)| night.contains_key(i)) {
        return Err(DataError::Format {
            path: night[i].clone(),
            message: format!(
                "frame '{}' is night here and day in {}: a frame has one condition",
                frames.names[*i],
                day_list.display()
            ),
        });
    }
    let condition = |i: usize| match (day.contains_key(&i), night.contains_key(&i)) {
        (true, _) => Some(Daytime::Day),
        (_, true) => Some(Daytime::Night),
        _ if day_lists.is_empty() => Some(Daytime::Day),
        _ if night_lists.is_empty() => Some(Daytime::Night),
        _ => None,
    };
    Ok(((0..frames.names.len()).map(condition).collect(), warnings))
}

fn night_if(night: bool) -> Daytime {
    if night {
        Daytime::Night
    } else {
        Daytime::Day
    }
}

/// Finds the frames a line names, in the split being opened and in the others (scanned once,
/// when a line needs it).
struct Lookup<'a> {
    description: &'a DatasetDescription,
    frames: &'a SplitFrames<'a>,
    by_name: HashMap<&'a str, usize>,
    scans: HashMap<String, Vec<(Fields, PathBuf)>>,
    /// Per split, its frames by some of their fields.
    indices: HashMap<String, PartialIndex>,
}

impl<'a> Lookup<'a> {
    fn new(description: &'a DatasetDescription, frames: &'a SplitFrames<'a>) -> Self {
        let by_name = frames
            .names
            .iter()
            .enumerate()
            .map(|(i, n)| (*n, i))
            .collect();
        Self {
            description,
            frames,
            by_name,
            scans: HashMap::new(),
            indices: HashMap::new(),
        }
    }

    /// The frames of this split the lines of `lists` name: index → the list naming it.
    fn listed(
        &mut self,
        lists: &[PathBuf],
        warnings: &mut Vec<String>,
    ) -> Result<HashMap<usize, PathBuf>, DataError> {
        let mut out = HashMap::new();
        for list in lists {
            let mut skipped = 0;
            for (line, tokens) in read_list_lines(list)? {
                let hits = self.hits(&tokens).map_err(|m| line_error(list, line, m))?;
                match hits.len() {
                    0 if self.description.unmatched_lines == UnmatchedLines::Warn => skipped += 1,
                    0 => return Err(line_error(list, line, self.no_frame(&tokens))),
                    1 => {}
                    n => {
                        let names: Vec<String> = hits.iter().map(|h| h.1.clone()).collect();
                        let message = format!(
                            "'{}' names {n} frames ({}): write more of the path",
                            tokens.join(" "),
                            names.join(", ")
                        );
                        return Err(line_error(list, line, message));
                    }
                }
                if let Some((Some(i), _)) = hits.first() {
                    out.insert(*i, list.clone());
                }
            }
            if skipped > 0 {
                warnings.push(format!(
                    "{}: {skipped} line(s) name no frame of the dataset (skipped: unmatched_lines: warn)",
                    list.display()
                ));
            }
        }
        Ok(out)
    }

    fn no_frame(&self, tokens: &[String]) -> String {
        let splits = self.description.split_names().join(", ");
        format!(
            "'{}' names no frame of the dataset (splits {splits})",
            tokens.join(" ")
        )
    }

    /// The distinct frames a line names: (index in this split, if there; name).
    fn hits(&mut self, tokens: &[String]) -> Result<Vec<(Option<usize>, String)>, String> {
        let mut seen: HashMap<PathBuf, usize> = HashMap::new();
        let mut out: Vec<(Option<usize>, String)> = Vec::new();
        // One frame per RGB file (splits may share folders), this split's index kept.
        let mut push = |at: Option<usize>, name: String, rgb: PathBuf| match seen.get(&rgb) {
            Some(&k) if at.is_some() => out[k] = (at, name),
            Some(_) => {}
            None => {
                seen.insert(rgb, out.len());
                out.push((at, name));
            }
        };
        for spec in &self.description.splits {
            let Some(fields) = line_fields(spec, tokens)? else {
                continue;
            };
            let full = fields.len() == spec.rgb.fields().len();
            if spec.name == self.frames.split {
                let here: Vec<usize> = match full {
                    true => self
                        .by_name
                        .get(frame_name(&fields).as_str())
                        .into_iter()
                        .copied()
                        .collect(),
                    false => (self.indices.entry(spec.name.clone()).or_default())
                        .lookup(self.frames.fields.iter().copied(), &fields)
                        .to_vec(),
                };
                for i in here {
                    let name = format!("{} ({})", self.frames.names[i], spec.name);
                    push(Some(i), name, self.frames.rgb[i].to_path_buf());
                }
                continue;
            }
            if full {
                let rgb = spec.rgb.path(&fields);
                if rgb.is_file() {
                    push(
                        None,
                        format!("{} ({})", frame_name(&fields), spec.name),
                        rgb,
                    );
                }
                continue;
            }
            if !self.scans.contains_key(&spec.name) {
                let found = spec.rgb.find().map_err(|e| e.to_string())?;
                self.scans.insert(spec.name.clone(), found);
            }
            let scan = &self.scans[&spec.name];
            let index = self.indices.entry(spec.name.clone()).or_default();
            for &i in index.lookup(scan.iter().map(|(f, _)| f), &fields) {
                let (f, rgb) = &scan[i];
                let name = format!("{} ({})", frame_name(f), spec.name);
                push(None, name, rgb.clone());
            }
        }
        Ok(out)
    }
}
