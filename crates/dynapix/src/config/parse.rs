//! Reading configuration documents: duplicate keys refused, DynaPix thresholds at their old
//! place moved into the flat section, type errors and unknown keys named by their key path.

use super::*;

/// A JSON document as a value; a key given twice in one map is an error naming it.
pub(super) fn parse_json(text: &str) -> std::result::Result<Value, String> {
    let mut de = serde_json::Deserializer::from_str(text);
    let v = serde::de::DeserializeSeed::deserialize(Strict { at: String::new() }, &mut de)
        .and_then(|v| de.end().map(|()| v))
        .map_err(|e| format!("not JSON: {e}"))?;
    Ok(v)
}

/// A YAML document as a value; a key given twice in one map is an error naming it.
pub(super) fn parse_yaml(text: &str) -> std::result::Result<Value, String> {
    serde_saphyr::from_str::<StrictValue>(text)
        .map(|v| v.0)
        .map_err(|e| format!("not YAML: {e}"))
}

/// A document value read by [`Strict`].
pub(super) struct StrictValue(Value);

impl<'de> Deserialize<'de> for StrictValue {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
        serde::de::DeserializeSeed::deserialize(Strict { at: String::new() }, d).map(StrictValue)
    }
}

/// Reads any self-describing document into a [`Value`], refusing a key that a map gives
/// twice (serde_json's own `Value` keeps the last one silently). `at` is the key path so far.
pub(super) struct Strict {
    at: String,
}

impl<'de> serde::de::DeserializeSeed<'de> for Strict {
    type Value = Value;
    fn deserialize<D: serde::Deserializer<'de>>(
        self,
        d: D,
    ) -> std::result::Result<Value, D::Error> {
        d.deserialize_any(self)
    }
}

impl<'de> serde::de::Visitor<'de> for Strict {
    type Value = Value;
    fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        f.write_str("a configuration value")
    }
    fn visit_bool<E>(self, v: bool) -> std::result::Result<Value, E> {
        Ok(Value::Bool(v))
    }
    fn visit_i64<E>(self, v: i64) -> std::result::Result<Value, E> {
        Ok(Value::from(v))
    }
    fn visit_u64<E>(self, v: u64) -> std::result::Result<Value, E> {
        Ok(Value::from(v))
    }
    fn visit_f64<E>(self, v: f64) -> std::result::Result<Value, E> {
        Ok(serde_json::Number::from_f64(v).map_or(Value::Null, Value::Number))
    }
    fn visit_str<E>(self, v: &str) -> std::result::Result<Value, E> {
        Ok(Value::String(v.to_string()))
    }
    fn visit_string<E>(self, v: String) -> std::result::Result<Value, E> {
        Ok(Value::String(v))
    }
    fn visit_none<E>(self) -> std::result::Result<Value, E> {
        Ok(Value::Null)
    }
    fn visit_unit<E>(self) -> std::result::Result<Value, E> {
        Ok(Value::Null)
    }
    fn visit_some<D: serde::Deserializer<'de>>(self, d: D) -> std::result::Result<Value, D::Error> {
        serde::de::DeserializeSeed::deserialize(self, d)
    }
    fn visit_seq<A: serde::de::SeqAccess<'de>>(
        self,
        mut seq: A,
    ) -> std::result::Result<Value, A::Error> {
        let mut out = Vec::new();
        while let Some(v) = seq.next_element_seed(Strict {
            at: format!("{}[{}]", self.at, out.len()),
        })? {
            out.push(v);
        }
        Ok(Value::Array(out))
    }
    fn visit_map<A: serde::de::MapAccess<'de>>(
        self,
        mut map: A,
    ) -> std::result::Result<Value, A::Error> {
        let mut out = serde_json::Map::new();
        while let Some(key) = map.next_key::<String>()? {
            let at = if self.at.is_empty() {
                key.clone()
            } else {
                format!("{}.{key}", self.at)
            };
            if out.contains_key(&key) {
                return Err(serde::de::Error::custom(format!(
                    "duplicate key {at} (each key may be given once)"
                )));
            }
            let v = map.next_value_seed(Strict { at })?;
            out.insert(key, v);
        }
        Ok(Value::Object(out))
    }
}

/// Reads DynaPix thresholds given at their old place, `slam.params.map.dynapix`, into the
/// flat section `dynapix` (with a warning naming the new key). The old block's `weighting`
/// must agree with `mode`; a threshold given in both places with different values is an
/// error.
pub(super) fn move_nested_dynapix(v: &mut Value, mode: Mode) -> Result<()> {
    let Some(old) = v
        .pointer_mut("/slam/params/map")
        .and_then(Value::as_object_mut)
        .and_then(|m| m.remove("dynapix"))
    else {
        return Ok(());
    };
    let Value::Object(old) = old else {
        return Err(Error::config(
            "slam.params.map.dynapix must be a map; the DynaPix thresholds are now the section \
             `dynapix` (gamma_add, gamma_del, update)",
        ));
    };
    for (key, value) in old {
        let at = format!("slam.params.map.dynapix.{key}");
        match key.as_str() {
            "weighting" => {
                let w: dynapix_slam::weighting::Weighting = serde_json::from_value(value)
                    .map_err(|e| Error::config(format!("{at}: {e}")))?;
                if w != mode.weighting() {
                    return Err(Error::config(format!(
                        "{at} is {w:?} but mode is {}: set only `mode` (the method turns \
                         weighting off for orbslam2 and threshold)",
                        mode.name()
                    )));
                }
            }
            "gamma_add" | "gamma_del" | "update" => {
                let Value::Object(root) = v else {
                    return Ok(());
                };
                let flat = root
                    .entry("dynapix")
                    .or_insert_with(|| Value::Object(Default::default()));
                let Value::Object(flat) = flat else {
                    return Err(Error::config("dynapix must be a map"));
                };
                match flat.get(&key) {
                    Some(given) if *given != value => {
                        return Err(Error::config(format!(
                            "{at} ({value}) and dynapix.{key} ({given}) disagree: give it once, \
                             as dynapix.{key}"
                        )));
                    }
                    Some(_) => {}
                    None => {
                        tracing::warn!("{at} is read as dynapix.{key}: write it there");
                        flat.insert(key, value);
                    }
                }
            }
            _ => {
                return Err(Error::config(format!(
                    "unknown key {at} (the DynaPix thresholds are now the section `dynapix`: \
                     gamma_add, gamma_del, update)"
                )));
            }
        }
    }
    Ok(())
}

/// The key of `user` whose value has the wrong type for the configuration: each value of the
/// document is tried alone over the defaults `base`, and the first that cannot be read is
/// named, with serde's reason. `None` when no single value is at fault.
pub(super) fn blame_type_error(base: &Value, user: &Value) -> Option<String> {
    fn leaves(v: &Value, at: &mut Vec<String>, out: &mut Vec<Vec<String>>) {
        match v {
            Value::Object(m) if !m.is_empty() => {
                for (k, child) in m {
                    at.push(k.clone());
                    leaves(child, at, out);
                    at.pop();
                }
            }
            _ => out.push(at.clone()),
        }
    }
    let mut paths = Vec::new();
    leaves(user, &mut Vec::new(), &mut paths);
    for path in paths {
        let mut value = user;
        for k in &path {
            value = value.get(k)?;
        }
        let mut single = value.clone();
        for k in path.iter().rev() {
            let mut m = serde_json::Map::new();
            m.insert(k.clone(), single);
            single = Value::Object(m);
        }
        let mut tried = base.clone();
        merge(&mut tried, single);
        if let Err(e) = serde_json::from_value::<Config>(tried) {
            let key = path.join(".");
            // serde names the struct field it was reading, not where it sits.
            return Some(format!("{key}: {e} (got {value})"));
        }
    }
    None
}

/// Errors for keys of `file` that `known` (the serialised defaults) does not have.
pub(super) fn check_known_keys(file: &Value, known: &Value, at: &str) -> Result<()> {
    if let (Value::Object(f), Value::Object(k)) = (file, known) {
        for (key, v) in f {
            let path = if at.is_empty() {
                key.clone()
            } else {
                format!("{at}.{key}")
            };
            match k.get(key) {
                None => {
                    let mut names: Vec<&str> = k.keys().map(String::as_str).collect();
                    names.sort_unstable();
                    return Err(Error::config(format!(
                        "unknown key {path} (known here: {})",
                        names.join(", ")
                    )));
                }
                Some(kv) => check_known_keys(v, kv, &path)?,
            }
        }
    }
    Ok(())
}

/// Replaces values of `base` by those of `over`, descending into maps.
pub(super) fn merge(base: &mut Value, over: Value) {
    match (base, over) {
        (Value::Object(b), Value::Object(o)) => {
            for (k, v) in o {
                match b.get_mut(&k) {
                    Some(slot) => merge(slot, v),
                    None => {
                        b.insert(k, v);
                    }
                }
            }
        }
        (slot, v) => *slot = v,
    }
}
