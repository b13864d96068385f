//! Decoded data straight into Python objects.
//!
//! The same shape as hartkit's `JsonVisitor::with_words` (the CLI's JSON view plus the
//! meaning of codes), built as dicts and lists directly instead of through JSON: a
//! command 3 reply decodes in about a third of the time, which is what a Python user
//! decoding a stream of frames pays per frame. `crates/hartkit-py/tests/test_codec.py`
//! checks the two agree on every public vector.

use hart_proto::wire::{Field, Meaning, Value, Visitor};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};

enum Open<'py> {
    List(&'static str, Bound<'py, PyList>),
    Item(Bound<'py, PyDict>),
}

/// Builds a dict from a [`Visitor`] walk.
pub struct PyVisitor<'py> {
    py: Python<'py>,
    root: Bound<'py, PyDict>,
    stack: Vec<Open<'py>>,
    error: Option<PyErr>,
}

impl<'py> PyVisitor<'py> {
    /// An empty dict to fill.
    pub fn new(py: Python<'py>) -> Self {
        PyVisitor {
            py,
            root: PyDict::new(py),
            stack: Vec::new(),
            error: None,
        }
    }

    /// The dict, or the first error met while filling it.
    pub fn finish(self) -> PyResult<Bound<'py, PyDict>> {
        match self.error {
            Some(e) => Err(e),
            None => Ok(self.root),
        }
    }

    fn current(&self) -> &Bound<'py, PyDict> {
        match self.stack.last() {
            Some(Open::Item(d)) => d,
            _ => &self.root,
        }
    }

    fn value(&self, v: &Value<'_>) -> PyResult<Bound<'py, PyAny>> {
        let py = self.py;
        Ok(match v {
            Value::Uint(u) => u.into_pyobject(py)?.into_any(),
            // As the JSON view: the shortest decimal that reads back as the same f32,
            // None when not finite.
            Value::Float(x) if !x.is_finite() => py.None().into_bound(py),
            Value::Float(x) => {
                let shortest: f64 = format!("{x}").parse().unwrap_or(f64::from(*x));
                shortest.into_pyobject(py)?.into_any()
            }
            Value::Str(s) => s.into_pyobject(py)?.into_any(),
            Value::Hex(b) => hart_proto::hex::compact(b).into_pyobject(py)?.into_any(),
            Value::Date(d) => d.to_string().into_pyobject(py)?.into_any(),
            Value::Bool(b) => b.into_pyobject(py)?.to_owned().into_any(),
        })
    }

    fn field(&self, f: &Field<'_>) -> PyResult<()> {
        let m = self.current();
        m.set_item(f.name, self.value(&f.value)?)?;
        let Value::Uint(code) = f.value else {
            return Ok(());
        };
        let code = code as u8;
        match f.meaning {
            Meaning::Unit => {
                if let Some(u) = hart_proto::tables::unit(code) {
                    m.set_item(format!("{}_symbol", f.name), u.symbol)?;
                    m.set_item(format!("{}_name", f.name), u.name)?;
                }
            }
            Meaning::Code(t) => {
                if let Some(n) = t.name(code) {
                    m.set_item(format!("{}_name", f.name), n)?;
                }
            }
            Meaning::Bits(t) => {
                let set: Vec<&str> = t.set_bits(code).map(|b| b.name).collect();
                m.set_item(format!("{}_set", f.name), set)?;
            }
            _ => {}
        }
        Ok(())
    }

    fn keep(&mut self, r: PyResult<()>) {
        if let Err(e) = r {
            self.error.get_or_insert(e);
        }
    }
}

impl Visitor for PyVisitor<'_> {
    fn field(&mut self, f: Field<'_>) {
        let r = PyVisitor::field(self, &f);
        self.keep(r);
    }
    fn begin_list(&mut self, name: &'static str) {
        self.stack.push(Open::List(name, PyList::empty(self.py)));
    }
    fn begin_item(&mut self, _index: usize) {
        self.stack.push(Open::Item(PyDict::new(self.py)));
    }
    fn end_item(&mut self) {
        if let Some(Open::Item(m)) = self.stack.pop() {
            // A list of scalars describes each element as one field named "item".
            let item = if m.len() == 1 {
                m.get_item("item").ok().flatten()
            } else {
                None
            };
            let item = item.unwrap_or_else(|| m.into_any());
            if let Some(Open::List(_, items)) = self.stack.last() {
                let r = items.append(item);
                self.keep(r);
            }
        }
    }
    fn end_list(&mut self) {
        if let Some(Open::List(name, items)) = self.stack.pop() {
            let r = self.current().set_item(name, items);
            self.keep(r);
        }
    }
}
