//! Scene errors that name the key and the reason.

use std::fmt;

/// One or more problems found in a scene, each tied to its key path
/// (`dem.friction`, `particles[0].packing.region`).
#[derive(Debug, Clone, PartialEq)]
pub struct SceneError {
    pub problems: Vec<(String, String)>,
}

impl SceneError {
    pub fn new(key: impl Into<String>, reason: impl Into<String>) -> Self {
        Self { problems: vec![(key.into(), reason.into())] }
    }

    pub fn many(problems: Vec<(String, String)>) -> Self {
        Self { problems }
    }

    /// True if any problem is about `key` (exact match).
    pub fn names_key(&self, key: &str) -> bool {
        self.problems.iter().any(|(k, _)| k == key)
    }
}

impl fmt::Display for SceneError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for (i, (key, reason)) in self.problems.iter().enumerate() {
            if i > 0 {
                writeln!(f)?;
            }
            if key.is_empty() {
                write!(f, "{reason}")?;
            } else {
                write!(f, "{key}: {reason}")?;
            }
        }
        Ok(())
    }
}

impl std::error::Error for SceneError {}
