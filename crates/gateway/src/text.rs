//! How a user's text is shown back in messages, logs and the audit trail.

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
    match text.char_indices().nth(SHOWN_CHARS) {
        Some((at, _)) => format!("{}…({} bytes)", &text[..at], text.len()),
        None => text.to_string(),
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
        assert_eq!(cut("abcdef", 3), ("abc", "..."));
        assert_eq!(cut("abc", 3), ("abc", ""));
    }
}
