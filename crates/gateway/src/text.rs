//! How a user's text is shown back in messages, logs and the audit trail, and how counts are
//! written.

/// A count with its noun in the right number: `count(1, "bus", "buses")` is `1 bus`,
/// `count(2, "bus", "buses")` is `2 buses` (and `0 buses`). Every count printed goes through it.
pub fn count(n: usize, one: &str, many: &str) -> String {
    format!("{n} {}", if n == 1 { one } else { many })
}

/// The first `max` characters of `text` to show in a message, and `"..."` when it was cut.
pub fn cut(text: &str, max: usize) -> (&str, &'static str) {
    match text.char_indices().nth(max) {
        Some((at, _)) => (&text[..at], "..."),
        None => (text, ""),
    }
}

/// Most characters of a user value shown by [`shown`].
pub const SHOWN_CHARS: usize = 64;

/// A user value as shown in an error, a log line or an audit record: as it is when it has at
/// most [`SHOWN_CHARS`] characters, else its first ones and `…(N bytes)` with its full length.
pub fn shown(text: &str) -> String {
    shown_max(text, SHOWN_CHARS)
}

/// [`shown`] with at most `max` characters kept (for whole messages that quote a user value).
pub fn shown_max(text: &str, max: usize) -> String {
    match text.char_indices().nth(max) {
        Some((at, _)) => format!("{}…({} bytes)", &text[..at], text.len()),
        None => text.to_string(),
    }
}

/// A number of a user as shown in a message or the audit trail: as Rust writes it when that is
/// short (`40`, `40.5`), in exponent notation otherwise (`1e308`, not 309 digits).
pub fn number(x: f64) -> String {
    let plain = x.to_string();
    if plain.len() <= 16 {
        plain
    } else {
        format!("{x:e}")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn long_values_are_cut_with_their_length() {
        assert_eq!(shown("40"), "40");
        let long = "9".repeat(309);
        assert_eq!(shown(&long), format!("{}…(309 bytes)", "9".repeat(64)));
        let wide = "é".repeat(100);
        assert_eq!(shown(&wide), format!("{}…(200 bytes)", "é".repeat(64)));
        assert_eq!(shown_max("abcdef", 3), "abc…(6 bytes)");
        assert_eq!(number(40.0), "40");
        assert_eq!(number(40.25), "40.25");
        assert_eq!(number(1e308), "1e308");
        assert_eq!(number(-1.5e-300), "-1.5e-300");
        assert_eq!(cut("abcdef", 3), ("abc", "..."));
        assert_eq!(cut("abc", 3), ("abc", ""));
    }

    #[test]
    fn counts_say_one_in_the_singular() {
        assert_eq!(count(1, "bus", "buses"), "1 bus");
        assert_eq!(count(2, "bus", "buses"), "2 buses");
        assert_eq!(count(0, "drive", "drives"), "0 drives");
    }
}
