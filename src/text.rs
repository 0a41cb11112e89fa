//! Text from files and arguments made safe to print: control characters (ESC, CR, BEL,
//! backspace, the C1 range, bidi overrides) would let a file clear the screen, move the
//! cursor or fake a line of output, so they are shown escaped (`\u{1b}`) instead.

/// Longest piece of user text echoed in a message; the rest is elided (a 110 KB spec in an
/// error line helps no one).
pub const MAX_ECHO_CHARS: usize = 200;

/// `s` with every control or bidi-formatting character escaped; tabs are kept.
pub fn sanitize(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for c in s.chars() {
        if is_unsafe(c) {
            out.extend(c.escape_unicode());
        } else {
            out.push(c);
        }
    }
    out
}

/// Like [`sanitize`], cut to [`MAX_ECHO_CHARS`] characters with the count of the rest.
pub fn sanitize_short(s: &str) -> String {
    let n = s.chars().count();
    if n <= MAX_ECHO_CHARS {
        return sanitize(s);
    }
    let head: String = s.chars().take(MAX_ECHO_CHARS).collect();
    format!(
        "{}… ({} more characters)",
        sanitize(&head),
        n - MAX_ECHO_CHARS
    )
}

/// Longest error line printed, in characters.
pub const MAX_LINE_CHARS: usize = 2000;

/// An error message for one stderr line: sanitized, and cut to [`MAX_LINE_CHARS`].
pub fn sanitize_line(s: &str) -> String {
    let n = s.chars().count();
    if n <= MAX_LINE_CHARS {
        return sanitize(s);
    }
    let head: String = s.chars().take(MAX_LINE_CHARS).collect();
    format!(
        "{}… ({} more characters)",
        sanitize(&head),
        n - MAX_LINE_CHARS
    )
}

/// Refuses JSON with a repeated key in any object: serde keeps the last silently, so
/// `{"albedo":0.5,"albedo":0.9}` would mean 0.9 without a word. The message names the key.
pub fn reject_duplicate_json_keys(json: &[u8]) -> Result<(), String> {
    use serde::de::{Deserializer, MapAccess, SeqAccess, Visitor};
    struct Check;
    impl<'de> serde::Deserialize<'de> for Check {
        fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
            d.deserialize_any(CheckVisitor)
        }
    }
    struct CheckVisitor;
    impl<'de> Visitor<'de> for CheckVisitor {
        type Value = Check;
        fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
            f.write_str("JSON")
        }
        fn visit_map<A: MapAccess<'de>>(self, mut m: A) -> Result<Check, A::Error> {
            let mut seen = std::collections::HashSet::new();
            while let Some(k) = m.next_key::<String>()? {
                m.next_value::<Check>()?;
                if !seen.insert(k.clone()) {
                    return Err(serde::de::Error::custom(format!(
                        "key {:?} appears twice in one object",
                        sanitize_short(&k)
                    )));
                }
            }
            Ok(Check)
        }
        fn visit_seq<A: SeqAccess<'de>>(self, mut s: A) -> Result<Check, A::Error> {
            while s.next_element::<Check>()?.is_some() {}
            Ok(Check)
        }
        fn visit_bool<E>(self, _: bool) -> Result<Check, E> {
            Ok(Check)
        }
        fn visit_i64<E>(self, _: i64) -> Result<Check, E> {
            Ok(Check)
        }
        fn visit_u64<E>(self, _: u64) -> Result<Check, E> {
            Ok(Check)
        }
        fn visit_f64<E>(self, _: f64) -> Result<Check, E> {
            Ok(Check)
        }
        fn visit_str<E>(self, _: &str) -> Result<Check, E> {
            Ok(Check)
        }
        fn visit_unit<E>(self) -> Result<Check, E> {
            Ok(Check)
        }
        fn visit_none<E>(self) -> Result<Check, E> {
            Ok(Check)
        }
    }
    // Syntax errors are left to the real parse, which reports them with its own context.
    match serde_json::from_slice::<Check>(json) {
        Err(e) if e.is_data() => Err(e.to_string()),
        _ => Ok(()),
    }
}

fn is_unsafe(c: char) -> bool {
    (c.is_control() && c != '\t')
        || matches!(c, '\u{200e}' | '\u{200f}' | '\u{202a}'..='\u{202e}' | '\u{2066}'..='\u{2069}')
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn escapes_terminal_controls_and_keeps_text() {
        assert_eq!(sanitize("a\x1b[2Jb"), "a\\u{1b}[2Jb");
        assert_eq!(sanitize("ok\r\n"), "ok\\u{d}\\u{a}");
        assert_eq!(sanitize("θ\tφ"), "θ\tφ");
        assert_eq!(sanitize("\u{202e}x"), "\\u{202e}x");
    }

    #[test]
    fn long_text_is_cut_with_a_count() {
        let s = "x".repeat(MAX_ECHO_CHARS + 5);
        assert!(sanitize_short(&s).ends_with("(5 more characters)"));
    }
}
