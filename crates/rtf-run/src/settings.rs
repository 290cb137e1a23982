//! A configuration document as the settings it records: one `a.b.c = value` row per scalar
//! leaf, for people to read and compare (the typed configuration: [`crate::RunFolder::config`]).

use serde_json::Value;

/// Lists longer than this are summarised as `[N items]`.
const LONGEST_LIST: usize = 8;

/// The scalar leaves of `value` under `prefix` as (`a.b.c`, JSON text) rows, in key order;
/// `null` leaves are left out and lists of more than [`LONGEST_LIST`] items summarised.
pub(crate) fn flatten(prefix: &str, value: &Value, out: &mut Vec<(String, String)>) {
    match value {
        Value::Object(map) => {
            for (k, v) in map {
                let key = if prefix.is_empty() {
                    k.clone()
                } else {
                    format!("{prefix}.{k}")
                };
                flatten(&key, v, out);
            }
        }
        Value::Array(items) if items.len() > LONGEST_LIST => {
            out.push((prefix.into(), format!("[{} items]", items.len())))
        }
        Value::Null => {}
        other => out.push((prefix.into(), other.to_string())),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn leaves_become_rows_in_key_order() {
        let doc = serde_json::json!({"b": {"y": "s", "x": [1, 2]}, "a": null, "c": 0.01,
            "long": [0, 1, 2, 3, 4, 5, 6, 7, 8]});
        let mut rows = Vec::new();
        flatten("", &doc, &mut rows);
        let rows: Vec<(&str, &str)> = rows.iter().map(|(k, v)| (&k[..], &v[..])).collect();
        assert_eq!(
            rows,
            [
                ("b.x", "[1,2]"),
                ("b.y", "\"s\""),
                ("c", "0.01"),
                ("long", "[9 items]")
            ]
        );
    }
}
