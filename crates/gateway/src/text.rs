//! How a user's text is shown back in messages, logs and the audit trail.

/// The first `max` characters of `text` to show in a message, and `"..."` when it was cut.
pub fn cut(text: &str, max: usize) -> (&str, &'static str) {
    match text.char_indices().nth(max) {
        Some((at, _)) => (&text[..at], "..."),
        None => (text, ""),
    }
}
