"""The optimizer checkpoint format: a data-only document from which no code can run.

A store file is shared and downloaded, and a worker resumes a run from the run's last
``generations.checkpoint`` blob: whatever that blob says is untrusted input. Checkpoints
used to be pickles, and unpickling runs whatever callable the pickle names
(``os.system`` ...). This module replaces pickle by an explicit, versioned document.

Format (``MAGIC`` then zlib-compressed UTF-8 JSON)::

    b"CMRT-CKPT-1\\n" + zlib(json({"format": 1, "pycma": "4.5.0", "root": <node>}))

A node is a JSON ``null``/``true``/``false``/int/float (``NaN``, ``Infinity`` allowed)/string
for the same Python value (exact type: a ``numpy.float64`` is not a ``float``), or a tagged
array (``id`` numbers the mutable objects in the order they are first met, from 0):

* ``["L", id, [node...]]`` a list, ``["T", [node...]]`` a tuple, ``["N", start, stop, step]`` a range;
* ``["D", id, [[key, node]...]]`` a dict (keys: None/bool/int/float/str, numpy scalars, tuples of keys);
* ``["A", id, dtype, shape, order, base64]`` a numpy array of an allowlisted numeric dtype, order "C"/"F";
* ``["S", dtype, value]`` a numpy scalar;
* ``["G", id, bit_generator, state]`` a ``numpy.random.Generator`` and its ``bit_generator.state``;
* ``["O", id, "module:qualname", [[attribute, node]...], items]`` an instance of an allowlisted class
  (``items``: null, or its entries when the class derives from dict or list; a module path cmrt has moved
  since is read at its new home, ``MOVED_MODULES``);
* ``["F", "module:qualname"]`` an allowlisted function or class used as a value;
* ``["R", id]`` the object numbered ``id`` again (identity and cycles survive:
  ``state.randn`` and the ES's ``opts['randn']`` stay ONE generator).

Why this and not pickle with a restricted ``find_class``: a restricted unpickler still
*calls* what it admits (``__reduce__`` callables, ``__setstate__``), so its safety rests on
every admitted callable being harmless with attacker-chosen arguments. Here reading calls
nothing named by the data: an instance of an allowlisted class is made by the builtin
``object.__new__`` (``dict.__new__``/``list.__new__`` for pycma's dict and list subclasses, whose
entries go in through ``dict.__setitem__``/``list.extend``, not the subclass's methods) and a
``__dict__.update`` - never a constructor, ``__init__``, ``__setstate__``, ``__reduce__`` or
``eval``; an attribute may not hide a method or property of its class. A generator is built
from an allowlisted bit generator class and given its state through the ``.state`` setter;
arrays come from bytes (``numpy.frombuffer``, never ``dtype=object``). A function only ever
comes back as one of the four objects in ``FUNCTIONS``, by name lookup in that table. The
document's size (decompressed), nesting depth and array sizes (which must match their
bytes) are bounded before anything is allocated for them.

What it does not do by itself: the *values* in the document are attacker-chosen, and the
pycma code that later runs on the rebuilt objects could misuse some of them (pycma
``eval``s string options). The semantic checks that close that gap (the options are
rebuilt from the run's settings and must match) live with the state in
:mod:`cmrt.optimize.driver`.

Anything outside the allowlists is refused: on writing with ``TypeError`` (a cmrt bug: the
state grew a type nobody vetted - a test fails), on reading with :class:`InvalidCheckpoint`
(a ``CmrtError``: the worker marks the run failed with that one-line message). A pickle
written by an older cmrt (it starts with ``0x80``) is refused too, never unpickled.

The allowlists are what pycma 4.5 keeps in a ``CMAEvolutionStrategy`` for cmrt's options
(see ``tests/optimize/test_checkpoint.py``, which checks the census); the pycma version is in the
document and a checkpoint written under another pycma is refused: its internals (and
so a bit-identical resume) are not guaranteed across versions.
"""

from __future__ import annotations

import base64
import functools
import inspect
import json
import math
import sys
import warnings
import zlib
from typing import Any

import numpy as np

from cmrt.errors import CmrtError


def import_cma():
    """pycma, without the 1.5 s its package import spends loading matplotlib (for ``cma.s``'s plotting) and
    scipy.stats (for the surrogate models' Kendall tau): pycma guards both imports and falls back when they
    fail, and the optimizer uses neither. Marking the two packages absent in ``sys.modules`` for the length
    of the import makes them fail; the marks are removed after, so a later ``import matplotlib`` (cmrt.viz.plot,
    a user's script) works as usual, as does ``cma.plot``, which imports pyplot when called. A package
    already imported is left alone. tests/optimize/test_checkpoint.py checks both."""
    absent = [name for name in ("matplotlib", "scipy.stats") if name not in sys.modules]
    for name in absent:
        sys.modules[name] = None  # the documented way to make an import raise ImportError
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # pycma warns that matplotlib is missing
            import cma
            import cma.boundary_handler  # the modules whose classes a checkpoint may name (below)
            import cma.evolution_strategy
            import cma.logger
            import cma.optimization_tools
            import cma.options_parameters
            import cma.recombination_weights
            import cma.sampler
            import cma.sigma_adaptation
            import cma.transformations
            import cma.utilities.utils
    finally:
        for name in absent:
            if name in sys.modules and sys.modules[name] is None:
                del sys.modules[name]
    return cma


cma = import_cma()

MAGIC = b"CMRT-CKPT-1\n"
FORMAT = 1
PICKLE_PREFIX = b"\x80"
MAX_DOCUMENT_BYTES = 64 * 2**20  # decompressed; a real checkpoint is ~100 kB
MAX_DEPTH = 64  # nesting of the document; a real one is < 15
_CMA_VERSION = cma.__version__


class InvalidCheckpoint(CmrtError):
    """A checkpoint blob that is not a cmrt checkpoint this cmrt can resume; nothing of it was run."""


def _name(obj: Any) -> str:
    return f"{obj.__module__}:{obj.__qualname__}"


#: Old homes of the classes a checkpoint names: before cmrt's modules moved into layer packages (issue 28)
#: ``CmaState`` and ``_Randn`` lived in ``cmrt.optimize`` (now ``cmrt.optimize.driver``), so the checkpoints of
#: runs in flight across the move say ``cmrt.optimize:CmaState``. A name is read at its new home; the class must
#: still be on the reader's allowlist. Writing always uses the current names.
MOVED_MODULES: dict[str, str] = {"cmrt.optimize": "cmrt.optimize.driver"}


def current_name(name: str) -> str:
    """A checkpoint's ``module:qualname`` with an old module path (``MOVED_MODULES``) replaced by its new one."""
    module, sep, qualname = name.partition(":")
    return f"{MOVED_MODULES[module]}:{qualname}" if sep and module in MOVED_MODULES else name


#: Classes whose instances may be in a checkpoint: the pycma objects a CMAEvolutionStrategy holds for
#: cmrt's options. cmrt's own classes (CmaState, the generator wrapper) are added by the caller.
PYCMA_CLASSES: tuple[type, ...] = (
    cma.boundary_handler.BoundNone,
    cma.evolution_strategy.CMAEvolutionStrategy,
    cma.evolution_strategy._CMASolutionDict_empty,
    cma.evolution_strategy._CMASolutionDict_functional,
    cma.evolution_strategy._CMAStopDict,
    cma.evolution_strategy._StopTolXStagnation,
    cma.logger.CMADataLogger,
    cma.optimization_tools.BestSolution,
    cma.options_parameters.CMAOptions,
    cma.options_parameters.CMAParameters,
    cma.recombination_weights.RecombinationWeights,
    cma.sampler.GaussFullSampler,
    cma.sigma_adaptation.CMAAdaptSigmaCSA,
    cma.transformations.DiagonalDecoding,
    cma.transformations.GenoPheno,
    cma.transformations.RoundIntegerVariables,
    cma.utilities.utils.BlancClass,
    cma.utilities.utils.DictFromTagsInString,
    cma.utilities.utils.ElapsedWCTime,
    cma.utilities.utils.MoreToWrite,
    cma.utilities.utils.SolutionDict,
)

#: Functions and classes that occur as *values* in the state (pycma's option defaults and its no-op
#: integer handling); read back only by looking the name up here.
FUNCTIONS: dict[str, Any] = {
    _name(f): f for f in (
        cma.evolution_strategy._pass,  # es.integer_centering
        cma.options_parameters.is_feasible,  # opts['is_feasible']
        np.linalg.eigh,  # opts['CMA_eigenmethod']
        cma.boundary_handler.BoundTransform,  # opts['BoundaryHandler'] (BoundNone is used: no bounds)
    )
}

#: Numeric dtypes arrays and numpy scalars may have (no object, string, structured or void dtypes).
DTYPES: dict[str, np.dtype] = {
    d.str: d for d in map(np.dtype, ("?", "<i1", "<i2", "<i4", "<i8", "<u1", "<u2", "<u4", "<u8",
                                     "<f2", "<f4", "<f8", "<c8", "<c16"))
}
_SCALAR_VALUE = {"b": bool, "i": int, "u": int, "f": float}  # dtype.kind -> the JSON value's type

#: Bit generators a numpy Generator may be rebuilt on (the state is restored via ``.state``).
BIT_GENERATORS: dict[str, type] = {
    c.__name__: c for c in (np.random.PCG64, np.random.PCG64DXSM, np.random.MT19937, np.random.Philox,
                            np.random.SFC64)
}

_PLAIN = (type(None), bool, int, float, str)


# --- writing --------------------------------------------------------------------------------------------

class _Encoder:
    def __init__(self, classes: tuple[type, ...]):
        self.classes = set(classes)
        self.functions = {id(f): name for name, f in FUNCTIONS.items()}
        self.memo: dict[int, int] = {}
        self.keep: list[Any] = []  # keeps encoded objects alive so their ids stay unique

    def _remember(self, obj: Any) -> int:
        n = len(self.memo)
        self.memo[id(obj)] = n
        self.keep.append(obj)
        return n

    def encode(self, obj: Any, path: str) -> Any:
        t = type(obj)
        if t in _PLAIN:
            return obj
        if id(obj) in self.functions:
            return ["F", self.functions[id(obj)]]
        if id(obj) in self.memo:
            return ["R", self.memo[id(obj)]]
        if t is tuple:
            return ["T", [self.encode(v, f"{path}[{i}]") for i, v in enumerate(obj)]]
        if t is range:  # pycma's indices of mirrored samples (popsize < 6)
            return ["N", obj.start, obj.stop, obj.step]
        if isinstance(obj, np.generic):
            if obj.dtype.str not in DTYPES or obj.dtype.kind not in _SCALAR_VALUE:
                raise TypeError(f"cannot checkpoint {path}: numpy scalar of dtype {obj.dtype}")
            return ["S", obj.dtype.str, obj.item()]
        if t is list:
            n = self._remember(obj)
            return ["L", n, [self.encode(v, f"{path}[{i}]") for i, v in enumerate(obj)]]
        if t is dict:
            n = self._remember(obj)
            return ["D", n, self._items(obj, path)]
        if t is np.ndarray:
            if obj.dtype.str not in DTYPES:
                raise TypeError(f"cannot checkpoint {path}: array of dtype {obj.dtype}")
            n = self._remember(obj)
            order = "F" if obj.flags.f_contiguous and not obj.flags.c_contiguous else "C"  # as pickle keeps it
            data = base64.b64encode(obj.tobytes(order=order)).decode("ascii")
            return ["A", n, obj.dtype.str, list(obj.shape), order, data]
        if t is np.random.Generator:
            bg = obj.bit_generator
            if type(bg) not in BIT_GENERATORS.values():
                raise TypeError(f"cannot checkpoint {path}: bit generator {type(bg).__name__}")
            state = self.encode(bg.state, f"{path}.bit_generator.state")  # numbered before the generator,
            n = self._remember(obj)  # as the reader rebuilds it first
            return ["G", n, type(bg).__name__, state]
        if t in self.classes:
            n = self._remember(obj)
            attrs = [[k, self.encode(v, f"{path}.{k}")] for k, v in vars(obj).items()]
            items = None
            if isinstance(obj, dict):
                items = self._items(obj, path)
            elif isinstance(obj, list):
                items = [self.encode(v, f"{path}[{i}]") for i, v in enumerate(list.__iter__(obj))]
            return ["O", n, _name(t), attrs, items]
        raise TypeError(f"cannot checkpoint {path}: {_name(t)} is not allowlisted in cmrt.optimize.checkpoint")

    def _items(self, d: dict, path: str) -> list:
        return [[self._key(k, path), self.encode(v, f"{path}[{k!r}]")] for k, v in dict.items(d)]

    def _key(self, k: Any, path: str) -> Any:
        if type(k) in _PLAIN:
            return k
        if type(k) is tuple:
            return ["T", [self._key(v, path) for v in k]]
        if isinstance(k, np.generic):
            return self.encode(k, path)
        raise TypeError(f"cannot checkpoint {path}: dict key of type {type(k).__name__}")


def dumps(root: Any, classes: tuple[type, ...]) -> bytes:
    """The checkpoint blob of ``root``; ``classes`` are allowlisted besides ``PYCMA_CLASSES``.
    TypeError (a bug) if the object graph holds anything outside the allowlists."""
    doc = {"format": FORMAT, "pycma": _CMA_VERSION, "root": _Encoder(PYCMA_CLASSES + classes).encode(root, "root")}
    return pack_document(doc)


def pack_document(doc: dict) -> bytes:
    """MAGIC + compressed JSON of ``doc`` (tests craft documents with it)."""
    text = json.dumps(doc, separators=(",", ":"), allow_nan=True)
    return MAGIC + zlib.compress(text.encode("utf-8"), 6)


# --- reading --------------------------------------------------------------------------------------------

class _Bad(Exception):
    """Why a document is refused (turned into InvalidCheckpoint)."""


def unpack_document(blob: bytes) -> dict:
    """The JSON document inside a checkpoint blob; _Bad if it is not one."""
    if blob[:1] == PICKLE_PREFIX:
        raise _Bad("it is a pickle written by an older cmrt; pickles are never loaded (unpickling a store's "
                   "content could run code), resubmit the run")
    if not blob.startswith(MAGIC):
        raise _Bad(f"unknown format (starts with {bytes(blob[:12])!r}, expected {MAGIC!r})")
    inflate = zlib.decompressobj()
    try:
        raw = inflate.decompress(blob[len(MAGIC):], MAX_DOCUMENT_BYTES)
    except zlib.error as exc:
        raise _Bad(f"corrupt compressed data ({exc})") from None
    if inflate.unconsumed_tail:
        raise _Bad(f"document larger than {MAX_DOCUMENT_BYTES} bytes")
    if not inflate.eof:
        raise _Bad("truncated")
    if inflate.unused_data:
        raise _Bad("trailing bytes after the document")

    def constant(name: str) -> float:
        return {"NaN": math.nan, "Infinity": math.inf, "-Infinity": -math.inf}[name]

    try:
        doc = json.loads(raw.decode("utf-8"), parse_constant=constant)
    except (ValueError, RecursionError) as exc:  # UnicodeDecodeError and JSONDecodeError are ValueErrors
        raise _Bad(f"not JSON ({type(exc).__name__}: {exc})") from None
    if not isinstance(doc, dict) or set(doc) != {"format", "pycma", "root"}:
        raise _Bad("not a checkpoint document")
    if doc["format"] != FORMAT:
        raise _Bad(f"format {doc['format']!r}, this cmrt reads format {FORMAT}")
    if doc["pycma"] != _CMA_VERSION:
        raise _Bad(f"written with pycma {doc['pycma']!r}, this worker has pycma {_CMA_VERSION} (the optimizer's "
                   "internals differ, so the run cannot continue exactly)")
    return doc


def _check(ok: bool, why: str) -> None:
    if not ok:
        raise _Bad(why)


def _shape(x: Any) -> list:
    _check(type(x) is list, "malformed node")
    return x


@functools.lru_cache(maxsize=4096)
def _shadows_code(cls: type, key: str) -> bool:
    """Whether an instance attribute ``key`` would hide a method, property or other descriptor of ``cls``
    (so that pycma calling ``obj.key(...)`` would call whatever the document put there)."""
    static = inspect.getattr_static(cls, key, None)
    return static is not None and (callable(static) or hasattr(type(static), "__get__"))


class _Decoder:
    def __init__(self, classes: tuple[type, ...]):
        self.classes = {_name(c): c for c in classes}
        self.memo: list[Any] = []
        self.done: set[int] = set()  # ids whose content is complete (tuples refer to them freely)
        self.instances: dict[type, list] = {}
        self.depth = 0

    def _register(self, n: Any, obj: Any) -> Any:
        _check(type(n) is int and n == len(self.memo), f"object number {n!r} out of sequence")
        self.memo.append(obj)
        return obj

    def decode(self, node: Any) -> Any:
        if type(node) in _PLAIN:
            return node
        self.depth += 1
        try:
            _check(self.depth <= MAX_DEPTH, "nested too deeply")
            return self._tagged(_shape(node))
        finally:
            self.depth -= 1

    def _tagged(self, node: list) -> Any:
        _check(len(node) >= 2 and type(node[0]) is str, "malformed node")
        tag, args = node[0], node[1:]
        arity = {"L": 2, "T": 1, "N": 3, "D": 2, "A": 5, "S": 2, "G": 3, "O": 4, "F": 1, "R": 1}
        _check(tag in arity and len(args) == arity[tag], f"unknown node {tag!r}/{len(args)}")
        if tag == "R":
            n = args[0]
            _check(type(n) is int and 0 <= n < len(self.memo), f"reference to unknown object {n!r}")
            return self.memo[n]
        if tag == "F":
            _check(type(args[0]) is str and args[0] in FUNCTIONS, f"function {args[0]!r} is not allowlisted")
            return FUNCTIONS[args[0]]
        if tag == "T":
            return tuple(self.decode(v) for v in _shape(args[0]))
        if tag == "S":
            return self._scalar(*args)
        if tag == "N":
            _check(all(type(v) is int for v in args) and args[2] != 0, "malformed range")
            return range(*args)
        if tag == "L":
            out = self._register(args[0], [])
            out.extend(self.decode(v) for v in _shape(args[1]))
            return out
        if tag == "D":
            out = self._register(args[0], {})
            for k, v in self._pairs(args[1]):
                out[k] = v
            return out
        if tag == "A":
            return self._register(args[0], self._array(*args[1:]))
        if tag == "G":
            return self._register(args[0], self._generator(*args[1:]))
        return self._object(*args)

    def _pairs(self, pairs: Any) -> list[tuple[Any, Any]]:
        out = []
        for pair in _shape(pairs):
            _check(type(pair) is list and len(pair) == 2, "malformed dict entry")
            out.append((self._key(pair[0]), self.decode(pair[1])))
        return out

    def _key(self, node: Any) -> Any:
        if type(node) in _PLAIN:
            return node
        node = _shape(node)
        _check(len(node) >= 2 and node[0] in ("T", "S"), "a dict key that is not a plain value")
        if node[0] == "S":
            return self.decode(node)
        _check(len(node) == 2, "malformed dict key")
        self.depth += 1
        try:
            _check(self.depth <= MAX_DEPTH, "nested too deeply")
            return tuple(self._key(v) for v in _shape(node[1]))
        finally:
            self.depth -= 1

    def _scalar(self, dtype: Any, value: Any) -> np.generic:
        _check(dtype in DTYPES and DTYPES[dtype].kind in _SCALAR_VALUE, f"numpy scalar dtype {dtype!r}")
        want = _SCALAR_VALUE[DTYPES[dtype].kind]
        _check(type(value) is want, f"numpy scalar {dtype} with a {type(value).__name__} value")
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("error")  # an int out of the dtype's range, a float that overflows
                return DTYPES[dtype].type(value)
        except (OverflowError, RuntimeWarning) as exc:
            raise _Bad(f"numpy scalar {dtype} {value!r}: {exc}") from None

    def _array(self, dtype: Any, shape: Any, order: Any, data: Any) -> np.ndarray:
        _check(dtype in DTYPES, f"array dtype {dtype!r} is not allowlisted")
        _check(type(shape) is list and len(shape) <= 32 and all(type(s) is int and s >= 0 for s in shape),
               f"bad array shape {shape!r}"[:120])
        _check(order in ("C", "F") and type(data) is str, "malformed array")
        try:
            raw = base64.b64decode(data.encode("ascii"), validate=True)
        except (ValueError, UnicodeEncodeError):
            raise _Bad("array data is not base64") from None
        count = math.prod(shape)
        _check(count * DTYPES[dtype].itemsize == len(raw),
               f"array of shape {shape} and dtype {dtype} does not match its {len(raw)} bytes"[:160])
        flat = np.frombuffer(bytearray(raw), dtype=DTYPES[dtype])  # writeable, owns a copy of the bytes
        return flat.reshape(shape, order=order)

    def _generator(self, name: Any, state: Any) -> np.random.Generator:
        _check(name in BIT_GENERATORS, f"bit generator {name!r} is not allowlisted")
        state = self.decode(state)
        _check(type(state) is dict and state.get("bit_generator") == name, "bad bit generator state")
        bg = BIT_GENERATORS[name](0)
        try:
            bg.state = state  # numpy validates it
        except (TypeError, ValueError, KeyError, OverflowError) as exc:
            raise _Bad(f"bad {name} state ({exc})") from None
        gen = np.random.Generator(bg)
        self.instances.setdefault(np.random.Generator, []).append(gen)
        return gen

    def _object(self, n: Any, name: Any, attrs: Any, items: Any) -> Any:
        _check(type(name) is str and current_name(name) in self.classes, f"class {name!r} is not allowlisted"[:160])
        cls = self.classes[current_name(name)]
        base = dict if issubclass(cls, dict) else list if issubclass(cls, list) else object
        obj = self._register(n, base.__new__(cls))  # the builtin __new__: no __init__, no class code
        self.instances.setdefault(cls, []).append(obj)
        state = {}
        for pair in _shape(attrs):
            _check(type(pair) is list and len(pair) == 2 and type(pair[0]) is str, "malformed attribute")
            key = pair[0]
            _check(not (key.startswith("__") and key.endswith("__")), f"attribute {key!r} of {name}")
            _check(not _shadows_code(cls, key), f"attribute {key!r} would shadow a method of {name}"[:160])
            state[key] = self.decode(pair[1])
        obj.__dict__.update(state)
        if isinstance(obj, dict):
            _check(items is not None, f"{name} without its entries")
            for k, v in self._pairs(items):
                dict.__setitem__(obj, k, v)  # not the subclass's __setitem__/update
        elif isinstance(obj, list):
            _check(items is not None, f"{name} without its items")
            list.extend(obj, [self.decode(v) for v in _shape(items)])
        else:
            _check(items is None, f"{name} with items")
        return obj


def loads(blob: bytes, classes: tuple[type, ...]) -> tuple[Any, dict[type, list]]:
    """The object graph in a checkpoint blob and the instances of each class in it (for the caller's
    checks). InvalidCheckpoint (message without a run number: ``why``) if it is not a valid one."""
    try:
        doc = unpack_document(bytes(blob))
        decoder = _Decoder(PYCMA_CLASSES + classes)
        root = decoder.decode(doc["root"])
    except _Bad as exc:
        raise InvalidCheckpoint(str(exc)) from None
    except Exception as exc:  # malformed data the checks above did not name (nothing of it ran)
        raise InvalidCheckpoint(f"{type(exc).__name__}: {exc}"[:200]) from None
    return root, decoder.instances
