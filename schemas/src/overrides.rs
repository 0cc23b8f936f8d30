//! `--set KEY.PATH=VALUE` overrides applied to the raw TOML before validation,
//! so an override is checked exactly like the file.
//!
//! Paths use dots for tables and `[i]` for array elements:
//! `output.end_time=0.2`, `particles[0].packing.seed=7`, `dem.time_step=1e-6`.
//! The value is parsed as a TOML value (`0.2`, `true`, `[1, 2, 3]`, `"text"`);
//! anything that does not parse is taken as a string.

use crate::error::SceneError;

enum Segment<'a> {
    Key(&'a str),
    Index(usize),
}

fn parse_path(path: &str) -> Result<Vec<Segment<'_>>, String> {
    let mut out = Vec::new();
    for part in path.split('.') {
        let (name, mut rest) = match part.find('[') {
            Some(i) => (&part[..i], &part[i..]),
            None => (part, ""),
        };
        if name.is_empty() {
            return Err(format!("empty key in path {path:?}"));
        }
        out.push(Segment::Key(name));
        while !rest.is_empty() {
            let close = rest.find(']').ok_or_else(|| format!("unclosed '[' in {path:?}"))?;
            let idx: usize =
                rest[1..close].parse().map_err(|_| format!("bad index {:?} in {path:?}", &rest[1..close]))?;
            out.push(Segment::Index(idx));
            rest = &rest[close + 1..];
        }
    }
    Ok(out)
}

fn parse_value(text: &str) -> toml::Value {
    let wrapped = format!("v = {text}");
    match toml::from_str::<toml::Table>(&wrapped) {
        Ok(mut t) => t.remove("v").unwrap_or_else(|| toml::Value::String(text.to_string())),
        Err(_) => toml::Value::String(text.to_string()),
    }
}

/// Applies one `KEY.PATH=VALUE` to `root`. Missing tables on the path are
/// created (so a default section can be set); arrays must already hold the index.
pub fn apply_override(root: &mut toml::Value, assignment: &str) -> Result<(), SceneError> {
    let (path, value) = assignment
        .split_once('=')
        .ok_or_else(|| SceneError::new("--set", format!("expected KEY.PATH=VALUE, got {assignment:?}")))?;
    let path = path.trim();
    let segments = parse_path(path).map_err(|e| SceneError::new("--set", e))?;
    let mut cur = root;
    let last = segments.len() - 1;
    for (i, seg) in segments.iter().enumerate() {
        let is_last = i == last;
        cur = match seg {
            Segment::Key(k) => {
                let table = cur
                    .as_table_mut()
                    .ok_or_else(|| SceneError::new(path, format!("cannot set {k:?}: its parent is not a table")))?;
                if is_last {
                    table.insert((*k).to_string(), parse_value(value.trim()));
                    return Ok(());
                }
                table.entry((*k).to_string()).or_insert_with(|| toml::Value::Table(Default::default()))
            }
            Segment::Index(idx) => {
                let arr = cur
                    .as_array_mut()
                    .ok_or_else(|| SceneError::new(path, format!("cannot index [{idx}]: not an array")))?;
                let len = arr.len();
                let slot = arr.get_mut(*idx).ok_or_else(|| {
                    SceneError::new(path, format!("index [{idx}] out of range: the array has {len} elements"))
                })?;
                if is_last {
                    *slot = parse_value(value.trim());
                    return Ok(());
                }
                slot
            }
        };
    }
    Ok(())
}
