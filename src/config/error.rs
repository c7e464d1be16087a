//! What a configuration's checks say: one refusal shape, [`Invalid`], that names the key; and
//! [`ConfigError`], the refusal in its file (or the file unreadable).

use crate::fsutil::TomlFileError;
use std::path::{Path, PathBuf};

/// What made a value invalid, when another error did (a regular expression that does not compile).
pub type Cause = Box<dyn std::error::Error + Send + Sync + 'static>;

/// A value a section refuses: the key (`section.field`, `pacs[1].url`) and what is wrong with it.
/// Every section's `validate` returns this; [`Config::parse`] adds the file ([`Invalid::in_file`]).
#[derive(Debug, thiserror::Error)]
#[error("key `{key}`: {message}")]
pub struct Invalid {
    pub key: String,
    /// What was expected, in our words (never the text of `source`).
    pub message: String,
    #[source]
    pub source: Option<Cause>,
}

impl Invalid {
    pub fn new(key: impl Into<String>, message: impl Into<String>) -> Invalid {
        Invalid {
            key: key.into(),
            message: message.into(),
            source: None,
        }
    }

    /// The same refusal, caused by `source`.
    pub fn because(mut self, source: impl Into<Cause>) -> Invalid {
        self.source = Some(source.into());
        self
    }

    /// The refusal of a value of `file`.
    pub fn in_file(self, file: &Path) -> ConfigError {
        ConfigError::Invalid {
            file: file.to_path_buf(),
            line: None,
            key: self.key,
            message: self.message,
            source: self.source,
        }
    }

    /// The refusal of a value of `file`, whose text is `text`: at the key's own line.
    pub fn in_text(self, file: &Path, text: &str) -> ConfigError {
        let line = crate::fsutil::key_line(text, &self.key).and_then(|l| u32::try_from(l).ok());
        let mut error = self.in_file(file);
        if let ConfigError::Invalid { line: at, .. } = &mut error {
            *at = line;
        }
        error
    }
}

/// A configuration that could not be used.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    /// Unreadable, or not TOML of the configuration's shape (the file, the line and column, the
    /// key and what was expected).
    #[error(transparent)]
    File(#[from] TomlFileError),
    /// A value that fails its section's check ([`Invalid`], in a file).
    #[error(
        "{file}: {}key `{key}`: {message}",
        .line.map(|l| format!("line {l}: ")).unwrap_or_default()
    )]
    Invalid {
        file: PathBuf,
        /// The key's own line, when the file holds it.
        /// (`u32`: the error stays small enough to return by value.)
        line: Option<u32>,
        key: String,
        message: String,
        #[source]
        source: Option<Cause>,
    },
}
