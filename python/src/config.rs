//! `Config`: the library's one configuration (method, mode, sequence reading, motion maps,
//! SLAM, passes, online schedule) from a dict, a JSON/YAML file or keyword overrides.

use std::path::{Path, PathBuf};

use pyo3::prelude::*;
use pyo3::types::{PyDict, PyString};
use serde_json::Value;

use crate::errors::{config, guard};

/// The configuration of a DynaPix run (the paper's defaults unless told otherwise).
///
/// ``Config()`` is the paper's DynaPix; ``Config({"method": "orbslam2"})``,
/// ``Config("run.yaml")`` (a JSON or YAML file) and keyword overrides such as
/// ``Config(mode="reference", slam__seed=3)`` (``__`` separates nested keys) change it.
/// Unknown keys raise ``ConfigError`` naming the key. ``to_dict()`` gives every value.
#[pyclass(name = "Config", module = "dynapix._dynapix", frozen)]
#[derive(Clone)]
pub struct Config {
    /// The library's configuration.
    pub inner: dynapix::Config,
}

/// A Python object as JSON (through the `json` module).
fn to_value(obj: &Bound<'_, PyAny>) -> PyResult<Value> {
    let py = obj.py();
    let text: String = py
        .import("json")?
        .call_method1("dumps", (obj,))
        .map_err(|e| config(format!("configuration values must be JSON-like: {e}")))?
        .extract()?;
    serde_json::from_str(&text).map_err(|e| config(format!("configuration values: {e}")))
}

/// A JSON value as a Python object.
pub fn to_python<'py>(py: Python<'py>, v: &Value) -> PyResult<Bound<'py, PyAny>> {
    py.import("json")?.call_method1("loads", (v.to_string(),))
}

/// Keyword overrides (`a__b=v` → `{"a": {"b": v}}`) merged into `base`.
fn apply_overrides(base: &mut Value, overrides: Option<&Bound<'_, PyDict>>) -> PyResult<()> {
    let Some(kw) = overrides else {
        return Ok(());
    };
    for (k, v) in kw.iter() {
        let key: String = k.extract()?;
        let mut value = to_value(&v)?;
        let parts: Vec<&str> = key.split("__").collect();
        for part in parts.iter().skip(1).rev() {
            value = serde_json::json!({ *part: value });
        }
        let top = key.split("__").next().unwrap_or_default().to_string();
        let mut wrapped = serde_json::Map::new();
        wrapped.insert(top, value);
        merge(base, Value::Object(wrapped));
    }
    Ok(())
}

/// Merges `over` into `base` key by key (objects recursively).
fn merge(base: &mut Value, over: Value) {
    match (base, over) {
        (Value::Object(b), Value::Object(o)) => {
            for (k, v) in o {
                match b.get_mut(&k) {
                    Some(slot) if slot.is_object() && v.is_object() => merge(slot, v),
                    _ => {
                        b.insert(k, v);
                    }
                }
            }
        }
        (slot, v) => *slot = v,
    }
}

/// A configuration file's document (JSON by extension, else YAML).
fn read_file(path: &Path) -> dynapix::Result<Value> {
    let bad = |message: String| dynapix::Error::Config {
        path: Some(path.to_path_buf()),
        message,
    };
    let text = std::fs::read_to_string(path).map_err(|e| bad(format!("cannot read: {e}")))?;
    if path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("json"))
    {
        serde_json::from_str(&text).map_err(|e| bad(format!("not JSON: {e}")))
    } else if text.trim().is_empty() {
        Ok(Value::Null)
    } else {
        serde_saphyr::from_str(&text).map_err(|e| bad(format!("not YAML: {e}")))
    }
}

/// A configuration from a document, errors naming `path` when it came from a file.
fn build(v: Value, path: Option<&Path>) -> PyResult<dynapix::Config> {
    guard(|| {
        dynapix::Config::from_value(v).map_err(|e| match (e, path) {
            (
                dynapix::Error::Config {
                    path: None,
                    message,
                },
                Some(p),
            ) => dynapix::Error::Config {
                path: Some(p.to_path_buf()),
                message,
            },
            (other, _) => other,
        })
    })
}

impl Config {
    /// `values` (None, a dict, a `Config` or a file path) with keyword overrides.
    pub fn from_any(
        values: Option<&Bound<'_, PyAny>>,
        overrides: Option<&Bound<'_, PyDict>>,
    ) -> PyResult<Self> {
        let (mut v, path) = match values {
            None => (Value::Object(Default::default()), None),
            Some(obj) if obj.is_none() => (Value::Object(Default::default()), None),
            Some(obj) => {
                if let Ok(c) = obj.cast::<Config>() {
                    (c.get().inner.to_json_value(), None)
                } else if obj.is_instance_of::<PyDict>() {
                    (to_value(obj)?, None)
                } else if obj.is_instance_of::<PyString>() || obj.hasattr("__fspath__")? {
                    let p: PathBuf = obj.extract()?;
                    (guard(|| read_file(&p))?, Some(p))
                } else {
                    return Err(config(format!(
                        "a configuration is a dict, a JSON/YAML file path or a Config, got {}",
                        obj.get_type().name()?
                    )));
                }
            }
        };
        if v.is_null() {
            v = Value::Object(Default::default());
        }
        apply_overrides(&mut v, overrides)?;
        Ok(Self {
            inner: build(v, path.as_deref())?,
        })
    }
}

#[pymethods]
impl Config {
    /// Builds a configuration from ``values`` (a dict, a JSON/YAML file path, another
    /// ``Config`` or None for the defaults) and keyword overrides (``a__b=v`` sets
    /// ``values["a"]["b"]``). Raises ``ConfigError`` for unknown keys or invalid values.
    #[new]
    #[pyo3(signature = (values=None, /, **overrides))]
    fn new(
        values: Option<&Bound<'_, PyAny>>,
        overrides: Option<&Bound<'_, PyDict>>,
    ) -> PyResult<Self> {
        Self::from_any(values, overrides)
    }

    /// A configuration from a JSON or YAML file (by extension; YAML otherwise) with
    /// keyword overrides.
    #[staticmethod]
    #[pyo3(signature = (path, /, **overrides))]
    fn from_file(path: PathBuf, overrides: Option<&Bound<'_, PyDict>>) -> PyResult<Self> {
        let mut v = guard(|| read_file(&path))?;
        if v.is_null() {
            v = Value::Object(Default::default());
        }
        apply_overrides(&mut v, overrides)?;
        Ok(Self {
            inner: build(v, Some(&path))?,
        })
    }

    /// A configuration from a dict with keyword overrides.
    #[staticmethod]
    #[pyo3(signature = (values, /, **overrides))]
    fn from_dict(
        values: &Bound<'_, PyDict>,
        overrides: Option<&Bound<'_, PyDict>>,
    ) -> PyResult<Self> {
        Self::from_any(Some(values.as_any()), overrides)
    }

    /// A configuration from JSON text.
    #[staticmethod]
    fn from_json(text: &str) -> PyResult<Self> {
        Ok(Self {
            inner: guard(|| dynapix::Config::from_json_str(text))?,
        })
    }

    /// A configuration from YAML text.
    #[staticmethod]
    fn from_yaml(text: &str) -> PyResult<Self> {
        Ok(Self {
            inner: guard(|| dynapix::Config::from_yaml_str(text))?,
        })
    }

    /// A copy with keyword overrides applied (``cfg.replace(method="orbslam2")``).
    #[pyo3(signature = (**overrides))]
    fn replace(&self, overrides: Option<&Bound<'_, PyDict>>) -> PyResult<Self> {
        let mut v = self.inner.to_json_value();
        apply_overrides(&mut v, overrides)?;
        Ok(Self {
            inner: build(v, None)?,
        })
    }

    /// Every value as a dict (what ``run.json`` records under ``config``).
    fn to_dict<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        to_python(py, &self.inner.to_json_value())
    }

    /// Every value as JSON text.
    #[pyo3(signature = (indent=None))]
    fn to_json(&self, indent: Option<usize>) -> PyResult<String> {
        let v = self.inner.to_json_value();
        let s = match indent {
            Some(_) => serde_json::to_string_pretty(&v),
            None => serde_json::to_string(&v),
        };
        s.map_err(|e| config(e.to_string()))
    }

    /// The method: ``dynapix``, ``dynapix+`` or ``orbslam2``.
    #[getter]
    fn method(&self) -> &'static str {
        self.inner.method.name()
    }

    /// ``paper`` or ``reference`` behaviour of the motion maps and SLAM weighting.
    #[getter]
    fn mode(&self) -> &'static str {
        self.inner.mode.name()
    }

    /// The relocalisation RANSAC seed.
    #[getter]
    fn seed(&self) -> u64 {
        self.inner.slam.seed
    }

    fn __eq__(&self, other: &Bound<'_, PyAny>) -> bool {
        other
            .cast::<Config>()
            .is_ok_and(|o| o.get().inner.to_json_value() == self.inner.to_json_value())
    }

    fn __repr__(&self) -> String {
        format!(
            "Config(method={:?}, mode={:?}, seed={})",
            self.inner.method.name(),
            self.inner.mode.name(),
            self.inner.slam.seed
        )
    }
}

/// The configuration of an optional argument (None, dict, path or `Config`).
pub fn config_arg(obj: Option<&Bound<'_, PyAny>>) -> PyResult<dynapix::Config> {
    match obj {
        Some(o) => match o.cast::<Config>() {
            Ok(c) => Ok(c.get().inner.clone()),
            Err(_) => Ok(Config::from_any(Some(o), None)?.inner),
        },
        None => Ok(dynapix::Config::default()),
    }
}
