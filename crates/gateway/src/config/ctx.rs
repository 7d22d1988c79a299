//! The file being read: a position's line and field for the errors, and the checks several
//! sections make (a listener's address, a count of 1 or more, a number in a range, user name
//! and password).

use std::fmt;
use std::net::SocketAddr;
use std::ops::{Range, RangeInclusive};

use toml::Spanned;

use super::ConfigError;

/// The file being read, for errors that name its line and field.
pub(super) struct Ctx<'a> {
    /// The file's name as errors give it.
    pub(super) file: &'a str,
    /// Its text.
    pub(super) text: &'a str,
}

impl Ctx<'_> {
    /// The line (from 1) of the position at `span`.
    fn line(&self, span: Range<usize>) -> usize {
        self.text[..span.start.min(self.text.len())].lines().count().max(1)
            + usize::from(self.text[..span.start.min(self.text.len())].ends_with('\n'))
    }

    /// `file:line: field `field`: msg`.
    pub(super) fn err<T>(
        &self,
        span: Range<usize>,
        field: &str,
        msg: impl fmt::Display,
    ) -> Result<T, ConfigError> {
        Err(ConfigError(format!("{}:{}: field `{field}`: {msg}", self.file, self.line(span))))
    }

    /// A file TOML could not read as the schema ([`super::file`]): one line naming the place,
    /// and the field where the position is at a `key = value` line.
    pub(super) fn toml_error(&self, e: &toml::de::Error) -> ConfigError {
        // toml's messages may take several lines: one line here ("invalid table header:
        // duplicate key `modbus` in document root").
        let msg = e.message().trim().lines().map(str::trim).collect::<Vec<_>>().join(": ");
        let file = self.file;
        match e.span() {
            // A value of the wrong type or range: name its field as the other checks do.
            Some(s) => match self.field_at(s.clone()) {
                Some(field) => ConfigError(format!("{file}:{}: field `{field}`: {msg}", self.line(s))),
                None => ConfigError(format!("{file}:{}: {msg}", self.line(s))),
            },
            None => ConfigError(format!("{file}: {msg}")),
        }
    }

    /// The field a value at `span` belongs to (`bus.drive.address`): the key before `=` on its
    /// line, under the last table header above it. `None` when the span is not at a `key =
    /// value` line (a header, a syntax error).
    fn field_at(&self, span: Range<usize>) -> Option<String> {
        let start = span.start.min(self.text.len());
        let line_start = self.text[..start].rfind('\n').map_or(0, |i| i + 1);
        let line_end = self.text[start..].find('\n').map_or(self.text.len(), |i| start + i);
        let (key, _) = self.text[line_start..line_end].split_once('=')?;
        let key = key.trim().trim_matches('"');
        if key.is_empty() || key.starts_with('[') || key.starts_with('#') {
            return None;
        }
        let table = self.text[..line_start]
            .lines()
            .rev()
            .map(str::trim)
            .find(|l| l.starts_with('['))
            .map(|h| h.trim_matches(|c| c == '[' || c == ']').trim().to_string());
        Some(match table {
            Some(t) if !t.is_empty() => format!("{t}.{key}"),
            _ => key.to_string(),
        })
    }

    /// A `HOST:PORT` value; the error gives `example`.
    pub(super) fn addr(
        &self,
        s: &Spanned<String>,
        field: &str,
        example: &str,
    ) -> Result<SocketAddr, ConfigError> {
        s.get_ref().parse().or_else(|_| {
            self.err(s.span(), field, format!("{:?} is not HOST:PORT (e.g. {example})", s.get_ref()))
        })
    }

    /// A listener's `HOST:PORT` (`default` when not given).
    pub(super) fn listener(
        &self,
        s: &Option<Spanned<String>>,
        field: &str,
        default: &str,
    ) -> Result<SocketAddr, ConfigError> {
        match s {
            None => Ok(default.parse().expect("default listener")),
            Some(s) => self.addr(s, field, "127.0.0.1:8080"),
        }
    }

    /// A count of 1 or more (`default` when not given).
    pub(super) fn at_least_one(
        &self,
        v: &Option<Spanned<usize>>,
        field: &str,
        default: usize,
    ) -> Result<usize, ConfigError> {
        match v {
            Some(n) if *n.get_ref() == 0 => self.err(n.span(), field, "use 1 or more"),
            Some(n) => Ok(*n.get_ref()),
            None => Ok(default),
        }
    }

    /// A number within `range` (`default` when not given); the error gives the range and `unit`.
    pub(super) fn within<T: Copy + PartialOrd + fmt::Display>(
        &self,
        v: &Option<Spanned<T>>,
        range: RangeInclusive<T>,
        field: &str,
        unit: &str,
        default: T,
    ) -> Result<T, ConfigError> {
        match v {
            Some(n) if !range.contains(n.get_ref()) => self.err(
                n.span(),
                field,
                format!("{} is outside {}..{}{unit}", n.get_ref(), range.start(), range.end()),
            ),
            Some(n) => Ok(*n.get_ref()),
            None => Ok(default),
        }
    }

    /// User name and password of section `section` (`mqtt`, `sparkplug`): both or neither; the
    /// password as written or from the environment variable `password_env`.
    pub(super) fn credentials(
        &self,
        section: &str,
        at: Range<usize>,
        username: &Option<Spanned<String>>,
        password: &Option<Spanned<String>>,
        password_env: &Option<Spanned<String>>,
    ) -> Result<Option<(String, String)>, ConfigError> {
        let password = match (password, password_env) {
            (Some(p), None) => Some(p.get_ref().clone()),
            (None, Some(var)) => Some(std::env::var(var.get_ref()).or_else(|_| {
                self.err(
                    var.span(),
                    &format!("{section}.password_env"),
                    format!("the environment variable {:?} is not set", var.get_ref()),
                )
            })?),
            (Some(p), Some(_)) => {
                return self.err(
                    p.span(),
                    &format!("{section}.password"),
                    "give password or password_env, not both",
                )
            }
            (None, None) => None,
        };
        match (username, password) {
            (Some(u), Some(p)) => Ok(Some((u.get_ref().clone(), p))),
            (None, None) => Ok(None),
            (Some(u), None) => self.err(
                u.span(),
                &format!("{section}.username"),
                "give a password (or password_env) with the user name",
            ),
            (None, Some(_)) => self.err(at, &format!("{section}.username"), "a password needs a user name"),
        }
    }
}
