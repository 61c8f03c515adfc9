//! Strict JSON input, shared by every file the tool reads (specs, scenario
//! files, intervention files): duplicate keys, trailing data and an array
//! where an object belongs are errors, and every error names the JSON path
//! of the field. Imports nothing from the crate.
//!
//! Reading is two steps: [`parse`] turns text into a [`Value`] (rejecting
//! duplicate keys and trailing data), then [`from_value`] deserializes a type
//! from a value through a deserializer whose structs accept JSON objects only.

use serde::de::{self, DeserializeOwned, DeserializeSeed, IntoDeserializer, MapAccess, SeqAccess, Unexpected, Visitor};
use serde::Deserialize;
use serde_json::{Map, Number, Value};
use std::fmt;

/// A number as messages echo it: as written for everyday values, in
/// exponent form when plain digits would run long (`1e308`, not 309
/// digits; `1e-12`, not `0.000000000001`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Shown(pub f64);

impl fmt::Display for Shown {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let v = self.0;
        if v.is_finite() && v != 0.0 && !(1e-4..1e16).contains(&v.abs()) {
            write!(f, "{v:e}")
        } else {
            write!(f, "{v}")
        }
    }
}

/// A text value shown in a message: quoted as written, or when long, its
/// first 64 characters and its length (a 100 MB name was echoed whole in
/// a one-line error).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ShownText<'a>(pub &'a str);

impl fmt::Display for ShownText<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        const SHOWN: usize = 64;
        match self.0.char_indices().nth(SHOWN + 16) {
            None => write!(f, "{:?}", self.0),
            Some(_) => {
                let cut = self.0.char_indices().nth(SHOWN).map_or(self.0.len(), |(at, _)| at);
                write!(f, "{:?}... ({} characters)", &self.0[..cut], self.0.chars().count())
            }
        }
    }
}

/// A problem in a JSON document: the path of the field (`a.b[2].c`, empty
/// for the whole document) and what is wrong.
#[derive(Debug, Clone, PartialEq)]
pub struct JsonError {
    pub path: String,
    pub message: String,
}

impl JsonError {
    /// The path below `prefix`, e.g. `interventions[0]` + `when.car`.
    pub fn under(self, prefix: &str) -> JsonError {
        let path = match (prefix.is_empty(), self.path.is_empty()) {
            (true, _) => self.path,
            (false, true) => prefix.to_string(),
            (false, false) if self.path.starts_with('[') => format!("{prefix}{}", self.path),
            (false, false) => format!("{prefix}.{}", self.path),
        };
        JsonError { path, message: self.message }
    }
}

/// Parses `text` strictly and deserializes a `T` from it.
pub fn parse_strict<T: DeserializeOwned>(text: &str) -> Result<T, JsonError> {
    from_value(parse(text)?)
}

/// Parses `text` into a value: any valid JSON, but no key twice in an
/// object and nothing but whitespace after the document.
pub fn parse(text: &str) -> Result<Value, JsonError> {
    let mut de = serde_json::Deserializer::from_str(text);
    let value = serde_path_to_error::deserialize::<_, Unique>(&mut de).map_err(|e| {
        let path = format_path(e.path(), false);
        let inner = e.into_inner();
        let message =
            if inner.is_syntax() || inner.is_eof() { format!("not valid JSON: {inner}") } else { inner.to_string() };
        JsonError { path, message }
    })?;
    de.end().map_err(|e| JsonError {
        path: String::new(),
        message: format!("not valid JSON: {e} (after the end of the document)"),
    })?;
    Ok(value.0)
}

/// Deserializes a `T` from `value`: structs accept objects only, errors
/// carry the path of the field.
pub fn from_value<T: DeserializeOwned>(value: Value) -> Result<T, JsonError> {
    from_value_with(value, false)
}

/// As [`from_value`], but the path leaves out enum variants: for an
/// externally tagged enum built in code (`{TAG: {fields}}`) to read fields
/// that sit beside their tag in the file.
pub fn from_value_untagged_path<T: DeserializeOwned>(value: Value) -> Result<T, JsonError> {
    from_value_with(value, true)
}

fn from_value_with<T: DeserializeOwned>(value: Value, skip_variants: bool) -> Result<T, JsonError> {
    serde_path_to_error::deserialize(Strict(value)).map_err(|e| JsonError {
        path: format_path(e.path(), skip_variants),
        message: in_plain_words(&e.into_inner().to_string()),
    })
}

/// What a `null` is told where a value must stand (`"frames": null` was
/// "invalid type: null, expected a whole number").
const NULL_REFUSED: &str = "null is not a value here: give a value, or leave the field out for its default";

/// serde's "expected u32" and the like in the words of a JSON file: a
/// user wrote a number, a list or an object, not a Rust type.
pub(crate) fn in_plain_words(message: &str) -> String {
    if message.starts_with("invalid type: null,") {
        return NULL_REFUSED.to_string();
    }
    const WHOLE: [&str; 9] = ["u8", "u16", "u32", "u64", "usize", "i8", "i16", "i32", "i64"];
    let plain_type = |rust: &str| match rust {
        "f32" | "f64" => Some("a number"),
        "a sequence" => Some("a list"),
        _ if WHOLE.contains(&rust) => Some("a whole number"),
        _ => None,
    };
    // What was found, as JSON names it.
    let message = message.replacen("invalid type: sequence,", "invalid type: a list,", 1);
    let message = message.replacen("invalid type: map,", "invalid type: an object,", 1);
    match message.rsplit_once("expected ") {
        Some((before, rust)) => match plain_type(rust) {
            Some(words) => format!("{before}expected {words}"),
            None => message,
        },
        None => message,
    }
}

fn format_path(path: &serde_path_to_error::Path, skip_variants: bool) -> String {
    use serde_path_to_error::Segment;
    let mut out = String::new();
    for segment in path.iter() {
        match segment {
            Segment::Seq { index } => out.push_str(&format!("[{index}]")),
            Segment::Map { key } => {
                if !out.is_empty() {
                    out.push('.');
                }
                out.push_str(key);
            }
            Segment::Enum { variant } => {
                if !skip_variants {
                    if !out.is_empty() {
                        out.push('.');
                    }
                    out.push_str(variant);
                }
            }
            Segment::Unknown => {
                if !out.is_empty() {
                    out.push('.');
                }
                out.push('?');
            }
        }
    }
    out
}

/// A JSON value read with unique keys.
struct Unique(Value);

impl<'de> Deserialize<'de> for Unique {
    fn deserialize<D: de::Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        deserializer.deserialize_any(UniqueVisitor)
    }
}

struct UniqueVisitor;

impl<'de> Visitor<'de> for UniqueVisitor {
    type Value = Unique;

    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        f.write_str("any JSON value")
    }
    fn visit_bool<E>(self, v: bool) -> Result<Unique, E> {
        Ok(Unique(Value::Bool(v)))
    }
    fn visit_i64<E>(self, v: i64) -> Result<Unique, E> {
        Ok(Unique(Value::Number(v.into())))
    }
    fn visit_u64<E>(self, v: u64) -> Result<Unique, E> {
        Ok(Unique(Value::Number(v.into())))
    }
    fn visit_f64<E: de::Error>(self, v: f64) -> Result<Unique, E> {
        Number::from_f64(v).map(|n| Unique(Value::Number(n))).ok_or_else(|| E::custom("not a finite number"))
    }
    fn visit_str<E>(self, v: &str) -> Result<Unique, E> {
        Ok(Unique(Value::String(v.to_string())))
    }
    fn visit_string<E>(self, v: String) -> Result<Unique, E> {
        Ok(Unique(Value::String(v)))
    }
    fn visit_unit<E>(self) -> Result<Unique, E> {
        Ok(Unique(Value::Null))
    }
    fn visit_none<E>(self) -> Result<Unique, E> {
        Ok(Unique(Value::Null))
    }
    fn visit_some<D: de::Deserializer<'de>>(self, d: D) -> Result<Unique, D::Error> {
        Unique::deserialize(d)
    }
    fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<Unique, A::Error> {
        let mut list = Vec::new();
        while let Some(Unique(v)) = seq.next_element()? {
            list.push(v);
        }
        Ok(Unique(Value::Array(list)))
    }
    fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> Result<Unique, A::Error> {
        let mut object = Map::new();
        while let Some(key) = map.next_key::<String>()? {
            if object.contains_key(&key) {
                // Fails inside the value, so that the path names the key.
                return Err(map.next_value_seed(Duplicate(key)).err().unwrap_or_else(|| de::Error::custom("")));
            }
            let Unique(value) = map.next_value()?;
            object.insert(key, value);
        }
        Ok(Unique(Value::Object(object)))
    }
}

/// Fails with "duplicate key" for the value of a repeated key.
struct Duplicate(String);

impl<'de> DeserializeSeed<'de> for Duplicate {
    type Value = ();
    fn deserialize<D: de::Deserializer<'de>>(self, _: D) -> Result<(), D::Error> {
        Err(de::Error::custom(format!("duplicate key `{}`: give every key once", self.0)))
    }
}

/// A value deserializer whose structs accept JSON objects only (serde's
/// derive would also take a list of the fields in order).
struct Strict(Value);

type Error = serde_json::Error;

impl Strict {
    fn unexpected(&self) -> Unexpected<'_> {
        match &self.0 {
            Value::Null => Unexpected::Unit,
            Value::Bool(b) => Unexpected::Bool(*b),
            Value::Number(n) => match (n.as_u64(), n.as_i64(), n.as_f64()) {
                (Some(u), _, _) => Unexpected::Unsigned(u),
                (_, Some(i), _) => Unexpected::Signed(i),
                (_, _, Some(f)) => Unexpected::Float(f),
                _ => Unexpected::Other("number"),
            },
            Value::String(s) => Unexpected::Str(s),
            Value::Array(_) => Unexpected::Seq,
            Value::Object(_) => Unexpected::Map,
        }
    }
}

impl<'de> de::Deserializer<'de> for Strict {
    type Error = Error;

    fn deserialize_any<V: Visitor<'de>>(self, visitor: V) -> Result<V::Value, Error> {
        match self.0 {
            Value::Null => visitor.visit_unit(),
            Value::Bool(b) => visitor.visit_bool(b),
            Value::Number(n) => {
                if let Some(u) = n.as_u64() {
                    visitor.visit_u64(u)
                } else if let Some(i) = n.as_i64() {
                    visitor.visit_i64(i)
                } else {
                    visitor.visit_f64(n.as_f64().unwrap_or(f64::NAN))
                }
            }
            Value::String(s) => visitor.visit_string(s),
            Value::Array(list) => {
                let len = list.len();
                let mut seq = Seq(list.into_iter());
                let value = visitor.visit_seq(&mut seq)?;
                if seq.0.len() == 0 {
                    Ok(value)
                } else {
                    Err(de::Error::invalid_length(len, &"fewer elements in the list"))
                }
            }
            Value::Object(object) => visitor.visit_map(Object { entries: object.into_iter(), value: None }),
        }
    }

    fn deserialize_option<V: Visitor<'de>>(self, visitor: V) -> Result<V::Value, Error> {
        match self.0 {
            // A field that may have no value is left out by null, as files
            // the tool writes say it (a camera's width in manifest.json).
            Value::Null => visitor.visit_none(),
            _ => visitor.visit_some(self),
        }
    }

    fn deserialize_newtype_struct<V: Visitor<'de>>(self, _: &'static str, visitor: V) -> Result<V::Value, Error> {
        visitor.visit_newtype_struct(self)
    }

    fn deserialize_struct<V: Visitor<'de>>(
        self,
        _: &'static str,
        _: &'static [&'static str],
        visitor: V,
    ) -> Result<V::Value, Error> {
        // A struct is read only from an object, never from a list.
        self.deserialize_map(visitor)
    }

    fn deserialize_map<V: Visitor<'de>>(self, visitor: V) -> Result<V::Value, Error> {
        match self.0 {
            Value::Object(_) => self.deserialize_any(visitor),
            _ => Err(de::Error::invalid_type(self.unexpected(), &"an object")),
        }
    }

    fn deserialize_enum<V: Visitor<'de>>(
        self,
        _: &'static str,
        _: &'static [&'static str],
        visitor: V,
    ) -> Result<V::Value, Error> {
        match self.0 {
            Value::String(s) => visitor.visit_enum(s.into_deserializer()),
            Value::Object(object) if object.len() == 1 => {
                let (variant, value) = object.into_iter().next().expect("one entry");
                visitor.visit_enum(Variant { variant, value })
            }
            other => Err(de::Error::invalid_type(Strict(other).unexpected(), &"a string or an object with one key")),
        }
    }

    fn deserialize_ignored_any<V: Visitor<'de>>(self, visitor: V) -> Result<V::Value, Error> {
        visitor.visit_unit()
    }

    whole_numbers! {
        deserialize_u8: u8, deserialize_u16: u16, deserialize_u32: u32, deserialize_u64: u64,
        deserialize_i8: i8, deserialize_i16: i16, deserialize_i32: i32, deserialize_i64: i64
    }

    serde::forward_to_deserialize_any! {
        bool i128 u128 f32 f64 char str string
        bytes byte_buf unit unit_struct seq tuple tuple_struct identifier
    }
}

/// Integer fields: a number that is not a whole number of the field's
/// range is refused with the range, echoing the number as written
/// ([`Shown`]) or, beyond what a float holds exactly, by which end it
/// passes (never `1.8446744073709552e+19` for the 2^64 a user typed).
macro_rules! whole_numbers {
    ($($method:ident: $t:ty),* $(,)?) => {$(
        fn $method<V: Visitor<'de>>(self, visitor: V) -> Result<V::Value, Error> {
            if let Value::Number(n) = &self.0 {
                let fits = match (n.as_u64(), n.as_i64()) {
                    (Some(u), _) => <$t>::try_from(u).is_ok(),
                    (_, Some(i)) => <$t>::try_from(i).is_ok(),
                    _ => false,
                };
                if !fits {
                    return Err(de::Error::custom(whole_number_message(n, <$t>::MIN as i128, <$t>::MAX as i128)));
                }
            }
            self.deserialize_any(visitor)
        }
    )*};
}
use whole_numbers;

/// Why `n` is not a whole number from `min` to `max`, and what is allowed.
fn whole_number_message(n: &Number, min: i128, max: i128) -> String {
    let allowed = format!("use a whole number from {min} to {max}");
    let value = n.as_f64().unwrap_or(f64::NAN);
    // A float as written (1e12, not 1000000000000.0), an integer whole; past
    // what a float holds exactly, by which end it passes.
    let shown = |beyond: &str, end: i128| match n.is_f64() {
        true if value.abs() >= 1e16 => format!("a number {beyond} {end}"),
        true => Shown(value).to_string(),
        false => n.to_string(),
    };
    // A float at a maximum that a float rounds up (2^64 - 1 to 2^64) is past it.
    let past_max = value > max as f64 || (n.is_f64() && value >= max as f64 && (max as f64) as i128 != max);
    if n.is_f64() && value.is_finite() && value.fract() != 0.0 {
        format!("{} is not a whole number: {allowed}", Shown(value))
    } else if past_max {
        format!("{} is too large: {allowed}", shown("above", max))
    } else if value < min as f64 && min == 0 {
        // Not "from 0 to 4294967295": the type's top is not the field's,
        // whose own range is checked once it reads.
        format!("{} is too small: use a whole number, 0 or more", shown("below", min))
    } else if value < min as f64 {
        format!("{} is too small: {allowed}", shown("below", min))
    } else {
        format!("{} is written as a decimal: {allowed}, without a decimal point or exponent", Shown(value))
    }
}

struct Seq(std::vec::IntoIter<Value>);

impl<'de> SeqAccess<'de> for Seq {
    type Error = Error;
    fn next_element_seed<T: DeserializeSeed<'de>>(&mut self, seed: T) -> Result<Option<T::Value>, Error> {
        self.0.next().map(|v| seed.deserialize(Strict(v))).transpose()
    }
    fn size_hint(&self) -> Option<usize> {
        Some(self.0.len())
    }
}

struct Object {
    entries: serde_json::map::IntoIter,
    value: Option<Value>,
}

impl<'de> MapAccess<'de> for Object {
    type Error = Error;
    fn next_key_seed<K: DeserializeSeed<'de>>(&mut self, seed: K) -> Result<Option<K::Value>, Error> {
        match self.entries.next() {
            Some((key, value)) => {
                self.value = Some(value);
                seed.deserialize(Strict(Value::String(key))).map(Some)
            }
            None => Ok(None),
        }
    }
    fn next_value_seed<V: DeserializeSeed<'de>>(&mut self, seed: V) -> Result<V::Value, Error> {
        seed.deserialize(Strict(self.value.take().unwrap_or(Value::Null)))
    }
    fn size_hint(&self) -> Option<usize> {
        Some(self.entries.len())
    }
}

struct Variant {
    variant: String,
    value: Value,
}

impl<'de> de::EnumAccess<'de> for Variant {
    type Error = Error;
    type Variant = Strict;
    fn variant_seed<V: DeserializeSeed<'de>>(self, seed: V) -> Result<(V::Value, Strict), Error> {
        let variant = seed.deserialize(Strict(Value::String(self.variant)))?;
        Ok((variant, Strict(self.value)))
    }
}

impl<'de> de::VariantAccess<'de> for Strict {
    type Error = Error;
    fn unit_variant(self) -> Result<(), Error> {
        match self.0 {
            Value::Null => Ok(()),
            _ => Err(de::Error::invalid_type(self.unexpected(), &"null")),
        }
    }
    fn newtype_variant_seed<T: DeserializeSeed<'de>>(self, seed: T) -> Result<T::Value, Error> {
        seed.deserialize(self)
    }
    fn tuple_variant<V: Visitor<'de>>(self, _: usize, visitor: V) -> Result<V::Value, Error> {
        de::Deserializer::deserialize_any(self, visitor)
    }
    fn struct_variant<V: Visitor<'de>>(self, fields: &'static [&'static str], visitor: V) -> Result<V::Value, Error> {
        de::Deserializer::deserialize_struct(self, "", fields, visitor)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Debug, Deserialize, PartialEq)]
    #[serde(deny_unknown_fields)]
    struct Size {
        width: u32,
        height: u32,
    }

    #[derive(Debug, Deserialize, PartialEq)]
    #[serde(deny_unknown_fields)]
    struct Doc {
        size: Size,
        #[serde(default)]
        tags: Vec<String>,
    }

    #[test]
    fn good_documents_read() {
        let doc: Doc = parse_strict(r#" {"size": {"width": 3, "height": 4}, "tags": ["a"]} "#).unwrap();
        assert_eq!(doc, Doc { size: Size { width: 3, height: 4 }, tags: vec!["a".into()] });
    }

    #[test]
    fn duplicate_keys_are_named_with_their_path() {
        let e = parse_strict::<Doc>(r#"{"size": {"width": 3, "width": 5, "height": 4}}"#).unwrap_err();
        assert_eq!(e.path, "size.width");
        assert!(e.message.contains("duplicate key"), "{e:?}");
    }

    #[test]
    fn trailing_data_is_an_error() {
        let e = parse_strict::<Doc>(r#"{"size": {"width": 3, "height": 4}} xyz"#).unwrap_err();
        assert!(e.message.contains("trailing"), "{e:?}");
        let e = parse_strict::<Doc>(r#"{"size": {"width": 3, "height": 4}}{}"#).unwrap_err();
        assert!(e.message.contains("trailing"), "{e:?}");
    }

    #[test]
    fn a_list_is_not_an_object() {
        let e = parse_strict::<Doc>(r#"{"size": [3, 4]}"#).unwrap_err();
        assert_eq!(e.path, "size");
        assert!(e.message.contains("invalid type: a list, expected an object"), "{e:?}");
    }

    #[test]
    fn unknown_fields_and_wrong_types_are_named() {
        let e = parse_strict::<Doc>(r#"{"size": {"width": 3, "height": 4, "depth": 1}}"#).unwrap_err();
        assert!(e.path.starts_with("size") && e.message.contains("depth"), "{e:?}");
        let e = parse_strict::<Doc>(r#"{"size": {"width": -3, "height": 4}}"#).unwrap_err();
        assert_eq!(e.path, "size.width");
        let e = parse_strict::<Doc>(r#"{"size": {"width": 3, "height": 4}, "tags": [1]}"#).unwrap_err();
        assert_eq!(e.path, "tags[0]");
    }
}
