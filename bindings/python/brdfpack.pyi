"""brdfpack: BRDF tables in Python (docs/bindings.md).

Open any source the CLI opens (a model spec, a .bpk, EXR, MERL .binary, MDL .mbsdf or RGL
.bsdf file), evaluate it on NumPy arrays of direction pairs (the GIL is released; no Python
work per pair), tabulate, compress, check, save and load. Errors raise `BrdfpackError` with
the CLI's message.

Directions: local frame, z = normal, x = tangent; `wi` towards the light, `wo` towards the
viewer, both pointing away from the surface. f_r in 1/sr without the cosine factor.
"""

from os import PathLike
from typing import Any, Literal, Optional, Union

import numpy as np
import numpy.typing as npt

__version__: str

Interp = Literal["linear", "nearest", "merl"]
ArrayLike = npt.ArrayLike

class BrdfpackError(Exception):
    """An error with the CLI's message (`brdfpack: ...`)."""

    exit_code: int
    """The CLI's exit code for it: 2 bad input or file, 1 a failure."""

class Source:
    """A source opened like the CLI opens a name."""

    @property
    def kind(self) -> Literal["model", "table", "measured"]: ...
    @property
    def channels(self) -> list[str]:
        """Channel names: `Y`, `R G B`, or spectral `550nm` ..."""
    def describe(self) -> str: ...
    def eval(
        self,
        wi: ArrayLike,
        wo: ArrayLike,
        *,
        exact: bool = False,
        outside_domain_zero: bool = False,
        out: Optional[npt.NDArray[np.float64]] = None,
    ) -> npt.NDArray[np.float64]:
        """f_r at the pairs of `wi`, `wo` (arrays of shape (N, 3), any finite non-zero
        vectors, normalized) as float64 of shape (N, channels); 0 below the horizon.

        Values are the bits `brdfpack eval` prints. `exact`: one evaluation per pair;
        otherwise tables take the batched lookup (the same bits, several times faster). Pairs beyond a table's stored θmax raise
        unless `outside_domain_zero`. `out`: a C-contiguous float64 array of shape
        (N, channels) to write into (and return) instead of a new one."""
    def table(self) -> Optional[Table]:
        """The source as a Table (a copy of its samples) when it is one, else None."""

class Table:
    """Samples on a grid with channels, validity and provenance."""

    @property
    def kind(self) -> Literal["table"]: ...
    @property
    def channels(self) -> list[str]: ...
    @property
    def grid(self) -> str:
        """The grid in words, e.g. `halfdiff3 90x90x360 (warp sqrt/linear/linear; at edge/edge/edge)`."""
    @property
    def grid_desc(self) -> dict[str, Any]:
        """The grid as file headers store it: {"kind", "axes": [{"quantity", "n", "warp",
        "placement"}], "theta_max_deg"?, "interp_weight"? ("cosine"), "interp_space"?
        ({"log": {"scale": s}}: values combined as asinh(v/s), docs/parameterizations.md)}."""
    @property
    def axes(self) -> list[dict[str, Any]]:
        """Per axis in storage order: "quantity", "n", "warp", "placement", "range" (lo, hi
        in radians), "periodic", "samples" (float64 of shape (n,), radians)."""
    @property
    def shape(self) -> list[int]:
        """Resolution per axis, storage order."""
    @property
    def data(self) -> npt.NDArray[np.float32]:
        """The samples, float32 of shape (*shape, channels) (a copy)."""
    @property
    def valid(self) -> npt.NDArray[np.bool_]:
        """Which cells hold a value, bool of shape `shape` (a copy)."""
    @property
    def provenance(self) -> dict[str, Any]:
        """{"source", "tool", "notes"?}: where the samples came from."""
    @property
    def codec(self) -> Optional[dict[str, Any]]:
        """The codec of a compressed or loaded native table as its header records it (a dict
        with "kind", e.g. "dct_context", and its stages), else None."""
    @property
    def metrics(self) -> Optional[dict[str, Any]]:
        """`compress`'s measured error against its input, else None."""
    def eval(
        self,
        wi: ArrayLike,
        wo: ArrayLike,
        *,
        exact: bool = False,
        outside_domain_zero: bool = False,
        out: Optional[npt.NDArray[np.float64]] = None,
    ) -> npt.NDArray[np.float64]:
        """As `Source.eval` (linear interpolation)."""
    def save(
        self,
        path: Union[str, PathLike[str]],
        *,
        format: Optional[Literal["native", "exr", "merl", "mbsdf"]] = None,
        codec: Optional[str] = None,
    ) -> None:
        """Writes atomically in the format of the name (.bpk, .exr, .binary, .mbsdf) or
        `format`. Native files: `codec` (default the bytes `compress` made, else lossless)."""
    def to_bytes(
        self,
        *,
        format: Literal["native", "exr", "merl", "mbsdf"] = "native",
        codec: Optional[str] = None,
    ) -> bytes: ...

SourceLike = Union[str, Source, Table]

def open(spec: str, *, interp: Interp = "linear", clamp_negative: bool = False) -> Source:
    """Opens a model spec (`ggx:alpha=0.2,fresnel=au`, JSON, `@file.json`), else an
    existing file by its content. `interp`: how a table is evaluated; `clamp_negative`:
    clamp negative values of a measured (RGL) source to 0."""

def load(path: Union[str, PathLike[str]]) -> Table:
    """Reads a table file (native .bpk, EXR, MERL .binary, MDL .mbsdf)."""

def loads(data: bytes, *, name: str = "<bytes>") -> Table:
    """A table from file bytes (format detected by content)."""

def tabulate(
    source: SourceLike,
    grid: str = "merl",
    *,
    interp: Interp = "linear",
    allow_anisotropic: bool = False,
    allow_nonreciprocal: bool = False,
    clamp_negative: bool = False,
    to_rgb: bool = False,
) -> Table:
    """Samples a source on a grid (`merl` or KIND:DIMS[,warp=..][,at=..][,theta-max=DEG];
    docs/parameterizations.md), as `brdfpack tabulate`."""

def compress(
    source: SourceLike,
    *,
    codec: Optional[str] = None,
    max_error: Optional[str] = None,
    grid: Optional[str] = None,
    samples: int = 65536,
    seed: int = 1,
    effort: Literal["fast", "default", "max"] = "default",
) -> Table:
    """Encodes a table (a source is tabulated on `grid`, default merl, first) with `codec`
    (docs/compression.md; default lossless) or as the smallest file meeting the error
    budget `max_error` (e.g. `log_rmse=0.01,p99_rel_core=0.2`), as `brdfpack compress`.
    Returns the decoded table; `.codec`, `.metrics`, and `.save()` writes the encoded bytes."""

def check(
    reference: SourceLike,
    candidate: SourceLike,
    *,
    samples: int = 65536,
    seed: int = 1,
    uniform_only: bool = False,
    interp: Interp = "linear",
) -> dict[str, Any]:
    """The error of `candidate` against `reference` with the metrics of docs/metrics.md:
    the dict `brdfpack check --json` prints (without `bounds_exceeded`)."""

def sample_pairs(
    n: int, *, kind: Literal["uniform", "grazing", "specular"] = "uniform", seed: int = 1
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """The sample sets of docs/metrics.md: (wi, wo), unit vectors of shape (n, 3) each."""
