//! The INI-like headers of phoenix `.pcr` and VGStudio `.vgi` files.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use crate::ct::error::io_err;
use crate::ct::{CtError, Result};

/// A parsed INI-like header: `[section]` then `key = value`; names are case-insensitive.
pub(super) struct Ini {
    path: PathBuf,
    /// (section, key) → value, lower-case names.
    entries: HashMap<(String, String), String>,
}

impl Ini {
    pub(super) fn read(path: &Path) -> Result<Self> {
        // A header of a few KB: a regular file of at most 1 MiB.
        let bytes = crate::fsutil::read_bounded(path, 1 << 20).map_err(io_err(path))?;
        // Headers written on Windows may be Latin-1: accept any bytes.
        let text = String::from_utf8_lossy(&bytes);
        let mut section = String::new();
        let mut entries = HashMap::new();
        for line in text.lines() {
            let line = line.trim();
            if line.is_empty() || line.starts_with(';') || line.starts_with('#') {
                continue;
            }
            if line.starts_with('[') && line.ends_with(']') {
                section = line[1..line.len() - 1].trim().to_ascii_lowercase();
                continue;
            }
            if line.starts_with('{') {
                // VGStudio `{volume1}` blocks: the sections below are what matter.
                continue;
            }
            if let Some((k, v)) = line.split_once('=') {
                entries
                    .entry((section.clone(), k.trim().to_ascii_lowercase()))
                    .or_insert_with(|| v.trim().to_string());
            }
        }
        Ok(Self {
            path: path.to_path_buf(),
            entries,
        })
    }

    pub(super) fn get(&self, section: &str, key: &str) -> Option<&str> {
        self.entries
            .get(&(section.to_string(), key.to_ascii_lowercase()))
            .map(String::as_str)
    }

    /// The key in `section`, or in any section when it moved between software versions.
    fn get_any(&self, section: &str, key: &str) -> Option<&str> {
        self.get(section, key).or_else(|| {
            let key = key.to_ascii_lowercase();
            let mut hits: Vec<_> = self
                .entries
                .iter()
                .filter(|((_, k), _)| *k == key)
                .collect();
            hits.sort_by(|a, b| a.0.cmp(b.0));
            hits.first().map(|(_, v)| v.as_str())
        })
    }

    pub(super) fn require(&self, section: &str, key: &str) -> Result<&str> {
        self.get_any(section, key)
            .ok_or_else(|| CtError::MissingKey {
                path: self.path.clone(),
                section: section.to_string(),
                key: key.to_string(),
            })
    }

    pub(super) fn bad(&self, key: &str, value: &str, reason: &str) -> CtError {
        CtError::BadValue {
            path: self.path.clone(),
            key: key.to_string(),
            value: value.to_string(),
            reason: reason.to_string(),
        }
    }

    pub(super) fn number<T: std::str::FromStr>(&self, section: &str, key: &str) -> Result<T> {
        let v = self.require(section, key)?;
        v.parse().map_err(|_| self.bad(key, v, "not a number"))
    }

    pub(super) fn numbers(&self, section: &str, key: &str, n: usize) -> Result<Vec<f64>> {
        let v = self.require(section, key)?;
        let xs: Vec<f64> = v
            .split_whitespace()
            .map(str::parse)
            .collect::<std::result::Result<_, _>>()
            .map_err(|_| self.bad(key, v, "not a list of numbers"))?;
        if xs.len() < n {
            return Err(self.bad(key, v, &format!("expected {n} numbers")));
        }
        Ok(xs)
    }
}
