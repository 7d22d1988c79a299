//! JSON from users: a document with a key twice in one object (`{"hz":40,"hz":41}`) is
//! refused, since which of the two a reader takes differs from one parser to the next.

use std::collections::HashSet;
use std::fmt;

use serde::de::{DeserializeSeed, Error as _, MapAccess, SeqAccess, Visitor};
use serde::Deserializer;

/// Checks that no object of the JSON document `bytes` has a key twice; the error is serde_json's
/// (a syntax error, or `duplicate key "hz"` at its line and column).
pub fn check_unique_keys(bytes: &[u8]) -> Result<(), serde_json::Error> {
    let mut de = serde_json::Deserializer::from_slice(bytes);
    Unique.deserialize(&mut de)?;
    de.end()
}

/// Walks a value, refusing repeated keys at every depth.
#[derive(Clone, Copy)]
struct Unique;

impl<'de> DeserializeSeed<'de> for Unique {
    type Value = ();

    fn deserialize<D: Deserializer<'de>>(self, d: D) -> Result<(), D::Error> {
        d.deserialize_any(self)
    }
}

impl<'de> Visitor<'de> for Unique {
    type Value = ();

    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        f.write_str("JSON")
    }

    fn visit_bool<E>(self, _: bool) -> Result<(), E> {
        Ok(())
    }

    fn visit_i64<E>(self, _: i64) -> Result<(), E> {
        Ok(())
    }

    fn visit_u64<E>(self, _: u64) -> Result<(), E> {
        Ok(())
    }

    fn visit_f64<E>(self, _: f64) -> Result<(), E> {
        Ok(())
    }

    fn visit_str<E>(self, _: &str) -> Result<(), E> {
        Ok(())
    }

    fn visit_unit<E>(self) -> Result<(), E> {
        Ok(())
    }

    fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<(), A::Error> {
        while seq.next_element_seed(Unique)?.is_some() {}
        Ok(())
    }

    fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> Result<(), A::Error> {
        let mut seen = HashSet::new();
        while let Some(key) = map.next_key::<String>()? {
            if !seen.insert(key.clone()) {
                return Err(A::Error::custom(format!(
                    "duplicate key {:?}: give each key once",
                    crate::text::shown(&key)
                )));
            }
            map.next_value_seed(Unique)?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn repeated_keys_are_refused_at_every_depth() {
        assert!(check_unique_keys(br#"{"hz": 40}"#).is_ok());
        assert!(check_unique_keys(br#"[{"a": 1}, {"a": 2}, 3, "x", null, true]"#).is_ok());
        let e = check_unique_keys(br#"{"hz":40,"hz":41}"#).unwrap_err();
        assert_eq!(e.classify(), serde_json::error::Category::Data);
        assert!(e.to_string().starts_with("duplicate key \"hz\": give each key once"), "{e}");
        assert!(check_unique_keys(br#"{"value": {"a": 1, "a": 1}}"#).is_err());
        assert!(check_unique_keys(br#"[{"a": 1, "a": 1}]"#).is_err());
        assert_eq!(
            check_unique_keys(b"{\"hz\": 4").unwrap_err().classify(),
            serde_json::error::Category::Eof
        );
        assert!(check_unique_keys(b"{} x").is_err());
    }
}
