//! glTF JSON read under a budget, so what a document costs in memory is bounded before
//! it is allocated.
//!
//! A `serde_json::Value` costs 30-100 bytes per JSON value whatever the value's own size,
//! so a 60 MB JSON chunk of tiny values (a million accessors, a 24-million-element
//! `extras` array) became gigabytes of tree. Here every value is counted as it is read
//! and the read stops at [`MAX_VALUES`]; strings other than URIs (which hold embedded
//! buffers and images, bounded by the upload limit) stop at [`MAX_STRING`]; an `extras`
//! member (application data the glTF spec lets a reader ignore) is kept only when its
//! text is at most [`MAX_EXTRAS`] bytes and otherwise dropped unread.

use super::MeshError;
use serde::de::{self, DeserializeSeed, MapAccess, SeqAccess, Visitor};
use serde_json::value::RawValue;
use serde_json::{Map, Value};
use std::cell::Cell;
use std::fmt;

/// JSON values a document may hold: far over what real files need (a 20,000-node scene
/// with matrices and a hundred animations is about a million), and at most a few
/// hundred megabytes of tree.
pub const MAX_VALUES: usize = 2_000_000;
/// Longest string other than a `uri`: names and the like.
pub const MAX_STRING: usize = 1 << 20;
/// Largest `extras` member kept, as JSON text; larger ones are dropped.
pub const MAX_EXTRAS: usize = 64 << 10;

/// Why a read stopped; kept beside serde's error so the caller gets a typed fault.
#[derive(Clone, Copy)]
enum Stop {
    Values,
    String(usize),
}

struct Budget {
    values: Cell<usize>,
    stop: Cell<Option<Stop>>,
}

impl Budget {
    fn take<E: de::Error>(&self) -> Result<(), E> {
        let n = self.values.get() + 1;
        self.values.set(n);
        if n > MAX_VALUES {
            self.stop.set(Some(Stop::Values));
            return Err(E::custom("too many values"));
        }
        Ok(())
    }

    fn string<E: de::Error>(&self, len: usize, uri: bool) -> Result<(), E> {
        if !uri && len > MAX_STRING {
            self.stop.set(Some(Stop::String(len)));
            return Err(E::custom("string too long"));
        }
        Ok(())
    }
}

/// Parses `bytes` as a JSON document within the budget above.
pub fn parse(bytes: &[u8]) -> Result<Value, MeshError> {
    let budget = Budget {
        values: Cell::new(0),
        stop: Cell::new(None),
    };
    let mut de = serde_json::Deserializer::from_slice(bytes);
    let parsed = Node {
        budget: &budget,
        uri: false,
    }
    .deserialize(&mut de)
    .and_then(|v| de.end().map(|_| v));
    parsed.map_err(|e| match budget.stop.get() {
        Some(Stop::Values) => MeshError::JsonTooComplex { cap: MAX_VALUES },
        Some(Stop::String(len)) => MeshError::StringTooLong {
            len,
            cap: MAX_STRING,
        },
        None => MeshError::Json(e.to_string()),
    })
}

/// One JSON value; `uri` when it is the value of a `uri` member.
#[derive(Clone, Copy)]
struct Node<'b> {
    budget: &'b Budget,
    uri: bool,
}

impl<'de> DeserializeSeed<'de> for Node<'_> {
    type Value = Value;

    fn deserialize<D: de::Deserializer<'de>>(self, d: D) -> Result<Value, D::Error> {
        d.deserialize_any(self)
    }
}

impl<'de> Visitor<'de> for Node<'_> {
    type Value = Value;

    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        f.write_str("a JSON value")
    }

    fn visit_bool<E: de::Error>(self, v: bool) -> Result<Value, E> {
        self.budget.take()?;
        Ok(Value::Bool(v))
    }

    fn visit_i64<E: de::Error>(self, v: i64) -> Result<Value, E> {
        self.budget.take()?;
        Ok(Value::from(v))
    }

    fn visit_u64<E: de::Error>(self, v: u64) -> Result<Value, E> {
        self.budget.take()?;
        Ok(Value::from(v))
    }

    fn visit_f64<E: de::Error>(self, v: f64) -> Result<Value, E> {
        self.budget.take()?;
        // JSON has no NaN or infinity, so a parsed float is always finite.
        Ok(serde_json::Number::from_f64(v).map_or(Value::Null, Value::Number))
    }

    fn visit_str<E: de::Error>(self, v: &str) -> Result<Value, E> {
        self.budget.take()?;
        self.budget.string(v.len(), self.uri)?;
        Ok(Value::String(v.to_owned()))
    }

    fn visit_string<E: de::Error>(self, v: String) -> Result<Value, E> {
        self.budget.take()?;
        self.budget.string(v.len(), self.uri)?;
        Ok(Value::String(v))
    }

    fn visit_unit<E: de::Error>(self) -> Result<Value, E> {
        self.budget.take()?;
        Ok(Value::Null)
    }

    fn visit_none<E: de::Error>(self) -> Result<Value, E> {
        self.visit_unit()
    }

    fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<Value, A::Error> {
        self.budget.take()?;
        let mut out = Vec::new();
        let item = Node {
            budget: self.budget,
            uri: false,
        };
        while let Some(v) = seq.next_element_seed(item)? {
            out.push(v);
        }
        Ok(Value::Array(out))
    }

    fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> Result<Value, A::Error> {
        self.budget.take()?;
        let mut out = Map::new();
        while let Some(key) = map.next_key_seed(Key(self.budget))? {
            if key == "extras" {
                // Borrowed from the input, so skipping a huge one allocates nothing.
                let raw: &RawValue = map.next_value()?;
                if raw.get().len() <= MAX_EXTRAS {
                    let mut de = serde_json::Deserializer::from_str(raw.get());
                    let v = Node {
                        budget: self.budget,
                        uri: false,
                    }
                    .deserialize(&mut de)
                    .map_err(de::Error::custom)?;
                    out.insert(key, v);
                }
                continue;
            }
            let v = map.next_value_seed(Node {
                budget: self.budget,
                uri: key == "uri",
            })?;
            out.insert(key, v);
        }
        Ok(Value::Object(out))
    }
}

/// A member name, held to the string budget before it is copied.
struct Key<'b>(&'b Budget);

impl<'de> DeserializeSeed<'de> for Key<'_> {
    type Value = String;

    fn deserialize<D: de::Deserializer<'de>>(self, d: D) -> Result<String, D::Error> {
        d.deserialize_str(self)
    }
}

impl<'de> Visitor<'de> for Key<'_> {
    type Value = String;

    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        f.write_str("a member name")
    }

    fn visit_str<E: de::Error>(self, v: &str) -> Result<String, E> {
        self.0.string(v.len(), false)?;
        Ok(v.to_owned())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_what_serde_json_reads() {
        let text = r#"{"asset":{"version":"2.0"},"a":[1,-2,3.5,true,null,"x"],"b":{"c":{}}}"#;
        let want: Value = serde_json::from_str(text).unwrap();
        assert_eq!(parse(text.as_bytes()).unwrap(), want);
    }

    #[test]
    fn small_extras_stay_and_large_ones_are_dropped_unread() {
        let small = r#"{"nodes":[{"name":"n","extras":{"k":[1,2]}}]}"#;
        let v = parse(small.as_bytes()).unwrap();
        assert_eq!(v["nodes"][0]["extras"]["k"][1], 2);
        let big = format!(
            r#"{{"extras":[{}],"asset":{{"version":"2.0"}}}}"#,
            vec!["0"; MAX_VALUES + 10].join(",")
        );
        let v = parse(big.as_bytes()).unwrap();
        assert!(v.get("extras").is_none());
        assert_eq!(v["asset"]["version"], "2.0");
    }

    #[test]
    fn too_many_values_and_long_strings_are_typed_faults() {
        let many = format!("[{}]", vec!["0"; MAX_VALUES + 1].join(","));
        assert_eq!(
            parse(many.as_bytes()),
            Err(MeshError::JsonTooComplex { cap: MAX_VALUES })
        );
        let long = format!(r#"{{"name":"{}"}}"#, "a".repeat(MAX_STRING + 1));
        assert!(matches!(
            parse(long.as_bytes()),
            Err(MeshError::StringTooLong { .. })
        ));
        let key = format!(r#"{{"{}":1}}"#, "k".repeat(MAX_STRING + 1));
        assert!(matches!(
            parse(key.as_bytes()),
            Err(MeshError::StringTooLong { .. })
        ));
        // A data URI may be as long as the upload allows.
        let uri = format!(r#"{{"uri":"{}"}}"#, "a".repeat(MAX_STRING + 1));
        assert!(parse(uri.as_bytes()).is_ok());
        assert!(matches!(parse(b"{\"a\":1"), Err(MeshError::Json(_))));
        assert!(matches!(parse(b"{} x"), Err(MeshError::Json(_))));
    }
}
