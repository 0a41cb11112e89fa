//! Python bindings of brdfpack (module `brdfpack`, docs/bindings.md): sources opened like the
//! CLI opens them, evaluated on NumPy arrays of direction pairs with the GIL released; tables
//! as arrays with their grid; tabulate, compress, check, save and load. Everything is a call
//! into the library: this file converts arguments and results and maps errors.

use brdfpack_core::check::{CheckOptions, SampleSet};
use brdfpack_core::codec::CodecRequest;
use brdfpack_core::geometry::Vec3;
use brdfpack_core::grid::parse_grid_spec;
use brdfpack_core::io::{self, FormatName, OutputFormat, atomic, native};
use brdfpack_core::pairs::{EvalOptions, Evaluable};
use brdfpack_core::plan::budget::Budget;
use brdfpack_core::plan::pack::{PackInput, PackSettings, plan};
use brdfpack_core::plan::rate::Effort;
use brdfpack_core::source::{Lookup, Source as CoreSource};
use brdfpack_core::table::Table as CoreTable;
use brdfpack_core::tabulate::{TabulateOptions, tabulate as core_tabulate};
use brdfpack_core::{Error, Result};
use numpy::{PyArray1, PyArrayMethods, PyUntypedArrayMethods};
use pyo3::exceptions::PyException;
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyDict, PyList};
use std::borrow::Cow;
use std::path::Path;

pyo3::create_exception!(
    brdfpack,
    BrdfpackError,
    PyException,
    "An error of brdfpack: the message is the CLI's (`brdfpack: ...`); `exit_code` is the \
     CLI's exit code (2 bad input or file, 1 failure)."
);

/// The library's error as a Python exception with the CLI's message.
fn py_err(e: Error) -> PyErr {
    let msg = format!(
        "brdfpack: {}",
        brdfpack_core::text::sanitize_line(&e.to_string())
    );
    let code = e.exit_code();
    Python::attach(|py| {
        let err = BrdfpackError::new_err(msg);
        // The attribute is a convenience: failing to set it must not hide the error.
        let _ = err.value(py).setattr("exit_code", code);
        err
    })
}

fn lookup(interp: &str) -> Result<Lookup> {
    match interp {
        "linear" => Ok(Lookup::Linear),
        "nearest" => Ok(Lookup::Nearest),
        "merl" => Ok(Lookup::Merl),
        other => Err(Error::input(format!(
            "interp {other:?}: expected \"linear\", \"nearest\" or \"merl\""
        ))),
    }
}

/// Converts any array-like of shape (N, 3) to a C-contiguous float64 NumPy array (one NumPy
/// call, no copy when it already is one).
fn pairs_array<'py>(
    py: Python<'py>,
    obj: &Bound<'py, PyAny>,
    name: &str,
) -> PyResult<Bound<'py, numpy::PyArray2<f64>>> {
    let np = py.import("numpy")?;
    let kwargs = PyDict::new(py);
    kwargs.set_item("dtype", np.getattr("float64")?)?;
    let arr = np.call_method("ascontiguousarray", (obj,), Some(&kwargs))?;
    let arr = arr.cast_into::<numpy::PyArray2<f64>>().map_err(|_| {
        py_err(Error::input(format!(
            "{name}: expected an array of shape (N, 3), got {} dimension(s)",
            arr_ndim(obj)
        )))
    })?;
    if arr.shape()[1] != 3 {
        return Err(py_err(Error::input(format!(
            "{name}: expected an array of shape (N, 3), got shape {:?}",
            arr.shape()
        ))));
    }
    Ok(arr)
}

fn arr_ndim(obj: &Bound<'_, PyAny>) -> String {
    obj.getattr("ndim")
        .and_then(|n| n.extract::<usize>())
        .map(|n| n.to_string())
        .unwrap_or_else(|_| "?".into())
}

/// The unit pairs of the last `eval`, kept so that the next one does not allocate and
/// first-touch them again (a call that finds it busy uses a fresh one).
type Scratch = std::sync::Mutex<Vec<(Vec3, Vec3)>>;

/// `eval` shared by `Source` and `Table`: into a new array, or into `out`.
#[allow(clippy::too_many_arguments)]
fn eval_arrays<'py>(
    py: Python<'py>,
    src: &Evaluable,
    scratch: &Scratch,
    wi: &Bound<'py, PyAny>,
    wo: &Bound<'py, PyAny>,
    exact: bool,
    outside_domain_zero: bool,
    out: Option<&Bound<'py, PyAny>>,
) -> PyResult<Bound<'py, PyAny>> {
    let wi = pairs_array(py, wi, "wi")?;
    let wo = pairs_array(py, wo, "wo")?;
    let (wi_r, wo_r) = (wi.readonly(), wo.readonly());
    let slice_err = |e: numpy::AsSliceError| py_err(Error::input(e.to_string()));
    let (a, b) = (
        wi_r.as_slice().map_err(slice_err)?,
        wo_r.as_slice().map_err(slice_err)?,
    );
    let n = a.len() / 3;
    let c = src.brdf().channels().len();
    let opts = EvalOptions {
        exact,
        outside_domain_zero,
    };
    let run = |out: &mut [f64]| {
        py.detach(|| match scratch.try_lock() {
            Ok(mut s) => src.eval_arrays_with(a, b, opts, out, &mut s),
            Err(_) => src.eval_arrays(a, b, opts, out),
        })
        .map_err(py_err)
    };
    if let Some(out) = out {
        let arr = out.cast::<numpy::PyArray2<f64>>().map_err(|_| {
            py_err(Error::input(format!(
                "out: expected a float64 array of shape ({n}, {c})"
            )))
        })?;
        if arr.shape() != [n, c] {
            return Err(py_err(Error::input(format!(
                "out: shape {:?}, expected ({n}, {c})",
                arr.shape()
            ))));
        }
        let mut w = arr.readwrite();
        run(w.as_slice_mut().map_err(slice_err)?)?;
        return Ok(out.clone());
    }
    let mut values = zeroed(n * c).ok_or_else(|| {
        py_err(Error::input(format!(
            "{n} pairs × {c} channels: out of memory"
        )))
    })?;
    run(&mut values)?;
    Ok(PyArray1::from_vec(py, values).reshape([n, c])?.into_any())
}

/// `len` zeros from the allocator's zeroed memory (`calloc`: fresh pages are zero without
/// being written), `None` when it fails. `resize(len, 0.0)` wrote them on the calling thread,
/// a serial pass over the output (24 MB for 10⁶ RGB pairs) before the parallel lookup
/// overwrote it; this way each page is first touched by the thread that writes its values.
fn zeroed(len: usize) -> Option<Vec<f64>> {
    if len == 0 {
        return Some(Vec::new());
    }
    let layout = std::alloc::Layout::array::<f64>(len).ok()?;
    // SAFETY: `layout` has a non-zero size. The memory comes from the global allocator with
    // the layout a `Vec<f64>` of capacity `len` frees it with, and all-zero bytes are a valid
    // f64 (0.0), so all `len` elements are initialized.
    unsafe {
        let p = std::alloc::alloc_zeroed(layout).cast::<f64>();
        (!p.is_null()).then(|| Vec::from_raw_parts(p, len, len))
    }
}

fn json_to_py<'py>(py: Python<'py>, value: &impl serde::Serialize) -> PyResult<Bound<'py, PyAny>> {
    let text =
        serde_json::to_string(value).map_err(|e| py_err(Error::Failure(format!("JSON: {e}"))))?;
    py.import("json")?.call_method1("loads", (text,))
}

/// A BRDF source opened like the CLI opens a name: a model spec (`ggx:alpha=0.2`, JSON,
/// `@file.json`), a table file (.bpk, EXR, MERL .binary, MDL .mbsdf) or an RGL .bsdf file.
#[pyclass(module = "brdfpack", frozen)]
struct Source {
    inner: Evaluable,
    scratch: Scratch,
    kind: &'static str,
    spec: String,
}

#[pymethods]
impl Source {
    /// "model", "table" or "measured".
    #[getter]
    fn kind(&self) -> &'static str {
        self.kind
    }

    /// The channel names (`Y`, `R G B`, `550nm` ...).
    #[getter]
    fn channels(&self) -> Vec<String> {
        self.inner.brdf().channels().names().to_vec()
    }

    /// A one-line description of the source.
    fn describe(&self) -> String {
        self.inner.brdf().describe()
    }

    /// f_r in 1/sr (no cosine factor) at the pairs of `wi` and `wo`, arrays of shape (N, 3)
    /// in the local frame (z = normal), both pointing away from the surface; any finite
    /// non-zero vectors (normalized). Returns float64 of shape (N, channels), the bits
    /// `brdfpack eval` prints. `exact`: one evaluation per pair; otherwise tables take the
    /// batched lookup (the same bits, several times faster). `out`: a C-contiguous
    /// float64 array of shape (N, channels) to write into and return (no allocation).
    #[pyo3(signature = (wi, wo, *, exact = false, outside_domain_zero = false, out = None))]
    fn eval<'py>(
        &self,
        py: Python<'py>,
        wi: &Bound<'py, PyAny>,
        wo: &Bound<'py, PyAny>,
        exact: bool,
        outside_domain_zero: bool,
        out: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<Bound<'py, PyAny>> {
        let (inner, scratch) = (&self.inner, &self.scratch);
        eval_arrays(py, inner, scratch, wi, wo, exact, outside_domain_zero, out)
    }

    /// The source as a `Table` (a copy of its samples) when it is one, else None.
    fn table(&self) -> Option<Table> {
        self.inner
            .table()
            .map(|t| Table::new(t.clone(), None, None))
    }

    fn __repr__(&self) -> String {
        format!("brdfpack.Source({:?}, kind={:?})", self.spec, self.kind)
    }
}

/// A table: samples on a grid, with channels, validity and provenance.
#[pyclass(module = "brdfpack", frozen)]
struct Table {
    inner: Evaluable,
    scratch: Scratch,
    /// The native file's bytes when this table came from `compress` (saved as they are).
    encoded: Option<Vec<u8>>,
    codec: Option<String>,
    metrics: Option<Py<PyAny>>,
}

impl Table {
    fn new(table: CoreTable, encoded: Option<Vec<u8>>, codec: Option<String>) -> Table {
        Table {
            inner: Evaluable::new(CoreSource::Table(table), Lookup::Linear)
                .expect("a table with a linear lookup is always evaluable"),
            scratch: Scratch::default(),
            encoded,
            codec,
            metrics: None,
        }
    }

    fn table(&self) -> &CoreTable {
        self.inner.table().expect("Table holds a table")
    }

    /// The file bytes of this table in the format `path` (or `format`) names.
    fn encode(&self, path: &Path, format: Option<&str>, codec: Option<&str>) -> Result<Vec<u8>> {
        let name = match format {
            Some("native") => FormatName::Native,
            Some("exr") => FormatName::Exr,
            Some("merl") => FormatName::Merl,
            Some("mbsdf") => FormatName::Mbsdf,
            Some(other) => {
                return Err(Error::input(format!(
                    "format {other:?}: expected native, exr, merl or mbsdf"
                )));
            }
            None => FormatName::from_path(path).ok_or_else(|| {
                Error::input(format!(
                    "{}: cannot tell the output format from the name; use .bpk, .exr, \
                     .binary or .mbsdf, or format=\"native\"|\"exr\"|\"merl\"|\"mbsdf\"",
                    path.display()
                ))
            })?,
        };
        let table = self.table();
        let format = match name {
            FormatName::Native => {
                if let (Some(bytes), None) = (&self.encoded, codec) {
                    return Ok(bytes.clone());
                }
                OutputFormat::Native(
                    CodecRequest::parse(codec.unwrap_or("lossless"))?.resolve(table)?,
                )
            }
            FormatName::Exr => OutputFormat::Exr(Default::default()),
            FormatName::Merl => OutputFormat::Merl,
            FormatName::Mbsdf => OutputFormat::Mbsdf(Default::default()),
            FormatName::Rgl => {
                return Err(Error::input(
                    "an RGL .bsdf is written from a BRDF by `brdfpack convert SOURCE -o \
                     out.bsdf`, not from a table",
                ));
            }
        };
        io::encode_table(table, &format)
    }
}

#[pymethods]
impl Table {
    #[getter]
    fn kind(&self) -> &'static str {
        "table"
    }

    /// The channel names.
    #[getter]
    fn channels(&self) -> Vec<String> {
        self.table().channels().names().to_vec()
    }

    /// The grid in words (`halfdiff3 90x90x360 (warp sqrt/linear/linear; at edge/...)`).
    #[getter]
    fn grid(&self) -> String {
        self.table().grid().describe()
    }

    /// The grid as stored in file headers: {"kind", "axes": [{"quantity", "n", "warp",
    /// "placement"}], "theta_max_deg"?, "interp_weight"?, "interp_space"?, "horizon"?}.
    #[getter]
    fn grid_desc<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        json_to_py(py, &self.table().grid().desc())
    }

    /// Per axis in storage order: a dict with "quantity", "n", "warp", "placement",
    /// "range" (lo, hi in radians), "periodic" and "samples" (the n sample angles in radians,
    /// float64).
    #[getter]
    fn axes<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyList>> {
        let desc = self.table().grid().desc();
        let list = PyList::empty(py);
        for (a, d) in self.table().grid().axes().iter().zip(&desc.axes) {
            let dict = json_to_py(py, d)?.cast_into::<PyDict>()?;
            dict.set_item("range", a.range())?;
            dict.set_item("periodic", a.is_periodic())?;
            let samples: Vec<f64> = (0..a.n).map(|i| a.sample(i)).collect();
            dict.set_item("samples", PyArray1::from_vec(py, samples))?;
            list.append(dict)?;
        }
        Ok(list)
    }

    /// The grid's resolution per axis (storage order).
    #[getter]
    fn shape(&self) -> Vec<usize> {
        self.table().grid().shape()
    }

    /// The samples, float32 of shape (*shape, channels) (a copy).
    #[getter]
    fn data<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let t = self.table();
        let mut dims = t.grid().shape();
        dims.push(t.channels().len());
        Ok(PyArray1::from_slice(py, t.data()).reshape(dims)?.into_any())
    }

    /// Which cells hold a value, bool of shape `shape` (a copy).
    #[getter]
    fn valid<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let t = self.table();
        Ok(PyArray1::from_slice(py, t.valid())
            .reshape(t.grid().shape())?
            .into_any())
    }

    /// Where the samples came from (the source spec or file), and notes on choices that
    /// change meaning.
    #[getter]
    fn provenance<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        json_to_py(py, self.table().provenance())
    }

    /// The codec the table was compressed with (`compress`) or stored with (`.bpk`), as the
    /// file header records it (a dict with "kind" and its stages), else None.
    #[getter]
    fn codec<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyAny>>> {
        self.codec
            .as_ref()
            .map(|json| py.import("json")?.call_method1("loads", (json,)))
            .transpose()
    }

    /// `compress`'s measured error of this table against its input (a dict), else None.
    #[getter]
    fn metrics(&self, py: Python<'_>) -> Option<Py<PyAny>> {
        self.metrics.as_ref().map(|m| m.clone_ref(py))
    }

    /// As `Source.eval`.
    #[pyo3(signature = (wi, wo, *, exact = false, outside_domain_zero = false, out = None))]
    fn eval<'py>(
        &self,
        py: Python<'py>,
        wi: &Bound<'py, PyAny>,
        wo: &Bound<'py, PyAny>,
        exact: bool,
        outside_domain_zero: bool,
        out: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<Bound<'py, PyAny>> {
        let (inner, scratch) = (&self.inner, &self.scratch);
        eval_arrays(py, inner, scratch, wi, wo, exact, outside_domain_zero, out)
    }

    /// Writes the table atomically in the format the name says (.bpk, .exr, .binary,
    /// .mbsdf) or `format` names. Native files use `codec` (default: the bytes `compress`
    /// made, else `lossless`).
    #[pyo3(signature = (path, *, format = None, codec = None))]
    fn save(
        &self,
        py: Python<'_>,
        path: std::path::PathBuf,
        format: Option<&str>,
        codec: Option<&str>,
    ) -> PyResult<()> {
        py.detach(|| {
            let bytes = self.encode(&path, format, codec)?;
            atomic::write_output(&path, &bytes)
        })
        .map_err(py_err)
    }

    /// The file bytes in `format` (default native).
    #[pyo3(signature = (*, format = "native", codec = None))]
    fn to_bytes<'py>(
        &self,
        py: Python<'py>,
        format: &str,
        codec: Option<&str>,
    ) -> PyResult<Bound<'py, PyBytes>> {
        let bytes = py
            .detach(|| self.encode(Path::new("<bytes>"), Some(format), codec))
            .map_err(py_err)?;
        Ok(PyBytes::new(py, &bytes))
    }

    fn __repr__(&self) -> String {
        let t = self.table();
        format!(
            "brdfpack.Table(grid={:?}, channels={:?})",
            t.grid().describe(),
            t.channels().names()
        )
    }
}

/// Opens `spec` like the CLI: a model spec, else an existing file by its content.
/// `interp` ("linear", "nearest", "merl") is how a table is evaluated; `clamp_negative`
/// clamps negative values of a measured (RGL) source to 0.
#[pyfunction]
#[pyo3(signature = (spec, *, interp = "linear", clamp_negative = false))]
fn open(py: Python<'_>, spec: String, interp: &str, clamp_negative: bool) -> PyResult<Source> {
    let lookup = lookup(interp).map_err(py_err)?;
    py.detach(|| {
        let src = match CoreSource::open(&spec)? {
            CoreSource::Measured(m) if clamp_negative => {
                CoreSource::Measured(m.with_clamp_negative(true))
            }
            other => other,
        };
        let kind = match &src {
            CoreSource::Table(_) => "table",
            CoreSource::Measured(_) => "measured",
            CoreSource::Model(_) => "model",
        };
        Ok(Source {
            inner: Evaluable::new(src, lookup)?,
            scratch: Scratch::default(),
            kind,
            spec: spec.clone(),
        })
    })
    .map_err(py_err)
}

/// The codec summary of native file bytes.
fn native_codec(bytes: &[u8], path: &Path) -> Option<String> {
    native::is_native(bytes)
        .then(|| native::read_header(bytes, path).ok())
        .flatten()
        .map(|h| h.codec.summary())
}

/// Reads a table file (native .bpk, EXR, MERL .binary, MDL .mbsdf).
#[pyfunction]
fn load(py: Python<'_>, path: std::path::PathBuf) -> PyResult<Table> {
    py.detach(|| {
        let bytes = atomic::read_input(&path)?;
        let table = io::decode_table(&bytes, &path)?;
        Ok(Table::new(table, None, native_codec(&bytes, &path)))
    })
    .map_err(py_err)
}

/// A table from file bytes (any table format, detected by content).
#[pyfunction]
#[pyo3(signature = (data, *, name = "<bytes>"))]
fn loads(data: &[u8], name: &str) -> PyResult<Table> {
    let path = Path::new(name);
    let table = io::decode_table(data, path).map_err(py_err)?;
    Ok(Table::new(table, None, native_codec(data, path)))
}

/// A source from a spec string, a `Source` or a `Table`.
enum SourceArg<'a> {
    Spec(String),
    Object(&'a Evaluable),
}

fn source_arg<'a>(obj: &'a Bound<'_, PyAny>) -> PyResult<SourceArg<'a>> {
    if let Ok(s) = obj.extract::<String>() {
        return Ok(SourceArg::Spec(s));
    }
    if let Ok(s) = obj.cast::<Source>() {
        return Ok(SourceArg::Object(&s.get().inner));
    }
    if let Ok(t) = obj.cast::<Table>() {
        return Ok(SourceArg::Object(&t.get().inner));
    }
    Err(pyo3::exceptions::PyTypeError::new_err(
        "expected a spec string, a brdfpack.Source or a brdfpack.Table",
    ))
}

/// Samples a source onto a grid (`merl`, or KIND:DIMS[,warp=..][,at=..][,theta-max=DEG];
/// docs/parameterizations.md), as `brdfpack tabulate`.
#[pyfunction]
#[pyo3(signature = (source, grid = "merl", *, interp = "linear", allow_anisotropic = false,
    allow_nonreciprocal = false, clamp_negative = false, to_rgb = false))]
#[allow(clippy::too_many_arguments)]
fn tabulate(
    py: Python<'_>,
    source: &Bound<'_, PyAny>,
    grid: &str,
    interp: &str,
    allow_anisotropic: bool,
    allow_nonreciprocal: bool,
    clamp_negative: bool,
    to_rgb: bool,
) -> PyResult<Table> {
    let source = source_arg(source)?;
    let lookup = lookup(interp).map_err(py_err)?;
    py.detach(|| {
        let grid = parse_grid_spec(grid)?;
        let opened;
        let brdf = match &source {
            SourceArg::Spec(s) => {
                let src = match CoreSource::open(s)? {
                    CoreSource::Measured(m) if clamp_negative => {
                        CoreSource::Measured(m.with_clamp_negative(true))
                    }
                    other => other,
                };
                opened = src.into_brdf(lookup)?;
                opened.as_ref()
            }
            SourceArg::Object(e) => e.brdf(),
        };
        let opts = TabulateOptions {
            allow_anisotropic,
            allow_nonreciprocal,
            fill_own_holes: false,
            progress: None,
        };
        let table = core_tabulate(brdf, &grid, &opts)?;
        let table = if to_rgb {
            brdfpack_core::table::spectral_to_rgb(&table)?
        } else {
            table
        };
        Ok(Table::new(table, None, None))
    })
    .map_err(py_err)
}

/// The table to compress: a table as is, other sources tabulated on `grid` (default merl).
fn table_input(source: &SourceArg, grid: Option<&str>) -> Result<CoreTable> {
    let opened;
    let brdf: &dyn brdfpack_core::brdf::Brdf = match source {
        SourceArg::Spec(s) => match CoreSource::open(s)? {
            CoreSource::Table(t) => return table_as_is(t, grid),
            other => {
                opened = other.into_brdf(Lookup::Linear)?;
                opened.as_ref()
            }
        },
        SourceArg::Object(e) => match e.table() {
            Some(t) => return table_as_is(t.clone(), grid),
            None => e.brdf(),
        },
    };
    let grid = parse_grid_spec(grid.unwrap_or("merl"))?;
    core_tabulate(brdf, &grid, &TabulateOptions::default())
}

/// A table input is compressed on its own grid: `grid` is refused for it (as the CLI does).
fn table_as_is(table: CoreTable, grid: Option<&str>) -> Result<CoreTable> {
    match grid {
        Some(g) => Err(already_a_table(g)),
        None => Ok(table),
    }
}

fn already_a_table(grid: &str) -> Error {
    Error::input(format!(
        "grid {grid}: the input is already a table (re-grid it with tabulate first)"
    ))
}

/// Re-encodes a table (or tabulates a source on `grid` first) with `codec`
/// (`lossless`, `dct:step=0.02`, `uniform:bits=12`, `f16` ...; docs/compression.md), or the
/// smallest file meeting the error budget `max_error` (`log_rmse=0.01,p99_rel_core=0.2`), as
/// `brdfpack compress`. Returns the decoded table; `.codec` names the codec, `.metrics` the
/// error against the input, `.save()` writes the compressed bytes.
#[pyfunction]
#[pyo3(signature = (source, *, codec = None, max_error = None, grid = None, samples = 65536,
    seed = 1, effort = "default"))]
#[allow(clippy::too_many_arguments)]
fn compress(
    py: Python<'_>,
    source: &Bound<'_, PyAny>,
    codec: Option<&str>,
    max_error: Option<&str>,
    grid: Option<&str>,
    samples: usize,
    seed: u64,
    effort: &str,
) -> PyResult<Table> {
    let source = source_arg(source)?;
    let (bytes, metrics) = py
        .detach(|| -> Result<_> {
            if samples == 0 || samples > 100_000_000 {
                return Err(Error::input(format!(
                    "samples {samples} is out of range [1, 100000000]"
                )));
            }
            let effort = Effort::parse(effort)?;
            match (codec, max_error) {
                (Some(_), Some(_)) => Err(Error::input(
                    "codec and max_error exclude each other: give one (or neither: lossless)",
                )),
                (_, Some(budget)) => {
                    let settings = PackSettings {
                        budget: Budget::parse(budget)?,
                        effort,
                        check_samples: samples,
                        check_seed: seed,
                    };
                    let opened;
                    // A table file is read again if the lossless chain is chosen, so that the
                    // encoder can decode its candidates into the table's memory meanwhile.
                    let again = |s: &str| -> Result<Vec<f32>> {
                        match CoreSource::open(s)? {
                            CoreSource::Table(t) => Ok(t.into_samples()),
                            _ => Err(Error::Failure(format!(
                                "{s}: the file changed while it was being compressed"
                            ))),
                        }
                    };
                    let spec_again;
                    let input = match &source {
                        SourceArg::Spec(s) => match CoreSource::open(s)? {
                            CoreSource::Table(t) => {
                                let regular = std::fs::metadata(s).is_ok_and(|m| m.is_file());
                                spec_again = move || again(s);
                                PackInput::Table {
                                    table: Cow::Owned(t),
                                    again: regular
                                        .then_some(&spec_again as brdfpack_core::plan::rate::Again),
                                }
                            }
                            other => {
                                opened = other.into_brdf(Lookup::Linear)?;
                                source_input(opened.as_ref(), grid)?
                            }
                        },
                        SourceArg::Object(e) => match e.table() {
                            Some(t) => PackInput::Table {
                                table: Cow::Borrowed(t),
                                again: None,
                            },
                            None => source_input(e.brdf(), grid)?,
                        },
                    };
                    if let (PackInput::Table { .. }, Some(g)) = (&input, grid) {
                        return Err(already_a_table(g));
                    }
                    let planned = plan(input, &settings, &|_| {})?;
                    let bytes = native::to_bytes_with_payload(
                        &planned.table,
                        &planned.encoded.spec,
                        &planned.encoded.payload,
                    )?;
                    let est = &planned.encoded.estimate;
                    let m = est.check.clone().unwrap_or_else(|| est.metrics.clone());
                    Ok((bytes, m))
                }
                (codec, None) => {
                    let table = table_input(&source, grid)?;
                    let set = SampleSet::uniform(samples, seed);
                    let spec = CodecRequest::parse(codec.unwrap_or("lossless"))?.resolve(&table)?;
                    let measured = brdfpack_core::plan::search::Evaluator::new(&table, &set)?
                        .measure(&spec)?;
                    let bytes = native::to_bytes(&table, &measured.spec)?;
                    Ok((bytes, measured.metrics))
                }
            }
        })
        .map_err(py_err)?;
    let path = Path::new("<compressed>");
    let decoded = native::from_bytes(&bytes, path).map_err(py_err)?;
    let codec = native_codec(&bytes, path);
    let mut t = Table::new(decoded, Some(bytes), codec);
    t.metrics = Some(json_to_py(py, &metrics)?.unbind());
    Ok(t)
}

fn source_input<'a>(
    brdf: &'a dyn brdfpack_core::brdf::Brdf,
    grid: Option<&str>,
) -> Result<PackInput<'a>> {
    Ok(PackInput::Source {
        source: brdf,
        grid: grid.map(parse_grid_spec).transpose()?,
        options: TabulateOptions::default(),
    })
}

/// The round-trip error of `candidate` against `reference` (spec strings, Sources or
/// Tables), as `brdfpack check --json`: a dict with the `uniform` set's metrics (combined
/// and per channel), the other sets and their worst values, and albedo_err.
#[pyfunction]
#[pyo3(signature = (reference, candidate, *, samples = 65536, seed = 1, uniform_only = false,
    interp = "linear"))]
fn check<'py>(
    py: Python<'py>,
    reference: &Bound<'py, PyAny>,
    candidate: &Bound<'py, PyAny>,
    samples: usize,
    seed: u64,
    uniform_only: bool,
    interp: &str,
) -> PyResult<Bound<'py, PyAny>> {
    let (reference, candidate) = (source_arg(reference)?, source_arg(candidate)?);
    let lookup = lookup(interp).map_err(py_err)?;
    let report = py
        .detach(|| {
            if samples == 0 || samples > 100_000_000 {
                return Err(Error::input(format!(
                    "samples {samples} is out of range [1, 100000000]"
                )));
            }
            let cand_opened;
            let cand = match &candidate {
                SourceArg::Spec(s) => {
                    cand_opened = Evaluable::new(CoreSource::open(s)?, lookup)?;
                    &cand_opened
                }
                SourceArg::Object(e) => *e,
            };
            let ref_opened;
            let reference = match &reference {
                SourceArg::Spec(s) => {
                    ref_opened = Evaluable::new(CoreSource::open(s)?, lookup)?;
                    &ref_opened
                }
                SourceArg::Object(e) => *e,
            };
            let cells = cand.table().map(|t| (t.grid(), t.valid()));
            brdfpack_core::check::check(
                reference.brdf(),
                cand.brdf(),
                cells,
                &CheckOptions {
                    samples,
                    seed,
                    all_sets: !uniform_only,
                },
            )
        })
        .map_err(py_err)?;
    json_to_py(py, &report)
}

/// The sample sets of docs/metrics.md as arrays: `kind` "uniform", "grazing" or
/// "specular", `n` pairs from `seed`. Returns (wi, wo), float64 of shape (n, 3) each.
#[pyfunction]
#[pyo3(signature = (n, *, kind = "uniform", seed = 1))]
fn sample_pairs<'py>(
    py: Python<'py>,
    n: usize,
    kind: &str,
    seed: u64,
) -> PyResult<(Bound<'py, PyAny>, Bound<'py, PyAny>)> {
    let set = py
        .detach(|| -> Result<SampleSet> {
            brdfpack_core::memory::require(
                &format!("{n} direction pairs"),
                brdfpack_core::memory::pair_bytes(n),
            )?;
            match kind {
                "uniform" => Ok(SampleSet::uniform(n, seed)),
                "grazing" => Ok(SampleSet::grazing(n, seed)),
                "specular" => Ok(SampleSet::specular(n, seed)),
                other => Err(Error::input(format!(
                    "kind {other:?}: expected \"uniform\", \"grazing\" or \"specular\""
                ))),
            }
        })
        .map_err(py_err)?;
    let n = set.pairs.len();
    let mut wi = Vec::with_capacity(n * 3);
    let mut wo = Vec::with_capacity(n * 3);
    for (a, b) in &set.pairs {
        wi.extend_from_slice(&a.to_array());
        wo.extend_from_slice(&b.to_array());
    }
    Ok((
        PyArray1::from_vec(py, wi).reshape([n, 3])?.into_any(),
        PyArray1::from_vec(py, wo).reshape([n, 3])?.into_any(),
    ))
}

/// brdfpack: BRDF tables in Python. Open any source the CLI opens, evaluate it on NumPy
/// arrays of direction pairs, tabulate, compress, check, save and load (docs/bindings.md).
#[pymodule]
#[pyo3(name = "brdfpack")]
fn brdfpack_module(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add("BrdfpackError", m.py().get_type::<BrdfpackError>())?;
    m.add_class::<Source>()?;
    m.add_class::<Table>()?;
    m.add_function(wrap_pyfunction!(open, m)?)?;
    m.add_function(wrap_pyfunction!(load, m)?)?;
    m.add_function(wrap_pyfunction!(loads, m)?)?;
    m.add_function(wrap_pyfunction!(tabulate, m)?)?;
    m.add_function(wrap_pyfunction!(compress, m)?)?;
    m.add_function(wrap_pyfunction!(check, m)?)?;
    m.add_function(wrap_pyfunction!(sample_pairs, m)?)?;
    Ok(())
}
