//! The one error every bowden configuration loader returns: which file (or other origin, e.g.
//! "the shipped plant"), which field, and why. Each crate validates its own schema; they share
//! this type so a caller (the CLI, a launcher, a test) handles a bad config one way whatever
//! loaded it.

use std::fmt::Display;

/// A configuration that could not be used, naming where it came from and, once it parsed, the
/// field.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    /// The file could not be read.
    #[error("{origin}: cannot read: {source}")]
    Io {
        origin: String,
        #[source]
        source: std::io::Error,
    },
    /// The text is not this schema's TOML: a syntax error, an unknown or missing field, a value
    /// of the wrong type.
    #[error("{origin}: malformed TOML: {message}")]
    Parse { origin: String, message: String },
    /// A field parsed, but its value cannot be used.
    #[error("{origin}: field `{field}`: {problem}")]
    Invalid {
        origin: String,
        field: String,
        problem: String,
    },
}

impl ConfigError {
    /// The file at `origin` could not be read.
    pub fn io(origin: impl Display, source: std::io::Error) -> Self {
        Self::Io {
            origin: origin.to_string(),
            source,
        }
    }

    /// The text from `origin` did not parse; `message` is the parser's, on one line.
    pub fn parse(origin: impl Display, message: impl Display) -> Self {
        Self::Parse {
            origin: origin.to_string(),
            message: message.to_string().trim().replace('\n', " "),
        }
    }

    /// `field` of the config from `origin` parsed, but `problem` makes it unusable.
    pub fn invalid(origin: impl Display, field: impl Into<String>, problem: impl Into<String>) -> Self {
        Self::Invalid {
            origin: origin.to_string(),
            field: field.into(),
            problem: problem.into(),
        }
    }

    /// Where the config came from (a path, or e.g. "the shipped plant").
    pub fn origin(&self) -> &str {
        match self {
            Self::Io { origin, .. } | Self::Parse { origin, .. } | Self::Invalid { origin, .. } => origin,
        }
    }

    /// The field at fault, once the text parsed.
    pub fn field(&self) -> Option<&str> {
        match self {
            Self::Invalid { field, .. } => Some(field),
            _ => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn messages_name_origin_field_and_problem() {
        let e = ConfigError::invalid("configs/x.toml", "dt_ms", "must be positive, got -1");
        assert_eq!(e.to_string(), "configs/x.toml: field `dt_ms`: must be positive, got -1");
        assert_eq!(e.field(), Some("dt_ms"));
        assert_eq!(e.origin(), "configs/x.toml");
        let p = ConfigError::parse("a.toml", "  expected `=`\n  at line 3\n");
        assert_eq!(p.to_string(), "a.toml: malformed TOML: expected `=`   at line 3");
        assert_eq!(p.field(), None);
        let io = ConfigError::io("/nonexistent.toml", std::io::Error::from(std::io::ErrorKind::NotFound));
        assert!(io.to_string().starts_with("/nonexistent.toml: cannot read: "), "{io}");
        assert!(
            std::error::Error::source(&io).is_some(),
            "the io error stays the source"
        );
    }
}
